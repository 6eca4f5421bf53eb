"""The choice among the fits of eq. 7 by held-out evidence, and how the two measured angles agree.

**Choice** (:func:`cross_validate`, :func:`choose_fit`): blocked cross-validation over
``cv_folds`` contiguous folds; each fit, refitted without the fold, predicts the road-wheel
angle of the independent channel(s) it did not use, normalised by that channel's own held-out
error; the lowest score among the trusted identifiable fits is the final estimate. The choice,
every score and every disagreement (``reconcile``) are in ``report['selection']``.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.recording import Recording
from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.fits import MapFit, _fit_direct, _yaw_angle
from hmpc.models.identify.steering.replay import _fit_replay
from hmpc.models.identify.steering.signals import SteeringSignals


#: the channel each direct fit is made on (its own channel); the replay uses neither
OWN_CHANNEL = {
    "wheel_speed_difference": "wheel_speeds",
    "yaw_rate": "yaw_rate",
    "position_replay": None,
}


def cross_validate(
    rec: Recording,
    sig: SteeringSignals,
    fits: dict[str, MapFit],
    sw_d: np.ndarray,
    steady: np.ndarray,
    usable: np.ndarray,
    cfg: SteeringIdConfig,
    lever=None,
) -> dict:
    """Blocked cross-validation of the candidate fits (``cfg.cv_folds`` contiguous folds).

    Each candidate is refitted without the fold and its map predicts, on the fold's trustworthy
    samples, the road-wheel angle measured by the independent channel(s) it did not use: the
    wheel-speed fit predicts the yaw-rate angle ``atan(b (r - r_bias) / v_R)`` (gyro bias and
    speed point from the yaw-rate fit of the same training folds), the yaw-rate fit the
    wheel-speed angle, the replay both. A fit whose recording has no other channel is scored on
    its own. Each channel's held-out RMS error is divided by that of the channel's own fit (its
    noise floor, = 1 for a perfect rival), and a candidate's score is the mean over its
    channels (lower is better). Returns ``{method: {"score", "channels": {channel: ratio},
    "rms_rad": {...}}}``.
    """
    n = len(sw_d)
    K = max(2, int(cfg.cv_folds))
    edges = np.linspace(0, n, K + 1).astype(int)
    err: dict[str, dict[str, list]] = {k: {} for k in fits}
    own: dict[str, list] = {}
    for k in range(K):
        fold = np.zeros(n, dtype=bool)
        fold[edges[k] : edges[k + 1]] = True
        train, test = steady & ~fold, steady & fold
        if test.sum() < 10 or train.sum() < 20:
            continue
        try:
            maps = _fit_direct(sig, sw_d, train, cfg, tuple(fits), fits.get("yaw_rate"))
        except (ValueError, np.linalg.LinAlgError):
            continue
        chans = {}
        if "wheel_speed_difference" in maps:
            assert sig.delta_a is not None  # the method ran
            chans["wheel_speeds"] = sig.delta_a[test]
        if "yaw_rate" in maps:
            chans["yaw_rate"] = _yaw_angle(sig, maps["yaw_rate"])[test]
        if "position_replay" in fits:
            f = fits["position_replay"]
            out, _ = _fit_replay(
                rec,
                sig.v_front,
                sw_d,
                usable & ~fold,
                sig.dt_s,
                sig.b,
                cfg,
                (f.offset_rad, f.scale),
                lever,
            )
            if out is not None:
                maps["position_replay"] = out[0]
        sw_t = sw_d[test]
        for m, f in maps.items():
            pred = f.offset_rad + f.scale * sw_t
            c_own = OWN_CHANNEL[m]
            if c_own in chans:
                own.setdefault(c_own, []).append(chans[c_own] - pred)
            for c in [c for c in chans if c != c_own] or [c for c in chans if c == c_own]:
                err[m].setdefault(c, []).append(chans[c] - pred)

    def rms(parts):
        v = np.concatenate(parts) if parts else np.array([])
        v = v[np.isfinite(v)]
        return float(np.sqrt(np.mean(v**2))) if len(v) else float("nan")

    floor = {c: rms(v) for c, v in own.items() if v}
    out_d = {}
    for m, by_c in err.items():
        r = {c: rms(v) for c, v in by_c.items()}
        ratios = {c: (r[c] / floor[c] if floor.get(c) else float("nan")) for c in r}
        vals = [v for v in ratios.values() if np.isfinite(v)]
        out_d[m] = {
            "score": float(np.mean(vals)) if vals else float("nan"),
            "channels": ratios,
            "rms_rad": r,
        }
    return {
        "folds": K,
        "noise_floor_rad": floor,
        "scores": out_d,
        "method": (
            f"blocked cross-validation over {K} contiguous folds: each fit, refitted "
            "without the fold, predicts the road-wheel angle of the independent "
            "channel(s) it did not use (its own when there is no other); score = "
            "held-out RMS / that channel's own fit's held-out RMS, averaged over "
            "channels (lower is better)"
        ),
    }


def choose_fit(
    fits: dict[str, MapFit], idents: dict[str, dict], cv: dict | None = None
) -> tuple[str, str]:
    """The final estimate's name and why: the trusted fit with the lowest held-out score
    (:func:`cross_validate`), among the identifiable ones when any is (a fit whose parameters
    the recording cannot separate, e.g. offset from gyro bias, also biases the channel it is
    scored against); an untrusted replay (unknown reference point) is never chosen.
    Without scores, the narrowest scale interval among the identifiable (else all) fits."""
    order = [
        k
        for k in ("position_replay", "yaw_rate", "wheel_speed_difference")
        if k in fits and fits[k].extra.get("trusted", True)
    ]
    scores = (cv or {}).get("scores", {})
    scored = [k for k in order if np.isfinite(scores.get(k, {}).get("score", np.nan))]
    if scored:
        pool = [k for k in scored if idents[k]["identifiable"]]
        best = min(pool or scored, key=lambda k: scores[k]["score"])
        among = "identifiable fits" if pool else "fits (none is identifiable)"
        return best, (
            f"lowest held-out score among the trusted {among}: "
            + ", ".join(f"{k} {scores[k]['score']:.3f}" for k in scored)
        )

    def rel_width(k):
        f = fits[k]
        return (f.scale_ci95[1] - f.scale_ci95[0]) / abs(f.scale) if f.scale else np.inf

    pool = [k for k in order if idents[k]["identifiable"]] or order
    return min(pool, key=rel_width), "no held-out scores: the narrowest scale interval"


def agreement_a_b(
    sig: SteeringSignals, fits: dict[str, MapFit], steady: np.ndarray
) -> tuple[dict | None, np.ndarray | None]:
    """How measurements (a) and (b) agree on the trustworthy samples, and (b)'s road-wheel
    angle with the fitted gyro bias removed; (None, None) without a yaw-rate fit, (None, (b))
    without the wheel speeds."""
    if "yaw_rate" not in fits:
        return None, None
    delta_b = _yaw_angle(sig, fits["yaw_rate"])
    if "wheel_speed_difference" not in fits:
        return None, delta_b
    delta_a = sig.delta_a
    assert delta_a is not None  # the wheel-speed fit ran
    dd = (delta_a - delta_b)[steady]
    fa, fb = fits["wheel_speed_difference"], fits["yaw_rate"]
    agreement = {
        "rms_difference_rad": float(np.sqrt(np.mean(dd**2))),
        "mean_difference_rad": float(np.mean(dd)),
        "correlation": float(np.corrcoef(delta_a[steady], delta_b[steady])[0, 1])
        if np.std(delta_b[steady]) > 0 and np.std(delta_a[steady]) > 0
        else float("nan"),
        "offset_difference_rad": fa.offset_rad - fb.offset_rad,
        "scale_ratio": fa.scale / fb.scale if fb.scale != 0 else float("nan"),
    }
    return agreement, delta_b
