"""Steering dead time, decided by held-out prediction, and the time shift it is applied with.

**Dead time** (:func:`dead_time_cv`): on a one-sample lag grid, eq. 7 is fitted to the measured
road-wheel angle (the source whose derivative cross-correlates best with the steering rate:
a cross-check, reported) over blocked folds; the interval is the run of lags whose held-out
error is not worse than the best lag's beyond the fold-to-fold noise (fold-paired t-test), and
a delay is used only when lag 0 lies outside it; otherwise it is "not determined" and 0 is
used. The fits use the steering-wheel angle delayed by it (:func:`delayed`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import t as student_t

from hmpc.models.identify.stats import savgol_derivative
from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.kinematics import road_wheel_angle_from_yaw
from hmpc.models.identify.steering.signals import SteeringSignals


def delayed(x: np.ndarray, delay_s: float, dt_s: float) -> np.ndarray:
    """``x(t - delay_s)`` on the same grid, linear interpolation; NaN where it reaches before t0."""
    x = np.asarray(x, dtype=float)
    if delay_s == 0.0:
        return x.copy()
    idx = np.arange(len(x)) - delay_s / dt_s
    out = np.interp(idx, np.arange(len(x)), x, left=np.nan, right=np.nan)
    lo = np.floor(idx).astype(int)
    hi = lo + 1
    ok = (lo >= 0) & (hi < len(x))
    nan_src = ~np.isfinite(x)
    bad = ~ok
    bad[ok] |= nan_src[lo[ok]] | nan_src[hi[ok]]
    out[bad] = np.nan
    return out


def xcorr_dead_time(
    u: np.ndarray,
    y: np.ndarray,
    mask: np.ndarray,
    dt_s: float,
    *,
    min_lag_s: float,
    max_lag_s: float,
) -> tuple[float, float]:
    """Lag [s] at which ``corr(u(t - lag), y(t))`` peaks over ``mask``, and the peak correlation.

    Both series are mean-removed over ``mask`` and zero elsewhere; the correlation at each lag
    is normalised by the energy of the overlapping parts. Sub-sample by a parabola.
    """
    m = np.asarray(mask, dtype=bool) & np.isfinite(u) & np.isfinite(y)
    if m.sum() < 50:
        return float("nan"), float("nan")
    a = np.where(m, u - np.mean(u[m]), 0.0)
    c = np.where(m, y - np.mean(y[m]), 0.0)
    n = len(a)
    lags = np.arange(int(np.floor(min_lag_s / dt_s)), int(np.ceil(max_lag_s / dt_s)) + 1)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    A, C = np.fft.rfft(a, nfft), np.fft.rfft(c, nfft)
    cc = np.fft.irfft(C * np.conj(A), nfft)  # cc[l] = sum_t y[t] u[t - l]
    a2 = np.fft.irfft(np.fft.rfft(a * a, nfft) * np.conj(np.fft.rfft(m.astype(float), nfft)), nfft)
    c2 = np.fft.irfft(np.fft.rfft(c * c, nfft) * np.conj(np.fft.rfft(m.astype(float), nfft)), nfft)
    # energy of u over samples t-l with t in mask and of y over t with t-l in mask
    vals: list[float] = []
    for lag_i in lags:
        num = cc[lag_i % nfft]
        ea = a2[(-lag_i) % nfft]  # sum_t a[t-l]^2 m[t]
        ec = c2[lag_i % nfft]  # sum_t c[t]^2 m[t-l]
        vals.append(num / np.sqrt(ea * ec) if ea > 0 and ec > 0 else 0.0)
    scores = np.array(vals)
    k = int(np.argmax(scores))
    lag = float(lags[k])
    if 0 < k < len(scores) - 1:
        y0, y1, y2 = scores[k - 1], scores[k], scores[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag += 0.5 * (y0 - y2) / den
    return lag * dt_s, float(scores[k])


@dataclass
class DeadTime:
    """Steering dead time, decided by held-out prediction (:func:`dead_time_cv`).

    Attributes:
        tau_s: the dead time used [s] (0 when it is not determined).
        estimate_s: the lag [s] with the best held-out score (NaN without a measured angle).
        interval_s: (low, high) [s], the lags whose held-out score is not worse than the best
            beyond the fold-to-fold noise (NaN without a measured angle).
        used: the best lag predicts held-out data better than no delay, beyond that noise.
        source: the measured road-wheel angle it was decided on.
        peak_corr: that source's cross-correlation peak (a cross-check).
        by_source: source -> (cross-correlation lag [s], peak correlation).
        cv: the held-out score curve (``dead_time_cv``), or None.
    """

    tau_s: float
    estimate_s: float
    peak_corr: float
    used: bool
    source: str
    by_source: dict[str, tuple[float, float]]
    interval_s: tuple[float, float] = (float("nan"), float("nan"))
    cv: dict | None = None

    def to_dict(self, smooth_s: float) -> dict:
        def fin(v):
            return float(v) if np.isfinite(v) else None

        return {
            "estimate_s": fin(self.estimate_s),
            "interval_s": [fin(v) for v in self.interval_s],
            "used": self.used,
            "determined": self.used,
            "note": (
                f"dead time {self.tau_s:.3f} s"
                if self.used
                else "not determined: no lag predicts held-out data better than no delay "
                "beyond the fold-to-fold noise"
            ),
            "source": self.source,
            "peak_correlation": fin(self.peak_corr),
            "by_source": {
                k: {"lag_s": fin(v[0]), "peak_correlation": fin(v[1])}
                for k, v in self.by_source.items()
            },
            "cv": self.cv,
            "method": "blocked cross-validation of eq. 7 over a one-sample lag grid "
            "(fold-paired t-test against the best lag; parabolic refinement); "
            "cross-check: cross-correlation of Savitzky-Golay derivatives "
            f"({smooth_s} s)",
        }


def _shifted(x: np.ndarray, lag: int) -> np.ndarray:
    """``x[t - lag]`` on the same grid (integer lag in samples), NaN where it reaches outside."""
    out = np.full(len(x), np.nan)
    if lag >= 0:
        out[lag:] = x[: len(x) - lag]
    else:
        out[:lag] = x[-lag:]
    return out


def dead_time_cv(
    sw: np.ndarray, meas: np.ndarray, mask: np.ndarray, dt_s: float, cfg: SteeringIdConfig
) -> dict | None:
    """Held-out evidence for a steering dead time, on a one-sample lag grid.

    For each lag L in [``dead_time_min_s``, ``dead_time_max_s``] eq. 7 (linear) is fitted to the
    measured road-wheel angle ``meas`` [rad] against ``sw(t - L)`` on all but one of
    ``dead_time_cv_folds`` contiguous folds, and scored by its mean squared error on the
    held-out fold (the same samples for every lag). Against the best lag L*, each lag's
    fold-paired excess error is tested (Student-t, K-1 degrees of freedom): the interval is the
    run of lags around L* not worse beyond that noise, and a delay is used only when lag 0 is
    outside it. L* is refined by a parabola through its neighbours; the interval reaches half a
    sample beyond the grid lags at its ends (the grid's resolution). None: too few samples.
    """
    n = len(sw)
    lags = np.arange(
        int(np.ceil(cfg.dead_time_min_s / dt_s - 1e-9)),
        int(np.floor(cfg.dead_time_max_s / dt_s + 1e-9)) + 1,
    )
    K = max(3, int(cfg.dead_time_cv_folds))
    fold = np.minimum(np.arange(n) * K // n, K - 1)
    xs = [_shifted(sw, int(L)) for L in lags]
    ok = np.asarray(mask, bool) & np.isfinite(meas)
    for x in xs:
        ok &= np.isfinite(x)
    f, y = fold[ok], meas[ok]
    cnt = np.bincount(f, minlength=K).astype(float)
    keep = cnt >= 10
    if keep.sum() < 3:
        return None
    E = np.empty((len(lags), K))
    Sy, Syy = np.bincount(f, y, K), np.bincount(f, y * y, K)
    for j, x in enumerate(xs):
        x = x[ok]
        Sx, Sxx, Sxy = np.bincount(f, x, K), np.bincount(f, x * x, K), np.bincount(f, x * y, K)
        tn, tx, ty = cnt.sum() - cnt, Sx.sum() - Sx, Sy.sum() - Sy
        txx, txy = Sxx.sum() - Sxx, Sxy.sum() - Sxy
        with np.errstate(invalid="ignore", divide="ignore"):
            c = (tn * txy - tx * ty) / (tn * txx - tx * tx)
            a = (ty - c * tx) / tn
            sse = Syy - 2 * a * Sy - 2 * c * Sxy + a * a * cnt + 2 * a * c * Sx + c * c * Sxx
            E[j] = sse / cnt
    E = E[:, keep]
    Kk = E.shape[1]
    mean = E.mean(axis=1)
    jb = int(np.nanargmin(mean))
    D = E - E[jb]
    se = D.std(axis=1, ddof=1) / np.sqrt(Kk)
    crit = float(student_t.ppf(0.975, Kk - 1))
    within = D.mean(axis=1) <= crit * se + 1e-15 * mean[jb]
    lo = hi = jb
    while lo > 0 and within[lo - 1]:
        lo -= 1
    while hi < len(lags) - 1 and within[hi + 1]:
        hi += 1
    best = float(lags[jb])
    if 0 < jb < len(lags) - 1:
        y0, y1, y2 = mean[jb - 1], mean[jb], mean[jb + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            best += 0.5 * (y0 - y2) / den
    j0 = int(np.flatnonzero(lags == 0)[0]) if 0 in lags else None
    used = j0 is not None and not within[j0]
    # the grid resolves lags to one sample: the interval reaches half a sample beyond its ends
    return {
        "best_s": best * dt_s,
        "interval_s": [(float(lags[lo]) - 0.5) * dt_s, (float(lags[hi]) + 0.5) * dt_s],
        "used": bool(used),
        "folds": int(Kk),
        "samples": int(ok.sum()),
        "excess_at_zero": (
            float(D[j0].mean() / mean[jb]) if j0 is not None and mean[jb] > 0 else None
        ),
        "excess_at_zero_t": (
            float(D[j0].mean() / se[j0]) if j0 is not None and se[j0] > 0 else None
        ),
        "t_critical": crit,
    }


def estimate_dead_time(sig: SteeringSignals, usable: np.ndarray, cfg: SteeringIdConfig) -> DeadTime:
    """Dead time: each measured road-wheel angle (wheel speeds; yaw rate) is cross-correlated
    with the steering-wheel angle (a cross-check, derivatives); the source with the best peak is
    then cross-validated over the lag grid (:func:`dead_time_cv`), which decides whether a
    delay is used and gives its interval. Replay only: not determined."""
    dt = sig.dt_s
    d_sw = savgol_derivative(sig.sw, dt, cfg.smooth_s)
    meas = {}
    if sig.delta_a is not None:
        meas["wheel_speed_difference"] = sig.delta_a
    if sig.yaw is not None:
        meas["yaw_rate"] = road_wheel_angle_from_yaw(sig.yaw, sig.v_rear, sig.b)
    nan = float("nan")
    if not meas:
        return DeadTime(0.0, nan, nan, False, "none (no measured road-wheel angle)", {})
    dead = {
        k: xcorr_dead_time(
            d_sw,
            savgol_derivative(m, dt, cfg.smooth_s),
            usable,
            dt,
            min_lag_s=cfg.dead_time_min_s,
            max_lag_s=cfg.dead_time_max_s,
        )
        for k, m in meas.items()
    }
    src = max(dead, key=lambda k: np.nan_to_num(dead[k][1], nan=-1))
    cv = dead_time_cv(sig.sw, meas[src], usable, dt, cfg)
    if cv is None:
        return DeadTime(0.0, nan, dead[src][1], False, src, dead)
    tau = cv["best_s"] if cv["used"] else 0.0
    return DeadTime(
        float(tau), cv["best_s"], dead[src][1], cv["used"], src, dead, tuple(cv["interval_s"]), cv
    )
