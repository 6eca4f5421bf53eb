"""Run a controller against the hybrid plant and measure how it did.

The loop owns the "bus": it takes the command each controller step returns, applies the
limits again (independently of the controller), delays it by the PLANT's actuator dead
times, and steps the plant. The plant may be built from different parameters than the
controller's model (``plant_params``: model mismatch, ``hmpc simulate --plant-params``).

The output is a canonical recording (``models.recording.Recording``) at the plant rate
with the applied inputs, the commands (``steering_cmd``, ``accel_pedal_cmd``,
``brake_pedal_cmd``) and the plant state, plus the metrics of issue 4 and the controller's
statuses: ``failures`` counts the steps whose own computation failed (any status but
solved/ok/hold), ``internal_errors`` those that were bugs (their tracebacks are in
``ClosedLoopResult.internal_errors``). The library prints nothing: progress goes to an
optional callback (the CLI prints it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import DelayLine, HybridPlant, heading_rate
from hmpc.models.logs.recording import Recording
from hmpc.models.sim.scenarios import Reference

from hmpc.controller.base import Controller, Status
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits


@dataclass
class ClosedLoopResult:
    """A closed-loop run: the recording, the metrics, and per-sample extras for plots.

    Attributes:
        recording: canonical channels at the plant rate.
        metrics: the issue 4 figures (see :func:`metrics_of`).
        zone: plant zone per sample.
        speed_ref_mps: reference speed per sample [m/s].
        lateral_error_m: signed distance to the path per sample [m].
        statuses: controller status per control step (:class:`Status`).
        reasons: the status reason per control step ("" when solved).
        solve_time_s: solver time per control step [s].
        step_time_s: wall time of each controller step [s].
        control_time_s: time of each control step [s].
        internal_errors: (time [s], traceback) of every step that was an internal error.
    """

    recording: Recording
    metrics: dict
    zone: np.ndarray
    speed_ref_mps: np.ndarray
    lateral_error_m: np.ndarray
    statuses: list = field(default_factory=list)
    solve_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    step_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    control_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reasons: list = field(default_factory=list)
    internal_errors: list = field(default_factory=list)


def run_closed_loop(controller: Controller, reference: Reference, params: Params, *,
                    plant_params: Params | None = None, control_period_s: float = 0.1,
                    plant_dt_s: float = 0.02, seed: int = 0, speed_noise_mps: float = 0.0,
                    position_noise_m: float = 0.0, extra_time_s: float = 0.0,
                    limits: ActuatorLimits | None = None,
                    progress: Callable[[float, float], None] | None = None,
                    initial_state: np.ndarray | None = None) -> ClosedLoopResult:
    """Closed loop: ``controller.step(measured_state, reference, t)`` every control period.

    Args:
        controller: a :class:`controller.base.Controller`.
        reference: the trajectory to follow.
        params: the controller's model (also the plant's, unless ``plant_params``).
        plant_params: a different plant (model mismatch).
        control_period_s: controller period [s] (commands held in between).
        plant_dt_s: plant integration step and recording period [s].
        seed: seed of the measurement noise (printed in the metrics).
        speed_noise_mps, position_noise_m: white measurement noise std [m/s], [m].
        extra_time_s: run this long past the reference's end [s].
        limits: limits applied at the actuation boundary (default from ``params``).
        progress: called as ``progress(fraction_done, t_s)`` (t_s since the start [s])
            at every further tenth of the run; None: no reports.
        initial_state: plant start state (default: on the reference).
    """
    if not (plant_dt_s > 0 and control_period_s >= plant_dt_s - 1e-12):
        raise ValueError("need 0 < plant_dt_s <= control_period_s")
    ratio = control_period_s / plant_dt_s
    if abs(ratio - round(ratio)) > 1e-6:
        raise ValueError("control_period_s must be a whole number of plant_dt_s")
    if progress is not None and not callable(progress):
        raise ValueError("progress must be a callable progress(fraction, t_s) or None")
    every = int(round(ratio))
    pp = plant_params if plant_params is not None else params
    plant = HybridPlant(pp)
    lim = limits or ActuatorLimits.from_params(params)
    rng = np.random.default_rng(seed)
    d_steer = DelayLine(float(pp.steering.dead_time_s or 0.0), plant_dt_s)
    d_acc = DelayLine(float(pp.longitudinal_dead_time_s or 0.0), plant_dt_s)
    d_brk = DelayLine(float(pp.longitudinal_dead_time_s or 0.0), plant_dt_s)
    controller.reset()

    t0 = float(reference.time_s[0])
    n = int(math.floor((reference.duration_s + extra_time_s) / plant_dt_s + 1e-9)) + 1
    s = np.array(initial_state, dtype=float) if initial_state is not None \
        else reference.initial_state(params)
    zone = plant.select_zone(float(s[3]), None)
    cols = {k: np.zeros(n) for k in ("time", "x", "y", "heading", "speed", "steering_wheel_angle",
                                     "accel_pedal", "brake_pedal", "yaw_rate", "accel_x",
                                     "steering_cmd", "accel_pedal_cmd", "brake_pedal_cmd")}
    zones = np.zeros(n, dtype=np.int64)
    statuses, reasons, errors, solve_t, step_t, ctl_t = [], [], [], [], [], []
    cmd = Command(0.0, 0.0, 0.0)
    prev_applied: Command | None = None
    last_report = -1
    for i in range(n):
        t = t0 + i * plant_dt_s
        if i % every == 0:
            meas = s.copy()
            if speed_noise_mps > 0:
                meas[3] = max(meas[3] + rng.normal(0.0, speed_noise_mps), 0.0)
            if position_noise_m > 0:
                meas[:2] += rng.normal(0.0, position_noise_m, 2)
            res = controller.step(meas, reference, t)
            c = res.command
            # the actuation boundary applies the limits again, whatever the controller did
            cmd = apply_limits(c, prev_applied, lim, control_period_s)
            prev_applied = cmd
            status = Status(res.status)
            statuses.append(status)
            reasons.append(res.reason)
            if status is Status.INTERNAL_ERROR:
                errors.append((t, res.traceback or res.reason))
            solve_t.append(float(res.solve_time_s))
            step_t.append(float(res.step_time_s))
            ctl_t.append(t)
            if progress is not None:
                tenth = int(100 * i / max(n - 1, 1)) // 10
                if tenth != last_report:
                    last_report = tenth
                    progress(tenth / 10, t - t0)
        u = np.array([d_steer.push(cmd.steering_wheel_angle_rad), d_acc.push(cmd.accel_pedal),
                      d_brk.push(cmd.brake_pedal)])
        cols["time"][i] = t
        cols["x"][i], cols["y"][i], cols["heading"][i], cols["speed"][i] = s
        cols["steering_wheel_angle"][i], cols["accel_pedal"][i], cols["brake_pedal"][i] = u
        cols["steering_cmd"][i] = cmd.steering_wheel_angle_rad
        cols["accel_pedal_cmd"][i] = cmd.accel_pedal
        cols["brake_pedal_cmd"][i] = cmd.brake_pedal
        delta = plant.road_wheel_angle(u[0])
        cols["yaw_rate"][i] = heading_rate(s[3], float(delta), plant.wheelbase_m, ops=math)
        r = plant.step(s, u, plant_dt_s, zone)
        cols["accel_x"][i] = r.accel_mps2
        zones[i] = r.zone
        s, zone = r.state, r.zone
    cols["heading"] = (cols["heading"] + np.pi) % (2 * np.pi) - np.pi
    rec = Recording(cols, {}, {"source": "hmpc closed loop", "controller": getattr(controller, "name", "?"),
                               "reference": reference.name, "seed": seed,
                               "rate_hz": 1.0 / plant_dt_s})
    v_ref = reference.speed_at(cols["time"])
    lat = reference.lateral_errors(cols["x"], cols["y"], cols["time"])
    result = ClosedLoopResult(rec, {}, zones, v_ref, lat, statuses, np.array(solve_t),
                              np.array(step_t), np.array(ctl_t), reasons, errors)
    result.metrics = metrics_of(result, lim)
    result.metrics["seed"] = seed
    return result


def pedal_switches(accel_pedal: np.ndarray, brake_pedal: np.ndarray, deadband: float = 1e-3) -> int:
    """Throttle-to-brake and brake-to-throttle changes of the pressed pedal (a pedal
    released with the other not yet pressed continues the last one)."""
    last = None
    count = 0
    for ap, bp in zip(accel_pedal, brake_pedal):
        cur = "T" if ap > deadband else "B" if bp > deadband else None
        if cur is None:
            continue
        if last is not None and cur != last:
            count += 1
        last = cur
    return count


def metrics_of(res: ClosedLoopResult, limits: ActuatorLimits) -> dict:
    """The issue 4 figures (stable keys, SI units), and the internal errors."""
    rec = res.recording
    t = rec.channels["time"]
    minutes = max((t[-1] - t[0]) / 60.0, 1e-9)
    v = rec.channels["speed"]
    ev = v - res.speed_ref_mps
    solve_ms = res.solve_time_s[res.solve_time_s > 0] * 1e3
    step_ms = res.step_time_s * 1e3

    def pct(a, q):
        return float(np.percentile(a, q)) if len(a) else 0.0
    ap, bp = rec.channels["accel_pedal_cmd"], rec.channels["brake_pedal_cmd"]
    nz = int(np.count_nonzero(np.diff(res.zone)))
    return {
        "speed_error_rms_mps": float(np.sqrt(np.mean(ev ** 2))),
        "lateral_error_rms_m": float(np.sqrt(np.mean(res.lateral_error_m ** 2))),
        "pedal_switches_per_min": pedal_switches(ap, bp, limits.pedal_deadband) / minutes,
        "zone_transitions_per_min": nz / minutes,
        "solve_time_ms": {"p50": pct(solve_ms, 50), "p99": pct(solve_ms, 99),
                          "max": float(solve_ms.max()) if len(solve_ms) else 0.0},
        "steps": int(len(res.statuses)),
        "failures": int(sum(1 for s in res.statuses if not Status(s).ok)),
        "internal_errors": int(sum(1 for s in res.statuses if s == Status.INTERNAL_ERROR)),
        # extras (not in the list, kept stable too)
        "step_time_ms": {"p50": pct(step_ms, 50), "p99": pct(step_ms, 99),
                         "max": float(step_ms.max()) if len(step_ms) else 0.0},
        "speed_error_max_mps": float(np.max(np.abs(ev))),
        "lateral_error_max_m": float(np.max(np.abs(res.lateral_error_m))),
        "pedal_switches": pedal_switches(ap, bp, limits.pedal_deadband),
        "zone_transitions": nz,
        "duration_s": float(t[-1] - t[0]),
        "both_pedals_samples": int(np.count_nonzero((ap > limits.pedal_deadband)
                                                    & (bp > limits.pedal_deadband))),
        "statuses": _count(res.statuses),
    }


def _count(statuses) -> dict:
    """Steps per status, keyed by the status value."""
    out: dict[str, int] = {}
    for s in statuses:
        key = Status(s).value
        out[key] = out.get(key, 0) + 1
    return out
