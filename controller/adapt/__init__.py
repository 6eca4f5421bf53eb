"""The online model estimator, beside the state estimator: what the car's data say its model
is now (eq. 7's offset and scale, eq. 8 per zone, the actuators' dead times and lags), learned
on line while the data can determine it, bounded against the parameter file it started from,
and handed to the controller and the state estimator as values (``ModelAdapter``,
``LearnedModel``). One concern per module: ``config`` (thresholds with their reasons and the
parameter keys), ``paramfilter`` (the Kalman filter on a few parameters), ``signals`` (one
control period's measurements and the sensor checks), ``steering`` and ``longitudinal`` (the
gates and regressions of eq. 7 and eq. 8), ``timing`` (dead time and lag by a candidate grid),
``adapter`` (validity, the model in use), ``report`` (the run's ``adaptation`` and the
history) and ``learned`` (the learned state as a parameter file: restore and save).

May import ``hmpc.models`` (not ``hmpc.models.sim``); never ``hmpc.tools``, nor the rest of
``hmpc.controller``.
"""

from hmpc.controller.adapt.adapter import LearnedModel, ModelAdapter
from hmpc.controller.adapt.config import AdaptConfig

__all__ = ["AdaptConfig", "LearnedModel", "ModelAdapter"]
