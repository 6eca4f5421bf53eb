"""Whether a fit of eq. 7 separates offset from scale (:func:`identifiability`).

The estimate is called identifiable only when enough trustworthy samples exist, the
steering-wheel range is wide enough, offset and scale are not too correlated, their intervals
are narrow, and some steering happened at speeds where the kinematic (no side-slip) assumption
holds. Otherwise ``identifiable`` is False and the note says plainly what the recording cannot
separate. Understeer (:func:`understeer_testability`) is named only as far as the recording
excites it: with no lateral acceleration, or steering at one speed only, it is not testable.
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.fits import MapFit


def identifiability(
    fit: MapFit,
    sw_steady: np.ndarray,
    v_steady: np.ndarray,
    dt_s: float,
    cfg: SteeringIdConfig,
    steering_ratio: float | None = None,
    road_wheel_min_range_rad: float | None = None,
) -> dict:
    """Checks that decide whether a recording separates offset from scale (module doc).

    With ``road_wheel_min_range_rad`` (a steering-command input, whose unit may be a
    road-wheel angle) the range check is on the road-wheel range ``|scale| * input range``
    against it, instead of the steering-wheel range against ``min_sw_range_rad``.

    Returns ``{"identifiable", "offset_identifiable", "scale_identifiable", "checks": [...],
    "note"}``; each check has name, value, threshold, passed.
    """
    checks = []

    def add(name, value, threshold, passed, text):
        checks.append(
            {
                "name": name,
                "value": float(value),
                "threshold": float(threshold),
                "passed": bool(passed),
                "text": text,
            }
        )

    n = len(sw_steady)
    need = int(math.ceil(cfg.min_trustworthy_s / dt_s - 1e-9))
    add(
        "samples",
        n,
        need,
        n >= need,
        f"{n} trustworthy samples ({n * dt_s:.1f} s; need {cfg.min_trustworthy_s:g} s)",
    )
    rng = float(np.subtract(*np.percentile(sw_steady, [97.5, 2.5]))) if n else 0.0
    what = "steering-wheel"
    if road_wheel_min_range_rad is None:
        add(
            "steering_range_rad",
            rng,
            cfg.min_sw_range_rad,
            rng >= cfg.min_sw_range_rad,
            f"steering-wheel range {np.degrees(rng):.1f} deg (2.5-97.5%; need "
            f"{np.degrees(cfg.min_sw_range_rad):.0f} deg)",
        )
    else:
        rng, what = rng * abs(fit.scale), "road-wheel"
        add(
            "steering_range_rad",
            rng,
            road_wheel_min_range_rad,
            rng >= road_wheel_min_range_rad,
            f"road-wheel range {np.degrees(rng):.1f} deg (|scale| x the command's 2.5-97.5% "
            f"range; need {np.degrees(road_wheel_min_range_rad):.1f} deg)",
        )
    add(
        "offset_scale_correlation",
        abs(fit.corr),
        cfg.max_param_corr,
        abs(fit.corr) <= cfg.max_param_corr,
        f"|corr(offset, scale)| = {abs(fit.corr):.3f}",
    )
    half_s = 0.5 * (fit.scale_ci95[1] - fit.scale_ci95[0])
    rel = half_s / abs(fit.scale) if fit.scale != 0 else float("inf")
    add(
        "scale_rel_ci95",
        rel,
        cfg.max_scale_rel_ci,
        rel <= cfg.max_scale_rel_ci,
        f"scale 95% interval +-{100 * rel:.1f}% (need <= {100 * cfg.max_scale_rel_ci:.0f}%)",
    )
    half_o = 0.5 * (fit.offset_ci95_rad[1] - fit.offset_ci95_rad[0])
    add(
        "offset_ci95_rad",
        half_o,
        cfg.max_offset_ci_rad,
        half_o <= cfg.max_offset_ci_rad,
        f"offset 95% interval +-{np.degrees(half_o):.3f} deg (need <= "
        f"{np.degrees(cfg.max_offset_ci_rad):.2f} deg)",
    )
    slow_s = float(np.sum(v_steady <= cfg.kinematic_speed_mps) * dt_s)
    add(
        "kinematic_speed_s",
        slow_s,
        cfg.min_kinematic_s,
        slow_s >= cfg.min_kinematic_s,
        f"{slow_s:.1f} s of trustworthy steering at or below {cfg.kinematic_speed_mps:g} m/s "
        f"(need {cfg.min_kinematic_s:g} s)",
    )
    # the gyro-bias check applies only to a fit that estimates a yaw-rate bias (the yaw-rate
    # fit); for the others it is not run, and not counted, by name below
    bias_corr = fit.extra.get("offset_bias_correlation")
    bias_applies = bias_corr is not None
    if bias_corr is not None:
        add(
            "offset_gyro_bias_correlation",
            abs(bias_corr),
            cfg.max_param_corr,
            abs(bias_corr) <= cfg.max_param_corr,
            f"|corr(offset, yaw-rate bias)| = {abs(bias_corr):.3f}",
        )
    # every check that applies is looked up by name: one that was not run raises KeyError,
    # it never counts as passed
    ok = {c["name"]: c["passed"] for c in checks}
    bias_ok = ok["offset_gyro_bias_correlation"] if bias_applies else True
    base = ok["samples"] and ok["steering_range_rad"] and ok["offset_scale_correlation"]
    scale_ok = base and ok["scale_rel_ci95"] and ok["kinematic_speed_s"]
    offset_ok = base and ok["offset_ci95_rad"] and bias_ok
    notes = []
    if not ok["samples"]:
        notes.append("too few trustworthy samples")
    if not ok["steering_range_rad"]:
        notes.append(
            f"the {what} range ({np.degrees(rng):.1f} deg) is too small to "
            "separate the offset from sensor biases (tyre radius mismatch, gyro bias, "
            "angle-sensor zero) or the scale from noise"
        )
    if not ok["offset_scale_correlation"]:
        notes.append(
            "offset and scale estimates are strongly correlated (steering mostly to one side)"
        )
    if not ok["scale_rel_ci95"]:
        notes.append(f"the scale is known only to +-{100 * rel:.0f}%")
    if not ok["offset_ci95_rad"]:
        notes.append(f"the offset is known only to +-{np.degrees(half_o):.3f} deg")
    if not bias_ok:
        # the offset's yaw rate is v tan(offset)/b, the bias a constant: only the spread of
        # the speeds tells them apart; say which speeds there were and what that left
        assert bias_corr is not None  # bias_ok is False only when the check ran
        vs = np.asarray(v_steady, dtype=float)
        vs = vs[np.isfinite(vs)]
        span = (
            f"{np.percentile(vs, 2.5):.1f}-{np.percentile(vs, 97.5):.1f} m/s, " if vs.size else ""
        )
        notes.append(
            "the speed range is too narrow to separate the offset from the yaw-rate "
            f"sensor's bias ({span}|corr(offset, bias)| = {abs(bias_corr):.3f}: "
            f"offset +-{np.degrees(half_o):.3f} deg; arcs at other speeds separate them)"
        )
    if not ok["kinematic_speed_s"]:
        notes.append(_kinematic_note(v_steady, slow_s, cfg))
    if notes:
        note = "NOT identifiable: " + "; ".join(notes) + "."
        if steering_ratio:
            note += (
                f" For comparison, the maker's nominal 1/steering_ratio = "
                f"{1.0 / steering_ratio:.4f}."
            )
    else:
        note = "offset and scale identifiable from this recording"
    return {
        "identifiable": bool(scale_ok and offset_ok),
        "offset_identifiable": bool(offset_ok),
        "scale_identifiable": bool(scale_ok),
        "checks": checks,
        "note": note,
    }


def _kinematic_note(v_steady: np.ndarray, slow_s: float, cfg) -> str:
    """Why the kinematic-speed check failed, from the speeds it saw: all steering above the
    kinematic speed (understeer folded into the gain), or simply too little of it."""
    v = np.asarray(v_steady, dtype=float)
    v = v[np.isfinite(v)]
    if v.size and slow_s == 0.0:
        return (
            f"all trustworthy steering happened above {cfg.kinematic_speed_mps:g} m/s "
            f"({np.min(v):.1f}-{np.max(v):.1f} m/s), where tyre side slip (understeer) is "
            "folded into the kinematic gain"
        )
    span = f" (speeds {np.min(v):.1f}-{np.max(v):.1f} m/s)" if v.size else ""
    fast = (
        (
            f"; above {cfg.kinematic_speed_mps:g} m/s tyre side slip (understeer) is folded "
            "into the kinematic gain"
        )
        if v.size and np.max(v) > cfg.kinematic_speed_mps
        else ""
    )
    return (
        f"only {slow_s:.1f} s of trustworthy steering at or below "
        f"{cfg.kinematic_speed_mps:g} m/s{span}, {cfg.min_kinematic_s:g} s are needed{fast}"
    )


def understeer_testability(
    v_mps: np.ndarray, lat_accel_mps2: np.ndarray, cfg: SteeringIdConfig
) -> dict:
    """Whether the trustworthy samples (speeds ``v_mps`` [m/s], lateral accelerations
    ``lat_accel_mps2`` [m/s^2]) can test understeer at all: its angle K a_y needs lateral
    acceleration (``understeer_min_lat_accel_mps2``), and telling it from the scale needs the
    steered samples at different speeds (``understeer_min_speed_sq_ratio``); on a straight line
    neither holds. Nothing is claimed about understeer, separable or not, unless both hold.

    Returns ``{"testable", "lat_accel_p97_5_mps2", "speed_sq_ratio", "steered_s"?, "note"}``.
    """
    v = np.asarray(v_mps, dtype=float)
    ay = np.abs(np.asarray(lat_accel_mps2, dtype=float))
    ok = np.isfinite(v) & np.isfinite(ay)
    v, ay = v[ok], ay[ok]
    a97 = float(np.percentile(ay, 97.5)) if ay.size else 0.0
    steered = ay > 0.25 * cfg.understeer_min_lat_accel_mps2
    if steered.sum() >= 2:
        v10, v90 = np.percentile(v[steered], [10, 90])
        ratio = float((v90 / v10) ** 2) if v10 > 0 else float("inf")
    else:
        v10 = v90 = ratio = float("nan")
    lat_ok = a97 >= cfg.understeer_min_lat_accel_mps2
    speed_ok = ratio >= cfg.understeer_min_speed_sq_ratio
    if not lat_ok:
        note = (
            f"understeer not testable on this recording: the lateral acceleration reaches "
            f"{a97:.2f} m/s^2 (97.5th percentile; {cfg.understeer_min_lat_accel_mps2:g} "
            "m/s^2 needed), and understeer acts only through it"
        )
    elif not speed_ok:
        note = (
            f"understeer not testable on this recording: the steering happened at "
            f"{v10:.1f}-{v90:.1f} m/s ((v_high/v_low)^2 = {ratio:.2f}, "
            f"{cfg.understeer_min_speed_sq_ratio:g} needed); at one speed understeer is a "
            "constant factor on the gain, not separable from the scale"
        )
    else:
        note = (
            f"understeer testable: lateral acceleration up to {a97:.2f} m/s^2, steering at "
            f"{v10:.1f}-{v90:.1f} m/s (hmpc diagnose tests it)"
        )
    return {
        "testable": bool(lat_ok and speed_ok),
        "lat_accel_p97_5_mps2": a97,
        "speed_sq_ratio": float(ratio) if np.isfinite(ratio) else None,
        "steered_speed_p10_p90_mps": [float(v10), float(v90)],
        "note": note,
    }
