"""Actuator and comfort limits, and the function that enforces them on every command.

The limits are frozen dataclasses with the unit in every name and the reason for every
default in a comment (docs/style.md 3). :func:`apply_limits` is applied after the optimiser,
again, independently of it: whatever a controller computes, the command that leaves the
controller step has its steering angle and rate clamped, pedals in [0, 1] and rate-limited,
and never throttle and brake together.

Two deceleration limits, by situation: in normal driving the brake is capped at the comfort
deceleration ``decel_max_mps2`` (3.5 m/s^2, ISO 15622); in a controlled stop (the
controller's fallback after a failure: a minimum-risk manoeuvre) at
``controlled_stop_decel_max_mps2`` (4.0 m/s^2, UN R157), see :class:`ActuatorLimits`.
``ActuatorLimits`` is not ``models.params.VehicleLimits``: that is the optional ``limits:``
section of a parameter file, which :meth:`ActuatorLimits.from_params` reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from hmpc.models.params import Params, Zone


@dataclass(frozen=True)
class Command:
    """One actuator command (what a controller step returns; it never sends it).

    Attributes:
        steering_wheel_angle_rad: commanded steering-wheel angle [rad], left positive.
        accel_pedal: accelerator pedal position [1], 0..1.
        brake_pedal: brake pedal position / normalised pressure [1], 0..1.
    """

    steering_wheel_angle_rad: float
    accel_pedal: float
    brake_pedal: float

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.steering_wheel_angle_rad, self.accel_pedal, self.brake_pedal)


@dataclass(frozen=True)
class ActuatorLimits:
    """Limits every command must respect (SI units, in the names).

    Defaults and their reasons:
    """

    # Steering-wheel range: the report (section II-B) gives about 5*pi lock to lock for most
    # four-wheel vehicles, i.e. +-2.5*pi = +-7.85 rad about centre.
    steering_wheel_angle_max_rad: float = 2.5 * math.pi
    # Steering-wheel rate: 360 deg/s, the order of what series electric power steering
    # actuators deliver under automation; with the report's scale 0.08 it is 0.5 rad/s at
    # the road wheel, enough for a full lane change in about 1 s.
    steering_wheel_rate_max_radps: float = 2.0 * math.pi
    # Acceleration: 2.0 m/s^2, the upper bound of ISO 15622 (adaptive cruise control) for
    # automated longitudinal control.
    accel_max_mps2: float = 2.0
    # Deceleration: 3.5 m/s^2, ISO 15622's bound for automated (non-emergency) braking.
    decel_max_mps2: float = 3.5
    # Deceleration in a controlled stop (the fallback after a failed solve or an internal
    # error, which brings the car to standstill): 4.0 m/s^2, the deceleration demand UN R157
    # (ALKS) para. 5.5.1 allows in its minimum risk manoeuvre. A stop after a failure must
    # not be held to the comfort figure above (ISO 15622 itself allows up to 5 m/s^2 at low
    # speed), but it is still not an emergency brake: the car behind must be able to follow.
    # The stop's own target (MpcConfig.stop_brake_decel_mps2, 2 m/s^2) is below both.
    controlled_stop_decel_max_mps2: float = 4.0
    # Jerk: 2.5 m/s^3, ISO 15622's bound on the average rate of change of deceleration.
    jerk_max_mps3: float = 2.5
    # Speed: 20 m/s, the top of the report's highest zone (section V); above it the zone
    # models are not identified.
    speed_max_mps: float = 20.0
    # Pedals: fractions of travel, physically 0..1 (docs/conventions.md).
    pedal_min: float = 0.0
    pedal_max: float = 1.0
    # Pedal rates (pressing only): full travel in 0.5 s. A backstop independent of the
    # optimiser (which limits jerk through the model): loose enough not to bind in normal
    # MPC operation, and still stops a bad command from slamming a pedal.
    accel_pedal_rate_max_ps: float = 2.0
    brake_pedal_rate_max_ps: float = 2.0
    # A pedal below this fraction counts as released (pedal position sensors resolve about
    # 0.5 % of travel; a smaller command is noise, not an intent).
    pedal_deadband: float = 1e-3

    def __post_init__(self):
        for name in (
            "steering_wheel_angle_max_rad",
            "steering_wheel_rate_max_radps",
            "accel_max_mps2",
            "decel_max_mps2",
            "controlled_stop_decel_max_mps2",
            "jerk_max_mps3",
            "speed_max_mps",
            "accel_pedal_rate_max_ps",
            "brake_pedal_rate_max_ps",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(
                    f"ActuatorLimits.{name} must be a positive finite number, got {v!r}"
                )
        if not 0.0 <= self.pedal_min < self.pedal_max <= 1.0:
            raise ValueError("ActuatorLimits: need 0 <= pedal_min < pedal_max <= 1")

    @classmethod
    def from_params(cls, params: Params | None) -> ActuatorLimits:
        """Defaults overridden by ``params.limits`` and the vehicle's steering range/rate.

        ``limits:`` keys win over the ``vehicle:`` keys of the same meaning.
        """
        if params is None:
            return cls()
        kw: dict[str, float] = {}
        v = params.vehicle
        if v.steering_wheel_angle_max_rad is not None:
            kw["steering_wheel_angle_max_rad"] = v.steering_wheel_angle_max_rad
        if v.steering_wheel_rate_max_radps is not None:
            kw["steering_wheel_rate_max_radps"] = v.steering_wheel_rate_max_radps
        lim = params.limits
        if lim is not None:
            for name in (
                "steering_wheel_angle_max_rad",
                "steering_wheel_rate_max_radps",
                "accel_max_mps2",
                "decel_max_mps2",
                "jerk_max_mps3",
                "speed_max_mps",
            ):
                val = getattr(lim, name)
                if val is not None:
                    kw[name] = val
        return cls(**kw)


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def apply_limits(
    command: Command,
    prev: Command | None,
    limits: ActuatorLimits,
    dt_s: float,
    zone: Zone | None = None,
    *,
    controlled_stop: bool = False,
) -> Command:
    """Return ``command`` made safe: the last line of defence, independent of any optimiser.

    In order:
      1. non-finite values -> steering held at ``prev`` (or 0), pedals released, brake
         applied at its rate limit (a NaN must never reach an actuator);
      2. pedals clamped to [pedal_min, pedal_max]; pressing (not releasing) a pedal is
         rate-limited from ``prev``;
      3. with ``zone`` (the zone model eq. 8 in force), the throttle is capped so the model
         acceleration stays <= accel_max and the brake so it stays >= -decel_max (in a
         ``controlled_stop``: >= -controlled_stop_decel_max);
      4. steering-wheel angle clamped to +-max and its change from ``prev`` to rate*dt;
      5. never throttle and brake together: if both are still pressed, the brake wins and
         the throttle is released (pedals below ``pedal_deadband`` count as released).

    Args:
        command: the controller's command.
        prev: the command applied one period before (None at start: no rate limits).
        limits: the limits.
        dt_s: time since ``prev`` [s] (> 0).
        zone: optional zone model for the acceleration caps.
        controlled_stop: the command is a controlled stop (a failure's fallback): the brake
            cap is ``limits.controlled_stop_decel_max_mps2`` instead of the comfort
            ``limits.decel_max_mps2``.
    """
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise ValueError(f"dt_s must be positive and finite, got {dt_s!r}")
    sw, ap, bp = (float(x) for x in command.as_tuple())
    if not (math.isfinite(sw) and math.isfinite(ap) and math.isfinite(bp)):
        sw = prev.steering_wheel_angle_rad if prev is not None else 0.0
        ap = 0.0
        bp = (prev.brake_pedal if prev is not None else 0.0) + limits.brake_pedal_rate_max_ps * dt_s
    ap = _clamp(ap, limits.pedal_min, limits.pedal_max)
    bp = _clamp(bp, limits.pedal_min, limits.pedal_max)
    if zone is not None:
        if zone.scale_mps2 > 0:
            ap = min(ap, max((limits.accel_max_mps2 - zone.offset_mps2) / zone.scale_mps2, 0.0))
        if zone.brake_scale_mps2 > 0:
            decel = limits.decel_max_mps2
            if controlled_stop:  # never below the comfort limit (a file may raise that)
                decel = max(decel, limits.controlled_stop_decel_max_mps2)
            bp = min(bp, max((zone.offset_mps2 + decel) / zone.brake_scale_mps2, 0.0))
    if prev is not None:  # rate limits on pressing only: releasing a pedal is always safe
        ap = min(ap, prev.accel_pedal + limits.accel_pedal_rate_max_ps * dt_s)
        bp = min(bp, prev.brake_pedal + limits.brake_pedal_rate_max_ps * dt_s)
        dsw = limits.steering_wheel_rate_max_radps * dt_s
        sw = _clamp(sw, prev.steering_wheel_angle_rad - dsw, prev.steering_wheel_angle_rad + dsw)
    if ap > limits.pedal_deadband and bp > limits.pedal_deadband:
        ap = 0.0  # the brake wins: releasing the throttle is always safe
    if ap <= limits.pedal_deadband:
        ap = 0.0
    if bp <= limits.pedal_deadband:
        bp = 0.0
    ap = _clamp(ap, 0.0, limits.pedal_max)
    bp = _clamp(bp, 0.0, limits.pedal_max)
    sw = _clamp(sw, -limits.steering_wheel_angle_max_rad, limits.steering_wheel_angle_max_rad)
    return Command(sw, ap, bp)


def with_limits(limits: ActuatorLimits, **changes) -> ActuatorLimits:
    """A copy of ``limits`` with some fields changed (validated again)."""
    return replace(limits, **changes)
