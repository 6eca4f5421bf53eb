"""Independent measurements of one quantity, compared: the accelerometer against the speed's
derivative (``accelerometer``), the wheel-speed difference against the yaw rate
(``wheelspeeds``); the CAN speed against the GNSS speed is ``sensors``. Two measurements that
disagree beyond their intervals are a finding, never a silent choice of one of them: the
measurement physics that reconciles them (``sensor_mounting``, ``accelerometer_lag``,
``wheel_speed_scale``) is named with the fit that makes both agree.

Each comparison returns a :class:`Comparison`: its channel (residual, noise floor, baseline
RMSE), its series for the report (both measurements, the baseline's and the reconciling fit),
its candidates (``candidates.candidate`` records) and the hypotheses it could not test with
the reason; ``diagnose`` merges them into its result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.diagnose import accelerometer as acc
from hmpc.models.diagnose import wheelspeeds as whl
from hmpc.models.diagnose.candidates import accept, candidate
from hmpc.models.diagnose.common import DiagnoseConfig, corr_length
from hmpc.models.diagnose.locate import noise_floor


@dataclass
class Comparison:
    """One pair of sensors compared (see the module doc); ``ran`` False: not comparable here,
    ``why`` says why."""

    ran: bool
    why: str = ""
    channel: str = ""
    info: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict)
    cands: list = field(default_factory=list)
    untested: list = field(default_factory=list)
    notes: list = field(default_factory=list)


def _judge(c: dict, extra_ok: bool, why_not: str) -> None:
    """An accepted candidate that fails the comparison's own condition is not a finding."""
    if c["_ok"] and not extra_ok:
        c["_ok"], c["why"] = False, why_not


def accelerometer(ch: dict, cfg: DiagnoseConfig) -> Comparison:
    """accel_x against the speed's derivative: ``sensor_mounting`` first (an IMU turned about
    the vertical), then ``accelerometer_lag`` (on top of an accepted mounting)."""
    d, why = acc.prepare(ch, cfg)
    if d is None:
        return Comparison(
            False,
            why,
            untested=[{"effect": h, "tested": False, "why": why} for h in acc.HYPOTHESES],
        )
    cl = corr_length(acc.residual(d, acc.fit(d, 0.0, False, d.ok)))
    b = acc.evaluate(d, None, cfg, cl)
    name = "accel_vs_speed"
    out = Comparison(True, channel=name)
    out.info = {
        "unit": "m/s^2",
        "noise_floor": noise_floor(d.m),
        "rmse_baseline": b.heldout_rmse_mps2,
        "heldout_rmse_baseline": b.heldout_rmse_mps2,
        "speed_source": d.speed_source,
        "baseline": {"gain": b.model.gain, "offset_mps2": float(b.model.coef[-1])},
    }
    out.series = {
        "before": b.heldout_err,
        "pair": {
            "measured": np.where(d.ok, d.m, np.nan),
            "reference": np.where(d.ok, d.a, np.nan),
            "baseline_fit": np.where(d.ok, acc.predict(d, b.model), np.nan),
            "labels": ("accel_x (smoothed)", f"d/dt of {d.speed_source}"),
        },
    }
    below, mounted = b, False
    for h in acc.HYPOTHESES:
        if h == "sensor_mounting" and d.q is None:
            out.untested.append(
                {
                    "effect": h,
                    "tested": False,
                    "why": "no yaw rate: the lateral acceleration v r is unknown",
                }
            )
            continue
        s = acc.evaluate(d, h, cfg, cl, mount=mounted)
        ok, why = accept(
            below.heldout_rmse_mps2, s.heldout_rmse_mps2, below.bic, s.bic, acc.RESOLUTION_MPS2, cfg
        )
        c = candidate(
            h,
            "longitudinal",
            name,
            below,
            s,
            below.heldout_rmse_mps2,
            s.heldout_rmse_mps2,
            ok,
            why,
            cfg.window_steer_s,
        )
        key = "yaw_rad" if h == "sensor_mounting" else "tau_s"
        _judge(
            c,
            acc.excludes_null(h, s),
            f"its interval {_iv(s.intervals[key])} does not exclude 0: the sensors agree within it",
        )
        if h == "accelerometer_lag":
            _judge(
                c,
                s.params["tau_s"] >= acc.MIN_TAU_SAMPLES * d.dt,
                f"a lag of {s.params['tau_s']:.3f} s is within {acc.MIN_TAU_SAMPLES} samples: "
                "the resampling's own timing, not a filter",
            )
            zp_tau, zp_sse = acc.zero_phase(d, mounted)
            lag_sse, base_sse = s.model.sse / s.model.n, below.model.sse / below.model.n
            out.info["zero_phase_smoother"] = {
                "tau_s": zp_tau,
                "sse_per_sample": zp_sse,
                "lag_sse_per_sample": lag_sse,
                "baseline_sse_per_sample": base_sse,
            }
            if zp_sse <= lag_sse:
                _judge(
                    c,
                    False,
                    f"a zero-phase smoother (tau {zp_tau:.2f} s forwards and "
                    "backwards) fits at least as well: the accelerometer reads a "
                    "smoother signal than the speed's derivative (a narrower "
                    "bandwidth), not a later one",
                )
            if zp_sse <= lag_sse and np.sqrt(zp_sse / base_sse) <= 1.0 - cfg.min_gain:
                out.notes.append(
                    f"accel_x and the speed's derivative differ in bandwidth, not in time: "
                    f"accel_x reads like d/dt of {d.speed_source} smoothed over {zp_tau:.2f} s "
                    f"without delay (equation error {np.sqrt(base_sse):.3g} -> "
                    f"{np.sqrt(zp_sse):.3g} m/s^2; a lag fits {np.sqrt(lag_sse):.3g}); no "
                    "accelerometer_lag is named"
                )
        if mounted:
            c["on_top_of"] = {"sensor_mounting": {"yaw_rad": below.params["yaw_rad"]}}
        if c["_ok"]:
            out.series["pair"][f"fit_{h}"] = np.where(d.ok, acc.predict(d, s.model), np.nan)
        out.cands.append(c)
        if h == "sensor_mounting" and c["_ok"]:
            below, mounted = s, True
            out.notes.append(
                f"the accelerometer is turned {np.degrees(s.params['yaw_rad']):+.1f} deg "
                f"[{np.degrees(s.intervals['yaw_rad'][0]):+.1f}, "
                f"{np.degrees(s.intervals['yaw_rad'][1]):+.1f}] about the vertical axis "
                f"(sensor_mounting): its accel_x reads {abs(np.sin(s.params['yaw_rad'])):.2f} "
                f"of the lateral acceleration v r and {abs(np.cos(s.params['yaw_rad'])):.2f} of "
                "dv/dt"
            )
    return out


def wheel_yaw(ch: dict, vehicle, cfg: DiagnoseConfig) -> Comparison:
    """The wheel-speed difference against the yaw rate: ``wheel_speed_scale``."""
    d, why = whl.prepare(ch, vehicle, cfg)
    h = "wheel_speed_scale"
    if d is None:
        return Comparison(False, why, untested=[{"effect": h, "tested": False, "why": why}])
    cl = corr_length(whl.residual(d, whl.fit(d, None, d.ok)))
    b = whl.evaluate(d, None, cfg, cl)
    name = "yaw_rate_vs_wheels"
    out = Comparison(True, channel=name)
    out.info = {
        "unit": "rad/s",
        "noise_floor": noise_floor(d.y),
        "rmse_baseline": b.heldout_rmse_radps,
        "heldout_rmse_baseline": b.heldout_rmse_radps,
        "wheels": d.pair,
        "track_m": d.track_m,
        "yaw_source": d.yaw_source,
        "track_scale_tested": d.fit_rho,
        "yaw_noise_share": d.attenuation,
        "yaw_explains": d.r2,
    }
    out.series = {
        "before": b.heldout_err,
        "pair": {
            "measured": np.where(d.ok, d.y, np.nan),
            "reference": np.where(d.ok, d.r, np.nan),
            "baseline_fit": np.where(d.ok, whl.predict(d, b.model), np.nan),
            "labels": (f"{d.pair} wheel-speed difference / track", d.yaw_source),
        },
    }
    if not d.fit_rho:
        out.notes.append(
            "effective track width not tested: the yaw rate is too little excited (noise "
            f"{100 * d.attenuation:.1f} % of its variance, at most {100 * whl.MAX_ATTENUATION:g} "
            f"%; it explains {100 * d.r2:.0f} % of the wheel-speed difference, at least "
            f"{100 * whl.MIN_R2:g} %); wheel_speed_scale tests the per-side radius only"
        )
    s = whl.evaluate(d, h, cfg, cl)
    ok, why = accept(
        b.heldout_rmse_radps, s.heldout_rmse_radps, b.bic, s.bic, whl.RESOLUTION_RADPS, cfg
    )
    c = candidate(
        h,
        "steering",
        name,
        b,
        s,
        b.heldout_rmse_radps,
        s.heldout_rmse_radps,
        ok,
        why,
        cfg.window_steer_s,
    )
    beyond = whl.disagreement(d, s)
    _judge(
        c,
        bool(beyond),
        "every interval includes the baseline (track_scale 1, side_ratio "
        "0): the sensors agree within them",
    )
    _judge(
        c,
        whl.in_bounds(s),
        "outside the catalogue's bounds: a wrong track in the geometry "
        "or swapped wheels, not a rolling radius",
    )
    if c["_ok"]:
        c["beyond_interval"] = beyond
        out.series["pair"]["fit_wheel_speed_scale"] = np.where(
            d.ok, whl.predict(d, s.model), np.nan
        )
    out.cands.append(c)
    return out


def _iv(iv) -> str:
    return f"[{iv[0]:.4g}, {iv[1]:.4g}]"
