"""The gear at each sample, for the ``gears`` hypothesis: the recorded gear when the recording
holds a numeric one, else the ratio engine speed / wheel speed clustered into gears.

A locked driveline turns the engine at ``rpm = R_g * v`` in gear g (R_g [1/min per m/s]: the
gear's ratio times the final drive over the wheel's circumference); a histogram of log(rpm / v)
on moving samples has one peak per gear used. Samples away from every peak (a shift, a slipping
torque converter, the clutch open) take the gear of the nearest sample in time that has one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: [m/s] below this the ratio rpm / v is dominated by the idle speed and the speed's noise
GEAR_MIN_SPEED_MPS = 1.5
#: histogram bin of log(rpm / v): 1 %, finer than the 10-40 % steps between gears of a car
LOG_BIN = 0.01
#: a sample belongs to a peak within this log distance (4 %: a locked converter slips 1-3 %)
PEAK_HALF_WIDTH = 0.04
#: a gear is a peak holding at least this share of the moving samples (2 %: a gear used for
#: a few seconds of a ten-minute drive; shifts through a gear leave less)
MIN_GEAR_SHARE = 0.02


def _recorded_gears(ch: dict) -> np.ndarray | None:
    g = ch.get("gear")
    if g is None:
        return None
    num = np.full(len(g), -1, int)
    for i, x in enumerate(np.asarray(g, object)):
        s = str(x).strip()
        if s.isdigit() and 1 <= int(s) <= 9:
            num[i] = int(s)
    return num if (num > 0).any() else None


def _peaks(lr: np.ndarray) -> list[float]:
    """Centres of the histogram peaks of log ratios ``lr`` (module doc)."""
    lo, hi = float(lr.min()) - 2 * LOG_BIN, float(lr.max()) + 2 * LOG_BIN
    edges = np.arange(lo, hi + LOG_BIN, LOG_BIN)
    h, _ = np.histogram(lr, edges)
    hs = np.convolve(h, np.ones(3) / 3, mode="same")
    centres = 0.5 * (edges[1:] + edges[:-1])
    peaks: list[float] = []
    for i in np.argsort(-hs):
        if hs[i] * 3 < MIN_GEAR_SHARE * len(lr):
            break
        if all(abs(centres[i] - p) > 2 * PEAK_HALF_WIDTH for p in peaks):
            peaks.append(float(centres[i]))
    out = []
    for p in peaks:  # the peak's centre: the median of its samples
        near = lr[np.abs(lr - p) < PEAK_HALF_WIDTH]
        if len(near) >= MIN_GEAR_SHARE * len(lr):
            out.append(float(np.median(near)))
    return sorted(out, reverse=True)  # gear 1 (largest ratio) first


def _fill_nearest(g: np.ndarray) -> np.ndarray:
    known = np.flatnonzero(g >= 0)
    if known.size == 0:
        return g
    pos = (
        np.clip(np.searchsorted(known, np.arange(len(g))), 1, len(known) - 1)
        if len(known) > 1
        else np.zeros(len(g), int)
    )
    left, right = known[np.maximum(pos - 1, 0)], known[pos]
    pick = np.where(
        np.abs(np.arange(len(g)) - left) <= np.abs(right - np.arange(len(g))), left, right
    )
    return g[pick]


def gear_index(ch: dict, v: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray | None, dict]:
    """Per sample the gear's index 0..n-1 (None when fewer than two gears can be told) and a
    summary: ``n``, ``source``, the ratios [1/min per m/s] and samples per gear, or ``why``."""
    moving = ok & np.isfinite(v) & (v > GEAR_MIN_SPEED_MPS)
    rec = _recorded_gears(ch)
    if rec is not None:
        used = sorted(set(rec[moving & (rec > 0)].tolist()))
        if len(used) < 2:
            return None, {
                "n": 1,
                "why": f"the recorded gear takes {len(used)} value(s) while moving",
            }
        g = np.full(len(v), -1, int)
        for i, x in enumerate(used):
            g[rec == x] = i
        info: dict[str, Any] = {"source": "gear channel", "gears": [str(x) for x in used]}
    else:
        rpm = ch.get("engine_rpm")
        if rpm is None or not np.isfinite(np.asarray(rpm, float)).any():
            return None, {"n": 0, "why": "no engine_rpm or gear channel"}
        rpm = np.asarray(rpm, float)
        use = moving & np.isfinite(rpm) & (rpm > 0)
        if use.sum() < 100:
            return None, {"n": 0, "why": "too few moving samples with engine_rpm"}
        lr = np.log(rpm[use] / v[use])
        peaks = _peaks(lr)
        if len(peaks) < 2:
            return None, {
                "n": len(peaks),
                "why": f"the ratio engine_rpm / speed has {len(peaks)} cluster(s): one gear",
            }
        g = np.full(len(v), -1, int)
        full = np.full(len(v), np.nan)
        full[use] = lr
        dist = np.abs(full[:, None] - np.array(peaks)[None, :])
        near = np.nanmin(np.where(np.isfinite(dist), dist, np.inf), axis=1) < PEAK_HALF_WIDTH
        g[near] = np.argmin(np.where(np.isfinite(dist[near]), dist[near], np.inf), axis=1)
        info = {
            "source": "engine_rpm / speed clustered",
            "ratios_rpm_per_mps": [float(np.exp(p)) for p in peaks],
        }
        # the engine-braking regressor [1000 1/min] (``longitudinal.inputs``); where the
        # engine speed is missing, the median of the recording's (not zero)
        info["drag_krpm"] = np.where(np.isfinite(rpm), rpm, np.nanmedian(rpm)) / 1000.0
    n = int(g.max()) + 1
    info["assigned_share"] = float((g[moving] >= 0).mean()) if moving.any() else 0.0
    g = _fill_nearest(g)
    info["n"] = n
    info["samples"] = [int(((g == i) & moving).sum()) for i in range(n)]
    return g, info
