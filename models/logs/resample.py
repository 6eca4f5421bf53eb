"""Resample raw per-channel samples onto a recording's uniform time grid.

Kinds:

- ``linear``: linear interpolation (continuous quantities: angles of the steering wheel, speeds,
  rates, accelerations, positions);
- ``hold``: zero-order hold, the last sample at or before each grid time (pedals, gear: a held
  value; never invents values between samples);
- ``angle``: unwrapped, interpolated linearly, wrapped back to (-pi, pi] (``heading``);
- ``string``: zero-order hold of text values (``gear``), ``""`` where there is no value.

Gaps: wherever two consecutive raw samples are further apart than the channel's gap threshold
(``gap_s`` if given, else the larger of :data:`MIN_GAP_S` and :data:`GAP_PERIODS` times the
channel's median sample period), grid times strictly inside the gap are NaN (``""`` for text)
instead of interpolated, and the gap is listed. Grid times before the first or after the last
raw sample are NaN as well (no extrapolation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a gap is at least this long [s]: shorter dropouts are bridged (0.5 s is 25 samples at 50 Hz,
#: far longer than any bus-load jitter of a periodic CAN message).
MIN_GAP_S = 0.5
#: ... and at least this many median sample periods (a 1 Hz gear message is not "gappy").
GAP_PERIODS = 5.0
KINDS = ("linear", "hold", "angle", "string")


@dataclass(frozen=True)
class Gap:
    """An interval without samples that was not interpolated [s, recording clock]."""

    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def to_dict(self) -> dict:
        return {
            "start_s": float(self.start_s),
            "end_s": float(self.end_s),
            "duration_s": float(self.duration_s),
        }


def make_grid(t_start_s: float, t_end_s: float, rate_hz: float) -> np.ndarray:
    """Uniform grid ``t_start + k / rate`` covering [t_start, t_end] [s].

    Raises:
        ValueError: non-positive or non-finite rate, or t_end < t_start.
    """
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate must be a positive number of Hz, got {rate_hz!r}")
    if not (np.isfinite(t_start_s) and np.isfinite(t_end_s)) or t_end_s < t_start_s:
        raise ValueError("grid end precedes its start")
    n = int(np.floor((t_end_s - t_start_s) * rate_hz + 1e-9)) + 1
    return t_start_s + np.arange(n) / rate_hz


def gap_threshold_s(
    t_s: np.ndarray, gap_s: float | None = None, *, median_step_s: float | None = None
) -> float:
    """The gap threshold of a channel sampled at ``t_s`` (see module docstring) [s].
    ``median_step_s``: the median of ``t_s``'s positive steps when the caller has it."""
    if gap_s is not None:
        return float(gap_s)
    if median_step_s is None:
        d = np.diff(np.asarray(t_s, float))
        d = d[d > 0]
        median_step_s = float(np.median(d)) if len(d) else 0.0
    return max(MIN_GAP_S, GAP_PERIODS * median_step_s)


def find_gaps(t_s: np.ndarray, threshold_s: float) -> list[Gap]:
    """Intervals between consecutive samples longer than ``threshold_s``."""
    t = np.asarray(t_s, float)
    if len(t) < 2:
        return []
    i = np.flatnonzero(np.diff(t) > threshold_s)
    return [Gap(float(t[k]), float(t[k + 1])) for k in i]


def resample(
    t_s: np.ndarray,
    values: np.ndarray,
    grid_s: np.ndarray,
    kind: str = "linear",
    gap_s: float | None = None,
    *,
    threshold_s: float | None = None,
) -> tuple[np.ndarray, list[Gap]]:
    """Resample one channel onto ``grid_s``.

    Args:
        t_s: raw sample times [s] (any order; sorted here, stable).
        values: raw values (float; object/str for ``string``). Non-finite numeric samples are
            dropped before interpolating (the caller counts them).
        grid_s: uniform grid [s].
        kind: one of :data:`KINDS`.
        gap_s: gap threshold [s]; None for the default rule.
        threshold_s: ``gap_threshold_s(t_s, gap_s)`` when the caller has it already; used
            only when no sample is dropped or reordered here (else it is worked out anew).

    Returns:
        (values on the grid, gaps). Float64 with NaN where there is no value, or an object array
        with ``""`` for ``string``.

    Raises:
        ValueError: unknown kind, or t_s and values of different lengths.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown resampling kind {kind!r}; expected one of {', '.join(KINDS)}")
    t = np.asarray(t_s, float)
    grid = np.asarray(grid_s, float)
    if kind == "string":
        v = np.asarray(values, dtype=object)
        keep = np.isfinite(t) & np.array([isinstance(x, str) and x != "" for x in v], bool)
    else:
        v = np.asarray(values, dtype=float)
        keep = np.isfinite(t) & np.isfinite(v)
    if t.shape != v.shape:
        raise ValueError("times and values differ in length")
    if not keep.all():
        t, v = t[keep], v[keep]
        threshold_s = None
    if len(t) and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        threshold_s = None
    empty = (
        np.full(grid.shape, "", dtype=object) if kind == "string" else np.full(grid.shape, np.nan)
    )
    if len(t) == 0:
        return empty, []
    thr = gap_threshold_s(t, gap_s) if threshold_s is None else threshold_s
    gaps = find_gaps(t, thr)
    inside = (grid >= t[0]) & (grid <= t[-1])
    if kind in ("hold", "string"):
        idx = np.searchsorted(t, grid, side="right") - 1
        out = empty.copy()
        out[inside] = v[idx[inside]]
    elif kind == "angle":
        out = np.interp(grid, t, np.unwrap(v))
        out = np.mod(out + np.pi, 2 * np.pi) - np.pi
        out[out == -np.pi] = np.pi
        out[~inside] = np.nan
    else:
        if len(t) == 1:
            out = np.where(grid == t[0], v[0], np.nan)
        else:
            # duplicate times: np.interp needs increasing x; keep the last value of each time
            if np.any(np.diff(t) == 0):
                last = np.concatenate([np.diff(t) > 0, [True]])
                t, v = t[last], v[last]
            out = np.interp(grid, t, v)
            out[~inside] = np.nan
    if gaps:
        starts = np.array([g.start_s for g in gaps])
        ends = np.array([g.end_s for g in gaps])
        k = np.searchsorted(starts, grid, side="right") - 1
        in_gap = (k >= 0) & (grid > starts[np.maximum(k, 0)]) & (grid < ends[np.maximum(k, 0)])
        out[in_gap] = "" if kind == "string" else np.nan
    return out, gaps
