"""The online model estimator's thresholds (:class:`AdaptConfig`), each number with its unit in
its name and its reason beside it, and the parameter keys it learns.

The gates repeat identification's reasoning (``models.identify.steering.config``,
``models.identify.longitudinal.config``): the same speeds, steering rates and accelerations
decide which samples can teach eq. 7 and eq. 8, on line as off line. The bounds say how far a
learned value may leave the parameter file it started from before it is taken for a broken
sensor or another car, not for the car's drift (openpilot's paramsd bounds the steer ratio to
0.5-2x nominal for the same reason).
"""

from __future__ import annotations

from dataclasses import dataclass

#: the run JSON's and the learned file's keys (the fleet contract's dotted parameter keys)
KEY_STEER_OFFSET = "steering.offset_rad"
KEY_STEER_SCALE = "steering.scale"
KEY_STEER_DELAY = "extensions.actuator_delay.steering.delay_s"
KEY_STEER_LAG = "extensions.actuator_lag.steering.tau_s"
KEY_LONG_DELAY = "extensions.actuator_delay.longitudinal.delay_s"
KEY_LONG_LAG = "extensions.actuator_lag.longitudinal.tau_s"


def zone_key(zone_name: str, coefficient: str) -> str:
    """``longitudinal.zones.<zone>.<coefficient>`` (``offset_mps2``, ``scale_mps2``,
    ``brake_scale_mps2``, or ``accel_cmd_gain`` for a car driven by an acceleration command)."""
    return f"longitudinal.zones.{zone_name}.{coefficient}"


@dataclass(frozen=True)
class AdaptConfig:
    """Gates, priors, drift rates and bounds of the online model estimator (SI, 1-sigma)."""

    # ---- steering (eq. 7 from the yaw rate: delta = asin(r b / v))
    #: [m/s] openpilot's paramsd learns above 1 m/s: below, the yaw rate per road-wheel angle
    #: is so small that what is left of a gyro bias (~0.001 rad/s once the state estimator has
    #: it) is a 2.6 mrad road-wheel angle. Each sample's noise grows as b / v (below), so the
    #: slow samples weigh little; they matter when a car pulls away with its offset unknown.
    steer_v_min_mps: float = 1.0
    #: [m/s] identification's kinematic_speed_mps: the scale is learned only below it (above,
    #: tyre side slip folds understeer into the gain); the offset is learned at any speed.
    steer_scale_v_max_mps: float = 10.0
    #: [rad/s] identification's sw_rate_max_radps: steering faster than ~86 deg/s is a
    #: transient (tyre relaxation, yaw lag, message timing).
    steer_rate_max_radps: float = 1.5
    #: [m/s^2] identification's lat_accel_max_mps2: 0.4 g leaves the tyres' linear range.
    steer_lat_accel_max_mps2: float = 4.0
    #: [m/s^2] identification's accel_max_mps2: 0.3 g means longitudinal tyre slip.
    steer_long_accel_max_mps2: float = 3.0
    #: [rad] the steering-wheel angle must be this far from straight ahead for the scale to
    #: move (identification's min_sw_range_rad: below ~29 deg at the wheel the road-wheel angle
    #: is comparable to sensor biases). Nearer straight ahead the offset learns with the
    #: scale held (straight driving teaches the offset only).
    steer_scale_sw_min_rad: float = 0.5
    #: [rad] floor of a steering sample's noise: the 0.1 deg angle-sensor step times a scale
    #: of 0.08, the gyro bias the state estimator has not yet separated, and the midpoint
    #: error of averaging eq. 7 over a control period.
    steer_noise_floor_rad: float = 0.0015
    #: [rad/s] the yaw-rate sensor's white noise when the caller does not give it (the
    #: simulated gyro's, a MEMS gyro's).
    yaw_rate_noise_radps: float = 0.005
    #: prior 1-sigma of how far the car may be from its file: [rad] the offset (a kerb strike
    #: or an alignment moves it by ~10 mrad) and [1] the scale relative (tyres, load and tyre
    #: pressure change the effective ratio by up to ~15 %).
    steer_offset_prior_rad: float = 0.010
    steer_scale_prior_rel: float = 0.15
    #: drift as a random walk per square root of an hour: [rad] the offset (alignment, road
    #: crown), [1] the relative scale (tyre wear, load). Keeps the intervals honest and lets a
    #: slowly changing car be followed; capped at the prior (no wind-up without excitation).
    steer_offset_walk_rad_rth: float = 0.003
    steer_scale_walk_rel_rth: float = 0.02
    #: bounds against the file: [rad] offset, [1] relative scale. A road-wheel offset of 3 deg
    #: is beyond any drivable alignment; a steering ratio half or twice the file's is another
    #: car or a broken sensor (openpilot's paramsd: 0.5-2x nominal).
    steer_offset_bound_rad: float = 0.05
    steer_scale_bound_rel: float = 0.5

    # ---- longitudinal (eq. 8 per zone, from the measured acceleration)
    #: [m/s] identification's v_stop_mps with margin: a held car does not follow eq. 8 (the
    #: plant clamps at standstill, wheel-speed sensors read zero below a few tenths of a m/s).
    long_v_min_mps: float = 0.5
    #: [m/s] samples this close to a zone boundary are skipped: with the plant's zone
    #: hysteresis (0.25 m/s by default) the car may still be in the neighbouring zone there.
    long_boundary_margin_mps: float = 0.3
    #: [1] identification's pressed: a pedal's gain learns only while the pedal is pressed
    #: beyond its 0.5 % quantisation step (a coefficient whose input is not exercised holds).
    long_pressed: float = 0.02
    #: [m/s^2] an acceleration command this large exercises a command-driven car's gain.
    long_cmd_min_mps2: float = 0.1
    #: [m/s^2] floor of an acceleration sample's noise: what is left of the accelerometer's
    #: bias, grade, and the half-step smear of a control period.
    long_noise_floor_mps2: float = 0.01
    #: [m/s^2] accelerometer white noise when the caller does not give it.
    accel_noise_mps2: float = 0.05
    #: [s] memory of the accelerometer bias estimate (the accelerometer's integral against
    #: the state estimator's speed change: a temperature-driven bias drifts over minutes),
    #: and its prior as a time: the speed's error at a window's two ends (~0.02 m/s) over the
    #: bias's prior 1-sigma (0.01 m/s^2, a MEMS accelerometer's turn-on bias). The bias is
    #: taken out of the measured acceleration: a zone offset learned on it would be off by it,
    #: and the controller's speed by its integral.
    accel_bias_window_s: float = 120.0
    accel_bias_prior_s: float = 2.0
    #: the accelerometer stands for eq. 8's acceleration (the change of eq. 1's front-axle
    #: speed) only while the car runs straight: road-wheel angle (the file's eq. 7) within
    #: [rad], and the centripetal term yaw_rate^2 x wheelbase within [m/s^2]. In a turn an
    #: accelerometer elsewhere on the body reads cos(delta) of eq. 8's acceleration plus
    #: yaw_rate^2 times its distance ahead of the rear axle (at most about a wheelbase):
    #: 0.1 rad is 0.5 % of a gain; 0.06 m/s^2 is a yaw rate of 0.15 rad/s on a 2.65 m
    #: wheelbase and 0.43 rad/s on a 1:10 car's 0.33 m. Such a period's acceleration is the
    #: speed change of eq. 1's point instead (the state estimator's speed). On CommonRoad
    #: recordings with the accelerometer at the rear axle (tests/adapt/test_adapt_indep.py)
    #: the accelerometer in turns took the idle zone's accelerator gain 5.6-9.8 % low and
    #: the low zone's offset 15 % off.
    long_imu_delta_max_rad: float = 0.1
    long_imu_centripetal_max_mps2: float = 0.06
    #: [m/s] noise of the state estimator's speed change over one control period, for the
    #: periods whose acceleration is that change (no accelerometer, or a turn). On hmpc's
    #: simulator at the default sensors in a 50 Hz loop the estimate's speed error is
    #: 0.016 m/s RMS with a lag-1 correlation of 0.7: its change over 20 ms has 0.0125 m/s,
    #: 0.62 m/s^2, twelve times the accelerometer's noise.
    long_speed_change_noise_mps: float = 0.0125
    #: [m/s^2] a measured acceleration beyond this is not a car on a road.
    long_accel_abs_max_mps2: float = 8.0
    #: prior 1-sigma: [m/s^2] offset (grade of 1 %, drag) and [1] relative gains (a full car
    #: is ~30 % heavier than an empty one; engine temperature, gear).
    long_offset_prior_mps2: float = 0.1
    long_gain_prior_rel: float = 0.15
    #: drift per square root of an hour: [m/s^2] offset, [1] relative gains.
    long_offset_walk_mps2_rth: float = 0.05
    long_gain_walk_rel_rth: float = 0.05
    #: bounds against the file: [m/s^2] offset (an 8 % grade), [1] relative gains (half or
    #: twice the file's gain is another car or a broken pedal signal).
    long_offset_bound_mps2: float = 0.8
    long_gain_bound_rel: float = 0.5

    # ---- outliers and sensor faults
    #: chi-square gate of a parameter update (1 value) at probability 0.999, as the state
    #: estimator's: a consistent filter rejects 1 good sample in 1000.
    gate_chi2: float = 10.83
    #: consecutive gated-out updates after which the filter widens its interval (a real,
    #: sudden change of the car is then learned within seconds; a spike is not).
    reject_widen_after: int = 20
    #: [rad/s] a yaw-rate sample this far from the last accepted one is a spike: a car turns
    #: in at most ~2 rad/s^2, plus five sigmas of gyro noise.
    yaw_rate_jump_radps: float = 0.08
    #: [m/s^2] an acceleration sample this far from the last accepted one is a spike (jerk of
    #: 10 m/s^3 over a 10 ms sample, plus five sigmas of accelerometer noise).
    accel_jump_mps2: float = 0.5
    #: consecutive spikes after which the new level is taken as the signal's (a step is
    #: followed, a single spike is not).
    jump_resync_samples: int = 5
    #: [m/s] the four wheel speeds may disagree by this much beyond what the turn explains
    #: (track times yaw rate): a channel further off is frozen or broken, and the samples of
    #: the next ``suspect_hold_s`` teach nothing.
    wheel_disagree_mps: float = 0.2
    suspect_hold_s: float = 1.0

    # ---- actuator delay and lag (command -> response, lagd-like)
    #: [s] longest dead time and lag searched (the catalogue's ranges).
    timing_max_s: float = 1.0
    #: [s] grid step of the dead time (lagd resolves 0.05 s at 20 Hz).
    delay_step_s: float = 0.05
    #: [s] the lag time constants tried.
    lag_grid_s: tuple = (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7, 1.0)
    #: [s] memory of the response fit (lagd's 60 s window).
    timing_window_s: float = 60.0
    #: [s] least usable, excited data before a dead time or lag is called valid (lagd: 25 s of
    #: usable data; here excitation is counted, not time).
    timing_min_excited_s: float = 15.0
    #: [s] a command counts as exciting for this long after it changed by more than its
    #: ``*_step`` below (the response to a step lasts a few time constants).
    timing_excited_after_s: float = 1.5
    #: [rad] / [m/s^2] a command change that excites the response fit.
    timing_steer_step_rad: float = 0.2
    timing_long_step_mps2: float = 0.2

    # ---- validity, output
    #: [1] relative / absolute 95 % half-widths under which a learned value is used (the
    #: identifiability thresholds of identification, as 95 % half-widths).
    valid_steer_scale_rel_ci: float = 0.10
    valid_steer_offset_ci_rad: float = 0.005
    valid_gain_rel_ci: float = 0.25
    valid_offset_ci_mps2: float = 0.1
    #: immaterial changes: a new model is handed to the controller only when a used value
    #: moved by more than these since the last hand-over ([rad], [1] relative, [m/s^2],
    #: [1] relative, [s]).
    push_offset_rad: float = 0.0001
    push_scale_rel: float = 0.001
    push_zone_offset_mps2: float = 0.005
    push_gain_rel: float = 0.002
    push_timing_s: float = 0.02
    #: [s] period of the recorded history (plots, convergence times).
    history_period_s: float = 0.2
    #: immaterial difference of a converged value: [rad] offset (identification's
    #: agree_offset_rad), [1] relative scale and gains (agree_scale_rel), [m/s^2] zone offset
    #: (agree_offset_mps2), [s] timing (one grid step).
    converged_offset_rad: float = 0.0005
    converged_rel: float = 0.01
    converged_offset_mps2: float = 0.02
    converged_timing_s: float = 0.05
