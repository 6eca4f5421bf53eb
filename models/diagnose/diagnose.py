"""``diagnose``: where the report's model and a recording differ, which physics is missing, and
the held-out fit with it added.

0. **Parts**: each part (``sensors``, ``steering``, ``longitudinal``) runs when the recording
   supports it (its channels, enough moving data); one that cannot is named with the reason
   under ``not_diagnosed``. Only a recording that supports no part is refused. The
   longitudinal model runs on the inputs the recording holds (a command that moves, else the
   pedals recorded: ``lon_inputs``); the others are ``absent_inputs``, never filled in.
1. **Replay and residuals** per channel, each with its noise floor: speed (free-run windows)
   and acceleration (equation error); heading (free-run windows), road-wheel angle and yaw
   rate; position (free-run windows of eq. 1); independent sensors of one quantity against
   each other: the CAN speed against the GNSS speed (``sensors``), the accelerometer against
   the speed's derivative and the wheel-speed difference against the yaw rate
   (``agreement``).
2. **Locate**: windows above the noise floor, change points, and the residual by regime.
3. **Name**: every hypothesis of ``models.catalogue`` is refitted jointly with the
   baseline (the report's eq. 7 / eq. 8 structure on this recording) and scored by blocked
   held-out free-run RMSE. A hypothesis is a finding when it lowers that RMSE by
   ``DiagnoseConfig.min_gain`` and by more than the channel's resolution, lowers the BIC (with
   the effective sample size of autocorrelated residuals) and, for a linear term, is selected
   by FOS (Korenberg) among the baseline's terms. Of two alternative descriptions (delay or
   lag, v^2 or v resistance) only the better is a finding (the other under its
   ``alternatives``; within the channel's resolution the BIC or, for a delay and a lag, their
   joint fit decides, the reason in ``chosen_because``). Findings stack: a static term is
   refitted on top of an accepted delay or lag, and a delay or lag on top of the best static
   term when it was not a finding alone (each scored against the model below it). A
   physically impossible baseline (a pedal map that is not monotone, a negative drag when
   drag is fitted) is recorded as evidence of missing physics. The acceptance rule is
   ``candidates``; alternatives, stacking and the joint dead time + lag are ``stacking``.
4. **Unexplained**: a change in the car that no hypothesis models (a split fit of the final
   model lowers its error significantly, an F test in effective samples, Bonferroni over the
   splits, and by at least ``change_min_reduction``) is reported with its windows and its
   share of the error, never named (``unexplained``).

5. **Verdict**: whether the model with every finding describes the vehicle at all, against the
   noise floors and the prediction that nothing changes (``verdict``).

This module runs the steps in order and assembles the result; the extended and the baseline
parameter files are written by ``params_out``. The result's ``to_json()`` is the
``hmpc diagnose`` JSON contract (``verdict``, ``findings``, ``unexplained``,
``not_diagnosed``) plus the replay, the hypotheses tested, the steering samples used and the
baseline checks. The thresholds are ``DiagnoseConfig.for_vehicle`` (scaled to the vehicle's
size).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hmpc.models.catalogue import CATALOGUE
from hmpc.models.diagnose import agreement as agr
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose import sensors as sen
from hmpc.models.diagnose import steering as ste
from hmpc.models.diagnose.candidates import Resolution, accept, candidate, fos_selects
from hmpc.models.diagnose.common import DiagnoseConfig, corr_length, rmse, size_factor
from hmpc.models.diagnose.lon_extra import lon_extra_step
from hmpc.models.diagnose.lon_inputs import absent_inputs
from hmpc.models.diagnose.locate import (
    change_point,
    elevated_windows,
    improved_windows,
    noise_floor,
    regime_table,
    regime_variables,
    top_regimes,
)
from hmpc.models.diagnose.params_out import baseline_params, extended_params
from hmpc.models.diagnose.stacking import (
    actuator_response,
    drop_alternatives,
    stack_dynamics_on_static,
    stack_on_dynamics,
)
from hmpc.models.diagnose.unexplained import unexplained_change
from hmpc.models.diagnose.verdict import model_verdict
from hmpc.models.errors import InputError
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Params, Vehicle


@dataclass
class Diagnosis:
    """The outcome of :func:`diagnose` (``to_json()`` is the CLI's JSON)."""

    findings: list
    unexplained: list
    channels: dict
    hypotheses: list
    evidence: list
    longitudinal_input: str | None
    series: dict = field(repr=False, default_factory=dict)
    params_out: Params | None = None
    #: the report's baseline (eq. 7, eq. 8) fitted on the recording as it came, without any
    #: finding or sensor correction: what the extended model is compared against in closed loop
    baseline_out: Params | None = None
    timing_s: float = 0.0
    notes: list = field(default_factory=list)
    #: parts the recording could not support -> the reason (the JSON's ``not_diagnosed``)
    not_diagnosed: dict = field(default_factory=dict)
    #: the overall verdict (:func:`models.diagnose.verdict.model_verdict`)
    verdict: dict = field(default_factory=dict)
    #: the steering samples used and dropped by reason (``steering.support``)
    steering_samples: dict = field(default_factory=dict)
    #: longitudinal input channels the recording does not hold (never filled in)
    absent_inputs: list = field(default_factory=list)

    def to_json(self) -> dict:
        return _clean(
            {
                "verdict": self.verdict,
                "findings": self.findings,
                "unexplained": self.unexplained,
                "not_diagnosed": self.not_diagnosed,
                "channels": self.channels,
                "hypotheses": self.hypotheses,
                "baseline_checks": self.evidence,
                "longitudinal_input": self.longitudinal_input,
                "absent_inputs": self.absent_inputs,
                "steering_samples": self.steering_samples,
                "notes": self.notes,
                "timing_s": self.timing_s,
            }
        )


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if np.isfinite(f) else None
    return obj


def _zones(params: Params | None):
    if params is not None and params.zones:
        return tuple((z.name, z.v_min_mps, z.v_max_mps) for z in params.zones)
    return lon.DEFAULT_ZONES


@dataclass
class _Work:
    """What the steps of :func:`diagnose` share: the (corrected) channels and the results."""

    ch: dict
    series: dict
    cands: list = field(default_factory=list)
    hyps: list = field(default_factory=list)
    channels: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    evidence: list = field(default_factory=list)
    not_diagnosed: dict = field(default_factory=dict)
    ran: list = field(default_factory=list)  #: the parts that ran
    sensor_why: dict = field(default_factory=dict)  #: sensor pair -> why it was not compared
    steering_samples: dict = field(default_factory=dict)


def diagnose(
    rec: Recording,
    vehicle: Vehicle,
    params: Params | None = None,
    cfg: DiagnoseConfig | None = None,
    res: Resolution = Resolution(),
    progress=None,
) -> Diagnosis:
    """Diagnose ``rec`` against the report's model (see the module doc).

    Each part (``sensors``, ``steering``, ``longitudinal``) runs when the recording supports
    it; one that cannot is named with the reason in ``Diagnosis.not_diagnosed``.

    Args:
        rec: canonical recording.
        vehicle: geometry (wheelbase).
        params: the model to replay (its zones are used; the baseline is refitted on the
            recording for the held-out comparison, the given model is replayed as well).
        cfg: thresholds (default: ``DiagnoseConfig.for_vehicle(vehicle)``).
        res: smallest held-out improvement that counts, per channel (:class:`Resolution`).
        progress: callable receiving progress lines, or None.

    Raises:
        InputError: the recording has no speed channel, or supports no part at all.
    """
    t_start = time.perf_counter()
    say = progress or (lambda m: None)
    rec.require("time", "speed")
    ch = dict(rec.channels)
    zones = _zones(params)
    cfg = _fit_windows(DiagnoseConfig.for_vehicle(vehicle) if cfg is None else cfg, ch)
    w = _Work(ch=ch, series={"t": np.asarray(ch["time"], float)})
    if "x" in ch and "y" in ch and np.isfinite(np.asarray(ch["x"], float)).sum() > 1:
        w.series["path"] = {"x": np.asarray(ch["x"], float), "y": np.asarray(ch["y"], float)}

    _sensor_step(w, vehicle, cfg, res, say)
    _agreement_step(w, vehicle, cfg, say)
    regimes = regime_variables(w.ch, zones)
    steer_final = _steering_step(w, vehicle, cfg, res, say)
    ld = _longitudinal_data(w, zones, cfg)
    lon_scores: dict[str | None, Any] = {}
    response = None
    if ld is not None:
        say(f"longitudinal: eq. 8 zones driven by {', '.join(ld.input_names)}")
        w.notes += ld.input_notes
        if ld.absent_inputs:
            w.notes.append(
                "not in the recording (no model fills them in): " + ", ".join(ld.absent_inputs)
            )
        lon_scores, cl = _longitudinal_step(w, ld, cfg, res)
        w.series["speed"]["measured"] = ld.v  # for the verdict's persistence yardstick
        stack_on_dynamics(ld, w.cands, lon_scores, cfg, cl, res)
        stack_dynamics_on_static(ld, w.cands, lon_scores, cfg, cl, res)
        response = actuator_response(w.cands, w.ch, ld, lon_scores, cfg, cl)
        if response is not None:
            w.channels.setdefault("speed", {})["response"] = response
            w.notes.append(response["verdict"])
    if not w.ran:
        raise InputError(
            "nothing to diagnose: " + "; ".join(f"{k}: {v}" for k, v in w.not_diagnosed.items()),
            rec.meta.get("path"),
        )
    for part, why in w.not_diagnosed.items():
        say(f"{part}: not diagnosed: {why}")

    drop_alternatives(w.cands, res, response)
    findings = _rank_findings(w, regimes)
    _locate_channels(w, regimes, cfg)
    t = w.series["t"]
    unexplained = []
    if ld is not None:
        u = unexplained_change(ld, _final_lon_spec(findings, lon_scores), cfg, t)
        if u is not None:
            unexplained.append(u)
    verdict = model_verdict(w.channels, w.series, findings, cfg, size_factor(vehicle))

    params_out = extended_params(
        rec, vehicle, params, ld, lon_scores, steer_final, findings, zones, cfg, w.not_diagnosed
    )
    baseline_out = baseline_params(rec, vehicle, params, zones, cfg, w.not_diagnosed)
    return Diagnosis(
        findings,
        unexplained,
        _clean(w.channels),
        w.hyps,
        w.evidence,
        None if ld is None else "+".join(ld.input_names),
        w.series,
        params_out,
        baseline_out,
        round(time.perf_counter() - t_start, 3),
        w.notes,
        w.not_diagnosed,
        _clean(verdict),
        w.steering_samples,
        absent_inputs(w.ch),
    )


# ---- which parts the recording supports, and the sensor pairs compared ----------------------


def _longitudinal_data(w: _Work, zones, cfg: DiagnoseConfig) -> lon.LonData | None:
    """The longitudinal part's data, or None with its reason in ``w.not_diagnosed`` (no input
    the model can use, or too little moving data)."""
    try:
        ld = lon.prepare(w.ch, zones, cfg)
    except InputError as exc:
        w.not_diagnosed["longitudinal"] = exc.reason
        return None
    moving = (ld.ok & (ld.vs > cfg.v_stop_mps)).sum() if ld.ok.any() else 0
    if moving < int(20.0 / ld.dt):
        w.not_diagnosed["longitudinal"] = (
            f"too little moving data for the longitudinal model ({moving * ld.dt:.1f} s; "
            "needs 20 s)"
        )
        return None
    w.ran.append("longitudinal")
    return ld


def _agreement_step(w: _Work, vehicle: Vehicle, cfg: DiagnoseConfig, say) -> None:
    """Independent sensors of one quantity compared (``agreement``): the accelerometer against
    the speed's derivative, the wheel-speed difference against the yaw rate; each pair's
    channel, series and candidates join the result. The sensors part ran when any pair (these
    or the speed against the GNSS speed) was compared; else it is not diagnosed, each pair's
    reason named."""
    for label, c in (
        ("accelerometer", agr.accelerometer(w.ch, cfg)),
        ("wheel speeds", agr.wheel_yaw(w.ch, vehicle, cfg)),
    ):
        w.hyps += c.untested
        if not c.ran:
            w.sensor_why[label] = c.why
            continue
        say(f"sensors: {c.channel.replace('_vs_', ' against ').replace('_', ' ')}")
        w.channels[c.channel] = c.info
        w.series[c.channel] = c.series
        w.cands += c.cands
        w.notes += c.notes
        if "sensors" not in w.ran:
            w.ran.append("sensors")
    if "sensors" not in w.ran:
        w.not_diagnosed["sensors"] = "; ".join(f"{k}: {v}" for k, v in w.sensor_why.items())


def _sensor_step(w: _Work, vehicle: Vehicle, cfg: DiagnoseConfig, res: Resolution, say) -> None:
    """Step 1 (first): the CAN speed against the GNSS speed; an accepted time offset or wheel
    radius error corrects ``w.ch`` before the steering and longitudinal hypotheses."""
    sd = sen.prepare(w.ch, vehicle.wheelbase_m, cfg)
    if sd is None:
        w.notes.append("no gps_speed channel: wheel_radius_error and sensor_time_offset not tested")
        w.sensor_why["speed against GNSS"] = (
            "no gps_speed channel"
            if "gps_speed" not in w.ch
            else "too little straight moving data with gps_speed (needs 20 s)"
        )
        return
    w.ran.append("sensors")
    say("sensors: CAN speed against GNSS speed")
    cl = corr_length(sen.residual(sd))
    b = sen.evaluate(sd, None, cfg, cl)
    w.channels["speed_vs_gnss"] = {
        "unit": "m/s",
        "noise_floor": noise_floor(sd.g - sd.v),
        "heldout_rmse_baseline": b.heldout_rmse_mps,
    }
    w.series["speed_vs_gnss"] = {"before": b.heldout_err}
    for h in sen.HYPOTHESES:
        s = sen.evaluate(sd, h, cfg, cl)
        ok, why = accept(
            b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_vs_gnss_mps, cfg
        )
        w.cands.append(
            candidate(
                h,
                "longitudinal",
                "speed_vs_gnss",
                b,
                s,
                b.heldout_rmse_mps,
                s.heldout_rmse_mps,
                ok,
                why,
                cfg.window_lon_s,
            )
        )
    off = next((c for c in w.cands if c["effect"] == "sensor_time_offset" and c["_ok"]), None)
    if off is not None:
        w.ch = sen.ins_shift(w.ch, off["parameters"]["offset_s"])
        w.notes.append(
            f"INS channels moved by {off['parameters']['offset_s']:+.3f} s onto the "
            "CAN clock before the steering and longitudinal hypotheses"
        )
    rad = next((c for c in w.cands if c["effect"] == "wheel_radius_error" and c["_ok"]), None)
    if rad is not None:
        k = rad["parameters"]["scale"]
        for name in (
            "speed",
            "wheel_speed_fl",
            "wheel_speed_fr",
            "wheel_speed_rl",
            "wheel_speed_rr",
        ):
            if name in w.ch:
                w.ch[name] = np.asarray(w.ch[name], float) / k
        w.notes.append(
            f"CAN wheel speeds divided by {k:.4f} (wheel_radius_error) before the "
            "steering and longitudinal hypotheses"
        )


def _steering_step(
    w: _Work, vehicle: Vehicle, cfg: DiagnoseConfig, res: Resolution, say
) -> dict | None:
    """Step 1-3 for steering: eq. 7 in eq. 1 against the yaw rate and heading, its channels'
    residuals and every steering hypothesis. Returns the scores by hypothesis (None: not tested)."""
    sdt, why, w.steering_samples = ste.support(w.ch, vehicle.wheelbase_m, cfg)
    if sdt is None:
        w.not_diagnosed["steering"] = why
        return None
    w.ran.append("steering")
    channels, series = w.channels, w.series
    say("steering: eq. 7 in eq. 1 against the yaw rate and heading")
    base_m = ste.fit(sdt, None, 0.0, sdt.ok)
    cl = corr_length(ste.residual(sdt, base_m))
    b = ste.evaluate(sdt, None, cfg, cl)
    rr = ste.residual(sdt, b.model)
    channels["heading"] = {
        "unit": "rad",
        "source": sdt.heading_source,
        "noise_floor": noise_floor(sdt.heading),
        "heldout_rmse_baseline": b.heldout_rmse_rad,
    }
    channels["road_wheel_angle"] = {
        "unit": "rad",
        "noise_floor": noise_floor(rr),
        "rmse_baseline": rmse(rr),
    }
    yaw_pred = sdt.v * np.tan(ste.road_wheel_angle(sdt, b.model)) / sdt.b + b.model.bias_radps
    yr = np.where(sdt.ok, sdt.yaw - yaw_pred, np.nan)
    channels["yaw_rate"] = {
        "unit": "rad/s",
        "noise_floor": noise_floor(sdt.yaw),
        "rmse_baseline": rmse(yr),
    }
    series["heading"] = {"before": b.heldout_err, "measured": sdt.heading}
    series["road_wheel_angle"] = {"before": rr}
    pos = ste.position_errors(w.ch, sdt, b.model, cfg)
    if pos is not None:
        channels["position"] = {
            "unit": "m",
            "window_s": cfg.window_steer_s,
            "rmse_baseline": rmse(pos),
        }
        series["position"] = {"before": pos}
    steer_scores: dict[str | None, Any] = {None: b}
    for h in ste.HYPOTHESES:
        s = ste.evaluate(sdt, h, cfg, cl)
        steer_scores[h] = s
        ok, why = accept(b.heldout_rmse_rad, s.heldout_rmse_rad, b.bic, s.bic, res.heading_rad, cfg)
        w.cands.append(
            candidate(
                h,
                "steering",
                "heading",
                b,
                s,
                b.heldout_rmse_rad,
                s.heldout_rmse_rad,
                ok,
                why,
                cfg.window_steer_s,
            )
        )
    channels["heading"]["understeer_vs_ratio"] = ste.separability(
        sdt, steer_scores["understeer"], b, vehicle, cl, cfg
    )
    w.notes.append(channels["heading"]["understeer_vs_ratio"]["verdict"])
    return steer_scores


def _longitudinal_step(
    w: _Work, ld: lon.LonData, cfg: DiagnoseConfig, res: Resolution
) -> tuple[dict, float]:
    """Step 1-3 for eq. 8: the baseline, its checks, its channels' residuals and every
    longitudinal hypothesis. Returns the scores by hypothesis and the residual's correlation
    length."""
    base_m = lon.fit(ld, lon.LonSpec(), ld.ok)
    ra = lon.residual(ld, base_m)
    cl = corr_length(ra)
    b = lon.evaluate(ld, None, cfg, cl)
    w.evidence += lon.baseline_checks(b.model, ld)
    drag_free = lon.unconstrained_ext(ld, "aero_drag")
    if drag_free < 0:
        w.evidence.append(
            {
                "term": "aero_drag",
                "value": drag_free,
                "why": f"unbounded v^2 coefficient {drag_free:.2e} 1/m is a negative "
                "drag: the v^2 term absorbs something else (grade, creep, a "
                "delay)",
            }
        )
    w.channels["speed"] = {
        "unit": "m/s",
        "window_s": cfg.window_lon_s,
        "noise_floor": noise_floor(ld.v),
        "heldout_rmse_baseline": b.heldout_rmse_mps,
    }
    w.channels["accel"] = {
        "unit": "m/s^2",
        "noise_floor": noise_floor(ra),
        "rmse_baseline": rmse(ra),
    }
    w.series["speed"] = {"before": b.heldout_err}
    w.series["accel"] = {"before": ra}
    lon_scores: dict[str | None, Any] = {None: b}
    for h in lon.HYPOTHESES:
        if h == "road_grade" and ld.grade is None:
            w.hyps.append({"effect": h, "tested": False, "why": "no altitude or pitch channel"})
            continue
        if h == "idle_creep" and (ld.commanded or "accel_pedal" not in ld.input_names):
            w.hyps.append(
                {
                    "effect": h,
                    "tested": False,
                    "why": "the car follows a command, not the pedal"
                    if ld.commanded
                    else "no accel_pedal channel: when the throttle is released is not known",
                }
            )
            continue
        s = lon.evaluate(ld, h, cfg, cl)
        lon_scores[h] = s
        ok, why = accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        if ok and h in lon.LINEAR_EXT and not fos_selects(ld, h, spec=s.model.spec):
            ok, why = False, "FOS does not select the term on its hold-out"
        c = candidate(
            h,
            "longitudinal",
            "speed",
            b,
            s,
            b.heldout_rmse_mps,
            s.heldout_rmse_mps,
            ok,
            why,
            cfg.window_lon_s,
        )
        if h == "road_grade":
            c["parameters"]["grade_source"] = ld.grade_source
        w.cands.append(c)
    lon_extra_step(w, ld, b, lon_scores, cfg, res, cl)
    return lon_scores, cl


_HYP_KEYS = (
    "effect",
    "subsystem",
    "channel",
    "parameters",
    "intervals",
    "heldout_rmse_before",
    "heldout_rmse_after",
    "gain",
    "delta_bic",
)


def _rank_findings(w: _Work, regimes) -> list:
    """The accepted candidates, best gain first, with their windows, regimes and equation; every
    tested candidate is recorded in ``w.hyps`` (the rejected ones first)."""
    series = w.series
    t = series["t"]
    findings = []
    for c in sorted([c for c in w.cands if c["_ok"]], key=lambda c: -c["gain"]):
        e_b, e_a = c.pop("_before"), c.pop("_after")
        L = int(c.pop("_window_s") / (t[1] - t[0]))
        c["windows"] = improved_windows(t, e_b, e_a, L)
        c["regime"] = top_regimes(regime_table(regimes, e_b, e_a))
        c["equation"] = CATALOGUE[c["effect"]]["equation"][c["subsystem"]]
        if "after" not in series.setdefault(c["channel"], {}):  # the top finding's replay
            series[c["channel"]]["after"] = e_a
            series[c["channel"]]["after_effect"] = c["effect"]
        c.pop("_ok")
        findings.append(c)
    for c in w.cands:
        if "_ok" in c:
            c.pop("_before"), c.pop("_after"), c.pop("_window_s")
            ok = c.pop("_ok")
            w.hyps.append(
                {
                    **{k: c[k] for k in _HYP_KEYS},
                    "finding": ok,
                    "why": c["why"],
                    **({"stacked": c["stacked"]} if "stacked" in c else {}),
                }
            )
    for f in findings:
        w.hyps.append(
            {
                **{k: f[k] for k in _HYP_KEYS},
                "finding": True,
                "why": "accepted",
                **({"on_top_of": f["on_top_of"]} if "on_top_of" in f else {}),
            }
        )
    return findings


def _locate_channels(w: _Work, regimes, cfg: DiagnoseConfig) -> None:
    """Step 2 per channel: windows above the noise floor, the change point, the residual by
    regime."""
    t = w.series["t"]
    for name, s in w.series.items():
        if name == "t" or name not in w.channels:
            continue
        L = int(
            (
                cfg.window_lon_s
                if name in ("speed", "accel", "speed_vs_gnss")
                else cfg.window_steer_s
            )
            / (t[1] - t[0])
        )
        floor = w.channels[name].get("noise_floor", float("nan"))
        err = s.get("after", s["before"])
        w.channels[name]["elevated"] = elevated_windows(t, err, L, floor)
        w.channels[name]["change_point"] = change_point(t, s["before"], L)
        w.channels[name]["regime"] = regime_table(regimes, s["before"], s.get("after"))


def _fit_windows(cfg: DiagnoseConfig, ch: dict) -> DiagnoseConfig:
    """Shorter free-run windows for a short recording: at least four windows per held-out
    fold (a one-minute log gets 3-s windows), never shorter than 2 s."""
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    dur = float(np.isfinite(np.asarray(ch["speed"], float)).sum() * dt)
    w = max(2.0, dur / (4 * cfg.n_folds))
    return replace(
        cfg, window_lon_s=min(cfg.window_lon_s, w), window_steer_s=min(cfg.window_steer_s, w)
    )


def _final_lon_spec(findings: list, lon_scores: dict) -> lon.LonSpec:
    """The longitudinal model with every finding on the speed channel: the best stacked model
    (a term on top of another) when there is one, else the top finding's, else the baseline."""
    lf = [f for f in findings if f["subsystem"] == "longitudinal" and f["channel"] == "speed"]
    stacked = [f for f in lf if "on_top_of" in f and ("on_top", f["effect"]) in lon_scores]
    if stacked:
        f = min(stacked, key=lambda f: f["heldout_rmse_after"])
        return lon_scores[("on_top", f["effect"])].model.spec
    if lf:
        return lon_scores[lf[0]["effect"]].model.spec
    return lon.LonSpec()
