"""Steering identification end to end (:func:`identify_steering`): signals, trustworthy samples,
dead time, the fits, identifiability, the choice, and the report and plot series.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Vehicle
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.deadtime import delayed, estimate_dead_time
from hmpc.models.identify.steering.fits import MapFit, direct_fits
from hmpc.models.identify.steering.identifiable import identifiability, understeer_testability
from hmpc.models.identify.steering.reconcile import (
    SENSOR_HEADLINE,
    disagreement,
    negative_gains,
    sensor_comparison,
)
from hmpc.models.identify.steering.replay import _fit_replay
from hmpc.models.identify.steering.selection import agreement_a_b, choose_fit, cross_validate
from hmpc.models.identify.steering.signals import (
    MIN_FIT_SAMPLES,
    SteeringSignals,
    dropped_text,
    steering_signals,
    trustworthy_samples,
)


@dataclass
class SteeringResult:
    """Outcome of :func:`identify_steering`.

    ``offset_rad``/``scale`` are the final estimate: the trusted fit with the best held-out
    score (:func:`choose_fit`; identifiable fits first), or the yaw-rate fit when the two
    sensors' scales are reconciled by ``wheel_speed_scale`` (``reconcile``), flagged NOT
    identifiable when the fits disagree beyond their intervals otherwise. ``fits`` holds all
    fits by name, ``report`` the JSON-ready figures, ``series`` time series for plots
    (road-wheel angle estimates etc.).
    """

    offset_rad: float
    scale: float
    offset_ci95_rad: tuple[float, float]
    scale_ci95: tuple[float, float]
    dead_time_s: float
    identifiable: bool
    note: str
    method: str
    rms_error_rad: float
    fits: dict[str, MapFit]
    report: dict
    series: dict = field(default_factory=dict, repr=False)


def identify_steering(
    rec: Recording,
    vehicle: Vehicle,
    config: SteeringIdConfig | None = None,
    input_channel: str = "steering_wheel_angle",
    progress=None,
) -> SteeringResult:
    """Identify eq. 7 from a canonical recording (see the package doc).

    Needs ``steering_wheel_angle`` and the channels of at least one method: the four wheel
    speeds (wheel-speed difference), ``yaw_rate`` and a speed (yaw rate), ``x``/``y``/
    ``heading`` and a speed (replay); uses every method the channels support, chooses among
    them by held-out evidence, and names each skipped method and why
    (``report['selection']['skipped']``). Uses ``gear`` to drop reverse.

    The thresholds default to :meth:`SteeringIdConfig.for_vehicle` (scaled to a vehicle
    smaller than a passenger car).

    ``input_channel="steering_cmd"`` fits the map to the steering command instead (a car with
    no steering measurement): road-wheel angle = offset + scale * steering_cmd, the servo
    included; every step is the same, errors name ``steering_cmd``, and the range check of
    identifiability is on the road-wheel angle (``_identify``).

    Raises:
        InputError: no method has its channels, no trustworthy samples remain, or no fit is
            trusted (every one with a gain <= 0, or only an untrusted replay).
    """
    cfg = config or SteeringIdConfig.for_vehicle(vehicle)
    say = progress or (lambda msg: None)
    if input_channel == "steering_cmd":
        try:
            res = _identify(
                _command_rec(rec), vehicle, cfg, say, cfg.min_sw_range_rad * cfg.replay_start_scale
            )
        except InputError as exc:
            raise InputError(
                exc.reason.replace("steering-wheel", "steering command"),
                exc.path,
                channel="steering_cmd" if exc.channel == "steering_wheel_angle" else exc.channel,
            ) from None
        res.report["input"] = "steering_cmd"
        res.note = (
            f"input steering_cmd (the commanded angle: road-wheel angle = offset + "
            f"scale * steering_cmd, the servo included): {res.note}"
        )
        res.report["identifiability"]["note"] = res.note
        return res
    if input_channel != "steering_wheel_angle":
        raise ValueError(f"unknown steering input {input_channel!r}")
    return _identify(rec, vehicle, cfg, say, None)


def _command_rec(rec: Recording) -> Recording:
    """``rec`` with the steering command read where the steps read the steering-wheel angle
    (the same arrays, nothing copied or filled in)."""
    rec.require("steering_cmd")
    ch = dict(rec.channels)
    ch["steering_wheel_angle"] = rec["steering_cmd"]
    return Recording(ch, rec.raw, rec.meta)


def _identify(
    rec: Recording,
    vehicle: Vehicle,
    cfg: SteeringIdConfig,
    say,
    road_wheel_min_range_rad: float | None,
) -> SteeringResult:
    """The steps of :func:`identify_steering`; ``road_wheel_min_range_rad`` (a command input)
    moves identifiability's range check to the road-wheel angle the fit implies: the
    steering-wheel threshold ``min_sw_range_rad`` times ``replay_start_scale`` (1/15), the
    road-wheel range it means on a passenger car."""
    sig = steering_signals(rec, vehicle)
    for m, why in sig.skipped.items():
        say(f"steering: {m} skipped: {why}")
    masks = trustworthy_samples(rec, sig, cfg)
    say(
        f"steering: {int(masks.steady.sum())} trustworthy samples of {len(sig.sw)} ("
        f"{dropped_text(masks.dropped, len(sig.sw))})"
    )
    if masks.relaxed:
        say(f"steering: too few samples pass every check: the fits include {masks.relaxed}")
    dead = estimate_dead_time(sig, masks.usable, cfg)
    sw_d = delayed(sig.sw, dead.tau_s, sig.dt_s)
    steady = masks.steady & np.isfinite(sw_d)
    usable = masks.usable & np.isfinite(sw_d)
    if steady.sum() < masks.steady.sum():  # the delayed angle reaches before the start
        masks.dropped.append(
            {
                "reason": "dead_time_edge",
                "samples": int(masks.steady.sum() - steady.sum()),
                "threshold": dead.tau_s,
                "text": f"within the dead time {dead.tau_s:.3g} s of a gap or the start",
            }
        )
    say(
        f"steering: dead time {dead.tau_s:.3f} s ("
        + (
            f"held-out interval {dead.interval_s[0]:.3f}-{dead.interval_s[1]:.3f} s"
            if dead.used
            else "not determined"
        )
        + f", from {dead.source})"
    )
    fits = direct_fits(sig, sw_d, steady, cfg)
    lever = getattr(vehicle, "nav_lever_arm_m", None)
    replay = None
    if "position_replay" not in sig.skipped:
        start = fits.get("yaw_rate") or fits.get("wheel_speed_difference")
        x0 = (
            (start.offset_rad, start.scale)
            if start is not None
            else (
                0.0,
                1.0 / vehicle.steering_ratio if vehicle.steering_ratio else cfg.replay_start_scale,
            )
        )
        say("steering: refining by eq. 1 position replay")
        out, _ = _fit_replay(rec, sig.v_front, sw_d, usable, sig.dt_s, sig.b, cfg, x0, lever)
        if out is not None:
            fits["position_replay"], replay, _ = out
        else:
            sig.skipped["position_replay"] = (
                f"fewer than 3 replay windows of {cfg.window_s} s with finite x, y, heading"
            )
    if not fits:
        raise InputError(
            "no steering fit converged ("
            + "; ".join(f"{m}: {w}" for m, w in sig.skipped.items())
            + ")",
            rec.meta.get("path"),
            channel="steering_wheel_angle",
        )
    for k, why in negative_gains(fits).items():  # a gain <= 0 is never a model value
        fits[k].extra.update(trusted=False, untrusted_because=why)
        say(f"steering: {k} not used: {why}")
    if not any(f.extra.get("trusted", True) for f in fits.values()):
        raise InputError(
            "no trusted steering fit ("
            + "; ".join(
                [f"{k}: {f.extra['untrusted_because']}" for k, f in fits.items()]
                + [f"{m}: {w}" for m, w in sig.skipped.items()]
            )
            + ")",
            rec.meta.get("path"),
            channel="steering_wheel_angle",
        )
    idents = {
        k: identifiability(
            f,
            sw_d[steady],
            sig.v_front[steady],
            sig.dt_s,
            cfg,
            vehicle.steering_ratio,
            road_wheel_min_range_rad,
        )
        for k, f in fits.items()
    }
    for k, f in fits.items():
        if not f.extra.get("trusted", True):
            idents[k] = dict(
                idents[k], identifiable=False, note="NOT trusted: " + f.extra["untrusted_because"]
            )
    say("steering: choosing by blocked cross-validation")
    cv = cross_validate(rec, sig, fits, sw_d, steady, usable, cfg, lever)
    chosen, why = choose_fit(fits, idents, cv)
    sensors = sensor_comparison(fits, sig.b, sig.T, cfg)
    if (
        sensors is not None
        and sensors["verdict"] == "reconciled"
        and chosen == "wheel_speed_difference"
    ):
        chosen, why = (
            "yaw_rate",
            (
                "the wheel-speed and yaw-rate scales disagree and the "
                "wheel-speed angle depends on the effective track width "
                f"(reconciled_by: wheel_speed_scale; by held-out score: {why})"
            ),
        )
    if sensors is not None and sensors["verdict"] != "agree":
        say(f"steering: {SENSOR_HEADLINE[sensors['verdict']]}: {sensors['note']}")
    final = fits[chosen]
    pairs, disagree_note = disagreement(fits, cfg, sensors)
    ident = dict(idents[chosen])
    not_ident = []
    if sensors is not None and (
        sensors["verdict"] == "offset"
        or (sensors["verdict"] == "unresolved" and chosen == "wheel_speed_difference")
    ):
        not_ident.append(sensors["note"])
    if disagree_note:
        not_ident.append(disagree_note)
    if masks.relaxed:
        not_ident.append(
            f"fewer than {MIN_FIT_SAMPLES} samples pass every sample check, so "
            f"the fits include {masks.relaxed}"
        )
    if not_ident:
        ident["identifiable"] = False
        ident["note"] = (
            "NOT identifiable: "
            + "; ".join(not_ident)
            + ". "
            + ident["note"].removeprefix("NOT identifiable: ")
        )
    if sensors is not None and sensors["verdict"] == "reconciled":
        ident["note"] += " " + sensors["note"] + "."
    if sig.skipped:  # the parameter file's note names the methods the recording did not allow
        ident["note"] += (
            " Not run: " + "; ".join(f"{m} ({w})" for m, w in sig.skipped.items()) + "."
        )
    selection = {
        "chosen": chosen,
        "because": why,
        **cv,
        "disagreements": pairs,
        "sensors": sensors,
        "untrusted": {
            k: f.extra["untrusted_because"]
            for k, f in fits.items()
            if not f.extra.get("trusted", True)
        },
        "skipped": dict(sig.skipped),
        "speeds": sig.speed_note,
    }
    agreement, delta_b = agreement_a_b(sig, fits, steady)
    delta_model = final.offset_rad + final.scale * sw_d
    ref = delta_b if delta_b is not None else sig.delta_a
    rms_rad = (
        float(np.sqrt(np.mean((ref - delta_model)[steady] ** 2)))
        if ref is not None
        else float("nan")
    )
    report = _report(
        sig,
        cfg,
        final,
        why,
        selection,
        dead,
        fits,
        agreement,
        rms_rad,
        ident,
        idents,
        masks,
        steady,
        usable,
        sw_d,
    )
    with np.errstate(invalid="ignore"):
        lat = sig.v_rear**2 * np.tan(delta_model) / sig.b
    report["understeer"] = understeer_testability(sig.v_rear[steady], lat[steady], cfg)
    report["thresholds_size_factor"] = SteeringIdConfig.size_factor(vehicle)
    series = _series(rec, sig, delta_b, delta_model, steady, replay, final)
    return SteeringResult(
        offset_rad=final.offset_rad,
        scale=final.scale,
        offset_ci95_rad=final.offset_ci95_rad,
        scale_ci95=final.scale_ci95,
        dead_time_s=dead.tau_s,
        identifiable=ident["identifiable"],
        note=ident["note"],
        method=final.method,
        rms_error_rad=rms_rad,
        fits=fits,
        report=report,
        series=series,
    )


def _report(
    sig,
    cfg,
    final,
    why,
    selection,
    dead,
    fits,
    agreement,
    rms_rad,
    ident,
    idents,
    masks,
    steady,
    usable,
    sw_d,
) -> dict:
    """The JSON-ready figures of :func:`identify_steering` (stable keys)."""
    return {
        "offset_rad": final.offset_rad,
        "scale": final.scale,
        "offset_ci95_rad": list(final.offset_ci95_rad),
        "scale_ci95": list(final.scale_ci95),
        "method": final.method,
        "method_selected_because": why,
        "selection": selection,
        "dead_time_s": dead.tau_s,
        "dead_time": dead.to_dict(cfg.smooth_s),
        "fits": {k: f.to_dict() for k, f in fits.items()},
        "agreement_a_b": agreement,
        "rms_error_rad": rms_rad,
        "identifiability": ident,
        "identifiability_by_fit": {
            k: {
                "identifiable": v["identifiable"],
                "offset_identifiable": v["offset_identifiable"],
                "scale_identifiable": v["scale_identifiable"],
                "note": v["note"],
            }
            for k, v in idents.items()
        },
        "samples": {
            "total": int(len(sig.sw)),
            "usable": int(usable.sum()),
            "trustworthy": int(steady.sum()),
            "excluded": masks.excluded,
            "dropped": masks.dropped,
            "relaxed": masks.relaxed,
        },
        "speed_source": sig.speed_source,
        "speed_range_mps": [
            float(np.percentile(sig.v_front[steady], 2.5)),
            float(np.percentile(sig.v_front[steady], 97.5)),
        ],
        "steering_wheel_range_rad": [
            float(np.percentile(sw_d[steady], 2.5)),
            float(np.percentile(sw_d[steady], 97.5)),
        ],
        "thresholds": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
    }


def _series(
    rec: Recording, sig: SteeringSignals, delta_b, delta_model, steady, replay, final: MapFit
) -> dict:
    """Time series for the plots (``models.report``)."""
    nan = np.full(len(sig.sw), np.nan)  # channels the recording lacks plot as gaps
    fl, fr = (nan if w is None else w for w in (sig.fl, sig.fr))
    series = {
        "time": rec.time,
        "steering_wheel_angle": sig.sw,
        "wheel_speed_fl": fl,
        "wheel_speed_fr": fr,
        "turn_rate_wheels_radps": (fr - fl) / sig.T,
        "delta_wheels_rad": nan if sig.delta_a is None else sig.delta_a,
        "delta_yaw_rad": delta_b,
        "delta_model_rad": delta_model,
        "trustworthy": steady,
    }
    if replay is not None:
        xp, yp = replay.predict((final.offset_rad, final.scale))
        series["replay"] = {
            "x_pred": np.where(replay.inwin, xp, np.nan),
            "y_pred": np.where(replay.inwin, yp, np.nan),
            "x": np.asarray(rec["x"], float),
            "y": np.asarray(rec["y"], float),
        }
    return series
