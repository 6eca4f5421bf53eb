"""The CasADi NMPC (controller/nmpc.py) checks the OSQP fast path on the same problem."""

from __future__ import annotations

import numpy as np
import pytest

from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.mpc import MpcController
from hmpc.controller.nmpc import NmpcController
from hmpc.models.params import load_params
from hmpc.models.reference import Reference
from hmpc.models.sim.scenarios import make_scenario
from hmpc.models.sim.simulator import random_params


@pytest.fixture(scope="module")
def params():
    return load_params("params/report_2008.yaml", require_model=True)


def _gentle_curve(seconds=6.0):
    """Speed 3 -> 4.5 m/s in the low zone along a gentle left curve."""
    t = np.arange(0.0, seconds, 0.02)
    v = np.clip(3.0 + 0.5 * (t - 1.0), 3.0, 4.5)
    kap = np.where(t > 1.0, 0.03, 0.0)
    th = np.concatenate([[0.0], np.cumsum(v[1:] * kap[1:] * 0.02)])
    x = np.concatenate([[0.0], np.cumsum(v[1:] * np.cos(th[1:]) * 0.02)])
    y = np.concatenate([[0.0], np.cumsum(v[1:] * np.sin(th[1:]) * 0.02)])
    return Reference(t, x, y, th, v, name="gentle_curve")


def test_nmpc_and_mpc_agree_on_a_simple_case(params):
    ref = _gentle_curve()
    x0 = ref.initial_state(params) + np.array([0.0, 0.3, 0.0, 0.0])  # start 0.3 m off the path
    a = run_closed_loop(MpcController(params), ref, params, initial_state=x0)
    b = run_closed_loop(NmpcController(params), ref, params, initial_state=x0)
    ra, rb = a.recording, b.recording
    dv = np.abs(ra["speed"] - rb["speed"]).max()
    dlat = np.abs(a.lateral_error_m - b.lateral_error_m).max()
    late = ra["time"] >= 1.0  # after the first second (the cold starts differ most)
    dsw = np.abs(ra["steering_cmd"] - rb["steering_cmd"])[late].max()
    dap = np.abs(ra["accel_pedal_cmd"] - rb["accel_pedal_cmd"])[late].max()
    print(
        f"\nMPC vs NMPC: max |dv| {dv:.4f} m/s, max |d lateral| {dlat:.4f} m, after 1 s max "
        f"|d sw| {dsw:.4f} rad, |d accel pedal| {dap:.4f}; "
        f"NMPC solve p50 {b.metrics['solve_time_ms']['p50']:.1f} ms, MPC "
        f"{a.metrics['solve_time_ms']['p50']:.2f} ms"
    )
    assert a.metrics["failures"] == 0 and b.metrics["failures"] == 0
    assert a.metrics["internal_errors"] == 0 and b.metrics["internal_errors"] == 0
    # with the shared input cost (the same smoothness terms in both) measured max |dv| 0.0004 m/s,
    # |d lateral| 0.0055 m, |d sw| 0.012 rad, |d accel pedal| 0.0001; an NMPC with its own
    # smoothness weights instead gave |d lateral| 0.17 m: these bounds catch a cost mismatch
    assert dv < 0.03
    assert dlat < 0.05
    assert dsw < 0.15
    assert dap < 0.02
    # both correct the initial 0.3 m offset
    assert abs(a.lateral_error_m[-1]) < 0.05 and abs(b.lateral_error_m[-1]) < 0.05


def test_nmpc_failure_is_a_status_and_a_safe_command(params):
    ref = _gentle_curve()
    ctl = NmpcController(params, ipopt_max_iter=1)
    r = ctl.step(ref.initial_state(params), ref, 0.0)
    assert not r.ok and r.status.startswith("controlled_stop")
    assert r.reason.startswith("ipopt")
    assert r.command.accel_pedal == 0.0 and r.command.brake_pedal > 0.0


# ---------------------------------------------------------------- smoothness
def _first(ref: Reference, seconds: float) -> Reference:
    """The first ``seconds`` of a scenario (the NMPC is slow: short closed loops)."""
    n = int(np.searchsorted(ref.time_s, ref.time_s[0] + seconds)) + 1
    return Reference(
        ref.time_s[:n],
        ref.x_m[:n],
        ref.y_m[:n],
        ref.heading_rad[:n],
        ref.speed_mps[:n],
        name=f"{ref.name}[:{seconds:g}s]",
    )


def _smooth_figures(m):
    return (
        f"rev>=1deg {m['steering_reversals_per_min']['1deg']:.1f}/min, >=5deg "
        f"{m['steering_reversals_per_min']['5deg']:.1f}/min, steering rate RMS "
        f"{m['steering_rate_rms_radps']:.3f} rad/s, brake rate RMS "
        f"{m['brake_pedal_rate_rms_ps']:.3f}/s, speed RMS {m['speed_error_rms_mps']:.3f} m/s, "
        f"lateral RMS {m['lateral_error_rms_m']:.3f} m, pedal switches "
        f"{m['pedal_switches_per_min']:.1f}/min, failures {m['failures']}, solve p50 "
        f"{m['solve_time_ms']['p50']:.0f} ms"
    )


@pytest.mark.parametrize("which", ["report_2008", "random_913"])
def test_nmpc_idle_hold_through_the_estimator_is_smooth(params, which):
    """The first 24 s of idle_hold (up to 1 m/s and holding it), default sensor noise
    through the EKF, seed 0, on report_2008 and on ``random_params(913)`` (a set no other
    test tunes against). Measured with the fast path's input cost (MpcConfig defaults),
    report_2008 / random_913: reversals >= 1 deg 10.0 / 7.5 per min, >= 5 deg 0 / 0;
    steering rate RMS 0.024 / 0.011 rad/s; brake rate RMS 0.010 / 0.010 /s (rates: change
    per control update / period); speed RMS 0.010 / 0.011 m/s; lateral RMS 0.008 / 0.003 m;
    no pedal switch. Without the input cost the NMPC reverses about ten times as often.
    Bounds: the acceptance limits for reversals >= 1 deg (12/min, 1.2x the larger
    figure), speed RMS and pedal switches; one reversal >= 5 deg in the run (2.5/min);
    about 2x the larger figure for the steering and brake rates and the lateral RMS."""
    if which == "random_913":
        params = random_params(913)
    ref = _first(make_scenario("idle_hold", params), 24.0)
    res = run_closed_loop(NmpcController(params), ref, params, seed=0)
    m = res.metrics
    print(f"\nNMPC idle_hold[:24 s] {which}: {_smooth_figures(m)}")
    assert m["failures"] == 0 and m["internal_errors"] == 0
    assert m["steering_reversals_per_min"]["1deg"] <= 12.0
    assert m["steering_reversals_per_min"]["5deg"] <= 2.5
    assert m["steering_rate_rms_radps"] <= 0.05
    assert m["brake_pedal_rate_rms_ps"] <= 0.022
    assert m["speed_error_rms_mps"] <= 0.05
    assert m["lateral_error_rms_m"] <= 0.02
    assert m["pedal_switches_per_min"] <= 6.0


def test_nmpc_figure8_through_the_estimator_is_smooth(params):
    """The first 20 s of figure8 (the first loop and the turn into the second), default
    sensor noise through the EKF, seed 0, report_2008. Measured: reversals >= 1 deg
    18/min, speed RMS 0.010 m/s, lateral RMS 0.113 m (the smoothness costs tracking here:
    without the input cost, about 70/min and 0.03 m). Bounds: the acceptance limits (30 reversals
    >= 1 deg/min, 1.7x the figure; speed 0.3 m/s; lateral 0.3 m, 2.7x)."""
    ref = _first(make_scenario("figure8", params), 20.0)
    res = run_closed_loop(NmpcController(params), ref, params, seed=0)
    m = res.metrics
    print(f"\nNMPC figure8[:20 s]: {_smooth_figures(m)}")
    assert m["failures"] == 0 and m["internal_errors"] == 0
    assert m["steering_reversals_per_min"]["1deg"] <= 30.0
    assert m["speed_error_rms_mps"] <= 0.3
    assert m["lateral_error_rms_m"] <= 0.3
