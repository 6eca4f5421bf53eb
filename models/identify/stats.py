"""Least squares with confidence intervals that survive correlated residuals.

Residuals of a fit to 50 Hz vehicle data are strongly autocorrelated (a wrong tyre radius or
a gust lasts seconds, not one sample), so the textbook OLS covariance ``s^2 (X'X)^-1`` gives
intervals many times too narrow (on AR(1) residuals with rho = 0.98 its nominal 95% interval
covers the truth 4% of the time). hmpc's default, :func:`ols_hac` with ``method="blocks"``:

- the score series ``x_t e_t`` is cut into G contiguous *time blocks* and the cluster-robust
  sandwich ``(X'X)^-1 (sum_g s_g s_g') (X'X)^-1 G/(G-1)`` is formed from the block sums ``s_g``
  (the batch-means HAC estimator), with Student-t(G-1) critical values (fixed-b inference,
  which keeps its coverage when the blocks are few). The block length is ``2 (L+1)`` samples,
  L the Andrews (1991) AR(1) plug-in bandwidth (:func:`andrews_bandwidth`), with G clipped to
  [:data:`MIN_BLOCKS`, :data:`MAX_BLOCKS`]. Measured on seeded AR(1) data (3000 samples): 94.5%
  coverage at rho = 0.9, 90.5% at 0.98 (the Newey-West interval gets 92% and 84%); with 30 000
  samples 95% and 94.5%.
- ``method="newey-west"``: the Newey-West (1987) sandwich with Bartlett weights ``1 - l/(L+1)``
  and the same bandwidth, normal critical values (:func:`hac_cov`).
- :func:`cluster_cov`: the cluster-robust sandwich for nonlinear least squares whose
  residuals come in independent groups (replay windows), from the Jacobian.
- :func:`quantisation_step` and :func:`quantisation_cov`: a CAN channel rounded to its DBC
  step reads the same wrong value for as long as the true value stays put (a steady arc's yaw
  rate), an error no residual shows (the fit absorbs it), so it is added to the covariance
  as a uniform error of variance q^2/12 shared by each run of samples on one level.
- :func:`block_bootstrap_ci`: a seeded moving-block bootstrap (Kuensch 1989) for statistics
  without a sandwich formula.
- :func:`heldout_sse` and :func:`not_worse_than_best`: blocked cross-validation of a linear
  fit from per-fold sums, and the fold-paired test of which candidates are not worse than the
  best beyond fold-to-fold noise (choices of source and dead time).
- :func:`half_sample_kernels`: the matched smoother read half a sample earlier and later (the
  pedal timing bound of the zone intervals).

Samples left out of a fit (masked) stay in the time series as zero scores, so lags and blocks
are in time, across the gaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: two-sided 95% normal quantile.
Z95 = 1.959963984540054
#: fewest and most time blocks of the default interval (fewer than 8 makes t(G-1) very wide;
#: more than 40 adds nothing once t(G-1) is close to the normal quantile).
MIN_BLOCKS, MAX_BLOCKS = 8, 40
#: AR(1) coefficients above this are capped in the bandwidth rule: at 0.99 the rule already
#: asks for ~350 lags (7 s at 50 Hz) on a minute of data; beyond, it becomes unstable.
RHO_MAX = 0.99


@dataclass
class OlsResult:
    """Ordinary least squares with HAC covariance.

    Attributes:
        coef: coefficients [k].
        cov: HAC covariance of ``coef`` [k, k].
        se: standard errors [k].
        ci95: 95% intervals [k, 2] (``coef +- crit * se``).
        crit: critical value used (t(G-1) quantile for blocks, 1.96 for Newey-West).
        method: "blocks (G=..)" or "newey-west".
        residuals: y - X coef on the samples fitted [n].
        rmse: root mean square of the residuals.
        bandwidth: Newey-West lag truncation L [samples].
        n: samples fitted.
        cond: condition number of X with its columns scaled to unit norm.
        corr: correlation matrix of the estimates (from ``cov``).
    """

    coef: np.ndarray
    cov: np.ndarray
    se: np.ndarray
    ci95: np.ndarray
    residuals: np.ndarray
    rmse: float
    bandwidth: int
    n: int
    cond: float
    corr: np.ndarray
    crit: float = Z95
    method: str = ""


def andrews_bandwidth(u: np.ndarray, mask: np.ndarray | None = None) -> int:
    """Andrews (1991) AR(1) plug-in bandwidth for the Bartlett kernel [samples].

    Args:
        u: score series [N, k] (zeros where ``mask`` is False).
        mask: samples that belong to the fit (default all).
    """
    u = np.atleast_2d(np.asarray(u, dtype=float).T).T
    n = u.shape[0]
    m = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    both = m[1:] & m[:-1]
    num = den = 0.0
    for a in range(u.shape[1]):
        x0, x1 = u[:-1, a][both], u[1:, a][both]
        if len(x0) < 3 or not np.any(x0):
            continue
        rho = float(np.clip(np.dot(x0, x1) / np.dot(x0, x0), -RHO_MAX, RHO_MAX))
        s2 = float(np.mean((x1 - rho * x0) ** 2))
        num += 4 * rho**2 * s2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2**2 / (1 - rho) ** 4
    if den <= 0:
        return 0
    n_eff = int(m.sum())
    L = 1.1447 * (num / den * n_eff) ** (1.0 / 3.0)
    return int(min(max(np.floor(L), 0), n // 4))


def long_run_cov(u: np.ndarray, bandwidth: int) -> np.ndarray:
    """Bartlett-weighted long-run covariance ``sum_l w_l Gamma_l`` of ``u`` [N, k] (sum, not mean).

    Autocovariances by FFT, so the cost does not grow with the bandwidth.
    """
    u = np.atleast_2d(np.asarray(u, dtype=float).T).T
    n, k = u.shape
    L = int(min(max(bandwidth, 0), n - 1))
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    U = np.fft.rfft(u, nfft, axis=0)
    w = 1.0 - np.arange(L + 1) / (L + 1.0)
    S = np.zeros((k, k))
    for a in range(k):
        for b in range(a, k):
            # c[l] = sum_t u_a[t + l] u_b[t]
            c = np.fft.irfft(U[:, a] * np.conj(U[:, b]), nfft)
            pos, neg = c[: L + 1], c[::-1][:L]  # lags 0..L and -1..-L
            val = w[0] * pos[0] + np.dot(w[1:], pos[1:]) + np.dot(w[1:], neg)
            S[a, b] = S[b, a] = val
    return S


def hac_cov(
    X: np.ndarray, resid: np.ndarray, mask: np.ndarray | None = None, bandwidth: int | None = None
) -> tuple[np.ndarray, int]:
    """Newey-West covariance of OLS coefficients; returns (cov [k, k], bandwidth).

    Args:
        X: regressors on the full time grid [N, k] (rows outside ``mask`` are ignored).
        resid: residuals on the full grid [N] (ignored outside ``mask``).
        mask: samples used in the fit (default all); others count as zero scores.
        bandwidth: lag truncation [samples]; default :func:`andrews_bandwidth`.
    """
    Xm, u, m, L = _scores(X, resid, mask, bandwidth)
    S = long_run_cov(u, L)
    XtX_inv = np.linalg.pinv(Xm.T @ Xm)
    return XtX_inv @ S @ XtX_inv, L


def _scores(X, resid, mask, bandwidth):
    """Masked regressors, scores u = X * e, the mask and the lag bandwidth (shared by the
    covariance estimators): samples outside ``mask`` count as zero scores."""
    X = np.asarray(X, dtype=float)
    m = np.ones(X.shape[0], dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    e = np.where(m, np.nan_to_num(np.asarray(resid, dtype=float)), 0.0)
    Xm = np.where(m[:, None], np.nan_to_num(X), 0.0)
    u = Xm * e[:, None]
    L = andrews_bandwidth(u, m) if bandwidth is None else int(bandwidth)
    return Xm, u, m, L


def _corr(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        c = cov / np.outer(d, d)
    return np.nan_to_num(c)


def scaled_cond(X: np.ndarray) -> float:
    """Condition number of X with each column scaled to unit Euclidean norm (Belsley)."""
    X = np.asarray(X, dtype=float)
    nrm = np.linalg.norm(X, axis=0)
    if X.size == 0 or np.any(nrm == 0):
        return float("inf")
    s = np.linalg.svd(X / nrm, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def block_cov(
    X: np.ndarray, resid: np.ndarray, mask: np.ndarray | None = None, bandwidth: int | None = None
) -> tuple[np.ndarray, int, int]:
    """Time-block cluster-robust covariance; returns (cov [k, k], bandwidth, blocks G).

    Args as :func:`hac_cov`. See the module doc for the block length and G.
    """
    Xm, u, m, L = _scores(X, resid, mask, bandwidth)
    idx = np.flatnonzero(m)
    span = idx[-1] - idx[0] + 1
    G = int(np.clip(span // (2 * (L + 1)), MIN_BLOCKS, MAX_BLOCKS))
    g = np.minimum((np.arange(Xm.shape[0]) - idx[0]) * G // span, G - 1)
    labels, inv = np.unique(g[m], return_inverse=True)
    G = len(labels)
    scores = np.zeros((G, Xm.shape[1]))
    np.add.at(scores, inv, u[m])
    bread = np.linalg.pinv(Xm.T @ Xm)
    adj = G / (G - 1.0) if G > 1 else 1.0
    return bread @ (scores.T @ scores) @ bread * adj, L, G


def ols_hac(
    X: np.ndarray,
    y: np.ndarray,
    mask: np.ndarray | None = None,
    bandwidth: int | None = None,
    method: str = "blocks",
) -> OlsResult:
    """OLS of ``y`` on ``X`` over ``mask`` (samples on a uniform time grid), HAC intervals.

    Args:
        X: regressors [N, k] on the uniform grid.
        y: target [N].
        mask: samples to fit (NaN rows are dropped as well).
        bandwidth: lag truncation [samples] (default Andrews).
        method: "blocks" (default) or "newey-west"; see the module doc.

    Raises:
        ValueError: fewer usable samples than twice the number of regressors; unknown method.
    """
    from scipy.stats import t as student_t

    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    n, k = X.shape
    m = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).copy()
    m &= np.all(np.isfinite(X), axis=1) & np.isfinite(y)
    if m.sum() < 2 * k:
        raise ValueError(f"only {int(m.sum())} usable samples for {k} coefficients")
    coef, *_ = np.linalg.lstsq(X[m], y[m], rcond=None)
    resid_full = np.where(m, y - np.nan_to_num(X) @ coef, 0.0)
    if method == "blocks":
        cov, L, G = block_cov(X, resid_full, m, bandwidth)
        crit = float(student_t.ppf(0.975, max(G - 1, 1)))
        label = f"time-block cluster-robust sandwich, t({G - 1})"
    elif method == "newey-west":
        cov, L = hac_cov(X, resid_full, m, bandwidth)
        crit, label = Z95, f"Newey-West (Bartlett, L={L})"
    else:
        raise ValueError(f"unknown method {method!r} (blocks, newey-west)")
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    ci = np.column_stack([coef - crit * se, coef + crit * se])
    r = resid_full[m]
    return OlsResult(
        coef=coef,
        cov=cov,
        se=se,
        ci95=ci,
        residuals=r,
        rmse=float(np.sqrt(np.mean(r**2))),
        bandwidth=L,
        n=int(m.sum()),
        cond=scaled_cond(X[m]),
        corr=_corr(cov),
        crit=crit,
        method=label,
    )


def cluster_cov(J: np.ndarray, resid: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Cluster-robust covariance of nonlinear least-squares parameters.

    ``(J'J)^-1 (sum_g J_g' r_g r_g' J_g) (J'J)^-1 * G/(G-1)``, residuals independent between
    groups (e.g. replay windows), arbitrarily correlated within one.

    Args:
        J: Jacobian of the residuals at the solution [n, p].
        resid: residuals [n].
        groups: group label per residual [n].
    """
    J = np.asarray(J, dtype=float)
    r = np.asarray(resid, dtype=float)
    groups = np.asarray(groups)
    labels, inv = np.unique(groups, return_inverse=True)
    G = len(labels)
    scores = np.zeros((G, J.shape[1]))
    np.add.at(scores, inv, J * r[:, None])
    meat = scores.T @ scores
    bread = np.linalg.pinv(J.T @ J)
    adj = G / (G - 1.0) if G > 1 else 1.0
    return bread @ meat @ bread * adj


def quantisation_step(x: np.ndarray, tol: float = 0.05) -> float | None:
    """The rounding step of a quantised channel on the sample grid, or None when it does not
    look quantised.

    The levels a rounded channel rests on are the values it repeats from one grid sample to
    the next (a CAN value held, or interpolated between two equal readings); neighbouring
    levels are whole steps apart. ``q`` is the smallest gap between neighbouring levels, kept
    when at least 90 % of the gaps are whole multiples of it to within ``tol`` steps and the
    channel repeats itself on at least a third of its samples. A float channel (an INS yaw
    rate) fails the test: its few repeats sit at arbitrary values."""
    x = np.asarray(x, float)
    same = np.isfinite(x[1:]) & (np.diff(x) == 0.0)
    if np.count_nonzero(same) < max(10, len(x) // 3):
        return None
    levels = np.unique(x[1:][same])
    gaps = np.diff(levels)
    gaps = gaps[gaps > 1e-9 * max(1.0, float(np.max(np.abs(levels))))]
    if len(gaps) < 3:
        return None
    q = float(np.min(gaps))
    frac = gaps / q
    return q if np.mean(np.abs(frac - np.round(frac)) <= tol) >= 0.9 else None


def quantisation_cov(J: np.ndarray, reading: np.ndarray, index: np.ndarray, q: float) -> np.ndarray:
    """Covariance [p, p] of nonlinear least-squares parameters from the rounding error of a
    reading that rests on one level.

    While the true value stays put (a steady arc's yaw rate) the channel reads one level for
    the whole run, with an error uniform in [-q/2, q/2] (variance q^2/12) that the fit absorbs
    and no residual shows. Each run of consecutive samples on one level carries one such error,
    independent between runs: ``(J'J)^-1 (sum_R g_R g_R') (J'J)^-1 q^2/12``, ``g_R`` the
    Jacobian summed over run R. A dithered channel (noise of a step or more) flickers between
    levels in short runs, whose errors are already in the residuals, and adds little.

    Args:
        J: Jacobian of the residuals [n, p] on the fitted samples.
        reading: the quantised channel on the same samples [n].
        index: their sample numbers on the grid [n] (a gap starts a new run).
        q: the step (:func:`quantisation_step`).
    """
    J = np.asarray(J, dtype=float)
    x = np.asarray(reading, float)
    idx = np.asarray(index)
    new = np.ones(len(x), dtype=bool)
    new[1:] = (np.diff(idx) != 1) | (np.diff(x) != 0.0)
    runs = np.cumsum(new) - 1
    g = np.zeros((runs[-1] + 1 if len(runs) else 0, J.shape[1]))
    np.add.at(g, runs, J)
    bread = np.linalg.pinv(J.T @ J)
    return bread @ (g.T @ g) @ bread * (q * q / 12.0)


def block_bootstrap_ci(
    stat, n: int, *, block_len: int, reps: int = 200, seed: int = 0, level: float = 0.95
) -> tuple[np.ndarray, np.ndarray]:
    """Moving-block bootstrap percentile interval of ``stat(indices) -> array``.

    Args:
        stat: function of an index array (a resampled series of sample numbers) returning a
            1-D array of statistics.
        n: series length [samples].
        block_len: block length [samples]; choose several correlation times.
        reps: bootstrap replicates.
        seed: seed of the generator (intervals are reproducible).
        level: coverage of the interval (0.95: the 2.5 % and 97.5 % percentiles).

    Returns:
        (low, high) arrays.
    """
    rng = np.random.default_rng(seed)
    b = max(1, min(int(block_len), n))
    nblocks = int(np.ceil(n / b))
    out = []
    for _ in range(reps):
        starts = rng.integers(0, n - b + 1, size=nblocks)
        idx = (starts[:, None] + np.arange(b)[None, :]).ravel()[:n]
        out.append(np.asarray(stat(idx), dtype=float))
    arr = np.array(out)
    a = (1.0 - level) / 2.0
    return np.nanquantile(arr, a, axis=0), np.nanquantile(arr, 1.0 - a, axis=0)


def savgol_derivative(
    x: np.ndarray, dt_s: float, window_s: float = 0.5, order: int = 2, deriv: int = 1
) -> np.ndarray:
    """Savitzky-Golay smoothed derivative of a uniformly sampled signal [unit/s^deriv].

    A least-squares polynomial of ``order`` over a centred window of ``window_s`` (rounded to an
    odd number of samples, at least order + 2) is fitted at every sample and differentiated
    ``deriv`` times (``deriv=0``: the smoothed signal). NaN samples are bridged by linear
    interpolation for the filter and are NaN again in the output, as is every sample whose
    window touches a NaN (so a gap never leaks a made-up slope).
    """
    from scipy.signal import savgol_filter

    x = np.asarray(x, dtype=float)
    n = len(x)
    w = int(round(window_s / dt_s)) | 1
    w = max(w, order + 2 + ((order + 2) % 2 == 0))
    if n < w:
        return np.full(n, np.nan)
    bad = ~np.isfinite(x)
    xf = x
    if bad.any():
        if bad.all():
            return np.full(n, np.nan)
        idx = np.arange(n)
        xf = x.copy()
        xf[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
    out = savgol_filter(xf, w, order, deriv=deriv, delta=dt_s, mode="interp")
    if bad.any():
        out[np.convolve(bad.astype(float), np.ones(w), mode="same") > 0.5] = np.nan
    return out


def dilate(mask: np.ndarray, n_before: int, n_after: int | None = None) -> np.ndarray:
    """Widen the True runs of a boolean mask by ``n_before``/``n_after`` samples."""
    m = np.asarray(mask, dtype=bool)
    nb, na = int(n_before), int(n_before if n_after is None else n_after)
    if nb <= 0 and na <= 0:
        return m.copy()
    k = np.ones(nb + na + 1)
    # a True at sample j sets samples j-nb .. j+na
    conv = np.convolve(m.astype(float), k, mode="full")[nb : nb + len(m)]
    return conv > 0.5


def matched_kernels(dt_s: float, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A derivative filter and the smoother it implies for the regressors of ``dv/dt = f``.

    ``d`` is the Savitzky-Golay first-derivative kernel (order 1 or 2: the local least-squares
    slope) over ``2M+1`` samples, ``M = round(window_s / dt_s / 2)``: ``d[k] = k / (dt sum k^2)``.
    Summation by parts gives ``sum_k d[k] v[t+k] = sum_k H[k] (v[t+k+1] - v[t+k])`` with
    ``H[k] = -sum_{j<=k} d[j]`` (a positive parabolic weight), and ``v[t+k+1] - v[t+k]`` is the
    integral of ``f`` over that interval, ~ ``dt (f[t+k] + f[t+k+1]) / 2``. So smoothing each
    regressor with ``g = dt * (H * [1/2, 1/2])`` makes the filtered model exact: if
    ``dv/dt = X theta`` then ``d * v = (g * X) theta`` (up to the trapezoid rule), whatever the
    shape of the inputs. (Smoothing the regressors with the Savitzky-Golay *smoother* instead
    does not commute with differentiation and biases coefficients by a few percent at pedal
    steps.) Both kernels are returned as correlation weights for offsets -M..M; ``sum(g) = 1``.
    """
    M = max(int(round(window_s / dt_s / 2.0)), 1)
    k = np.arange(-M, M + 1, dtype=float)
    d = k / (dt_s * np.sum(k * k))
    H = -np.cumsum(d)[:-1]  # offsets -M..M-1
    g = np.zeros(2 * M + 1)
    g[:-1] += 0.5 * H * dt_s
    g[1:] += 0.5 * H * dt_s
    return d, g


def apply_kernel(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Centred correlation ``y[t] = sum_k kernel[k] x[t+k]`` (k = -M..M); NaN where the window
    leaves the series or touches a NaN."""
    x = np.asarray(x, dtype=float)
    n, w = len(x), len(kernel)
    M = w // 2
    out = np.full(n, np.nan)
    if n < w:
        return out
    bad = ~np.isfinite(x)
    xf = np.where(bad, 0.0, x)
    out[M : n - M] = np.correlate(xf, kernel, mode="valid")
    if bad.any():
        out[np.convolve(bad.astype(float), np.ones(w), mode="same") > 0.5] = np.nan
    return out


def half_sample_kernels(d: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The matched smoother of :func:`matched_kernels` moved half a sample earlier and later.

    :func:`matched_kernels` integrates the regressor over each sample interval by the trapezoid
    rule (``(f[t+k] + f[t+k+1]) / 2``): right for an input that changes linearly between
    samples. A CAN pedal is sampled and held, and *when* within a sample interval it changed
    is not in the recording; the two zero-order-hold readings ``f[t+k]`` (the change came at
    the start of the interval) and ``f[t+k+1]`` (at its end) bracket it. Returns the smoothing
    kernels for those two readings (correlation weights, offsets -M..M, each summing to 1).
    """
    H = -np.cumsum(np.asarray(d, dtype=float))[:-1] * dt_s
    early, late = np.zeros(len(d)), np.zeros(len(d))
    early[:-1], late[1:] = H, H
    return early, late


def contiguous_fold_ids(n: int, k: int) -> np.ndarray:
    """Contiguous blocked cross-validation: fold index (0..k-1) of each of ``n`` samples, the
    whole range cut into ``k`` blocks in time order (fold ``i * k // n`` of sample ``i``).
    ``models.diagnose.common.segment_fold_ids`` cuts only the samples inside segments."""
    return np.minimum(np.arange(n) * k // max(n, 1), k - 1)


def heldout_sse(
    X: np.ndarray, Y: np.ndarray, fold: np.ndarray, k: int, fit_col: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Blocked cross-validation of a linear least-squares fit, from per-fold sums.

    The coefficients are fitted to ``Y[:, fit_col]`` on every fold but one and evaluated on the
    held-out fold against each column of ``Y`` (the target it was fitted to, and other
    measurements of the same quantity).

    Args:
        X: regressors of the samples used [n, p] (finite).
        Y: targets [n, c] (finite).
        fold: fold index per sample [n] (0..k-1).
        k: number of folds.
        fit_col: the column of ``Y`` the fit is made to.

    Returns:
        (sse [k, c]: held-out sum of squared errors per fold and column; count [k]).
    """
    p, c = X.shape[1], Y.shape[1]
    S, B, YY = np.zeros((k, p, p)), np.zeros((k, p, c)), np.zeros((k, c))
    cnt = np.bincount(fold, minlength=k).astype(float)
    ordered = bool(np.all(np.diff(fold) >= 0))  # contiguous folds: slices, no copies
    edges = np.searchsorted(fold, np.arange(k + 1)) if ordered else None
    for g in range(k):
        sel = slice(edges[g], edges[g + 1]) if edges is not None else fold == g
        Xg, Yg = X[sel], Y[sel]
        S[g], B[g], YY[g] = Xg.T @ Xg, Xg.T @ Yg, np.sum(Yg * Yg, axis=0)
    St, Bt = S.sum(axis=0), B.sum(axis=0)
    sse = np.zeros((k, c))
    for g in range(k):
        if cnt[g] == 0:
            continue
        coef = np.linalg.lstsq(St - S[g], Bt[:, fit_col] - B[g][:, fit_col], rcond=None)[0]
        sse[g] = YY[g] - 2.0 * coef @ B[g] + coef @ S[g] @ coef
    return np.maximum(sse, 0.0), cnt


def not_worse_than_best(E: np.ndarray) -> tuple[int, np.ndarray, float]:
    """Which candidates a blocked cross-validation cannot tell from the best.

    Args:
        E: held-out loss per candidate and fold [m, k] (lower is better).

    Returns:
        (index of the best mean loss; per candidate whether its fold-paired excess over the
        best is within ``t(k-1) * standard error`` (Student-t, 97.5%); that critical value).
    """
    from scipy.stats import t as student_t

    E = np.asarray(E, dtype=float)
    kk = E.shape[1]
    jb = int(np.nanargmin(E.mean(axis=1)))
    D = E - E[jb]
    se = D.std(axis=1, ddof=1) / np.sqrt(kk) if kk > 1 else np.zeros(len(E))
    crit = float(student_t.ppf(0.975, max(kk - 1, 1)))
    within = D.mean(axis=1) <= crit * se + 1e-12 * abs(E[jb].mean())
    return jb, within, crit
