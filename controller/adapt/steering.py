"""Eq. 7's offset and scale learned on line (:class:`SteeringLearner`).

Each control period gives one sample: the road-wheel angle the yaw rate says the car had,
``delta = asin(r b / v)`` (eq. 1 inverted; ``r`` the period's mean yaw rate less the state
estimator's gyro bias, ``v`` its speed), against the period's mean measured steering-wheel
angle ``sw``: ``delta = offset + scale * sw`` is linear in the two parameters
(:class:`~hmpc.controller.adapt.paramfilter.ParamFilter`).

What a sample may teach (identification's reasoning, ``models.identify.steering``):

- nothing below ``steer_v_min_mps``, while the steering turns faster than
  ``steer_rate_max_radps``, beyond ``steer_lat_accel_max_mps2`` or
  ``steer_long_accel_max_mps2``, or while a wheel-speed channel is suspect;
- near straight ahead (within ``steer_scale_sw_min_rad`` of the steering-wheel angle that
  drives straight) only the offset: the scale is held (straight driving teaches the offset
  and holds the scale); the scale moves only while turning, and only below
  ``steer_scale_v_max_mps`` (kinematic steering, no side slip folded into the gain).

A sample's noise: the gyro's white noise over the period's samples, through ``b / v``, and a
floor (``steer_noise_floor_rad``).
"""

from __future__ import annotations

import math

from hmpc.models.params import Params

from hmpc.controller.adapt.config import AdaptConfig
from hmpc.controller.adapt.paramfilter import ParamFilter

#: parameter indices
OFFSET, SCALE = 0, 1
_S_PER_RTH = 60.0  # sqrt(3600 s): a walk per square root of an hour, per square root of a second


class SteeringLearner:
    """The steering map's filter and its gates (see the module docstring).

    Args:
        params: the parameter file it starts from (eq. 7, the wheelbase).
        config: gates, priors, bounds.
        yaw_rate_noise_radps: the yaw-rate sensor's white noise (1-sigma) [rad/s].
    """

    def __init__(self, params: Params, config: AdaptConfig, yaw_rate_noise_radps: float):
        c = config
        self.cfg = c
        assert params.steering is not None
        off0, sc0 = float(params.steering.offset_rad), float(params.steering.scale)
        self.file = (off0, sc0)
        self.b = float(params.vehicle.wheelbase_m)
        self.filter = ParamFilter(
            [off0, sc0],
            [c.steer_offset_prior_rad, c.steer_scale_prior_rel * sc0],
            [
                c.steer_offset_walk_rad_rth / _S_PER_RTH,
                c.steer_scale_walk_rel_rth * sc0 / _S_PER_RTH,
            ],
            [off0 - c.steer_offset_bound_rad, sc0 * (1.0 - c.steer_scale_bound_rel)],
            [off0 + c.steer_offset_bound_rad, sc0 * (1.0 + c.steer_scale_bound_rel)],
            gate_chi2=c.gate_chi2,
            widen_after=c.reject_widen_after,
        )
        self._yaw_var = float(yaw_rate_noise_radps) ** 2
        self._h = [1.0, 0.0]
        self._free = [True, False]
        self.samples = {"used": 0, "offset_only": 0, "gated": 0}

    def road_wheel_angle(self, yaw_rate_radps: float, v_mps: float) -> float:
        """Eq. 1 inverted: the road-wheel angle [rad] of a yaw rate at a speed."""
        s = yaw_rate_radps * self.b / v_mps
        return math.asin(min(max(s, -0.99), 0.99))

    def gate(
        self,
        v_mps: float,
        yaw_rate_radps: float,
        sw_rate_radps: float,
        accel_mps2: float,
        suspect: bool,
    ) -> bool:
        """Whether the period may teach the map at all (module docstring)."""
        c = self.cfg
        return (
            v_mps >= c.steer_v_min_mps
            and abs(sw_rate_radps) <= c.steer_rate_max_radps
            and abs(v_mps * yaw_rate_radps) <= c.steer_lat_accel_max_mps2
            and abs(accel_mps2) <= c.steer_long_accel_max_mps2
            and not suspect
        )

    def learn(self, v_mps: float, yaw_rate_radps: float, n_yaw: int, sw_rad: float) -> bool:
        """One gated sample (call :meth:`gate` first): the period's speed [m/s], yaw rate less
        the gyro bias [rad/s] over ``n_yaw`` samples, mean steering-wheel angle [rad].
        Returns True when the filter took it."""
        c = self.cfg
        th = self.filter.theta
        delta = self.road_wheel_angle(yaw_rate_radps, v_mps)
        sw_straight = -th[OFFSET] / th[SCALE]
        turning = abs(sw_rad - sw_straight) >= c.steer_scale_sw_min_rad
        self._free[SCALE] = turning and v_mps <= c.steer_scale_v_max_mps
        self._h[SCALE] = sw_rad
        g = self.b / (v_mps * max(math.cos(delta), 0.1))  # d delta / d r
        r = g * g * self._yaw_var / max(n_yaw, 1) + c.steer_noise_floor_rad**2
        ok = self.filter.update(self._h, delta, r, self._free)
        if ok:
            self.samples["used"] += 1
            if not self._free[SCALE]:
                self.samples["offset_only"] += 1
        else:
            self.samples["gated"] += 1
        return ok
