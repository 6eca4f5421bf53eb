"""The PID baseline (controller/pid.py) through the state estimator: filtered inputs and
rate-limited outputs keep its steering quiet, while it stays a naive PID.

Closed loops run at the default sensor noise through the EKF (controller/closed_loop.py
feeds the controller from simulated sensors), seed 0, on params/report_2008.yaml and on
``random_params(913)``, a parameter set no other test tunes against. Each bound states
the figure measured with this PidConfig and the margin; a PID without the input filter and
the output rate limits exceeds them several times over on report_2008 idle_hold. Rates are
per control update.
"""

from __future__ import annotations

import numpy as np
import pytest

from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.pid import PidConfig, PidController
from hmpc.models.params import load_params
from hmpc.models.reference import Reference
from hmpc.models.sim.scenarios import make_scenario
from hmpc.models.sim.simulator import random_params

SEED = 0


@pytest.fixture(scope="module", params=["report_2008", "random_913"])
def params(request):
    if request.param == "report_2008":
        return load_params("params/report_2008.yaml", require_model=True)
    return random_params(913)


def _straight(v_of_t, seconds=10.0, dt=0.02):
    t = np.arange(0.0, seconds, dt)
    v = np.asarray(v_of_t(t), dtype=float)
    x = np.concatenate([[0.0], np.cumsum(v[1:] * dt)])
    return Reference(t, x, np.zeros_like(t), np.zeros_like(t), v, name="straight")


def _figures(m):
    return (
        f"rev>=1deg {m['steering_reversals_per_min']['1deg']:.1f}/min, >=5deg "
        f"{m['steering_reversals_per_min']['5deg']:.1f}/min, steering rate RMS "
        f"{m['steering_rate_rms_radps']:.3f} rad/s, brake rate RMS "
        f"{m['brake_pedal_rate_rms_ps']:.3f}/s, speed RMS {m['speed_error_rms_mps']:.3f} m/s, "
        f"lateral RMS {m['lateral_error_rms_m']:.3f} m, pedal switches "
        f"{m['pedal_switches_per_min']:.1f}/min, failures {m['failures']}"
    )


def test_idle_hold_through_the_estimator_is_smooth(params):
    """Measured (report_2008 / random_913): reversals >= 1 deg 18.3 / 18.3 per min (the
    MPC's acceptance target, 12, is missed by the baseline), >= 5 deg 0 / 0; steering rate
    RMS 0.020 / 0.024 rad/s; brake rate RMS 0.041 / 0.041 /s; speed RMS 0.042 / 0.038 m/s;
    pedal switches 3.1 / 3.1 per min. Bounds: about 1.4x the larger figure, or the
    acceptance limit where that is tighter (speed RMS 0.05 m/s, pedal switches 6/min)."""
    ref = make_scenario("idle_hold", params)
    res = run_closed_loop(PidController(params), ref, params, seed=SEED)
    m = res.metrics
    print(f"\nPID idle_hold: {_figures(m)}")
    assert m["failures"] == 0 and m["internal_errors"] == 0
    assert m["steering_reversals_per_min"]["1deg"] <= 25.0
    assert m["steering_reversals_per_min"]["5deg"] <= 2.0
    assert m["steering_rate_rms_radps"] <= 0.034
    assert m["brake_pedal_rate_rms_ps"] <= 0.058
    assert m["speed_error_rms_mps"] <= 0.05
    assert m["lateral_error_rms_m"] <= 0.01
    assert m["pedal_switches_per_min"] <= 6.0


def test_figure8_through_the_estimator(params):
    """Measured (report_2008 / random_913): reversals >= 1 deg 9.0 / 9.0 per min, speed RMS
    0.033 / 0.039 m/s, lateral RMS 0.387 / 0.387 m (pure pursuit cuts the 8 m loops: the
    acceptance's 0.3 m is missed by the baseline). Bounds ~1.3x."""
    ref = make_scenario("figure8", params)
    res = run_closed_loop(PidController(params), ref, params, seed=SEED)
    m = res.metrics
    print(f"\nPID figure8: {_figures(m)}")
    assert m["failures"] == 0 and m["internal_errors"] == 0
    assert m["steering_reversals_per_min"]["1deg"] <= 15.0
    assert m["speed_error_rms_mps"] <= 0.06
    assert m["lateral_error_rms_m"] <= 0.45


def test_pedal_output_is_rate_limited_and_steps_do_not_kick(params):
    """A 2 m/s step of the speed reference: the signed pedal moves at most
    ``pedal_rate_max_ps`` per second (no proportional or derivative kick), and still
    reaches full throttle."""
    cfg = PidConfig()
    ref = _straight(lambda t: np.where(t < 1.0, 0.0, 2.0))
    ctl = PidController(params, cfg)
    prev, t = None, 0.0
    peds = []
    for k in range(40):
        t = 0.1 * k
        r = ctl.step(np.array([0.0, 0.0, 0.0, 0.0]), ref, t)  # the car does not move
        u = r.command.accel_pedal - r.command.brake_pedal
        if prev is not None:
            assert abs(u - prev) <= cfg.pedal_rate_max_ps * 0.1 + 1e-9
        prev = u
        peds.append(u)
    assert max(peds) == pytest.approx(1.0)


def test_speed_noise_is_filtered(params):
    """White 0.05 m/s speed noise on a car held at the reference: the pedal moves far less
    than a PID on the raw measurement (``speed_filter_tau_s=0``) would move it."""
    ref = _straight(lambda t: np.full_like(t, 3.0))
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.05, 100)

    def pedal_rms_rate(cfg):
        ctl = PidController(params, cfg)
        us = []
        for k in range(100):
            x = np.array([3.0 * 0.1 * k, 0.0, 0.0, 3.0 + noise[k]])
            c = ctl.step(x, ref, 0.1 * k).command
            us.append(c.accel_pedal - c.brake_pedal)
        return float(np.sqrt(np.mean(np.diff(us[10:]) ** 2)))

    filtered = pedal_rms_rate(PidConfig())
    raw = pedal_rms_rate(PidConfig(speed_filter_tau_s=0.0, pedal_rate_max_ps=1e9))
    print(f"\npedal change RMS per step: filtered {filtered:.4f}, raw {raw:.4f}")
    assert filtered < 0.5 * raw


def test_steering_output_respects_its_rate_limit(params):
    """A car 2 m off a straight path: the steering wheel turns at most
    ``steering_rate_max_radps`` per second."""
    cfg = PidConfig()
    ref = _straight(lambda t: np.full_like(t, 3.0))
    ctl = PidController(params, cfg)
    sws = [
        ctl.step(np.array([0.3 * k, 2.0, 0.0, 3.0]), ref, 0.1 * k).command.steering_wheel_angle_rad
        for k in range(20)
    ]
    steps = np.abs(np.diff(sws))
    assert steps.max() <= cfg.steering_rate_max_radps * 0.1 + 1e-9
    assert abs(sws[-1]) > 0.5  # it does steer back towards the path


def test_config_rejects_nonsense():
    with pytest.raises(ValueError):
        PidConfig(setpoint_weight=1.5)
    with pytest.raises(ValueError):
        PidConfig(pedal_rate_max_ps=0.0)
    with pytest.raises(ValueError):
        PidConfig(speed_filter_tau_s=-1.0)
