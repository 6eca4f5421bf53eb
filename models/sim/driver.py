"""The simulated driver of the experiments: it follows an experiment's plan
(``models.sim.plans``) and drives the truth plant (``models.sim.truth_plant``) on the internal
grid, inputs held over each step; the result is the truth
(:class:`~hmpc.models.sim.truth_plant.Truth`).

- Steering: the steering wheel follows a reference (a scripted profile, or a human lane-keeper
  holding the road's direction with small random corrections) through a first-order lag of
  ``DriverConfig.steer_tau_s`` with a rate limit.
- Speed: a PI speed controller with feed-forward and a slow human-like dither, mapped to
  throttle OR brake (never both: one pedal is released to zero before the other is pressed)
  with pedal rate limits; at rest with a zero speed reference it holds the brake. The
  open-loop experiment plays a pedal programme instead (levels held until a speed is reached
  or the car stops).

The car starts at rest at the ENU origin with the heading it is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hmpc.models.params import Params
from hmpc.models.sim import sensors as sn
from hmpc.models.sim.effect_base import Effect
from hmpc.models.sim.plans import Phase, Plan, sw_max_rad
from hmpc.models.sim.truth_plant import Truth, TruthPlant


@dataclass(frozen=True)
class DriverConfig:
    """The simulated driver and low-level speed controller (units in the names)."""

    #: steering wheel follows its reference with this lag [s] (a human arm / steering actuator)
    steer_tau_s: float = 0.12
    #: ... and at most this rate [rad/s] (344 deg/s: brisk human, typical EPS actuator limit)
    steer_rate_max_radps: float = 6.0
    #: PI speed controller on pedal fraction: proportional [1/(m/s)], integral [1/m]
    kp_per_mps: float = 0.40
    ki_per_m: float = 0.10
    #: feed-forward of the reference acceleration: 1 / (a nominal pedal scale of 2.5 m/s^2)
    ff_per_mps2: float = 0.4
    #: coasting band: throttle = u - deadband above it, brake = -u - brake_deadband below
    #: -brake_deadband, both released between (a driver lifts off for small corrections and
    #: brakes only for larger ones) [fraction]
    deadband: float = 0.01
    brake_deadband: float = 0.04
    #: pedal rates [1/s]: a foot or pedal robot moves a pedal fully in about 1 s
    throttle_rate_max_per_s: float = 1.0
    brake_rate_max_per_s: float = 1.5
    #: a foot moves from one pedal to the other in no less than this [s]: both are released
    pedal_switch_s: float = 0.25
    #: brake held at rest with a zero speed reference [fraction] (beats any idle creep)
    hold_brake: float = 0.35
    #: human dither on the speed controller output: rms [fraction], correlation time [s]
    dither: float = 0.02
    dither_tau_s: float = 2.0
    #: lane keeper: road-wheel angle per rad of heading error and per metre of lateral error
    lane_k_heading: float = 0.6
    lane_k_lateral_radpm: float = 0.06
    #: human steering corrections while lane keeping: rms road-wheel angle [rad], corr. time [s]
    lane_noise_rad: float = 0.008
    lane_noise_tau_s: float = 1.0


def _phase_segment(ph: Phase, t0_s: float, t1_s: float) -> dict:
    what = {
        "throttle": f"throttle {ph.level:.2f}",
        "sweep": f"throttle sweep {ph.level:.2f}-{ph.level_end:.2f}",
        "brake": f"brake {ph.level:.2f}",
        "hold": f"hold brake {ph.level:.2f} at rest",
        "coast": "coast (no pedal)",
    }[ph.kind]
    return {"label": f"open loop {what}", "t_start_s": round(t0_s, 6), "t_end_s": round(t1_s, 6)}


@dataclass
class _DriveRefs:
    """What the driver follows, on the internal grid: speed, acceleration and steering-wheel
    references (``sw_ref`` NaN: lane keeping), low-gear flags, the speed controller's dither and
    the lane-keeping noise. ``v_ref``/``a_ref`` are empty for an open-loop pedal programme."""

    open_loop: bool
    n_max: int
    v_ref: np.ndarray
    a_ref: np.ndarray
    sw_ref: np.ndarray
    low: np.ndarray
    dither: np.ndarray
    lane_noise: np.ndarray


@dataclass
class _DriverState:
    """The driver between steps: steering-wheel angle [rad], pedals [0..1], the speed
    controller's integral [m], the programme phase and when it began [s], and the last times a
    pedal was pressed [s]."""

    sw: float
    th: float = 0.0
    br: float = 0.0
    integ: float = 0.0
    phase_i: int = 0
    phase_t0: float = 0.0
    t_th_last: float = -1e9
    t_br_last: float = -1e9


#: integral share of the driver's pedal command [fraction].
_KI_LIMIT = 0.5
_TRUTH_NAMES = (
    "x_m",
    "y_m",
    "psi_rad",
    "v_mps",
    "sw_rad",
    "sw_eff_rad",
    "accel_pedal",
    "brake_pedal",
    "accel_pedal_eff",
    "brake_pedal_eff",
    "zone",
    "accel_model_mps2",
    "accel_extra_mps2",
    "accel_mps2",
    "grade_rad",
)


def _drive_refs(plan: Plan, dt: float, rng, driver: DriverConfig) -> _DriveRefs:
    """The references of ``plan`` and the driver's noise (drawn from ``rng`` in this order:
    dither, then lane-keeping noise)."""
    open_loop = plan.program is not None
    if plan.program is not None:  # open loop
        n_max = int(round(sum(ph.longest_s for ph in plan.program) / dt)) + 1
        v_ref = a_ref = np.zeros(0)
        sw_ref = np.full(n_max, np.nan)
        low = np.zeros(n_max, dtype=bool)
    else:
        v_ref, a_ref, sw_ref, low = plan.arrays()
        n_max = len(v_ref)
    dither = (
        np.zeros(n_max)
        if open_loop
        else sn.gauss_markov(rng, n_max, driver.dither, driver.dither_tau_s, dt)
    )
    lane_noise = sn.gauss_markov(rng, n_max, driver.lane_noise_rad, driver.lane_noise_tau_s, dt)
    return _DriveRefs(open_loop, n_max, v_ref, a_ref, sw_ref, low, dither, lane_noise)


def drive(
    params: Params,
    plan: Plan,
    dt: float,
    rng,
    effects: list[Effect],
    driver: DriverConfig,
    psi0: float,
) -> Truth:
    """Run the driver and the plant; return the truth on the internal grid."""
    truth_plant = TruthPlant(params, effects, dt)
    plant = truth_plant.plant
    off, scl = plant.offset_rad, plant.scale
    sw_max = sw_max_rad(params)
    refs = _drive_refs(plan, dt, rng, driver)
    rec = {k: np.empty(refs.n_max) for k in _TRUTH_NAMES}
    s = np.array([0.0, 0.0, psi0, 0.0])
    cpsi, spsi = math.cos(psi0), math.sin(psi0)
    d = _DriverState(0.0 if math.isnan(refs.sw_ref[0]) else float(refs.sw_ref[0]))
    alpha_sw = 1.0 - math.exp(-dt / driver.steer_tau_s)
    dsw_max = driver.steer_rate_max_radps * dt
    dth_max, dbr_max = driver.throttle_rate_max_per_s * dt, driver.brake_rate_max_per_s * dt
    grade = truth_plant.grade_rad
    n = refs.n_max
    for k in range(refs.n_max):
        t = k * dt
        x, y, psi, v = s[0], s[1], s[2], s[3]
        # ---- steering: reference (scripted or lane keeping) through the arm/actuator
        swr = refs.sw_ref[k]
        if swr != swr:  # NaN: human lane keeping along the initial direction
            e_y = -x * spsi + y * cpsi
            e_psi = math.remainder(psi - psi0, 2.0 * math.pi)
            d_cmd = -(driver.lane_k_heading * e_psi + driver.lane_k_lateral_radpm * e_y)
            d_cmd = min(max(d_cmd, -0.1), 0.1) + refs.lane_noise[k]
            swr = (d_cmd - off) / scl
        swr = min(max(swr, -sw_max), sw_max)
        dsw = min(max(alpha_sw * (swr - d.sw), -dsw_max), dsw_max)
        d.sw = min(max(d.sw + dsw, -sw_max), sw_max)
        # ---- pedals: the programme's, or the speed controller's
        if refs.open_loop:
            want = _programme_pedals(plan, d, t, v)
            if want is None:  # programme finished
                n = k
                break
        else:
            want = _speed_pedals(d, driver, refs.v_ref[k], v, refs.a_ref[k], refs.dither[k], dt)
        _move_feet(d, want, t, driver, dth_max, dbr_max)
        # ---- concealed effects, plant
        ts = truth_plant.step(s, (d.sw, d.th, d.br))
        res = ts.result
        sw_e, th_e, br_e = ts.u_eff
        rec["x_m"][k], rec["y_m"][k], rec["psi_rad"][k], rec["v_mps"][k] = x, y, psi, v
        rec["sw_rad"][k], rec["sw_eff_rad"][k] = d.sw, sw_e
        rec["accel_pedal"][k], rec["brake_pedal"][k] = d.th, d.br
        rec["accel_pedal_eff"][k], rec["brake_pedal_eff"][k] = th_e, br_e
        rec["zone"][k] = res.zone
        rec["accel_model_mps2"][k] = ts.accel_model_mps2
        rec["accel_extra_mps2"][k] = ts.accel_extra_mps2
        rec["accel_mps2"][k] = res.accel_mps2
        rec["grade_rad"][k] = grade
        s = res.state
    return _truth(rec, n, dt, off, scl, plant.wheelbase_m, refs.low)


def _programme_pedals(
    plan: Plan, d: _DriverState, t: float, v: float
) -> tuple[float, float] | None:
    """The open-loop programme's pedal targets (throttle, brake) at time ``t`` [s] and speed
    ``v`` [m/s], advancing ``d``'s phase (and ``plan.segments``) as phases end; None when the
    programme has finished."""
    assert plan.program is not None  # called for an open-loop plan
    while True:
        ph = plan.program[d.phase_i]
        el = t - d.phase_t0
        kind = ph.kind
        if kind in ("throttle", "sweep"):
            done = v >= ph.v_mps or el >= ph.max_s or v >= 18.0
        elif kind == "brake":
            done = v <= ph.v_mps or el >= ph.max_s
        else:
            done = el >= ph.dur_s
        if done and d.phase_i + 1 < len(plan.program):
            plan.segments.append(_phase_segment(ph, d.phase_t0, t))
            d.phase_i += 1
            d.phase_t0 = t
            continue
        break
    if done:
        plan.segments.append(_phase_segment(ph, d.phase_t0, t))
        return None
    if kind == "throttle":
        return ph.level, 0.0
    if kind == "sweep":
        return ph.level + (ph.level_end - ph.level) * min(el / ph.max_s, 1.0), 0.0
    if kind in ("brake", "hold"):
        return 0.0, ph.level
    return 0.0, 0.0


def _speed_pedals(
    d: _DriverState,
    driver: DriverConfig,
    vr: float,
    v: float,
    a_ref: float,
    dither: float,
    dt: float,
) -> tuple[float, float]:
    """The human speed controller's pedal targets (throttle, brake): hold the brake at rest,
    else feed-forward plus PI on the speed error with dither, through the pedal dead bands."""
    if vr <= 0.05 and v < 0.3:  # at rest: hold the car on the brake
        d.integ = 0.0
        return 0.0, driver.hold_brake
    err = vr - v
    i_max = _KI_LIMIT / driver.ki_per_m
    d.integ = min(max(d.integ + err * dt, -i_max), i_max)
    u = driver.ff_per_mps2 * a_ref + driver.kp_per_mps * err + driver.ki_per_m * d.integ + dither
    if u > driver.deadband:
        return min(u - driver.deadband, 1.0), 0.0
    if u < -driver.brake_deadband:
        return 0.0, min(-u - driver.brake_deadband, 1.0)
    return 0.0, 0.0


def _move_feet(
    d: _DriverState,
    want: tuple[float, float],
    t: float,
    driver: DriverConfig,
    dth_max: float,
    dbr_max: float,
) -> None:
    """Move the pedals toward ``want`` (throttle, brake) at their rate limits, one pedal at a
    time: release the other to zero, then move the foot across (``pedal_switch_s``)."""
    th_d, br_d = want
    if br_d > 0.0 and (d.th > 0.0 or t - d.t_th_last < driver.pedal_switch_s):
        th_d, br_d = 0.0, 0.0
    if th_d > 0.0 and (d.br > 0.0 or t - d.t_br_last < driver.pedal_switch_s):
        th_d, br_d = 0.0, 0.0
    th = d.th + min(max(th_d - d.th, -dth_max), dth_max)
    br = d.br + min(max(br_d - d.br, -dbr_max), dbr_max)
    d.th = 0.0 if th < 1e-12 else th
    d.br = 0.0 if br < 1e-12 else br
    if d.th > 0.0:
        d.t_th_last = t
    if d.br > 0.0:
        d.t_br_last = t


def _truth(
    rec: dict[str, np.ndarray], n: int, dt: float, off: float, scl: float, b: float, low: np.ndarray
) -> Truth:
    """The first ``n`` steps of ``rec`` with the derived truth arrays (time, road-wheel angle,
    yaw rate, low gear, height from the grade)."""
    arr = {k: v[:n] for k, v in rec.items()}
    arr["zone"] = arr["zone"].astype(int)
    arr["t_s"] = np.arange(n) * dt
    arr["delta_rad"] = off + scl * arr["sw_eff_rad"]
    arr["yaw_rate_radps"] = arr["v_mps"] * np.sin(arr["delta_rad"]) / b
    arr["low_gear"] = low[:n].astype(bool)
    v = arr["v_mps"]
    dz = 0.5 * (v[1:] + v[:-1]) * dt * np.sin(arr["grade_rad"][:-1])
    arr["z_m"] = np.concatenate([[0.0], np.cumsum(dz)])
    return Truth(dt, arr)
