"""The pedal dead time of eq. 8, decided by held-out prediction.

**Dead time** (:func:`pedal_dead_time_cv`): blocked cross-validation of the zone fits over a
one-sample grid of pedal delays; a delay is used only when no delay predicts the held-out data
worse beyond fold-to-fold noise, and it is reported with its 95% held-out interval; otherwise
"not determined" and 0 is used. The held-out error of per-zone fits (:func:`_heldout_by_zone`)
also scores the acceleration sources (``sources``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.identify.stats import contiguous_fold_ids, heldout_sse, not_worse_than_best
from hmpc.models.identify.longitudinal.config import LongitudinalIdConfig


@dataclass
class PedalDeadTime:
    """Pedal dead time: ``tau_s`` used [s], the held-out best ``estimate_s`` [s], its held-out
    residual reduction against no delay ``gain`` [1], ``note`` saying why 0 is used (None when
    the estimate is), the 95% held-out ``interval_s`` [s] (None: not determined) and the
    cross-validation figures ``cv``."""

    tau_s: float
    estimate_s: float
    gain: float
    note: str | None
    interval_s: tuple | None = None
    cv: dict = field(default_factory=dict)


def _heldout_by_zone(
    pair,
    Y: np.ndarray,
    ok: np.ndarray,
    zid: np.ndarray,
    n_zones: int,
    fold: np.ndarray,
    k: int,
    fit_col: int,
    min_samples: int,
) -> np.ndarray:
    """Held-out SSE [k, columns of Y] of per-zone eq. 8 fits to the smoothed pedal ``pair``
    (``stats.heldout_sse``), summed over the zones with at least ``min_samples`` samples in
    ``ok``."""
    E = np.zeros((k, Y.shape[1]))
    for zi in range(n_zones):
        idx = np.flatnonzero(ok & (zid == zi))
        if len(idx) >= min_samples:
            X = np.column_stack([np.ones(len(idx)), pair[0][idx], -pair[1][idx]])
            E += heldout_sse(X, Y[idx], fold[idx], k, fit_col)[0]
    return E


def pedal_dead_time_cv(
    a_meas: np.ndarray,
    ok: np.ndarray,
    zid: np.ndarray,
    n_zones: int,
    lagged: list,
    cfg: LongitudinalIdConfig,
    dt_s: float,
) -> PedalDeadTime:
    """The pedal dead time by blocked cross-validation over the one-sample lag grid.

    For each lag the zone fits are made on all but one of ``cv_folds`` contiguous folds and
    scored by the squared error on the held-out fold (the same samples ``ok`` for every lag).
    Against the best lag, each lag's fold-paired excess is tested (``stats.not_worse_than_best``):
    the 95% interval is the run of lags around the best not worse beyond that noise (half a
    sample wider at each end: the grid's resolution). A delay is used only when no delay is
    outside that run, the best lag is inside the grid, and it lowers the held-out error by at
    least ``dead_time_min_gain``; otherwise 0 is used and the note says why.
    """
    nan = float("nan")
    for pair in lagged:
        ok = ok & np.isfinite(pair[0]) & np.isfinite(pair[1])
    ok = ok & np.isfinite(a_meas)
    K = max(3, int(cfg.cv_folds))
    fold = contiguous_fold_ids(len(a_meas), K)
    y = np.where(ok, a_meas, 0.0)[:, None]
    E = np.array(
        [
            _heldout_by_zone(p, y, ok, zid, n_zones, fold, K, 0, cfg.min_samples(dt_s))[:, 0]
            for p in lagged
        ]
    )
    keep = E.sum(axis=0) > 0
    if keep.sum() < 3:
        return PedalDeadTime(
            0.0, nan, 0.0, "no zone had enough samples to estimate it: not determined, 0 used"
        )
    E = E[:, keep]
    jb, within, crit = not_worse_than_best(E)
    lo = hi = jb
    while lo > 0 and within[lo - 1]:
        lo -= 1
    while hi < len(lagged) - 1 and within[hi + 1]:
        hi += 1
    mean = E.mean(axis=1)
    best = float(jb)
    if 0 < jb < len(lagged) - 1:
        den = mean[jb - 1] - 2 * mean[jb] + mean[jb + 1]
        if den > 0:
            best += 0.5 * (mean[jb - 1] - mean[jb + 1]) / den
    gain = float(1.0 - mean[jb] / mean[0]) if mean[0] > 0 else 0.0
    interval: tuple[float, float] | None
    interval = ((lo - 0.5) * dt_s, (hi + 0.5) * dt_s)
    cv = {
        "folds": int(E.shape[1]),
        "samples": int(ok.sum()),
        "t_critical": crit,
        "heldout_rms_at_zero_mps2": float(np.sqrt(E[0].sum() / max(ok.sum(), 1))),
        "heldout_rms_at_best_mps2": float(np.sqrt(E[jb].sum() / max(ok.sum(), 1))),
    }
    tau = best * dt_s
    note = None
    if jb == len(lagged) - 1:
        note = (
            f"held-out error still falling at the search limit {cfg.dead_time_max_s:g} s: "
            "not determined, 0 used"
        )
        interval = None
    elif within[0]:
        lo_s = max(interval[0], 0.0)
        note = (
            f"no delay improves the held-out prediction beyond fold-to-fold noise (best "
            f"{tau:.2f} s, 95% interval {lo_s:.2f}-{interval[1]:.2f} s"
            + (" includes 0" if lo_s == 0.0 else "; no delay predicts as well within that noise")
            + "): not determined, 0 used"
        )
    elif gain < cfg.dead_time_min_gain:
        note = (
            f"a dead time of {tau:.2f} s lowers the held-out error by only "
            f"{100 * gain:.1f}% (< {100 * cfg.dead_time_min_gain:g}%): not determined, 0 used"
        )
    return PedalDeadTime(0.0 if note else tau, tau, gain, note, interval, cv)
