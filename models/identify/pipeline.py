"""``identify``: the report's steering map (eq. 7) and zone accelerator models (eq. 8) from a
recording, as a parameter set the controller loads, plus a report of every figure.

Steps: :func:`models.identify.steering.identify_steering` (wheel-speed and yaw-rate fits, eq. 1
position replay, dead time, intervals, identifiability) and
:func:`models.identify.longitudinal.identify_longitudinal` (per-zone eq. 8 with brake, FOS term
selection, NMSE%, speed RMSE, intervals). A car without the report's inputs is identified
from its commands: without ``steering_wheel_angle`` the steering map reads ``steering_cmd``
(written as ``steering.input: steering_cmd``), and without ``accel_pedal`` the zones read
``accel_cmd`` or ``speed_cmd`` (``longitudinal.input``, ``params.CommandZone``). The geometry
(wheelbase, track) comes from the vehicle file and is copied to the result unchanged.

The result's ``params`` holds the keys of ``docs/conventions.md`` and the optional keys of
``models.params`` (delays, intervals, fit metrics, identifiability flags and notes,
provenance); ``report`` holds the same figures and more, JSON-ready, with stable keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from hmpc import __version__
from hmpc.models.logs.channels import STRING_CHANNELS
from hmpc.models.errors import InputError
from hmpc.models.logs.ingest import sha256_file
from hmpc.models.identify.longitudinal import (
    DEFAULT_ZONES,
    LongitudinalIdConfig,
    LongitudinalResult,
    identify_longitudinal,
    zones_for_vehicle,
)
from hmpc.models.params import Params, Steering, Vehicle
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.steering import SteeringIdConfig, SteeringResult, identify_steering


def _steering_scores(report: dict) -> dict | None:
    """Each steering method's held-out score (``selection.scores``), finite ones only."""
    scores = (report.get("selection") or {}).get("scores") or {}
    out = {
        k: float(v["score"])
        for k, v in scores.items()
        if isinstance(v, dict) and v.get("score") is not None and math.isfinite(v["score"])
    }
    return out or None


def _dead_time_ci(report: dict) -> tuple | None:
    """The steering dead time's held-out interval [s], when it was determined."""
    dt = report.get("dead_time") or {}
    ci = dt.get("interval_s")
    if not dt.get("determined") or not ci or not all(math.isfinite(float(x)) for x in ci):
        return None
    return (float(ci[0]), float(ci[1]))


@dataclass
class IdentifyResult:
    """``params``: the identified model; ``report``: every figure (JSON-ready);
    ``steering``/``longitudinal``: the detailed results (with time series for plots)."""

    params: Params
    report: dict
    steering: SteeringResult | None
    longitudinal: LongitudinalResult | None


def concat_recordings(recs: list[Recording], gap_s: float = 2.0) -> Recording:
    """Join recordings on one uniform grid, separated by ``gap_s`` of missing samples.

    All must share one rate (within 0.1%). Every channel present in any recording is kept
    (NaN, or "" for strings, where a recording lacks it). The gap keeps smoothing windows and
    replay windows from bridging two recordings; positions may jump across it.

    Raises:
        ValueError: no recordings, or different rates.
    """
    if not recs:
        raise ValueError("no recordings to join")
    rate = recs[0].rate_hz
    for r in recs[1:]:
        if abs(r.rate_hz - rate) > 1e-3 * rate:
            raise ValueError(f"rates differ: {rate} Hz and {r.rate_hz} Hz")
    dt = 1.0 / rate
    names: list[str] = []
    for r in recs:
        names += [k for k in r.channels if k not in names]
    gap_n = max(int(round(gap_s / dt)), 1)
    cols: dict[str, list] = {k: [] for k in names}
    t_next = 0.0
    for i, r in enumerate(recs):
        n = len(r)
        tt = t_next + np.arange(n) * dt
        for k in names:
            if k == "time":
                cols[k].append(tt)
            elif k in r.channels:
                cols[k].append(np.asarray(r.channels[k]))
            else:
                cols[k].append(
                    np.full(n, "", dtype=object) if k in STRING_CHANNELS else np.full(n, np.nan)
                )
        t_next = tt[-1] + dt
        if i < len(recs) - 1:
            gt = t_next + np.arange(gap_n) * dt
            for k in names:
                if k == "time":
                    cols[k].append(gt)
                else:
                    cols[k].append(
                        np.full(gap_n, "", dtype=object)
                        if k in STRING_CHANNELS
                        else np.full(gap_n, np.nan)
                    )
            t_next = gt[-1] + dt
    channels = {k: np.concatenate(v) for k, v in cols.items()}
    meta = {
        "joined": [r.meta.get("experiment") or r.meta.get("path") for r in recs],
        "gaps": [],
        "path": "+".join(str(r.meta.get("path", "?")) for r in recs),
    }
    return Recording(channels, {}, meta)


def identify(
    recording: Recording,
    vehicle: Vehicle,
    *,
    zones=None,
    steering_config: SteeringIdConfig | None = None,
    longitudinal_config: LongitudinalIdConfig | None = None,
    sources: dict | None = None,
    progress=None,
) -> IdentifyResult:
    """Identify eq. 7 and eq. 8 (+ brake) per zone from ``recording``.

    Args:
        recording: a canonical recording (``models.logs.recording``).
        vehicle: the measured geometry (``load_params(path).vehicle``).
        zones: speed zones as ``[(name, v_min_mps, v_max_mps), ...]``; overrides
            ``longitudinal_config.zones``. Default: the config's zones, or when those are the
            report's (idle [0, 2], low (2, 5], high (5, 20] m/s), the report's scaled to the
            vehicle (``longitudinal.zones_for_vehicle``: a 1:10 car's are 0-0.71-1.8-7.1 m/s).
        steering_config: steering thresholds (defaults documented there).
        longitudinal_config: longitudinal thresholds (defaults documented there).
        sources: provenance of the input files, ``{role: path}``; hashed into the result.
        progress: callable receiving progress lines (the CLI prints them on stderr).

    Raises:
        InputError: a required channel is absent, or the recording has too little usable data.
    """
    say = progress or (lambda msg: None)
    lcfg = longitudinal_config or LongitudinalIdConfig()
    if zones is not None:
        lcfg = replace(lcfg, zones=tuple((str(n), float(a), float(b)) for n, a, b in zones))
    elif lcfg.zones == DEFAULT_ZONES:
        lcfg = replace(lcfg, zones=zones_for_vehicle(vehicle))
    if len(recording) < 10:
        raise InputError(
            f"the recording has only {len(recording)} samples", recording.meta.get("path")
        )
    say(f"identify: {len(recording)} samples at {recording.rate_hz:.3g} Hz")
    # each part needs only its own channels: a part the recording cannot support is skipped
    # with its reason (``not_identified:``); only a recording that supports neither is refused
    not_identified: dict[str, str] = {}
    errors: list[InputError] = []

    def part(name, fn, *args):
        try:
            return fn(*args, progress=say)
        except InputError as exc:
            errors.append(exc)
            not_identified[name] = exc.one_line()
            say(f"{name}: not identified: {exc.one_line()}")
            return None

    steering_input = (
        "steering_cmd"
        if "steering_wheel_angle" not in recording and "steering_cmd" in recording
        else "steering_wheel_angle"
    )
    if steering_input == "steering_cmd":
        say("steering: no steering_wheel_angle: the map's input is the command 'steering_cmd'")
    if steering_input not in recording:

        def no_input(*args, progress):
            raise InputError(
                "neither 'steering_wheel_angle' nor 'steering_cmd' is in the "
                "recording: the steering map has no input",
                recording.meta.get("path"),
                channel="steering_wheel_angle",
            )

        st = part("steering", no_input)
    else:
        st = part(
            "steering", identify_steering, recording, vehicle, steering_config, steering_input
        )
    lo = part("longitudinal", identify_longitudinal, recording, vehicle, lcfg)
    if st is None and lo is None:
        raise InputError(
            "nothing could be identified: "
            + "; ".join(
                f"{k}: {e.reason}" + (f" (channel '{e.channel}')" if e.channel else "")
                for k, e in zip(not_identified, errors)
            ),
            recording.meta.get("path"),
        )
    # every zone value the recording did not determine (copied from another zone, the prior,
    # or absorbing unobserved braking), named with its reason whether or not the zone was
    # fitted: ``longitudinal.zones.<name>.<key>`` (the zone itself is written, complete and
    # flagged ``identifiable: false``, so the controller keeps a model for every speed)
    zone_ni = (
        {}
        if lo is None
        else {f"longitudinal.{k}": why for k, why in lo.report["not_identified"].items()}
    )

    steering = (
        None
        if st is None
        else Steering(
            offset_rad=float(st.offset_rad),
            scale=float(st.scale),
            dead_time_s=float(st.dead_time_s),
            offset_ci95_rad=tuple(float(x) for x in st.offset_ci95_rad),
            scale_ci95=tuple(float(x) for x in st.scale_ci95),
            rms_error_rad=(float(st.rms_error_rad) if math.isfinite(st.rms_error_rad) else None),
            method=st.method,
            method_scores=_steering_scores(st.report),
            dead_time_ci95_s=_dead_time_ci(st.report),
            identifiable=bool(st.identifiable),
            note=st.note,
            input=None if steering_input == "steering_wheel_angle" else steering_input,
        )
    )
    t = recording.time
    prov: dict = {
        "hmpc_version": __version__,
        "time_start_s": float(t[0]),
        "time_end_s": float(t[-1]),
        "duration_s": float(t[-1] - t[0]),
        "samples": int(len(t)),
        "rate_hz": float(round(recording.rate_hz, 6)),
    }
    for role, path in (sources or {}).items():
        if path:
            prov[f"{role}_file"] = str(path)
            prov[f"{role}_sha256"] = sha256_file(path)
    params = Params(
        vehicle=replace(vehicle),
        steering=steering,
        zones=[] if lo is None else lo.zones,
        command_input=None if lo is None else lo.command_input,
        command_zones=[] if lo is None else lo.command_zones,
        longitudinal_dead_time_s=None if lo is None else float(lo.dead_time_s),
        hysteresis_mps=(
            lcfg.hysteresis_mps if lo is not None and lcfg.hysteresis_mps > 0 else None
        ),
        accel_source=None if lo is None else lo.accel_source,
        provenance=prov,
        accel_source_chosen=(None if lo is None else lo.report["selection"]["chosen"]),
        accel_source_scores_mps2=(
            None
            if lo is None
            else {
                k: float(v["score_mps2"])
                for k, v in lo.report["selection"]["scores"].items()
                if math.isfinite(v["score_mps2"])
            }
        ),
        not_identified={**not_identified, **zone_ni},
    )
    report = {
        "hmpc_version": __version__,
        "provenance": prov,
        "vehicle": {"wheelbase_m": vehicle.wheelbase_m, "track_front_m": vehicle.track_front_m},
        "steering": None if st is None else st.report,
        "longitudinal": None if lo is None else lo.report,
        "not_identified": {**not_identified, **zone_ni},
    }
    return IdentifyResult(params, _finite_json(report), st, lo)


def _finite_json(obj):
    """Replace NaN/inf by None and numpy scalars by Python numbers (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {k: _finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_json(v) for v in obj]
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj
