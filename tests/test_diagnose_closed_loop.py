"""Closing the loop (diagnosis issue): the MPC on a benchmark case's ground-truth plant
(``models.sim.simulator.TruthPlant`` with the concealed effect), once with the report's
baseline model and once with the extended model ``diagnose`` writes (``--params-out``), both
fitted on that case's recording. A dead time reaches the MPC through the conventions' keys and
tracking improves; an effect the MPC cannot represent leaves its tracking as it was (the keys
hold the baseline's fit), never worse. The MPC is fed as a car is (simulated sensors through
the EKF, ``run_closed_loop(effects=)``). Seed 1; ``tools/bench_diagnose.py --closed-loop`` runs
every case."""
from __future__ import annotations

import pytest

from hmpc.tools.bench_diagnose import closed_loop


@pytest.fixture(scope="module")
def rows():
    got = closed_loop(1, cases=["actuator_delay_longitudinal", "actuator_delay_steering",
                                "aero_drag"])
    return {r["case"]: r for r in got}


@pytest.mark.parametrize("case", ["actuator_delay_longitudinal", "actuator_delay_steering"])
def test_a_diagnosed_dead_time_improves_mpc_tracking(rows, case):
    r = rows[case]
    key = r["metric"]
    assert r["extended"][key] < 0.8 * r["baseline"][key], r
    # the other channel does not pay for it
    other = "speed_rmse_mps" if key == "lateral_rmse_m" else "lateral_rmse_m"
    assert r["extended"][other] <= 1.1 * r["baseline"][other] + 1e-3, r


def test_an_effect_the_mpc_cannot_use_leaves_tracking_unchanged(rows):
    r = rows["aero_drag"]
    key = r["metric"]
    assert r["extended"][key] <= 1.02 * r["baseline"][key], r
    assert any("aero_drag" in n for n in r["notes"])
