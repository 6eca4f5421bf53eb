"""Safety limits of the actuation profiles, applied twice, independently (docs/style.md 3).

1. After the controller, a **limiter** makes each command comply (``ToyotaTorqueLimiter``,
   ``clip_accel``, ``AngleLimiter``, ``clip_pedals``): it computes the largest allowed step.
2. At the encoder, a **check** tests the value about to be encoded (``ToyotaSteerCheck``,
   ``accel_ok``, ``AngleCheck``, ``pedals_ok``): written the way the panda firmware tests a
   frame, with its own state. A command that fails is not encoded; the drive loop sends the
   safe substitute instead (torque 0 without request, the acceleration clamped, the angle
   held, pedals released with the brake kept) and counts it.

Numbers carry their reason and source beside them. Toyota: the panda firmware's Toyota safety
mode (commaai/panda ``board/safety/safety_toyota.h``, 2022-2023, and opendbc
``opendbc/safety/modes/toyota.h``: ``TOYOTA_STEERING_LIMITS`` / ``TOYOTA_LONG_LIMITS``).
By-wire angle profile: ISO 11270:2014 (lane keeping assistance systems), lateral acceleration
and lateral jerk bounds, turned into a steering-wheel angle and rate per speed through the
bicycle model (eq. 1) and the steering map (eq. 7) of the vehicle's parameter file.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from hmpc.models.params import Params


# =============================================================================== Toyota
@dataclass(frozen=True)
class ToyotaLimits:
    """The panda Toyota safety mode's checks, in the units the frames carry."""

    # TOYOTA_STEERING_LIMITS.max_torque = 1500: "max torque cmd allowed ever" (raw
    # STEERING_LKA.STEER_TORQUE_CMD units).
    max_torque: int = 1500
    # .max_rate_up = 15 per 100 Hz frame ("ramp up slow"): 1500 units/s.
    max_rate_up: int = 15
    # .max_rate_down = 25 per frame ("ramp down fast").
    max_rate_down: int = 25
    # .max_torque_error = 350: "max torque cmd in excess of motor torque" (TorqueMotorLimited:
    # the command may exceed the EPS's measured torque by at most this).
    max_torque_error: int = 350
    # .max_rt_delta = 450 over .max_rt_interval = 250000 us: "the real time limit is
    # 1800/sec, a 20% buffer" over the 1500/s rate limit.
    max_rt_delta: int = 450
    rt_interval_s: float = 0.25
    # panda keeps the last 3 EPS torque samples (sample_t values[3]) and widens min/max by
    # one unit "to be conservative on rounding".
    eps_samples: int = 3
    # opendbc EPS_SCALE for the RAV4 (toyota/values.py, 73): panda multiplies
    # STEER_TORQUE_EPS by eps_factor/100 to get command units.
    eps_torque_factor: float = 0.73
    # TOYOTA_LONG_LIMITS: max_accel 2000 (2.0 m/s^2), min_accel -3500 (-3.5 m/s^2); also
    # ISO 15622's bounds for adaptive cruise control.
    accel_max_mps2: float = 2.0
    accel_min_mps2: float = -3.5
    # panda's inactive_accel for Toyota: 0 while controls are not allowed.
    accel_inactive_mps2: float = 0.0
    # STEERING_LKA is sent at 100 Hz (the rate limits are per frame).
    steer_period_s: float = 0.01
    # STEER_REQUEST tolerance (.has_steer_req_tolerance = true): "the EPS faults when the
    # steering angle rate is above a certain threshold for too long", so openpilot may clear
    # the request bit while keeping the torque for .max_invalid_request_frames = 1 frame,
    # after at least .min_valid_request_frames = 18 frames with the bit set, and no sooner
    # than .min_valid_request_rt_interval = 170000 us ("a ~10% buffer on cutting every 19
    # frames") after the last cut. Any other torque without the request bit is a violation.
    min_valid_request_frames: int = 18
    max_invalid_request_frames: int = 1
    min_valid_request_interval_s: float = 0.170


class ToyotaTorqueLimiter:
    """After the controller: the largest torque step the panda checks allow.

    State: the last torque sent, and the torque at the start of the current 250 ms
    real-time window. ``clip`` returns an integer torque inside every bound, one unit inside
    the real-time and error bounds so that the check at the encoder never trips on rounding.
    """

    def __init__(self, limits: ToyotaLimits = ToyotaLimits()):
        self.limits = limits
        self.reset(0.0)

    def reset(self, t_s: float) -> None:
        self.last = 0
        self.rt_ref = 0
        self.rt_t0_s = t_s

    def clip(
        self, desired: float, t_s: float, eps_min: float, eps_max: float, active: bool = True
    ) -> int:
        """Args: desired torque [raw units]; t_s now [s]; eps_min/eps_max: min/max of the recent
        measured EPS torque [command units]; active: controls allowed (else 0)."""
        lim = self.limits
        if not active or not math.isfinite(desired):
            self.reset(t_s)
            return 0
        last = self.last
        hi: float = max(last, 0) + lim.max_rate_up
        lo: float = min(last, 0) - lim.max_rate_up
        hi = min(hi, max(last - lim.max_rate_down, max(eps_max, 0) + lim.max_torque_error - 2))
        lo = max(lo, min(last + lim.max_rate_down, min(eps_min, 0) - lim.max_torque_error + 2))
        # panda's rt_rate_limit_check: within max_rt_delta of the window's reference, but
        # always allowed towards 0 (the bounds are taken from max(ref, 0) and min(ref, 0))
        hi = min(hi, max(self.rt_ref, 0) + lim.max_rt_delta - 1, lim.max_torque)
        lo = max(lo, min(self.rt_ref, 0) - lim.max_rt_delta + 1, -lim.max_torque)
        if lo <= hi:
            out = int(min(max(round(desired), math.ceil(lo)), math.floor(hi)))
        else:  # no room (cannot happen from a state this limiter made): step towards 0
            out = int(
                max(last - lim.max_rate_down, 0) if last > 0 else min(last + lim.max_rate_down, 0)
            )
        if t_s - self.rt_t0_s >= lim.rt_interval_s:  # panda's window: checked, then moved
            self.rt_ref, self.rt_t0_s = out, t_s
        self.last = out
        return out


class ToyotaSteerCheck:
    """At the encoder: panda's ``steer_torque_cmd_checks`` for TorqueMotorLimited, with its
    own state (desired_torque_last, rt_torque_last, ts_last, the EPS torque samples).

    ``check`` returns ("" if allowed, else the reason) and updates the state as panda does:
    after a violation, or while controls are not allowed, the last torque and the real-time
    reference fall back to 0.
    """

    def __init__(self, limits: ToyotaLimits = ToyotaLimits()):
        self.limits = limits
        self.meas: deque = deque([0.0] * limits.eps_samples, maxlen=limits.eps_samples)
        self.desired_last = 0
        self.rt_last = 0
        self.ts_last_s = 0.0
        self.valid_req = 0  # consecutive frames with the request bit matching
        self.invalid_req = 0  # consecutive frames of torque without the request bit
        self.req_cut_last_s = -math.inf  # time of the last cut (or reset) [s]

    def eps_torque(self, eps_raw: float) -> None:
        """A new STEER_TORQUE_EPS sample (raw DBC units)."""
        self.meas.append(eps_raw * self.limits.eps_torque_factor)

    def check(self, torque: int, request: bool, t_s: float, allowed: bool) -> str:
        lim = self.limits
        reason = ""
        if torque != int(torque):
            reason = "torque not an integer"
        elif not allowed:
            if torque != 0 or request:
                reason = "torque while controls are not allowed"
        else:
            if abs(torque) > lim.max_torque:
                reason = "max torque"
            mmin = min(self.meas) - 1
            mmax = max(self.meas) + 1
            last = self.desired_last
            hi = max(last, 0) + lim.max_rate_up
            lo = min(last, 0) - lim.max_rate_up
            hi = min(hi, max(last - lim.max_rate_down, max(mmax, 0) + lim.max_torque_error))
            lo = max(lo, min(last + lim.max_rate_down, min(mmin, 0) - lim.max_torque_error))
            if not reason and not lo <= torque <= hi:
                reason = "torque rate / error vs EPS torque"
            if not reason and not (
                min(self.rt_last, 0) - lim.max_rt_delta
                <= torque
                <= max(self.rt_last, 0) + lim.max_rt_delta
            ):
                reason = "real-time delta over 250 ms"  # panda: rt_rate_limit_check
            if not reason and t_s - self.ts_last_s >= lim.rt_interval_s:
                self.rt_last, self.ts_last_s = torque, t_s
        req_reason = self._request_bit(torque, request, t_s)
        reason = reason or req_reason
        if reason or not allowed:
            self.desired_last = 0
            self.rt_last = 0
            self.ts_last_s = t_s
            self.valid_req = self.invalid_req = 0
            self.req_cut_last_s = t_s
        else:
            self.desired_last = int(torque)
        return reason

    def _request_bit(self, torque: int, request: bool, t_s: float) -> str:
        """panda's steer-request tolerance: torque with the request bit cleared is allowed for
        ``max_invalid_request_frames`` frames, only after ``min_valid_request_frames`` frames
        with the bit set and ``min_valid_request_interval_s`` after the previous cut."""
        lim = self.limits
        if request or torque == 0:
            self.valid_req = min(self.valid_req + 1, lim.min_valid_request_frames)
            self.invalid_req = 0
            return ""
        reason = ""
        if self.invalid_req == 0:
            if self.valid_req < lim.min_valid_request_frames:
                reason = "torque without STEER_REQUEST after too few request frames"
            elif t_s - self.req_cut_last_s < lim.min_valid_request_interval_s:
                reason = "torque without STEER_REQUEST too soon after the last cut"
        elif self.invalid_req >= lim.max_invalid_request_frames:
            reason = "torque without STEER_REQUEST for too many frames"
        self.valid_req = 0
        self.req_cut_last_s = t_s
        self.invalid_req = min(self.invalid_req + 1, lim.max_invalid_request_frames)
        return reason


def clip_accel(
    accel_mps2: float, limits: ToyotaLimits = ToyotaLimits(), active: bool = True
) -> float:
    """After the controller: the acceleration request inside the panda bounds; 0 when not
    active; a NaN becomes -1 m/s^2 (a controlled stop's request, not a jump to full braking)."""
    if not active:
        return limits.accel_inactive_mps2
    if not math.isfinite(accel_mps2):
        return -1.0
    # 1 mm/s^2 inside, so the 0.001 m/s^2 encoding cannot round past a bound
    return min(max(float(accel_mps2), limits.accel_min_mps2 + 0.001), limits.accel_max_mps2 - 0.001)


def accel_ok(accel_mps2: float, allowed: bool, limits: ToyotaLimits = ToyotaLimits()) -> str:
    """At the encoder: panda's ``longitudinal_accel_checks`` ("" if allowed, else the reason)."""
    if not math.isfinite(accel_mps2):
        return "acceleration not finite"
    if not allowed:
        return "" if accel_mps2 == limits.accel_inactive_mps2 else "acceleration while not allowed"
    if not limits.accel_min_mps2 <= accel_mps2 <= limits.accel_max_mps2:
        return "acceleration out of bounds"
    return ""


# ======================================================================== by-wire, angle
@dataclass(frozen=True)
class AngleLimits:
    """Steering-wheel angle and rate scheduled by speed, and pedal limits, for a by-wire kit.

    ``angle_max_rad(v)`` and ``rate_max_radps(v)`` follow from ISO 11270's bounds through
    the kinematic bicycle model: a_y = v^2 tan(delta) / L, so delta_max(v) = atan(a_y,max L / v^2)
    and d(delta)/dt max = j_y,max L / v^2; the steering map (eq. 7) turns road-wheel into
    steering-wheel angle (delta = offset + scale * sw).
    """

    wheelbase_m: float
    steer_offset_rad: float
    steer_scale: float
    # ISO 11270:2014 (LKAS) 5.3: lateral acceleration from the system at most 3 m/s^2.
    lateral_accel_max_mps2: float = 3.0
    # ISO 11270:2014: lateral jerk at most 5 m/s^3 (moving average over half a second).
    lateral_jerk_max_mps3: float = 5.0
    # Lock to lock of the report's car (section II-B, about 5 pi): +-2.5 pi about centre.
    lock_rad: float = 2.5 * math.pi
    # The actuator's own rate: 360 deg/s at the steering wheel, what series EPS motors deliver
    # under automation (the same number as controller/limits.py's default).
    actuator_rate_max_radps: float = 2.0 * math.pi
    # Below this speed the ISO bounds (which grow as 1/v^2) are evaluated at this speed: the
    # lock and the actuator rate bind there anyway.
    v_floor_mps: float = 1.0
    # Pedals: fractions of travel (docs/conventions.md); pressing rate full travel in 0.5 s
    # (controller/limits.py's backstop); releasing is always allowed.
    pedal_rate_max_ps: float = 2.0
    # a pedal below this counts as released (0.5 % sensor resolution order)
    pedal_deadband: float = 1e-3

    @classmethod
    def from_params(cls, params: Params, **kw) -> AngleLimits:
        lock = params.vehicle.steering_wheel_angle_max_rad
        if lock is not None:
            kw.setdefault("lock_rad", float(lock))
        assert params.steering is not None
        return cls(
            float(params.vehicle.wheelbase_m),
            float(params.steering.offset_rad),
            float(params.steering.scale),
            **kw,
        )

    def angle_range_rad(self, v_mps: float) -> tuple[float, float]:
        """Allowed steering-wheel angles at speed v [rad]: those whose road-wheel angle (eq. 7,
        offset included) stays within +-delta_max(v), within the lock."""
        v = max(abs(float(v_mps)), self.v_floor_mps)
        delta = math.atan(self.lateral_accel_max_mps2 * self.wheelbase_m / (v * v))
        a = (-delta - self.steer_offset_rad) / self.steer_scale
        b = (delta - self.steer_offset_rad) / self.steer_scale
        lo, hi = min(a, b), max(a, b)
        return max(lo, -self.lock_rad), min(hi, self.lock_rad)

    def angle_max_rad(self, v_mps: float) -> float:
        """Largest |steering-wheel angle| allowed on both sides at speed v [rad]."""
        lo, hi = self.angle_range_rad(v_mps)
        return max(min(-lo, hi), 0.0)

    def rate_max_radps(self, v_mps: float) -> float:
        """Largest steering-wheel rate at speed v [rad/s]."""
        v = max(abs(float(v_mps)), self.v_floor_mps)
        rate = self.lateral_jerk_max_mps3 * self.wheelbase_m / (v * v) / abs(self.steer_scale)
        return min(rate, self.actuator_rate_max_radps)


def _outside(x: float, lo: float, hi: float) -> float:
    """How far x lies outside [lo, hi] (0 inside)."""
    return lo - x if x < lo else x - hi if x > hi else 0.0


class AngleLimiter:
    """After the controller: the steering-wheel angle clamped to the schedule and its step to
    the scheduled rate (state: the last angle sent). When the speed rises faster than the
    angle may move, the schedule wins: an angle the new speed puts outside it is brought back
    at once (the lateral-acceleration bound before the rate; the check allows the same)."""

    def __init__(self, limits: AngleLimits):
        self.limits = limits
        self.last: float | None = None

    def clip(self, angle_rad: float, v_mps: float, dt_s: float) -> float:
        lim = self.limits
        if not math.isfinite(angle_rad):
            angle_rad = 0.0 if self.last is None else self.last
        lo, hi = lim.angle_range_rad(v_mps)
        out = min(max(angle_rad, lo + 1e-4), hi - 1e-4)
        if self.last is not None:
            step = lim.rate_max_radps(v_mps) * dt_s * (1 - 1e-3) + _outside(self.last, lo, hi)
            out = min(max(out, self.last - step), self.last + step)
        self.last = out
        return out


class AngleCheck:
    """At the encoder: the angle sent within the speed schedule, and its change from the last
    frame within the scheduled rate times the message's nominal period (a per-frame check like
    panda's, so send jitter cannot make a legal stream illegal). "" if allowed, else the
    reason; 1 mrad tolerance (the kit's resolution)."""

    def __init__(self, limits: AngleLimits, period_s: float):
        self.limits = limits
        self.period_s = float(period_s)
        self.last: float | None = None

    def check(self, angle_rad: float, v_mps: float) -> str:
        lim = self.limits
        reason = ""
        lo, hi = lim.angle_range_rad(v_mps)
        if not math.isfinite(angle_rad):
            reason = "angle not finite"
        elif not lo - 1e-3 <= angle_rad <= hi + 1e-3:
            reason = "steering-wheel angle over the speed schedule"
        elif self.last is not None:
            back = _outside(self.last, lo, hi)
            if abs(angle_rad - self.last) > lim.rate_max_radps(v_mps) * self.period_s + back + 1e-3:
                reason = "steering-wheel rate over the speed schedule"
        if not reason:
            self.last = float(angle_rad)
        return reason


def clip_pedals(
    accel_pedal: float,
    brake_pedal: float,
    prev: tuple[float, float] | None,
    dt_s: float,
    limits: AngleLimits,
) -> tuple[float, float]:
    """After the controller: pedals in [0, 1], pressing rate-limited, never both (the brake
    wins), below the deadband released. A NaN releases the throttle and keeps the brake."""
    ap, bp = float(accel_pedal), float(brake_pedal)
    if not math.isfinite(ap):
        ap = 0.0
    if not math.isfinite(bp):
        bp = prev[1] if prev is not None else 0.0
    ap = min(max(ap, 0.0), 1.0)
    bp = min(max(bp, 0.0), 1.0)
    if prev is not None:
        step = limits.pedal_rate_max_ps * dt_s
        ap = min(ap, prev[0] + step)
        bp = min(bp, prev[1] + step)
    if bp > limits.pedal_deadband:
        ap = 0.0
    if ap <= limits.pedal_deadband:
        ap = 0.0
    if bp <= limits.pedal_deadband:
        bp = 0.0
    return ap, bp


def pedals_ok(accel_pedal: float, brake_pedal: float, limits: AngleLimits) -> str:
    """At the encoder: pedals finite, in [0, 1], never throttle with brake."""
    if not (math.isfinite(accel_pedal) and math.isfinite(brake_pedal)):
        return "pedal not finite"
    if not (0.0 <= accel_pedal <= 1.0 and 0.0 <= brake_pedal <= 1.0):
        return "pedal out of [0, 1]"
    if accel_pedal > limits.pedal_deadband and brake_pedal > limits.pedal_deadband:
        return "throttle with brake"
    return ""
