"""Clock alignment of CAN, nav (GNSS/INS) and IMU by cross-correlation.

Convention: an *offset* is what is added to a source's timestamps to put them on the reference
clock (the CAN log's clock, the time base of a recording): ``t_on_reference = t_source + offset_s``.
A nav file whose clock runs 0.2 s behind the CAN log has offset +0.2 s.

:func:`estimate_offset` finds the offset that maximises the normalised (Pearson) correlation of
two signals of the same quantity (CAN speed vs GNSS ground speed; IMU yaw rate vs nav or CAN yaw
rate): both are interpolated onto a common uniform grid, shifted by whole samples within
``+-max_lag_s``, and the peak is refined to sub-sample resolution by fitting a parabola through
the three best lags. ``derivative=True`` correlates time derivatives instead (a sharper peak
for slowly varying signals), but on the comma minute the accelerations from wheel speeds and
from the INS velocity disagree in their dynamics by ~0.2 s (flat correlation from -0.25 to
0 s), while raw speeds (-0.03 s) agree with the yaw-rate cross-check (CAN KINEMATICS vs the
device's IMU, +0.03 s); so speeds are correlated as they are by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OffsetEstimate:
    """A clock offset and how it was obtained.

    Attributes:
        offset_s: add to the source's timestamps to get the reference clock [s].
        peak: normalised correlation at the peak (-1..1; NaN when not estimated).
        samples: grid samples in the overlap used.
        method: "cross-correlation of <what>", "given", "same device as nav", "none".
        ok: True when estimated with a clear peak (above ``min_peak``, inside the window),
            or when given.
        note: why not ok, or other remarks.
    """

    offset_s: float
    peak: float = float("nan")
    samples: int = 0
    method: str = "given"
    ok: bool = True
    note: str = ""

    def to_dict(self) -> dict:
        return {
            "offset_s": float(self.offset_s),
            "correlation_peak": None if not np.isfinite(self.peak) else float(self.peak),
            "samples": int(self.samples),
            "method": self.method,
            "ok": bool(self.ok),
            "note": self.note,
        }


def _finite(t, v):
    t = np.asarray(t, float)
    v = np.asarray(v, float)
    m = np.isfinite(t) & np.isfinite(v)
    return t[m], v[m]


def estimate_offset(
    t_ref,
    v_ref,
    t_src,
    v_src,
    *,
    max_lag_s: float = 5.0,
    rate_hz: float = 50.0,
    derivative: bool = False,
    smooth_s: float = 0.2,
    min_peak: float = 0.5,
    what: str = "signals",
) -> OffsetEstimate:
    """Estimate the offset of a source clock relative to a reference clock.

    Args:
        t_ref: reference sample times (e.g. CAN speed's) [s].
        v_ref: reference samples [any unit].
        t_src: the source's sample times [s].
        v_src: the same quantity from the source to align (e.g. GNSS speed).
        max_lag_s: search window [s] (+-).
        rate_hz: grid rate of the correlation [Hz]; the result has sub-sample resolution.
        derivative: correlate the time derivatives (sharper peak for slowly varying signals).
        smooth_s: moving-average length applied before differentiating [s] (noise, quantisation).
        min_peak: correlation below this is reported as not ok.
        what: words for the method field.

    Returns:
        :class:`OffsetEstimate`; ``ok`` False (offset 0) when the signals do not overlap enough
        or do not vary.

    Raises:
        ValueError: non-positive ``rate_hz`` or ``max_lag_s``.
    """
    if not rate_hz > 0 or not max_lag_s > 0:
        raise ValueError("rate_hz and max_lag_s must be positive")
    method = f"cross-correlation of {what}" + (" (derivatives)" if derivative else "")
    tr, vr = _finite(t_ref, v_ref)
    ts, vs = _finite(t_src, v_src)
    if len(tr) < 4 or len(ts) < 4:
        return OffsetEstimate(0.0, float("nan"), 0, method, False, "too few samples")
    for v in (vr, vs):
        if np.ptp(v) <= 1e-9 * max(1.0, float(np.max(np.abs(v)))):
            return OffsetEstimate(0.0, float("nan"), 0, method, False, "a signal does not vary")
    dt = 1.0 / rate_hz
    k_max = int(np.ceil(max_lag_s * rate_hz))
    # reference grid over the reference span; the source is sampled on the same grid extended by
    # the search window, so every lag sees the same reference samples where the source exists
    t0 = max(tr[0], ts[0] - max_lag_s)
    t1 = min(tr[-1], ts[-1] + max_lag_s)
    n = int(np.floor((t1 - t0) * rate_hz)) + 1
    if n < 4 * (1 + int(smooth_s * rate_hz)):
        return OffsetEstimate(
            0.0, float("nan"), 0, method, False, "the two sources hardly overlap in time"
        )
    g = t0 + dt * np.arange(n)
    a = np.interp(g, tr, vr)
    ge = t0 + dt * np.arange(-k_max, n + k_max)
    b = np.interp(ge, ts, vs)
    b_ok = (ge >= ts[0]) & (ge <= ts[-1])
    w = max(1, int(round(smooth_s * rate_hz)))
    if w > 1:
        ker = np.ones(w) / w
        a = np.convolve(a, ker, mode="same")
        b = np.convolve(b, ker, mode="same")
    if derivative:
        a = np.gradient(a, dt)
        b = np.gradient(b, dt)
    # edges of the moving average/derivative are not trustworthy
    trim = w + 1
    a_ok = np.zeros(n, bool)
    a_ok[trim : n - trim] = True
    b_ok[:trim] = False
    b_ok[len(b_ok) - trim :] = False
    lags = np.arange(-k_max, k_max + 1)
    corr = np.full(len(lags), np.nan)
    counts = np.zeros(len(lags), int)
    for i, k in enumerate(lags):
        # source value at reference time g is the raw source sample at g - offset; offset = k*dt
        # -> source grid index (j - k) + k_max for reference index j
        lo = k_max - k
        bb = b[lo : lo + n]
        m = a_ok & b_ok[lo : lo + n]
        c = int(m.sum())
        counts[i] = c
        if c < 10:
            continue
        x = a[m] - a[m].mean()
        y = bb[m] - bb[m].mean()
        den = np.sqrt(np.dot(x, x) * np.dot(y, y))
        if den > 0:
            corr[i] = float(np.dot(x, y) / den)
    if not np.isfinite(corr).any():
        return OffsetEstimate(
            0.0, float("nan"), 0, method, False, "no overlap with variation in both signals"
        )
    i = int(np.nanargmax(corr))
    peak = float(corr[i])
    frac = 0.0
    if 0 < i < len(lags) - 1 and np.isfinite(corr[i - 1]) and np.isfinite(corr[i + 1]):
        y0, y1, y2 = corr[i - 1], corr[i], corr[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    offset = (lags[i] + frac) * dt
    ok, note = True, ""
    if i == 0 or i == len(lags) - 1:
        ok, note = False, f"peak at the edge of the +-{max_lag_s:g} s search window"
    elif peak < min_peak:
        ok, note = False, f"weak correlation peak {peak:.2f} < {min_peak:g}"
    return OffsetEstimate(float(offset), peak, int(counts[i]), method, ok, note)


def shift(t_s: np.ndarray, offset_s: float) -> np.ndarray:
    """Timestamps of a source on the reference clock."""
    return np.asarray(t_s, float) + float(offset_s)
