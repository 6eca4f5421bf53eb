"""A naive baseline: PID speed control on one signed pedal + pure-pursuit steering.

The speed PID's output u [1] is split by sign: u > 0 presses the throttle, u < 0 the
brake. There is no mode logic and no hysteresis, on purpose: it is the controller the
report's section II-D warns about (throttle-brake chatter near idle speed), shown beside
the MPC on the same scenarios. It implements the controller contract
(:class:`controller.base.Controller`); it ignores stop commands and obstacles.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import steering_wheel_angle_for
from hmpc.models.sim.scenarios import Reference

from hmpc.controller.base import ControlResult, Status, internal_error
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.modes import PedalMode


@dataclass(frozen=True)
class PidConfig:
    """Gains (a hand tuning that tracks the ramps; not an optimised baseline)."""

    kp_per_mps: float = 0.6        # pedal per m/s of speed error
    ki_per_m: float = 0.3          # pedal per m of integrated speed error
    kd_per_mps2: float = 0.0
    integral_max: float = 2.0      # anti-windup clamp on the integral [m]
    lookahead_min_m: float = 3.0   # pure pursuit look-ahead = max(min, time * v)
    lookahead_time_s: float = 1.0


class PidController:
    """Naive PID + pure pursuit. ``step`` never raises and never returns None."""

    name = "pid"

    def __init__(self, params: Params, config: PidConfig | None = None,
                 limits: ActuatorLimits | None = None):
        if not params.is_model:
            raise ValueError("PidController needs a complete model (steering and zones)")
        self.params = params
        self.config = config or PidConfig()
        self.limits = limits or ActuatorLimits.from_params(params)
        self.wheelbase_m = params.vehicle.wheelbase_m
        self.reset()

    def reset(self) -> None:
        self._i = 0.0
        self._e_prev: float | None = None
        self._t_prev: float | None = None
        self._last: Command | None = None
        self._s: float | None = None

    def step(self, state, reference: Reference, t_s: float, *, stop: bool = False,
             obstacle_distance_m: float | None = None) -> ControlResult:
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
        cmd = apply_limits(Command(prev.steering_wheel_angle_rad, 0.0, 0.3), prev,
                           self.limits, 0.1)
        self._last = cmd
        return cmd

    def _step(self, x: np.ndarray, ref: Reference, t: float) -> ControlResult:
        c = self.config
        dt = 0.1 if self._t_prev is None else max(t - self._t_prev, 1e-3)
        v = float(x[3])
        e = float(ref.speed_at(t)) - v
        self._i = float(np.clip(self._i + e * dt, -c.integral_max, c.integral_max))
        de = 0.0 if self._e_prev is None else (e - self._e_prev) / dt
        u = c.kp_per_mps * e + c.ki_per_m * self._i + c.kd_per_mps2 * de
        ap, bp = (u, 0.0) if u > 0 else (0.0, -u)
        # pure pursuit from the rear axle towards a point ``lookahead`` ahead on the path
        b = self.wheelbase_m
        hint = float(ref.s_at_time(t)) if self._s is None else self._s
        s0, _ = ref.project(float(x[0]), float(x[1]), hint, 30.0 if self._s is None else 5.0 + v)
        self._s = s0
        ld = max(c.lookahead_min_m, c.lookahead_time_s * v)
        gx, gy, _, _ = ref.point_at(np.array([s0 + ld]))
        rx, ry = x[0] - b * math.cos(x[2]), x[1] - b * math.sin(x[2])
        alpha = math.atan2(float(gy[0]) - ry, float(gx[0]) - rx) - x[2]
        dist = math.hypot(float(gx[0]) - rx, float(gy[0]) - ry)
        delta = math.atan2(2 * b * math.sin(alpha), max(dist, 1e-3))
        p = self.params.steering
        sw = steering_wheel_angle_for(delta, p.offset_rad, p.scale)
        cmd = apply_limits(Command(sw, ap, bp), self._last, self.limits, dt)
        self._last, self._t_prev, self._e_prev = cmd, t, e
        mode = PedalMode.THROTTLE if cmd.accel_pedal > 0 else PedalMode.BRAKE
        return ControlResult(cmd, Status.OK, pedal_mode=int(mode))
