"""An unexplained change in the car: a change no catalogue hypothesis models (mass, load,
tyres, a trailer), found as a split of the recording whose separate fits of the final
longitudinal model explain the data better than one fit for all of it (a Chow F test in
effective samples, Bonferroni over the split points, and an effect size). It is reported with
its windows and its share of the error, never named.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import f as f_dist

from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.common import DiagnoseConfig, corr_length, windows


def _inputs_on_both_sides(d: lon.LonData, left: np.ndarray, right: np.ndarray) -> bool:
    """Every input the recording uses is used on both sides of a split (at least 10 % of its
    active samples on each): a side that never saw an input (the driver's pedal before an ACC
    engages) cannot fit its gain, and its split fit would fake a change in the car."""
    act = np.abs(np.nan_to_num(d.U)) > 0.01
    n = act[d.ok].sum(axis=0)
    used = n > 0
    return bool(
        np.all(act[left].sum(axis=0)[used] >= 0.1 * n[used])
        and np.all(act[right].sum(axis=0)[used] >= 0.1 * n[used])
    )


def _block_corr_length(r: np.ndarray, block: int) -> float:
    """Correlation length [samples] of a residual counted in blocks: ``block`` times
    :func:`corr_length` of its means over consecutive ``block``-sample blocks.

    The acceleration is a Savitzky-Golay derivative over ``deriv_window_s``: every sample
    within one window shares the same speeds, and the filter's negative side lobes pull the
    residual's autocorrelation below :func:`corr_length`'s 0.05 cut within that window even
    when a slow error follows it, and the raw residual counts too many independent samples."""
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    nb = len(r) // block
    if nb < 2:
        return float(max(len(r), 1))
    return block * corr_length(r[: nb * block].reshape(nb, block).mean(axis=1))


def _split_test(
    d: lon.LonData, spec: lon.LonSpec, pooled: lon.LonModel, tk: float, t, block: int
) -> dict | None:
    """Chow F test of one split at ``tk`` [s]: the final model fitted before and after it
    against one fit for all, counted in effective samples. ``None`` when a side cannot be
    fitted or the effective samples do not exceed the split's parameters."""
    left, right = d.ok & (t < tk), d.ok & (t >= tk)
    m1, m2 = lon.fit(d, spec, left), lon.fit(d, spec, right)
    sse = m1.sse + m2.sse
    extra = m1.k + m2.k - pooled.k  # the parameters the second fit adds
    if not (m1.k and m2.k and np.isfinite(sse) and 0.0 < sse) or extra <= 0:
        return None
    # residual correlation under the split (a real change inflates the pooled one's), the
    # larger side's: fewer independent samples, the cautious count
    cl = max(
        _block_corr_length(np.where(left, lon.residual(d, m1), np.nan), block),
        _block_corr_length(np.where(right, lon.residual(d, m2), np.nan), block),
    )
    n_eff = (m1.n + m2.n) / cl
    dof = n_eff - m1.k - m2.k
    if dof < 1.0:
        return None
    red = 1.0 - sse / pooled.sse
    f = max(pooled.sse - sse, 0.0) / extra / (sse / dof)
    return {
        "t": float(tk),
        "reduction": float(red),
        "f": float(f),
        "dof": [int(extra), round(dof, 1)],
        "effective_samples": round(n_eff, 1),
        "p": float(f_dist.sf(f, extra, dof)),
    }


def unexplained_change(d: lon.LonData, spec: lon.LonSpec, cfg: DiagnoseConfig, t) -> dict | None:
    """A change in the car no hypothesis models: the final longitudinal model (``spec``)
    fitted before and after a split explains the data better than one model for all of it,
    by more than chance and by more than ``cfg.change_min_reduction``.

    The rule (a Chow test with a sup over the split points, Bonferroni-corrected). At each of
    up to 13 split points (20-80 % of the moving samples) the split fit lowers the equation
    error's SSE from S0 to S1 with ``q`` more parameters (``k1 + k2 - k0``). The residuals are
    strongly autocorrelated (in closed-loop ACC driving, seconds of residual are one
    independent sample), so the samples are counted as effective samples n_e = n / l,
    ``l`` the residual's correlation length under the split (:func:`_block_corr_length`, the
    larger side's), and ``F = ((S0 - S1) / q) / (S1 / (n_e - k1 - k2))`` is referred to
    F(q, n_e - k1 - k2). The best of the splits (smallest p) is a change when its p times the
    number of splits tested is at most ``cfg.change_alpha`` (Bonferroni: at most that chance
    of a false alarm on a recording without change; neighbouring splits share most of their
    data, so it is cautious) AND its SSE reduction is at least ``cfg.change_min_reduction``
    (an effect size: on a long recording a reduction of a few per cent is significant and
    still no change in the car, only a model that is not exactly right everywhere).

    Why: a fixed reduction alone does not know how much data stands behind it: on a minute of
    clean ACC driving a few dozen effective samples carry the split's 6-10 parameters, and the
    best of the splits lowers the SSE by a large fraction with nothing changed in the car."""
    pooled = lon.fit(d, spec, d.ok)
    idx = np.flatnonzero(d.ok & (d.vs > cfg.v_stop_mps) & np.isfinite(d.a))
    if len(idx) < 200 or not np.isfinite(pooled.sse) or pooled.sse <= 0:
        return None
    block = max(int(round(cfg.deriv_window_s / d.dt)), 1)
    tests = []
    for q in np.arange(0.2, 0.81, 0.05):
        tk = t[idx[int(q * (len(idx) - 1))]]
        if not _inputs_on_both_sides(d, d.ok & (t < tk), d.ok & (t >= tk)):
            continue
        s = _split_test(d, spec, pooled, tk, t, block)
        if s is not None:
            tests.append(s)
    cands = [s for s in tests if s["reduction"] >= cfg.change_min_reduction]
    if not cands:
        return None
    best = min(cands, key=lambda s: (s["p"], -s["reduction"]))
    p_family = min(1.0, best["p"] * len(tests))
    if p_family > cfg.change_alpha:
        return None
    t_cp = best["t"]
    ref = lon.fit(d, spec, d.ok & (t < t_cp))  # the car as it was first recorded
    L = int(cfg.window_lon_s / d.dt)
    w = windows(d.ok, L)
    err = np.full(d.n, np.nan)
    err[w] = lon.free_run(d, ref, w)
    sq = np.nan_to_num(err**2)
    share = float(sq[t >= t_cp].sum() / sq.sum()) if sq.sum() > 0 else 0.0
    t_end = float(t[idx[-1]])
    return {
        "channel": "speed",
        "windows": [[round(float(t_cp), 3), round(t_end, 3)]],
        "share_of_error": share,
        "subsystem": "longitudinal",
        "why": f"separate fits before and after t = {t_cp:.1f} s leave "
        f"{100 * best['reduction']:.0f} % less equation error than one model for "
        f"the whole recording (F = {best['f']:.1f} on {best['dof'][0]} and "
        f"{best['dof'][1]:g} effective degrees of freedom, p = {p_family:.2g} over "
        f"{len(tests)} split points); no catalogue hypothesis models such a change "
        "(mass, load, tyres, a trailer)",
        "error_reduction_split": best["reduction"],
        "split_test": {
            "f": best["f"],
            "dof": best["dof"],
            "effective_samples": best["effective_samples"],
            "p_value": best["p"],
            "p_family": p_family,
            "splits_tested": len(tests),
        },
        "heldout_note": "windows after the change replayed with the model fitted before it",
    }
