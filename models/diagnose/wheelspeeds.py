"""The wheel-speed difference against the yaw rate: two independent measurements of how fast
the car turns (the steering map fitted from either is the same map), and the measurement
physics that reconciles them when they disagree (catalogue id ``wheel_speed_scale``).

The rear wheels (unsteered) of a rigid body turning at r roll at speeds differing by exactly
``r T`` (T the rear track); without rear wheel speeds the front pair is used (``r T cos(delta)``:
within 0.1 % below 2.5 deg of road-wheel angle). Both sides are smoothed by the same
Savitzky-Golay kernel (``DiagnoseConfig.deriv_window_s``)::

    y = (v_right - v_left) / T,   r the gyro's yaw rate (or the heading's derivative)

Baseline: ``y = r - r0`` (r0 the gyro's bias). ``wheel_speed_scale``: ``y = rho (r - r0) +
eps v / T``: the tyres' contact patches move under load, so the effective track is rho T
(rho scales the difference, not the gyro); a per-side rolling-radius difference (right /
left reading at equal speed 1 + eps) adds ``eps v / T``, growing with speed where a gyro bias
does not. rho is fitted only where the yaw rate is excited well above its noise
(:data:`MAX_ATTENUATION`: noise in the regressor would bias it towards 0) and explains most of
the wheel-speed difference (:data:`MIN_R2`); otherwise rho = 1 and only eps is fitted.

Scores are the blocked held-out RMSE of the equation error [rad/s]; a finding needs
``candidates.accept`` and an interval that excludes the baseline (rho = 1 or eps = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs

from hmpc.models.diagnose.common import (
    DiagnoseConfig,
    bic,
    rmse,
    segment_fold_ids,
    segments,
    train_mask,
)
from hmpc.models.diagnose.locate import noise_floor
from hmpc.models.identify.stats import savgol_derivative

#: [rad/s] smallest held-out improvement that counts: about the smoothed wheel-speed
#: difference's step (0.01 km/h on a 1.6 m track is 0.0017 rad/s per sample, averaged down
#: over the 0.5-s kernel)
RESOLUTION_RADPS = 0.0005
#: [1] largest share of the smoothed yaw rate's variance that its own noise may hold before
#: rho is fitted: a regressor's noise biases its coefficient by that share (1 %: well inside
#: the effective track's plausible range, 0.8..1.2)
MAX_ATTENUATION = 0.01
#: [1] least share of the wheel-speed difference's variance the yaw rate must explain (squared
#: correlation) before rho is fitted: below it the turning is lost in the wheel speeds' noise
#: and a scale fitted there says nothing about the track (a straight road)
MIN_R2 = 0.8
#: bounds of the parameters (the catalogue's)
RHO_BOUNDS = (0.8, 1.2)
EPS_BOUNDS = (-0.05, 0.05)


@dataclass
class WheelYawData:
    t: np.ndarray
    dt: float
    y: np.ndarray  #: (v_right - v_left) / T [rad/s] (smoothed)
    r: np.ndarray  #: yaw rate [rad/s] (smoothed)
    v_over_t: np.ndarray  #: v / T [1/s]
    segs: list
    ok: np.ndarray
    pair: str  #: "rear" or "front"
    track_m: float
    yaw_source: str
    fit_rho: bool  #: the yaw rate is excited enough to fit rho
    attenuation: float  #: noise share of the smoothed yaw rate's variance
    r2: float  #: share of y's variance the yaw rate explains (correlation^2)

    @property
    def n(self) -> int:
        return len(self.t)


def prepare(
    ch: dict, vehicle, cfg: DiagnoseConfig = DiagnoseConfig()
) -> tuple[WheelYawData | None, str]:
    """(data or None, the reason when None)."""
    if "wheel_speed_rl" in ch and "wheel_speed_rr" in ch:
        left, right, pair = ch["wheel_speed_rl"], ch["wheel_speed_rr"], "rear"
        track = float(vehicle.track_rear_m or vehicle.track_front_m)
    elif "wheel_speed_fl" in ch and "wheel_speed_fr" in ch:
        left, right, pair = ch["wheel_speed_fl"], ch["wheel_speed_fr"], "front"
        track = float(vehicle.track_front_m)
    else:
        return None, "no left and right wheel speeds"
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    w = cfg.deriv_window_s
    if "yaw_rate" in ch and np.isfinite(np.asarray(ch["yaw_rate"], float)).mean() > 0.5:
        r_raw, src = np.asarray(ch["yaw_rate"], float), "yaw_rate"
    elif "heading" in ch and np.isfinite(np.asarray(ch["heading"], float)).mean() > 0.5:
        r_raw = savgol_derivative(np.unwrap(np.nan_to_num(np.asarray(ch["heading"], float))), dt, w)
        src = "the heading's derivative"
    else:
        return None, "no yaw_rate or heading channel"
    left, right = np.asarray(left, float), np.asarray(right, float)
    y = savgol_derivative((right - left) / track, dt, w, deriv=0)
    r = savgol_derivative(r_raw, dt, w, deriv=0)
    v = savgol_derivative(0.5 * (left + right), dt, w, deriv=0)
    valid = np.isfinite(y) & np.isfinite(r) & np.isfinite(v) & (v > cfg.v_move_min_mps)
    segs = segments(valid, int(cfg.min_segment_s / dt))
    ok = np.zeros(len(t), bool)
    for a, b in segs:
        ok[a:b] = True
    if ok.sum() < int(cfg.min_pair_s / dt):
        return None, (
            f"too little moving data with both wheel speeds and a yaw rate "
            f"({ok.sum() * dt:.1f} s in runs of {cfg.min_segment_s:g} s; needs "
            f"{cfg.min_pair_s:g} s)"
        )
    # the noise the smoothing leaves in r: the raw noise times the kernel's noise gain
    k = int(round(w / dt)) | 1
    gain = float(np.sum(savgol_coeffs(max(k, 5), 2) ** 2))
    var_noise = noise_floor(r_raw[ok]) ** 2 * gain
    var_r = float(np.var(r[ok]))
    att = var_noise / var_r if var_r > 0 else 1.0
    r2 = float(np.corrcoef(y[ok], r[ok])[0, 1] ** 2) if var_r > 0 else 0.0
    return WheelYawData(
        t,
        dt,
        y,
        r,
        v / track,
        segs,
        ok,
        pair,
        track,
        src,
        att <= MAX_ATTENUATION and r2 >= MIN_R2,
        float(att),
        r2,
    ), ""


@dataclass
class WheelYawFit:
    rho: float
    r0: float
    eps: float
    sse: float
    n: int
    k: int
    cov: np.ndarray  #: covariance of the fitted (rho, r0, eps) entries (white residual)


def fit(d: WheelYawData, name: str | None, mask: np.ndarray) -> WheelYawFit:
    """Baseline (name None): y - r = -r0; ``wheel_speed_scale``: y = rho r + c + eps v / T
    (r0 = -c / rho), rho fixed at 1 when the yaw rate is not excited."""
    use = mask & d.ok
    y, r, vt = d.y[use], d.r[use], d.v_over_t[use]
    if name is None:
        X, target = np.ones((len(y), 1)), y - r
    elif d.fit_rho:
        X, target = np.column_stack([r, np.ones(len(y)), vt]), y
    else:
        X, target = np.column_stack([np.ones(len(y)), vt]), y - r
    coef, *_ = np.linalg.lstsq(X, target, rcond=None)
    res = target - X @ coef
    sse = float(res @ res)
    s2 = sse / max(len(y) - X.shape[1], 1)
    try:
        cov = s2 * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        cov = np.full((X.shape[1], X.shape[1]), np.nan)
    if name is None:
        return WheelYawFit(1.0, -float(coef[0]), 0.0, sse, len(y), 1, cov)
    if d.fit_rho:
        rho = float(coef[0])
        return WheelYawFit(rho, -float(coef[1]) / rho, float(coef[2]), sse, len(y), 3, cov)
    return WheelYawFit(1.0, -float(coef[0]), float(coef[1]), sse, len(y), 2, cov)


def predict(d: WheelYawData, f: WheelYawFit) -> np.ndarray:
    return f.rho * (d.r - f.r0) + f.eps * d.v_over_t


def residual(d: WheelYawData, f: WheelYawFit) -> np.ndarray:
    e = d.y - predict(d, f)
    e[~d.ok] = np.nan
    return e


@dataclass
class WheelYawScore:
    """Held-out and full-data results (a :class:`~models.diagnose.hypothesis.HypothesisScore`)."""

    name: str | None
    model: WheelYawFit
    heldout_rmse_radps: float
    heldout_err: np.ndarray
    bic: float
    params: dict
    intervals: dict


def evaluate(
    d: WheelYawData, name: str | None, cfg: DiagnoseConfig, corr_len: float
) -> WheelYawScore:
    folds = segment_fold_ids(d.n, d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    err = np.full(d.n, np.nan)
    for f in range(cfg.n_folds):
        m = fit(d, name, train_mask(folds, f, guard))
        test = (folds == f) & d.ok
        err[test] = (d.y - predict(d, m))[test]
    full = fit(d, name, d.ok)
    params, intervals = {}, {}
    if name is not None:
        se = np.sqrt(np.clip(np.diag(full.cov), 0.0, None) * max(corr_len, 1.0))
        params["track_scale"], params["side_ratio"] = full.rho, full.eps
        if d.fit_rho:
            intervals["track_scale"] = [full.rho - 1.96 * se[0], full.rho + 1.96 * se[0]]
        intervals["side_ratio"] = [full.eps - 1.96 * se[-1], full.eps + 1.96 * se[-1]]
        params["gyro_bias_radps"] = full.r0
    return WheelYawScore(
        name, full, rmse(err), err, bic(full.sse, full.n, full.k, corr_len), params, intervals
    )


def disagreement(d: WheelYawData, s: WheelYawScore) -> list[str]:
    """What lies beyond its interval: ``track_scale`` (rho != 1), ``side_ratio`` (eps != 0)."""
    out = []
    lo, hi = s.intervals.get("track_scale", (1.0, 1.0))
    if lo > 1.0 or hi < 1.0:
        out.append("track_scale")
    lo, hi = s.intervals["side_ratio"]
    if lo > 0.0 or hi < 0.0:
        out.append("side_ratio")
    return out


def in_bounds(s: WheelYawScore) -> bool:
    """Both parameters inside the catalogue's bounds (beyond them it is another problem: a
    wrong track in the geometry, swapped wheels)."""
    return (
        RHO_BOUNDS[0] <= s.params["track_scale"] <= RHO_BOUNDS[1]
        and EPS_BOUNDS[0] <= s.params["side_ratio"] <= EPS_BOUNDS[1]
    )
