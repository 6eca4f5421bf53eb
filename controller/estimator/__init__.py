"""The state estimator shared by simulate, drive and replay, one concern per module: ``config``
(the state layout and the noise model), ``ekf`` (the extended Kalman filter core:
propagation on the plant's equations, gated updates), ``estimator`` (Estimator: messages as
they arrive, the event log and the out-of-sequence GNSS replay) and ``recording`` (the
estimator run over a canonical recording offline).

May import ``hmpc.models`` (not ``hmpc.models.sim``); never ``hmpc.tools``, nor the rest of
``hmpc.controller``.
"""

from hmpc.controller.estimator.config import (
    IBR,
    IDOFF,
    IKWS,
    IPSI,
    IV,
    IX,
    IY,
    NXE,
    SENSORS,
    STATE_NAMES,
    EstimatorConfig,
)
from hmpc.controller.estimator.estimator import Estimator
from hmpc.controller.estimator.recording import EstimateRun, estimate_recording

__all__ = [
    "IBR",
    "IDOFF",
    "IKWS",
    "IPSI",
    "IV",
    "IX",
    "IY",
    "NXE",
    "SENSORS",
    "STATE_NAMES",
    "EstimateRun",
    "Estimator",
    "EstimatorConfig",
    "estimate_recording",
]
