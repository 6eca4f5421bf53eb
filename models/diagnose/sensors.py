"""Sensor hypotheses: the CAN wheel speed against the GNSS/INS ground speed.

Baseline: ``speed(t) = gps_speed(t)`` (the CAN speed is the ground speed, both clocks agree).

- ``wheel_radius_error``: ``speed = k * gps_speed`` (the ECU's rolling radius is off by
  1/k), k in [0.9, 1.1] (tyre wear and pressure change the radius by a few per cent);
- ``sensor_time_offset``: ``speed(t) = gps_speed(t - c)``: the CAN clock runs ``c`` [s] ahead
  of the INS clock, c in [-1, 1] s.

Only straight driving is compared (road-wheel angle from the yaw rate under 0.02 rad): in a
turn the four wheels and the GNSS antenna move at different speeds (the rear wheels at
v cos(delta)), which is geometry, not a sensor error. Scores are the blocked held-out RMSE
of the speed difference [m/s].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hmpc.models.diagnose.common import (
    DiagnoseConfig,
    bic,
    profile_interval,
    rmse,
    segment_fold_ids,
    segments,
    train_mask,
)

HYPOTHESES = ("wheel_radius_error", "sensor_time_offset")
SCALE_BOUNDS = (0.9, 1.1)
OFFSET_MAX_S = 1.0


@dataclass
class SensorData:
    t: np.ndarray
    dt: float
    v: np.ndarray
    g: np.ndarray
    segs: list
    ok: np.ndarray
    straight: np.ndarray  #: driving straight (sensor comparison samples)


def prepare(
    ch: dict, wheelbase_m: float, cfg: DiagnoseConfig = DiagnoseConfig()
) -> SensorData | None:
    if "speed" not in ch or "gps_speed" not in ch:
        return None
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    v, g = np.asarray(ch["speed"], float), np.asarray(ch["gps_speed"], float)
    valid = np.isfinite(v) & np.isfinite(g)
    segs = segments(valid, int(cfg.min_segment_s / dt))
    straight = np.ones(len(t), bool)
    if "yaw_rate" in ch and np.isfinite(ch["yaw_rate"]).any():
        with np.errstate(invalid="ignore", divide="ignore"):
            straight = (
                np.abs(np.asarray(ch["yaw_rate"], float) * wheelbase_m / np.maximum(g, 0.1)) < 0.02
            )
    ok = np.zeros(len(t), bool)
    for a, b in segs:
        ok[a:b] = True
    if (ok & (g > 1.0) & straight).sum() < int(20.0 / dt):
        return None
    return SensorData(t, dt, v, g, segs, ok, straight)


def _shift(d: SensorData, c: float) -> np.ndarray:
    """gps_speed at t - c (per segment; NaN off the ends)."""
    if c == 0:
        return d.g
    out = np.full(len(d.t), np.nan)
    for a, b in d.segs:
        tt = d.t[a:b]
        out[a:b] = np.interp(tt - c, tt, d.g[a:b], left=np.nan, right=np.nan)
    return out


def _fit(d: SensorData, name, mask, c=None):
    """(param value, SSE, n) of hypothesis ``name`` on ``mask``."""
    use = mask & d.ok & (d.g > 1.0) & d.straight
    if name == "wheel_radius_error":
        g, v = d.g[use], d.v[use]
        k = float(np.clip((g @ v) / (g @ g), *SCALE_BOUNDS))
        return k, float(np.sum((v - k * g) ** 2)), int(use.sum())
    if name == "sensor_time_offset":
        gs = _shift(d, c)
        u = use & np.isfinite(gs)
        return c, float(np.sum((d.v[u] - gs[u]) ** 2)), int(u.sum())
    u = use
    return 0.0, float(np.sum((d.v[u] - d.g[u]) ** 2)), int(u.sum())


def _best_offset(d: SensorData, mask, grid):
    per_sample = []
    for c in grid:
        _, s, n = _fit(d, "sensor_time_offset", mask, c)
        per_sample.append(s / max(n, 1))
    sse = np.array(per_sample)
    return float(grid[int(np.nanargmin(sse))]), sse


def predict(d: SensorData, name, val) -> np.ndarray:
    if name == "wheel_radius_error":
        return val * d.g
    if name == "sensor_time_offset":
        return _shift(d, val)
    return d.g


@dataclass
class SensorScore:
    """Held-out and full-data results of one sensor hypothesis (a
    :class:`~models.diagnose.hypothesis.HypothesisScore`)."""

    name: str | None
    value: float
    heldout_rmse_mps: float
    heldout_err: np.ndarray
    bic: float
    params: dict
    intervals: dict


def evaluate(d: SensorData, name, cfg: DiagnoseConfig, corr_len: float) -> SensorScore:
    folds = segment_fold_ids(len(d.t), d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    coarse = np.round(np.arange(-OFFSET_MAX_S, OFFSET_MAX_S + 1e-9, max(d.dt, 0.01)), 6)
    err = np.full(len(d.t), np.nan)
    full_val, grid, sse_grid = 0.0, None, None
    if name == "sensor_time_offset":
        full_val, sse_grid = _best_offset(d, d.ok, coarse)
        grid = coarse
    for f in range(cfg.n_folds):
        tr = train_mask(folds, f, guard)
        if name == "sensor_time_offset":
            local = full_val + d.dt * np.arange(-5, 6)
            val, _ = _best_offset(d, tr, local)
        else:
            val, _, _ = _fit(d, name, tr)
        test = (folds == f) & (d.g > 1.0) & d.straight
        p = predict(d, name, val)
        err[test] = d.v[test] - p[test]
    val, sse, n = _fit(d, name, d.ok, full_val if name == "sensor_time_offset" else None)
    k = 0 if name is None else 1
    params, intervals = {}, {}
    if name == "wheel_radius_error":
        params["scale"] = val
        use = d.ok & (d.g > 1.0) & d.straight
        g = d.g[use]
        ne = max(use.sum() / corr_len, 3.0)
        se = np.sqrt(sse / max(n, 1) / (g @ g) * use.sum() / ne)
        intervals["scale"] = [val - 1.96 * se, val + 1.96 * se]
    elif name == "sensor_time_offset":
        params["offset_s"] = val
        assert grid is not None and sse_grid is not None  # searched for this hypothesis
        lo, hi = profile_interval(grid, sse_grid * n, n, corr_len)
        intervals["offset_s"] = [lo - 0.5 * d.dt, hi + 0.5 * d.dt]
    return SensorScore(name, val, rmse(err), err, bic(sse, n, k, corr_len), params, intervals)


def residual(d: SensorData, name=None, val=0.0) -> np.ndarray:
    r = d.v - predict(d, name, val)
    r[~(d.ok & (d.g > 1.0) & d.straight)] = np.nan
    return r


def ins_shift(ch: dict, offset_s: float) -> dict:
    """Channels with the INS ones moved onto the CAN clock (INS sample at t - offset_s)."""
    ins = ("yaw_rate", "accel_x", "accel_y", "x", "y", "z", "heading", "pitch", "roll", "gps_speed")
    t = np.asarray(ch["time"], float)
    out = dict(ch)
    for k in ins:
        if k in ch:
            x = np.asarray(ch[k], float)
            if k == "heading":
                x = np.unwrap(np.nan_to_num(x))
            y = np.interp(t - offset_s, t, x, left=np.nan, right=np.nan)
            if k == "heading":
                y = np.angle(np.exp(1j * y))
            out[k] = y
    return out
