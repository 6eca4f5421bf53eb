"""Locate a mismatch: noise floors, residual windows above them, change points, and the
residual by regime (speed zone, pedal, brake, steering magnitude, lateral acceleration,
distance travelled, altitude change).
"""

from __future__ import annotations

import numpy as np

from hmpc.models.diagnose.common import merge_windows, rmse, windows


def noise_floor(x: np.ndarray) -> float:
    """White-noise standard deviation of a sampled signal from its first differences
    (robust: 1.4826 MAD / sqrt 2); a smooth signal contributes almost nothing to them.

    A held or quantised signal (a CAN value repeated on a faster grid: 74 % of the VerifiedCAN
    yaw rate's differences are exactly 0) would read 0; its floor is taken from the
    differences where it changed, about its quantisation step."""
    d = np.diff(np.asarray(x, float))
    d = d[np.isfinite(d)]
    if len(d) < 10:
        return float("nan")
    if np.mean(d == 0.0) >= 0.5 and np.count_nonzero(d) >= 10:
        d = d[d != 0.0]
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def window_rms(err: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """(index matrix, rms per window) of windows tiling the finite runs of ``err``."""
    idx = windows(np.isfinite(err), length)
    if idx.size == 0:
        return idx, np.zeros(0)
    return idx, np.sqrt(np.mean(err[idx] ** 2, axis=1))


def elevated_windows(t, err, length: int, floor: float, factor: float = 3.0) -> dict:
    """Windows whose residual RMS exceeds ``factor`` times the larger of the noise floor and
    the median window RMS, merged into [t0, t1] intervals, with their share of the error."""
    idx, w = window_rms(err, length)
    if idx.size == 0:
        return {"windows": [], "share_of_error": 0.0, "threshold": float("nan")}
    thr = factor * max(floor if np.isfinite(floor) else 0.0, float(np.median(w)))
    flags = w > thr
    sq = w**2
    share = float(sq[flags].sum() / sq.sum()) if sq.sum() > 0 else 0.0
    return {"windows": merge_windows(t, flags, idx), "share_of_error": share, "threshold": thr}


def change_point(t, err, length: int) -> dict | None:
    """The single split of the window-RMS series that best separates two levels (log RMS);
    reported when the two levels differ by more than a factor of 2."""
    idx, w = window_rms(err, length)
    if len(w) < 6:
        return None
    lw = np.log(np.maximum(w, 0.05 * np.median(w) + 1e-12))  # a window at rest has ~0 error
    best, k_best = 0.0, None
    for k in range(2, len(w) - 2):
        d = abs(lw[:k].mean() - lw[k:].mean())
        if d > best:
            best, k_best = d, k
    if k_best is None or np.exp(best) < 2.0:
        return None
    return {
        "t_s": round(float(t[idx[k_best, 0]]), 3),
        "rms_ratio": float(np.exp(best)),
        "rms_before": float(np.sqrt(np.mean(w[:k_best] ** 2))),
        "rms_after": float(np.sqrt(np.mean(w[k_best:] ** 2))),
    }


def regime_variables(ch: dict, zones) -> dict[str, tuple[np.ndarray, list[str]]]:
    """Per-sample regime labels: name -> (bin index per sample (-1 unknown), bin names)."""
    n = len(ch["time"])
    out = {}
    v = np.asarray(ch.get("speed", np.full(n, np.nan)), float)
    if zones:
        vmax = np.array([z[2] for z in zones])
        zi = np.minimum(np.searchsorted(vmax, np.nan_to_num(v), side="left"), len(zones))
        names = [z[0] for z in zones] + ["above last zone"]
        out["speed zone"] = (np.where(np.isfinite(v), zi, -1), names)
    if "accel_pedal" in ch:
        ap = np.asarray(ch["accel_pedal"], float)
        b = np.where(~np.isfinite(ap), -1, np.where(ap < 0.01, 0, np.where(ap <= 0.2, 1, 2)))
        out["accel pedal"] = (b, ["released", "0.01-0.2", "> 0.2"])
    if "brake_pedal" in ch and np.isfinite(ch["brake_pedal"]).any():
        bp = np.asarray(ch["brake_pedal"], float)
        out["brake"] = (np.where(~np.isfinite(bp), -1, (bp > 0.01).astype(int)), ["off", "on"])
    if "accel_cmd" in ch and np.isfinite(ch["accel_cmd"]).any():
        c = np.asarray(ch["accel_cmd"], float)
        out["accel command"] = (
            np.where(~np.isfinite(c), -1, np.digitize(c, [-0.5, 0.5])),
            ["< -0.5 m/s^2", "-0.5..0.5 m/s^2", "> 0.5 m/s^2"],
        )
    if "steering_wheel_angle" in ch:
        s = np.abs(np.asarray(ch["steering_wheel_angle"], float))
        out["steering magnitude"] = (
            np.where(~np.isfinite(s), -1, np.digitize(s, [0.5, 2.0])),
            ["< 0.5 rad", "0.5-2 rad", "> 2 rad"],
        )
    if "yaw_rate" in ch:
        ay = np.abs(v * np.asarray(ch["yaw_rate"], float))
        out["lateral acceleration"] = (
            np.where(~np.isfinite(ay), -1, np.digitize(ay, [1.0, 3.0])),
            ["< 1 m/s^2", "1-3 m/s^2", "> 3 m/s^2"],
        )
    dt = float(np.median(np.diff(ch["time"])))
    dist = np.cumsum(np.nan_to_num(v) * dt)
    if dist[-1] > 0:
        q = np.quantile(dist, [0.25, 0.5, 0.75])
        out["distance travelled"] = (
            np.digitize(dist, q),
            [
                f"< {q[0]:.0f} m",
                f"{q[0]:.0f}-{q[1]:.0f} m",
                f"{q[1]:.0f}-{q[2]:.0f} m",
                f"> {q[2]:.0f} m",
            ],
        )
    if "z" in ch and np.isfinite(ch["z"]).mean() > 0.5:
        from hmpc.models.identify.stats import savgol_derivative

        dz = savgol_derivative(np.asarray(ch["z"], float), dt, 3.0)
        grade = dz / np.maximum(np.nan_to_num(v), 1.0)
        out["altitude change"] = (
            np.where(~np.isfinite(grade), -1, np.digitize(grade, [-0.01, 0.01])),
            ["downhill (< -1 %)", "level", "uphill (> 1 %)"],
        )
    return out


def regime_table(
    regimes: dict, before: np.ndarray, after: np.ndarray | None = None, min_samples: int = 100
) -> list[dict]:
    """RMS of the residual per regime bin (before and, if given, after)."""
    rows = []
    for name, (b, labels) in regimes.items():
        for i, lab in enumerate(labels):
            sel = (b == i) & np.isfinite(before)
            if after is not None:
                sel &= np.isfinite(after)
            if sel.sum() < min_samples:
                continue
            row = {
                "variable": name,
                "bin": lab,
                "samples": int(sel.sum()),
                "rmse_before": rmse(before[sel]),
            }
            if after is not None:
                row["rmse_after"] = rmse(after[sel])
            rows.append(row)
    return rows


def top_regimes(rows: list[dict], k: int = 3) -> list[dict]:
    """The bins where the extension lowers the residual most (absolute RMS reduction)."""
    scored = [r for r in rows if "rmse_after" in r]
    scored.sort(key=lambda r: r["rmse_before"] - r["rmse_after"], reverse=True)
    return scored[:k]


def improved_windows(t, before, after, length: int, min_reduction: float = 0.3) -> list:
    """Windows where the residual RMS falls by ``min_reduction`` or more and was above the
    median window RMS before, merged into [t0, t1]."""
    both = np.where(np.isfinite(after), before, np.nan)
    idx = windows(np.isfinite(both), length)
    if idx.size == 0:
        return []
    wb = np.sqrt(np.mean(before[idx] ** 2, axis=1))
    wa = np.sqrt(np.mean(after[idx] ** 2, axis=1))
    flags = (wb > np.median(wb)) & (wa <= (1.0 - min_reduction) * wb)
    return merge_windows(t, flags, idx)
