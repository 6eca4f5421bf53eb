"""Steering hypotheses: the report's steering map (eq. 7) in the bicycle model (eq. 1),
extended one physical term at a time and refitted jointly with the offset and the scale.

Measured road-wheel angle (eq. 1 inverted, yaw-rate sensor bias ``r0`` fitted alongside)::

    delta_m = atan(b r / v_rear),   delta_m = offset + scale * sw(t) + b r0 / v   (baseline)

(v_rear: the rear-axle centre's speed, the mean of the unsteered rear wheels; eq. 1's front
point moves at v_rear / cos(delta).)

Extensions (``CATALOGUE`` ids):

- ``actuator_delay``: sw(t - d), d in [0, delay_max_s];
- ``actuator_lag``: sw through 1 / (tau s + 1), tau in [0, tau_max_s];
- ``steering_nonlinearity``: scale * (sw + k3 sw^3): the rack's gain changes towards full lock,
  |k3| <= 0.02 1/rad^2;
- ``understeer``: the kinematic angle acts as delta / (1 + K v^2 / b) (K the understeer
  gradient [rad per m/s^2 of lateral acceleration]), K in [0, 0.02].

Scores are heading free-run replays: the heading integrated from eq. 1 with the measured speed
and steering over each window, against the INS heading (or the bias-corrected gyro).
:func:`position_errors` replays eq. 1's position over the same windows, and
:func:`separability` says whether a recording can tell understeer from the steering ratio.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter

from hmpc.models.params import Vehicle
from hmpc.models.plant import PlantExtensions
from hmpc.models.diagnose.hypothesis import grid_search, sse_per_sample
from hmpc.models.diagnose.common import (
    DiagnoseConfig,
    bic,
    lstsq_bounded,
    profile_interval,
    rmse,
    segment_fold_ids,
    segments,
    train_mask,
    windows,
)

HYPOTHESES = ("actuator_delay", "actuator_lag", "steering_nonlinearity", "understeer")
#: hypothesis -> its grid-searched parameter as the catalogue names it (the JSON's key)
NONLINEAR = {
    "actuator_delay": "delay_s",
    "actuator_lag": "tau_s",
    "understeer": "gradient_rad_per_mps2",
}
#: hypothesis -> the :class:`SteerModel` field that holds its grid-searched parameter
SEARCHED_FIELD = {
    "actuator_delay": "delay_s",
    "actuator_lag": "tau_s",
    "understeer": "understeer_rad_per_mps2",
}
#: understeer gradients of passenger cars are 0.002..0.005 rad/(m/s^2); 0.02 is a bound
K_MAX = 0.02
#: rack nonlinearity bound [1/rad^2]: 0.02 changes the gain by 140 % at 8.4 rad (full lock)
K3_MAX = 0.02


@dataclass
class SteerData:
    t: np.ndarray
    dt: float
    v: np.ndarray  #: rear-axle centre speed [m/s]
    sw: np.ndarray
    yaw: np.ndarray
    heading: np.ndarray  #: unwrapped heading reference [rad]
    heading_source: str
    b: float
    dm: np.ndarray  #: measured road-wheel angle [rad] (NaN where unusable)
    segs: list
    ok: np.ndarray  #: samples usable for heading replay
    fit_ok: np.ndarray  #: samples usable for the angle fit
    vf: np.ndarray  #: front point speed v_rear / cos(delta_m) [m/s] (understeer)

    @property
    def n(self) -> int:
        return len(self.t)


def prepare(
    ch: dict, wheelbase_m: float, cfg: DiagnoseConfig = DiagnoseConfig()
) -> SteerData | None:
    """Steering data, or None when the recording lacks steering angle, speed or yaw, or holds
    too little of them (:func:`support` says why)."""
    return support(ch, wheelbase_m, cfg)[0]


def support(
    ch: dict, wheelbase_m: float, cfg: DiagnoseConfig = DiagnoseConfig()
) -> tuple[SteerData | None, str | None, dict]:
    """(steering data or None, the reason when None, the samples dropped by reason).

    The dropped samples are counted in order, each sample under the first reason that drops
    it: a channel missing (NaN), standing or slower than ``cfg.v_move_min_mps``, in a run too
    short for a free-run window, slower than ``cfg.v_steer_min_mps`` (heading replay only,
    not the angle fit)."""
    if "steering_wheel_angle" not in ch:
        return None, "no steering_wheel_angle channel", {}
    if "speed" not in ch:
        return None, "no speed channel", {}
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    if "wheel_speed_rl" in ch and "wheel_speed_rr" in ch:
        # the rear-axle centre's speed (unsteered wheels: exactly their mean); eq. 1's yaw
        # rate v sin(delta) / b of the front point is v_rear tan(delta) / b
        v = 0.5 * (
            np.asarray(ch["wheel_speed_rl"], float) + np.asarray(ch["wheel_speed_rr"], float)
        )
    else:
        v = np.asarray(ch["speed"], float)
    sw = np.asarray(ch["steering_wheel_angle"], float)
    yaw = ch.get("yaw_rate")
    head = ch.get("heading")
    if yaw is None and head is None:
        return None, "no yaw_rate or heading channel", {}
    if yaw is None or not np.isfinite(yaw).any():
        from hmpc.models.identify.stats import savgol_derivative

        assert head is not None  # a recording with no usable yaw rate has a heading here
        yaw = savgol_derivative(np.unwrap(np.nan_to_num(head)), dt, cfg.deriv_window_s)
    yaw = np.asarray(yaw, float)
    finite = np.isfinite(v) & np.isfinite(sw) & np.isfinite(yaw)
    if head is not None and np.isfinite(head).mean() > 0.5:
        finite &= np.isfinite(head)
    valid = finite & (v > cfg.v_move_min_mps)
    segs = segments(valid, int(cfg.window_steer_s / dt))
    ok = np.zeros(len(t), bool)
    for a, b_ in segs:
        ok[a:b_] = True
    b = float(wheelbase_m)
    with np.errstate(invalid="ignore", divide="ignore"):
        dm = np.arctan(b * yaw / v)
    fit_ok = ok & (v > cfg.v_steer_min_mps) & np.isfinite(dm)
    vf = np.where(np.isfinite(dm), v / np.cos(np.nan_to_num(dm)), v)  # front point speed
    dropped = {
        "channel missing (NaN)": int((~finite).sum()),
        f"speed at or below {cfg.v_move_min_mps:.2g} m/s": int((finite & ~valid).sum()),
        f"moving runs shorter than {cfg.window_steer_s:g} s": int((valid & ~ok).sum()),
        f"speed at or below {cfg.v_steer_min_mps:.2g} m/s (angle fit only)": int(
            (ok & ~fit_ok).sum()
        ),
    }
    samples = {
        "total": int(len(t)),
        "angle_fit": int(fit_ok.sum()),
        "replay": int(ok.sum()),
        "dropped": {k: n for k, n in dropped.items() if n},
    }
    if fit_ok.sum() < int(cfg.min_steer_s / dt):
        return (
            None,
            (
                f"too little moving steering data ({fit_ok.sum() * dt:.1f} s above "
                f"{cfg.v_steer_min_mps:.2g} m/s in runs of {cfg.window_steer_s:g} s; "
                f"needs {cfg.min_steer_s:g} s)"
            ),
            samples,
        )
    if head is not None and np.isfinite(head).mean() > 0.5:
        href = np.full(len(t), np.nan)
        for a, b_ in segs:
            href[a:b_] = np.unwrap(np.asarray(head, float)[a:b_])
        src = "INS heading"
    else:
        href = np.full(len(t), np.nan)
        for a, b_ in segs:
            href[a:b_] = np.cumsum(yaw[a:b_]) * dt
        src = "integrated yaw rate"
    return SteerData(t, dt, v, sw, yaw, href, src, b, dm, segs, ok, fit_ok, vf), None, samples


@dataclass
class SteerModel:
    """Eq. 7 in eq. 1 fitted with the steering hypothesis ``name`` (None: the baseline); the
    parameters of the other hypotheses are 0."""

    name: str | None
    offset_rad: float
    scale: float
    bias_radps: float  #: yaw-rate sensor bias r0 [rad/s]
    delay_s: float = 0.0  #: actuator_delay: dead time d [s]
    tau_s: float = 0.0  #: actuator_lag: time constant tau [s]
    cubic_per_rad2: float = 0.0  #: steering_nonlinearity: cubic k3 [1/rad^2]
    understeer_rad_per_mps2: float = 0.0  #: understeer: gradient K [rad/(m/s^2)]
    sse: float = float("nan")
    n: int = 0
    k: int = 0


def searched(m: SteerModel) -> float:
    """The value of the parameter grid-searched for ``m.name`` (:data:`SEARCHED_FIELD`)."""
    assert m.name is not None  # the baseline searches nothing
    return getattr(m, SEARCHED_FIELD[m.name])


def _sw(d: SteerData, delay_s: float = 0.0, tau_s: float = 0.0) -> np.ndarray:
    """The steering-wheel angle as the rack receives it: after the dead time ``delay_s`` or
    through the lag ``tau_s`` (each when set; per segment)."""
    if delay_s > 0:
        out = np.full(d.n, np.nan)
        for a, b in d.segs:
            tt = d.t[a:b]
            out[a:b] = np.interp(tt - delay_s, tt, d.sw[a:b])  # held before the start
        return out
    if tau_s > 0:
        al = 1.0 - np.exp(-d.dt / tau_s)
        out = np.full(d.n, np.nan)
        for a, b in d.segs:
            x = d.sw[a:b]
            out[a:b] = lfilter([al], [1.0, al - 1.0], x, zi=[(1.0 - al) * x[0]])[0]
        return out
    return d.sw


def fit(d: SteerData, name: str | None, value: float, mask: np.ndarray) -> SteerModel:
    """Eq. 7 with hypothesis ``name`` fitted jointly with the offset, the scale and the
    yaw-rate bias on ``mask``; ``value``: the grid-searched parameter of ``name``
    (:data:`SEARCHED_FIELD`; ignored for the others)."""
    searched_kw = {SEARCHED_FIELD[name]: value} if name in SEARCHED_FIELD else {}
    sw = _sw(d, searched_kw.get("delay_s", 0.0), searched_kw.get("tau_s", 0.0))
    use = mask & d.fit_ok & np.isfinite(sw)
    v = d.v[use]
    vf = d.vf[use]
    cols = [np.ones(use.sum()), sw[use], d.b / v]
    if name == "steering_nonlinearity":
        cols.append(sw[use] ** 3)
    X = np.column_stack(cols)
    gradient = searched_kw.get("understeer_rad_per_mps2", 0.0)
    div = 1.0 + gradient * vf * vf / d.b if name == "understeer" else 1.0
    y = d.dm[use]
    c, _ = lstsq_bounded(X / np.atleast_1d(div)[:, None] if name == "understeer" else X, y)
    k3 = float(c[3] / c[1]) if name == "steering_nonlinearity" and c[1] != 0 else 0.0
    if abs(k3) > K3_MAX:  # bounded: refit the map with k3 on its bound
        k3 = float(np.sign(k3) * K3_MAX)
        X = np.column_stack([cols[0], sw[use] + k3 * sw[use] ** 3, cols[2]])
        c3, _ = lstsq_bounded(X, y)
        c = np.concatenate([c3, [k3 * c3[1]]])
        X = np.column_stack([cols[0], sw[use], cols[2], sw[use] ** 3])
    pred = (X @ c) / div if name == "understeer" else X @ c
    sse = float(np.sum((y - pred) ** 2))
    k = len(c) + (name in NONLINEAR)
    return SteerModel(
        name,
        float(c[0]),
        float(c[1]),
        float(c[2]),
        cubic_per_rad2=k3,
        sse=sse,
        n=int(use.sum()),
        k=k,
        **searched_kw,
    )


def road_wheel_angle(d: SteerData, m: SteerModel) -> np.ndarray:
    """Model road-wheel angle [rad] (the kinematic angle eq. 1 turns with): eq. 7 with the
    rack's cubic and the understeer gradient as the plant writes them
    (``models.plant.PlantExtensions.road_wheel_angle``, at the front point's speed), on the
    steering-wheel angle after the model's dead time or lag."""
    ext = PlantExtensions(
        cubic_per_rad2=m.cubic_per_rad2, understeer_rad_per_mps2=m.understeer_rad_per_mps2
    )
    return ext.road_wheel_angle(_sw(d, m.delay_s, m.tau_s), d.vf, m.offset_rad, m.scale, d.b)


def free_run(d: SteerData, m: SteerModel, idx: np.ndarray) -> np.ndarray:
    """Heading error [rad] of free-run windows ``idx`` (integrated eq. 1 - measured)."""
    if idx.size == 0:
        return np.zeros(idx.shape)
    r = d.v * np.tan(road_wheel_angle(d, m)) / d.b
    if d.heading_source == "integrated yaw rate":  # the reference carries the gyro's bias
        r = r + m.bias_radps
    r = np.nan_to_num(r)
    rr = r[idx] * d.dt
    pred = d.heading[idx[:, :1]] + np.concatenate(
        [np.zeros((len(idx), 1)), np.cumsum(rr[:, :-1], axis=1)], axis=1
    )
    return pred - d.heading[idx]


def _grid(name):
    if name == "actuator_delay":
        return np.arange(0.0, 1.0 + 1e-9, 0.05)
    if name == "actuator_lag":
        return np.arange(0.0, 1.0 + 1e-9, 0.05)
    if name == "understeer":
        return np.linspace(0.0, K_MAX, 41)
    return np.zeros(1)


def fit_best(d: SteerData, name, mask, grid=None):
    """Fit hypothesis ``name`` on ``mask``, its searched parameter by grid on the SSE
    (``grid`` overrides the default grid, which is refined around the best point: a delay or
    lag to one sample, the understeer gradient to a tenth of its step).

    Returns (model, grid, SSE per sample per grid point)."""
    if name not in NONLINEAR:
        m = fit(d, name, 0.0, mask)
        return m, np.zeros(1), np.array([sse_per_sample(m)])
    refine = grid is None
    grid = _grid(name) if grid is None else np.asarray(grid, float)
    fine_step: float | None = None
    if refine:
        fine_step = max(d.dt, 0.01) if name != "understeer" else (grid[1] - grid[0]) / 10
    return grid_search(
        lambda g: fit(d, name, g, mask),
        grid,
        fine_step,
        end_pad=1e-12,
        rtol=0.0,
        atol=fine_step / 10 if fine_step is not None else 0.0,
    )


def residual(d: SteerData, m: SteerModel) -> np.ndarray:
    """Angle equation error [rad] (measured - model, yaw bias removed); NaN where not fitted."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = d.dm - road_wheel_angle(d, m) - d.b * m.bias_radps / d.v
    r[~d.fit_ok] = np.nan
    return r


@dataclass
class SteerScore:
    """Held-out and full-data results of one steering hypothesis (a
    :class:`~models.diagnose.hypothesis.HypothesisScore`)."""

    name: str | None
    model: SteerModel
    heldout_rmse_rad: float
    heldout_err: np.ndarray
    bic: float
    params: dict
    intervals: dict
    fold_values: list


def evaluate(d: SteerData, name, cfg: DiagnoseConfig, corr_len: float) -> SteerScore:
    folds = segment_fold_ids(d.n, d.segs, cfg.n_folds)
    guard = int(cfg.guard_s / d.dt)
    L = int(cfg.window_steer_s / d.dt)
    full, grid, sse_grid = fit_best(d, name, d.ok)
    local = None
    if name in NONLINEAR:
        step = {"actuator_delay": 0.05, "actuator_lag": 0.05, "understeer": K_MAX / 40}[name]
        local = np.unique(np.maximum(searched(full) + step * np.arange(-2, 3), 0.0))
    err = np.full(d.n, np.nan)
    vals = []
    for f in range(cfg.n_folds):
        m, _, _ = fit_best(d, name, train_mask(folds, f, guard), grid=local)
        idx = windows(folds == f, L)
        if idx.size:
            err[idx] = free_run(d, m, idx)
        vals.append(searched(m) if name in NONLINEAR else m.cubic_per_rad2)
    params, intervals = {}, {}
    if name in NONLINEAR:
        key = NONLINEAR[name]
        params[key] = float(searched(full))
        lo, hi = profile_interval(grid, sse_grid * full.n, full.n, corr_len)
        half = 0.5 * float(np.min(np.diff(grid))) if len(grid) > 1 else 0.0
        intervals[key] = [max(lo - half, float(grid[0])), hi + half]
    if name == "steering_nonlinearity":
        params["cubic_per_rad2"] = full.cubic_per_rad2
        intervals["cubic_per_rad2"] = list(_k3_interval(d, full, corr_len))
    if name is not None:
        params["offset_rad"], params["scale"] = full.offset_rad, full.scale
    return SteerScore(
        name, full, rmse(err), err, bic(full.sse, full.n, full.k, corr_len), params, intervals, vals
    )


def _k3_interval(d: SteerData, m: SteerModel, corr_len: float):
    grid = np.clip(
        m.cubic_per_rad2 + np.linspace(-1, 1, 41) * max(abs(m.cubic_per_rad2), 1e-4),
        -K3_MAX,
        K3_MAX,
    )
    sse = []
    use = d.fit_ok
    v, sw, y = d.v[use], d.sw[use], d.dm[use]
    for g in grid:
        X = np.column_stack([np.ones(len(v)), sw + g * sw**3, d.b / v])
        _, s = lstsq_bounded(X, y)
        sse.append(s)
    return profile_interval(grid, np.array(sse), len(y), corr_len)


def position_errors(ch, d: SteerData, m: SteerModel, cfg) -> np.ndarray | None:
    """Position error [m] of free-run windows of eq. 1 (measured speed, modelled heading)."""
    if "x" not in ch or "y" not in ch:
        return None
    x, y = np.asarray(ch["x"], float), np.asarray(ch["y"], float)
    L = int(cfg.window_steer_s / d.dt)
    idx = windows(d.ok & np.isfinite(x) & np.isfinite(y), L)
    if idx.size == 0:
        return None
    delta = np.nan_to_num(road_wheel_angle(d, m))
    r = d.v * np.tan(delta) / d.b
    vf = d.v / np.cos(delta)  # the front point (eq. 1's x, y) moves faster than the rear axle
    psi = d.heading[idx[:, :1]] + np.concatenate(
        [np.zeros((len(idx), 1)), np.cumsum(r[idx][:, :-1] * d.dt, axis=1)], axis=1
    )
    ang = psi + delta[idx]
    vx, vy = vf[idx] * np.cos(ang), vf[idx] * np.sin(ang)
    px = x[idx[:, :1]] + np.concatenate(
        [np.zeros((len(idx), 1)), np.cumsum(vx[:, :-1] * d.dt, axis=1)], axis=1
    )
    py = y[idx[:, :1]] + np.concatenate(
        [np.zeros((len(idx), 1)), np.cumsum(vy[:, :-1] * d.dt, axis=1)], axis=1
    )
    out = np.full(d.n, np.nan)
    out[idx] = np.hypot(px - x[idx], py - y[idx])
    return out


def _sse_fixed_scale(d: SteerData, scale: float) -> float:
    """Smallest angle SSE with the steering scale fixed and the understeer gradient free."""
    use = d.fit_ok
    v, sw, y = d.v[use], d.sw[use], d.dm[use]
    best = np.inf
    for k in np.linspace(0.0, K_MAX, 81):
        div = 1.0 + k * v * v / d.b
        X = np.column_stack([1.0 / div, d.b / v])
        r = y - scale * sw / div
        c = np.linalg.lstsq(X, r, rcond=None)[0]
        best = min(best, float(np.sum((r - X @ c) ** 2)))
    return best


def excitation(d: SteerData, cfg: DiagnoseConfig) -> dict:
    """What the recording offers understeer: the lateral acceleration (97.5th percentile of
    |v r| on the angle fit's samples) and the spread of speeds while steered ((v90 / v10)^2
    where |v r| exceeds a quarter of ``cfg.understeer_min_lat_accel_mps2``), and whether both
    reach their bounds (``testable``; the reason when not)."""
    ay = np.abs(d.v * d.yaw)[d.fit_ok]
    ay = ay[np.isfinite(ay)]
    a97 = float(np.percentile(ay, 97.5)) if len(ay) else 0.0
    lat_accel_mps2 = np.abs(d.v * d.yaw)[d.fit_ok]
    steered = d.v[d.fit_ok][lat_accel_mps2 > 0.25 * cfg.understeer_min_lat_accel_mps2]
    ratio = (
        float((np.percentile(steered, 90) / np.percentile(steered, 10)) ** 2)
        if len(steered) >= 10
        else 1.0
    )
    out: dict[str, Any] = {"lat_accel_p97_5_mps2": a97, "speed_sq_ratio": ratio, "testable": True}
    if a97 < cfg.understeer_min_lat_accel_mps2:
        out.update(
            testable=False,
            why=(
                f"lateral acceleration reaches only {a97:.2f} m/s^2 (97.5th percentile; "
                f"{cfg.understeer_min_lat_accel_mps2:g} m/s^2 needed): understeer's angle K a_y "
                "is not excited"
            ),
        )
    elif ratio < cfg.understeer_min_speed_sq_ratio:
        out.update(
            testable=False,
            why=(
                f"the steered samples span a speed-squared ratio of only {ratio:.2f} "
                f"({cfg.understeer_min_speed_sq_ratio:g} needed): at one speed understeer is a "
                "constant factor on the steering gain"
            ),
        )
    return out


def separability(
    d: SteerData,
    us: SteerScore,
    base: SteerScore,
    vehicle: Vehicle,
    corr_len: float,
    cfg: DiagnoseConfig = DiagnoseConfig(),
) -> dict:
    """Can this recording tell understeer (delta / (1 + K v^2 / b)) from the steering ratio?

    Only when it excites understeer (:func:`excitation`: lateral acceleration and a spread of
    speeds while steered); otherwise the verdict is "not testable" and no likelihood ratio is
    claimed. Two explanations of the measured yaw response are compared: the kinematic one (scale
    fitted, K = 0: the baseline) and the maker's ratio with understeer (scale = 1 /
    steering_ratio, K fitted). Separable when the likelihood ratio between them exceeds the
    95 % chi-square(1) point with the effective sample size; without a maker's ratio, when
    the understeer gradient's interval is narrower than the passenger-car range (0.003)."""
    lo, hi = us.intervals.get("gradient_rad_per_mps2", [0.0, K_MAX])
    ne = max(base.model.n / max(corr_len, 1.0), 3.0)
    exc = excitation(d, cfg)
    out: dict[str, Any] = {"gradient_interval": [lo, hi], "excitation": exc}
    if not exc["testable"]:
        out.update(
            separable=False,
            testable=False,
            verdict=f"understeer against the steering ratio: not testable on this "
            f"recording ({exc['why']})",
        )
        return out
    ratio = vehicle.steering_ratio
    if ratio:
        sse_maker = _sse_fixed_scale(d, 1.0 / ratio)
        lr = float(ne * np.log(sse_maker / base.model.sse))
        ok = abs(lr) > 3.84
        out.update(maker_scale=1.0 / ratio, kinematic_scale=base.model.scale, likelihood_ratio=lr)
        verdict = (
            "understeer and the steering ratio are separable on this recording: "
            if ok
            else "this recording cannot separate understeer from the steering ratio: "
        ) + (
            f"the kinematic scale {base.model.scale:.4f} with no understeer and the maker's "
            f"1/{ratio:g} = {1 / ratio:.4f} with understeer fit with likelihood ratio "
            f"{lr:.1f} (separable above 3.84)"
        )
    else:
        ok = (hi - lo) < 0.003
        verdict = (
            "understeer and the steering ratio are separable on this recording"
            if ok
            else "this recording cannot separate understeer from the steering ratio"
        ) + f": understeer gradient in [{lo:.4f}, {hi:.4f}] rad/(m/s^2)"
    out.update(separable=bool(ok), testable=True, verdict=verdict)
    return out
