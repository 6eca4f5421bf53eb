"""The choice of the measured acceleration by held-out evidence, and where the sources disagree.

**Choice of source** (:func:`choose_accel_source`, ``accel_source="auto"``): blocked
cross-validation over ``cv_folds`` contiguous folds. Each source gets its own pedal dead time
(a sensor latency shows there), and its zone fits, made without the fold, predict the
held-out acceleration measured by every other source; the score is the RMS of that error
beyond the other source's own fit [m/s^2]: how far its model is from the others'. A source
corrupted in a way the others are not (a wrong tyre radius, GNSS latency, an accelerometer's
pitch or lever arm) is far from the rest and scores worst. Among the sources whose
fold-paired excess over the best score is within fold-to-fold noise, the first of
:data:`SOURCE_ORDER` is chosen (wheel speeds first: they measure eq. 1's own speed; the GNSS
speed and ``accel_x`` are taken at their antenna or sensor point). Every other source is then
fitted like the chosen one and compared term by term (:func:`source_disagreements`): a zone on
which a source disagrees beyond the 95% intervals says so with the likely cause; it stays
identifiable only when another source corroborates the chosen one. Choice, scores and
disagreements are in ``report['selection']``.
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.models.identify.stats import contiguous_fold_ids, not_worse_than_best
from hmpc.models.identify.longitudinal.config import SOURCE_ORDER, LongitudinalIdConfig
from hmpc.models.identify.longitudinal.deadtime import _heldout_by_zone, pedal_dead_time_cv
from hmpc.models.identify.longitudinal.signals import LongitudinalSignals, ZoneMasks, _pedals
from hmpc.models.identify.longitudinal.zonefit import ZoneFit, _zone_design, ols_timed


def choose_accel_source(
    sig: LongitudinalSignals,
    ok: np.ndarray,
    zid: np.ndarray,
    n_zones: int,
    lagged: list,
    cfg: LongitudinalIdConfig,
) -> dict:
    """Score every candidate acceleration on held-out data and choose (module doc).

    Each candidate gets its own pedal dead time (:func:`pedal_dead_time_cv`; a sensor latency
    shows there). Over ``cv_folds`` contiguous folds, each candidate's zone fits, made without
    the fold, predict the held-out acceleration measured by every OTHER candidate (its own
    when it is alone); each channel's held-out RMS error is divided by that of the channel's
    own fit (its noise floor), and the score is the mean ratio (1 = as good as the channel's
    own model; lower is better). The chosen source is the first of :data:`SOURCE_ORDER` whose
    fold-paired excess over the best score is within fold-to-fold noise
    (``stats.not_worse_than_best``). Returns the selection report (JSON-ready) with
    ``dead_times`` ({source: :class:`PedalDeadTime`}) for the caller.
    """
    names = list(sig.candidates)
    Y = np.column_stack([sig.candidates[c][0] for c in names])
    ok = ok & np.all(np.isfinite(Y), axis=1)
    deads = {
        c: pedal_dead_time_cv(Y[:, j], ok, zid, n_zones, lagged, cfg, sig.dt_s)
        for j, c in enumerate(names)
    }
    for pair in lagged:
        ok = ok & np.isfinite(pair[0]) & np.isfinite(pair[1])
    K = max(3, int(cfg.cv_folds))
    fold = contiguous_fold_ids(len(Y), K)
    Yf = np.where(ok[:, None], Y, 0.0)
    E = {}
    for j, c in enumerate(names):
        lag = int(round(deads[c].tau_s / sig.dt_s))
        E[c] = _heldout_by_zone(
            lagged[lag], Yf, ok, zid, n_zones, fold, K, j, cfg.min_samples(sig.dt_s)
        )
    floor = {c: E[c][:, j] for j, c in enumerate(names)}
    cnt = np.maximum(np.bincount(fold[ok], minlength=K).astype(float), 1.0)
    scores, per_fold = {}, []
    for j, c in enumerate(names):
        others = [i for i, o in enumerate(names) if o != c] or [j]
        # excess held-out MSE over each other channel's own fit [(m/s^2)^2 per fold]
        ex = {names[i]: (E[c][:, i] - floor[names[i]]) / cnt for i in range(len(names))}
        per_fold.append(np.mean([ex[names[i]] for i in others], axis=0))
        mean_ex = float(per_fold[-1].mean())
        # the score clips a negative excess (this source's model predicts the others better
        # than their own fits do) to 0; the signed figure, sign(excess) * sqrt(|excess|),
        # still orders two sources that both clip
        scores[c] = {
            "score_mps2": float(np.sqrt(max(mean_ex, 0.0))),
            "score_signed_mps2": float(math.copysign(math.sqrt(abs(mean_ex)), mean_ex))
            if math.isfinite(mean_ex)
            else None,
            "excess_rms_mps2": {o: float(np.sqrt(max(e.mean(), 0.0))) for o, e in ex.items()},
            "dead_time_s": deads[c].tau_s,
            "dead_time_note": deads[c].note,
        }
    n_ok = max(int(ok.sum()), 1)
    sel = {
        "candidates": names,
        "skipped": dict(sig.skipped),
        "folds": K,
        "samples": n_ok,
        "scores": scores,
        "noise_floor_rms_mps2": {c: float(np.sqrt(floor[c].sum() / n_ok)) for c in names},
        "method": (
            f"blocked cross-validation over {K} contiguous folds: each source's zone "
            "fits (its own pedal dead time), made without the fold, predict the "
            "held-out acceleration measured by every other source; score = RMS of "
            "the held-out error beyond that source's own fit's error, averaged over "
            "the other sources [m/s^2] (how far its model is from theirs; lower is "
            "better, 0 = indistinguishable)"
        ),
        "dead_times": deads,
    }
    if len(names) == 1:
        forced = cfg.accel_source != "auto"
        sel.update(
            chosen=names[0],
            because=(
                "set by the configuration (--accel-source)"
                if forced
                else "the only source in the recording"
            ),
        )
        return sel
    pf = np.array(per_fold)
    keep = np.all(np.isfinite(pf), axis=0)
    judged = keep.sum() >= 2
    jb, within, _ = (
        not_worse_than_best(pf[:, keep])
        if judged
        else (int(np.argmin([_key_signed(scores, c) for c in names])), None, 0.0)
    )
    if within is None:
        within = np.arange(len(names)) == jb
    chosen = next(c for c in SOURCE_ORDER if c in names and within[names.index(c)])
    best = names[jb]
    tied = [c for c in SOURCE_ORDER if c in names and within[names.index(c)]]
    sel.update(
        chosen=chosen,
        because=_choice_because(chosen, best, tied, scores, judged),
        not_worse_than_best=[c for i, c in enumerate(names) if within[i]],
        tie=tied if len(tied) > 1 else [],
        tie_broken_by=(
            "the order of preference (" + ", ".join(SOURCE_ORDER) + ")" if len(tied) > 1 else None
        ),
    )
    return sel


def _key_signed(scores: dict, c: str) -> float:
    """Sort key: a source's signed held-out score (inf when there is none)."""
    x = scores[c].get("score_signed_mps2")
    return math.inf if x is None else x


def _signed(scores: dict, c: str) -> str:
    """A source's signed held-out score, with enough digits to tell two apart [m/s^2]."""
    x = scores[c].get("score_signed_mps2")
    return "n/a" if x is None else f"{x:+.4f}"


def _choice_because(
    chosen: str, best: str, tied: list[str], scores: dict, judged: bool = True
) -> str:
    """Why ``chosen`` was chosen: alone ahead of the rest beyond fold-to-fold noise, or a tie
    within noise broken by :data:`SOURCE_ORDER` (then every tied source and its signed score
    is named, so equal printed scores never pass for a decision)."""
    if len(tied) <= 1:
        others = sorted((c for c in scores if c != chosen), key=lambda c: _key_signed(scores, c))
        nxt = (
            ""
            if not others
            else (
                f"; next {others[0]} {_signed(scores, others[0])} m/s^2, "
                + (
                    "worse beyond fold-to-fold noise"
                    if judged
                    else "too few folds to judge fold-to-fold noise"
                )
            )
        )
        return f"lowest held-out score (signed {_signed(scores, chosen)} m/s^2{nxt})"
    listed = ", ".join(f"{c} {_signed(scores, c)}" for c in tied)
    lowest = "it also has the lowest mean" if chosen == best else f"the lowest mean is {best}'s"
    return (
        f"tie within fold-to-fold noise between {listed} m/s^2 (signed held-out scores; "
        f"negative: predicts the other sources better than their own fits); broken by the "
        f"order of preference ({', '.join(SOURCE_ORDER)}): {chosen} is first, {lowest}"
    )


def source_disagreements(
    sig: LongitudinalSignals,
    masks: ZoneMasks,
    fits: list[ZoneFit],
    deads: dict,
    cfg: LongitudinalIdConfig,
) -> dict:
    """Each other candidate source fitted like the chosen one (same zones, samples and terms,
    its own dead time) and compared term by term: two sources disagree on a term when their
    95% intervals are apart by more than ``agree_offset_mps2`` (offset) or ``agree_scale_rel``
    of the chosen value (scales). Per zone: the disagreeing sources, the corroborating ones
    (no term apart), and the likely cause (:func:`_likely_cause`). JSON-ready."""
    out: dict = {"zones": {}, "statements": []}
    chosen = sig.source
    for c in [c for c in sig.candidates if c != chosen]:
        a_c = sig.candidates[c][0]
        ped = _pedals(sig, deads[c].tau_s)
        for zi, f in enumerate(fits):
            if not f.fitted:
                continue
            rep = f.report
            use_a, use_b = rep["scale_mps2"] is not None, rep["brake_scale_mps2"] is not None
            m = ~masks.bad & (masks.zid == zi) & np.isfinite(a_c)
            m &= np.isfinite(ped.aps) & np.isfinite(ped.bps)
            if m.sum() < cfg.min_samples(sig.dt_s):
                continue
            X = _zone_design(ped.aps, ped.bps, use_a, use_b)
            r, ci, _, _ = ols_timed(
                X, [_zone_design(a, b, use_a, use_b) for a, b in ped.alt], a_c, m
            )
            terms = (
                ["offset_mps2"]
                + (["scale_mps2"] if use_a else [])
                + (["brake_scale_mps2"] if use_b else [])
            )
            apart = {}
            for k, term in enumerate(terms):
                ref, ref_ci = rep[term], rep[term.replace("_mps2", "_ci95_mps2")]
                gap = max(ci[k][0] - ref_ci[1], ref_ci[0] - ci[k][1], 0.0)
                tol = cfg.agree_offset_mps2 if k == 0 else cfg.agree_scale_rel * abs(ref)
                if gap > tol:
                    apart[term] = {chosen: [ref, list(ref_ci)], c: [float(r.coef[k]), list(ci[k])]}
            z = out["zones"].setdefault(
                rep["name"],
                {
                    "chosen": chosen,
                    "disagree": [],
                    "corroborated_by": [],
                    "terms": {},
                    "likely_cause": "",
                },
            )
            if apart:
                z["disagree"].append(c)
                z["terms"][c] = apart
                cause = _likely_cause(chosen, c, deads, apart, sig.dt_s)
                z["likely_cause"] = "; ".join(x for x in (z["likely_cause"], cause) if x)
                out["statements"].append(
                    f"zone {rep['name']}: {c} disagrees with {chosen} on "
                    f"{', '.join(apart)} beyond the 95% intervals; likely cause: {cause}"
                )
            else:
                z["corroborated_by"].append(c)
    return out


def _likely_cause(chosen: str, other: str, deads: dict, apart: dict, dt_s: float) -> str:
    """The physical reason two acceleration sources most plausibly differ, from the pattern
    of their difference (a delay, a common scale ratio, an offset)."""
    causes = []
    d_tau = deads[other].tau_s - deads[chosen].tau_s
    if abs(d_tau) >= 2 * dt_s:
        late = other if d_tau > 0 else chosen
        causes.append(f"{late} lags by {abs(d_tau):.2f} s (sensor latency)")
    pair = {chosen, other}
    ratios = [
        v[other][0] / v[chosen][0] for t, v in apart.items() if t != "offset_mps2" and v[chosen][0]
    ]
    if ratios and pair & {"wheel_speeds", "speed"}:
        causes.append(
            f"a speed scale error (tyre radius or wheel-speed calibration: scale "
            f"ratio {other}/{chosen} {np.mean(ratios):.3f})"
        )
    if "accel_x" in pair:
        causes.append(
            "accel_x is the INS/IMU point's acceleration: sensor pitch or road grade "
            "shifts its offset, and a point away from the front axle adds "
            "centripetal acceleration in turns"
        )
    if "gps_speed" in pair and not causes:
        causes.append(
            "the GNSS speed is the antenna point's speed (it differs from the "
            "front-axle speed in turns) and lags by its latency"
        )
    return "; ".join(causes) or "unknown (the sources differ beyond their intervals)"
