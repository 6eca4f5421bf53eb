"""The measurements of one control period, as the online model estimator uses them
(:class:`PeriodSignals`): sums of the samples that arrived since the last control step, with
the sensor checks that keep a faulty channel from teaching anything.

Fed as messages arrive (``add_can``, ``add_imu``; a few float additions each), read and
cleared once per control step (:meth:`PeriodSignals.take`). The checks:

- **spikes**: a yaw-rate or acceleration sample further from the last accepted one than the
  car can change in one sample (``AdaptConfig.yaw_rate_jump_radps``, ``accel_jump_mps2``) is
  dropped and counted; ``jump_resync_samples`` such samples in a row are a step of the signal
  and taken as its new level;
- **a frozen or broken wheel-speed channel**: the four wheel speeds must agree to
  ``wheel_disagree_mps`` beyond what the turn explains (left-right difference = track x yaw
  rate, front against rear = v (1 - cos delta), well under it at the speeds that teach): a
  channel stuck at an old value while the car speeds up fails within a fraction of a second,
  and the periods of the next ``suspect_hold_s`` teach nothing (``suspect``);
- non-finite values are absent. A GNSS outage needs no check: nothing here uses GNSS.
"""

from __future__ import annotations

import math

from hmpc.controller.adapt.config import AdaptConfig


class PeriodSignals:
    """Sums of one control period's samples, checked (see the module docstring).

    Args:
        config: the thresholds.
        track_m: the wheel track [m] (the left-right wheel-speed difference of a turn).
    """

    def __init__(self, config: AdaptConfig, track_m: float):
        c = config
        self._yaw_jump, self._acc_jump = c.yaw_rate_jump_radps, c.accel_jump_mps2
        self._resync = c.jump_resync_samples
        self._wheel_tol = c.wheel_disagree_mps
        self._hold = c.suspect_hold_s
        self._track = float(track_m)
        self._yaw_last = math.nan
        self._acc_last = math.nan
        self._yaw_run = 0
        self._acc_run = 0
        self._suspect_until = -math.inf
        self.spikes = {"yaw_rate": 0, "accel": 0}
        self.wheel_faults = 0
        self.clear()

    def clear(self) -> None:
        """Start a new period."""
        self.n_yaw = 0
        self.sum_yaw = 0.0
        self.n_acc = 0
        self.sum_acc = 0.0
        self.n_sw = 0
        self.sum_sw = 0.0
        self.sw_first = math.nan
        self.sw_last = math.nan
        self.t_sw_first = math.nan
        self.t_sw_last = math.nan
        self.n_v = 0
        self.sum_v = 0.0

    def add_yaw(self, t_s: float, yaw_rate_radps: float) -> None:
        """A yaw-rate sample [rad/s] (gyro or CAN)."""
        y = yaw_rate_radps
        if not math.isfinite(y):
            return
        last = self._yaw_last
        if last == last and abs(y - last) > self._yaw_jump:
            self._yaw_run += 1
            if self._yaw_run < self._resync:
                self.spikes["yaw_rate"] += 1
                return
        self._yaw_run = 0
        self._yaw_last = y
        self.n_yaw += 1
        self.sum_yaw += y

    def add_accel(self, t_s: float, accel_mps2: float) -> None:
        """A longitudinal acceleration sample [m/s^2] (accelerometer)."""
        a = accel_mps2
        if not math.isfinite(a):
            return
        last = self._acc_last
        if last == last and abs(a - last) > self._acc_jump:
            self._acc_run += 1
            if self._acc_run < self._resync:
                self.spikes["accel"] += 1
                return
        self._acc_run = 0
        self._acc_last = a
        self.n_acc += 1
        self.sum_acc += a

    def add_imu(self, t_s: float, yaw_rate_radps=None, accel_x_mps2=None) -> None:
        """An IMU sample: yaw rate [rad/s], longitudinal acceleration [m/s^2] (None: absent)."""
        if yaw_rate_radps is not None:
            self.add_yaw(t_s, float(yaw_rate_radps))
        if accel_x_mps2 is not None:
            self.add_accel(t_s, float(accel_x_mps2))

    def add_can(
        self, t_s: float, wheel_speeds_mps=None, steering_wheel_angle_rad=None, yaw_rate_radps=None
    ) -> None:
        """A CAN sample: the four wheel speeds (fl, fr, rl, rr) [m/s], the steering-wheel angle
        [rad], a yaw rate [rad/s] (None or non-finite: absent)."""
        if steering_wheel_angle_rad is not None:
            sw = float(steering_wheel_angle_rad)
            if math.isfinite(sw):
                if self.n_sw == 0:
                    self.sw_first, self.t_sw_first = sw, t_s
                self.sw_last, self.t_sw_last = sw, t_s
                self.n_sw += 1
                self.sum_sw += sw
        if wheel_speeds_mps is not None:
            fl, fr, rl, rr = wheel_speeds_mps
            if math.isfinite(fl + fr + rl + rr):
                self._check_wheels(t_s, fl, fr, rl, rr)
                self.n_v += 1
                self.sum_v += 0.25 * (fl + fr + rl + rr)
        if yaw_rate_radps is not None:
            self.add_yaw(t_s, float(yaw_rate_radps))

    def _check_wheels(self, t_s: float, fl: float, fr: float, rl: float, rr: float) -> None:
        """The four wheels against each other (module docstring); a failure marks the next
        ``suspect_hold_s`` as suspect."""
        yaw = self._yaw_last if self._yaw_last == self._yaw_last else 0.0
        turn = self._track * abs(yaw)
        tol = self._wheel_tol
        front, rear = 0.5 * (fl + fr), 0.5 * (rl + rr)
        if (
            abs(fl - fr) > turn + tol
            or abs(rl - rr) > turn + tol
            or abs(front - rear) > 0.1 * front + tol
        ):
            if t_s >= self._suspect_until:
                self.wheel_faults += 1
            self._suspect_until = t_s + self._hold

    def suspect(self, t_s: float) -> bool:
        """Whether a wheel-speed check failed within ``suspect_hold_s`` before ``t_s``."""
        return t_s < self._suspect_until
