"""The estimator's state layout and noise model: :class:`EstimatorConfig`, every number 1-sigma
and SI, with its reason.

State (``NXE`` = 7, ``STATE_NAMES``): the plant's ``[x_m, y_m, psi_rad, v_mps]`` (local ENU,
the front-wheel point of eq. 1) and three slowly varying sensor/model errors:
``delta_offset_rad`` (a correction to eq. 7's road-wheel angle), ``gyro_bias_radps`` and
``wheel_speed_scale`` (see controller/estimator/ekf.py). ``SENSORS``: the measurement
streams whose accepted and rejected updates :attr:`Estimator.stats` counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NXE = 7  #: estimator state size
IX, IY, IPSI, IV, IDOFF, IBR, IKWS = range(NXE)
STATE_NAMES = (
    "x_m",
    "y_m",
    "psi_rad",
    "v_mps",
    "delta_offset_rad",
    "gyro_bias_radps",
    "wheel_speed_scale",
)
SENSORS = ("can_speed", "wheel_yaw_rate", "can_yaw_rate", "imu_yaw_rate", "gnss")


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise model and settings of the estimator; every number is 1-sigma and SI.

    Random-walk densities are per square root of a second: over ``dt`` the state's variance
    grows by ``density**2 * dt``.
    """

    #: eq. 8's error as a speed random walk [m/s/sqrt(s)]: on the comma minute the high zone
    #: leaves about half the acceleration variance unexplained (NMSE 48 %), ~0.3 m/s^2 rms.
    speed_walk_mps_rts: float = 0.5
    #: the same when the IMU's acceleration drives the speed (accelerometer noise 0.05 m/s^2,
    #: bias up to 0.02 m/s^2, grade) [m/s/sqrt(s)].
    speed_walk_imu_mps_rts: float = 0.1
    #: heading error of eq. 1 beyond a steering offset (slip, road camber) [rad/sqrt(s)].
    heading_walk_rad_rts: float = 0.005
    #: position error of eq. 1 (side slip of the front point) [m/sqrt(s)].
    position_walk_m_rts: float = 0.02
    #: drift of the road-wheel angle correction [rad/sqrt(s)] (understeer changes with speed
    #: and lateral acceleration within seconds).
    delta_offset_walk_rad_rts: float = 0.001
    #: gyro bias drift [rad/s/sqrt(s)]: wanders about 0.001 rad/s in an hour, as a MEMS
    #: gyro's bias does with temperature.
    gyro_bias_walk_radps_rts: float = 2e-5
    #: tyre radius drift (load, pressure, temperature) [1/sqrt(s)].
    wheel_scale_walk_rts: float = 1e-4

    #: initial uncertainty (after the first fix or :meth:`Estimator.reset`).
    init_position_m: float = 0.5
    init_heading_rad: float = 0.05
    init_speed_mps: float = 0.5
    init_delta_offset_rad: float = 0.005
    init_gyro_bias_radps: float = 0.003
    init_wheel_scale: float = 0.02

    #: measurement noise; the defaults match ``models.sim.live_sensors.SensorConfig()``
    #: (see :meth:`matching`).
    can_speed_mps: float = 0.05
    wheel_yaw_rate_radps: float = 0.035  # comma minute, rear difference against the gyro
    can_yaw_rate_radps: float = 0.005
    imu_yaw_rate_radps: float = 0.005
    gnss_position_m: float = 0.02
    gnss_heading_rad: float = math.radians(0.1)
    gnss_speed_mps: float = 0.05
    #: GNSS point relative to the eq. 1 point (front-axle centre), body axes (x fwd, y left)
    #: [m]. A conventions ``nav_lever_arm_m`` [lx, ly] from the rear axle is (lx - b, ly).
    gnss_offset_m: tuple[float, float] = (0.0, 0.0)

    #: use the rear wheel-speed difference as a yaw-rate measurement (report's eq. 5). Off by
    #: default: on the comma minute it differs from the gyro by 0.034 rad/s rms with heavy tails
    #: and a -0.009 rad/s offset (left/right tyre radii differ), which no state here models; it
    #: earns its place on a car without a yaw-rate sensor.
    use_wheel_yaw_rate: bool = False
    #: the IMU's longitudinal acceleration replaces eq. 8 while fresher than this [s].
    use_imu_accel: bool = True
    imu_accel_max_age_s: float = 0.05
    #: the CAN steering-wheel angle replaces the commanded one while fresher than this [s].
    steer_input_max_age_s: float = 0.1
    #: innovation gate: chi-square probability (see controller/estimator/ekf.py).
    gate_probability: float = 0.999
    #: consecutive rejected GNSS fixes before the filter re-initialises on GNSS.
    gnss_reinit_after: int = 20
    #: longest propagation sub-step [s] (the plant's step is exact in speed and heading for
    #: held inputs, midpoint in position: about dist * dpsi^2 / 24, 0.1 mm per 20 ms step at
    #: 20 m/s on a 5 m radius).
    max_step_s: float = 0.02
    #: depth of the event log for latency compensation (about 300 events/s: 1.7-3.4 s).
    history_events: int = 1024

    def __post_init__(self):
        if not 0.5 < self.gate_probability < 1.0:
            raise ValueError(
                f"gate_probability must be within (0.5, 1), got {self.gate_probability}"
            )
        if self.history_events < 16:
            raise ValueError("history_events must be at least 16")
        if not self.max_step_s > 0:
            raise ValueError("max_step_s must be positive")

    @classmethod
    def matching(cls, sensors, **overrides) -> EstimatorConfig:
        """Measurement noise matched to a ``live_sensors.SensorConfig`` (noise_scale applied)."""
        k = sensors.noise_scale
        quant = 0.01 / 3.6 / math.sqrt(12.0)  # WHEEL_SPEEDS 0.01 km/h step
        wheel = math.hypot(k * sensors.wheel_jitter_mps, quant)
        track = 1.6  # nominal; only sets a noise level
        kw = dict(
            can_speed_mps=math.hypot(k * sensors.speed_noise_mps, wheel / 2.0),
            wheel_yaw_rate_radps=math.sqrt(2.0) * wheel / track,
            can_yaw_rate_radps=k * sensors.can_yaw_rate_noise_radps,
            imu_yaw_rate_radps=k * sensors.gyro_noise_radps,
            gnss_position_m=max(k * sensors.position_noise_m, 1e-4),
            gnss_heading_rad=max(k * sensors.heading_noise_rad, 1e-5),
            gnss_speed_mps=max(k * sensors.gnss_speed_noise_mps, 1e-3),
        )
        kw.update(overrides)
        return cls(**kw)
