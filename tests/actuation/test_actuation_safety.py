"""Seeded property tests of the actuation limits: whatever stream of commands a controller or an
operator produces, the limiter after the controller makes it pass the independent check at the
encoder, and the bytes that leave decode to values within the limits. Never throttle with brake.
"""

from __future__ import annotations

import math
from collections import deque

import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

from _data import PARAMS_DIR, REPORT_PARAMS
from hmpc.controller.actuation import builders
from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.actuation.safety import (
    AngleCheck,
    AngleLimiter,
    AngleLimits,
    ToyotaLimits,
    ToyotaSteerCheck,
    ToyotaTorqueLimiter,
    accel_ok,
    clip_accel,
    clip_pedals,
    pedals_ok,
)
from hmpc.models.params import load_params

SEED = 20261123  # printed by hypothesis on failure; fixed so a failure reproduces
TOY = load_profile(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml")
BW = load_profile(PARAMS_DIR / "bywire.actuation.yaml")
PARAMS = load_params(REPORT_PARAMS, require_model=True)

wild = st.one_of(st.floats(-5000, 5000), st.sampled_from([math.nan, math.inf, -math.inf, 1e9]))


@seed(SEED)
@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(wild, st.floats(-2000, 2000), st.booleans(), st.floats(0.005, 0.02)),
        min_size=1,
        max_size=300,
    )
)
def test_toyota_torque_never_leaves_outside_panda_limits(stream):
    lim = ToyotaLimits()
    limiter, check = ToyotaTorqueLimiter(lim), ToyotaSteerCheck(lim)
    eps = deque([0.0] * lim.eps_samples, maxlen=lim.eps_samples)
    spec = TOY.commands["steer_torque"]
    t = 0.0
    for k, (desired, eps_raw, allowed, dt) in enumerate(stream):
        t += dt
        eps.append(eps_raw * lim.eps_torque_factor)
        check.eps_torque(eps_raw)
        torque = limiter.clip(desired, t, min(eps), max(eps), active=allowed)
        frame = builders.steering_lka(spec, torque, allowed, k)
        sent = builders.decode_command(spec, frame.data)["STEER_TORQUE_CMD"]
        assert sent == torque and abs(sent) <= lim.max_torque
        assert check.check(sent, allowed, t, allowed) == ""


@seed(SEED)
@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(st.one_of(st.floats(-50, 50), st.just(math.nan)), st.booleans()),
        min_size=1,
        max_size=100,
    )
)
def test_toyota_accel_within_bounds(stream):
    lim = ToyotaLimits()
    spec = TOY.commands["accel"]
    for a, allowed in stream:
        a2 = clip_accel(a, lim, active=allowed)
        assert accel_ok(a2, allowed, lim) == ""
        raw = builders.decode_command(spec, builders.acc_control(spec, a2).data)["ACCEL_CMD"]
        assert lim.accel_min_mps2 <= raw * 0.001 <= lim.accel_max_mps2


@seed(SEED)
@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.one_of(st.floats(-20, 20), st.just(math.nan)),
            st.floats(0, 30),
            st.floats(-1, 2),
            st.floats(-1, 2),
        ),
        min_size=1,
        max_size=200,
    )
)
def test_bywire_angle_and_pedals_within_schedule_never_both_pedals(stream):
    lim = AngleLimits.from_params(PARAMS)
    s_spec, p_spec = BW.commands["steer_angle"], BW.commands["pedals"]
    limiter, check = AngleLimiter(lim), AngleCheck(lim, s_spec.period_s)
    prev, dt = None, p_spec.period_s
    for k, (angle, v, ap, bp) in enumerate(stream):
        a = limiter.clip(angle, v, s_spec.period_s)
        raw = builders.decode_command(s_spec, builders.bw_steer_cmd(s_spec, a, True, k).data)
        sent = raw["STEER_ANGLE_CMD"] * 0.001
        assert check.check(sent, v) == ""
        lo, hi = lim.angle_range_rad(v)
        assert lo - 1e-3 <= sent <= hi + 1e-3
        ap2, bp2 = clip_pedals(ap, bp, prev, dt, lim)
        prev = (ap2, bp2)
        assert pedals_ok(ap2, bp2, lim) == ""
        raw = builders.decode_command(p_spec, builders.bw_pedal_cmd(p_spec, ap2, bp2, True, k).data)
        assert not (raw["ACCEL_PEDAL_CMD"] > 0 and raw["BRAKE_PEDAL_CMD"] > 0)


def test_checks_catch_what_the_limiter_would_have_stopped():
    """The encoder-side checks are not vacuous: raw violations are refused."""
    lim = ToyotaLimits()
    c = ToyotaSteerCheck(lim)
    assert c.check(0, True, 0.01, True) == ""
    assert "rate" in c.check(100, True, 0.02, True)  # +100 in one frame
    assert c.check(5, True, 0.03, True) == ""
    assert c.check(3, True, 0.04, False) != ""  # torque while not allowed
    assert accel_ok(2.5, True) != "" and accel_ok(-4.0, True) != ""
    assert accel_ok(0.5, False) != ""
    al = AngleLimits.from_params(PARAMS)
    a = AngleCheck(al, 0.01)
    assert a.check(0.0, 10.0) == ""
    assert "rate" in a.check(0.3, 10.0)
    assert "schedule" in a.check(al.angle_range_rad(20.0)[1] + 0.1, 20.0)
    assert pedals_ok(0.2, 0.2, al) == "throttle with brake"


def test_angle_schedule_follows_iso_11270():
    """At speed the lateral acceleration of the largest angle is 3 m/s^2 (ISO 11270)."""
    al = AngleLimits.from_params(PARAMS)
    for v in (8.0, 15.0, 25.0):
        for sw in al.angle_range_rad(v):  # both ends, the steering offset included (eq. 7)
            delta = PARAMS.steering.offset_rad + PARAMS.steering.scale * sw
            assert v * v * abs(math.tan(delta)) / al.wheelbase_m == pytest.approx(3.0, rel=1e-6)
    assert al.angle_range_rad(0.0) == (-al.lock_rad, al.lock_rad)
    assert al.rate_max_radps(30.0) < al.rate_max_radps(5.0) <= al.actuator_rate_max_radps


def _cut_stream(check, pattern, t0=0.0, dt=0.01, torque=100):
    """Feed ``pattern`` (a string of '1' = request bit set, '0' = cleared, torque kept) at
    100 Hz with a constant torque already reached; returns the reasons per frame."""
    out = []
    for k, bit in enumerate(pattern):
        out.append(check.check(torque, bit == "1", t0 + k * dt, True))
    return out


def test_steer_request_cut_follows_panda_tolerance():
    """panda's has_steer_req_tolerance for Toyota: one frame of torque without STEER_REQUEST is
    allowed after 18 frames with it, at most every 170 ms; anything else is refused."""
    lim = ToyotaLimits()
    warm = ToyotaSteerCheck(lim)
    # ramp to 100 units within the rate limit with the request set (7 frames of +15)
    ramp = [warm.check(min(15 * (k + 1), 100), True, 0.01 * k, True) for k in range(7)]
    assert ramp == [""] * 7
    # 18 frames with the request, then one cut frame: allowed
    r = _cut_stream(warm, "1" * 11 + "0", t0=0.07)
    assert r == [""] * 12
    # a second cut frame right after the first: refused (max_invalid_request_frames = 1)
    assert "too many frames" in warm.check(100, False, 0.19, True)
    # after a violation panda resets; torque without request on a fresh state is refused
    fresh = ToyotaSteerCheck(lim)
    assert "too few" in fresh.check(10, False, 0.0, True)
    # too few valid frames since the last cut: refused
    c = ToyotaSteerCheck(lim)
    assert _cut_stream(c, "1" * 18 + "0", torque=0) == [""] * 19  # torque 0: never a cut
    c = ToyotaSteerCheck(lim)
    seq = [c.check(min(15 * (k + 1), 60), True, 0.01 * k, True) for k in range(18)]
    assert seq == [""] * 18
    assert c.check(60, False, 0.18, True) == ""  # the first cut: allowed
    later = _cut_stream(c, "1" * 10 + "0", t0=0.19, torque=60)  # 10 frames later: refused
    assert later[:10] == [""] * 10 and "too few" in later[10]
    # 18 valid frames but within 170 ms of the last cut (frames at 5 ms): refused
    c = ToyotaSteerCheck(lim)
    assert [c.check(min(15 * (k + 1), 60), True, 0.005 * k, True) for k in range(18)] == [""] * 18
    assert c.check(60, False, 0.09, True) == ""
    r = _cut_stream(c, "1" * 18 + "0", t0=0.095, dt=0.005, torque=60)
    assert r[:18] == [""] * 18 and "too soon" in r[18]


def test_cutting_torque_to_zero_is_always_allowed_as_in_panda():
    """panda's rate and real-time checks bound the torque by max(last, 0) + delta and
    min(last, 0) - delta: a cut to 0 passes from any torque (a controller may always let go),
    while the same jump away from 0 is refused."""
    lim = ToyotaLimits()
    c = ToyotaSteerCheck(lim)
    t, tq = 0.0, 0
    while t < 0.7:  # ramp to 600, hold past a window
        c.eps_torque(tq / lim.eps_torque_factor)  # the EPS follows the command
        tq = min(tq + lim.max_rate_up, 600)
        t += lim.steer_period_s
        assert c.check(tq, True, t, True) == ""
    assert c.rt_last > lim.max_rt_delta  # the window's reference is high
    assert c.check(0, True, t + 0.01, True) == ""  # 600 -> 0 in one frame: allowed
    c2 = ToyotaSteerCheck(lim)
    assert c2.check(60, True, 0.01, True) != ""  # 0 -> 60 in one frame: refused
    lt = ToyotaTorqueLimiter(lim)  # the limiter agrees: it may cut to 0
    t = 0.0
    for _ in range(60):
        t += lim.steer_period_s
        out = lt.clip(600.0, t, -1e4, 1e4)
    assert out > lim.max_rt_delta and lt.clip(0.0, t + 0.01, -1e4, 1e4) == 0


def test_watchdog_stops_on_three_consecutive_late_steps_only():
    """The deadline rule the drive tests rely on (they run again once after a host stall):
    one or two late control steps are counted, three in a row stop the car; an on-time step
    resets the count."""
    from hmpc.controller.actuation.watchdog import Watchdog

    wd = Watchdog()
    assert [wd.deadline(x) for x in (True, True, False, True, True)] == [""] * 5
    assert wd.deadline(True) == "deadline_misses"
    wd2 = Watchdog()
    assert [wd2.deadline(True) for _ in range(3)] == ["", "", "deadline_misses"]
