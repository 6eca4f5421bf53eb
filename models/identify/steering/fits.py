"""The direct fits of eq. 7 (:class:`MapFit`): (a) on the wheel-speed angle, (b) on the yaw rate.

(a) is ordinary least squares of the wheel-speed road-wheel angle on the delayed
steering-wheel angle. (b) is fitted in the rate domain,
``r = r_bias + v_R tan(offset + scale * sw) / b``, where the yaw-rate noise is white and a gyro
bias ``r_bias`` [rad/s] is estimated with the map: at 2.4 m/s a 0.002 rad/s bias would
otherwise shift the offset by 0.0022 rad. Separating the bias from the offset needs a range of
speeds (the parameter correlation is reported). Standstill samples are not used to pin the
bias: a quantised channel at rest reads its step nearest 0 (Toyota's YAW_RATE has 0.244 deg/s
steps), which bounds the bias only to +-0.0021 rad/s, i.e. the offset to +-b/v times that
(+-12% of a 0.017 rad offset at 2.5 m/s). The same rounding, on a steady arc that reads one
level throughout, is an error the bias and offset absorb and no residual shows: a channel that
rests on whole steps (:func:`~hmpc.models.identify.stats.quantisation_step`) adds it to the
intervals (:func:`~hmpc.models.identify.stats.quantisation_cov`). With ``speed`` or
``gps_speed`` at an unknown point on the centre line, at |x_s| from the rear axle, which moves
at ``v_R sqrt(1 + (x_s/b)^2 tan^2(delta))``: ``k = (x_s/b)^2`` is estimated with the map (it
acts on the cubic term only; 4% of the angle at 0.3 rad), and the axle speeds for the replay
follow from it and the yaw rate.

**Intervals**: 95%, from sandwich covariances that allow correlated residuals
(``models.identify.stats``) over time-block clusters, Student-t critical values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from hmpc.models.identify.stats import Z95, block_cov, ols_hac, quantisation_cov, quantisation_step
from hmpc.models.identify.steering.config import SteeringIdConfig
from hmpc.models.identify.steering.kinematics import rear_axle_speed, road_wheel_angle_from_yaw
from hmpc.models.identify.steering.signals import SteeringSignals


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
        return {
            "method": self.method,
            "offset_rad": self.offset_rad,
            "scale": self.scale,
            "offset_ci95_rad": list(self.offset_ci95_rad),
            "scale_ci95": list(self.scale_ci95),
            "offset_scale_correlation": self.corr,
            "samples": self.samples,
            f"rms_error_{self.rms_unit}": self.rms_error,
            "ci_method": self.ci_method,
            **self.extra,
        }


def _fit_front(delta_a, sw_d, steady) -> MapFit:
    X = np.column_stack([np.ones_like(sw_d), sw_d])
    r = ols_hac(X, delta_a, steady)
    return MapFit(
        "wheel_speed_difference",
        float(r.coef[0]),
        float(r.coef[1]),
        (float(r.ci95[0, 0]), float(r.ci95[0, 1])),
        (float(r.ci95[1, 0]), float(r.ci95[1, 1])),
        float(r.corr[0, 1]),
        r.n,
        r.rmse,
        "rad",
        r.method,
        {"condition_number": r.cond},
    )


def _fit_yaw(yaw, v, sw_d, steady, b, x0, k_max: float | None = None) -> MapFit:
    """Eq. 7 in the rate domain, ``r = r_bias + v tan(delta) / (b sqrt(1 + k tan^2(delta)))``.

    ``k_max`` None: ``v`` is the rear-axle speed and k = 0 (eq. (b) of ``kinematics``).
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
        assert k_max is not None
        sol = least_squares(
            res,
            np.array([x0[0], x0[1], 0.0, 0.25 * k_max]),
            method="trf",
            bounds=([-np.inf, -np.inf, -np.inf, 0.0], [np.inf, np.inf, np.inf, k_max]),
            x_scale=np.array([0.01, 0.01, 0.001, 0.1]),
        )
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
    extra = {
        "yaw_rate_bias_radps": float(th[2]),
        "yaw_rate_bias_ci95_radps": [float(th[2] - crit * se[2]), float(th[2] + crit * se[2])],
        "offset_bias_correlation": float(corr[0, 2]),
    }
    if fit_k:
        assert k_max is not None
        k, hk = float(th[3]), float(crit * se[3])
        extra.update(
            {
                "speed_point_k": k,
                "speed_point_k_ci95": [k - hk, k + hk],
                "speed_point_x_m": float(b * np.sqrt(k)),
                "speed_point_source": "estimated with the map: |x| of the speed's point "
                "from the rear axle (the sign is not observable)",
                "speed_point_at_bound": bool(min(k, k_max - k) < 1e-6),
            }
        )
    return MapFit(
        "yaw_rate",
        float(th[0]),
        float(th[1]),
        (float(th[0] - crit * se[0]), float(th[0] + crit * se[0])),
        (float(th[1] - crit * se[1]), float(th[1] + crit * se[1])),
        float(corr[0, 1]),
        len(i),
        float(np.sqrt(np.mean(sol.fun**2))),
        "radps",
        f"time-block cluster-robust sandwich (Jacobian), t({G - 1})"
        + (f" + rounding of the yaw rate ({q:.2g} rad/s steps)" if q is not None else ""),
        extra,
    )


def _speed_point_update(sig: SteeringSignals, fit: MapFit) -> None:
    """With the speed channel's point estimated by the yaw-rate fit (k = (x_s/b)^2), the
    rear- and front-axle speeds follow from it and the bias-free yaw rate (in place)."""
    k = fit.extra.get("speed_point_k")
    if k is None or sig.v_src is None:
        return
    r = sig.yaw - fit.extra["yaw_rate_bias_radps"]
    sig.v_rear = rear_axle_speed(sig.v_src, r, (sig.b * np.sqrt(k), 0.0))
    sig.v_front = np.hypot(sig.v_rear, sig.b * r)


def _fit_direct(
    sig: SteeringSignals,
    sw_d: np.ndarray,
    mask: np.ndarray,
    cfg: SteeringIdConfig,
    methods=("wheel_speed_difference", "yaw_rate"),
    start=None,
) -> dict[str, MapFit]:
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
                assert sig.v_src is not None  # the yaw-rate method needs a speed
                x0 = _fit_front(
                    road_wheel_angle_from_yaw(sig.yaw, sig.v_src, sig.b),
                    sw_d,
                    mask & np.isfinite(sig.v_src) & (np.nan_to_num(sig.v_src) > 0),
                )
            k_max = cfg.speed_point_k_max if sig.speed_point_unknown else None
            fits["yaw_rate"] = _fit_yaw(
                sig.yaw,
                sig.v_src if k_max else sig.v_rear,
                sw_d,
                mask,
                sig.b,
                (x0.offset_rad, x0.scale),
                k_max,
            )
        except (ValueError, np.linalg.LinAlgError):
            pass
    return fits


def direct_fits(
    sig: SteeringSignals, sw_d: np.ndarray, steady: np.ndarray, cfg: SteeringIdConfig | None = None
) -> dict[str, MapFit]:
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
    v_r = (
        sig.v_rear
        if k is None
        else rear_axle_speed(sig.v_src, sig.yaw - bias, (sig.b * np.sqrt(k), 0.0))
    )
    return road_wheel_angle_from_yaw(sig.yaw, v_r, sig.b, bias)
