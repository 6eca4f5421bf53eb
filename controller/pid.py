"""A baseline: PID speed control on one signed pedal + pure-pursuit steering.

The speed PID's output u [1] is split by sign: u > 0 presses the throttle, u < 0 the
brake. There is no mode logic and no hysteresis, on purpose: it is the controller the
report's section II-D warns about (throttle-brake chatter near idle speed), shown beside
the MPC on the same scenarios. It implements the controller contract
(:class:`controller.base.Controller`); it ignores stop commands and obstacles.

It is the PID a controls engineer would write against a noisy state estimate,
not a tuned optimiser: the measured speed is low-pass filtered; the proportional term
acts on a weighted setpoint (b r - y) and the derivative on the filtered measurement only,
never on the error (both available; the defaults, b = 1 and no D, are what measured best
on the scenarios, see :class:`PidConfig`); the integral is clamped and frozen while the
output is held back by its rate limit (anti-windup); the signed pedal output and the
steering-wheel output are rate-limited, and pure pursuit's steering target is low-pass
filtered. These cut the chatter an estimate's noise excites; the sign split stays naive,
so the pedals still switch near idle where the MPC's mode logic does not.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import steering_wheel_angle_for
from hmpc.models.reference import Reference

from hmpc.controller.base import ControlResult, Status, internal_error
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.modes import PedalMode


@dataclass(frozen=True)
class PidConfig:
    """Gains and filters (a hand tuning that tracks the ramps; not an optimised baseline).
    Time constants and rates are SI; 0 disables a filter, ``inf`` a rate limit."""

    kp_per_mps: float = 0.6  # pedal per m/s of speed error
    ki_per_m: float = 0.3  # pedal per m of integrated speed error
    # derivative on the filtered measured speed (pedal per m/s^2 of acceleration), never
    # on the error (no kick on a reference step). Off: the plant is first order, and 0.05
    # raised idle_hold's brake rate RMS 0.09 -> 0.14 /s through the estimator
    kd_per_mps2: float = 0.0
    # setpoint weight of the proportional term: P = kp (b v_ref - v) (Astrom & Hagglund);
    # b < 1 softens the answer to reference steps, but the scenarios' references are ramps,
    # which it lags: 0.8 raised ramp_sequence's speed RMS 0.21 -> 0.42 m/s. Hence 1
    setpoint_weight: float = 1.0
    # speed measurement low-pass [s]: the estimator's speed wanders by its 0.05 m/s wheel-speed
    # noise; 0.3 s is 3 control periods, well under the 1-2 s of the speed ramps
    speed_filter_tau_s: float = 0.3
    integral_max: float = 2.0  # anti-windup clamp on the integral [m]
    # signed pedal output rate [full travel / s]: full travel in 2 s, 4x slower than the
    # actuation backstop (ActuatorLimits, 0.5 s); at the largest zone scale (about 3.5 m/s^2
    # per pedal) still 1.75 m/s^3, under the 2.5 m/s^3 jerk limit
    pedal_rate_max_ps: float = 0.5
    # pure pursuit look-ahead = max(min, time * v). Its gain on a lateral offset falls as
    # 1 / look-ahead^2: 4 m rather than 3 cut idle_hold's reversals >= 1 deg 28 -> 18 /min
    # with the filter below, lateral RMS unchanged on arcs and figure8 (measured)
    lookahead_min_m: float = 4.0
    lookahead_time_s: float = 1.0
    # pure pursuit's road-wheel angle target low-pass [s]: a 1 cm error in the estimated
    # position turns the look-ahead angle by ~2.5e-3 rad, about 4 deg of steering wheel at
    # the report's scale 0.08; 0.5 s is 5 control periods, under the ~1 s of a path's turn-in
    steer_filter_tau_s: float = 0.5
    # steering-wheel rate of the output [rad/s]: 2/3 of the actuator's 2 pi. Lower binds on
    # figure8 (1.5 rad/s raised its lateral RMS 0.38 -> 1.99 m)
    steering_rate_max_radps: float = 4.0

    def __post_init__(self):
        for name in (
            "kp_per_mps",
            "ki_per_m",
            "kd_per_mps2",
            "speed_filter_tau_s",
            "steer_filter_tau_s",
            "integral_max",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"PidConfig.{name} must be >= 0")
        if not 0.0 <= self.setpoint_weight <= 1.0:
            raise ValueError("PidConfig.setpoint_weight must be in [0, 1]")
        for name in ("pedal_rate_max_ps", "steering_rate_max_radps", "lookahead_min_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"PidConfig.{name} must be positive")


def _lowpass(prev: float | None, x: float, tau_s: float, dt_s: float) -> float:
    """One step of a first-order low-pass (exact for a held input); ``prev`` None: x."""
    if prev is None or tau_s <= 0:
        return x
    return prev + (1.0 - math.exp(-dt_s / tau_s)) * (x - prev)


def _toward(prev: float | None, x: float, step: float) -> float:
    """``x`` moved at most ``step`` from ``prev`` (None: no limit)."""
    return x if prev is None else min(max(x, prev - step), prev + step)


class PidController:
    """PID + pure pursuit with filtered inputs and rate-limited outputs. ``step`` never
    raises and never returns None."""

    name = "pid"

    def __init__(
        self, params: Params, config: PidConfig | None = None, limits: ActuatorLimits | None = None
    ):
        if not params.is_model:
            raise ValueError("PidController needs a complete model (steering and zones)")
        self.params = params
        self.config = config or PidConfig()
        self.limits = limits or ActuatorLimits.from_params(params)
        self.wheelbase_m = params.vehicle.wheelbase_m
        self.reset()

    def use_model(self, model) -> None:
        """New model values (``controller.adapt.LearnedModel``): the PID uses only eq. 7's
        offset and scale, for its steering feed-forward."""
        assert self.params.steering is not None
        self.params = replace(
            self.params,
            steering=replace(
                self.params.steering, offset_rad=float(model.offset_rad), scale=float(model.scale)
            ),
        )

    def reset(self) -> None:
        self._i = 0.0
        self._v_f: float | None = None  # filtered speed [m/s]
        self._t_prev: float | None = None
        self._u: float | None = None  # signed pedal output [1]
        self._delta_f: float | None = None  # filtered road-wheel angle target [rad]
        self._last: Command | None = None
        self._s: float | None = None

    def step(
        self,
        state,
        reference: Reference,
        t_s: float,
        *,
        stop: bool = False,
        obstacle_distance_m: float | None = None,
    ) -> ControlResult:
        """One step (the contract of :class:`controller.base.Controller`; ``stop`` and
        ``obstacle_distance_m`` are ignored: a naive baseline). Never raises."""
        t_wall = time.perf_counter()
        try:
            x = np.asarray(state, dtype=float).reshape(-1)
            if x.shape != (4,) or not np.all(np.isfinite(x)):
                res = ControlResult(self._stop(), Status.CONTROLLED_STOP, "invalid state")
            else:
                res = self._step(x, reference, float(t_s))
        except Exception as exc:  # never raise into the loop: a bug, recorded as one
            res = internal_error(ControlResult(self._stop(), Status.CONTROLLED_STOP), exc)
        res.step_time_s = time.perf_counter() - t_wall
        return res

    def _stop(self) -> Command:
        """Stop command: throttle released, brake 0.3 (rate-limited), steering held."""
        prev = self._last or Command(0.0, 0.0, 0.0)
        cmd = apply_limits(Command(prev.steering_wheel_angle_rad, 0.0, 0.3), prev, self.limits, 0.1)
        self._last = cmd
        self._u = -cmd.brake_pedal
        return cmd

    def _speed_pid(self, v: float, v_ref: float, dt: float) -> float:
        """Signed pedal [1] from the speed [m/s]: PI on the setpoint-weighted error, D on
        the filtered measurement, the output rate-limited, the integral frozen while that
        limit holds the output back in the direction the error pushes."""
        c = self.config
        v_prev = self._v_f
        v_f = self._v_f = _lowpass(v_prev, v, c.speed_filter_tau_s, dt)
        dv = 0.0 if v_prev is None else (v_f - v_prev) / dt
        e = v_ref - v_f
        i_new = float(np.clip(self._i + e * dt, -c.integral_max, c.integral_max))
        want = (
            c.kp_per_mps * (c.setpoint_weight * v_ref - v_f)
            + c.ki_per_m * i_new
            - c.kd_per_mps2 * dv
        )
        u = float(np.clip(_toward(self._u, want, c.pedal_rate_max_ps * dt), -1.0, 1.0))
        if abs(u - want) < 1e-12 or (want - u) * e < 0:  # not held back towards the error
            self._i = i_new
        self._u = u
        return u

    def _pure_pursuit(self, x: np.ndarray, ref: Reference, t: float) -> float:
        """Road-wheel angle [rad] that steers the rear axle towards the point
        ``lookahead`` ahead on the path."""
        c, b, v = self.config, self.wheelbase_m, float(x[3])
        hint = float(ref.s_at_time(t)) if self._s is None else self._s
        s0, _ = ref.project(float(x[0]), float(x[1]), hint, 30.0 if self._s is None else 5.0 + v)
        self._s = s0
        ld = max(c.lookahead_min_m, c.lookahead_time_s * v)
        gx, gy, _, _ = ref.point_at(np.array([s0 + ld]))
        rx, ry = x[0] - b * math.cos(x[2]), x[1] - b * math.sin(x[2])
        alpha = math.atan2(float(gy[0]) - ry, float(gx[0]) - rx) - x[2]
        dist = math.hypot(float(gx[0]) - rx, float(gy[0]) - ry)
        return math.atan2(2 * b * math.sin(alpha), max(dist, 1e-3))

    def _step(self, x: np.ndarray, ref: Reference, t: float) -> ControlResult:
        c = self.config
        dt = 0.1 if self._t_prev is None else max(t - self._t_prev, 1e-3)
        u = self._speed_pid(float(x[3]), float(ref.speed_at(t)), dt)
        ap, bp = (u, 0.0) if u > 0 else (0.0, -u)
        delta = self._pure_pursuit(x, ref, t)
        self._delta_f = _lowpass(self._delta_f, delta, c.steer_filter_tau_s, dt)
        p = self.params.steering
        assert p is not None
        sw = steering_wheel_angle_for(self._delta_f, p.offset_rad, p.scale)
        prev_sw = None if self._last is None else self._last.steering_wheel_angle_rad
        sw = _toward(prev_sw, sw, c.steering_rate_max_radps * dt)
        cmd = apply_limits(Command(sw, ap, bp), self._last, self.limits, dt)
        self._last, self._t_prev = cmd, t
        mode = PedalMode.THROTTLE if cmd.accel_pedal > 0 else PedalMode.BRAKE
        return ControlResult(cmd, Status.OK, pedal_mode=int(mode))
