"""The actuator's response to its longitudinal input fitted as a dead time AND a first-order
lag together (:func:`joint_response`): the total effective delay, and whether a recording
tells the two apart. On ``longitudinal``'s fits and blocked held-out replays."""

from __future__ import annotations

import numpy as np

from hmpc.models.diagnose.common import DiagnoseConfig, rmse, segment_fold_ids, train_mask, windows
from hmpc.models.diagnose.hypothesis import sse_per_sample
from hmpc.models.diagnose.longitudinal import LonData, LonSpec, _covered, fit, free_run


#: grid steps [s] of the joint dead-time + lag fit (:func:`joint_response`): a coarse map of
#: the whole range, then a fine one around the coarse 95 % region (0.025 s: finer than the
#: 0.05 s an interval is quoted to), or 0.05 s when that region is large (a short recording)
JOINT_STEPS_S = (0.1, 0.025, 0.05)
#: most fine-grid fits before the fine step is coarsened (bounds the cost on long recordings)
JOINT_MAX_FINE = 300


def joint_response(d: LonData, base: dict | None, cfg: DiagnoseConfig, corr_len: float) -> dict:
    """The actuator's response to its input fitted as a dead time d AND a first-order lag tau
    together (u(t - d) through 1 / (tau s + 1)), on top of ``base`` (LonSpec keywords of the
    static term the final model carries), to say what one of them alone cannot: the total
    effective delay d + tau (the centroid of the response, the 63 % time of a step) and
    whether the recording tells a dead time from a lag.

    The SSE is mapped on a coarse grid (d + tau up to the larger search bound), then on a fine
    grid around the coarse points within twice the 95 % likelihood-ratio bound. Intervals are
    95 % profile-likelihood intervals with the effective sample size, widened by half a fine
    step. ``separable`` is False when the dead time alone or the lag alone fits within the
    chi-square(1) 95 % point (3.84) of the joint fit: the data then fix the total delay, not
    its split. The held-out speed RMSE [m/s] refits d and tau per fold near the full-data
    optimum, like :func:`evaluate`."""
    top = max(cfg.delay_max_s, cfg.tau_max_s)
    kw = dict(base or {})

    def spec(a, b):
        return LonSpec(None, **{**kw, "delay_s": float(a), "tau_s": float(b)})

    sse: dict = {}

    def run(pairs):
        for a, b in pairs:
            key = (round(float(a), 6), round(float(b), 6))
            if key not in sse and key[0] + key[1] <= top + 1e-9:
                m = fit(d, spec(*key), d.ok)
                sse[key] = (sse_per_sample(m), m.n)

    coarse, fine, wide = JOINT_STEPS_S
    g = np.arange(0.0, top + 1e-9, coarse)
    run([(a, b) for a in g for b in g])
    ne = max(min(n for _, n in sse.values()) / max(corr_len, 1.0), 3.0)
    s0 = min(v for v, _ in sse.values())
    near = np.array([k for k, (v, _) in sse.items() if ne * np.log(v / s0) <= 2 * 3.84])
    lo, hi = np.maximum(near.min(axis=0) - coarse, 0.0), near.max(axis=0) + coarse
    step = fine if np.prod((hi - lo) / fine + 1) <= JOINT_MAX_FINE else wide
    run(
        [
            (a, b)
            for a in np.arange(lo[0], hi[0] + 1e-9, step)
            for b in np.arange(lo[1], hi[1] + 1e-9, step)
        ]
    )
    P = np.array(list(sse))
    v = np.array([x for x, _ in sse.values()])
    i = int(np.argmin(v))
    lr = ne * np.log(v / v[i])

    def interval(x):
        inside = x[lr <= 3.84]
        return [max(float(inside.min()) - step / 2, 0.0), float(inside.max()) + step / 2]

    lr_delay = float(lr[P[:, 1] == 0].min())
    lr_lag = float(lr[P[:, 0] == 0].min())
    d_hat, tau_hat = float(P[i, 0]), float(P[i, 1])
    return {
        "input": "+".join(d.input_names),
        "dead_time_s": d_hat,
        "tau_s": tau_hat,
        "effective_delay_s": d_hat + tau_hat,
        "intervals": {
            "dead_time_s": interval(P[:, 0]),
            "tau_s": interval(P[:, 1]),
            "effective_delay_s": interval(P.sum(axis=1)),
        },
        "lr_dead_time_only": lr_delay,
        "lr_lag_only": lr_lag,
        "separable": bool(min(lr_delay, lr_lag) > 3.84),
        "heldout_rmse_mps": _joint_heldout(d, spec, (d_hat, tau_hat), cfg),
        "n_eff": ne,
        "grid_step_s": step,
    }


def _joint_heldout(d: LonData, spec, best: tuple, cfg: DiagnoseConfig) -> float:
    """Held-out free-run speed RMSE [m/s] of the joint fit (blocked folds as in
    :func:`evaluate`; each fold picks d and tau on its own data, each within 0.05 s of the
    full-data optimum)."""
    folds = segment_fold_ids(d.n, d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    L = int(cfg.window_lon_s / d.dt)
    near = JOINT_STEPS_S[2] * np.arange(-1, 2)
    local = sorted(
        {
            (round(float(a), 6), round(float(b), 6))
            for a in np.maximum(best[0] + near, 0.0)
            for b in np.maximum(best[1] + near, 0.0)
        }
    )
    err = np.full(d.n, np.nan)
    for f in range(cfg.n_folds):
        tr = train_mask(folds, f, guard)
        m = min((fit(d, spec(a, b), tr) for a, b in local), key=sse_per_sample)
        idx = _covered(d, tr, windows(folds == f, L))
        if idx.size:
            err[idx] = free_run(d, m, idx)
    return rmse(err)
