"""``unobserved_braking``: a deceleration no recorded input explains, for a pedal-driven car
whose recording has no brake channel.

With the accelerator released the zone models say how the car coasts; where it decelerates
harder than that for a while, something the recording does not carry brakes it (the driver's
brake, a retarder). The braking is estimated only where needed: in windows where the pedal is
released and the equation error of the coasting model stays below ``-threshold`` for at least
``MIN_BRAKE_S``, one deceleration level per window (its mean equation error), non-negative and
at most ``mu * g`` (tyre friction). The zone models are refitted around the windows, the
windows found again (three rounds). The hypothesis's model is eq. 8 plus that estimated
braking (``LonSpec.extra_accel``, one parameter per window in the BIC); its held-out score
refits eq. 8 on the training folds, finds the windows from that fit's error (the braking is
an input reconstructed from the measured motion, on held-out data too) and replays the
held-out windows with and without it.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.constants import G_MPS2
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.common import (
    DiagnoseConfig,
    bic,
    rmse,
    segment_fold_ids,
    train_mask,
    windows,
)

#: friction coefficient bounding the estimated braking (mu * g): dry asphalt's peak 0.8-1.0;
#: 0.8 is what a road car's service brake reaches there
MU = 0.8
#: [m/s^2] least deceleration beyond the coasting model counted as braking: gentle braking
#: starts near 0.5 m/s^2; 0.3 stays above a coasting car's equation-error noise (0.05-0.15)
MIN_BRAKE_DECEL_MPS2 = 0.3
#: [s] shortest braking window: a brake application lasts longer than the 0.5-s derivative
MIN_BRAKE_S = 1.0
#: rounds of refit and window search
ROUNDS = 3


def applies(d: lon.LonData) -> str | None:
    """Why the hypothesis is not tested on ``d`` (None: it is)."""
    if d.commanded:
        return "the car follows a command, whose controller brakes"
    if "brake_pedal" in d.input_names:
        return "the brake is recorded"
    if "accel_pedal" not in d.input_names:
        return "no accel_pedal channel: when the pedal is released is not known"
    return None


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    x = np.concatenate([[0], mask.astype(np.int8), [0]])
    st, en = np.flatnonzero(np.diff(x) == 1), np.flatnonzero(np.diff(x) == -1)
    return [(int(a), int(b)) for a, b in zip(st, en) if b - a >= min_len]


def braking_windows(
    d: lon.LonData, mask: np.ndarray, mu: float = MU
) -> tuple[lon.LonModel, np.ndarray, list]:
    """The coasting model fitted on ``mask`` outside the braking windows, the estimated braking
    [m/s^2] per sample (<= 0) and the windows ``(start, end, level)`` (module doc)."""
    brake = np.zeros(d.n, bool)
    min_len = max(int(round(MIN_BRAKE_S / d.dt)), 1)
    runs: list = []
    m = lon.fit(d, lon.LonSpec(), mask)
    for _ in range(ROUNDS):
        m = lon.fit(d, lon.LonSpec(), mask & ~brake)
        r = lon.residual(d, m)
        # the equation error's spread where no braking can hide (the pedal pressed): the
        # released samples mix coasting and the braking looked for
        quiet = ~d.idle & np.isfinite(r)
        sd = (
            1.4826 * float(np.median(np.abs(r[quiet] - np.median(r[quiet]))))
            if quiet.sum() > 10
            else 0.0
        )
        thr = max(MIN_BRAKE_DECEL_MPS2, 3.0 * sd)
        runs = _runs(d.idle & np.nan_to_num(r < -thr), min_len)
        new = np.zeros(d.n, bool)
        for a, b in runs:
            new[a:b] = True
        if (new == brake).all():
            break
        brake = new
    extra = np.zeros(d.n)
    out = []
    r = lon.residual(d, m)
    for a, b in runs:
        level = float(np.clip(np.nanmean(r[a:b]), -mu * G_MPS2, 0.0))
        extra[a:b] = level
        out.append((a, b, level))
    return m, extra, out


def _spec(extra: np.ndarray, wins: list) -> lon.LonSpec:
    return lon.LonSpec("unobserved_braking", extra_accel=extra, extra_params=len(wins))


def evaluate(
    d: lon.LonData, cfg: DiagnoseConfig, corr_len: float, mu: float = MU
) -> tuple[lon.LonScore | None, list]:
    """The hypothesis scored like ``longitudinal.evaluate`` (None when no window is found) and
    its windows ``[t_start_s, t_end_s, decel_mps2]``."""
    _, extra, wins = braking_windows(d, d.ok, mu)
    if not wins:
        return None, []
    full = lon.fit(d, _spec(extra, wins), d.ok)
    folds = segment_fold_ids(d.n, d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    L = int(cfg.window_lon_s / d.dt)
    err = np.full(d.n, np.nan)
    vals = []
    for f in range(cfg.n_folds):
        tr = train_mask(folds, f, guard)
        _, ex_f, w_f = braking_windows(d, tr, mu)
        m = lon.fit(d, _spec(ex_f, w_f), tr)
        idx = lon._covered(d, tr, windows(folds == f, L))
        if idx.size:
            err[idx] = lon.free_run(d, m, idx)
        vals.append(len(w_f))
    levels = np.array([lv for _, _, lv in wins])
    dur = float(sum(b - a for a, b, _ in wins) * d.dt)
    params = {
        "mu": mu,
        "max_decel_mps2": float(-levels.min()),
        "mean_decel_mps2": float(-np.mean(levels)),
        "braking_s": dur,
        "n_windows": float(len(wins)),
    }
    score = lon.LonScore(
        "unobserved_braking",
        full,
        rmse(err),
        err,
        bic(full.sse, full.n, full.k, corr_len),
        params,
        {},
        vals,
    )
    t = d.t
    return score, [[float(t[a]), float(t[min(b, d.n - 1)]), float(-lv)] for a, b, lv in wins]
