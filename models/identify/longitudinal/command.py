"""Zone models of a car driven by a command instead of pedals (:func:`identify_command`).

A by-wire kit or a model car has no accelerator pedal channel: its speed controller follows a
command. With ``accel_cmd`` (an acceleration request) each zone z is::

    dv/dt = offset_z + accel_cmd_gain_z * accel_cmd(t - tau)

and with ``speed_cmd`` (a speed request, e.g. ROS ``cmd_vel`` or an Ackermann speed) a
first-order speed response::

    dv/dt = offset_z + speed_cmd_gain_ps_z * (speed_cmd(t - tau) - v)

whose time constant is 1 / speed_cmd_gain_ps_z [s] (``models.params.CommandZone``). When both
channels exist ``accel_cmd`` is used (the model is linear in it without assuming a speed loop).

The steps are the pedal model's (``signals``, ``sources``, ``deadtime``, ``zonefit``): eq. 1's
speed, every measured acceleration as a candidate with the matched smoother, the source chosen
by held-out evidence, the dead time by blocked cross-validation over a one-sample lag grid,
and per zone OLS on [1, command regressor] with HAC intervals widened by the half-sample
timing bound. The brake channel is not a regressor: the speed controller applies the brake
itself to follow the command. A gain fitted below zero is set aside (a larger command never
slows the car): the zone then copies the gain of the nearest zone that determined it (95%
interval above 0), as a zone without enough data does, and is flagged ``identifiable: false``
with the reason under ``not_identified``; a gain whose interval reaches 0 is written, flagged
and named there too.

The speed replay (``speed_rmse_mps``) of a speed-command zone integrates the model in closed
loop from the measured speed at the start of every run (the command is the input, the speed
is the model's own), so it scores the speed response the controller would predict.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import COMMAND_GAIN_KEYS, CommandZone, Vehicle
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import apply_kernel, half_sample_kernels
from hmpc.models.identify.steering import delayed
from hmpc.models.identify.longitudinal.config import LongitudinalIdConfig, _check_config
from hmpc.models.identify.longitudinal.deadtime import pedal_dead_time_cv
from hmpc.models.identify.longitudinal.signals import (
    LongitudinalSignals,
    signals_with_inputs,
    zone_masks,
)
from hmpc.models.identify.longitudinal.sources import choose_accel_source
from hmpc.models.identify.longitudinal.zonefit import _runs, ols_timed, speed_rmse

#: the command channels, in the order of preference
COMMAND_CHANNELS = ("accel_cmd", "speed_cmd")


def command_channel(rec: Recording) -> str | None:
    """The command a car without ``accel_pedal`` is identified from, or None."""
    return next((c for c in COMMAND_CHANNELS if c in rec), None)


def _regressor(cmd: np.ndarray, v: np.ndarray, inp: str, tau_s: float, dt_s: float):
    """The unsmoothed regressor at dead time ``tau_s``: the delayed command, minus the speed
    for a speed command."""
    c = delayed(cmd, tau_s, dt_s)
    return c - v if inp == "speed_cmd" else c


def _closed_loop_rmse(v_meas, cmd_d, off, k, mask, dt_s, segment_s) -> float:
    """RMS error [m/s] of the speed integrated in closed loop, dv/dt = off + k (cmd_d - v), over
    runs of ``mask`` (cut at ``segment_s``) from the measured speed at each run's start."""
    err = []
    n = max(int(round(segment_s / dt_s)), 2)
    for s, e in _runs(mask, n):
        if e - s < 2:
            continue
        vs = np.empty(e - s)
        vs[0] = v_meas[s]
        for i in range(1, e - s):
            vs[i] = max(vs[i - 1] + dt_s * (off + k * (cmd_d[s + i - 1] - vs[i - 1])), 0.0)
        err.append(vs - v_meas[s:e])
    if not err:
        return float("nan")
    e = np.concatenate(err)
    return float(np.sqrt(np.mean(e**2)))


def _signals(
    rec: Recording, vehicle: Vehicle, cfg: LongitudinalIdConfig, inp: str
) -> LongitudinalSignals:
    """Speed, candidate accelerations and the raw command (in ``ap_raw``; no brake term)."""
    cmd = np.asarray(rec[inp], dtype=float)
    return signals_with_inputs(
        rec,
        vehicle,
        cfg,
        cmd,
        np.zeros(len(rec)),
        False,
        no_source=("no acceleration source ('speed', 'gps_speed' or 'accel_x')", "speed"),
    )


def _fit(
    zi: int,
    zone,
    sig: LongitudinalSignals,
    inp: str,
    tau_s: float,
    ok: np.ndarray,
    zid: np.ndarray,
    cfg: LongitudinalIdConfig,
) -> dict:
    """One zone's OLS fit on [1, smoothed regressor] (module doc); the report entry."""
    zname, lo, hi = zone
    dt, v = sig.dt_s, sig.v
    raw = _regressor(sig.ap_raw, v, inp, tau_s, dt)
    u = sig.smooth(raw)
    m = ok & (zid == zi) & np.isfinite(u)
    nz = int(m.sum())
    rep: dict = {
        "name": zname,
        "v_min_mps": lo,
        "v_max_mps": hi,
        "samples": nz,
        "seconds_in_zone": float(np.sum(np.isfinite(v) & (zid == zi) & (v >= cfg.v_stop_mps)) * dt),
    }
    if nz < cfg.min_samples(dt):
        rep["not_fitted_because"] = (
            f"no usable data ({nz} samples, {nz * dt:.1f} s; {cfg.min_zone_s:g} s needed)"
        )
        return rep
    X = np.column_stack([np.ones(len(u)), u])
    alt = [
        np.column_stack([np.ones(len(u)), apply_kernel(raw, g)])
        for g in half_sample_kernels(sig.d_ker, dt)
    ]
    r, ci, stat_hw, sys_hw = ols_timed(X, alt, sig.a_meas, m)
    off, gain = float(r.coef[0]), float(r.coef[1])
    resid = sig.a_meas[m] - (X @ r.coef)[m]
    var = float(np.var(sig.a_meas[m]))
    raw_f = np.nan_to_num(raw)
    if inp == "speed_cmd":
        cmd_d = np.nan_to_num(delayed(sig.ap_raw, tau_s, dt))
        srmse = _closed_loop_rmse(v, cmd_d, off, gain, m, dt, cfg.segment_s)
    else:
        srmse = speed_rmse(v, off + gain * raw_f, m, dt, cfg.segment_s)
    rep.update(
        {
            "offset_mps2": off,
            "offset_ci95_mps2": list(ci[0]),
            "gain": gain,
            "gain_ci95": list(ci[1]),
            "nmse_pct": 100.0 * float(np.mean(resid**2)) / var if var > 0 else None,
            "speed_rmse_mps": srmse,
            "residual_rms_mps2": float(np.sqrt(np.mean(resid**2))),
            "regressor_range": [float(np.percentile(u[m], 2.5)), float(np.percentile(u[m], 97.5))],
            "ci_method": r.method + " + half-sample command timing bound",
            "ci_statistical_half_width": [float(x) for x in stat_hw],
            "ci_timing_half_width": [float(x) for x in sys_hw],
        }
    )
    if gain < 0:
        rep["negative_gain"] = {
            "value": gain,
            "ci95": list(ci[1]),
            "reason": (
                f"gain not determined: {gain:.3g}, its 95% interval [{ci[1][0]:.3g}, "
                f"{ci[1][1]:.3g}] spans 0"
                if ci[1][1] > 0
                else f"negative gain {gain:.3g} [{ci[1][0]:.3g}, {ci[1][1]:.3g}]: "
                f"a larger {inp} must "
                f"accelerate the car; check the sign convention of {inp}"
            ),
        }
    return rep


def _zone(
    i: int, reps: list[dict], zones, cfg: LongitudinalIdConfig, inp: str, path
) -> tuple[CommandZone, dict]:
    """Zone ``i``'s written zone with its fallbacks, and what it did not identify."""
    rep, (zname, lo, hi) = reps[i], zones[i]
    key = COMMAND_GAIN_KEYS[inp]
    has_gain = [j for j, r in enumerate(reps) if "gain" in r and "negative_gain" not in r]
    fitted = [j for j, r in enumerate(reps) if "gain" in r]
    ni, notes = {}, []
    ident = "gain" in rep
    if not fitted:
        raise InputError(
            "no speed zone has enough usable samples (moving, finite, inside one "
            f"zone; need {cfg.min_zone_s:g} s per zone)",
            path,
            channel=inp,
        )
    if not has_gain:
        raise InputError(
            "no zone has a usable command gain ("
            + "; ".join(r["negative_gain"]["reason"] for r in reps if "negative_gain" in r)
            + ")",
            path,
            channel=inp,
        )

    def nearest(cands):
        return min(cands, key=lambda j: (abs(j - i), j))

    if "gain" not in rep:
        j = nearest(fitted)
        off, off_ci = reps[j]["offset_mps2"], None
        ni["offset_mps2"] = f"{rep['not_fitted_because']}: copied from zone '{zones[j][0]}'"
        notes.append(f"{rep['not_fitted_because']}: offset copied from zone '{zones[j][0]}'")
    else:
        off, off_ci = rep["offset_mps2"], rep["offset_ci95_mps2"]
        half = 0.5 * (off_ci[1] - off_ci[0])
        if half > cfg.max_offset_ci_mps2:
            ident = False
            notes.append(f"offset known only to +-{half:.2f} m/s^2")
    if "gain" not in rep or "negative_gain" in rep:
        # from the nearest zone that determined its gain (interval above 0), else the nearest
        # with a gain >= 0
        j = nearest([k for k in has_gain if reps[k]["gain_ci95"][0] > 0.0] or has_gain)
        gain, gain_ci = reps[j]["gain"], None
        why = rep["negative_gain"]["reason"] if "gain" in rep else rep["not_fitted_because"]
        ni[key] = f"{why}: copied from zone '{zones[j][0]}'"
        notes.append(
            f"{key} copied from zone '{zones[j][0]}'"
            if "gain" not in rep
            else f"{why}: {key} copied from zone '{zones[j][0]}'"
        )
        ident = False
    else:
        gain, gain_ci = rep["gain"], rep["gain_ci95"]
        rel = abs(0.5 * (gain_ci[1] - gain_ci[0]) / gain) if gain else float("inf")
        if gain_ci[0] <= 0.0:
            # a gain whose interval reaches 0 is not determined: the zone still needs one (the
            # estimate is written), and the key is named
            ni[key] = (
                f"not determined: {gain:.3g}, its 95% interval [{gain_ci[0]:.3g}, "
                f"{gain_ci[1]:.3g}] includes 0; the estimate is written"
            )
            notes.append(f"{key} {ni[key]}")
            ident = False
        elif rel > cfg.max_rel_ci:
            ident = False
            notes.append(f"{key} known only to +-{100 * rel:.0f}%")
    note = "; ".join(notes) if notes else None
    opt = {
        k: (float(rep[k]) if rep.get(k) is not None and np.isfinite(rep[k]) else None)
        for k in ("nmse_pct", "speed_rmse_mps")
    }
    gkw: dict[str, Any] = {
        key: float(gain),
        ("accel_cmd_gain_ci95" if inp == "accel_cmd" else "speed_cmd_gain_ci95_ps"): None
        if gain_ci is None
        else (float(gain_ci[0]), float(gain_ci[1])),
    }
    z = CommandZone(
        name=zname,
        v_min_mps=float(lo),
        v_max_mps=float(hi),
        offset_mps2=float(off),
        offset_ci95_mps2=None if off_ci is None else (float(off_ci[0]), float(off_ci[1])),
        nmse_pct=opt["nmse_pct"],
        speed_rmse_mps=opt["speed_rmse_mps"],
        samples=float(rep["samples"]),
        identifiable=bool(ident),
        note=note,
        **gkw,
    )
    rep.update(
        {
            "identifiable": bool(ident),
            "note": note,
            "not_identified": ni,
            "written": {"offset_mps2": z.offset_mps2, key: gain},
        }
    )
    return z, ni


def identify_command(
    rec: Recording, vehicle: Vehicle, cfg: LongitudinalIdConfig, inp: str, say
) -> tuple[list[CommandZone], float, LongitudinalSignals, dict, dict]:
    """Fit the command model per zone (module doc).

    Returns (zones, dead time [s], signals, report, series).

    Raises:
        InputError: no speed or acceleration source, no zone with enough data, or no zone with
            a gain >= 0 (naming the command channel).
    """
    path = rec.meta.get("path")
    zones = _check_config(cfg, path)
    sig = _signals(rec, vehicle, cfg, inp)
    dt = sig.dt_s
    zeros = np.zeros(len(sig.v))
    lagged = [
        (sig.smooth(_regressor(sig.ap_raw, sig.v, inp, lag * dt, dt)), zeros)
        for lag in range(int(round(cfg.dead_time_max_s / dt)) + 1)
    ]
    say(
        f"longitudinal: no accelerator pedal: the model's input is '{inp}'; choosing the "
        "acceleration source by blocked cross-validation"
    )
    common = zone_masks(sig, zones, cfg, [a for a, _ in sig.candidates.values()])
    selection = choose_accel_source(sig, ~common.bad, common.zid, len(zones), lagged, cfg)
    deads = selection.pop("dead_times")
    sig.use(selection["chosen"])
    masks = zone_masks(sig, zones, cfg)
    dead = (
        deads[sig.source]
        if np.array_equal(masks.bad, common.bad)
        else pedal_dead_time_cv(sig.a_meas, ~masks.bad, masks.zid, len(zones), lagged, cfg, dt)
    )
    say(
        f"longitudinal: acceleration from {sig.source} ({selection['because']}); command dead "
        f"time {dead.tau_s:.2f} s"
    )
    ok = ~masks.bad
    reps = [_fit(zi, z, sig, inp, dead.tau_s, ok, masks.zid, cfg) for zi, z in enumerate(zones)]
    out, not_identified = [], {}
    for i in range(len(zones)):
        z, ni = _zone(i, reps, zones, cfg, inp, path)
        out.append(z)
        not_identified.update({f"zones.{z.name}.{k}": why for k, why in ni.items()})
    n_above = int(masks.above.sum())
    standing = masks.standstill & np.isfinite(sig.v)
    equation = (
        "dv/dt = offset_mps2 + accel_cmd_gain * accel_cmd(t - dead_time_s)"
        if inp == "accel_cmd"
        else "dv/dt = offset_mps2 + speed_cmd_gain_ps * (speed_cmd(t - dead_time_s) - v)"
    )
    report = {
        "input": inp,
        "equation": equation,
        "gain_key": COMMAND_GAIN_KEYS[inp],
        "accel_source": sig.accel_desc,
        "speed_source": sig.speed_src,
        "dead_time_s": dead.tau_s,
        "dead_time_estimate_s": dead.estimate_s,
        "dead_time_ci95_s": None if dead.interval_s is None else list(dead.interval_s),
        "dead_time_residual_reduction": dead.gain,
        "dead_time_note": dead.note,
        "dead_time_cv": dead.cv,
        "zones": reps,
        "selection": selection,
        "not_identified": not_identified,
        "above_last_zone": {
            "samples": n_above,
            "seconds": float(n_above * dt),
            "v_max_mps": zones[-1][2],
            "note": "not fitted (no zone model above the last zone)",
        },
        "standstill": {
            "samples": int(np.sum(standing)),
            "seconds": float(np.sum(standing) * dt),
            "v_stop_mps": cfg.v_stop_mps,
            "note": "excluded (and reverse): the car is held or backing",
        },
        "brake_pedal": (
            "not a regressor: the speed controller brakes to follow the command"
            if "brake_pedal" in rec
            else None
        ),
        "smooth_s": cfg.smooth_s,
        "hysteresis_mps": cfg.hysteresis_mps,
    }
    series = {
        "time": rec.time,
        "v_mps": sig.v,
        "a_meas_mps2": sig.a_meas,
        inp: sig.ap_raw,
        "zone": masks.zid,
        "used": ok,
    }
    return out, dead.tau_s, sig, report, series
