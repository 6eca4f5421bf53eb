"""``diagnose``: where the report's model and a recording differ, which physics is missing, and
the held-out fit with it added.

1. **Replay and residuals** per channel, each with its noise floor: speed (free-run windows)
   and acceleration (equation error); heading (free-run windows), road-wheel angle and yaw
   rate; position (free-run windows of eq. 1); the CAN speed against the GNSS speed.
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
   drag is fitted) is recorded as evidence of missing physics.
4. **Unexplained**: a change in the car that no hypothesis models (a split fit of the final
   model lowers its error significantly, an F test in effective samples, Bonferroni over the
   splits, and by at least ``change_min_reduction``) is reported with its windows and its
   share of the error, never named.

The result's ``to_json()`` is the ``hmpc diagnose`` JSON contract (``findings``,
``unexplained``) plus the replay, the hypotheses tested and the baseline checks.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.stats import f as f_dist

from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose import sensors as sen
from hmpc.models.diagnose import steering as ste
from hmpc.models.catalogue import ALTERNATIVES, CATALOGUE
from hmpc.models.diagnose.common import DiagnoseConfig, corr_length, rmse, windows
from hmpc.models.diagnose.locate import (change_point, elevated_windows, improved_windows,
                                         noise_floor, regime_table, regime_variables,
                                         top_regimes)
from hmpc.models.errors import InputError
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Params, Steering, Vehicle, Zone


@dataclass(frozen=True)
class Resolution:
    """Smallest held-out improvement that counts, per channel (the sensors' resolution)."""

    #: CAN wheel speed: 0.01 km/h steps, GNSS speed noise ~0.03 m/s; a speed replay that
    #: improves by less than 0.005 m/s is inside what the sensors can tell apart
    speed_mps: float = 0.005
    #: 0.06 deg: a survey-grade INS heading is good to 0.1 deg rms (models.sim.sensors.InsNoise),
    #: so a replay that gains less than about half of that is not a change in the car's steering
    heading_rad: float = 0.001
    #: speed difference CAN - GNSS
    speed_vs_gnss_mps: float = 0.005


@dataclass
class Diagnosis:
    """The outcome of :func:`diagnose` (``to_json()`` is the CLI's JSON)."""

    findings: list
    unexplained: list
    channels: dict
    hypotheses: list
    evidence: list
    longitudinal_input: str
    series: dict = field(repr=False, default_factory=dict)
    params_out: Params | None = None
    #: the report's baseline (eq. 7, eq. 8) fitted on the recording as it came, without any
    #: finding or sensor correction: what the extended model is compared against in closed loop
    baseline_out: Params | None = None
    timing_s: float = 0.0
    notes: list = field(default_factory=list)

    def to_json(self) -> dict:
        return _clean({"findings": self.findings, "unexplained": self.unexplained,
                       "channels": self.channels, "hypotheses": self.hypotheses,
                       "baseline_checks": self.evidence,
                       "longitudinal_input": self.longitudinal_input,
                       "notes": self.notes, "timing_s": self.timing_s})


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


def _fos_selects(d: lon.LonData, name: str, base: dict | None = None,
                 spec: lon.LonSpec | None = None) -> bool:
    """FOS (forced baseline terms) keeps the extension's term on its blocked hold-out
    (``spec``: the fitted hypothesis, e.g. a grade with its compensation rate)."""
    from hmpc.models.identify.fos import fos
    spec = spec or lon.LonSpec(name, **(base or {}))
    X, zone = lon._design(d, lon.fit_inputs(d, spec), spec)
    # the samples the fit uses (not those whose zone is ambiguous: a derivative window across
    # a zone change, or a speed at a zone boundary): there the measured dv/dt is neither
    # zone's law, and its error, larger than a resistance's within-zone slope, decides FOS's
    # hold-out instead of the term (independent recording A seed 5: a 0.006 1/s rolling
    # resistance, held-out gain 30 %, was refused by FOS on all samples)
    use = lon.fit_samples(d, X, zone)
    Xs = X[use]
    keep = np.abs(Xs).max(axis=0) > 1e-12
    Xs = Xs[:, keep]
    names = [f"b{i}" for i in range(Xs.shape[1] - 1)] + [name]
    y = d.a[use]
    # FOS's smallest error reduction (1e-4) is a fraction of mean(y^2); here y is the whole
    # pedal-driven acceleration and the baseline is forced, so the question is what the term
    # adds to what the baseline leaves: the threshold is taken as that fraction of the
    # baseline's residual (a 0.006 1/s rolling resistance reduces the residual by 6 %, 30 %
    # of the 10-s free-run error, and only 5e-5 of mean(a^2)); Korenberg's 4/(N+1) rule and
    # the blocked hold-out stay as they are
    if len(y) > Xs.shape[1]:
        base = Xs[:, :-1]
        resid = y - base @ np.linalg.lstsq(base, y, rcond=None)[0]
        frac = float(np.mean(resid ** 2) / max(np.mean(y ** 2), 1e-300))
    else:
        frac = 1.0
    try:
        res = fos(Xs, y, names, force=names[:-1], block_len=int(10.0 / d.dt),
                  min_reduction=1e-4 * min(frac, 1.0))
    except ValueError:
        return False
    return name in res.terms


def _accept(before: float, after: float, bic_b: float, bic_a: float, res: float,
            cfg: DiagnoseConfig) -> tuple[bool, str]:
    gain = (before - after) / before if before > 0 else 0.0
    if not np.isfinite(after):
        return False, "no held-out score"
    if gain < cfg.min_gain:
        return False, f"held-out gain {100 * gain:.1f} % < {100 * cfg.min_gain:.0f} %"
    if before - after < res:
        return False, f"held-out improvement {before - after:.4g} below the channel resolution {res:g}"
    if cfg.require_bic and not bic_a < bic_b:
        return False, "BIC does not improve"
    return True, "accepted"


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


def diagnose(rec: Recording, vehicle: Vehicle, params: Params | None = None,
             cfg: DiagnoseConfig = DiagnoseConfig(), res: Resolution = Resolution(),
             progress=None) -> Diagnosis:
    """Diagnose ``rec`` against the report's model (see the module doc).

    Args:
        rec: canonical recording. vehicle: geometry (wheelbase). params: the model to replay
            (its zones are used; the baseline is refitted on the recording for the held-out
            comparison, the given model is replayed as well).

    Raises:
        InputError: the recording has no speed channel or too little moving data.
    """
    t_start = time.perf_counter()
    say = progress or (lambda m: None)
    rec.require("time", "speed")
    ch = dict(rec.channels)
    zones = _zones(params)
    cfg = _fit_windows(cfg, ch)
    w = _Work(ch=ch, series={"t": np.asarray(ch["time"], float)})

    _sensor_step(w, vehicle, cfg, res, say)
    regimes = regime_variables(w.ch, zones)
    steer_final = _steering_step(w, vehicle, cfg, res, say)
    ld = lon.prepare(w.ch, zones, cfg)
    if not ld.ok.any() or (ld.ok & (ld.vs > cfg.v_stop_mps)).sum() < int(20.0 / ld.dt):
        raise InputError("too little moving data for the longitudinal model (needs 20 s)",
                         rec.meta.get("path"), channel="speed")
    say(f"longitudinal: eq. 8 zones driven by {', '.join(ld.input_names)}")
    lon_scores, cl = _longitudinal_step(w, ld, cfg, res)
    _stack_on_dynamics(ld, w.cands, lon_scores, cfg, cl, res)
    _stack_dynamics_on_static(ld, w.cands, lon_scores, cfg, cl, res)
    _joint_response(w, ld, lon_scores, cfg, cl)

    _drop_alternatives(w.cands, res, w.channels.get("speed", {}).get("response"))
    findings = _rank_findings(w, regimes)
    _locate_channels(w, regimes, cfg)
    t = w.series["t"]
    unexplained = []
    u = _change_unexplained(ld, _final_lon_spec(findings, lon_scores), cfg, t)
    if u is not None:
        unexplained.append(u)

    params_out = _params_out(rec, vehicle, params, ld, lon_scores, steer_final, findings,
                             zones, cfg)
    baseline_out = _baseline_out(rec, vehicle, params, zones, cfg)
    return Diagnosis(findings, unexplained, _clean(w.channels), w.hyps, w.evidence,
                     "+".join(ld.input_names), w.series, params_out, baseline_out,
                     round(time.perf_counter() - t_start, 3), w.notes)


def _sensor_step(w: _Work, vehicle: Vehicle, cfg: DiagnoseConfig, res: Resolution, say) -> None:
    """Step 1 (first): the CAN speed against the GNSS speed; an accepted time offset or wheel
    radius error corrects ``w.ch`` before the steering and longitudinal hypotheses."""
    sd = sen.prepare(w.ch, vehicle.wheelbase_m, cfg)
    if sd is None:
        w.notes.append("no gps_speed channel: wheel_radius_error and sensor_time_offset not tested")
        return
    say("sensors: CAN speed against GNSS speed")
    cl = corr_length(sen.residual(sd))
    b = sen.evaluate(sd, None, cfg, cl)
    w.channels["speed_vs_gnss"] = {
        "unit": "m/s", "noise_floor": noise_floor(sd.g - sd.v),
        "heldout_rmse_baseline": b.heldout_rmse_mps}
    w.series["speed_vs_gnss"] = {"before": b.heldout_err}
    for h in sen.HYPOTHESES:
        s = sen.evaluate(sd, h, cfg, cl)
        ok, why = _accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic,
                          res.speed_vs_gnss_mps, cfg)
        w.cands.append(_cand(h, "longitudinal", "speed_vs_gnss", b.heldout_rmse_mps,
                             s.heldout_rmse_mps, s.params, s.intervals, ok, why,
                             b.heldout_err, s.heldout_err, cfg.window_lon_s, s.bic - b.bic))
    off = next((c for c in w.cands if c["effect"] == "sensor_time_offset" and c["_ok"]), None)
    if off is not None:
        w.ch = sen.ins_shift(w.ch, off["parameters"]["offset_s"])
        w.notes.append(f"INS channels moved by {off['parameters']['offset_s']:+.3f} s onto the "
                       "CAN clock before the steering and longitudinal hypotheses")
    rad = next((c for c in w.cands if c["effect"] == "wheel_radius_error" and c["_ok"]), None)
    if rad is not None:
        k = rad["parameters"]["scale"]
        for name in ("speed", "wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl",
                     "wheel_speed_rr"):
            if name in w.ch:
                w.ch[name] = np.asarray(w.ch[name], float) / k
        w.notes.append(f"CAN wheel speeds divided by {k:.4f} (wheel_radius_error) before the "
                       "steering and longitudinal hypotheses")


def _steering_step(w: _Work, vehicle: Vehicle, cfg: DiagnoseConfig, res: Resolution,
                   say) -> dict | None:
    """Step 1-3 for steering: eq. 7 in eq. 1 against the yaw rate and heading, its channels'
    residuals and every steering hypothesis. Returns the scores by hypothesis (None: not tested)."""
    sdt = ste.prepare(w.ch, vehicle.wheelbase_m, cfg)
    if sdt is None:
        w.notes.append("no steering angle with yaw rate or heading: steering hypotheses not tested")
        return None
    channels, series = w.channels, w.series
    say("steering: eq. 7 in eq. 1 against the yaw rate and heading")
    base_m = ste.fit(sdt, None, 0.0, sdt.ok)
    cl = corr_length(ste.residual(sdt, base_m))
    b = ste.evaluate(sdt, None, cfg, cl)
    rr = ste.residual(sdt, b.model)
    channels["heading"] = {"unit": "rad", "source": sdt.heading_source,
                           "noise_floor": noise_floor(sdt.heading),
                           "heldout_rmse_baseline": b.heldout_rmse_rad}
    channels["road_wheel_angle"] = {"unit": "rad", "noise_floor": noise_floor(rr),
                                    "rmse_baseline": rmse(rr)}
    yaw_pred = sdt.v * np.tan(ste.road_wheel_angle(sdt, b.model)) / sdt.b + b.model.bias_radps
    yr = np.where(sdt.ok, sdt.yaw - yaw_pred, np.nan)
    channels["yaw_rate"] = {"unit": "rad/s", "noise_floor": noise_floor(sdt.yaw),
                            "rmse_baseline": rmse(yr)}
    series["heading"] = {"before": b.heldout_err}
    series["road_wheel_angle"] = {"before": rr}
    pos = _position_errors(w.ch, sdt, b.model, cfg)
    if pos is not None:
        channels["position"] = {"unit": "m", "window_s": cfg.window_steer_s,
                                "rmse_baseline": rmse(pos)}
        series["position"] = {"before": pos}
    steer_scores = {None: b}
    for h in ste.HYPOTHESES:
        s = ste.evaluate(sdt, h, cfg, cl)
        steer_scores[h] = s
        ok, why = _accept(b.heldout_rmse_rad, s.heldout_rmse_rad, b.bic, s.bic,
                          res.heading_rad, cfg)
        w.cands.append(_cand(h, "steering", "heading", b.heldout_rmse_rad, s.heldout_rmse_rad,
                             s.params, s.intervals, ok, why, b.heldout_err, s.heldout_err,
                             cfg.window_steer_s, s.bic - b.bic))
    channels["heading"]["understeer_vs_ratio"] = _separability(
        sdt, steer_scores["understeer"], b, vehicle, cl)
    w.notes.append(channels["heading"]["understeer_vs_ratio"]["verdict"])
    return steer_scores


def _longitudinal_step(w: _Work, ld: lon.LonData, cfg: DiagnoseConfig,
                       res: Resolution) -> tuple[dict, float]:
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
        w.evidence.append({"term": "aero_drag", "value": drag_free,
                           "why": f"unbounded v^2 coefficient {drag_free:.2e} 1/m is a negative "
                                  "drag: the v^2 term absorbs something else (grade, creep, a "
                                  "delay)"})
    w.channels["speed"] = {"unit": "m/s", "window_s": cfg.window_lon_s,
                           "noise_floor": noise_floor(ld.v),
                           "heldout_rmse_baseline": b.heldout_rmse_mps}
    w.channels["accel"] = {"unit": "m/s^2", "noise_floor": noise_floor(ra),
                           "rmse_baseline": rmse(ra)}
    w.series["speed"] = {"before": b.heldout_err}
    w.series["accel"] = {"before": ra}
    lon_scores = {None: b}
    for h in lon.HYPOTHESES:
        if h == "road_grade" and ld.grade is None:
            w.hyps.append({"effect": h, "tested": False, "why": "no altitude or pitch channel"})
            continue
        if h == "idle_creep" and "accel_cmd" in ld.input_names:
            w.hyps.append({"effect": h, "tested": False,
                           "why": "the car follows an acceleration command, not the pedal"})
            continue
        s = lon.evaluate(ld, h, cfg, cl)
        lon_scores[h] = s
        ok, why = _accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        if ok and h in lon.LINEAR_EXT and not _fos_selects(ld, h, spec=s.model.spec):
            ok, why = False, "FOS does not select the term on its hold-out"
        c = _cand(h, "longitudinal", "speed", b.heldout_rmse_mps, s.heldout_rmse_mps, s.params,
                  s.intervals, ok, why, b.heldout_err, s.heldout_err, cfg.window_lon_s,
                  s.bic - b.bic)
        if h == "road_grade":
            c["parameters"]["grade_source"] = ld.grade_source
        w.cands.append(c)
    return lon_scores, cl


def _drop_alternatives(cands: list, res: Resolution = Resolution(),
                       response: dict | None = None) -> None:
    """Of two alternative descriptions of one subsystem only the better stays a finding.

    Better is the lower held-out free-run RMSE, unless the two differ by less than the
    channel's resolution: then the replay cannot tell them apart and the equation-error BIC
    over all samples (the same baseline below both, one extension parameter each) decides. A
    v and a v^2 resistance are such a pair: the zone offsets hold the constant part, so the
    two differ only in how the slope changes from zone to zone, which a 10-s free run hardly
    sees (independent recordings: 0.00016 m/s apart, the v term's BIC 5.6 lower, truth v).
    Only for linear terms (one coefficient each, the same zone structure): a dead time and a
    lag are fitted against a smoothed derivative that itself looks like a lag, so their
    equation-error likelihoods are no fair judge between them (the comma minute: held-out
    0.251 against 0.253 m/s, the BIC prefers the lag; the replay keeps the dead time).

    A dead time and a lag within the resolution are judged by their joint fit (``response``,
    :func:`_joint_response`): the one that alone fits as well as the joint fit, where the other
    does not. When either alone does (the recording fixes the total delay, not its split),
    the dead time is named: of two responses with the same effective delay it costs the
    more phase (omega d against atan(omega tau), unbounded against at most 90 deg), so a
    controller designed on it keeps its margin on the other; a lag would promise a margin
    the car may not have (the comma minute: dead time 0.27 s and lag 0.33 s, 0.003 m/s
    apart, the joint fit's likelihood ratios 0.7 and 0.1)."""
    tol = {"speed": res.speed_mps, "heading": res.heading_rad,
           "speed_vs_gnss": res.speed_vs_gnss_mps}
    for group in ALTERNATIVES:
        for sub in ("steering", "longitudinal"):
            g = [c for c in cands if c["effect"] in group and c["subsystem"] == sub and c["_ok"]]
            if len(g) > 1:
                g.sort(key=lambda c: c["heldout_rmse_after"])
                a, b = g[0], g[1]
                if (a["effect"] in lon.LINEAR_EXT and b["effect"] in lon.LINEAR_EXT
                        and a["channel"] == b["channel"]
                        and a["heldout_rmse_before"] == b["heldout_rmse_before"]
                        and b["heldout_rmse_after"] - a["heldout_rmse_after"]
                        < tol.get(a["channel"], 0.0)
                        and b["delta_bic"] < a["delta_bic"]):
                    g[0], g[1] = b, a
                elif ({a["effect"], b["effect"]} == set(_DYNAMICS) and response is not None
                      and a["heldout_rmse_before"] == b["heldout_rmse_before"]
                      and b["heldout_rmse_after"] - a["heldout_rmse_after"]
                      < tol.get(a["channel"], 0.0)):
                    pick = _dynamics_by_joint_fit(response)
                    if pick is not None and pick != a["effect"]:
                        g[0], g[1] = b, a
                        b["chosen_because"] = (
                            f"{a['effect']} replays only "
                            f"{b['heldout_rmse_after'] - a['heldout_rmse_after']:.4f} m/s better "
                            f"(within the speed resolution); the joint dead-time + lag fit: "
                            f"{response['split']}"
                            + ("; so the dead time is named: for the same delay it costs the "
                               "more phase"
                               if response["lr_lag_only"] <= 3.84 else ""))
                for c in g[1:]:
                    c["_ok"] = False
                    c["why"] = f"alternative to {g[0]['effect']}, " + (
                        "which explains more" if g[0]["heldout_rmse_after"]
                        <= c["heldout_rmse_after"] else "the better description within the "
                        "channel's resolution")
                g[0]["alternatives"] = [{"effect": c["effect"], "parameters": c["parameters"],
                                         "heldout_rmse_after": c["heldout_rmse_after"]}
                                        for c in g[1:]]


_HYP_KEYS = ("effect", "subsystem", "channel", "parameters", "intervals", "heldout_rmse_before",
             "heldout_rmse_after", "gain", "delta_bic")


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
            w.hyps.append({**{k: c[k] for k in _HYP_KEYS}, "finding": ok, "why": c["why"],
                           **({"stacked": c["stacked"]} if "stacked" in c else {})})
    for f in findings:
        w.hyps.append({**{k: f[k] for k in _HYP_KEYS}, "finding": True, "why": "accepted",
                       **({"on_top_of": f["on_top_of"]} if "on_top_of" in f else {})})
    return findings


def _locate_channels(w: _Work, regimes, cfg: DiagnoseConfig) -> None:
    """Step 2 per channel: windows above the noise floor, the change point, the residual by
    regime."""
    t = w.series["t"]
    for name, s in w.series.items():
        if name == "t" or name not in w.channels:
            continue
        L = int((cfg.window_lon_s if name in ("speed", "accel", "speed_vs_gnss")
                 else cfg.window_steer_s) / (t[1] - t[0]))
        floor = w.channels[name].get("noise_floor", float("nan"))
        err = s.get("after", s["before"])
        w.channels[name]["elevated"] = elevated_windows(t, err, L, floor)
        w.channels[name]["change_point"] = change_point(t, s["before"], L)
        w.channels[name]["regime"] = regime_table(regimes, s["before"], s.get("after"))


def _sse_fixed_scale(d: ste.SteerData, scale: float) -> float:
    """Smallest angle SSE with the steering scale fixed and the understeer gradient free."""
    use = d.fit_ok
    v, sw, y = d.v[use], d.sw[use], d.dm[use]
    best = np.inf
    for k in np.linspace(0.0, ste.K_MAX, 81):
        div = 1.0 + k * v * v / d.b
        X = np.column_stack([1.0 / div, d.b / v])
        r = y - scale * sw / div
        c = np.linalg.lstsq(X, r, rcond=None)[0]
        best = min(best, float(np.sum((r - X @ c) ** 2)))
    return best


def _separability(d: ste.SteerData, us, base, vehicle: Vehicle, corr_len: float) -> dict:
    """Can this recording tell understeer (delta / (1 + K v^2 / b)) from the steering ratio?

    Two explanations of the measured yaw response are compared: the kinematic one (scale
    fitted, K = 0: the baseline) and the maker's ratio with understeer (scale = 1 /
    steering_ratio, K fitted). Separable when the likelihood ratio between them exceeds the
    95 % chi-square(1) point with the effective sample size; without a maker's ratio, when
    the understeer gradient's interval is narrower than the passenger-car range (0.003)."""
    lo, hi = us.intervals.get("gradient_rad_per_mps2", [0.0, ste.K_MAX])
    ne = max(base.model.n / max(corr_len, 1.0), 3.0)
    out = {"gradient_interval": [lo, hi]}
    ratio = vehicle.steering_ratio
    if ratio:
        sse_maker = _sse_fixed_scale(d, 1.0 / ratio)
        lr = float(ne * np.log(sse_maker / base.model.sse))
        ok = abs(lr) > 3.84
        out.update(maker_scale=1.0 / ratio, kinematic_scale=base.model.scale,
                   likelihood_ratio=lr)
        verdict = ("understeer and the steering ratio are separable on this recording: "
                   if ok else "this recording cannot separate understeer from the steering "
                   "ratio: ") + (
            f"the kinematic scale {base.model.scale:.4f} with no understeer and the maker's "
            f"1/{ratio:g} = {1 / ratio:.4f} with understeer fit with likelihood ratio "
            f"{lr:.1f} (separable above 3.84)")
    else:
        ok = (hi - lo) < 0.003
        verdict = ("understeer and the steering ratio are separable on this recording"
                   if ok else "this recording cannot separate understeer from the steering ratio") \
            + f": understeer gradient in [{lo:.4f}, {hi:.4f}] rad/(m/s^2)"
    out.update(separable=bool(ok), verdict=verdict)
    return out


def _stack_on_dynamics(ld, cands, lon_scores, cfg, cl, res) -> None:
    """Refit the static longitudinal extensions on top of an accepted delay or lag: a drag or
    grade that only looked useful because the actuator's dynamics were missing is dropped, one
    that helps on top of them is kept (scored against the model with the dynamics)."""
    dyn = [c for c in cands if c["subsystem"] == "longitudinal" and c["_ok"]
           and c["effect"] in ("actuator_delay", "actuator_lag")]
    if not dyn:
        return
    top = min(dyn, key=lambda c: c["heldout_rmse_after"])
    key = lon.NONLINEAR[top["effect"]]
    base = {key: top["parameters"][key]}
    b = lon_scores[top["effect"]]
    for c in [c for c in cands if c["subsystem"] == "longitudinal" and c["channel"] == "speed"
              and c["effect"] in lon.LINEAR_EXT]:
        h = c["effect"]
        s = lon.evaluate(ld, h, cfg, cl, base=base)
        ok, why = _accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        if ok and not _fos_selects(ld, h, spec=s.model.spec):
            ok, why = False, "FOS does not select the term on its hold-out"
        if ok:
            lon_scores[("on_top", h)] = s
            new = _cand(h, "longitudinal", "speed", b.heldout_rmse_mps, s.heldout_rmse_mps,
                        s.params, s.intervals, True, f"accepted on top of {top['effect']}",
                        b.heldout_err, s.heldout_err, cfg.window_lon_s, s.bic - b.bic)
            new["on_top_of"] = {top["effect"]: base}
            if h == "road_grade":
                new["parameters"]["grade_source"] = ld.grade_source
            c.clear()
            c.update(new)
        elif c["_ok"]:
            c["_ok"] = False
            c["why"] = f"explained by {top['effect']}: on top of it {why}"


def _stack_dynamics_on_static(ld, cands, lon_scores, cfg, cl, res) -> None:
    """An actuator's delay or lag can hide behind a larger static mismatch (on the comma minute
    a grade change the ACC compensates only over seconds dwarfs its 0.3 s response). When no
    delay or lag is a finding on its own but a static term is, each is refitted on top of the
    best static term (its parameters searched again) and scored against that model."""
    lon_speed = [c for c in cands if c["subsystem"] == "longitudinal" and c["channel"] == "speed"]
    if any(c["_ok"] and c["effect"] in _DYNAMICS for c in lon_speed):
        return
    static = [c for c in lon_speed if c["_ok"] and c["effect"] in lon.LINEAR_EXT]
    if not static:
        return
    top = min(static, key=lambda c: c["heldout_rmse_after"])
    b = lon_scores[top["effect"]]
    base = {"ext_name": top["effect"], "comp_rate_per_s": b.model.spec.comp_rate_per_s,
            "creep_speed_mps": b.model.spec.creep_speed_mps}
    below = {k: v for k, v in top["parameters"].items() if isinstance(v, float)}
    for c in [c for c in lon_speed if c["effect"] in _DYNAMICS]:
        h = c["effect"]
        s = lon.evaluate(ld, h, cfg, cl, base=base)
        ok, why = _accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
        new = _cand(h, "longitudinal", "speed", b.heldout_rmse_mps, s.heldout_rmse_mps, s.params,
                    s.intervals, ok, f"accepted on top of {top['effect']}" if ok
                    else f"on top of {top['effect']}: {why}", b.heldout_err, s.heldout_err,
                    cfg.window_lon_s, s.bic - b.bic)
        new["on_top_of"] = {top["effect"]: below}
        if not ok:  # the hypothesis alone stays on record; the stacked try goes beside it
            c["why"] = f"{c['why']}; {new['why']}"
            c["stacked"] = {k: new[k] for k in ("parameters", "intervals", "heldout_rmse_before",
                                                "heldout_rmse_after", "gain", "on_top_of")}
            continue
        lon_scores[("on_top", h)] = s
        c.clear()
        c.update(new)


_DYNAMICS = ("actuator_delay", "actuator_lag")


def _dynamics_by_joint_fit(response: dict) -> str | None:
    """The dead time or the lag as the joint fit judges them (:func:`_drop_alternatives`):
    the one that alone fits within likelihood ratio 3.84 of the joint fit where the other does
    not; the dead time when both do; None when neither does (the joint fit needs both)."""
    lr_d, lr_l = response.get("lr_dead_time_only"), response.get("lr_lag_only")
    if lr_d is None or lr_l is None:
        return None
    if lr_d <= 3.84:
        return "actuator_delay"
    return "actuator_lag" if lr_l <= 3.84 else None



def _split_verdict(lr_dead: float, lr_lag: float) -> str:
    """What the likelihood ratios of the dead time alone and the lag alone against their joint
    fit say when the joint fit does not need both (3.84: chi-square, 1 dof, 95 %)."""
    if lr_dead <= 3.84 and lr_lag <= 3.84:
        return (f"it cannot tell a dead time from a lag (either alone fits within likelihood "
                f"ratio 3.84 of the joint fit: dead time {lr_dead:.1f}, lag {lr_lag:.1f}): it "
                "fixes the total delay, not its split")
    one, other, lr_one, lr_other = (("a lag", "a dead time", lr_lag, lr_dead) if lr_lag <= 3.84
                                    else ("a dead time", "a lag", lr_dead, lr_lag))
    return (f"{one} alone fits as well as the joint fit (likelihood ratio {lr_one:.1f}), "
            f"{other} alone does not ({lr_other:.1f} > 3.84): the response is {one}")

def _joint_response(w: _Work, ld: lon.LonData, lon_scores: dict, cfg: DiagnoseConfig,
                    cl: float) -> None:
    """The actuator's response as a dead time and a lag fitted together
    (:func:`longitudinal.joint_response`), on top of the model the single delay and lag were
    scored against: its total effective delay d + tau with intervals, its held-out speed
    RMSE, and whether the recording can tell a dead time from a lag. Recorded in
    ``channels["speed"]["response"]`` and as a note. It names no finding of its own (the
    catalogue's delay and lag are the descriptions that are ranked); it decides between the
    two when their replays are within the speed resolution (:func:`_drop_alternatives`)."""
    lon_speed = [c for c in w.cands if c["subsystem"] == "longitudinal"
                 and c["channel"] == "speed"]
    dyn = [c for c in lon_speed if c["effect"] in _DYNAMICS and (
        c["_ok"] or max(c["gain"], c.get("stacked", {}).get("gain", 0.0)) >= cfg.min_gain / 2)]
    if not dyn:  # no delay or lag found or hinted at (half a finding's gain, alone or on top
        return   # of a static term): nothing to qualify, and the map costs seconds
    # the static term of the final model: the one a delay or lag was fitted on top of, or one
    # accepted on top of the delay or lag
    below = next((next(iter(c.get("on_top_of") or c.get("stacked", {}).get("on_top_of") or {}))
                  for c in dyn if c.get("on_top_of") or "stacked" in c), None)
    below = below or next((c["effect"] for c in lon_speed if c["_ok"] and c["effect"]
                           in lon.LINEAR_EXT and set(c.get("on_top_of") or ()) & set(_DYNAMICS)),
                          None)
    base, before = {}, lon_scores[None].heldout_rmse_mps
    if below is not None and below in lon_scores:
        sp = lon_scores[below].model.spec
        base = {"ext_name": sp.term, "comp_rate_per_s": sp.comp_rate_per_s,
                "creep_speed_mps": sp.creep_speed_mps}
        before = lon_scores[below].heldout_rmse_mps
    r = lon.joint_response(ld, base, cfg, cl)
    after = r["heldout_rmse_mps"]
    r.update(on_top_of=below, heldout_rmse_before=before,
             gain=(before - after) / before if before > 0 and np.isfinite(after) else 0.0)
    iv = r["intervals"]
    split = ("no delay or lag beyond the model's" if iv["effective_delay_s"][0] == 0.0
             and r["gain"] < cfg.min_gain else
             "it separates a dead time from a lag" if r["separable"] else
             _split_verdict(r["lr_dead_time_only"], r["lr_lag_only"]))
    r["split"] = split
    r["verdict"] = (
        f"response of the acceleration to {r['input']}"
        + (f" on top of {below}" if below else "")
        + f": dead time {r['dead_time_s']:.2f} s [{iv['dead_time_s'][0]:.2f}, "
        f"{iv['dead_time_s'][1]:.2f}] and lag {r['tau_s']:.2f} s [{iv['tau_s'][0]:.2f}, "
        f"{iv['tau_s'][1]:.2f}] fitted together, effective delay d + tau "
        f"{r['effective_delay_s']:.2f} s [{iv['effective_delay_s'][0]:.2f}, "
        f"{iv['effective_delay_s'][1]:.2f}] (63 % of a step), held-out speed RMSE "
        f"{before:.3f} -> {after:.3f} m/s ({100 * r['gain']:.0f} %); {split}")
    other = _response_on_gnss_speed(w.ch, ld, base, cfg)
    if other is not None:
        r["gnss_speed"] = other
        oi = other["intervals"]["effective_delay_s"]
        r["verdict"] += (f"; measured on the GNSS speed instead (an independent sensor): d + tau "
                         f"{other['effective_delay_s']:.2f} s [{oi[0]:.2f}, {oi[1]:.2f}]")
    w.channels.setdefault("speed", {})["response"] = r
    w.notes.append(r["verdict"])


def _response_on_gnss_speed(ch: dict, ld: lon.LonData, base: dict, cfg: DiagnoseConfig
                            ) -> dict | None:
    """The joint dead time + lag of the same inputs with the GNSS ground speed as the speed: a
    cross-check of the response on a sensor independent of the wheel speeds (their own
    filtering or timing would show as a different delay). None without a usable GNSS speed."""
    g = ch.get("gps_speed")
    if g is None or np.isfinite(np.asarray(g, float)).mean() < 0.8:
        return None
    lg = lon.prepare({**ch, "speed": np.asarray(g, float)}, ld.zones, cfg)
    if (lg.ok & (lg.vs > cfg.v_stop_mps)).sum() < int(20.0 / lg.dt):
        return None
    cl = corr_length(lon.residual(lg, lon.fit(lg, lon.LonSpec(), lg.ok)))
    r = lon.joint_response(lg, base, cfg, cl)
    return {k: r[k] for k in ("dead_time_s", "tau_s", "effective_delay_s", "intervals",
                              "heldout_rmse_mps")}


def _fit_windows(cfg: DiagnoseConfig, ch: dict) -> DiagnoseConfig:
    """Shorter free-run windows for a short recording: at least four windows per held-out
    fold (a one-minute log gets 3-s windows), never shorter than 2 s."""
    t = np.asarray(ch["time"], float)
    dt = float(np.median(np.diff(t)))
    dur = float(np.isfinite(np.asarray(ch["speed"], float)).sum() * dt)
    w = max(2.0, dur / (4 * cfg.n_folds))
    return replace(cfg, window_lon_s=min(cfg.window_lon_s, w),
                   window_steer_s=min(cfg.window_steer_s, w))


def _cand(effect, subsystem, channel, before, after, params, intervals, ok, why, e_b, e_a,
          window_s, dbic) -> dict:
    gain = (before - after) / before if before > 0 and np.isfinite(after) else 0.0
    return {"effect": effect, "subsystem": subsystem, "channel": channel,
            "parameters": {k: float(v) for k, v in params.items()},
            "intervals": {k: [float(a), float(b)] for k, (a, b) in intervals.items()},
            "heldout_rmse_before": float(before), "heldout_rmse_after": float(after),
            "gain": float(gain), "delta_bic": float(dbic), "physics": CATALOGUE[effect]["physics"],
            "why": why, "_ok": ok, "_before": e_b, "_after": e_a, "_window_s": window_s}


def _position_errors(ch, d: ste.SteerData, m: ste.SteerModel, cfg) -> np.ndarray | None:
    """Position error [m] of free-run windows of eq. 1 (measured speed, modelled heading)."""
    if "x" not in ch or "y" not in ch:
        return None
    x, y = np.asarray(ch["x"], float), np.asarray(ch["y"], float)
    L = int(cfg.window_steer_s / d.dt)
    idx = windows(d.ok & np.isfinite(x) & np.isfinite(y), L)
    if idx.size == 0:
        return None
    delta = np.nan_to_num(ste.road_wheel_angle(d, m))
    r = d.v * np.tan(delta) / d.b
    vf = d.v / np.cos(delta)  # the front point (eq. 1's x, y) moves faster than the rear axle
    psi = d.heading[idx[:, :1]] + np.concatenate(
        [np.zeros((len(idx), 1)), np.cumsum(r[idx][:, :-1] * d.dt, axis=1)], axis=1)
    ang = psi + delta[idx]
    vx, vy = vf[idx] * np.cos(ang), vf[idx] * np.sin(ang)
    px = x[idx[:, :1]] + np.concatenate([np.zeros((len(idx), 1)),
                                         np.cumsum(vx[:, :-1] * d.dt, axis=1)], axis=1)
    py = y[idx[:, :1]] + np.concatenate([np.zeros((len(idx), 1)),
                                         np.cumsum(vy[:, :-1] * d.dt, axis=1)], axis=1)
    out = np.full(d.n, np.nan)
    out[idx] = np.hypot(px - x[idx], py - y[idx])
    return out


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


def _inputs_on_both_sides(d: lon.LonData, left: np.ndarray, right: np.ndarray) -> bool:
    """Every input the recording uses is used on both sides of a split (at least 10 % of its
    active samples on each): a side that never saw an input (the driver's pedal before an ACC
    engages) cannot fit its gain, and its split fit would fake a change in the car."""
    act = np.abs(np.nan_to_num(d.U)) > 0.01
    n = act[d.ok].sum(axis=0)
    used = n > 0
    return bool(np.all(act[left].sum(axis=0)[used] >= 0.1 * n[used])
                and np.all(act[right].sum(axis=0)[used] >= 0.1 * n[used]))


def _block_corr_length(r: np.ndarray, block: int) -> float:
    """Correlation length [samples] of a residual counted in blocks: ``block`` times
    :func:`corr_length` of its means over consecutive ``block``-sample blocks.

    The acceleration is a Savitzky-Golay derivative over ``deriv_window_s``: every sample
    within one window shares the same speeds, and the filter's negative side lobes pull the
    residual's autocorrelation below :func:`corr_length`'s 0.05 cut within that window even
    when a slow error follows it (acc_truth flat, 60 s, seed 6: 16 samples per independent one
    from the raw residual, about 50 from its 0.5 s means)."""
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    nb = len(r) // block
    if nb < 2:
        return float(max(len(r), 1))
    return block * corr_length(r[:nb * block].reshape(nb, block).mean(axis=1))


def _split_test(d: lon.LonData, spec: lon.LonSpec, pooled: lon.LonModel, tk: float, t,
                block: int) -> dict | None:
    """Chow F test of one split at ``tk`` [s]: the final model fitted before and after it
    against one fit for all, counted in effective samples. ``None`` when a side cannot be
    fitted or the effective samples do not exceed the split's parameters."""
    left, right = d.ok & (t < tk), d.ok & (t >= tk)
    m1, m2 = lon.fit(d, spec, left), lon.fit(d, spec, right)
    sse = m1.sse + m2.sse
    extra = m1.k + m2.k - pooled.k    # the parameters the second fit adds
    if not (m1.k and m2.k and np.isfinite(sse) and 0.0 < sse) or extra <= 0:
        return None
    # residual correlation under the split (a real change inflates the pooled one's), the
    # larger side's: fewer independent samples, the cautious count
    cl = max(_block_corr_length(np.where(left, lon.residual(d, m1), np.nan), block),
             _block_corr_length(np.where(right, lon.residual(d, m2), np.nan), block))
    n_eff = (m1.n + m2.n) / cl
    dof = n_eff - m1.k - m2.k
    if dof < 1.0:
        return None
    red = 1.0 - sse / pooled.sse
    f = max(pooled.sse - sse, 0.0) / extra / (sse / dof)
    return {"t": float(tk), "reduction": float(red), "f": float(f),
            "dof": [int(extra), round(dof, 1)], "effective_samples": round(n_eff, 1),
            "p": float(f_dist.sf(f, extra, dof))}


def _change_unexplained(d: lon.LonData, spec: lon.LonSpec, cfg: DiagnoseConfig,
                        t) -> dict | None:
    """A change in the car no hypothesis models: the final longitudinal model (``spec``)
    fitted before and after a split explains the data better than one model for all of it,
    by more than chance and by more than ``cfg.change_min_reduction``.

    The rule (a Chow test with a sup over the split points, Bonferroni-corrected). At each of
    up to 13 split points (20-80 % of the moving samples) the split fit lowers the equation
    error's SSE from S0 to S1 with ``q`` more parameters (``k1 + k2 - k0``). The residuals are
    strongly autocorrelated (on a minute of closed-loop ACC driving, 1-5 s of residual are
    one independent sample), so the samples are counted as effective samples n_e = n / l,
    ``l`` the residual's correlation length under the split (:func:`_block_corr_length`, the
    larger side's), and ``F = ((S0 - S1) / q) / (S1 / (n_e - k1 - k2))`` is referred to
    F(q, n_e - k1 - k2). The best of the splits (smallest p) is a change when its p times the
    number of splits tested is at most ``cfg.change_alpha`` (Bonferroni: at most that chance
    of a false alarm on a recording without change; neighbouring splits share most of their
    data, so it is cautious) AND its SSE reduction is at least ``cfg.change_min_reduction``
    (an effect size: on 10 minutes a 2-3 % reduction is significant and still no change in
    the car, only a model that is not exactly right everywhere).

    Why: a fixed reduction alone does not know how much data stands behind it: on one minute
    of a clean ACC recording (tests/indep/acc_truth.py) 13-67 effective samples carry the
    split's 6-10 parameters, and the best of 13 splits lowered the SSE by 16-73 % with nothing
    changed in the car (16 of 16 flat and hilly minutes reported a change; now none of 40,
    while a 0.7 x pedal gain from half time is found on a minute with p below 1e-6)."""
    pooled = lon.fit(d, spec, d.ok)
    idx = np.flatnonzero(d.ok & (d.vs > cfg.v_stop_mps) & np.isfinite(d.a))
    if len(idx) < 200 or not np.isfinite(pooled.sse) or pooled.sse <= 0:
        return None
    block = max(int(round(cfg.deriv_window_s / d.dt)), 1)
    tests = []
    for q in np.arange(0.2, 0.81, 0.05):
        tk = t[idx[int(q * (len(idx) - 1))]]
        if not _inputs_on_both_sides(d, d.ok & (t < tk), d.ok & (t >= tk)):
            continue
        s = _split_test(d, spec, pooled, tk, t, block)
        if s is not None:
            tests.append(s)
    cands = [s for s in tests if s["reduction"] >= cfg.change_min_reduction]
    if not cands:
        return None
    best = min(cands, key=lambda s: (s["p"], -s["reduction"]))
    p_family = min(1.0, best["p"] * len(tests))
    if p_family > cfg.change_alpha:
        return None
    t_cp = best["t"]
    ref = lon.fit(d, spec, d.ok & (t < t_cp))  # the car as it was first recorded
    L = int(cfg.window_lon_s / d.dt)
    w = windows(d.ok, L)
    err = np.full(d.n, np.nan)
    err[w] = lon.free_run(d, ref, w)
    sq = np.nan_to_num(err ** 2)
    share = float(sq[t >= t_cp].sum() / sq.sum()) if sq.sum() > 0 else 0.0
    t_end = float(t[idx[-1]])
    return {"channel": "speed", "windows": [[round(float(t_cp), 3), round(t_end, 3)]],
            "share_of_error": share, "subsystem": "longitudinal",
            "why": f"separate fits before and after t = {t_cp:.1f} s leave "
                   f"{100 * best['reduction']:.0f} % less equation error than one model for "
                   f"the whole recording (F = {best['f']:.1f} on {best['dof'][0]} and "
                   f"{best['dof'][1]:g} effective degrees of freedom, p = {p_family:.2g} over "
                   f"{len(tests)} split points); no catalogue hypothesis models such a change "
                   "(mass, load, tyres, a trailer)",
            "error_reduction_split": best["reduction"],
            "split_test": {"f": best["f"], "dof": best["dof"],
                           "effective_samples": best["effective_samples"],
                           "p_value": best["p"], "p_family": p_family,
                           "splits_tested": len(tests)},
            "heldout_note": "windows after the change replayed with the model fitted before it"}


def extensions_section(findings: list, longitudinal_input: str) -> dict:
    """The findings as a parameter file's ``extensions:`` section (models.params): catalogue
    id -> subsystem -> its catalogue parameters, their intervals, the equation and, for the
    longitudinal part, the input the model is driven by."""
    out: dict = {}
    for f in findings:
        names = CATALOGUE[f["effect"]]["parameters"]
        e = {k: float(v) for k, v in f["parameters"].items() if k in names}
        iv = {k: [float(a), float(b)] for k, (a, b) in f["intervals"].items() if k in names}
        if iv:
            e["intervals"] = iv
        e["equation"] = f["equation"]
        if f["subsystem"] == "longitudinal" and f["channel"] == "speed":
            e["input"] = longitudinal_input
        if isinstance(f["parameters"].get("grade_source"), str):
            e["grade_source"] = f["parameters"]["grade_source"]
        below = next(iter(f.get("on_top_of", {})), None)
        if below is not None:
            e["on_top_of"] = below
        out.setdefault(f["effect"], {})[f["subsystem"]] = e
    return out


def _baseline_out(rec, vehicle, params, zones, cfg) -> Params:
    """The report's model fitted on the uncorrected recording (no finding, no sensor fix)."""
    from types import SimpleNamespace
    ch = dict(rec.channels)
    sdt = ste.prepare(ch, vehicle.wheelbase_m, cfg)
    steer = None if sdt is None else {None: SimpleNamespace(model=ste.fit(sdt, None, 0.0, sdt.ok))}
    ld = lon.prepare(ch, zones, cfg)
    lon_scores = {None: SimpleNamespace(model=lon.fit(ld, lon.LonSpec(), ld.ok))}
    p = _params_out(rec, vehicle, params, ld, lon_scores, steer, [], zones, cfg)
    p.provenance["source"] = "hmpc diagnose (the report's baseline, no findings)"
    return p


#: longitudinal findings whose fit the conventions' keys take (see :func:`_params_out`)
_KEYS_HOLD = ("actuator_delay", "road_grade")


def _params_out(rec, vehicle, params, ld, lon_scores, steer_scores, findings, zones, cfg):
    """The extended model: the findings in the parameter file's ``extensions:`` section
    (models.params), and the conventions' keys (steering map, zones, dead times) as a tool that
    ignores ``extensions:`` should use them: fitted with a dead time (which the keys hold) or
    with the road grade taken out (a disturbance of this road, not of the car: another road
    has another grade); for the car's own terms the keys cannot hold (lag, drag, creep, a
    steering-map shape) the baseline's fit, whose coefficients absorb them at the speeds and
    angles driven (the jointly fitted coefficients without the term would be worse there)."""
    fx = {(f["effect"], f["subsystem"]): f for f in findings}
    steering = params.steering if params is not None else None
    if steer_scores is not None:
        best = "actuator_delay" if ("actuator_delay", "steering") in fx else None
        m = steer_scores[best].model
        steering = Steering(offset_rad=m.offset_rad, scale=m.scale,
                            method=f"hmpc diagnose ({best or 'baseline'})")
        if best == "actuator_delay":
            steering.dead_time_s = m.delay_s
    d_pedal = ld
    if "accel_cmd" in ld.input_names:  # the conventions' zones are pedal maps
        ch = {k: v for k, v in rec.channels.items() if k != "accel_cmd"}
        d_pedal = lon.prepare(ch, zones, cfg)
    best_lon = next((f["effect"] for f in findings if f["subsystem"] == "longitudinal"
                     and f["channel"] == "speed" and f["effect"] in _KEYS_HOLD), None)
    if d_pedal is ld:
        m = lon_scores[best_lon].model
    else:
        m = lon.fit(d_pedal, lon.LonSpec(), d_pedal.ok)
    zs = []
    for i, (nm, lo, hi) in enumerate(zones):
        c = m.C[i]
        z = Zone(name=nm, v_min_mps=float(lo), v_max_mps=float(hi), offset_mps2=float(c[0]),
                 scale_mps2=float(c[1]) if len(c) > 1 else 0.0,
                 brake_scale_mps2=float(c[2]) if len(c) > 2 else 0.0,
                 identifiable=bool(i in m.fitted_zones))
        if params is not None and params.zones:  # what this recording cannot tell: as given
            g = params.zones[i]
            if i not in m.fitted_zones:
                z.offset_mps2, z.scale_mps2, z.brake_scale_mps2 = (
                    g.offset_mps2, g.scale_mps2, g.brake_scale_mps2)
                z.note = "not in this recording: kept from the given parameter file"
            elif z.brake_scale_mps2 == 0.0:
                z.brake_scale_mps2 = g.brake_scale_mps2
                z.note = "brake not used in this recording: brake scale kept from the given file"
        elif z.brake_scale_mps2 == 0.0:
            z.note = "brake not used in this recording: brake scale unknown (0 written)"
        zs.append(z)
    p = Params(vehicle=replace(vehicle), steering=steering, zones=zs,
               provenance={"source": "hmpc diagnose",
                           "recording": str(rec.meta.get("path", "?"))})
    if ("actuator_delay", "longitudinal") in fx and d_pedal is ld:
        p.longitudinal_dead_time_s = fx[("actuator_delay", "longitudinal")]["parameters"]["delay_s"]
    p.extensions = extensions_section(findings, "+".join(ld.input_names))
    for f in findings:  # each entry carries the coefficients it was fitted jointly with
        e = p.extensions[f["effect"]][f["subsystem"]]
        if f["subsystem"] == "steering" and steer_scores is not None:
            sm = steer_scores[f["effect"]].model
            e["base"] = {"offset_rad": float(sm.offset_rad), "scale": float(sm.scale)}
        elif f["channel"] == "speed":
            sc = lon_scores.get(("on_top", f["effect"])) or lon_scores[f["effect"]]
            e["base"] = {"zones": _base_zones(sc.model, ld.input_names, zones)}
    return p


def _base_zones(m: lon.LonModel, names: list, zones) -> list[dict]:
    """Per zone the offset and one gain per input of ``m`` (``models.params``' ``base``)."""
    key = {"accel_pedal": "scale_mps2", "brake_pedal": "brake_scale_mps2",
           "accel_cmd": "accel_cmd_gain"}
    out = []
    for i, (nm, _, _) in enumerate(zones):
        z = {"name": nm, "offset_mps2": float(m.C[i, 0])}
        for j, inp in enumerate(names):
            g = float(m.C[i, 1 + j])
            # U holds -brake_pedal (longitudinal.py), so the gain on it is the report's
            # positive brake scale: dv/dt = offset + scale * ap - brake_scale * bp
            z[key[inp]] = g
        out.append(z)
    return out
