"""The hybrid-mode MPC's fast path (OSQP), one concern per module: ``config`` (the tuning),
``delay`` (dead time and lag compensation), ``zone_rules`` (zone schedule, floor and
zone-transition band), ``qp`` (the fixed pattern and the OSQP solver), ``cost`` and
``constraints`` (the values written into it each step), ``controller`` (MpcController,
which ties them together; the NMPC, controller/nmpc.py, subclasses it).

May import ``hmpc.models`` (not ``hmpc.models.sim``) and the shared controller modules
(base, horizon, limits, modes); never ``hmpc.tools``.
"""

from hmpc.controller.mpc.config import MpcConfig
from hmpc.controller.mpc.controller import MpcController
from hmpc.controller.mpc.zone_rules import preferred_zone

__all__ = ["MpcConfig", "MpcController", "preferred_zone"]
