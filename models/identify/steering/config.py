"""Thresholds of steering identification (:class:`SteeringIdConfig`), each with the reason for
its number, and their scaling to the vehicle's size (:meth:`SteeringIdConfig.for_vehicle`).
Imports nothing of hmpc.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

#: [m] the wheelbase the default thresholds were set for: the report's car (a passenger car).
REFERENCE_WHEELBASE_M = 2.65
#: thresholds that :meth:`SteeringIdConfig.for_vehicle` scales with a smaller vehicle's size f =
#: wheelbase / REFERENCE_WHEELBASE_M (f <= 1), by dynamic similarity (equal Froude number v^2 /
#: (g b): a 1:10 model behaves like the full-size car at speeds scaled by sqrt(f), on time scales
#: scaled by sqrt(f), so rates scale by 1/sqrt(f)) and geometric similarity (lengths by f).
#: Accelerations (tyre friction, 0.3-0.4 g) are the same at every size and stay.
SPEED_THRESHOLDS = ("v_min_mps", "kinematic_speed_mps")
RATE_THRESHOLDS = ("sw_rate_max_radps",)
LENGTH_THRESHOLDS = ("lever_arm_x_bounds_m", "max_lever_arm_ci_m")
#: durations of the vehicle's motion (the replay window: long enough for a heading error to show
#: in position); the smoothing and guard windows belong to the recording's sampling and stay.
TIME_THRESHOLDS = ("window_s",)


@dataclass(frozen=True)
class SteeringIdConfig:
    """Thresholds of steering identification (the reason for each number in its comment)."""

    #: [m/s] below this the 0.01 km/h wheel-speed step is > 0.4% of the speed difference a
    #: 1 deg road-wheel angle makes; the report's slowest arcs run at 2.4 m/s.
    v_min_mps: float = 1.5
    #: [1] rear-axle speed vs front-axle speed x cos(delta): 3% is well above the 0.01 km/h
    #: quantisation at 1.5 m/s (0.2%) and below the slip of hard traction or braking.
    slip_max: float = 0.03
    #: [m/s^2] |dv/dt| above this (about 0.3 g) means longitudinal tyre slip.
    accel_max_mps2: float = 3.0
    #: [m/s^2] lateral acceleration above 0.4 g leaves the tyres' linear range (side slip).
    lat_accel_max_mps2: float = 4.0
    #: [rad/s] steering-wheel rate above ~86 deg/s: transients (tyre relaxation, yaw lag, message
    #: timing) dominate; excluded from the direct fits only (the replay handles dynamics).
    sw_rate_max_radps: float = 1.5
    #: [s] excluded margin around every excluded sample (resampling and smoothing spread).
    guard_s: float = 0.3
    #: [s] Savitzky-Golay window for the steering rate, accelerations and the dead time.
    smooth_s: float = 0.5
    #: [s] dead-time search range (negative: measurement leads, a clock problem).
    dead_time_min_s: float = -0.2
    dead_time_max_s: float = 1.0
    #: [1] a source's cross-correlation lag is reported as a cross-check only when its peak
    #: reaches this (the dead time itself is decided by held-out prediction, below).
    dead_time_min_corr: float = 0.3
    #: [1] contiguous folds of the blocked cross-validation over the dead time's lag grid: ten
    #: folds of a 4-minute drive are 24 s each (several steering cycles), and t(9) = 2.26 keeps
    #: the fold-paired test of "better than no delay" from needing a huge effect.
    dead_time_cv_folds: int = 10
    #: [s] replay window of the refinement: long enough for a heading error to show in
    #: position, short enough that INS drift and model error stay small.
    window_s: float = 5.0
    #: [samples] position residual every this many samples (0.1 s at 50 Hz).
    replay_stride: int = 5
    #: [m] bounds of the estimated nav lever arm's x (no ``nav_lever_arm_m`` in the geometry):
    #: (low, margin beyond the front axle); a GNSS/INS antenna sits on the body, from behind the
    #: rear axle to over the bonnet.
    lever_arm_x_bounds_m: tuple = (-1.0, 2.0)
    #: [1] upper bound of k = (x_s / b)^2, x_s the unknown longitudinal distance of the speed
    #: channel's point from the rear axle (``speed`` from CAN, or ``gps_speed`` without
    #: ``nav_lever_arm_m``): 4 puts it up to two wheelbases away, beyond any antenna or any
    #: average of wheel speeds.
    speed_point_k_max: float = 4.0
    #: [1] the replay's starting scale when no direct fit exists and the geometry gives no
    #: ``steering_ratio``: 1/15, mid-range of passenger cars' ratios (12-18); the fit moves it.
    replay_start_scale: float = 1.0 / 15.0
    #: [m] half-width of the estimated lever arm's 95% interval above which the replay is not
    #: trusted: 0.25 m of lever arm moves the replayed front axle by ~1% of a 2.7 m wheelbase.
    max_lever_arm_ci_m: float = 0.25
    #: [1] contiguous folds of the blocked cross-validation that chooses the final fit.
    cv_folds: int = 5
    #: [rad] / [1] immaterial differences between fits: two fits disagree only when their 95%
    #: intervals, each widened by these, do not overlap. A tenth of the identifiability
    #: thresholds (``max_offset_ci_rad``, ``max_scale_rel_ci``): on long clean recordings the
    #: intervals shrink below the channels' own systematic resolution (0.1 deg steering-wheel
    #: steps, 0.01 km/h wheel-speed steps).
    agree_offset_rad: float = 0.0005
    agree_scale_rel: float = 0.01
    # ---- identifiability
    #: [s] least trustworthy data (500 samples at 50 Hz, 100 at 10 Hz: a duration, so that
    #: the recording's rate does not decide identifiability).
    min_trustworthy_s: float = 10.0
    #: [rad] steering-wheel range (2.5-97.5 percentile) needed: below ~29 deg at the wheel the
    #: road-wheel angle is < ~1.7 deg, comparable to sensor biases (tyre radius mismatch,
    #: gyro bias, angle-sensor zero).
    min_sw_range_rad: float = 0.5
    #: [1] |correlation| of the offset and scale estimates above this: not separable.
    max_param_corr: float = 0.95
    #: [1] relative half-width of the scale's 95% interval above this: gain not determined.
    max_scale_rel_ci: float = 0.10
    #: [rad] half-width of the offset's 95% interval above this (0.3 deg) : offset not determined.
    max_offset_ci_rad: float = 0.005
    #: [m/s] the kinematic map (no side slip) is checked only with steering below this speed.
    kinematic_speed_mps: float = 10.0
    #: [s] of trustworthy steering below ``kinematic_speed_mps`` needed.
    min_kinematic_s: float = 5.0
    # ---- the two independent sensors (wheel-speed difference, yaw rate)
    #: [1] relative difference of the wheel-speed and yaw-rate scales above which it matters
    #: even when it is within the noise: half of ``max_scale_rel_ci``, so the value written is
    #: not off by more than an identifiable scale's own interval allows, whichever sensor is
    #: right. Within the noise, such a difference leaves the scale NOT identifiable.
    sensor_scale_material_rel: float = 0.05
    # ---- understeer: whether the recording can test it at all
    #: [m/s^2] lateral acceleration (97.5th percentile of |a_y| on the trustworthy samples)
    #: needed before anything is said about understeer: its angle is K a_y, and a passenger
    #: car's K ~ 0.004 rad/(m/s^2) (2.3 deg/g) makes 0.008 rad at 2 m/s^2, several times the
    #: angle sensor's 0.1 deg step; on a straight line it is not testable.
    understeer_min_lat_accel_mps2: float = 2.0
    #: [1] (v_high / v_low)^2 of the steered samples (10th and 90th speed percentiles where
    #: |a_y| > a quarter of ``understeer_min_lat_accel_mps2``) needed: at one speed the
    #: understeer factor 1 / (1 + K v^2 / b) is a constant on the gain, not separable from it.
    understeer_min_speed_sq_ratio: float = 2.0

    @classmethod
    def for_vehicle(cls, vehicle, **overrides) -> SteeringIdConfig:
        """The defaults scaled to a vehicle smaller than the reference (:data:`SPEED_THRESHOLDS`,
        :data:`RATE_THRESHOLDS`, :data:`LENGTH_THRESHOLDS`, :data:`TIME_THRESHOLDS`), then
        ``overrides`` (field name ->
        value) on top. A vehicle at least as long as the reference keeps the defaults: the
        reasons behind the speed thresholds (wheel-speed steps, gyro bias over speed) do not
        grow with size.

        Raises:
            ValueError: an override names no threshold.
        """
        known = {f.name for f in fields(cls)}
        bad = [k for k in overrides if k not in known]
        if bad:
            raise ValueError(
                f"unknown steering threshold '{bad[0]}' (one of {', '.join(sorted(known))})"
            )
        f = min(1.0, float(vehicle.wheelbase_m) / REFERENCE_WHEELBASE_M)
        base = cls()
        scaled = {}
        if f < 1.0:
            scaled.update({k: getattr(base, k) * math.sqrt(f) for k in SPEED_THRESHOLDS})
            scaled.update({k: getattr(base, k) / math.sqrt(f) for k in RATE_THRESHOLDS})
            scaled.update({k: getattr(base, k) * math.sqrt(f) for k in TIME_THRESHOLDS})
            for k in LENGTH_THRESHOLDS:
                v = getattr(base, k)
                scaled[k] = tuple(x * f for x in v) if isinstance(v, tuple) else v * f
        return replace(base, **{**scaled, **overrides})

    @staticmethod
    def size_factor(vehicle) -> float:
        """The factor f (<= 1) by which :meth:`for_vehicle` scales to ``vehicle``."""
        return min(1.0, float(vehicle.wheelbase_m) / REFERENCE_WHEELBASE_M)
