"""Shared pieces of the diagnosis: contiguous segments, blocked folds, free-run windows,
least squares with bounds on the extension terms, information criteria and profile intervals.

Held-out evaluation is always blocked in time: the valid samples are cut into ``N_FOLDS``
contiguous folds; a hypothesis is fitted on the other folds (with a guard band either side of
the held-out fold) and scored by free-run replay inside the held-out fold only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np


@dataclass(frozen=True)
class DiagnoseConfig:
    """Thresholds of the diagnosis (units in the names, the reason for each number beside it)."""

    #: contiguous held-out folds: 5 keeps 80 % of the data for each fit and gives 5 scores
    n_folds: int = 5
    #: guard band between a held-out fold and its training data [s]: longer than the
    #: longest delay or lag tested, so no training sample sees held-out inputs
    guard_s: float = 2.0
    #: free-run window for speed [s]: long enough for drag/grade to build up a speed error,
    #: short enough that a 10 % gain error does not drift the replay off the data
    window_lon_s: float = 10.0
    #: free-run window for heading and position [s]
    window_steer_s: float = 5.0
    #: a hypothesis is a finding when it lowers the held-out free-run RMSE by this fraction
    #: (the clean benchmark must stay below 10 %; noise moves scores by 1-3 %)
    min_gain: float = 0.05
    #: ... and lowers the BIC (effective samples) of the equation-error fit
    require_bic: bool = True
    #: speed below which the car counts as stopped [m/s] (the plant holds it at rest)
    v_stop_mps: float = 0.3
    #: steering fits use speeds above this [m/s] (yaw rate carries no angle at rest)
    v_steer_min_mps: float = 2.0
    #: Savitzky-Golay window for derivatives [s] (the identification's 0.5 s)
    deriv_window_s: float = 0.5
    #: shortest contiguous segment used [s]
    min_segment_s: float = 5.0
    #: dead-time search range [s]: actuators of road cars react within 1 s
    delay_max_s: float = 1.0
    #: lag time-constant search range [s]
    tau_max_s: float = 1.0
    #: change-point search for unexplained mismatch: relative equation-error reduction of a
    #: split fit that counts as a change in the car (mass, trailer, tyres) [fraction], an
    #: effect size required on top of ``change_alpha`` (10-minute clean recordings: 0.2-4 %,
    #: significant for a model that is not exactly right everywhere; a 0.7 x pedal gain: 94-99 %)
    change_min_reduction: float = 0.15
    #: ... and the split's F test (effective samples, the parameters it adds) must reach this
    #: family-wise false-alarm probability, Bonferroni over the split points scanned
    change_alpha: float = 0.05
    # ---- the steering and sensor comparisons (scaled to the vehicle by :meth:`for_vehicle`)
    #: samples count as moving above this [m/s]: below it the yaw rate carries no angle and a
    #: speed ratio is dominated by the wheel-speed step
    v_move_min_mps: float = 1.0
    #: least steering fit data [s] (samples above ``v_steer_min_mps`` in segments of at least a
    #: free-run window): five folds of two 2-s windows each; identification asks as much
    #: trustworthy steering (``SteeringIdConfig.min_trustworthy_s``)
    min_steer_s: float = 10.0
    #: least data for comparing two sensors of one quantity [s] (the accelerometer against the
    #: speed's derivative, the wheel-speed difference against the yaw rate): a static relation,
    #: scored on five held-out folds of 2 s, as much as the steering fit asks
    min_pair_s: float = 10.0
    #: [m/s^2] lateral acceleration (97.5th percentile of |v r| on the steering fit's samples)
    #: before understeer and the steering ratio are judged separable at all: understeer's angle
    #: is K a_y, and a passenger car's K ~ 0.004 rad/(m/s^2) makes 0.008 rad at 2 m/s^2, several
    #: times the angle sensor's step; on a straight line it is not testable (the same bound as
    #: identification's ``understeer_min_lat_accel_mps2``)
    understeer_min_lat_accel_mps2: float = 2.0
    #: [1] (v_high / v_low)^2 of the steered samples (10th and 90th speed percentiles where
    #: |a_y| exceeds a quarter of ``understeer_min_lat_accel_mps2``): at one speed the factor
    #: 1 / (1 + K v^2 / b) is a constant on the gain, not separable from it
    understeer_min_speed_sq_ratio: float = 2.0

    @classmethod
    def for_vehicle(cls, vehicle, **overrides) -> DiagnoseConfig:
        """The defaults with the speed thresholds (:data:`SPEED_THRESHOLDS`) scaled to a vehicle
        smaller than the reference (wheelbase ``REFERENCE_WHEELBASE_M``) by sqrt(f), f =
        wheelbase / reference (<= 1): dynamic similarity (equal Froude number v^2 / (g b)), the
        rule identification follows (``SteeringIdConfig.for_vehicle``). A vehicle at least as
        long keeps the defaults: the reasons behind them (wheel-speed steps, gyro bias over
        speed) do not grow with size. ``overrides``: field name -> value, applied last.

        Raises:
            ValueError: an override names no field.
        """
        known = {f.name for f in fields(cls)}
        bad = [k for k in overrides if k not in known]
        if bad:
            raise ValueError(
                f"unknown diagnose threshold '{bad[0]}' (one of {', '.join(sorted(known))})"
            )
        f = size_factor(vehicle)
        base = cls()
        scaled = {k: getattr(base, k) * math.sqrt(f) for k in SPEED_THRESHOLDS} if f < 1.0 else {}
        return replace(base, **{**scaled, **overrides})


#: [m] the wheelbase the default thresholds were set for: the report's car (a passenger car)
REFERENCE_WHEELBASE_M = 2.65
#: the steering and sensor thresholds :meth:`DiagnoseConfig.for_vehicle` scales with size
SPEED_THRESHOLDS = ("v_move_min_mps", "v_steer_min_mps")


def size_factor(vehicle) -> float:
    """f = wheelbase / ``REFERENCE_WHEELBASE_M``, at most 1 (see ``DiagnoseConfig.for_vehicle``)."""
    return min(1.0, float(vehicle.wheelbase_m) / REFERENCE_WHEELBASE_M)


def segments(valid: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """[start, stop) index ranges of runs of True at least ``min_len`` long."""
    v = np.concatenate([[False], np.asarray(valid, bool), [False]])
    d = np.diff(v.astype(np.int8))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops) if b - a >= min_len]


def segment_fold_ids(n: int, segs: list[tuple[int, int]], n_folds: int) -> np.ndarray:
    """Fold index (0..n_folds-1) of every sample in ``segs`` by time order; -1 elsewhere: the
    samples of all segments together cut into ``n_folds`` contiguous blocks (the gaps between
    segments belong to no fold). ``models.identify.stats.contiguous_fold_ids`` cuts a whole
    range of samples."""
    out = np.full(n, -1, dtype=int)
    idx = np.concatenate([np.arange(a, b) for a, b in segs]) if segs else np.zeros(0, int)
    if len(idx) == 0:
        return out
    edges = np.linspace(0, len(idx), n_folds + 1).astype(int)
    for f in range(n_folds):
        out[idx[edges[f] : edges[f + 1]]] = f
    return out


def train_mask(folds: np.ndarray, f: int, guard_n: int) -> np.ndarray:
    """Samples of every fold but ``f``, minus a guard band of ``guard_n`` samples around ``f``."""
    test = folds == f
    if guard_n > 0 and test.any():
        k = np.ones(2 * guard_n + 1)
        near = np.convolve(test.astype(float), k, mode="same") > 0
    else:
        near = test
    return (folds >= 0) & ~near


def windows(mask: np.ndarray, length: int) -> np.ndarray:
    """Index matrix [n_windows, length] of non-overlapping windows tiling runs of ``mask``."""
    rows = []
    for a, b in segments(mask, length):
        for s in range(a, b - length + 1, length):
            rows.append(np.arange(s, s + length))
    return np.array(rows, dtype=int).reshape(-1, length)


def lstsq_bounded(
    X: np.ndarray, y: np.ndarray, bounds: dict[int, tuple[float, float]] | None = None
) -> tuple[np.ndarray, float]:
    """Least squares ``y ~ X c`` with box bounds on a few columns (active set, exact for the
    one or two bounded columns an extension adds). Returns (coef, SSE)."""
    XtX, Xty = X.T @ X, X.T @ y
    yty = float(y @ y)
    k = X.shape[1]
    fixed: dict[int, float] = {}
    for _ in range(4):
        free = [i for i in range(k) if i not in fixed]
        c = np.zeros(k)
        for i, val in fixed.items():
            c[i] = val
        rhs = (
            Xty[free] - XtX[np.ix_(free, list(fixed))] @ np.array(list(fixed.values()))
            if fixed
            else Xty[free]
        )
        A = XtX[np.ix_(free, free)]
        try:
            c[free] = np.linalg.solve(A + 1e-12 * np.trace(A) / len(free) * np.eye(len(free)), rhs)
        except np.linalg.LinAlgError:
            c[free] = np.linalg.lstsq(A, rhs, rcond=None)[0]
        viol = False
        for i, (lo, hi) in (bounds or {}).items():
            if i in fixed:
                continue
            if c[i] < lo or c[i] > hi:
                fixed[i] = float(np.clip(c[i], lo, hi))
                viol = True
        if not viol:
            break
    sse = yty - 2 * c @ Xty + c @ XtX @ c
    return c, max(float(sse), 0.0)


def corr_length(resid: np.ndarray) -> float:
    """Integrated autocorrelation length [samples] of a residual (>= 1): how many samples
    carry one independent piece of information, for the effective sample size."""
    r = np.asarray(resid, float)
    r = r[np.isfinite(r)] - np.nanmean(r)
    n = len(r)
    if n < 20:
        return 1.0
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac /= ac[0] if ac[0] > 0 else 1.0
    cut = np.flatnonzero(ac < 0.05)
    m = int(cut[0]) if len(cut) else min(n // 4, 500)
    return float(max(1.0, 1.0 + 2.0 * ac[1:m].sum()))


def bic(sse: float, n: int, k: int, corr_len: float) -> float:
    """BIC with the effective sample size n / corr_len (autocorrelated residuals)."""
    ne = max(n / max(corr_len, 1.0), k + 2.0)
    return float(ne * np.log(max(sse, 1e-300) / max(n, 1)) + k * np.log(ne))


def profile_interval(
    grid: np.ndarray, sse: np.ndarray, n: int, corr_len: float
) -> tuple[float, float]:
    """95 % profile-likelihood interval of a scalar from SSE on a grid (effective samples)."""
    grid, sse = np.asarray(grid, float), np.asarray(sse, float)
    ok = np.isfinite(sse)
    if not ok.any():
        return (float("nan"), float("nan"))
    ne = max(n / max(corr_len, 1.0), 3.0)
    lr = ne * np.log(sse / np.nanmin(sse))
    inside = grid[ok & (lr <= 3.84)]
    return (float(inside.min()), float(inside.max()))


def rmse(e: np.ndarray) -> float:
    e = np.asarray(e, float)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if len(e) else float("nan")


def merge_windows(
    t: np.ndarray, flags: np.ndarray, idx: np.ndarray, gap_s: float = 1.0
) -> list[list[float]]:
    """Merge flagged windows (rows of ``idx``) into [[t0, t1], ...] time intervals [s]."""
    out: list[list[float]] = []
    for row in idx[np.asarray(flags, bool)]:
        t0, t1 = float(t[row[0]]), float(t[row[-1]])
        if out and t0 - out[-1][1] <= gap_s:
            out[-1][1] = t1
        else:
            out.append([t0, t1])
    return [[round(a, 3), round(b, 3)] for a, b in out]
