"""Accelerator models per speed zone: eq. 8 plus a brake term, chosen and fitted from a recording.

Per zone z (default idle [0, 2], low (2, 5], high (5, 20] m/s, the report's section V)::

    dv/dt = offset_z + scale_z * accel_pedal(t - tau) - brake_scale_z * brake_pedal(t - tau)

A package, not sibling modules of ``models.identify``, because its steps are one method with
one entry point (:func:`identify_longitudinal`) and share their types (signals, zone masks,
zone fits); the package's name stays the name outside code imports. One module per step, in
the order :func:`identify_longitudinal` runs them:

- ``config``: the settings (:class:`LongitudinalIdConfig`), each with its reason, the default
  zones and the acceleration sources, and the check of the configured zones;
- ``signals``: data preparation: eq. 1's speed, the candidate measured accelerations with
  their matched smoother, the zone of each sample and which samples the fits may use, the
  pedals at a dead time;
- ``deadtime``: the pedal dead time by blocked cross-validation;
- ``sources``: the choice of the acceleration source by held-out evidence, and the sources'
  disagreements term by term;
- ``zonefit``: eq. 8 on one zone by OLS with intervals (HAC plus the pedal timing bound), its
  metrics (NMSE, the speed replay) and the FOS term selection;
- ``identifiable``: what each zone's data determined, the fallbacks for what it did not, and
  the written ``params.Zone``;
- ``command``: the same steps for a car driven by ``accel_cmd`` or ``speed_cmd`` without an
  accelerator pedal channel (the command is the input; ``params.CommandZone``);
- ``identify``: :func:`identify_longitudinal`, the steps in order and the report.

Imports hmpc.models.identify.stats, fos and steering (the time shift and eq. 1's speed from
the front wheel speeds), params, zones, logs.recording and errors; never controller or tools.
Inside the package the modules import one way: config <- signals, deadtime <- zonefit <-
sources, identifiable, command <- identify.
"""

from hmpc.models.identify.longitudinal.config import (
    ACCEL_SOURCES,
    DEFAULT_ZONES,
    SOURCE_ORDER,
    LongitudinalIdConfig,
    zones_for_vehicle,
)
from hmpc.models.identify.longitudinal.signals import (
    LongitudinalSignals,
    Pedals,
    ZoneMasks,
    accel_candidates,
    assign_zones,
    eq1_speed,
    lagged_pedals,
    longitudinal_signals,
    zone_masks,
)
from hmpc.models.identify.longitudinal.deadtime import PedalDeadTime, pedal_dead_time_cv
from hmpc.models.identify.longitudinal.zonefit import (
    ZoneFit,
    fit_zone,
    fos_candidates,
    ols_timed,
    speed_rmse,
)
from hmpc.models.identify.longitudinal.sources import choose_accel_source, source_disagreements
from hmpc.models.identify.longitudinal.identifiable import braking_evidence, zone_from_fit
from hmpc.models.identify.longitudinal.command import COMMAND_CHANNELS, command_channel
from hmpc.models.identify.longitudinal.identify import LongitudinalResult, identify_longitudinal

__all__ = [
    "LongitudinalIdConfig",
    "LongitudinalResult",
    "identify_longitudinal",
    "DEFAULT_ZONES",
    "SOURCE_ORDER",
    "ACCEL_SOURCES",
    "zones_for_vehicle",
    "COMMAND_CHANNELS",
    "command_channel",
    "LongitudinalSignals",
    "ZoneMasks",
    "Pedals",
    "PedalDeadTime",
    "ZoneFit",
    "eq1_speed",
    "accel_candidates",
    "longitudinal_signals",
    "assign_zones",
    "zone_masks",
    "lagged_pedals",
    "pedal_dead_time_cv",
    "choose_accel_source",
    "source_disagreements",
    "fos_candidates",
    "ols_timed",
    "fit_zone",
    "speed_rmse",
    "zone_from_fit",
    "braking_evidence",
]
