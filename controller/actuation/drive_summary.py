"""The drive run's figures: the trace (one row per control update and per control period of the
stop: the simulator node's true state when a node is present, else the loop's estimate) and the
run JSON's summary of it (loop period and jitter, deadline misses, frames sent, limits, the
stop, tracking and smoothness of the engaged part, solve times).
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.controller.metrics import (
    follow_verdict,
    limit_times,
    pedal_switches,
    smoothness_of,
    stall_figures,
)

#: the trace's columns, one value per recorded row
TRACE_KEYS = (
    "t_s",
    "x",
    "y",
    "v",
    "v_ref",
    "sw_cmd",
    "sw",
    "ap_cmd",
    "bp_cmd",
    "accel_req",
    "zone",
    "t_ref",
    "engaged",
    "stopping",
)


def record_row(
    trace: dict,
    node,
    reference,
    t,
    t_ref,
    est,
    sw_cmd,
    sw_meas,
    ap,
    bp,
    accel_req,
    res,
    engaged,
    stopping,
) -> None:
    """Append one row at loop time ``t`` [s] (reference time ``t_ref``, NaN while stopping):
    position, speed and steering-wheel angle from ``node`` when there is one, else from the
    estimate ``est`` and the measured angle; the commands and the acceleration request sent."""
    truth = node.snapshot() if node is not None else None
    x, y, v = (
        (truth["state"][0], truth["state"][1], truth["state"][3])
        if truth
        else (est[0], est[1], est[3])
    )
    trace["t_s"].append(t)
    trace["x"].append(x)
    trace["y"].append(y)
    trace["v"].append(v)
    trace["v_ref"].append(float(reference.speed_at(t_ref)) if np.isfinite(t_ref) else math.nan)
    trace["t_ref"].append(t_ref)
    trace["sw_cmd"].append(sw_cmd)
    trace["sw"].append(truth["sw_rad"] if truth else sw_meas)
    trace["ap_cmd"].append(ap)
    trace["bp_cmd"].append(bp)
    trace["accel_req"].append(accel_req)
    trace["zone"].append(int(getattr(res, "zone", -1)) if res is not None else -1)
    trace["engaged"].append(engaged)
    trace["stopping"].append(stopping)


def summarize(
    trace,
    periods,
    late_steps,
    solve_ms,
    statuses,
    failures,
    sent,
    blocked,
    clips,
    engaged_at,
    stop,
    ticks,
    *,
    profile_name: str,
    controller_name: str,
    reference,
    node,
    car_rejected,
    control_period_s: float,
    candump: str,
    estimator: str,
    steering_wheel_angle_max_rad: float = math.inf,
) -> dict:
    """The run JSON's summary. ``periods``: the control steps' start-to-start intervals [s];
    ``node``: the vehicle simulator node or None; ``car_rejected``: the frames the car reports
    rejected (without a node), or None. Whether the car did what was asked, over the engaged
    rows: time at each actuator limit (``limits``, the steering lock
    ``steering_wheel_angle_max_rad``), stalls (``stalls``) and the verdict (``followed``,
    ``not_followed``; ``controller.metrics.follow_verdict``)."""

    def pct(a, q):
        return float(np.percentile(a, q)) if len(a) else 0.0

    per = np.asarray(periods) * 1e3
    tr = {k: np.asarray(v, dtype=float) for k, v in trace.items()}
    eng = tr["engaged"] > 0.5 if len(tr["t_s"]) else np.zeros(0, bool)
    kpi: dict[str, object] = {
        "speed_error_rms_mps": None,
        "lateral_error_rms_m": None,
        "pedal_switches_per_min": None,
        "zone_transitions_per_min": None,
        "steering_reversals_per_min": None,
        "steering_rate_rms_radps": None,
        "accel_pedal_rate_rms_ps": None,
        "brake_pedal_rate_rms_ps": None,
    }
    if eng.sum() >= 2:
        t = tr["t_ref"][eng]
        minutes = max((t[-1] - t[0]) / 60.0, 1e-9)
        ev = tr["v"][eng] - tr["v_ref"][eng]
        lat = reference.lateral_errors(tr["x"][eng], tr["y"][eng], t)
        ap, bp = tr["ap_cmd"][eng], tr["bp_cmd"][eng]
        z = tr["zone"][eng]
        kpi = {
            "speed_error_rms_mps": float(np.sqrt(np.mean(ev**2))),
            "lateral_error_rms_m": float(np.sqrt(np.mean(np.asarray(lat) ** 2))),
            "pedal_switches_per_min": pedal_switches(ap, bp) / minutes,
            "zone_transitions_per_min": int(np.count_nonzero(np.diff(z))) / minutes,
            # the smoothness of the commands the controller gave, as simulate's:
            # the engaged rows are the control updates, so a rate is each update's
            # change over the control period (metrics.rate_rms)
            **smoothness_of(tr["t_s"][eng], tr["sw_cmd"][eng], ap, bp),
        }
    follow = {"followed": True, "not_followed": [], "limits": None, "stalls": None}
    if eng.sum() >= 2:
        te = tr["t_s"][eng]
        lim = limit_times(
            te,
            tr["sw_cmd"][eng],
            tr["ap_cmd"][eng],
            tr["bp_cmd"][eng],
            steering_wheel_angle_max_rad=steering_wheel_angle_max_rad,
        )
        stalls = stall_figures(te, tr["v"][eng], tr["v_ref"][eng])
        ok, why = follow_verdict(
            lim,
            stalls,
            float(te[-1] - te[0]),
            steering_wheel_angle_max_rad=steering_wheel_angle_max_rad,
        )
        follow = {"followed": ok, "not_followed": why, "limits": lim, "stalls": stalls}
    sm = np.asarray(solve_ms)
    node_stats = node.stats.to_dict() if node is not None else None
    # the node's count; without a node, what the car reports (the kit's REJECTED_FRAMES)
    rejected = node_stats["rejected_total"] if node_stats is not None else car_rejected
    jitter = np.abs(per - control_period_s * 1e3)
    out = {
        "profile": profile_name,
        "controller": controller_name,
        "reference": reference.name,
        "steps": int(len(statuses)),
        "ticks": int(ticks),
        "loop_period_ms": {
            "p50": pct(per, 50),
            "p99": pct(per, 99),
            "max": float(per.max()) if len(per) else 0.0,
        },
        "loop_jitter_ms": {
            "p99": pct(jitter, 99),
            "max": float(jitter.max()) if len(jitter) else 0.0,
        },
        "deadline_misses": int(late_steps),
        "frames_sent": dict(sent),
        "frames_rejected_by_vehicle": rejected,
        "limit_clips": dict(clips),
        "blocked_at_encoder": dict(blocked),
        "limit_violations": None,  # filled by audit_candump
        "engaged_s": (
            float(tr["t_s"][eng][-1] - engaged_at) if engaged_at is not None and eng.any() else 0.0
        ),
        "stop": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in stop.items()},
        **kpi,
        **follow,
        "solve_time_ms": {
            "p50": pct(sm, 50),
            "p99": pct(sm, 99),
            "max": float(sm.max()) if len(sm) else 0.0,
        },
        "failures": int(failures),
        "node": node_stats,
        "candump": candump,
        "estimator": estimator,
    }
    return out


def cpu_percentiles(seconds) -> dict:
    """{p50, p99, max} [us] of CPU times given in seconds."""
    a = np.asarray(seconds, dtype=float) * 1e6
    if not len(a):
        return {"p50": 0.0, "p99": 0.0, "max": 0.0}
    return {
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
    }
