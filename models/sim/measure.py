"""The recording's sensors: what the car's CAN and the INS report about a truth on a uniform
grid (:func:`measure`), from the sensor models of ``models.sim.sensors``: CAN channels
quantised as the RAV4's DBC encodes them and sent at the real message rates, INS channels with
the noise of a survey-grade GNSS/INS. The INS reference point is the front-axle centre: eq. 1's
(x, y).

Noise levels (``NOISE_LEVELS``): ``"typical"`` (quantisation, message rates, timing jitter,
sensor noise and biases), ``"quantised"`` (quantisation and message rates only, no random
errors), ``"none"`` (ideal sensors: every channel is the truth at the grid time, nothing
quantised or delayed; eq. 1, 7 and 8 hold exactly on it, effects aside).
"""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.channels import CHANNELS
from hmpc.models.params import Params
from hmpc.models.sim import sensors as sn
from hmpc.models.sim.effect_base import Effect
from hmpc.models.sim.truth_plant import Truth

NOISE_LEVELS = ("typical", "quantised", "none")


def measure(
    truth: Truth,
    params: Params,
    rate_hz: float,
    noise: str,
    effects: list[Effect],
    rng_can: np.random.Generator,
    rng_ins: np.random.Generator,
) -> tuple[dict, dict, dict, np.ndarray]:
    """What the car's CAN and the INS report about ``truth`` (``models.sim.sensors``).

    Reusable for any truth on a uniform grid (a closed loop, too) holding the arrays listed in
    :class:`Truth`; ``1 / (rate_hz * truth.dt_s)`` must be a whole number (the output grid is
    every m-th truth sample). Effects contribute their sensor hooks (wheel-speed scale, CAN
    clock offset); their plant hooks must already be in ``truth``.

    Returns:
        channels (canonical names, on the output grid), raw samples per channel
        (``(t_s, values)``, CAN at its message times), the sensor truth (biases, clock offset,
        wheel-speed scale), and the truth index of each output row.
    """
    tr = truth.arrays
    dt = truth.dt_s
    m = int(round(1.0 / (rate_hz * dt)))
    if m < 1 or abs(m * rate_hz * dt - 1.0) > 1e-9:
        raise ValueError(
            f"rate_hz {rate_hz} is not the truth rate {1 / dt:g} Hz over a whole number"
        )
    t = tr["t_s"]
    idx = np.arange(0, len(t), m)
    grid = t[idx]
    veh = params.vehicle
    b = veh.wheelbase_m
    t_r = veh.track_rear_m if veh.track_rear_m is not None else veh.track_front_m
    c = float(sum(e.can_clock_offset_s() for e in effects))
    ws = float(np.prod([e.wheel_speed_scale() for e in effects])) if effects else 1.0

    ch: dict[str, np.ndarray] = {"time": grid.copy()}
    raw: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    _measure_can(tr, veh, t_r, grid, idx, noise, c, ws, rng_can, ch, raw)
    sensor_truth = {
        "can_clock_offset_s": c,
        "wheel_speed_scale": ws,
        "yaw_rate_bias_radps": 0.0,
        "accel_x_bias_mps2": 0.0,
        "accel_y_bias_mps2": 0.0,
    }
    ins = _measure_ins(tr, dt, b, noise, rng_ins, sensor_truth)
    for name, val in ins.items():
        raw[name] = (t.copy(), val)
        ch[name] = val[idx]  # the INS grid contains the output grid: hold = the sample itself
    ordered = {k: ch[k] for k in CHANNELS if k in ch}
    return ordered, raw, sensor_truth, idx


def _measure_can(
    tr: dict,
    veh,
    t_r: float,
    grid: np.ndarray,
    idx: np.ndarray,
    noise: str,
    c: float,
    ws: float,
    rng_can: np.random.Generator,
    ch: dict,
    raw: dict,
) -> None:
    """The CAN channels of :func:`measure` into ``ch`` (on ``grid``) and ``raw`` (at message
    times): exact samples at ``noise="none"``, else periodic messages with random phase
    (and jitter and noise at ``"typical"``), DBC-quantised and held on the grid. ``c``: CAN
    clock offset [s]; ``ws``: wheel-speed scale."""
    t = tr["t_s"]
    # ---- CAN truth signals on the internal grid (continuous, SI)
    fl, fr, rl, rr = sn.wheel_speeds(
        tr["v_mps"], tr["delta_rad"], veh.wheelbase_m, veh.track_front_m, t_r
    )
    can_truth = {
        "steering_wheel_angle": tr["sw_rad"],
        "wheel_speed_fl": fl * ws,
        "wheel_speed_fr": fr * ws,
        "wheel_speed_rl": rl * ws,
        "wheel_speed_rr": rr * ws,
        "accel_pedal": tr["accel_pedal"],
        "brake_pedal": tr["brake_pedal"],
        "engine_rpm": sn.engine_rpm(tr["v_mps"], tr["accel_pedal"], veh, tr["low_gear"]),
    }
    gear_truth = np.where(tr["low_gear"], "L", "D").astype(object)
    if noise == "none":
        for name, val in can_truth.items():
            ch[name] = val[idx] if c == 0.0 else np.interp(grid - c, t, val)
            raw[name] = (grid.copy(), ch[name])
        wheels = [ch[f"wheel_speed_{w}"] for w in ("fl", "fr", "rl", "rr")]
        ch["speed"] = sum(wheels) / 4.0
        raw["speed"] = (grid.copy(), ch["speed"])
        gi = np.clip(np.searchsorted(t, grid - c, side="right") - 1, 0, len(t) - 1)
        ch["gear"] = gear_truth[gi]
        raw["gear"] = (grid.copy(), ch["gear"])
        return
    typical = noise == "typical"
    jitter = sn.CAN_JITTER_S if typical else 0.0
    t_lo, t_hi = -abs(c) - 0.1, t[-1] + abs(c) + 0.1
    by_msg: dict[str, np.ndarray] = {}
    for sig in sn.CAN_SIGNALS:
        if sig.message not in by_msg:  # signals of one message share its send times
            by_msg[sig.message] = sn.message_times(rng_can, sig.rate_hz, t_lo, t_hi, jitter)
        t_msg = by_msg[sig.message]
        val = np.interp(t_msg, t, can_truth[sig.channel])
        if typical and sig.noise_dbc > 0:
            val = val + rng_can.normal(0.0, sig.noise_dbc * sig.to_si, val.shape)
        val = sn.quantise_dbc(val, sig)
        raw[sig.channel] = (t_msg + c, val)
        ch[sig.channel] = sn.hold_on_grid(t_msg + c, val, grid)
    tw = raw["wheel_speed_fl"][0]
    sp = sum(raw[f"wheel_speed_{w}"][1] for w in ("fl", "fr", "rl", "rr")) / 4.0
    raw["speed"] = (tw, sp)
    ch["speed"] = sn.hold_on_grid(tw, sp, grid)
    tg = sn.message_times(rng_can, sn.GEAR_RATE_HZ, t_lo, t_hi, jitter)
    gi = np.clip(np.searchsorted(t, tg, side="right") - 1, 0, len(t) - 1)
    raw["gear"] = (tg + c, gear_truth[gi])
    ch["gear"] = sn.hold_on_grid(tg + c, gear_truth[gi], grid)


def _measure_ins(
    tr: dict, dt: float, b: float, noise: str, rng_ins: np.random.Generator, sensor_truth: dict
) -> dict[str, np.ndarray]:
    """The INS channels of :func:`measure` at the internal rate, reference point = the
    front-axle centre; at ``noise="typical"`` with ``InsNoise`` errors, whose biases are
    written into ``sensor_truth``."""
    t = tr["t_s"]
    ddelta = np.gradient(tr["delta_rad"], dt) if len(t) > 1 else np.zeros(len(t))
    ax, ay = sn.ins_body_accel(tr["v_mps"], tr["accel_mps2"], tr["delta_rad"], ddelta, b)
    ins = {
        "yaw_rate": tr["yaw_rate_radps"].copy(),
        "accel_x": ax,
        "accel_y": ay,
        "x": tr["x_m"].copy(),
        "y": tr["y_m"].copy(),
        "z": tr["z_m"].copy(),
        "heading": tr["psi_rad"].copy(),
        "pitch": tr["grade_rad"] + sn.PITCH_PER_ACCEL * ax,
        "roll": sn.ROLL_PER_LATERAL_ACCEL * ay,
        "gps_speed": tr["v_mps"].copy(),
    }
    if noise == "typical":
        nz = sn.InsNoise()
        n = len(t)
        gm = lambda s, tau: sn.gauss_markov(rng_ins, n, s, tau, dt)  # noqa: E731
        ins["x"] += gm(nz.pos_xy_m, nz.pos_xy_tau_s)
        ins["y"] += gm(nz.pos_xy_m, nz.pos_xy_tau_s)
        ins["z"] += gm(nz.pos_z_m, nz.pos_z_tau_s)
        ins["heading"] += gm(nz.heading_rad, nz.heading_tau_s)
        ins["pitch"] += gm(nz.attitude_rad, nz.attitude_tau_s)
        ins["roll"] += gm(nz.attitude_rad, nz.attitude_tau_s)
        bias_r = float(rng_ins.uniform(-nz.yaw_rate_bias_max_radps, nz.yaw_rate_bias_max_radps))
        bias_ax, bias_ay = np.clip(
            rng_ins.normal(0.0, nz.accel_bias_mps2, 2),
            -nz.accel_bias_max_mps2,
            nz.accel_bias_max_mps2,
        )
        ins["yaw_rate"] += bias_r + rng_ins.normal(0.0, nz.yaw_rate_radps, n)
        ins["accel_x"] += bias_ax + rng_ins.normal(0.0, nz.accel_mps2, n)
        ins["accel_y"] += bias_ay + rng_ins.normal(0.0, nz.accel_mps2, n)
        ins["gps_speed"] = np.abs(ins["gps_speed"] + rng_ins.normal(0.0, nz.gps_speed_mps, n))
        sensor_truth.update(
            yaw_rate_bias_radps=bias_r,
            accel_x_bias_mps2=float(bias_ax),
            accel_y_bias_mps2=float(bias_ay),
        )
    ins["heading"] = np.angle(np.exp(1j * ins["heading"]))  # wrap to (-pi, pi]
    ins["heading"][ins["heading"] <= -np.pi] = np.pi
    return ins
