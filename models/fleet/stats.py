"""Pooling a parameter over drives, and finding where it changed.

Each drive gives a value with a 95 % interval; its standard error is the interval's half
width / 1.96 (the intervals hmpc writes are normal-theory or bootstrap 95 % intervals).

- :func:`pool`: inverse-variance weighting with a between-drive variance tau^2
  (DerSimonian-Laird): when drives disagree beyond their intervals, tau^2 > 0 widens the
  pooled interval instead of letting the tightest drive dominate.
- :func:`drift`: a change across drives (in drive order) that the intervals cannot explain:
  a step (the value changes at one drive and stays) or a trend (the value starts to move
  linearly at one drive). Every change point and both shapes are scanned; each candidate is
  a two-coefficient weighted regression with its own DerSimonian-Laird tau^2 from the
  residuals (a wrong shape leaves misfit, which widens its own interval) and the
  Knapp-Hartung scaling of its standard errors. The candidate whose change coefficient is
  least likely under no change is kept when that probability is below the Bonferroni level
  ``alpha`` / (2 x number of candidates): a family-wise false-alarm rate ``alpha`` per
  parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm
from scipy.stats import t as t_dist

#: z of a two-sided 95 % interval (the intervals hmpc writes)
Z95 = float(norm.ppf(0.975))
#: family-wise false-alarm rate of one parameter's drift scan: 1 % (tests/test_fleet_stats
#: measures it on seeded fleets with no change)
DRIFT_ALPHA = 0.01
#: fewest drives on each side of a step (one drive alone is as likely an outlier as a change)
MIN_SEGMENT = 2


def se_from_ci(lo, hi) -> float:
    """Standard error from a 95 % interval (NaN when absent or of no width)."""
    if lo is None or hi is None:
        return math.nan
    se = (float(hi) - float(lo)) / (2.0 * Z95)
    return se if math.isfinite(se) and se > 0 else math.nan


def _dl_tau2(y: np.ndarray, se: np.ndarray, X: np.ndarray) -> float:
    """DerSimonian-Laird between-drive variance for the weighted regression y ~ X (the
    method-of-moments estimator of meta-regression; X with one column: the plain DL)."""
    n, p = X.shape
    if n <= p:
        return 0.0
    w = 1.0 / se**2
    XtW = X.T * w
    A = np.linalg.inv(XtW @ X)
    beta = A @ (XtW @ y)
    q = float(np.sum(w * (y - X @ beta) ** 2))
    # E[Q] = (n - p) + tau^2 * (sum w - tr(A X' W^2 X))
    c = float(np.sum(w) - np.trace(A @ ((X.T * w**2) @ X)))
    return max(0.0, (q - (n - p)) / c) if c > 0 else 0.0


def _wls(y, se, X, knapp_hartung: bool = False):
    """(coefficients, their standard errors, tau^2, scaled) of the random-effects regression;
    ``knapp_hartung``: the standard errors scaled by the weighted residual variance when it
    exceeds 1 (the Knapp-Hartung adjustment: tau^2 from a few drives is itself uncertain, so
    the coefficient is referred to Student t with n - p degrees of freedom); ``scaled`` says
    whether that happened."""
    tau2 = _dl_tau2(y, se, X)
    w = 1.0 / (se**2 + tau2)
    XtW = X.T * w
    A = np.linalg.inv(XtW @ X)
    beta = A @ (XtW @ y)
    bse = np.sqrt(np.diag(A))
    n, p = X.shape
    scaled = False
    if knapp_hartung and n > p:
        q = float(np.sum(w * (y - X @ beta) ** 2)) / (n - p)
        scaled = q > 1.0
        bse = bse * math.sqrt(max(1.0, q))
    return beta, bse, tau2, scaled


def pool(values, ses) -> tuple[float, tuple[float, float] | None, float]:
    """(pooled value, its 95 % interval, tau^2). Drives without a standard error (NaN) are
    left out of the weighting; with none left, the plain mean and no interval."""
    y = np.asarray(values, float)
    se = np.asarray(ses, float)
    ok = np.isfinite(y) & np.isfinite(se) & (se > 0)
    if not ok.any():
        yy = y[np.isfinite(y)]
        return (float(np.mean(yy)) if len(yy) else math.nan), None, math.nan
    beta, bse, tau2, _ = _wls(y[ok], se[ok], np.ones((int(ok.sum()), 1)))
    m, s = float(beta[0]), float(bse[0])
    return m, (m - Z95 * s, m + Z95 * s), tau2


@dataclass
class Drift:
    """A change found across drives: ``index`` is the first drive of the change (0-based, in
    drive order), ``before``/``after`` the fitted value before it and at its end (a step:
    the two levels; a trend: the level before and the value at the last drive), ``z`` the
    change coefficient over its standard error, ``bound`` the |z| it had to exceed."""

    kind: str
    index: int
    before: float
    after: float
    z: float
    bound: float


def _candidates(n: int):
    """(kind, first changed drive, design matrix) of every step and trend scanned."""
    i = np.arange(n, dtype=float)
    for k in range(MIN_SEGMENT, n - MIN_SEGMENT + 1):
        yield "step", k, np.column_stack([np.ones(n), (i >= k).astype(float)])
    for k in range(1, n - MIN_SEGMENT + 1):
        # flat up to drive k-1, then linear: drive k is one step along the trend
        yield "trend", k, np.column_stack([np.ones(n), np.maximum(0.0, i - (k - 1))])


def drift(values, ses, alpha: float = DRIFT_ALPHA) -> Drift | None:
    """The change across drives (in the order given) beyond their intervals, or None (see
    the module doc). Needs a standard error for every drive and ``2 * MIN_SEGMENT`` drives."""
    y = np.asarray(values, float)
    se = np.asarray(ses, float)
    n = len(y)
    if n < 2 * MIN_SEGMENT or not (
        np.isfinite(y).all() and np.isfinite(se).all() and (se > 0).all()
    ):
        return None
    cands = list(_candidates(n))
    level = alpha / (2.0 * len(cands))  # Bonferroni: one two-sided test per candidate
    best = None
    for kind, k, X in cands:
        beta, bse, _, scaled = _wls(y, se, X, knapp_hartung=True)
        z = float(beta[1] / bse[1]) if bse[1] > 0 else 0.0
        # the intervals explain the residuals: normal reference; else Student t (n - 2)
        ref = t_dist(n - 2) if scaled else norm
        p = float(ref.sf(abs(z)))
        if best is None or p < best[0]:
            best = (p, z, kind, k, beta, float(ref.isf(level)))
    assert best is not None  # there is at least one candidate
    p, z, kind, k, beta, bound = best
    if p >= level:
        return None
    b0, b1 = float(beta[0]), float(beta[1])
    after = b0 + b1 if kind == "step" else b0 + b1 * (n - k)
    return Drift(kind, k, b0, after, z, bound)
