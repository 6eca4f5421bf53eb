"""Steering map identification: road-wheel angle = offset + scale * steering-wheel angle (eq. 7).

One module per step, in the order :func:`identify_steering` runs them:

- ``config``: the thresholds (:class:`SteeringIdConfig`), each with its reason;
- ``kinematics``: the two measurements of the road-wheel angle, (a) from the front
  wheel-speed difference (the report's eqs. 2-6, exact) and (b) from yaw rate and speed;
- ``signals``: the channels the recording gives, which methods they support, and which
  samples to trust;
- ``deadtime``: the steering dead time, decided by held-out prediction;
- ``fits``: the direct fits of eq. 7 on (a) and on the yaw rate (b), with gyro bias and the
  speed's point;
- ``replay``: the refinement by eq. 1 position replay;
- ``identifiable``: whether a fit separates offset from scale (:func:`identifiability`), and
  whether the recording can test understeer at all (:func:`understeer_testability`);
- ``selection``: the choice of the final fit by held-out evidence;
- ``reconcile``: fits against the sign convention (:func:`negative_gains`), the two sensors
  against each other with the physics that separates them (:func:`sensor_comparison`), and
  every disagreement (:func:`disagreement`);
- ``identify``: :func:`identify_steering`, the steps in order and the report.

Intervals are 95%, from sandwich covariances that allow correlated residuals
(``models.identify.stats``): time-block clusters for the direct fits, replay windows as
clusters for the refinement, Student-t critical values.

Imports hmpc.models.identify.stats, plant, params, logs.recording and errors; never
controller or tools. Inside the package the modules import one way:
config, kinematics <- signals <- deadtime, fits <- replay, identifiable, reconcile <- selection
<- identify.
"""

from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.kinematics import (
    rear_axle_speed,
    road_wheel_angle_from_front,
    road_wheel_angle_from_yaw,
)
from hmpc.models.identify.steering.signals import (
    SampleMasks,
    SteeringSignals,
    steering_signals,
    trustworthy_samples,
)
from hmpc.models.identify.steering.deadtime import (
    DeadTime,
    dead_time_cv,
    delayed,
    estimate_dead_time,
    xcorr_dead_time,
)
from hmpc.models.identify.steering.fits import MapFit, direct_fits
from hmpc.models.identify.steering.identifiable import identifiability, understeer_testability
from hmpc.models.identify.steering.reconcile import (
    SENSOR_HEADLINE,
    disagreement,
    negative_gains,
    sensor_comparison,
)
from hmpc.models.identify.steering.selection import agreement_a_b, choose_fit, cross_validate
from hmpc.models.identify.steering.identify import SteeringResult, identify_steering

__all__ = [
    "SteeringIdConfig",
    "SteeringResult",
    "MapFit",
    "identify_steering",
    "SteeringSignals",
    "SampleMasks",
    "DeadTime",
    "steering_signals",
    "trustworthy_samples",
    "estimate_dead_time",
    "dead_time_cv",
    "direct_fits",
    "rear_axle_speed",
    "choose_fit",
    "cross_validate",
    "disagreement",
    "agreement_a_b",
    "negative_gains",
    "sensor_comparison",
    "understeer_testability",
    "SENSOR_HEADLINE",
    "identifiability",
    "road_wheel_angle_from_front",
    "road_wheel_angle_from_yaw",
    "xcorr_dead_time",
    "delayed",
]
