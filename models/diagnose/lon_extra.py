"""The longitudinal hypotheses that depend on what the recording holds, each tested only where
it can be and named as untested (with the reason) where it cannot:

- ``actuator_saturation``: a recorded command (``accel_cmd``, ``speed_cmd``) whose regressor
  is clipped at a fitted level (``longitudinal.saturation_grid``);
- ``gears``: eq. 8's coefficients per gear (``gear_data``): needs ``engine_rpm`` or ``gear``;
- ``unobserved_braking``: a pedal-driven car without a brake channel (``braking``).

Each is scored against the baseline like the others (``candidates.accept``) and its
candidate carries what it found (the gears and their gains, the braking windows).
"""

from __future__ import annotations

import numpy as np

from hmpc.models.diagnose import braking
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.candidates import Resolution, accept, candidate
from hmpc.models.diagnose.common import DiagnoseConfig


def _untested(w, effect: str, why: str) -> None:
    w.hyps.append({"effect": effect, "tested": False, "why": why})


def _add(
    w, ld, effect: str, b: lon.LonScore, s: lon.LonScore, cfg: DiagnoseConfig, res: Resolution
) -> dict:
    ok, why = accept(b.heldout_rmse_mps, s.heldout_rmse_mps, b.bic, s.bic, res.speed_mps, cfg)
    c = candidate(
        effect,
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
    w.cands.append(c)
    return c


def _runs(t: np.ndarray, g: np.ndarray, moving: np.ndarray, min_s: float) -> list:
    """[t_start_s, t_end_s, gear index] of each moving stretch in one gear of ``min_s`` or more."""
    key = np.where(moving, g, -1)
    edges = np.flatnonzero(np.diff(key) != 0) + 1
    out = []
    for a, e in zip(np.r_[0, edges], np.r_[edges, len(key)]):
        if key[a] >= 0 and t[e - 1] - t[a] >= min_s:
            out.append([float(t[a]), float(t[e - 1]), int(key[a])])
    return out


#: [s] shortest stretch in one gear listed in the finding's windows (shorter: a shift through)
GEAR_WINDOW_MIN_S = 2.0


def _gears_record(ld: lon.LonData, s: lon.LonScore) -> dict:
    """The gears found, the samples in each, and each gear's accelerator gain and
    released-pedal (engine-braking) acceleration of the full-data fit."""
    m = s.model
    info = dict(ld.gear_info)
    j = ld.input_names.index("accel_pedal") + 1 if "accel_pedal" in ld.input_names else None
    fitted = m.fitted_zones
    info["offset_mps2"] = [float(m.C[g, 0]) for g in range(info["n"])]
    if j is not None:
        info["accel_pedal_gain_mps2"] = [float(m.C[g, j]) for g in range(info["n"])]
        # the released pedal's column follows the recorded inputs (``longitudinal.inputs``)
        key = "engine_braking_per_krpm_mps2" if "drag_krpm" in info else "released_pedal_mps2"
        info[key] = [float(m.C[g, -1]) for g in range(info["n"])]
        info.pop("drag_krpm", None)
    info["fitted"] = [int(g) for g in fitted]
    moving = ld.ok & (ld.vs > DiagnoseConfig.v_stop_mps)
    assert ld.gear is not None  # gears were found
    info["windows"] = _runs(ld.t, ld.gear, moving, GEAR_WINDOW_MIN_S)
    return info


def _gears_params(ld: lon.LonData, s: lon.LonScore) -> None:
    m = s.model
    fz = m.fitted_zones or list(range(len(m.C)))
    s.params["n_gears"] = float(ld.gear_info["n"])
    if "accel_pedal" in ld.input_names:
        gains = np.array([m.C[g, ld.input_names.index("accel_pedal") + 1] for g in fz])
        pos = gains[gains > 0]
        if pos.size:
            s.params["gain_ratio"] = float(pos.max() / pos.min())
    # released-pedal acceleration per gear at the recording's median released engine speed
    drag = ld.gear_info.get("drag_krpm", 1.0)
    rel = ld.idle & ld.ok
    x = float(np.median(np.asarray(drag * np.ones(ld.n))[rel])) if rel.any() else 1.0
    col = -1 if "accel_pedal" in ld.input_names else None
    off = np.array([m.C[g, 0] + (m.C[g, col] * x if col is not None else 0.0) for g in fz])
    s.params["engine_braking_spread_mps2"] = float(off.max() - off.min())


def speed_cmd_response(ld: lon.LonData, b: lon.LonScore) -> dict:
    """How the reached speed follows a speed command in the baseline (``dv/dt = offset_z +
    k_z (speed_cmd - v)``): per fitted zone k_z [1/s] and the time constant 1 / k_z [s] of
    that first-order response (how far the speed lags the command)."""
    j = 1 + ld.input_names.index("speed_cmd")
    out = {}
    for z in b.model.fitted_zones:
        k = float(b.model.C[z, j])
        out[ld.zones[z][0]] = {"gain_per_s": k, "tau_s": 1.0 / k if k > 0 else None}
    return out


def lon_extra_step(
    w,
    ld: lon.LonData,
    b: lon.LonScore,
    lon_scores: dict,
    cfg: DiagnoseConfig,
    res: Resolution,
    cl: float,
) -> None:
    """Test the recording-dependent hypotheses (module doc) against the baseline ``b``; each
    score joins ``lon_scores``, each candidate ``w.cands``, each untested one ``w.hyps``."""
    if "speed_cmd" in ld.input_names:
        w.channels.setdefault("speed", {})["speed_cmd_response"] = speed_cmd_response(ld, b)
    if ld.commanded:
        s = lon.evaluate(ld, "actuator_saturation", cfg, cl)
        gains = [s.model.C[z, 1] for z in s.model.fitted_zones]
        if "sat_level" in s.params and np.isfinite(s.params["sat_level"]):
            s.params["accel_mps2"] = (
                float(s.params["sat_level"] * np.mean(gains)) if gains else float("nan")
            )
        lon_scores["actuator_saturation"] = s
        c = _add(w, ld, "actuator_saturation", b, s, cfg, res)
        c["input"] = ld.input_names[0]
    else:
        _untested(w, "actuator_saturation", "no accel_cmd or speed_cmd drives the car")
    if ld.gear is not None:
        s = lon.evaluate(ld, "gears", cfg, cl)
        _gears_params(ld, s)
        lon_scores["gears"] = s
        c = _add(w, ld, "gears", b, s, cfg, res)
        c["gears"] = _gears_record(ld, s)
        if c["_ok"]:
            g = c["gears"]
            ratios = ", ".join(f"{r:.0f}" for r in g.get("ratios_rpm_per_mps", []))
            w.notes.append(
                f"gears: {g['n']} from {g['source']}"
                + (f" (ratios {ratios} 1/min per m/s)" if ratios else "")
                + "; moving samples per gear "
                + ", ".join(map(str, g["samples"]))
            )
    else:
        why = ld.gear_info.get("why", "no engine_rpm or gear channel")
        _untested(w, "gears", why)
        w.notes.append(f"gear effects could not be tested: {why}")
    why = braking.applies(ld)
    if why is not None:
        _untested(w, "unobserved_braking", why)
        return
    sb, wins = braking.evaluate(ld, cfg, cl)
    if sb is None:
        w.hyps.append(
            {
                "effect": "unobserved_braking",
                "tested": True,
                "finding": False,
                "why": "no released-pedal deceleration beyond the coasting model",
            }
        )
        return
    lon_scores["unobserved_braking"] = sb
    c = _add(w, ld, "unobserved_braking", b, sb, cfg, res)
    c["braking_windows"] = wins
    if c["_ok"]:
        w.notes.append(
            f"unobserved_braking: {len(wins)} window(s) where the car decelerates "
            "beyond its coasting with the pedal released and no brake channel, "
            f"first {wins[0][0]:.1f}-{wins[0][1]:.1f} s"
        )
    c["absent_inputs"] = list(ld.absent_inputs)
