"""The online model estimator's acceptance over several seeded hidden parameter sets, and the
MPC's smoothness on cars it was not tuned on.

The controller starts from params/report_2008.yaml; the simulated car is a seeded hidden set
(tests/_adapt.py: steering scale and every zone's gains 10-25 % off, steering offset 13 mrad
off). Per set:

- figure8 with ``--adapt``: the learned steering offset within 2 mrad and scale within 3 % of
  the truth; speed and lateral RMS within 2x of the controller given the truth (0.05 floors);
  no failure;
- ramp_sequence with ``--adapt``: the low and high zones' accelerator gains within 6 %;
  tracking within 2x of the truth's controller; no failure;
- ramp_sequence, adaptation on and off: steering reversals of 1 deg or more at most 12 per
  minute (the truth's controller: 2-10); without learning also on set 1, whose file is
  28 deg of steering wheel off its straight-ahead, and the car on its path within 0.3 m.

Sets 2, 3 and 8 have a steering gain 14-25 % above the file's (the lateral loop's margin
smallest). docs/results.md lists these sets and eight more that no tuning looked at.
"""

from __future__ import annotations

import pytest

from _adapt import hidden_params
from _data import REPORT_PARAMS
from hmpc.controller.adapt import ModelAdapter
from hmpc.controller.build import make_controller
from hmpc.controller.closed_loop import run_closed_loop
from hmpc.models.params import load_params
from hmpc.models.sim.scenarios import make_scenario

OFF, SCALE = "steering.offset_rad", "steering.scale"
#: the hidden sets checked (seeds of tests/_adapt.py)
SEEDS = (2, 3, 5, 7, 8)
#: steering reversals >= 1 deg per minute on ramp_sequence, adaptation on or off
MAX_REVERSALS_PER_MIN = 12.0


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS)


def _run(params, truth, scenario: str, mode: str) -> dict:
    """``mode``: "truth" (the controller given the car's values), "file" (the file, no
    learning) or "adapt" (the file and the online learner)."""
    ctl_params = truth if mode == "truth" else params
    ad = ModelAdapter(params, 0.1) if mode == "adapt" else None
    res = run_closed_loop(
        make_controller("mpc", ctl_params),
        make_scenario(scenario, params),
        ctl_params,
        plant_params=truth,
        adapter=ad,
    )
    m = res.metrics
    assert m["internal_errors"] == 0, res.internal_errors[:1]
    return m


def _within_2x(m: dict, m_truth: dict) -> None:
    for key in ("speed_error_rms_mps", "lateral_error_rms_m"):
        assert m[key] <= max(2.0 * m_truth[key], 0.05), (key, m[key], m_truth[key])
    assert m["failures"] == 0 and m["followed"]


@pytest.mark.parametrize("seed", SEEDS)
def test_a_hidden_set_is_learned_tracked_and_driven_smoothly(params, seed):
    truth = hidden_params(params, seed)
    # figure8: the steering map
    f8 = _run(params, truth, "figure8", "adapt")
    a = f8["adaptation"]
    assert abs(a[OFF]["final"] - truth.steering.offset_rad) < 0.002
    assert abs(a[SCALE]["final"] / truth.steering.scale - 1) < 0.03
    assert a[OFF]["valid"] and a[SCALE]["identified"] and a[SCALE]["converged_t_s"] < 10.0
    lo, hi = a[SCALE]["ci95"]
    assert lo < a[SCALE]["final"] < hi
    # the cost per control step: CPU time, tens of microseconds (a loaded host's counts)
    assert f8["adaptation_details"]["cost_us"]["p50"] < 1000.0
    _within_2x(f8, _run(params, truth, "figure8", "truth"))
    # ramp_sequence: the pedal gains, and the steering on a straight road
    rs = _run(params, truth, "ramp_sequence", "adapt")
    for zone in (1, 2):
        z = truth.zones[zone]
        got = rs["adaptation"][f"longitudinal.zones.{z.name}.scale_mps2"]["final"]
        assert abs(got / z.scale_mps2 - 1) < 0.06, (z.name, got, z.scale_mps2)
    # straight: the scale is held where the file has it, the offset drives straight with it
    a = rs["adaptation"]
    assert a[SCALE]["final"] == params.steering.scale and not a[SCALE]["identified"]
    _within_2x(rs, _run(params, truth, "ramp_sequence", "truth"))
    assert rs["steering_reversals_per_min"]["1deg"] <= MAX_REVERSALS_PER_MIN


@pytest.mark.parametrize("seed", [1, *SEEDS])
def test_without_learning_the_steering_stays_calm_on_a_straight_road(params, seed):
    truth = hidden_params(params, seed)
    rf = _run(params, truth, "ramp_sequence", "file")
    assert rf["failures"] == 0
    # sets 1 and 8: the file's straight-ahead is 10-28 deg of steering wheel off; the
    # offset-free steering (MpcConfig.steer_correction_tau_s) brings them from 15.5 and 13.5
    # reversals a minute to 7.7 and 9.7
    assert rf["steering_reversals_per_min"]["1deg"] <= MAX_REVERSALS_PER_MIN
    # and the car drives the straight road on its path, not beside it (0.44 and 0.25 m RMS
    # without the correction; measured 0.26 and 0.05 m with it)
    assert rf["lateral_error_rms_m"] <= 0.3
