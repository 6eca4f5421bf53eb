"""The zone rule of eq. 8: which speed zone's accelerator model holds at a speed.

Zone i holds the speeds in ``(v_min_i, v_max_i]``; zones are contiguous, so the first zone
takes every speed up to its ``v_max`` (0 included). Above the last zone and for NaN there is
no zone (-1); with ``clamp=True`` (the plant, the MPC) the last zone's model is used there
instead. With hysteresis h the current zone is kept while the speed is within
``[v_min - h, v_max + h]`` (the first zone has no lower edge; the last zone's upper edge is
its ``v_max``, or none with ``clamp``), and only then re-selected by speed, so noise on a
boundary cannot make it chatter.

The parameter file (``Params.zone_for``), the plant, the MPC, the estimator and
identification all select zones here. Imports numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def zone_of_speed(v_mps: float, v_max_mps: Sequence[float], *, clamp: bool = False) -> int:
    """Index of the zone whose ``(v_min, v_max]`` holds ``v_mps`` (see the module doc).

    Args:
        v_mps: speed [m/s].
        v_max_mps: upper bound of each zone, ascending [m/s] (zones are contiguous).
        clamp: above the last zone (and for NaN) return the last zone instead of -1.
    """
    for i, hi in enumerate(v_max_mps):
        if v_mps <= hi:
            return i
    return len(v_max_mps) - 1 if clamp else -1


def zones_of_speed(
    v_mps: np.ndarray, v_max_mps: Sequence[float], *, clamp: bool = False
) -> np.ndarray:
    """:func:`zone_of_speed` for an array of speeds (vectorised), as int64."""
    v = np.asarray(v_mps, dtype=float)
    vmax = np.asarray(v_max_mps, dtype=float)
    z = np.searchsorted(vmax, v, side="left")  # first i with v <= v_max[i]; NaN sorts last
    return np.where(z < len(vmax), z, len(vmax) - 1 if clamp else -1).astype(np.int64)


def zone_with_hysteresis(
    v_mps: float,
    current: int | None,
    v_min_mps: Sequence[float],
    v_max_mps: Sequence[float],
    hysteresis_mps: float,
    *,
    clamp: bool = False,
) -> int:
    """Zone with hysteresis: ``current`` while ``v_mps`` is within its band widened by
    ``hysteresis_mps`` [m/s], otherwise :func:`zone_of_speed`. ``current`` None or -1: no
    zone yet (by speed). A NaN speed leaves every band."""
    n = len(v_max_mps)
    if current is not None and 0 <= current < n:
        lo = -math.inf if current == 0 else v_min_mps[current] - hysteresis_mps
        if current < n - 1:
            hi = v_max_mps[current] + hysteresis_mps
        else:  # above the last zone there is no zone to hand over to
            hi = math.inf if clamp else v_max_mps[current]
        if lo <= v_mps <= hi:
            return current
    return zone_of_speed(v_mps, v_max_mps, clamp=clamp)


def zones_with_hysteresis(
    v_mps: np.ndarray,
    v_min_mps: Sequence[float],
    v_max_mps: Sequence[float],
    hysteresis_mps: float,
    *,
    start: int | None = None,
    clamp: bool = False,
) -> np.ndarray:
    """:func:`zone_with_hysteresis` along a speed sequence, each sample starting from the
    previous one's zone (the first from ``start``); int64 array, equal to that loop's.

    Each sample depends on the last, but the zone only changes where the speed leaves the
    current zone's band: one vectorised search per zone held (a horizon holds a few), not
    one Python call per sample."""
    n = len(v_max_mps)
    vmin = [float(x) for x in v_min_mps]
    vmax = [float(x) for x in v_max_mps]
    h = float(hysteresis_mps)
    v = np.asarray(v_mps, dtype=float).reshape(-1)
    by_speed = zones_of_speed(v, vmax, clamp=clamp)  # where the band is left (or no zone)
    out = np.empty(len(v), dtype=np.int64)
    cur, i = start, 0
    while i < len(v):
        if cur is None or not 0 <= cur < n:
            cur = int(by_speed[i])
            out[i] = cur
            i += 1
            continue
        # the band of zone_with_hysteresis; NaN is outside it
        lo = -math.inf if cur == 0 else vmin[cur] - h
        hi = vmax[cur] + h if cur < n - 1 else (math.inf if clamp else vmax[cur])
        seg = v[i:]
        left = np.flatnonzero(~((seg >= lo) & (seg <= hi)))
        j = int(left[0]) if len(left) else len(seg)
        out[i : i + j] = cur
        i += j
        if i < len(v):
            cur = int(by_speed[i])
            out[i] = cur
            i += 1
    return out
