"""The accelerometer against the speed's derivative: two independent measurements of the
longitudinal acceleration, and the measurement physics that reconciles them when they disagree.

Both sides are smoothed by the same Savitzky-Golay kernel (``DiagnoseConfig.deriv_window_s``):
``a`` the derivative of the speed (the rear-axle centre's, the mean of the rear wheels, when
the recording has them; else ``speed``), ``m`` the accelerometer's ``accel_x``, ``q = v r``
the lateral acceleration of the path (speed times yaw rate).

Baseline: ``m = k a + c`` (``k`` the accelerometer's scale against the wheel speeds, ``c``
its bias and, where the reading holds gravity, the mean grade).

- ``sensor_mounting``: ``m = k (cos(psi) a + sin(psi) q) + c``: the IMU turned by ``psi``
  about the vertical axis (counter-clockwise seen from above), so that its x axis reads part
  of the lateral acceleration; linear in (a, q) with ``psi = atan2`` of their coefficients.
  Needs a yaw rate.
- ``accelerometer_lag``: ``m = k F[a] + c``, ``F = 1 / (tau s + 1)`` the sensor's own filter,
  tau in [0, ``TAU_MAX_S``]; on top of an accepted mounting both a and q go through ``F``.
  A lag is a delay as well as a smoothing: it is named only when it fits better than the
  zero-phase smoother of the best time constant (:func:`zero_phase`, F forwards and
  backwards); otherwise the accelerometer only reads a smoother signal (its bandwidth), which
  the comparison records, and no lag is named.

Scores are the blocked held-out RMSE of the equation error [m/s^2] (a static relation between
two sensors: nothing to free-run); a hypothesis is a finding by ``candidates.accept`` (held-out
gain, the resolution :data:`RESOLUTION_MPS2`, BIC) and only when its parameter's interval
excludes the baseline's value (psi = 0, tau = 0): the two sensors disagree beyond it; a lag
also needs :data:`MIN_TAU_SAMPLES`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from hmpc.models.diagnose.common import (
    DiagnoseConfig,
    bic,
    profile_interval,
    rmse,
    segment_fold_ids,
    segments,
    train_mask,
)
from hmpc.models.diagnose.hypothesis import grid_search
from hmpc.models.identify.stats import savgol_derivative

HYPOTHESES = ("sensor_mounting", "accelerometer_lag")
#: [s] longest filter lag searched: an accelerometer's low-pass (a CAN message's smoothing, a
#: phone IMU's output filter) sits well below a second
TAU_MAX_S = 1.0
#: [samples] shortest lag that is a filter: within two samples of the recording's grid the two
#: channels' resampling (each interpolated from its own message times) sets the timing
MIN_TAU_SAMPLES = 2
#: [m/s^2] smallest held-out improvement that counts: about five times the noise of the speed's
#: Savitzky-Golay derivative over 0.5 s from 0.01 km/h wheel-speed steps (~0.001 m/s^2)
RESOLUTION_MPS2 = 0.005


@dataclass
class AccelData:
    """The two measurements of the longitudinal acceleration on the recording grid."""

    t: np.ndarray
    dt: float
    a: np.ndarray  #: speed derivative [m/s^2] (smoothed)
    q: np.ndarray | None  #: lateral acceleration v r [m/s^2] (smoothed); None: no yaw rate
    m: np.ndarray  #: accel_x [m/s^2] (smoothed like ``a``)
    segs: list
    ok: np.ndarray  #: samples compared (moving, every channel finite)
    speed_source: str

    @property
    def n(self) -> int:
        return len(self.t)


def prepare(ch: dict, cfg: DiagnoseConfig = DiagnoseConfig()) -> tuple[AccelData | None, str]:
    """(data or None, the reason when None)."""
    if "accel_x" not in ch or not np.isfinite(np.asarray(ch["accel_x"], float)).any():
        return None, "no accel_x channel"
    if "speed" not in ch:
        return None, "no speed channel"
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    if "wheel_speed_rl" in ch and "wheel_speed_rr" in ch:
        v = 0.5 * (
            np.asarray(ch["wheel_speed_rl"], float) + np.asarray(ch["wheel_speed_rr"], float)
        )
        src = "the rear wheels' mean speed"
    else:
        v = np.asarray(ch["speed"], float)
        src = "speed"
    w = cfg.deriv_window_s
    a = savgol_derivative(v, dt, w)
    vs = savgol_derivative(v, dt, w, deriv=0)
    m = savgol_derivative(np.asarray(ch["accel_x"], float), dt, w, deriv=0)
    q = None
    if "yaw_rate" in ch and np.isfinite(np.asarray(ch["yaw_rate"], float)).mean() > 0.5:
        q = vs * savgol_derivative(np.asarray(ch["yaw_rate"], float), dt, w, deriv=0)
    valid = np.isfinite(a) & np.isfinite(m) & (np.abs(vs) > cfg.v_move_min_mps)
    if q is not None:
        valid &= np.isfinite(q)
    segs = segments(valid, int(cfg.min_segment_s / dt))
    ok = np.zeros(len(t), bool)
    for s0, s1 in segs:
        ok[s0:s1] = True
    if ok.sum() < int(cfg.min_pair_s / dt):
        return None, (
            f"too little moving data with accel_x ({ok.sum() * dt:.1f} s in runs of "
            f"{cfg.min_segment_s:g} s; needs {cfg.min_pair_s:g} s)"
        )
    return AccelData(t, dt, a, q, m, segs, ok, src), ""


@dataclass
class AccelFit:
    """One fit: ``m = c_a F[a] (+ c_q F[q]) + c`` with the lag ``tau_s`` (0: none)."""

    tau_s: float
    mount: bool
    coef: np.ndarray  #: (c_a[, c_q], c)
    sse: float
    n: int
    k: int
    cov: np.ndarray  #: covariance of ``coef`` (white residual; scale by corr length)

    @property
    def yaw_rad(self) -> float:
        return float(np.arctan2(self.coef[1], self.coef[0])) if self.mount else 0.0

    @property
    def gain(self) -> float:
        return float(np.hypot(self.coef[0], self.coef[1])) if self.mount else float(self.coef[0])


def _lag(x: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    """``x`` (one contiguous run) through 1 / (tau s + 1), started at its first value."""
    al = 1.0 - np.exp(-dt / tau_s)
    return lfilter([al], [1.0, al - 1.0], x, zi=[(1.0 - al) * x[0]])[0]


def _lagged(d: AccelData, x: np.ndarray, tau_s: float) -> np.ndarray:
    """``x`` through 1 / (tau s + 1), per segment (NaN outside the segments)."""
    if tau_s <= 0:
        return x
    out = np.full(d.n, np.nan)
    for s0, s1 in d.segs:
        out[s0:s1] = _lag(x[s0:s1], d.dt, tau_s)
    return out


def _smoothed(d: AccelData, x: np.ndarray, tau_s: float) -> np.ndarray:
    """``x`` through the lag forwards and backwards, per segment: a zero-phase smoother of the
    same time constant (attenuation without delay)."""
    if tau_s <= 0:
        return x
    out = np.full(d.n, np.nan)
    for s0, s1 in d.segs:
        out[s0:s1] = _lag(_lag(x[s0:s1], d.dt, tau_s)[::-1], d.dt, tau_s)[::-1]
    return out


def _design(d: AccelData, tau_s: float, mount: bool, zero_phase: bool = False) -> np.ndarray:
    filt = _smoothed if zero_phase else _lagged
    cols = [filt(d, d.a, tau_s)]
    if mount:
        assert d.q is not None  # a mounting hypothesis needs the lateral accelerometer
        cols.append(filt(d, d.q, tau_s))
    cols.append(np.ones(d.n))
    return np.column_stack(cols)


def fit(
    d: AccelData, tau_s: float, mount: bool, mask: np.ndarray, zero_phase: bool = False
) -> AccelFit:
    X = _design(d, tau_s, mount, zero_phase)
    use = mask & d.ok & np.isfinite(X).all(axis=1)
    Xu, y = X[use], d.m[use]
    coef, *_ = np.linalg.lstsq(Xu, y, rcond=None)
    r = y - Xu @ coef
    sse = float(r @ r)
    n, k = int(use.sum()), Xu.shape[1] + (tau_s > 0)
    s2 = sse / max(n - Xu.shape[1], 1)
    try:
        cov = s2 * np.linalg.inv(Xu.T @ Xu)
    except np.linalg.LinAlgError:
        cov = np.full((Xu.shape[1], Xu.shape[1]), np.nan)
    return AccelFit(float(tau_s), mount, coef, sse, n, k, cov)


def predict(d: AccelData, f: AccelFit) -> np.ndarray:
    return _design(d, f.tau_s, f.mount) @ f.coef


def residual(d: AccelData, f: AccelFit) -> np.ndarray:
    r = d.m - predict(d, f)
    r[~d.ok] = np.nan
    return r


def _tau_grid(d: AccelData) -> np.ndarray:
    return np.round(np.arange(0.0, TAU_MAX_S + 1e-9, max(2 * d.dt, 0.02)), 6)


def fit_best(
    d: AccelData,
    name: str | None,
    mask: np.ndarray,
    mount: bool = False,
    grid: np.ndarray | None = None,
):
    """The fit of hypothesis ``name`` on ``mask`` (``mount``: with the mounting rotation, for
    the lag on top of it). Returns (fit, tau grid or None, SSE per sample on it or None)."""
    if name == "accelerometer_lag":
        refine = grid is None
        grid = _tau_grid(d) if grid is None else np.asarray(grid, float)
        return grid_search(
            lambda g: fit(d, g, mount, mask),
            grid,
            max(d.dt, 0.01) if refine else None,
            end_pad=1e-12,
            atol=max(d.dt, 0.01) / 10 if refine else 0.0,
        )
    return fit(d, 0.0, mount or name == "sensor_mounting", mask), None, None


@dataclass
class AccelScore:
    """Held-out and full-data results of one accelerometer hypothesis (a
    :class:`~models.diagnose.hypothesis.HypothesisScore`)."""

    name: str | None
    model: AccelFit
    heldout_rmse_mps2: float
    heldout_err: np.ndarray
    bic: float
    params: dict
    intervals: dict


def evaluate(
    d: AccelData, name: str | None, cfg: DiagnoseConfig, corr_len: float, mount: bool = False
) -> AccelScore:
    """Blocked held-out score and the full-data fit of ``name`` (None: the baseline;
    ``mount``: every fit keeps the mounting rotation)."""
    folds = segment_fold_ids(d.n, d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    full, grid, sse_grid = fit_best(d, name, d.ok, mount)
    local = None
    if name == "accelerometer_lag":
        step = max(2 * d.dt, 0.02)
        local = np.unique(np.maximum(full.tau_s + step * np.arange(-2, 3), 0.0))
    err = np.full(d.n, np.nan)
    for f in range(cfg.n_folds):
        m, _, _ = fit_best(d, name, train_mask(folds, f, guard), mount, grid=local)
        test = (folds == f) & d.ok
        err[test] = (d.m - predict(d, m))[test]
    params, intervals = {}, {}
    ne_scale = max(corr_len, 1.0)
    if full.mount:
        c1, c2 = full.coef[0], full.coef[1]
        cov = full.cov[:2, :2] * ne_scale
        g2 = c1 * c1 + c2 * c2
        jac = np.array([-c2 / g2, c1 / g2])  # d psi / d(c1, c2)
        se = float(np.sqrt(max(jac @ cov @ jac, 0.0)))
        params["yaw_rad"] = full.yaw_rad
        intervals["yaw_rad"] = [full.yaw_rad - 1.96 * se, full.yaw_rad + 1.96 * se]
    if name == "accelerometer_lag":
        params["tau_s"] = full.tau_s
        lo, hi = profile_interval(grid, sse_grid * full.n, full.n, corr_len)
        half = 0.5 * float(np.min(np.diff(grid))) if len(grid) > 1 else 0.0
        intervals["tau_s"] = [max(lo - half, 0.0), hi + half]
    if name is not None:
        params["gain"] = full.gain
        params["offset_mps2"] = float(full.coef[-1])
    return AccelScore(
        name, full, rmse(err), err, bic(full.sse, full.n, full.k, corr_len), params, intervals
    )


def zero_phase(d: AccelData, mount: bool = False) -> tuple[float, float]:
    """(time constant [s], SSE per sample) of the best zero-phase smoother of the speed's
    derivative (:func:`_smoothed`): the alternative to a lag. When it fits as well as the lag,
    the accelerometer reads a smoother signal (a narrower bandwidth), not a later one."""
    m, grid, sse = grid_search(lambda g: fit(d, g, mount, d.ok, zero_phase=True), _tau_grid(d))
    return m.tau_s, float(np.nanmin(sse))


def excludes_null(name: str, s: AccelScore) -> bool:
    """The parameter's interval excludes the baseline's value (psi = 0, tau = 0)."""
    key = {"sensor_mounting": "yaw_rad", "accelerometer_lag": "tau_s"}[name]
    lo, hi = s.intervals.get(key, (np.nan, np.nan))
    if name == "accelerometer_lag":
        return bool(lo > 0.0)
    return bool(lo > 0.0 or hi < 0.0)
