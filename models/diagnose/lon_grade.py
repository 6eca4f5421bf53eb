"""The road grade a longitudinal hypothesis (``road_grade``) is fitted with: from the altitude
over the distance travelled, else the INS pitch."""

from __future__ import annotations

import numpy as np

from hmpc.models.diagnose.common import segments
from hmpc.models.identify.stats import savgol_derivative


def measured_grade(ch: dict, v: np.ndarray, dt: float) -> tuple[np.ndarray | None, str]:
    """Road grade [rad] from the altitude over the distance travelled, else the pitch."""
    z = ch.get("z")
    if z is not None and np.isfinite(z).mean() > 0.5 and np.nanstd(z) > 0.05:
        dz = savgol_derivative(np.asarray(z, float), dt, 3.0)
        vsm = savgol_derivative(v, dt, 3.0, deriv=0)
        g = np.where(vsm > 2.0, np.arcsin(np.clip(dz / np.maximum(vsm, 1e-3), -0.3, 0.3)), np.nan)
        # below 2 m/s dz/dt over 3 s is noise against a small ds/dt: there the grade is the
        # slope of the altitude against the distance travelled, over the 6 m that 3 s cover at
        # 2 m/s (the road's grade where the car is: a car creeping at 1 m/s for 20 s crosses
        # 20 m of road, whose grade a held last value does not follow)
        g_low = _grade_over_distance(np.asarray(z, float), v, dt, GRADE_LOW_SPEED_SPAN_M)
        g = np.where(np.isfinite(g) | ~(vsm <= 2.0), g, g_low)
        idx = np.flatnonzero(np.isfinite(g))
        if len(idx) > 10:
            g = np.interp(np.arange(len(g)), idx, g[idx])
            return g, (
                "altitude z over distance travelled (3 s Savitzky-Golay; below 2 m/s "
                f"the altitude's slope over {GRADE_LOW_SPEED_SPAN_M:g} m of distance)"
            )
    p = ch.get("pitch")
    if p is not None and np.isfinite(p).mean() > 0.5:
        return np.nan_to_num(np.asarray(p, float)), "INS pitch"
    return None, "none (no altitude or pitch channel)"


#: [m] distance span of the low-speed grade (3 s at the 2 m/s where the time estimate stops)
GRADE_LOW_SPEED_SPAN_M = 6.0
#: [m] distance bins in which the altitude is averaged for the low-speed grade
GRADE_BIN_M = 0.25


def _grade_over_distance(z: np.ndarray, v: np.ndarray, dt: float, span_m: float) -> np.ndarray:
    """Grade [rad] per sample: the least-squares slope of the altitude against the distance
    travelled (speed integrated) over ``span_m``, the altitude averaged per 0.25 m of distance
    (a car at rest adds samples to one bin, not a slope); per contiguous run of samples with
    both channels (a gap may join two drives whose altitudes share no origin)."""
    out = np.full(len(z), np.nan)
    for a, b in segments(np.isfinite(z) & np.isfinite(v), 2):
        out[a:b] = _grade_over_distance_run(z[a:b], v[a:b], dt, span_m)
    return out


def _grade_over_distance_run(z: np.ndarray, v: np.ndarray, dt: float, span_m: float) -> np.ndarray:
    s = np.cumsum(np.maximum(v, 0.0) * dt)
    b = (s / GRADE_BIN_M).astype(int)
    fin = np.isfinite(z)
    nb = int(b[-1]) + 1
    cnt = np.bincount(b[fin], minlength=nb)
    zs = np.bincount(b[fin], weights=z[fin], minlength=nb)
    have = np.flatnonzero(cnt > 0)
    if len(have) < 2:
        return np.full(len(z), np.nan)
    zb = np.interp(np.arange(nb), have, zs[have] / cnt[have])
    k = max(1, int(round(0.5 * span_m / GRADE_BIN_M)))
    x = np.arange(-k, k + 1) * GRADE_BIN_M
    w = x / np.sum(x * x)  # slope of a straight line over the span
    slope = np.convolve(np.pad(zb, k, mode="edge"), w[::-1], mode="valid")
    g = np.arcsin(np.clip(slope, -0.3, 0.3))
    if nb > 2 * k:  # ends: no full span (unless that is all)
        g[:k] = np.nan
        g[nb - k :] = np.nan
    return g[b]
