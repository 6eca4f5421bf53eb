"""What each zone's data determined, and the written zone (:func:`zone_from_fit`).

**Identifiability**: a pedal gain fitted below zero is set aside (:func:`drop_negative_gains`: a
reversed sign convention, or an input that is not a pedal), and then, like a coefficient whose
input is never exercised in a zone (pedal pressed for less than ``min_pressed_s``), it is not
fitted; it is copied from the nearest zone that identified
it, or (brake only) set to ``brake_scale_prior_mps2``, and the zone is marked
``identifiable: false`` with a note. A zone with less than ``min_zone_s`` of usable samples is
copied from the nearest fitted zone and marked the same way. Without brake data (no channel, or the
pedal never pressed), a zone whose released-accelerator samples still decelerate beyond
coasting (:func:`braking_evidence`) says that the offset and scale absorb unobserved braking.
Every written value that the zone's own data did not determine (copied from another zone, the
prior, or absorbing unobserved braking) is listed with its reason, naming the zone it was copied
from, in ``report['not_identified']`` (``zones.<name>.<key>``), whether the zone was fitted or
not; ``models.identify.pipeline`` names them under the top-level ``not_identified``.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Zone
from hmpc.models.identify.longitudinal.config import LongitudinalIdConfig
from hmpc.models.identify.longitudinal.signals import LongitudinalSignals, ZoneMasks
from hmpc.models.identify.longitudinal.zonefit import ZoneFit


def _pair(ci) -> tuple[float, float] | None:
    return None if ci is None else (float(ci[0]), float(ci[1]))


def _opt(x) -> float | None:
    """A finite Python float, or None (a parameter file holds no NaN)."""
    return float(x) if x is not None and np.isfinite(x) else None


def _nearest(i: int, candidates: list[int]) -> int | None:
    if not candidates:
        return None
    return min(candidates, key=lambda j: (abs(j - i), j))


def _nearest_fitted(i: int, fits, key: str) -> int | None:
    """The zone nearest to ``i`` whose fit produced ``key`` (a zone's value is copied from it)."""
    return _nearest(i, [k for k, g in enumerate(fits) if g.fitted and g.report[key] is not None])


def _rel_half_width(value: float, ci) -> float:
    """Half-width of the 95% interval relative to the value (inf for a zero value)."""
    return abs(0.5 * (ci[1] - ci[0]) / value) if value != 0 else float("inf")


#: a pedal's channel and what pressing it must do, by the zone key of its gain
_GAIN_INPUT = {
    "scale_mps2": ("accel_pedal", "accelerate"),
    "brake_scale_mps2": ("brake_pedal", "decelerate (the brake term is subtracted)"),
}


def drop_negative_gains(fits: list[ZoneFit]) -> None:
    """Set aside every fitted pedal gain < 0 (in place): pressing a pedal never works against
    it, so a negative gain is a reversed sign convention or an input that is not a pedal (a
    speed or torque command), never a model value. The gain goes to
    ``report['negative_gains'][key]`` with its interval and the reason, and ``report[key]`` to
    None, so the zone takes the value as a zone that did not exercise the pedal does."""
    for f in fits:
        if not f.fitted:
            continue
        rep = f.report
        for key, (channel, does) in _GAIN_INPUT.items():
            v = rep.get(key)
            if v is None or v >= 0:
                continue
            ci_key = key.replace("_mps2", "_ci95_mps2")
            lo, hi = rep.get(ci_key) or (v, v)
            why = (
                f"gain not determined: {key} {v:.3g} m/s^2, its 95% interval [{lo:.3g}, "
                f"{hi:.3g}] spans 0"
                if hi > 0
                else f"negative gain {v:.3g} m/s^2 [{lo:.3g}, {hi:.3g}]: pressing {channel} must "
                f"{does}; check the sign convention of {channel} (0 released, 1 pressed), or "
                "the input is not a pedal (a speed or torque command?)"
            )
            rep.setdefault("negative_gains", {})[key] = {
                "value": v,
                "ci95": [lo, hi],
                "reason": why,
            }
            rep[key], rep[ci_key] = None, None


def _negative_why(rep: dict, key: str) -> str | None:
    """The reason a fitted gain was set aside (:func:`drop_negative_gains`), or None."""
    return (rep.get("negative_gains") or {}).get(key, {}).get("reason")


def zone_from_fit(
    i: int,
    fits: list[ZoneFit],
    zones,
    cfg: LongitudinalIdConfig,
    has_brake: bool,
    path,
    disagreements: dict | None = None,
) -> Zone:
    """Zone ``i``'s written ``params.Zone``, with fallbacks for what its data did not exercise
    (module doc); sets ``fits[i].zone`` and the report's identifiable, note and written keys.

    Raises:
        InputError: the accelerator was never pressed long enough in any zone.
    """
    f, (zname, lo, hi) = fits[i], zones[i]
    rep = f.report
    fitted = [k for k, g in enumerate(fits) if g.fitted]
    notes = []
    ident = f.fitted
    # every written value that the zone's own data did not determine (copied from another
    # zone, or the prior) is named here with its reason, fitted zone or not (CONVENTIONS:
    # ``not_identified:``; ``identify_longitudinal`` collects them)
    rep.setdefault("not_identified", {})
    if not f.fitted:
        j = _nearest(i, fitted)
        assert j is not None  # at least one zone is fitted (checked by the caller)
        off = fits[j].report["offset_mps2"]
        why = f"{rep['not_fitted_because']}: copied from zone '{zones[j][0]}'"
        rep["not_identified"]["offset_mps2"] = why
        notes.append(f"{rep['not_fitted_because']}: offset copied from zone '{zones[j][0]}'")
        rep_off_ci = None
    else:
        off = rep["offset_mps2"]
        rep_off_ci = rep["offset_ci95_mps2"]
        if 0.5 * (rep_off_ci[1] - rep_off_ci[0]) > cfg.max_offset_ci_mps2:
            ident = False
            notes.append(
                f"offset known only to +-{0.5 * (rep_off_ci[1] - rep_off_ci[0]):.2f} m/s^2"
            )
    sc, sc_ci, sc_ok = _zone_scale(i, fits, zones, cfg, path, notes)
    br, br_ci, br_ok = _zone_brake_scale(i, fits, zones, cfg, has_brake, notes)
    ident = ident and sc_ok and br_ok
    dis = (disagreements or {}).get("zones", {}).get(zname)
    if dis and dis["disagree"]:
        if dis["corroborated_by"]:
            notes.append(
                f"{', '.join(dis['disagree'])} disagree(s) with {dis['chosen']} beyond "
                f"the intervals ({dis['likely_cause']}); {dis['chosen']} is "
                f"corroborated by {', '.join(dis['corroborated_by'])}"
            )
        else:
            ident = False
            notes.append(
                f"NOT identifiable: the acceleration sources disagree beyond their "
                f"intervals ({dis['chosen']} against {', '.join(dis['disagree'])}; "
                f"likely cause: {dis['likely_cause']})"
            )
    note = "; ".join(notes) if notes else None
    z = Zone(
        name=zname,
        v_min_mps=float(lo),
        v_max_mps=float(hi),
        offset_mps2=float(off),
        scale_mps2=float(sc),
        brake_scale_mps2=float(br),
        offset_ci95_mps2=_pair(rep_off_ci),
        scale_ci95_mps2=_pair(sc_ci),
        brake_scale_ci95_mps2=_pair(br_ci),
        nmse_pct=_opt(rep.get("nmse_pct")),
        speed_rmse_mps=_opt(rep.get("speed_rmse_mps")),
        samples=float(rep["samples"]),
        identifiable=bool(ident),
        note=note,
    )
    f.zone = z
    rep["identifiable"] = bool(ident)
    rep["note"] = note
    rep["written"] = {
        "offset_mps2": z.offset_mps2,
        "scale_mps2": z.scale_mps2,
        "brake_scale_mps2": z.brake_scale_mps2,
    }
    return z


def braking_evidence(
    sig: LongitudinalSignals, masks: ZoneMasks, zi: int, f: ZoneFit, cfg: LongitudinalIdConfig
) -> dict:
    """Seconds in zone ``zi`` with the accelerator released and a deceleration more than
    ``braking_evidence_mps2`` below the zone's fitted offset (coasting): braking that eq. 8
    must explain, observed or not."""
    m = ~masks.bad & (masks.zid == zi) & (np.nan_to_num(sig.ap_raw) < cfg.pressed)
    off = f.report["offset_mps2"]
    decel = m & (sig.a_meas < off - cfg.braking_evidence_mps2)
    return {
        "released_s": float(m.sum() * sig.dt_s),
        "decel_beyond_coasting_s": float(decel.sum() * sig.dt_s),
        "threshold_mps2": cfg.braking_evidence_mps2,
    }


def _zone_scale(
    i: int, fits: list[ZoneFit], zones, cfg: LongitudinalIdConfig, path, notes: list[str]
):
    """Zone ``i``'s throttle scale, its interval and whether it is identified; a zone that did
    not fit it copies the nearest zone's. Appends the reason to ``notes``."""
    f = fits[i]
    rep = f.report
    sc = rep.get("scale_mps2") if f.fitted else None
    sc_ci = rep.get("scale_ci95_mps2") if f.fitted else None
    if sc is None:
        j = _nearest_fitted(i, fits, "scale_mps2")
        if j is None:
            neg = next(
                (w for g in fits if g.fitted for w in [_negative_why(g.report, "scale_mps2")] if w),
                None,
            )
            raise InputError(
                (
                    f"no zone has a usable accelerator gain ({neg})"
                    if neg
                    else "the accelerator pedal is never pressed long enough in any zone "
                    f"(need {cfg.min_pressed_s} s)"
                )
                + ": cannot identify eq. 8",
                path,
                channel="accel_pedal",
            )
        sc = fits[j].report["scale_mps2"]
        why = (
            _negative_why(rep, "scale_mps2")
            or f"accelerator pressed only {rep['accel_pedal_pressed_s']:.1f} s "
            f"({cfg.min_pressed_s:g} s needed)"
            if f.fitted
            else rep["not_fitted_because"]
        )
        rep["not_identified"]["scale_mps2"] = f"{why}: copied from zone '{zones[j][0]}'"
        notes.append(
            f"{why}: scale copied from zone '{zones[j][0]}'"
            if f.fitted
            else f"scale copied from zone '{zones[j][0]}'"
        )
        return sc, sc_ci, False
    if _rel_half_width(sc, sc_ci) > cfg.max_rel_ci:
        notes.append(
            f"scale known only to +-{100 * _rel_half_width(sc, sc_ci):.0f}%"
            if sc != 0
            else "scale is zero"
        )
        return sc, sc_ci, False
    return sc, sc_ci, True


def _zone_brake_scale(
    i: int, fits: list[ZoneFit], zones, cfg: LongitudinalIdConfig, has_brake: bool, notes: list[str]
):
    """Zone ``i``'s brake scale, its interval and whether it is identified; a zone that did not
    fit it copies the nearest zone's, or the prior when none did. Appends the reason to
    ``notes``."""
    f = fits[i]
    rep = f.report
    br = rep.get("brake_scale_mps2") if f.fitted else None
    br_ci = rep.get("brake_scale_ci95_mps2") if f.fitted else None
    if br is None:
        j = _nearest_fitted(i, fits, "brake_scale_mps2")
        why = (
            "no brake_pedal channel"
            if not has_brake
            else _negative_why(rep, "brake_scale_mps2")
            or f"brake pressed only {rep['brake_pedal_pressed_s']:.1f} s"
            if f.fitted
            else rep["not_fitted_because"]
        )
        ni = rep["not_identified"]
        ev = rep.get("braking") or {}
        if ev.get("decel_beyond_coasting_s", 0.0) >= cfg.min_pressed_s:
            absorbed = (
                f"the car decelerated {ev['decel_beyond_coasting_s']:.1f} s more than "
                f"{ev['threshold_mps2']:g} m/s^2 below coasting with the accelerator "
                "released: braking (pedal or ACC) that no channel observes, which the "
                "offset and scale absorb"
            )
            ni["offset_mps2"] = ni["scale_mps2"] = f"{why}: {absorbed}"
            why = f"{why}, yet {absorbed}"
        if j is not None:
            br = fits[j].report["brake_scale_mps2"]
            ni["brake_scale_mps2"] = f"{why}: copied from zone '{zones[j][0]}'"
            notes.append(
                f"{why + ': ' if f.fitted else ''}brake scale copied from zone '{zones[j][0]}'"
            )
        else:
            br = cfg.brake_scale_prior_mps2
            ni["brake_scale_mps2"] = (
                f"{why}; no zone identified it: the prior {cfg.brake_scale_prior_mps2:g} m/s^2"
            )
            notes.append(
                f"{why + ' (in every zone): ' if f.fitted else ''}brake scale is the "
                f"prior {cfg.brake_scale_prior_mps2:g} m/s^2, not identified"
                + ("" if f.fitted else " in any zone")
            )
        return br, br_ci, False
    if _rel_half_width(br, br_ci) > cfg.max_rel_ci:
        notes.append(
            f"brake scale known only to +-{100 * _rel_half_width(br, br_ci):.0f}%"
            if br != 0
            else "brake scale is zero"
        )
        return br, br_ci, False
    return br, br_ci, True
