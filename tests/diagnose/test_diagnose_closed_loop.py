"""Closing the loop: the MPC on a benchmark case's ground-truth plant
(``models.sim.simulator.TruthPlant`` with the concealed effect), once with the report's
baseline model and once with the extended model ``diagnose`` writes (``--params-out``), both
fitted on that case's recording. A dead time reaches the MPC through the conventions' keys, a
lag, drag or creep through ``extensions:`` (the MPC's ``HybridPlant(params, extensions=True)``
and its lag handling), and tracking improves, never worsens, as far as the MPC on the true
model with the effect (``ideal``) tracks. The MPC is fed as a car is (simulated sensors through
the EKF, ``run_closed_loop(effects=)``). Seed 1; ``tools/bench_diagnose.py --closed-loop`` runs
every case."""

from __future__ import annotations

import pytest

from hmpc.tools.bench_diagnose import closed_loop


@pytest.fixture(scope="module")
def rows():
    got = closed_loop(
        1,
        cases=[
            "actuator_delay_longitudinal",
            "actuator_delay_steering",
            "actuator_lag",
            "aero_drag",
        ],
        with_truth=False,
    )
    return {r["case"]: r for r in got}


@pytest.mark.parametrize(
    "case", ["actuator_delay_longitudinal", "actuator_delay_steering", "actuator_lag"]
)
def test_a_diagnosed_dead_time_or_lag_improves_mpc_tracking(rows, case):
    r = rows[case]
    key = r["metric"]
    assert r["extended"][key] < 0.8 * r["baseline"][key], r
    # and reaches what the true model with the effect gives the same MPC (within 10 %)
    assert r["extended"][key] <= 1.1 * r["ideal"][key], r
    # the other channel does not pay for it
    other = "speed_rmse_mps" if key == "lateral_rmse_m" else "lateral_rmse_m"
    assert r["extended"][other] <= 1.1 * r["baseline"][other] + 1e-3, r


def test_a_diagnosed_drag_improves_mpc_tracking_as_far_as_the_true_model_does(rows):
    # the baseline's zones absorb most of the drag at the speeds driven, and the MPC's
    # feedback the rest: a small gain (-2 %), but all there is: the MPC on the true model
    # with the drag tracks no better (measured: baseline 0.1579, extended 0.1535, ideal
    # 0.1547 m/s)
    r = rows["aero_drag"]
    key = r["metric"]
    assert r["extended"][key] < r["baseline"][key], r
    assert r["extended"][key] <= 1.02 * r["ideal"][key], r
    assert any("aero_drag" in n and "eq. 8" in n for n in r["notes"])
