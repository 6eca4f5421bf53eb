"""Where the fits of eq. 7 contradict each other or the sign convention, and the named physics
that reconciles two of them.

**Sign** (:func:`negative_gains`): a left turn has a positive steering-wheel angle, road-wheel
angle and yaw rate (CONVENTIONS), so the scale is positive; a fit with a scale <= 0 is never a
model value. It points at the channel whose sign convention is reversed (every fit negative:
the steering-wheel angle; one fit: its own channel), or at a recording that does not determine
the gain (its interval does not exclude 0, e.g. a channel that reads 0 throughout).

**The two sensors** (:func:`sensor_comparison`): the wheel-speed difference (a) and the yaw
rate (b) are independent sensors of one road-wheel angle; their difference is judged against
its own 95% interval (the two fits' half-widths in quadrature). Named physics separates them
(catalogue id ``wheel_speed_scale``): (a) is ``b (fr - fl) / (T v)``, so it is rho times the
road-wheel angle, rho = effective track width / the geometry's T (the tyres' contact patches
move under load), offset and scale alike, while the gyro does not depend on the track; a
per-side rolling-radius difference (right / left wheel-speed ratio 1 + eps) adds ``(b / T)
eps``, an offset. A disagreement by the factor rho alone is what an effective track width
other than the geometry's predicts: the yaw-rate fit is used and the implied track is named
(``reconciled_by: wheel_speed_scale``). An offset left over is a per-side radius difference or
the gyro's bias, which this recording does not tell apart: NOT identifiable. A scale
difference within the noise but above ``sensor_scale_material_rel`` leaves the wheel-speed
scale NOT identifiable (which sensor is right is not known).

**Disagreements** (:func:`disagreement`): every pair of trusted fits whose offset or scale
differ beyond the difference's 95% interval widened by twice ``agree_offset_rad`` /
``agree_scale_rel`` (immaterial differences), with the likely cause.

Imports the steering package's config and fits; nothing else of hmpc.
"""

from __future__ import annotations

import math

from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.fits import MapFit

#: how a person is told each verdict of :func:`sensor_comparison` other than "agree"
SENSOR_HEADLINE = {
    "reconciled": "SENSORS DISAGREE",
    "offset": "SENSORS DISAGREE",
    "unresolved": "SENSORS DIFFER (within their noise)",
}
#: the channel each fit's road-wheel angle comes from, named when its sign looks reversed
SIGN_CHANNEL = {
    "wheel_speed_difference": "the wheel speeds (left and right swapped?)",
    "yaw_rate": "yaw_rate (left turn positive)",
    "position_replay": "heading / x, y (ENU, heading from east counter-clockwise)",
}


def negative_gains(fits: dict[str, MapFit]) -> dict[str, str]:
    """Fits whose scale is <= 0, each with the reason (module doc); {} when none is."""
    bad = {k: f for k, f in fits.items() if not f.scale > 0}
    if not bad:
        return {}
    negative = {k for k, f in bad.items() if f.scale < 0 and f.scale_ci95[1] < 0}
    every = len(negative) == len(fits)
    out = {}
    for k, f in bad.items():
        lo, hi = f.scale_ci95
        if k not in negative:
            out[k] = (
                f"gain not determined: scale {f.scale:.4g}, its 95% interval "
                f"[{lo:.4g}, {hi:.4g}] does not exclude 0 (too little steering, or a "
                "channel that does not move)"
            )
            continue
        channel = "steering_wheel_angle (left turn positive)" if every else SIGN_CHANNEL[k]
        out[k] = (
            f"negative gain {f.scale:.4g} [{lo:.4g}, {hi:.4g}]: the road-wheel angle falls "
            f"as the steering-wheel angle rises; check the sign convention of {channel}"
        )
    return out


def _ratio_ci(fa: MapFit, fb: MapFit) -> tuple[float, float, float]:
    """scale_a / scale_b and its 95% interval (relative half-widths in quadrature)."""
    rho = fa.scale / fb.scale
    rel = math.hypot(
        0.5 * (fa.scale_ci95[1] - fa.scale_ci95[0]) / fa.scale,
        0.5 * (fb.scale_ci95[1] - fb.scale_ci95[0]) / fb.scale,
    )
    return rho, rho * (1.0 - rel), rho * (1.0 + rel)


def _half(ci) -> float:
    return 0.5 * (ci[1] - ci[0])


def sensor_comparison(
    fits: dict[str, MapFit], b_m: float, track_m: float, cfg: SteeringIdConfig
) -> dict | None:
    """The wheel-speed (a) and yaw-rate (b) fits compared (module doc); None unless both are
    fitted, trusted and positive.

    An effective track width T_eff makes (a) = rho (b) + c with rho = T_eff / T (offset and
    scale alike), and a per-side radius difference eps adds c = (b / T) eps. So the scale ratio
    rho is tested against 1, and the offset left over, c = offset_a - rho offset_b, against 0,
    each beyond its 95% interval widened by twice the immaterial difference.

    Returns ``{"scale_ratio", "scale_ratio_ci95", "offset_residual_rad",
    "offset_residual_ci95_rad", "scale_disagrees", "offset_disagrees", "material", "verdict",
    "note", ...}`` with ``verdict`` one of "agree", "reconciled" (rho only: the yaw-rate fit
    is used; ``reconciled_by``, ``effective_track_m`` and its interval), "offset" (c: a
    per-side radius difference or the gyro's bias, not told apart: NOT identifiable) and
    "unresolved" (a material scale difference within the noise: the wheel-speed scale is NOT
    identifiable).
    """
    fa, fb = fits.get("wheel_speed_difference"), fits.get("yaw_rate")
    if (
        fa is None
        or fb is None
        or not all(f.extra.get("trusted", True) and f.scale > 0 for f in (fa, fb))
    ):
        return None
    rho, lo, hi = _ratio_ci(fa, fb)
    c = fa.offset_rad - rho * fb.offset_rad
    h_c = math.sqrt(
        _half(fa.offset_ci95_rad) ** 2
        + (rho * _half(fb.offset_ci95_rad)) ** 2
        + (fb.offset_rad * (hi - rho)) ** 2
    )
    scale_dis = abs(rho - 1.0) > (hi - rho) + 2.0 * cfg.agree_scale_rel
    off_dis = abs(c) > h_c + 2.0 * cfg.agree_offset_rad
    material = abs(rho - 1.0) > cfg.sensor_scale_material_rel
    eps, eps_h = track_m / b_m * c, track_m / b_m * h_c
    out = {
        "fits": ["wheel_speed_difference", "yaw_rate"],
        "scale_ratio": rho,
        "scale_ratio_ci95": [lo, hi],
        "offset_residual_rad": c,
        "offset_residual_ci95_rad": [c - h_c, c + h_c],
        "scale_disagrees": bool(scale_dis),
        "offset_disagrees": bool(off_dis),
        "material": bool(material),
        "material_threshold_rel": cfg.sensor_scale_material_rel,
        "physics": (
            "wheel_speed_scale: the wheel-speed angle is rho times the road-wheel "
            "angle, rho = effective track width / the geometry's, plus (b / T) eps "
            "for a right/left wheel-speed ratio 1 + eps (per-side rolling radius); "
            "the yaw rate depends on neither (but has a bias)"
        ),
    }
    pct = f"{100 * (rho - 1):+.1f}% (ratio {rho:.3f} [{lo:.3f}, {hi:.3f}])"
    if off_dis:
        out.update(
            verdict="offset",
            implied_side_ratio=1.0 + eps,
            implied_side_ratio_ci95=[1.0 + eps - eps_h, 1.0 + eps + eps_h],
        )
        out["note"] = (
            f"the wheel-speed and yaw-rate fits disagree on the offset by "
            f"{math.degrees(c):+.3f} deg [{math.degrees(c - h_c):+.3f}, "
            f"{math.degrees(c + h_c):+.3f}]"
            + (f" beyond their scale ratio {pct}" if scale_dis else "")
            + ": a right/left wheel-speed ratio of "
            f"{1 + eps:.4f} [{1 + eps - eps_h:.4f}, {1 + eps + eps_h:.4f}] (wheel_speed_scale: "
            "per-side rolling radius) or the yaw-rate sensor's bias; this recording does not "
            "tell them apart"
        )
    elif scale_dis:
        t_eff = track_m * rho
        out.update(
            verdict="reconciled",
            reconciled_by="wheel_speed_scale",
            effective_track_m=t_eff,
            effective_track_ci95_m=[track_m * lo, track_m * hi],
            use="yaw_rate",
        )
        out["note"] = (
            f"reconciled_by: wheel_speed_scale: the wheel-speed fit is the yaw-rate fit times "
            f"{rho:.3f} [{lo:.3f}, {hi:.3f}] (scale {100 * (rho - 1):+.1f}%, offset alike); the "
            f"wheel-speed angle scales with 1 / (effective track width), the yaw rate does "
            f"not, so the yaw-rate fit is used; implied effective track width {t_eff:.3f} m "
            f"[{track_m * lo:.3f}, {track_m * hi:.3f}] against the geometry's {track_m:g} m "
            "(tyre contact patches under load, or per-side rolling radii changing with the "
            "turn)"
        )
    elif material:
        out["verdict"] = "unresolved"
        out["note"] = (
            f"the wheel-speed and yaw-rate scales differ by {pct}: within their noise, but more "
            f"than {100 * cfg.sensor_scale_material_rel:g}%, and this recording cannot tell "
            "which sensor is right (wheel_speed_scale: the wheel-speed angle scales with 1 / "
            "effective track width; the yaw rate does not)"
        )
    else:
        out["verdict"] = "agree"
        out["note"] = f"the wheel-speed and yaw-rate fits agree (scale {pct})"
    return out


def disagreement(
    fits: dict[str, MapFit], cfg: SteeringIdConfig | None = None, explained: dict | None = None
) -> tuple[list[dict], str | None]:
    """Pairs of trusted fits whose offset or scale differ beyond the difference's 95% interval
    (half-widths in quadrature) widened by twice ``cfg.agree_offset_rad`` /
    ``cfg.agree_scale_rel``, and a note naming them and the likely cause (None when all
    agree). With ``explained`` (the :func:`sensor_comparison` of this recording), the pair of
    wheel-speed and yaw-rate fits is left to it, and when it reconciled them, the wheel-speed
    fit is set aside (scaled by the effective track width) and its other pairs left out too."""
    cfg = cfg or SteeringIdConfig()
    names = [
        k
        for k in ("wheel_speed_difference", "yaw_rate", "position_replay")
        if k in fits and fits[k].extra.get("trusted", True)
    ]
    reconciled = (explained or {}).get("verdict") == "reconciled"
    pairs: list[dict[str, list[str]]] = []
    for i, a in enumerate(names):
        for b_ in names[i + 1 :]:
            fa, fb = fits[a], fits[b_]
            tol_s = 0.5 * cfg.agree_scale_rel * (abs(fa.scale) + abs(fb.scale))
            what = [
                q
                for q, (va, vb, ia, ib), tol in (
                    ("scale", (fa.scale, fb.scale, fa.scale_ci95, fb.scale_ci95), tol_s),
                    (
                        "offset",
                        (fa.offset_rad, fb.offset_rad, fa.offset_ci95_rad, fb.offset_ci95_rad),
                        cfg.agree_offset_rad,
                    ),
                )
                if abs(va - vb) > math.hypot(_half(ia), _half(ib)) + 2.0 * tol
            ]
            if explained is not None and {a, b_} == {"wheel_speed_difference", "yaw_rate"}:
                continue
            if reconciled and "wheel_speed_difference" in (a, b_):
                continue  # set aside: scaled by the effective track (wheel_speed_scale)
            if what:
                pairs.append({"fits": [a, b_], "quantities": what})
    if not pairs:
        return [], None
    causes = []
    for p in pairs:
        if "position_replay" in p["fits"]:
            c = "the position's reference point (vehicle.nav_lever_arm_m) or the heading's mount"
        elif "scale" in p["quantities"]:
            c = (
                "wheel_speed_scale: an effective track width other than the geometry's "
                "(the wheel-speed angle scales with 1 / track width, the yaw rate does not)"
            )
        else:
            c = (
                "wheel_speed_scale (a per-side rolling-radius difference) or the yaw-rate "
                "sensor's bias"
            )
        causes.append(
            f"{' and '.join(p['fits'])} disagree on {' and '.join(p['quantities'])} "
            f"beyond their 95% intervals (likely cause: {c})"
        )
    return pairs, "; ".join(causes)
