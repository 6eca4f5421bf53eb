"""Accelerator identification end to end (:func:`identify_longitudinal`): signals, the choice of
source, the dead time, the zone fits, what each zone identified, and the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import CommandZone, Vehicle, Zone
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.longitudinal.command import command_channel, identify_command
from hmpc.models.identify.longitudinal.config import LongitudinalIdConfig, _check_config
from hmpc.models.identify.longitudinal.deadtime import PedalDeadTime, pedal_dead_time_cv
from hmpc.models.identify.longitudinal.identifiable import (
    braking_evidence,
    drop_negative_gains,
    zone_from_fit,
)
from hmpc.models.identify.longitudinal.signals import (
    LongitudinalSignals,
    ZoneMasks,
    _pedals,
    lagged_pedals,
    longitudinal_signals,
    zone_masks,
)
from hmpc.models.identify.longitudinal.sources import choose_accel_source, source_disagreements
from hmpc.models.identify.longitudinal.zonefit import ZoneFit, fit_zone, fos_candidates


@dataclass
class LongitudinalResult:
    """Outcome of :func:`identify_longitudinal`: zones (``params.Zone``), dead time, report."""

    zones: list[Zone]
    dead_time_s: float
    accel_source: str
    report: dict
    series: dict = field(default_factory=dict, repr=False)
    #: a car without an accelerator pedal: the command its zones read (``accel_cmd`` or
    #: ``speed_cmd``; ``command``) and the zones (``zones`` is then empty)
    command_input: str | None = None
    command_zones: list[CommandZone] = field(default_factory=list)


def identify_longitudinal(
    rec: Recording, vehicle: Vehicle, config: LongitudinalIdConfig | None = None, progress=None
) -> LongitudinalResult:
    """Fit eq. 8 with brake per zone (see the package doc).

    Needs ``accel_pedal`` and a speed (front wheel speeds or ``speed``); ``brake_pedal`` when
    present (absent: brake terms are not identified). Without ``accel_pedal``, a car with
    ``accel_cmd`` or ``speed_cmd`` is identified with the command as the input
    (``command.identify_command``; the result's ``command_input`` and ``command_zones``).

    Raises:
        InputError: a required channel is absent, the accel source is unavailable, the zones
            are malformed, or no zone has enough samples.
    """
    cfg = config or LongitudinalIdConfig()
    say = progress or (lambda msg: None)
    zones = _check_config(cfg, rec.meta.get("path"))
    inp = command_channel(rec) if "accel_pedal" not in rec else None
    if inp is not None:
        czones, tau, sig, report, series = identify_command(rec, vehicle, cfg, inp, say)
        return LongitudinalResult([], tau, sig.accel_desc, report, series, inp, czones)
    rec.require("accel_pedal")
    sig = longitudinal_signals(rec, vehicle, cfg)
    say("longitudinal: choosing the acceleration source by blocked cross-validation")
    lagged = lagged_pedals(sig, cfg)
    common = zone_masks(sig, zones, cfg, [a for a, _ in sig.candidates.values()])
    selection = choose_accel_source(sig, ~common.bad, common.zid, len(zones), lagged, cfg)
    deads = selection.pop("dead_times")
    sig.use(selection["chosen"])
    masks = zone_masks(sig, zones, cfg)
    dead = (
        deads[sig.source]
        if np.array_equal(masks.bad, common.bad)
        else pedal_dead_time_cv(
            sig.a_meas, ~masks.bad, masks.zid, len(zones), lagged, cfg, sig.dt_s
        )
    )
    ped = _pedals(sig, dead.tau_s)
    masks.bad |= ~(np.isfinite(ped.aps) & np.isfinite(ped.bps))
    say(
        f"longitudinal: acceleration from {sig.source} ({selection['because']}); pedal dead "
        f"time {dead.tau_s:.2f} s"
    )
    names, P_all = fos_candidates(rec, sig, ped)
    fits = [fit_zone(zi, zone, sig, masks, ped, names, P_all, cfg) for zi, zone in enumerate(zones)]
    fitted = [i for i, f in enumerate(fits) if f.fitted]
    if not fitted:
        raise InputError(
            "no speed zone has enough usable samples (moving, finite, inside one "
            f"zone; need {cfg.min_zone_s:g} s per zone): cannot identify eq. 8",
            rec.meta.get("path"),
            channel="accel_pedal",
        )
    selection["disagreements"] = source_disagreements(sig, masks, fits, deads, cfg)
    drop_negative_gains(fits)
    for zi, f in enumerate(fits):
        if f.fitted:
            f.report["braking"] = braking_evidence(sig, masks, zi, f, cfg)
    out_zones = [
        zone_from_fit(
            i, fits, zones, cfg, sig.has_brake, rec.meta.get("path"), selection["disagreements"]
        )
        for i in range(len(fits))
    ]
    report = _report(sig, masks, dead, fits, zones, names, cfg)
    report["selection"] = selection
    report["not_identified"] = {
        f"zones.{f.report['name']}.{k}": why
        for f in fits
        for k, why in f.report.get("not_identified", {}).items()
    }
    series = {
        "time": rec.time,
        "v_mps": sig.v,
        "a_meas_mps2": sig.a_meas,
        "accel_pedal": sig.ap_raw,
        "brake_pedal": sig.bp_raw if sig.has_brake else None,
        "zone": masks.zid,
        "used": ~masks.bad,
        "a_model_mps2": {zones[i][0]: f.a_model for i, f in enumerate(fits) if f.fitted},
    }
    return LongitudinalResult(out_zones, dead.tau_s, sig.accel_desc, report, series)


def _report(
    sig: LongitudinalSignals,
    masks: ZoneMasks,
    dead: PedalDeadTime,
    fits: list[ZoneFit],
    zones,
    names: list[str],
    cfg: LongitudinalIdConfig,
) -> dict:
    """The JSON-ready report of :func:`identify_longitudinal`."""
    dt, v = sig.dt_s, sig.v
    n_above = int(masks.above.sum())
    standing = masks.standstill & np.isfinite(v)
    return {
        "accel_source": sig.accel_desc,
        "speed_source": sig.speed_src,
        "dead_time_s": dead.tau_s,
        "dead_time_method": (
            f"blocked cross-validation ({cfg.cv_folds} folds) over a "
            "one-sample lag grid; used only when no delay is worse beyond "
            "fold-to-fold noise"
        ),
        "dead_time_estimate_s": dead.estimate_s,
        "dead_time_ci95_s": None if dead.interval_s is None else list(dead.interval_s),
        "dead_time_residual_reduction": dead.gain,
        "dead_time_note": dead.note,
        "dead_time_cv": dead.cv,
        "zones": [f.report for f in fits],
        "above_last_zone": {
            "samples": n_above,
            "seconds": float(n_above * dt),
            "v_max_mps": zones[-1][2],
            "note": "not fitted (no zone model above the last zone)",
        },
        "standstill": {
            "samples": int(np.sum(standing)),
            "seconds": float(np.sum(standing) * dt),
            "v_stop_mps": cfg.v_stop_mps,
            "note": "excluded: the car is held, acceleration clamped at zero",
        },
        "boundary_samples_excluded": int(np.sum(masks.boundary & ~masks.base_bad)),
        "hysteresis_mps": cfg.hysteresis_mps,
        "smooth_s": cfg.smooth_s,
        "fos_candidates": names,
    }
