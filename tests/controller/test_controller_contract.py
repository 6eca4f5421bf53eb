"""The controller contract (controller/base.py): every controller implements it, a step never
raises and never returns None, and a bug inside a controller is an internal error with its
traceback (and a safe stop), never a quiet "controlled_stop". Also the deceleration limit of
a controlled stop (controller/limits.py)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.base import ControlResult, Controller, Status
from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.nmpc import NmpcController
from hmpc.controller.pid import PidController
from hmpc.models.params import load_params
from hmpc.models.reference import Reference

CONTROLLERS = (MpcController, NmpcController, PidController)


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


def straight(v_mps: float, seconds: float = 20.0) -> Reference:
    t = np.arange(0.0, seconds, 0.02)
    v = np.full(len(t), v_mps)
    x = np.concatenate([[0.0], np.cumsum(v[1:] * 0.02)])
    return Reference(t, x, 0 * t, 0 * t, v, name="straight")


def assert_safe_stop(r: ControlResult, lim: ActuatorLimits) -> None:
    """A command the car can take, and a stop: throttle released, the brake applied."""
    c = r.command
    assert np.isfinite(c.steering_wheel_angle_rad)
    assert abs(c.steering_wheel_angle_rad) <= lim.steering_wheel_angle_max_rad
    assert c.accel_pedal == 0.0 and 0.0 < c.brake_pedal <= 1.0


@pytest.mark.parametrize("cls", CONTROLLERS, ids=lambda c: c.__name__)
def test_every_controller_implements_the_protocol(params, cls):
    ctl = cls(params)
    assert isinstance(ctl, Controller)
    sig = inspect.signature(ctl.step)
    for name in ("stop", "obstacle_distance_m"):
        assert sig.parameters[name].kind is inspect.Parameter.KEYWORD_ONLY, name
    assert isinstance(ctl.name, str) and ctl.name
    ref = straight(3.0)
    ctl.reset()
    r = ctl.step(ref.initial_state(params), ref, 0.0, stop=False, obstacle_distance_m=None)
    assert isinstance(r, ControlResult) and isinstance(r.status, Status)
    assert r.ok and r.status in (Status.SOLVED, Status.SOLVED_INACCURATE, Status.OK)
    assert r.traceback is None and r.step_time_s > 0


def test_status_values_are_the_stable_json_text():
    assert [s.value for s in Status] == [
        "solved",
        "solved_inaccurate",
        "ok",
        "hold",
        "shifted_plan",
        "controlled_stop",
        "internal_error",
    ]
    assert str(Status.SHIFTED_PLAN) == "shifted_plan" and Status("hold") is Status.HOLD
    assert {s for s in Status if s.ok} == {
        Status.SOLVED,
        Status.SOLVED_INACCURATE,
        Status.OK,
        Status.HOLD,
    }


def _boom(*_a, **_k):
    raise TypeError("deliberate bug")


@pytest.mark.parametrize(
    "cls, part, method",
    [
        (MpcController, "qp", "solve"),
        (NmpcController, None, "_set_parameters"),
        (PidController, None, "_step"),
    ],
    ids=["mpc", "nmpc", "pid"],
)
def test_a_bug_is_an_internal_error_with_traceback_and_a_safe_stop(
    params, cls, part, method, monkeypatch
):
    ctl = cls(params)
    monkeypatch.setattr(ctl if part is None else getattr(ctl, part), method, _boom)
    ref = straight(3.0)
    r = ctl.step(ref.initial_state(params), ref, 0.0)
    assert r.status is Status.INTERNAL_ERROR and not r.ok
    assert r.reason == "TypeError: deliberate bug"
    assert "Traceback" in r.traceback and "_boom" in r.traceback
    assert_safe_stop(r, ctl.limits)


def test_a_bug_after_a_good_plan_is_still_a_stop_not_the_old_plan(params, monkeypatch):
    """A solver failure follows the previous plan (shifted); a bug does not trust it."""
    ref = straight(5.0)
    ctl = MpcController(params)
    x = ref.initial_state(params)
    assert ctl.step(x, ref, 0.0).status is Status.SOLVED
    monkeypatch.setattr(ctl.qp, "solve", _boom)
    r = ctl.step(x + np.array([0.5, 0.0, 0.0, 0.0]), ref, 0.1)
    assert r.status is Status.INTERNAL_ERROR and r.plan is None
    assert_safe_stop(r, ctl.limits)
    monkeypatch.undo()
    # the next steps start again from a cold plan, not from one written by the failed step
    r = ctl.step(x + np.array([1.0, 0.0, 0.0, 0.0]), ref, 0.2)
    assert r.status is Status.SOLVED


def test_a_bug_in_the_fallback_too_still_returns_a_safe_stop(params, monkeypatch):
    ctl = MpcController(params)
    monkeypatch.setattr(ctl.qp, "solve", _boom)
    monkeypatch.setattr(ctl, "_controlled_stop", _boom)
    ref = straight(3.0)
    r = ctl.step(ref.initial_state(params), ref, 0.0)
    assert r.status is Status.INTERNAL_ERROR and "deliberate bug" in r.traceback
    assert_safe_stop(r, ctl.limits)


def test_bad_input_is_a_controlled_stop_not_an_internal_error(params):
    ref = straight(3.0)
    for cls in (MpcController, PidController):
        ctl = cls(params)
        for state in ([np.nan, 0.0, 0.0, 3.0], [0.0, 0.0, 0.0]):
            r = ctl.step(state, ref, 0.0)
            assert r.status is Status.CONTROLLED_STOP and r.reason == "invalid state", cls
            assert r.traceback is None
            assert_safe_stop(r, ctl.limits)


def test_the_closed_loop_counts_internal_errors(params, monkeypatch):
    ref = straight(3.0, seconds=2.0)
    ctl = MpcController(params)
    monkeypatch.setattr(ctl.qp, "solve", _boom)
    res = run_closed_loop(ctl, ref, params)
    m = res.metrics
    assert m["steps"] == 20 and m["internal_errors"] == 20 and m["failures"] == 20
    assert m["statuses"] == {"internal_error": 20}
    assert len(res.internal_errors) == 20 and "deliberate bug" in res.internal_errors[0][1]
    assert np.all(res.recording["accel_pedal_cmd"] == 0.0)
    # without the bug: none
    monkeypatch.undo()
    m = run_closed_loop(MpcController(params), ref, params).metrics
    assert m["internal_errors"] == 0 and m["failures"] == 0


def test_progress_is_a_callback_not_a_print(params, capsys):
    ref = straight(3.0, seconds=2.0)
    seen = []
    run_closed_loop(PidController(params), ref, params, progress=lambda f, t: seen.append(f))
    assert seen == sorted(seen) and seen[0] == 0.0 and len(seen) >= 9
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
    with pytest.raises(ValueError):
        run_closed_loop(PidController(params), ref, params, progress=True)


# ------------------------------------------------------------ controlled-stop deceleration
def test_apply_limits_brake_cap_comfort_in_driving_higher_in_a_controlled_stop(params):
    lim = ActuatorLimits()
    assert lim.decel_max_mps2 == 3.5 and lim.controlled_stop_decel_max_mps2 == 4.0
    z = params.zones[1]
    full = Command(0.0, 0.0, 1.0)
    bp_drive = apply_limits(full, None, lim, 0.1, zone=z).brake_pedal
    bp_stop = apply_limits(full, None, lim, 0.1, zone=z, controlled_stop=True).brake_pedal
    # the zone model's deceleration at the capped pedal is exactly the limit
    assert z.accel_mps2(0.0, bp_drive) == pytest.approx(-3.5, abs=1e-12)
    assert z.accel_mps2(0.0, bp_stop) == pytest.approx(-4.0, abs=1e-12)
    # a parameter file that raises the comfort limit above it raises the stop's too
    hi = ActuatorLimits(decel_max_mps2=4.5)
    bp = apply_limits(full, None, hi, 0.1, zone=z, controlled_stop=True).brake_pedal
    assert z.accel_mps2(0.0, bp) == pytest.approx(-4.5, abs=1e-12)


def test_the_controlled_stop_path_uses_the_stop_limit(params):
    """A controlled stop asked to brake at 6 m/s^2 ramps up to the stop limit (4.0 m/s^2 on
    the zone model), not to the comfort limit (3.5) and not beyond."""
    ctl = MpcController(params, MpcConfig(stop_brake_decel_mps2=6.0))
    ctl._zone = 1
    z = params.zones[1]
    bps = [ctl._controlled_stop(0.1 * i, "test", 1).command.brake_pedal for i in range(40)]
    assert np.all(np.diff(bps) >= 0) and bps[0] < bps[-1]  # a ramp
    assert z.accel_mps2(0.0, bps[-1]) == pytest.approx(-4.0, abs=1e-9)
    r = ctl._controlled_stop(4.0, "test", 1)
    assert r.status is Status.CONTROLLED_STOP and r.reason == "test"
