"""controller/limits.py: the last line of defence, independent of any optimiser."""

from __future__ import annotations

import copy
import dataclasses
import math

import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.models.params import VehicleLimits
from hmpc.models.params import load_params


@pytest.fixture(scope="module")
def params():
    return load_params("params/report_2008.yaml", require_model=True)


def test_limits_come_from_the_parameter_file(params):
    assert ActuatorLimits.from_params(None) == ActuatorLimits()
    p = copy.deepcopy(params)
    p.vehicle.steering_wheel_angle_max_rad = 8.0
    p.limits = VehicleLimits(
        steering_wheel_rate_max_radps=3.0, accel_max_mps2=1.5, jerk_max_mps3=1.0
    )
    lim = ActuatorLimits.from_params(p)
    assert lim.steering_wheel_angle_max_rad == 8.0
    assert lim.steering_wheel_rate_max_radps == 3.0
    assert lim.accel_max_mps2 == 1.5 and lim.jerk_max_mps3 == 1.0
    assert lim.decel_max_mps2 == ActuatorLimits().decel_max_mps2
    p.limits = VehicleLimits(steering_wheel_angle_max_rad=6.0)  # limits: wins over vehicle:
    assert ActuatorLimits.from_params(p).steering_wheel_angle_max_rad == 6.0


def test_limits_are_frozen_and_validated():
    lim = ActuatorLimits()
    with pytest.raises(dataclasses.FrozenInstanceError):
        lim.accel_max_mps2 = 5.0  # frozen
    with pytest.raises(ValueError):
        ActuatorLimits(jerk_max_mps3=-1.0)
    with pytest.raises(ValueError):
        ActuatorLimits(steering_wheel_angle_max_rad=float("nan"))
    with pytest.raises(ValueError):
        apply_limits(Command(0, 0, 0), None, lim, 0.0)


def test_clamps_rates_and_pedal_exclusion():
    lim = ActuatorLimits()
    dt = 0.1
    out = apply_limits(Command(100.0, 2.0, 0.0), None, lim, dt)
    assert out == Command(lim.steering_wheel_angle_max_rad, 1.0, 0.0)
    prev = Command(0.0, 0.0, 0.0)
    out = apply_limits(Command(3.0, 0.9, 0.0), prev, lim, dt)
    assert out.steering_wheel_angle_rad == pytest.approx(lim.steering_wheel_rate_max_radps * dt)
    assert out.accel_pedal == pytest.approx(lim.accel_pedal_rate_max_ps * dt)
    # releasing is never rate-limited
    assert apply_limits(Command(0, 0.0, 0.0), Command(0, 0.8, 0), lim, dt).accel_pedal == 0.0
    # both pressed: the brake wins
    out = apply_limits(Command(0.0, 0.5, 0.1), Command(0.0, 0.5, 0.1), lim, dt)
    assert out.accel_pedal == 0.0 and out.brake_pedal == pytest.approx(0.1)
    # NaN never reaches an actuator: steering held, throttle released, brake applied
    out = apply_limits(Command(float("nan"), 0.3, 0.0), Command(0.2, 0.3, 0.0), lim, dt)
    assert out.steering_wheel_angle_rad == 0.2 and out.accel_pedal == 0.0
    assert out.brake_pedal > 0.0


def test_zone_model_caps_acceleration_and_deceleration(params):
    lim = ActuatorLimits()
    z = params.zones[2]  # high: offset -0.25, scale 3.0, brake 6.0
    out = apply_limits(Command(0.0, 1.0, 0.0), None, lim, 0.1, zone=z)
    assert z.accel_mps2(out.accel_pedal, 0.0) == pytest.approx(lim.accel_max_mps2)
    out = apply_limits(Command(0.0, 0.0, 1.0), None, lim, 0.1, zone=z)
    assert z.accel_mps2(0.0, out.brake_pedal) == pytest.approx(-lim.decel_max_mps2)


finite = st.floats(-1e3, 1e3, allow_nan=False)
any_float = st.one_of(finite, st.just(float("nan")), st.just(float("inf")))


@seed(4242)
@settings(max_examples=300, deadline=None)
@given(
    sw=any_float,
    ap=any_float,
    bp=any_float,
    psw=st.floats(-7.8, 7.8),
    pap=st.floats(0, 1),
    dt=st.floats(0.01, 0.5),
)
def test_property_output_always_within_limits(sw, ap, bp, psw, pap, dt):
    lim = ActuatorLimits()
    prev = Command(psw, pap, 0.0)
    out = apply_limits(Command(sw, ap, bp), prev, lim, dt)
    assert all(math.isfinite(v) for v in out.as_tuple())
    assert abs(out.steering_wheel_angle_rad) <= lim.steering_wheel_angle_max_rad + 1e-12
    assert abs(out.steering_wheel_angle_rad - psw) <= lim.steering_wheel_rate_max_radps * dt + 1e-9
    assert 0.0 <= out.accel_pedal <= 1.0 and 0.0 <= out.brake_pedal <= 1.0
    assert not (out.accel_pedal > 0 and out.brake_pedal > 0)
    assert out.accel_pedal <= pap + lim.accel_pedal_rate_max_ps * dt + 1e-12
    assert out.brake_pedal <= lim.brake_pedal_rate_max_ps * dt + 1e-12
