"""Steering map identification: road-wheel angle = offset + scale * steering-wheel angle (eq. 7).

Geometry (ISO 8855; the report's eq. 1 point F is the front-axle centre, moving at speed v in
the direction heading + delta, yaw rate r = v sin(delta) / b, b = wheelbase): with no tyre
slip, the front wheels at F +- T_f/2 move at ``fl, fr = |(v cos(delta) -+ r T_f/2, v sin(delta))|``
and the rear-axle centre at ``v_R = v cos(delta) = (rl + rr) / 2``. Two measurements of the
road-wheel angle delta of the virtual middle tyre follow:

(a) **front wheel-speed difference** (the report's eqs. 2-6): eq. 5 gives the turn rate
    ``omega = (fr - fl) / T_f``. Eq. 6 as printed, ``delta_t = omega / v``, is the path
    *curvature* [1/m], not an angle; the angle follows from the kinematic relation with the
    wheelbase, ``sin(delta) = b omega / v``. hmpc inverts the exact rigid-body relations above,
    ``fr^2 - fl^2 = T_f v^2 sin(2 delta) / b`` and ``fl^2 + fr^2 = 2 v^2 (1 + T_f^2 sin^2(delta) /
    (4 b^2))`` (closed form), which reduce to eqs. 5-6 with the wheelbase for small
    angles and stay exact at full lock (0.66 rad), where eq. 5 alone is 5-20% off.
(b) **yaw rate and speed**: ``tan(delta) = b r / v_R`` (= atan(L r / v) with v the rear-axle
    speed; equivalently sin(delta) = b r / v with the front-axle speed). Fitted in the rate
    domain, ``r = r_bias + v_R tan(offset + scale * sw) / b``, where the yaw-rate noise is white
    and a gyro bias ``r_bias`` [rad/s] is estimated with the map: at 2.4 m/s a 0.002 rad/s bias
    would otherwise shift the offset by 0.0022 rad. Separating the bias from the offset needs
    a range of speeds (the parameter correlation is reported). Standstill samples are not used
    to pin the bias: a quantised channel at rest reads its step nearest 0 (Toyota's YAW_RATE,
    0.244 deg/s steps, reads -0.072 deg/s throughout the 2019 RAV4's 24 s at rest in
    tools/data), which bounds the bias only to +-0.0021 rad/s, i.e. the offset to +-b/v times
    that (+-12% of a 0.017 rad offset at 2.5 m/s). The same rounding, on a steady arc that
    reads one level throughout, is an error the bias and offset absorb and no residual shows:
    a channel that rests on whole steps (:func:`~hmpc.models.identify.stats.quantisation_step`)
    adds it to the intervals (:func:`~hmpc.models.identify.stats.quantisation_cov`; without it
    the interval covered the true offset on 19 of 60 seeded rounded arcs). Without wheel
    speeds the speed is ``gps_speed`` with the geometry's ``nav_lever_arm_m`` (then ``v_R``
    follows exactly, :func:`rear_axle_speed`), else ``speed`` or ``gps_speed`` at an unknown
    point on the centre line, at |x_s| from the rear axle, which moves at
    ``v_R sqrt(1 + (x_s/b)^2 tan^2(delta))``:
    ``k = (x_s/b)^2`` is estimated with the map (it acts on the cubic term only; 4% of the
    angle at 0.3 rad), and the axle speeds for the replay follow from it and the yaw rate.

**Methods the recording supports**: (a) needs the four wheel speeds, (b) ``yaw_rate`` and a
speed, the replay ``x``, ``y``, ``heading`` and a speed; each skipped method is named with the
missing channel (``report['selection']['skipped']``), and a recording that supports none is
an InputError naming them. The sample checks use the measured angle available (the slip check
needs the wheel speeds).

**Trustworthy samples** (:class:`SteeringIdConfig`, each threshold with its reason): moving
(front-axle speed >= ``v_min_mps``), forward gear, finite channels, no wheel slip (rear-axle
speed within ``slip_max`` of ``v cos(delta)``), longitudinal acceleration within
``accel_max_mps2`` and lateral acceleration within ``lat_accel_max_mps2`` (the tyres' linear
range), and, for the least-squares fits, no transients (steering-wheel rate below
``sw_rate_max_radps``); every excluded sample also excludes ``guard_s`` around it.

**Dead time** (:func:`dead_time_cv`): decided by held-out prediction. On a one-sample lag grid,
eq. 7 is fitted to the measured road-wheel angle (the source whose derivative
cross-correlates best with the steering rate: a cross-check, reported) over blocked folds;
the interval is the run of lags whose held-out error is not worse than the best lag's beyond
the fold-to-fold noise (fold-paired t-test), and a delay is used only when lag 0 lies outside
it; otherwise it is "not determined" and 0 is used. The fits use the steering-wheel angle
delayed by it.

**Refinement** (the report's "compare the actual position with our estimate"): the bicycle model
(eq. 1) is replayed over non-overlapping windows of ``window_s`` from the measured position and
heading at each window's start, driven by the measured front-axle speed and the delayed
steering-wheel angle, and offset and scale minimise the position error
(``scipy.optimize.least_squares``). Needs ``x``, ``y``, ``heading`` (body yaw, ENU). Eq. 1 moves
the front-axle centre F, the recording gives the nav point N = F + R(heading) (lever - [b, 0]):
the geometry's ``vehicle.nav_lever_arm_m`` when given, else the lever arm's x is estimated
with the map (y taken as 0, bounds ``lever_arm_x_bounds_m``) and reported; when it cannot be
separated from the map the replay is marked untrusted and never chosen.

**Choice** (:func:`cross_validate`, :func:`choose_fit`): blocked cross-validation over
``cv_folds`` contiguous folds; each fit, refitted without the fold, predicts the road-wheel
angle of the independent channel(s) it did not use, normalised by that channel's own held-out
error; the lowest score among the trusted identifiable fits is the final estimate. The choice,
every score and every disagreement (95% intervals that do not overlap beyond
``agree_offset_rad``/``agree_scale_rel``, with the likely cause) are in
``report['selection']``; a disagreement makes the estimate "NOT identifiable".

**Intervals**: 95%, from sandwich covariances that allow correlated residuals
(``models.stats``): time-block clusters for the direct fits, replay windows as clusters for the
refinement, Student-t critical values.

**Identifiability** (:func:`identifiability`): the final estimate is called identifiable only
when enough trustworthy samples exist, the steering-wheel range is wide enough, offset and
scale are not too correlated, their intervals are narrow, and some steering happened at speeds
where the kinematic (no side-slip) assumption holds. Otherwise ``identifiable`` is False and the
note says plainly what the recording cannot separate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from hmpc.models.errors import InputError
from hmpc.models.params import Vehicle
from hmpc.models.plant import heading_rate, position_rates, road_wheel_angle
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import (Z95, block_cov, cluster_cov, dilate, ols_hac,
                                       quantisation_cov, quantisation_step, savgol_derivative)


@dataclass(frozen=True)
class SteeringIdConfig:
    """Thresholds of steering identification (the reason for each number in its comment)."""

    #: [m/s] below this the 0.01 km/h wheel-speed step is > 0.4% of the speed difference a
    #: 1 deg road-wheel angle makes; the report's slowest arcs run at 2.4 m/s.
    v_min_mps: float = 1.5
    #: [1] rear-axle speed vs front-axle speed x cos(delta): 3% is well above the 0.01 km/h
    #: quantisation at 1.5 m/s (0.2%) and below the slip of hard traction or braking.
    slip_max: float = 0.03
    #: [m/s^2] |dv/dt| above this (about 0.3 g) means longitudinal tyre slip.
    accel_max_mps2: float = 3.0
    #: [m/s^2] lateral acceleration above 0.4 g leaves the tyres' linear range (side slip).
    lat_accel_max_mps2: float = 4.0
    #: [rad/s] steering-wheel rate above ~86 deg/s: transients (tyre relaxation, yaw lag, message
    #: timing) dominate; excluded from the direct fits only (the replay handles dynamics).
    sw_rate_max_radps: float = 1.5
    #: [s] excluded margin around every excluded sample (resampling and smoothing spread).
    guard_s: float = 0.3
    #: [s] Savitzky-Golay window for the steering rate, accelerations and the dead time.
    smooth_s: float = 0.5
    #: [s] dead-time search range (negative: measurement leads, a clock problem).
    dead_time_min_s: float = -0.2
    dead_time_max_s: float = 1.0
    #: [1] a source's cross-correlation lag is reported as a cross-check only when its peak
    #: reaches this (the dead time itself is decided by held-out prediction, below).
    dead_time_min_corr: float = 0.3
    #: [1] contiguous folds of the blocked cross-validation over the dead time's lag grid: ten
    #: folds of a 4-minute drive are 24 s each (several steering cycles), and t(9) = 2.26 keeps
    #: the fold-paired test of "better than no delay" from needing a huge effect.
    dead_time_cv_folds: int = 10
    #: [s] replay window of the refinement: long enough for a heading error to show in
    #: position, short enough that INS drift and model error stay small.
    window_s: float = 5.0
    #: [samples] position residual every this many samples (0.1 s at 50 Hz).
    replay_stride: int = 5
    #: [m] bounds of the estimated nav lever arm's x (no ``nav_lever_arm_m`` in the geometry):
    #: (low, margin beyond the front axle); a GNSS/INS antenna sits on the body, from behind the
    #: rear axle to over the bonnet.
    lever_arm_x_bounds_m: tuple = (-1.0, 2.0)
    #: [1] upper bound of k = (x_s / b)^2, x_s the unknown longitudinal distance of the speed
    #: channel's point from the rear axle (``speed`` from CAN, or ``gps_speed`` without
    #: ``nav_lever_arm_m``): 4 puts it up to two wheelbases away, beyond any antenna or any
    #: average of wheel speeds.
    speed_point_k_max: float = 4.0
    #: [1] the replay's starting scale when no direct fit exists and the geometry gives no
    #: ``steering_ratio``: 1/15, mid-range of passenger cars' ratios (12-18); the fit moves it.
    replay_start_scale: float = 1.0 / 15.0
    #: [m] half-width of the estimated lever arm's 95% interval above which the replay is not
    #: trusted: 0.25 m of lever arm moves the replayed front axle by ~1% of a 2.7 m wheelbase.
    max_lever_arm_ci_m: float = 0.25
    #: [1] contiguous folds of the blocked cross-validation that chooses the final fit.
    cv_folds: int = 5
    #: [rad] / [1] immaterial differences between fits: two fits disagree only when their 95%
    #: intervals, each widened by these, do not overlap. A tenth of the identifiability
    #: thresholds (``max_offset_ci_rad``, ``max_scale_rel_ci``): on long clean recordings the
    #: intervals shrink below the channels' own systematic resolution (0.1 deg steering-wheel
    #: steps, 0.01 km/h wheel-speed steps).
    agree_offset_rad: float = 0.0005
    agree_scale_rel: float = 0.01
    # ---- identifiability
    #: [s] least trustworthy data (500 samples at 50 Hz, 100 at 10 Hz: a duration, so that
    #: the recording's rate does not decide identifiability).
    min_trustworthy_s: float = 10.0
    #: [rad] steering-wheel range (2.5-97.5 percentile) needed: below ~29 deg at the wheel the
    #: road-wheel angle is < ~1.7 deg, comparable to sensor biases (tyre radius mismatch,
    #: gyro bias, angle-sensor zero).
    min_sw_range_rad: float = 0.5
    #: [1] |correlation| of the offset and scale estimates above this: not separable.
    max_param_corr: float = 0.95
    #: [1] relative half-width of the scale's 95% interval above this: gain not determined.
    max_scale_rel_ci: float = 0.10
    #: [rad] half-width of the offset's 95% interval above this (0.3 deg) : offset not determined.
    max_offset_ci_rad: float = 0.005
    #: [m/s] the kinematic map (no side slip) is checked only with steering below this speed.
    kinematic_speed_mps: float = 10.0
    #: [s] of trustworthy steering below ``kinematic_speed_mps`` needed.
    min_kinematic_s: float = 5.0


@dataclass
class MapFit:
    """One fit of eq. 7: estimates, 95% intervals, and how they were obtained."""

    method: str
    offset_rad: float
    scale: float
    offset_ci95_rad: tuple[float, float]
    scale_ci95: tuple[float, float]
    corr: float
    samples: int
    rms_error: float
    rms_unit: str
    ci_method: str
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"method": self.method, "offset_rad": self.offset_rad, "scale": self.scale,
                "offset_ci95_rad": list(self.offset_ci95_rad), "scale_ci95": list(self.scale_ci95),
                "offset_scale_correlation": self.corr, "samples": self.samples,
                f"rms_error_{self.rms_unit}": self.rms_error, "ci_method": self.ci_method,
                **self.extra}


@dataclass
class SteeringResult:
    """Outcome of :func:`identify_steering`.

    ``offset_rad``/``scale`` are the final estimate: the trusted fit with the best held-out
    score (:func:`choose_fit`; identifiable fits first), flagged NOT identifiable when the fits
    disagree beyond their intervals. ``fits`` holds all fits by name, ``report`` the
    JSON-ready figures, ``series`` time series for plots (road-wheel angle estimates etc.).
    """

    offset_rad: float
    scale: float
    offset_ci95_rad: tuple[float, float]
    scale_ci95: tuple[float, float]
    dead_time_s: float
    identifiable: bool
    note: str
    method: str
    rms_error_rad: float
    fits: dict[str, MapFit]
    report: dict
    series: dict = field(default_factory=dict, repr=False)


# ----------------------------------------------------------------------------- kinematics
def road_wheel_angle_from_front(fl_mps, fr_mps, wheelbase_m: float,
                                track_front_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(a) Road-wheel angle [rad] and front-axle-centre speed [m/s] from the front wheel speeds.

    Exact inverse of the no-slip rigid-body relations (module doc), in closed form: with
    ``k = 2 b (fr^2 - fl^2) / (T (fl^2 + fr^2)) = sin(2 delta) / (1 + c s)``, ``c = T^2/(4 b^2)``
    and ``s = sin^2(delta)``, ``k^2 (1 + c s)^2 = 4 s (1 - s)`` is a quadratic in s whose
    smaller root belongs to |delta| < 45 deg. The angle is NaN at rest (both wheels at 0) and
    the speed 0; both are NaN where a wheel speed is NaN.
    """
    fl = np.asarray(fl_mps, dtype=float)
    fr = np.asarray(fr_mps, dtype=float)
    b, T = float(wheelbase_m), float(track_front_m)
    S, Q = fr * fr - fl * fl, fl * fl + fr * fr
    c = T * T / (4.0 * b * b)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = 2.0 * b * S / (T * Q)
        k2 = k * k
        A, B = k2 * c * c + 4.0, 2.0 * k2 * c - 4.0
        disc = np.maximum(B * B - 4.0 * A * k2, 0.0)
        sq = np.clip((-B - np.sqrt(disc)) / (2.0 * A), 0.0, 0.5)
        delta = np.sign(k) * np.arcsin(np.sqrt(sq))
        v = np.sqrt(Q / (2.0 * (1.0 + c * np.nan_to_num(sq))))
    moving = Q > 0
    return np.where(moving, delta, np.nan), np.where(np.isfinite(Q), v, np.nan)


def road_wheel_angle_from_yaw(yaw_rate_radps, v_rear_mps, wheelbase_m: float,
                              yaw_bias_radps: float = 0.0) -> np.ndarray:
    """(b) Road-wheel angle [rad] = atan(b (r - bias) / v_R), v_R the rear-axle speed [m/s]."""
    r = np.asarray(yaw_rate_radps, dtype=float) - yaw_bias_radps
    v = np.asarray(v_rear_mps, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(v > 0, np.arctan(wheelbase_m * r / v), np.nan)


def rear_axle_speed(speed_mps, yaw_rate_radps, lever_m) -> np.ndarray:
    """Rear-axle-centre speed [m/s] from the speed [m/s] of a body point at ``lever_m`` = (x, y)
    [m] (body axes from the rear-axle centre) and the yaw rate [rad/s]: with no side slip at the
    rear axle the point moves at ``(v_R - r y, r x)``, so ``v_R = r y + sqrt(v^2 - (r x)^2)``."""
    v = np.asarray(speed_mps, dtype=float)
    r = np.asarray(yaw_rate_radps, dtype=float)
    lx, ly = float(lever_m[0]), float(lever_m[1])
    return r * ly + np.sqrt(np.maximum(v * v - (r * lx) ** 2, 0.0))


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


def xcorr_dead_time(u: np.ndarray, y: np.ndarray, mask: np.ndarray, dt_s: float, *,
                    min_lag_s: float, max_lag_s: float) -> tuple[float, float]:
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
    cc = np.fft.irfft(C * np.conj(A), nfft)       # cc[l] = sum_t y[t] u[t - l]
    a2 = np.fft.irfft(np.fft.rfft(a * a, nfft) * np.conj(np.fft.rfft(m.astype(float), nfft)), nfft)
    c2 = np.fft.irfft(np.fft.rfft(c * c, nfft) * np.conj(np.fft.rfft(m.astype(float), nfft)), nfft)
    # energy of u over samples t-l with t in mask and of y over t with t-l in mask
    vals = []
    for lag in lags:
        num = cc[lag % nfft]
        ea = a2[(-lag) % nfft]   # sum_t a[t-l]^2 m[t]
        ec = c2[lag % nfft]      # sum_t c[t]^2 m[t-l]
        vals.append(num / np.sqrt(ea * ec) if ea > 0 and ec > 0 else 0.0)
    vals = np.array(vals)
    k = int(np.argmax(vals))
    lag = float(lags[k])
    if 0 < k < len(vals) - 1:
        y0, y1, y2 = vals[k - 1], vals[k], vals[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag += 0.5 * (y0 - y2) / den
    return lag * dt_s, float(vals[k])


# ------------------------------------------------------------------------------ replay
def _windows(ok: np.ndarray, n_win: int) -> list[tuple[int, int]]:
    """Non-overlapping windows [i0, i1) of ``n_win`` samples inside the True runs of ``ok``."""
    out = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    for s, e in zip(idx[::2], idx[1::2]):
        for i0 in range(s, e - n_win + 1, n_win):
            out.append((i0, i0 + n_win))
    return out


class _Replay:
    """Vectorised eq. 1 replay over windows; residuals are predicted minus measured (x, y).

    Eq. 1 moves the front-axle centre F. The recorded position is the nav point N (GNSS/INS
    reference), ``N = F + R(psi) (lever - [b, 0])`` with ``lever`` [m] in body axes from the
    rear-axle centre and psi the recorded body heading (ENU yaw, the heading of eq. 1). Each
    window starts from F derived from the measured N and heading; the replayed F is carried
    back to N with the replayed heading and compared with the measurement. ``lever`` given:
    theta = (offset, scale); None: theta = (offset, scale, lever_x), lever_y = 0.
    """

    def __init__(self, windows, x, y, psi, v, sw, dt_s, b, stride, lever=None):
        self.dt, self.b, self.lever = dt_s, b, lever
        self.lever_x_fit = b  # the estimated lever arm's x once fitted (lever None)
        self.win_id = np.full(len(x), -1)
        self.start = np.zeros(len(x), dtype=int)
        for w, (i0, i1) in enumerate(windows):
            self.win_id[i0:i1] = w
            self.start[i0:i1] = i0
        self.inwin = self.win_id >= 0
        sel = np.zeros(len(x), dtype=bool)
        for i0, i1 in windows:
            sel[i0 + stride:i1:stride] = True
        self.res_idx = np.flatnonzero(sel)
        self.groups = np.concatenate([self.win_id[self.res_idx]] * 2)
        self.x, self.y, self.psi, self.v = x, y, psi, v
        self.sw = np.where(self.inwin, sw, 0.0)
        self.vz = np.where(self.inwin, v, 0.0)

    def arm(self, theta) -> tuple[float, float]:
        """(dx, dy) [m]: body-axes vector from the front-axle centre to the nav point."""
        if self.lever is not None:
            return float(self.lever[0]) - self.b, float(self.lever[1])
        lx = theta[2] if len(theta) > 2 else self.lever_x_fit
        return float(lx) - self.b, 0.0

    def predict(self, theta):
        """Nav-point positions from eq. 7 and eq. 1 (the plant's functions), integrated by the
        cumulative trapezoid from each window's first measured pose."""
        off, sc = theta[0], theta[1]
        dx, dy = self.arm(theta)
        p0 = self.psi[self.start]
        x0 = self.x[self.start] - (np.cos(p0) * dx - np.sin(p0) * dy)
        y0 = self.y[self.start] - (np.sin(p0) * dx + np.cos(p0) * dy)
        delta = road_wheel_angle(self.sw, off, sc)
        w = heading_rate(self.vz, delta, self.b)
        cw = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (w[1:] + w[:-1]))])
        psi = p0 + cw - cw[self.start]
        fx, fy = position_rates(psi, self.vz, delta)
        cx = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (fx[1:] + fx[:-1]))])
        cy = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (fy[1:] + fy[:-1]))])
        xp = x0 + cx - cx[self.start] + np.cos(psi) * dx - np.sin(psi) * dy
        yp = y0 + cy - cy[self.start] + np.sin(psi) * dx + np.cos(psi) * dy
        return xp, yp

    def residuals(self, theta):
        xp, yp = self.predict(theta)
        i = self.res_idx
        return np.concatenate([xp[i] - self.x[i], yp[i] - self.y[i]])


# -------------------------------------------------------------------------------- main
def _need(rec: Recording, *names: str) -> None:
    rec.require(*names)


def _fit_front(delta_a, sw_d, steady) -> MapFit:
    X = np.column_stack([np.ones_like(sw_d), sw_d])
    r = ols_hac(X, delta_a, steady)
    return MapFit("wheel_speed_difference", float(r.coef[0]), float(r.coef[1]),
                  (float(r.ci95[0, 0]), float(r.ci95[0, 1])),
                  (float(r.ci95[1, 0]), float(r.ci95[1, 1])), float(r.corr[0, 1]), r.n,
                  r.rmse, "rad", r.method, {"condition_number": r.cond})


def _fit_yaw(yaw, v, sw_d, steady, b, x0, k_max: float | None = None) -> MapFit:
    """Eq. 7 in the rate domain, ``r = r_bias + v tan(delta) / (b sqrt(1 + k tan^2(delta)))``.

    ``k_max`` None: ``v`` is the rear-axle speed and k = 0 (eq. (b) of the module doc).
    Otherwise ``v`` is the speed of a body point at an unknown distance x_s ahead of or behind
    the rear axle on the centre line, which moves at ``v_R sqrt(1 + (x_s/b)^2 tan^2(delta))``:
    k = (x_s / b)^2 is estimated with the map, within [0, k_max]. It is separable from the scale
    because it acts on the cubic term of the angle only; its interval is reported, and it
    widens the map's intervals through their correlation."""
    i = np.flatnonzero(steady & np.isfinite(yaw) & np.isfinite(v) & np.isfinite(sw_d))
    if len(i) < 10:
        raise ValueError("too few samples")
    r, vv, s = yaw[i], v[i], sw_d[i]
    fit_k = k_max is not None

    def res(th):
        t = np.tan(th[0] + th[1] * s)
        k = th[3] if fit_k else 0.0
        return r - th[2] - vv * t / (b * np.sqrt(1.0 + k * t * t))

    if fit_k:
        sol = least_squares(res, np.array([x0[0], x0[1], 0.0, 0.25 * k_max]), method="trf",
                            bounds=([-np.inf, -np.inf, -np.inf, 0.0],
                                    [np.inf, np.inf, np.inf, k_max]),
                            x_scale=np.array([0.01, 0.01, 0.001, 0.1]))
    else:
        sol = least_squares(res, np.array([x0[0], x0[1], 0.0]), method="lm")
    th = sol.x
    full = np.zeros(len(yaw))
    full[i] = sol.fun
    J = np.zeros((len(yaw), len(th)))
    J[i] = sol.jac
    m = np.zeros(len(yaw), dtype=bool)
    m[i] = True
    cov, _, G = block_cov(J, full, m)
    crit = float(student_t.ppf(0.975, max(G - 1, 1)))
    q = quantisation_step(yaw)
    if q is not None:
        # a steady arc reads one rounded level throughout; its error goes into the bias and
        # offset and never shows in the residuals. Known in law (uniform), so it enters at the
        # normal quantile: its covariance is scaled so that crit * se carries Z95 * its se.
        cov = cov + quantisation_cov(sol.jac, r, i, q) * (Z95 / crit) ** 2
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    d = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    corr = np.divide(cov, d, out=np.zeros_like(cov), where=d > 0)
    extra = {"yaw_rate_bias_radps": float(th[2]),
             "yaw_rate_bias_ci95_radps": [float(th[2] - crit * se[2]),
                                          float(th[2] + crit * se[2])],
             "offset_bias_correlation": float(corr[0, 2])}
    if fit_k:
        k, hk = float(th[3]), float(crit * se[3])
        extra.update({"speed_point_k": k, "speed_point_k_ci95": [k - hk, k + hk],
                      "speed_point_x_m": float(b * np.sqrt(k)),
                      "speed_point_source": "estimated with the map: |x| of the speed's point "
                                            "from the rear axle (the sign is not observable)",
                      "speed_point_at_bound": bool(min(k, k_max - k) < 1e-6)})
    return MapFit("yaw_rate", float(th[0]), float(th[1]),
                  (float(th[0] - crit * se[0]), float(th[0] + crit * se[0])),
                  (float(th[1] - crit * se[1]), float(th[1] + crit * se[1])), float(corr[0, 1]),
                  len(i), float(np.sqrt(np.mean(sol.fun ** 2))), "radps",
                  f"time-block cluster-robust sandwich (Jacobian), t({G - 1})"
                  + (f" + rounding of the yaw rate ({q:.2g} rad/s steps)" if q is not None else ""),
                  extra)


def _fit_replay(rec, v_front, sw_d, usable, dt, b, cfg, x0, lever=None):
    """Eq. 7 by the position replay (:class:`_Replay`). ``lever``: the geometry's
    ``nav_lever_arm_m``; None: its x is estimated with the map (bounded to
    ``cfg.lever_arm_x_bounds_m``) and the replay is untrusted when it cannot be separated
    from the map (``extra['trusted']``, ``extra['untrusted_because']``)."""
    x, y, psi = (np.asarray(rec[c], dtype=float) for c in ("x", "y", "heading"))
    ok = usable & np.isfinite(x) & np.isfinite(y) & np.isfinite(psi) & np.isfinite(sw_d)
    n_win = int(round(cfg.window_s / dt))
    wins = _windows(ok, n_win)
    if len(wins) < 3:
        return None, 0
    rp = _Replay(wins, x, y, np.unwrap(np.nan_to_num(psi)), np.nan_to_num(v_front),
                 np.nan_to_num(sw_d), dt, b, max(1, cfg.replay_stride), lever)
    theta0 = np.asarray(x0, dtype=float)[:2]
    if lever is None:
        lo_x, hi_x = cfg.lever_arm_x_bounds_m[0], b + cfg.lever_arm_x_bounds_m[1]
        theta0 = np.append(theta0, 0.5 * b)
        sol = least_squares(rp.residuals, theta0, method="trf", x_scale=np.array([0.01, 0.01, 1.0]),
                            bounds=([-np.inf, -np.inf, lo_x], [np.inf, np.inf, hi_x]))
    else:
        sol = least_squares(rp.residuals, theta0, method="lm", x_scale=np.array([0.01, 0.01]))
    if lever is None:
        rp.lever_x_fit = float(sol.x[2])
    cov = cluster_cov(sol.jac, sol.fun, rp.groups)
    G = len(wins)
    crit = float(student_t.ppf(0.975, max(G - 1, 1)))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    d = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    corr_m = np.divide(cov, d, out=np.zeros_like(cov), where=d > 0)
    corr = float(corr_m[0, 1])
    extra = {"windows": G, "window_s": cfg.window_s, "status": int(sol.status),
             "initial": [float(v) for v in x0], "trusted": True}
    if lever is not None:
        extra["nav_lever_arm_m"] = [float(lever[0]), float(lever[1])]
        extra["lever_arm_source"] = "geometry (vehicle.nav_lever_arm_m)"
    else:
        lx, half = float(sol.x[2]), float(crit * se[2])
        c_lever = float(np.max(np.abs(corr_m[2, :2])))
        extra.update({"nav_lever_arm_m": [lx, 0.0], "lever_arm_x_ci95_m": [lx - half, lx + half],
                      "lever_arm_source": "estimated with the map (y taken as 0)",
                      "lever_arm_map_correlation": c_lever})
        why = []
        if c_lever > cfg.max_param_corr:
            why.append(f"the lever arm's x is correlated {c_lever:.3f} with the map")
        if not half <= cfg.max_lever_arm_ci_m:
            why.append(f"the lever arm's x is known only to +-{half:.2f} m")
        if min(lx - lo_x, hi_x - lx) < 1e-3:
            why.append(f"the lever arm's x ({lx:.2f} m) is at its bound")
        if why:
            extra["trusted"] = False
            extra["untrusted_because"] = ("the position's reference point is not in the geometry "
                                          "(vehicle.nav_lever_arm_m) and " + "; ".join(why))
    fit = MapFit("position_replay", float(sol.x[0]), float(sol.x[1]),
                 (float(sol.x[0] - crit * se[0]), float(sol.x[0] + crit * se[0])),
                 (float(sol.x[1] - crit * se[1]), float(sol.x[1] + crit * se[1])), corr,
                 len(rp.res_idx), float(np.sqrt(np.mean(sol.fun ** 2))), "m",
                 f"cluster-robust sandwich over {G} replay windows, t({G - 1})", extra)
    return (fit, rp, sol.x), G


def identifiability(fit: MapFit, sw_steady: np.ndarray, v_steady: np.ndarray, dt_s: float,
                    cfg: SteeringIdConfig, steering_ratio: float | None = None) -> dict:
    """Checks that decide whether a recording separates offset from scale (module doc).

    Returns ``{"identifiable", "offset_identifiable", "scale_identifiable", "checks": [...],
    "note"}``; each check has name, value, threshold, passed.
    """
    checks = []

    def add(name, value, threshold, passed, text):
        checks.append({"name": name, "value": float(value), "threshold": float(threshold),
                       "passed": bool(passed), "text": text})

    n = len(sw_steady)
    need = int(math.ceil(cfg.min_trustworthy_s / dt_s - 1e-9))
    add("samples", n, need, n >= need,
        f"{n} trustworthy samples ({n * dt_s:.1f} s; need {cfg.min_trustworthy_s:g} s)")
    rng = float(np.subtract(*np.percentile(sw_steady, [97.5, 2.5]))) if n else 0.0
    add("steering_range_rad", rng, cfg.min_sw_range_rad, rng >= cfg.min_sw_range_rad,
        f"steering-wheel range {np.degrees(rng):.1f} deg (2.5-97.5%; need "
        f"{np.degrees(cfg.min_sw_range_rad):.0f} deg)")
    add("offset_scale_correlation", abs(fit.corr), cfg.max_param_corr,
        abs(fit.corr) <= cfg.max_param_corr, f"|corr(offset, scale)| = {abs(fit.corr):.3f}")
    half_s = 0.5 * (fit.scale_ci95[1] - fit.scale_ci95[0])
    rel = half_s / abs(fit.scale) if fit.scale != 0 else float("inf")
    add("scale_rel_ci95", rel, cfg.max_scale_rel_ci, rel <= cfg.max_scale_rel_ci,
        f"scale 95% interval +-{100 * rel:.1f}% (need <= {100 * cfg.max_scale_rel_ci:.0f}%)")
    half_o = 0.5 * (fit.offset_ci95_rad[1] - fit.offset_ci95_rad[0])
    add("offset_ci95_rad", half_o, cfg.max_offset_ci_rad, half_o <= cfg.max_offset_ci_rad,
        f"offset 95% interval +-{half_o:.4f} rad (need <= {cfg.max_offset_ci_rad} rad)")
    slow_s = float(np.sum(v_steady <= cfg.kinematic_speed_mps) * dt_s)
    add("kinematic_speed_s", slow_s, cfg.min_kinematic_s, slow_s >= cfg.min_kinematic_s,
        f"{slow_s:.1f} s of trustworthy steering at or below {cfg.kinematic_speed_mps:g} m/s "
        f"(need {cfg.min_kinematic_s:g} s)")
    # the gyro-bias check applies only to a fit that estimates a yaw-rate bias (the yaw-rate
    # fit); for the others it is not run, and not counted, by name below
    bias_corr = fit.extra.get("offset_bias_correlation")
    bias_applies = bias_corr is not None
    if bias_applies:
        add("offset_gyro_bias_correlation", abs(bias_corr), cfg.max_param_corr,
            abs(bias_corr) <= cfg.max_param_corr,
            f"|corr(offset, yaw-rate bias)| = {abs(bias_corr):.3f}")
    # every check that applies is looked up by name: one that was not run raises KeyError,
    # it never counts as passed
    ok = {c["name"]: c["passed"] for c in checks}
    bias_ok = ok["offset_gyro_bias_correlation"] if bias_applies else True
    base = ok["samples"] and ok["steering_range_rad"] and ok["offset_scale_correlation"]
    scale_ok = base and ok["scale_rel_ci95"] and ok["kinematic_speed_s"]
    offset_ok = base and ok["offset_ci95_rad"] and bias_ok
    notes = []
    if not ok["samples"]:
        notes.append("too few trustworthy samples")
    if not ok["steering_range_rad"]:
        notes.append(f"the steering-wheel range ({np.degrees(rng):.1f} deg) is too small to "
                     "separate the offset from sensor biases (tyre radius mismatch, gyro bias, "
                     "angle-sensor zero) or the scale from noise")
    if not ok["offset_scale_correlation"]:
        notes.append("offset and scale estimates are strongly correlated (steering mostly to one "
                     "side)")
    if not ok["scale_rel_ci95"]:
        notes.append(f"the scale is known only to +-{100 * rel:.0f}%")
    if not ok["offset_ci95_rad"]:
        notes.append(f"the offset is known only to +-{half_o:.4f} rad")
    if not bias_ok:
        # the offset's yaw rate is v tan(offset)/b, the bias a constant: only the spread of
        # the speeds tells them apart; say which speeds there were and what that left
        vs = np.asarray(v_steady, dtype=float)
        vs = vs[np.isfinite(vs)]
        span = (f"{np.percentile(vs, 2.5):.1f}-{np.percentile(vs, 97.5):.1f} m/s, "
                if vs.size else "")
        notes.append("the speed range is too narrow to separate the offset from the yaw-rate "
                     f"sensor's bias ({span}|corr(offset, bias)| = {abs(bias_corr):.3f}: "
                     f"offset +-{half_o:.4f} rad; arcs at other speeds separate them)")
    if not ok["kinematic_speed_s"]:
        notes.append(_kinematic_note(v_steady, slow_s, cfg))
    if notes:
        note = "NOT identifiable: " + "; ".join(notes) + "."
        if steering_ratio:
            note += (f" For comparison, the maker's nominal 1/steering_ratio = "
                     f"{1.0 / steering_ratio:.4f}.")
    else:
        note = "offset and scale identifiable from this recording"
    return {"identifiable": bool(scale_ok and offset_ok), "offset_identifiable": bool(offset_ok),
            "scale_identifiable": bool(scale_ok), "checks": checks, "note": note}


def _kinematic_note(v_steady: np.ndarray, slow_s: float, cfg) -> str:
    """Why the kinematic-speed check failed, from the speeds it saw: all steering above the
    kinematic speed (understeer folded into the gain), or simply too little of it."""
    v = np.asarray(v_steady, dtype=float)
    v = v[np.isfinite(v)]
    if v.size and slow_s == 0.0:
        return (f"all trustworthy steering happened above {cfg.kinematic_speed_mps:g} m/s "
                f"({np.min(v):.1f}-{np.max(v):.1f} m/s), where tyre side slip (understeer) is "
                "folded into the kinematic gain")
    span = f" (speeds {np.min(v):.1f}-{np.max(v):.1f} m/s)" if v.size else ""
    fast = (f"; above {cfg.kinematic_speed_mps:g} m/s tyre side slip (understeer) is folded "
            "into the kinematic gain") if v.size and np.max(v) > cfg.kinematic_speed_mps else ""
    return (f"only {slow_s:.1f} s of trustworthy steering at or below "
            f"{cfg.kinematic_speed_mps:g} m/s{span}, {cfg.min_kinematic_s:g} s are needed{fast}")


#: the four wheel speeds, which the wheel-speed-difference method needs
WHEEL_SPEEDS = ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")
#: speed channels for the yaw-rate method and the replay when the wheel speeds are absent
SPEED_CHANNELS = ("speed", "gps_speed")
#: the channel each direct fit is made on (its own channel); the replay uses neither
OWN_CHANNEL = {"wheel_speed_difference": "wheel_speeds", "yaw_rate": "yaw_rate",
               "position_replay": None}


@dataclass
class SteeringSignals:
    """The recording's channels for steering identification, and measurement (a).

    Attributes:
        sw: steering-wheel angle [rad]; fl, fr, rl, rr: wheel speeds [m/s] (None when absent).
        delta_a: road-wheel angle from the front wheel speeds [rad] (None without them);
            v_front: front-axle-centre speed [m/s]; v_rear: rear-axle-centre speed [m/s].
        yaw: yaw rate [rad/s], None when the recording has none.
        dt_s: sample interval [s]; b, T: wheelbase and front track [m].
        speed_source: where the speeds come from ("wheel speeds", "speed", "gps_speed");
            v_src: that channel [m/s]; speed_point_unknown: its body point is not known (the
            yaw-rate fit estimates it, :func:`_fit_yaw`); speed_note: how v_front/v_rear follow.
        skipped: method -> why the recording does not support it (named channel).
    """

    sw: np.ndarray
    fl: np.ndarray | None
    fr: np.ndarray | None
    rl: np.ndarray | None
    rr: np.ndarray | None
    delta_a: np.ndarray | None
    v_front: np.ndarray
    v_rear: np.ndarray
    yaw: np.ndarray | None
    dt_s: float
    b: float
    T: float
    speed_source: str = "wheel speeds"
    v_src: np.ndarray | None = None
    speed_point_unknown: bool = False
    speed_note: str = "front- and rear-axle speeds from the wheel speeds"
    skipped: dict = field(default_factory=dict)


@dataclass
class SampleMasks:
    """Which samples to trust (module doc): ``usable`` for the dead time and the replay,
    ``steady`` (usable and no steering transient) for the direct fits; ``excluded`` counts why
    (None: a check the channels do not allow)."""

    usable: np.ndarray
    steady: np.ndarray
    excluded: dict


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
        fin = (lambda v: float(v) if np.isfinite(v) else None)
        return {"estimate_s": fin(self.estimate_s), "interval_s": [fin(v) for v in self.interval_s],
                "used": self.used, "determined": self.used,
                "note": (f"dead time {self.tau_s:.3f} s" if self.used else
                         "not determined: no lag predicts held-out data better than no delay "
                         "beyond the fold-to-fold noise"),
                "source": self.source, "peak_correlation": fin(self.peak_corr),
                "by_source": {k: {"lag_s": fin(v[0]), "peak_correlation": fin(v[1])}
                              for k, v in self.by_source.items()},
                "cv": self.cv,
                "method": "blocked cross-validation of eq. 7 over a one-sample lag grid "
                          "(fold-paired t-test against the best lag; parabolic refinement); "
                          "cross-check: cross-correlation of Savitzky-Golay derivatives "
                          f"({smooth_s} s)"}


def steering_signals(rec: Recording, vehicle: Vehicle) -> SteeringSignals:
    """The channels steering identification uses, and which methods they support.

    Wheel-speed difference: the four wheel speeds. Yaw rate: ``yaw_rate`` and a speed (the
    rear wheel speeds, else ``gps_speed`` with the geometry's ``nav_lever_arm_m``, else
    ``speed`` or ``gps_speed`` at a point estimated with the map). Replay: ``x``, ``y``,
    ``heading`` and a speed. Raises InputError (naming the channels) when none is supported.
    """
    _need(rec, "steering_wheel_angle")
    b, T = float(vehicle.wheelbase_m), float(vehicle.track_front_m)
    sw = np.asarray(rec["steering_wheel_angle"], dtype=float)
    yaw = np.asarray(rec["yaw_rate"], dtype=float) if "yaw_rate" in rec else None
    lever = getattr(vehicle, "nav_lever_arm_m", None)
    missing_ws = next((c for c in WHEEL_SPEEDS if c not in rec), None)
    missing_pos = next((c for c in ("x", "y", "heading") if c not in rec), None)
    skipped: dict[str, str] = {}
    kw: dict = {}
    if missing_ws is None:
        fl, fr, rl, rr = (np.asarray(rec[c], dtype=float) for c in WHEEL_SPEEDS)
        delta_a, v_front = road_wheel_angle_from_front(fl, fr, b, T)
        v_rear = 0.5 * (rl + rr)
        kw["v_src"] = v_rear
    else:
        fl = fr = rl = rr = delta_a = None
        skipped["wheel_speed_difference"] = (f"no channel '{missing_ws}' (needs the four wheel "
                                             "speeds)")
        src = ("gps_speed" if lever is not None and yaw is not None and "gps_speed" in rec
               else next((c for c in SPEED_CHANNELS if c in rec), None))
        if src is None:
            why = "no speed: no wheel speeds, no channel 'speed' and no channel 'gps_speed'"
            skipped.setdefault("yaw_rate", why)
            skipped.setdefault("position_replay", why)
            v_front = v_rear = v_src = np.full(len(sw), np.nan)
        else:
            v_src = np.asarray(rec[src], dtype=float)
            if src == "gps_speed" and lever is not None and yaw is not None:
                v_rear = rear_axle_speed(v_src, yaw, lever)
                v_front = np.hypot(v_rear, b * yaw)
                note = (f"rear- and front-axle speeds from 'gps_speed' at the geometry's "
                        f"nav_lever_arm_m {list(lever)} and the yaw rate")
                unknown = False
            else:
                v_front = v_rear = v_src
                unknown = True
                note = (f"'{src}' at an unknown body point: " +
                        ("its distance from the rear axle is estimated with the map by the "
                         "yaw-rate fit" if yaw is not None else
                         "taken as the front-axle speed (no yaw rate to place it)"))
            kw.update(speed_source=src, v_src=v_src, speed_point_unknown=unknown,
                      speed_note=note)
    if yaw is None:
        skipped.setdefault("yaw_rate", "no channel 'yaw_rate'")
    if missing_pos is not None:
        skipped.setdefault("position_replay", f"no channel '{missing_pos}' (needs x, y, heading)")
    if len(skipped) == 3:
        raise InputError("no steering method has its channels: " + "; ".join(
            f"{m}: {why}" for m, why in skipped.items()), rec.meta.get("path"),
            channel=missing_ws or "yaw_rate")
    return SteeringSignals(sw, fl, fr, rl, rr, delta_a, v_front, v_rear, yaw, 1.0 / rec.rate_hz,
                           b, T, skipped=skipped, **kw)


def _measured_angle(sig: SteeringSignals) -> np.ndarray:
    """A measured road-wheel angle [rad] for the sample checks: from the wheel speeds, else
    from the yaw rate and the rear-axle speed (provisional), else zeros (replay only)."""
    if sig.delta_a is not None:
        return sig.delta_a
    if sig.yaw is not None:
        return road_wheel_angle_from_yaw(sig.yaw, sig.v_rear, sig.b)
    return np.where(np.isfinite(sig.v_rear), 0.0, np.nan)


def trustworthy_samples(rec: Recording, sig: SteeringSignals,
                        cfg: SteeringIdConfig) -> SampleMasks:
    """The samples to trust (module doc), with a count per reason of exclusion (the slip check
    needs the wheel speeds: None when they are absent).

    Raises:
        InputError: fewer than 20 trustworthy samples.
    """
    dt, sw, v_front, v_rear = sig.dt_s, sig.sw, sig.v_front, sig.v_rear
    delta_m = _measured_angle(sig)
    finite = np.isfinite(sw) & np.isfinite(delta_m) & np.isfinite(v_rear)
    moving = finite & (np.nan_to_num(v_front) >= cfg.v_min_mps)
    slip = np.zeros(len(sw))
    if sig.delta_a is not None:
        with np.errstate(invalid="ignore"):
            slip = np.abs(v_rear - v_front * np.cos(delta_m)) / np.maximum(v_front, 1e-6)
    accel = savgol_derivative(v_rear, dt, cfg.smooth_s)
    lat = v_rear ** 2 * np.tan(np.nan_to_num(delta_m)) / sig.b
    sw_rate = savgol_derivative(sw, dt, cfg.smooth_s)
    reverse = np.zeros(len(sw), dtype=bool)
    if "gear" in rec:
        reverse = np.asarray([str(g) == "R" for g in rec["gear"]])
    bad_usable = ~(moving & (np.nan_to_num(slip, nan=1.0) <= cfg.slip_max)
                   & (np.abs(np.nan_to_num(accel, nan=1e9)) <= cfg.accel_max_mps2)
                   & (np.abs(lat) <= cfg.lat_accel_max_mps2) & ~reverse)
    if sig.yaw is not None:
        bad_usable |= ~np.isfinite(sig.yaw)
    guard = int(round(cfg.guard_s / dt))
    usable = ~dilate(bad_usable, guard)
    transient = np.abs(np.nan_to_num(sw_rate, nan=1e9)) > cfg.sw_rate_max_radps
    steady = usable & ~dilate(transient, guard)
    excluded = {
        "not_moving_or_missing": int(np.sum(~moving)),
        "wheel_slip": (int(np.sum(moving & (np.nan_to_num(slip, nan=1.0) > cfg.slip_max)))
                       if sig.delta_a is not None else None),
        "longitudinal_accel": int(np.sum(moving & (np.abs(np.nan_to_num(accel, nan=0)) >
                                                   cfg.accel_max_mps2))),
        "lateral_accel": int(np.sum(moving & (np.abs(lat) > cfg.lat_accel_max_mps2))),
        "reverse": int(np.sum(reverse)),
        "steering_transient": int(np.sum(usable & ~steady)),
    }
    if steady.sum() < 20:
        raise InputError(f"only {int(steady.sum())} trustworthy steering samples (moving >= "
                         f"{cfg.v_min_mps} m/s, no slip, no transients): cannot identify the "
                         "steering map", rec.meta.get("path"), channel="steering_wheel_angle")
    return SampleMasks(usable, steady, excluded)


def _shifted(x: np.ndarray, lag: int) -> np.ndarray:
    """``x[t - lag]`` on the same grid (integer lag in samples), NaN where it reaches outside."""
    out = np.full(len(x), np.nan)
    if lag >= 0:
        out[lag:] = x[:len(x) - lag]
    else:
        out[:lag] = x[-lag:]
    return out


def dead_time_cv(sw: np.ndarray, meas: np.ndarray, mask: np.ndarray, dt_s: float,
                 cfg: SteeringIdConfig) -> dict | None:
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
    lags = np.arange(int(np.ceil(cfg.dead_time_min_s / dt_s - 1e-9)),
                     int(np.floor(cfg.dead_time_max_s / dt_s + 1e-9)) + 1)
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
    return {"best_s": best * dt_s,
            "interval_s": [(float(lags[lo]) - 0.5) * dt_s, (float(lags[hi]) + 0.5) * dt_s],
            "used": bool(used), "folds": int(Kk), "samples": int(ok.sum()),
            "excess_at_zero": (float(D[j0].mean() / mean[jb]) if j0 is not None else None),
            "excess_at_zero_t": (float(D[j0].mean() / se[j0]) if j0 is not None and se[j0] > 0
                                 else None), "t_critical": crit}


def estimate_dead_time(sig: SteeringSignals, usable: np.ndarray,
                       cfg: SteeringIdConfig) -> DeadTime:
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
    dead = {k: xcorr_dead_time(d_sw, savgol_derivative(m, dt, cfg.smooth_s), usable, dt,
                               min_lag_s=cfg.dead_time_min_s, max_lag_s=cfg.dead_time_max_s)
            for k, m in meas.items()}
    src = max(dead, key=lambda k: np.nan_to_num(dead[k][1], nan=-1))
    cv = dead_time_cv(sig.sw, meas[src], usable, dt, cfg)
    if cv is None:
        return DeadTime(0.0, nan, dead[src][1], False, src, dead)
    tau = cv["best_s"] if cv["used"] else 0.0
    return DeadTime(float(tau), cv["best_s"], dead[src][1], cv["used"], src, dead,
                    tuple(cv["interval_s"]), cv)


def _speed_point_update(sig: SteeringSignals, fit: MapFit) -> None:
    """With the speed channel's point estimated by the yaw-rate fit (k = (x_s/b)^2), the
    rear- and front-axle speeds follow from it and the bias-free yaw rate (in place)."""
    k = fit.extra.get("speed_point_k")
    if k is None or sig.v_src is None:
        return
    r = sig.yaw - fit.extra["yaw_rate_bias_radps"]
    sig.v_rear = rear_axle_speed(sig.v_src, r, (sig.b * np.sqrt(k), 0.0))
    sig.v_front = np.hypot(sig.v_rear, sig.b * r)


def _fit_direct(sig: SteeringSignals, sw_d: np.ndarray, mask: np.ndarray, cfg: SteeringIdConfig,
                methods=("wheel_speed_difference", "yaw_rate"), start=None) -> dict[str, MapFit]:
    """The direct fits the channels support, on ``mask``: (a) on the wheel-speed angle, (b) on
    the yaw rate (started from (a), ``start``, or a linear fit of its own angle; the speed's
    point estimated when unknown). A yaw-rate fit that does not converge is left out."""
    fits: dict[str, MapFit] = {}
    if sig.delta_a is not None and "wheel_speed_difference" in methods:
        fits["wheel_speed_difference"] = _fit_front(sig.delta_a, sw_d, mask)
    if sig.yaw is not None and "yaw_rate" in methods:
        x0 = fits.get("wheel_speed_difference") or start
        try:
            if x0 is None:
                x0 = _fit_front(road_wheel_angle_from_yaw(sig.yaw, sig.v_src, sig.b), sw_d,
                                mask & np.isfinite(sig.v_src) & (np.nan_to_num(sig.v_src) > 0))
            k_max = cfg.speed_point_k_max if sig.speed_point_unknown else None
            fits["yaw_rate"] = _fit_yaw(sig.yaw, sig.v_src if k_max else sig.v_rear, sw_d,
                                        mask, sig.b, (x0.offset_rad, x0.scale), k_max)
        except (ValueError, np.linalg.LinAlgError):
            pass
    return fits


def direct_fits(sig: SteeringSignals, sw_d: np.ndarray, steady: np.ndarray,
                cfg: SteeringIdConfig | None = None) -> dict[str, MapFit]:
    """The direct fits of eq. 7 on the trustworthy samples (:func:`_fit_direct`); a yaw-rate
    fit that estimated its speed's point updates ``sig``'s axle speeds."""
    fits = _fit_direct(sig, sw_d, steady, cfg or SteeringIdConfig())
    if "yaw_rate" in fits and sig.speed_point_unknown:
        _speed_point_update(sig, fits["yaw_rate"])
    return fits


def _yaw_angle(sig: SteeringSignals, fit: MapFit) -> np.ndarray:
    """The yaw-rate road-wheel angle [rad] with ``fit``'s gyro bias (and speed point) applied."""
    bias = fit.extra["yaw_rate_bias_radps"]
    k = fit.extra.get("speed_point_k")
    v_r = sig.v_rear if k is None else rear_axle_speed(sig.v_src, sig.yaw - bias,
                                                       (sig.b * np.sqrt(k), 0.0))
    return road_wheel_angle_from_yaw(sig.yaw, v_r, sig.b, bias)


def cross_validate(rec: Recording, sig: SteeringSignals, fits: dict[str, MapFit],
                   sw_d: np.ndarray, steady: np.ndarray, usable: np.ndarray,
                   cfg: SteeringIdConfig, lever=None) -> dict:
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
        fold[edges[k]:edges[k + 1]] = True
        train, test = steady & ~fold, steady & fold
        if test.sum() < 10 or train.sum() < 20:
            continue
        try:
            maps = _fit_direct(sig, sw_d, train, cfg, tuple(fits), fits.get("yaw_rate"))
        except (ValueError, np.linalg.LinAlgError):
            continue
        chans = {}
        if "wheel_speed_difference" in maps:
            chans["wheel_speeds"] = sig.delta_a[test]
        if "yaw_rate" in maps:
            chans["yaw_rate"] = _yaw_angle(sig, maps["yaw_rate"])[test]
        if "position_replay" in fits:
            f = fits["position_replay"]
            out, _ = _fit_replay(rec, sig.v_front, sw_d, usable & ~fold, sig.dt_s, sig.b, cfg,
                                 (f.offset_rad, f.scale), lever)
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
        return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")

    floor = {c: rms(v) for c, v in own.items() if v}
    out_d = {}
    for m, by_c in err.items():
        r = {c: rms(v) for c, v in by_c.items()}
        ratios = {c: (r[c] / floor[c] if floor.get(c) else float("nan")) for c in r}
        vals = [v for v in ratios.values() if np.isfinite(v)]
        out_d[m] = {"score": float(np.mean(vals)) if vals else float("nan"),
                    "channels": ratios, "rms_rad": r}
    return {"folds": K, "noise_floor_rad": floor, "scores": out_d,
            "method": (f"blocked cross-validation over {K} contiguous folds: each fit, refitted "
                       "without the fold, predicts the road-wheel angle of the independent "
                       "channel(s) it did not use (its own when there is no other); score = "
                       "held-out RMS / that channel's own fit's held-out RMS, averaged over "
                       "channels (lower is better)")}


def identify_steering(rec: Recording, vehicle: Vehicle, config: SteeringIdConfig | None = None,
                      progress=None) -> SteeringResult:
    """Identify eq. 7 from a canonical recording (see the module doc).

    Needs ``steering_wheel_angle`` and the channels of at least one method: the four wheel
    speeds (wheel-speed difference), ``yaw_rate`` and a speed (yaw rate), ``x``/``y``/
    ``heading`` and a speed (replay); uses every method the channels support, chooses among
    them by held-out evidence, and names each skipped method and why
    (``report['selection']['skipped']``). Uses ``gear`` to drop reverse.

    Raises:
        InputError: no method has its channels, or no trustworthy samples remain.
    """
    cfg = config or SteeringIdConfig()
    say = progress or (lambda msg: None)
    sig = steering_signals(rec, vehicle)
    for m, why in sig.skipped.items():
        say(f"steering: {m} skipped: {why}")
    masks = trustworthy_samples(rec, sig, cfg)
    say(f"steering: {int(masks.steady.sum())} trustworthy samples of {len(sig.sw)}")
    dead = estimate_dead_time(sig, masks.usable, cfg)
    sw_d = delayed(sig.sw, dead.tau_s, sig.dt_s)
    steady = masks.steady & np.isfinite(sw_d)
    usable = masks.usable & np.isfinite(sw_d)
    say(f"steering: dead time {dead.tau_s:.3f} s (" + (
        f"held-out interval {dead.interval_s[0]:.3f}-{dead.interval_s[1]:.3f} s" if dead.used
        else "not determined") + f", from {dead.source})")
    fits = direct_fits(sig, sw_d, steady, cfg)
    lever = getattr(vehicle, "nav_lever_arm_m", None)
    replay = None
    if "position_replay" not in sig.skipped:
        start = fits.get("yaw_rate") or fits.get("wheel_speed_difference")
        x0 = ((start.offset_rad, start.scale) if start is not None else
              (0.0, 1.0 / vehicle.steering_ratio if vehicle.steering_ratio
               else cfg.replay_start_scale))
        say("steering: refining by eq. 1 position replay")
        out, _ = _fit_replay(rec, sig.v_front, sw_d, usable, sig.dt_s, sig.b, cfg, x0, lever)
        if out is not None:
            fits["position_replay"], replay, _ = out
        else:
            sig.skipped["position_replay"] = (f"fewer than 3 replay windows of {cfg.window_s} s "
                                              "with finite x, y, heading")
    if not fits:
        raise InputError("no steering fit converged (" + "; ".join(
            f"{m}: {w}" for m, w in sig.skipped.items()) + ")", rec.meta.get("path"),
            channel="steering_wheel_angle")
    idents = {k: identifiability(f, sw_d[steady], sig.v_front[steady], sig.dt_s, cfg,
                                 vehicle.steering_ratio) for k, f in fits.items()}
    rp_fit = fits.get("position_replay")
    if rp_fit is not None and not rp_fit.extra.get("trusted", True):
        idents["position_replay"] = dict(idents["position_replay"], identifiable=False,
                                         note="NOT trusted: " + rp_fit.extra["untrusted_because"])
    say("steering: choosing by blocked cross-validation")
    cv = cross_validate(rec, sig, fits, sw_d, steady, usable, cfg, lever)
    chosen, why = choose_fit(fits, idents, cv)
    final = fits[chosen]
    pairs, disagree_note = disagreement(fits, cfg)
    ident = dict(idents[chosen])
    if disagree_note:
        ident["identifiable"] = False
        ident["note"] = ("NOT identifiable: " + disagree_note + ". " +
                         ident["note"].removeprefix("NOT identifiable: "))
    if sig.skipped:  # the parameter file's note names the methods the recording did not allow
        ident["note"] += " Not run: " + "; ".join(f"{m} ({w})" for m, w in sig.skipped.items()) \
            + "."
    selection = {"chosen": chosen, "because": why, **cv, "disagreements": pairs,
                 "untrusted": {k: f.extra["untrusted_because"] for k, f in fits.items()
                               if not f.extra.get("trusted", True)},
                 "skipped": dict(sig.skipped), "speeds": sig.speed_note}
    agreement, delta_b = agreement_a_b(sig, fits, steady)
    delta_model = final.offset_rad + final.scale * sw_d
    ref = delta_b if delta_b is not None else sig.delta_a
    rms_rad = (float(np.sqrt(np.mean((ref - delta_model)[steady] ** 2))) if ref is not None
               else float("nan"))
    report = _report(sig, cfg, final, why, selection, dead, fits, agreement, rms_rad, ident,
                     idents, masks, steady, usable, sw_d)
    series = _series(rec, sig, delta_b, delta_model, steady, replay, final)
    return SteeringResult(
        offset_rad=final.offset_rad, scale=final.scale, offset_ci95_rad=final.offset_ci95_rad,
        scale_ci95=final.scale_ci95, dead_time_s=dead.tau_s, identifiable=ident["identifiable"],
        note=ident["note"], method=final.method, rms_error_rad=rms_rad, fits=fits,
        report=report, series=series)


def _report(sig, cfg, final, why, selection, dead, fits, agreement, rms_rad, ident, idents,
            masks, steady, usable, sw_d) -> dict:
    """The JSON-ready figures of :func:`identify_steering` (stable keys)."""
    return {
        "offset_rad": final.offset_rad, "scale": final.scale,
        "offset_ci95_rad": list(final.offset_ci95_rad), "scale_ci95": list(final.scale_ci95),
        "method": final.method,
        "method_selected_because": why,
        "selection": selection,
        "dead_time_s": dead.tau_s,
        "dead_time": dead.to_dict(cfg.smooth_s),
        "fits": {k: f.to_dict() for k, f in fits.items()},
        "agreement_a_b": agreement,
        "rms_error_rad": rms_rad,
        "identifiability": ident,
        "identifiability_by_fit": {k: {"identifiable": v["identifiable"],
                                       "offset_identifiable": v["offset_identifiable"],
                                       "scale_identifiable": v["scale_identifiable"],
                                       "note": v["note"]}
                                   for k, v in idents.items()},
        "samples": {"total": int(len(sig.sw)), "usable": int(usable.sum()),
                    "trustworthy": int(steady.sum()), "excluded": masks.excluded},
        "speed_source": sig.speed_source,
        "speed_range_mps": [float(np.percentile(sig.v_front[steady], 2.5)),
                            float(np.percentile(sig.v_front[steady], 97.5))],
        "steering_wheel_range_rad": [float(np.percentile(sw_d[steady], 2.5)),
                                     float(np.percentile(sw_d[steady], 97.5))],
        "thresholds": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
    }


def choose_fit(fits: dict[str, MapFit], idents: dict[str, dict],
               cv: dict | None = None) -> tuple[str, str]:
    """The final estimate's name and why: the trusted fit with the lowest held-out score
    (:func:`cross_validate`), among the identifiable ones when any is (a fit whose parameters
    the recording cannot separate, e.g. offset from gyro bias, also biases the channel it is
    scored against); an untrusted replay (unknown reference point) is never chosen.
    Without scores, the narrowest scale interval among the identifiable (else all) fits."""
    order = [k for k in ("position_replay", "yaw_rate", "wheel_speed_difference") if k in fits
             and fits[k].extra.get("trusted", True)]
    scores = (cv or {}).get("scores", {})
    scored = [k for k in order if np.isfinite(scores.get(k, {}).get("score", np.nan))]
    if scored:
        pool = [k for k in scored if idents[k]["identifiable"]]
        best = min(pool or scored, key=lambda k: scores[k]["score"])
        among = "identifiable fits" if pool else "fits (none is identifiable)"
        return best, (f"lowest held-out score among the trusted {among}: " + ", ".join(
            f"{k} {scores[k]['score']:.3f}" for k in scored))

    def rel_width(k):
        f = fits[k]
        return (f.scale_ci95[1] - f.scale_ci95[0]) / abs(f.scale) if f.scale else np.inf
    pool = [k for k in order if idents[k]["identifiable"]] or order
    return min(pool, key=rel_width), "no held-out scores: the narrowest scale interval"


def disagreement(fits: dict[str, MapFit],
                 cfg: SteeringIdConfig | None = None) -> tuple[list[dict], str | None]:
    """Pairs of trusted fits whose 95% intervals (offset or scale, each widened by
    ``cfg.agree_offset_rad`` / ``cfg.agree_scale_rel``) do not overlap, and a note naming them
    and the likely cause (None when all agree)."""
    cfg = cfg or SteeringIdConfig()
    names = [k for k in ("wheel_speed_difference", "yaw_rate", "position_replay") if k in fits
             and fits[k].extra.get("trusted", True)]
    pairs = []
    for i, a in enumerate(names):
        for b_ in names[i + 1:]:
            fa, fb = fits[a], fits[b_]
            tol_s = 0.5 * cfg.agree_scale_rel * (abs(fa.scale) + abs(fb.scale))
            what = [q for q, (ia, ib), tol in (
                ("scale", (fa.scale_ci95, fb.scale_ci95), tol_s),
                ("offset", (fa.offset_ci95_rad, fb.offset_ci95_rad), cfg.agree_offset_rad))
                if ia[1] + tol < ib[0] - tol or ib[1] + tol < ia[0] - tol]
            if what:
                pairs.append({"fits": [a, b_], "quantities": what})
    if not pairs:
        return [], None
    causes = []
    for p in pairs:
        if "position_replay" in p["fits"]:
            c = ("the position's reference point (vehicle.nav_lever_arm_m) or the heading's "
                 "mount")
        elif "scale" in p["quantities"]:
            c = "understeer (tyre side slip) folded into the yaw-rate angle"
        else:
            c = "a sensor bias (gyro bias, tyre radius mismatch, angle-sensor zero)"
        causes.append(f"{' and '.join(p['fits'])} disagree on {' and '.join(p['quantities'])} "
                      f"beyond their 95% intervals (likely cause: {c})")
    return pairs, "; ".join(causes)


def agreement_a_b(sig: SteeringSignals, fits: dict[str, MapFit],
                  steady: np.ndarray) -> tuple[dict | None, np.ndarray | None]:
    """How measurements (a) and (b) agree on the trustworthy samples, and (b)'s road-wheel
    angle with the fitted gyro bias removed; (None, None) without a yaw-rate fit, (None, (b))
    without the wheel speeds."""
    if "yaw_rate" not in fits:
        return None, None
    delta_b = _yaw_angle(sig, fits["yaw_rate"])
    if "wheel_speed_difference" not in fits:
        return None, delta_b
    delta_a = sig.delta_a
    dd = (delta_a - delta_b)[steady]
    fa, fb = fits["wheel_speed_difference"], fits["yaw_rate"]
    agreement = {
        "rms_difference_rad": float(np.sqrt(np.mean(dd ** 2))),
        "mean_difference_rad": float(np.mean(dd)),
        "correlation": float(np.corrcoef(delta_a[steady], delta_b[steady])[0, 1])
        if np.std(delta_b[steady]) > 0 and np.std(delta_a[steady]) > 0 else float("nan"),
        "offset_difference_rad": fa.offset_rad - fb.offset_rad,
        "scale_ratio": fa.scale / fb.scale if fb.scale != 0 else float("nan"),
    }
    return agreement, delta_b


def _series(rec: Recording, sig: SteeringSignals, delta_b, delta_model, steady, replay,
            final: MapFit) -> dict:
    """Time series for the plots (``models.report``)."""
    nan = np.full(len(sig.sw), np.nan)  # channels the recording lacks plot as gaps
    fl, fr = (nan if w is None else w for w in (sig.fl, sig.fr))
    series = {"time": rec.time, "steering_wheel_angle": sig.sw, "wheel_speed_fl": fl,
              "wheel_speed_fr": fr, "turn_rate_wheels_radps": (fr - fl) / sig.T,
              "delta_wheels_rad": nan if sig.delta_a is None else sig.delta_a,
              "delta_yaw_rad": delta_b,
              "delta_model_rad": delta_model, "trustworthy": steady}
    if replay is not None:
        xp, yp = replay.predict((final.offset_rad, final.scale))
        series["replay"] = {"x_pred": np.where(replay.inwin, xp, np.nan),
                            "y_pred": np.where(replay.inwin, yp, np.nan),
                            "x": np.asarray(rec["x"], float), "y": np.asarray(rec["y"], float)}
    return series


__all__ = ["SteeringIdConfig", "SteeringResult", "MapFit", "identify_steering",
           "SteeringSignals", "SampleMasks", "DeadTime", "steering_signals", "trustworthy_samples",
           "estimate_dead_time", "dead_time_cv", "direct_fits", "rear_axle_speed", "choose_fit",
           "cross_validate", "disagreement", "agreement_a_b",
           "identifiability", "road_wheel_angle_from_front", "road_wheel_angle_from_yaw",
           "xcorr_dead_time", "delayed", "Z95"]
