"""An independent ground truth for the response of a car to an ACC acceleration request,
driven in CLOSED LOOP on a hilly highway, as an openpilot-driven 2017 Toyota RAV4 is.

Test-only; imports numpy and the sibling ``commonroad_truth`` (for ``_quantise`` and the CSV
writer), never hmpc. Nothing here comes from hmpc's simulator; everything is in this module's
own terms. SI units everywhere (names carry them).

**Road.** A highway, mostly straight with gentle curves: the steering-wheel angle is a few
degrees (slow random sines plus a small lane-keeping jitter), road-wheel angle
``delta = 0.0 + sw / 16`` (:data:`STEER_RATIO`), kinematic bicycle on the rear-axle centre
(wheelbase 2.65 m, track 1.6 m). A hilly profile along the distance ``s`` travelled:
grade ``theta(s)`` = a sum of 2-3 sines with wavelengths 150-600 m whose amplitudes add up to
``Scenario.grade_amp_rad`` (nose up / uphill positive), altitude ``z(s) = int sin(theta) ds``.

**Planner** (stands in for openpilot's planner following traffic): a smooth random target
speed ``v_plan(t)`` in [8, 20] m/s: holds of 1-6 s and raised-cosine ramps to a new random
target whose peak acceleration is 0.4-1.5 m/s^2 (several slowdowns and speed-ups a minute,
like following a lead car); ``a_plan = dv_plan/dt``.

**Controller** (openpilot-like longitudinal PI, the request): at 33 Hz, on the speed it
measures (the mean of the four quantised CAN wheel speeds, the latest sample that has arrived),

    r = a_plan + kp (v_plan - v_meas) + ki * int (v_plan - v_meas) dt,

clipped to [-3, 1.5] m/s^2 (the integral frozen while clipped, and its share held within
+-1 m/s^2), rate limited to 2 m/s^3, quantised to 0.001 m/s^2 and held between updates (the
updates fall on the first simulation step at or after each 1/33 s tick, at most 5 ms late).
The ``accel_cmd`` channel is this held request as sent, sampled on the 50 Hz grid.

**The car** (its ACC ECU and powertrain; the concealed truth, :class:`Car`): the request acts
after a dead time ``d`` and through a first-order lag ``tau``,
``r_eff(t) = LAG_tau(r(t - d))``. The ECU closes its own acceleration loop against
disturbances (grade, drag, rolling resistance) with an integrator ``I``,
``dI/dt = (r_eff - a_ecu) / T_c`` where ``a_ecu`` is the car's true acceleration through a
0.1 s low-pass (``da_ecu/dt = (dv/dt - a_ecu) / 0.1``). The propulsive acceleration is
``a_prop = K (r_eff + I) + res_ecu(v)``, ``res_ecu(v) = 0.1 + 4e-4 v^2`` (the ECU's nominal
feed-forward of the resistance), and the body

    dv/dt = a_prop - (0.12 + 4.5e-4 v^2) - g sin(theta(s))

(the true resistance differs slightly from the feed-forward). With ``K = 1`` and no
disturbance the car's acceleration is exactly ``r_eff``: the truth of "the delay between
``accel_cmd`` and the acceleration" is ``d`` (a dead time) plus ``tau`` (a lag), ``d + tau``
the effective delay. The disturbance reaches the acceleration high-passed by the ECU's loop
(roughly over ``T_c``, but through the 0.1 s measurement filter and ``K``: on purpose not a
pure low-pass-of-grade model).

**Sensors** (:class:`Sensors`): CAN wheel speeds at the contact points (rigid body, Ackermann
front wheels; in gentle curves nearly equal), each quantised to 0.01 km/h, sampled at 83 Hz and
held onto the 50 Hz grid after a 10 ms latency; ``speed`` = their mean (same quantisation);
INS/GNSS at 20 Hz held onto the grid: ``x, y`` (ENU, 0.02 m noise), ``z`` (0.05 m),
``heading`` (from east, CCW, 0.002 rad), ``pitch`` (theta + 0.002 rad), ``gps_speed``
(horizontal, 0.02 m/s); ``yaw_rate`` (true + 0.002 rad/s) and ``accel_x`` (true dv/dt, gravity
removed, + 0.05 m/s^2) at 50 Hz; ``steering_wheel_angle`` quantised to 0.1 deg.

The state (speed, distance, position, heading, lag, ECU integrator and filter) is integrated
with fixed-step RK4 at 200 Hz (:data:`SIM_DT_S`) with the delayed request held over each step
(the dead time and the lag are exact: ``d`` is a multiple of the step). Seeded with numpy's
``default_rng``, deterministic; about 2 s per 600 s recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from indep import commonroad_truth as ct
from indep.commonroad_truth import _quantise

#: Column order of the recordings made here (CONVENTIONS names).
COLUMNS = (
    "time",
    "steering_wheel_angle",
    "wheel_speed_fl",
    "wheel_speed_fr",
    "wheel_speed_rl",
    "wheel_speed_rr",
    "speed",
    "yaw_rate",
    "accel_x",
    "x",
    "y",
    "z",
    "heading",
    "pitch",
    "gps_speed",
    "accel_cmd",
)

#: [s] integration step (200 Hz; the 50 Hz grid and the 20 Hz INS fall on steps).
SIM_DT_S = 0.005
#: [s] recording grid step (50 Hz).
GRID_DT_S = 0.02
G_MPS2 = 9.81
#: geometry of the car (a 2017 RAV4: opendbc wheelbase; track rounded)
WHEELBASE_M = 2.65
TRACK_M = 1.6
#: road-wheel angle = STEER_OFFSET_RAD + steering-wheel angle / STEER_RATIO
STEER_OFFSET_RAD = 0.0
STEER_RATIO = 16.0


# ------------------------------------------------------------------------------- the truth
@dataclass(frozen=True)
class Car:
    """The car's ACC ECU and powertrain (concealed from the recording)."""

    #: [s] dead time of the request (a multiple of SIM_DT_S).
    dead_time_s: float = 0.5
    #: [s] first-order lag of the request (0: none).
    lag_s: float = 0.0
    #: [s] time constant of the ECU's disturbance-rejecting integrator.
    comp_time_s: float = 3.0
    #: [s] low-pass of the acceleration the ECU measures.
    ecu_accel_filter_s: float = 0.1
    #: [1] gain of the powertrain on the (request + integrator).
    gain: float = 1.0
    #: ECU's feed-forward of the resistance: a0 [m/s^2] + c2 [1/m] v^2
    ff_res_mps2: float = 0.10
    ff_res_per_m: float = 4.0e-4
    #: the true resistance: a0 [m/s^2] + c2 [1/m] v^2
    true_res_mps2: float = 0.12
    true_res_per_m: float = 4.5e-4


@dataclass(frozen=True)
class Controller:
    """openpilot-like longitudinal PI producing the request."""

    kp_per_s: float = 0.7
    ki_per_s2: float = 0.15
    rate_hz: float = 33.0
    accel_min_mps2: float = -3.0
    accel_max_mps2: float = 1.5
    jerk_max_mps3: float = 2.0
    step_mps2: float = 0.001
    #: [m/s^2] bound of the integral's share of the request (anti-windup)
    integral_max_mps2: float = 1.0


@dataclass(frozen=True)
class Sensors:
    """Sensor rates, latencies, quantisation and 1-sigma white noise."""

    wheel_rate_hz: float = 83.0
    wheel_latency_s: float = 0.010
    wheel_speed_step_mps: float = 0.01 / 3.6
    ins_rate_hz: float = 20.0
    pos_noise_m: float = 0.02
    alt_noise_m: float = 0.05
    heading_noise_rad: float = 0.002
    pitch_noise_rad: float = 0.002
    gps_speed_noise_mps: float = 0.02
    yaw_noise_radps: float = 0.002
    accel_noise_mps2: float = 0.05
    sw_step_rad: float = math.radians(0.1)


@dataclass(frozen=True)
class Scenario:
    """One recording."""

    car: Car = field(default_factory=Car)
    controller: Controller = field(default_factory=Controller)
    sensors: Sensors = field(default_factory=Sensors)
    duration_s: float = 600.0
    seed: int = 0
    #: [rad] sum of the grade sines' amplitudes (0: a flat road)
    grade_amp_rad: float = 0.03
    #: number of grade sines (2 or 3)
    grade_terms: int = 3
    #: [m/s] planner's speed range
    v_min_mps: float = 8.0
    v_max_mps: float = 20.0
    #: [m/s^2] largest peak acceleration of a planner ramp
    plan_accel_max_mps2: float = 1.5
    #: [rad] amplitude of the steering-wheel schedule (about 3 deg)
    sw_amp_rad: float = math.radians(3.0)


# ------------------------------------------------------------------------------ profiles
@dataclass(frozen=True)
class Road:
    """Grade theta(s) = sum_k amp_k sin(2 pi s / wavelength_k + phase_k) [rad]."""

    amps_rad: tuple
    wavelengths_m: tuple
    phases_rad: tuple

    def grade_rad(self, s_m):
        th = 0.0 * np.asarray(s_m, dtype=float)
        for a, w, p in zip(self.amps_rad, self.wavelengths_m, self.phases_rad):
            th = th + a * np.sin(2.0 * np.pi * np.asarray(s_m) / w + p)
        return th

    def grade_scalar(self, s_m: float) -> float:
        th = 0.0
        for a, w, p in zip(self.amps_rad, self.wavelengths_m, self.phases_rad):
            th += a * math.sin(2.0 * math.pi * s_m / w + p)
        return th


def make_road(sc: Scenario, rng: np.random.Generator) -> Road:
    """2-3 sines, wavelengths 150-600 m, random weights adding up to ``grade_amp_rad``."""
    k = sc.grade_terms
    wl = rng.uniform(150.0, 600.0, k)
    wts = rng.uniform(0.5, 1.0, k)
    ph = rng.uniform(0.0, 2.0 * np.pi, k)
    amps = sc.grade_amp_rad * wts / wts.sum()
    return Road(tuple(amps), tuple(wl), tuple(ph))


def plan_profile(sc: Scenario, t_s: np.ndarray, rng: np.random.Generator):
    """v_plan [m/s] and a_plan [m/s^2] at the times ``t_s``: holds of 1-6 s and raised-cosine
    ramps to random targets in [v_min, v_max] (a ramp of dv over T peaks at pi dv / (2 T))."""
    v0 = float(rng.uniform(sc.v_min_mps + 2.0, sc.v_max_mps - 2.0))
    knots = [(0.0, v0, 0.0, 0.0)]  # (start, v_start, duration, dv) of each ramp
    t, v = 0.0, v0
    t_end = float(t_s[-1]) + 1.0
    while t < t_end:
        t += float(rng.uniform(1.0, 6.0))  # hold
        while True:
            v_new = float(rng.uniform(sc.v_min_mps, sc.v_max_mps))
            if abs(v_new - v) >= 1.5:
                break
        a_pk = float(rng.uniform(0.4, sc.plan_accel_max_mps2))
        dur = math.pi * abs(v_new - v) / (2.0 * a_pk)
        knots.append((t, v, dur, v_new - v))
        t += dur
        v = v_new
    vp = np.full_like(t_s, v0, dtype=float)
    ap = np.zeros_like(t_s, dtype=float)
    for t0, vs, dur, dv in knots[1:]:
        m = (t_s >= t0) & (t_s < t0 + dur)
        ph = np.pi * (t_s[m] - t0) / dur
        vp[m] = vs + 0.5 * dv * (1.0 - np.cos(ph))
        ap[m] = 0.5 * dv * np.pi / dur * np.sin(ph)
        vp[t_s >= t0 + dur] = vs + dv
    return vp, ap


def steering_profile(sc: Scenario, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Steering-wheel angle [rad]: slow sines (periods 25-120 s; gentle highway curves) and a
    small lane-keeping jitter (0.2-0.6 Hz, 0.15 deg)."""
    f = rng.uniform(1.0 / 120.0, 1.0 / 25.0, 3)
    ph = rng.uniform(0.0, 2.0 * np.pi, 3)
    w = rng.uniform(0.5, 1.0, 3)
    sw = (w[:, None] * np.sin(2 * np.pi * f[:, None] * t_s[None, :] + ph[:, None])).sum(0)
    sw *= sc.sw_amp_rad / w.sum()
    fj = rng.uniform(0.2, 0.6, 2)
    pj = rng.uniform(0.0, 2.0 * np.pi, 2)
    sw += math.radians(0.075) * np.sin(2 * np.pi * fj[:, None] * t_s[None, :] + pj[:, None]).sum(0)
    return sw


# ---------------------------------------------------------------------------- simulation
@dataclass
class Run:
    """True states per simulation step (SIM_DT_S) and the sensor samples taken in the loop."""

    t: np.ndarray
    v: np.ndarray  # speed along the road at the rear-axle centre [m/s]
    s: np.ndarray  # distance travelled [m]
    x: np.ndarray  # ENU position of the rear-axle centre [m]
    y: np.ndarray
    psi: np.ndarray  # heading from east, CCW [rad]
    vdot: np.ndarray  # dv/dt at the step [m/s^2]
    delta: np.ndarray  # road-wheel angle [rad]
    sw: np.ndarray  # steering-wheel angle [rad]
    r_sent: np.ndarray  # request as sent (held) [m/s^2]
    r_eff: np.ndarray  # request as the powertrain acts on it [m/s^2]
    integ: np.ndarray  # ECU integrator [m/s^2]
    v_plan: np.ndarray
    a_plan: np.ndarray
    wheel_t: np.ndarray  # 83 Hz wheel-speed sample times [s]
    wheel_q: np.ndarray  # (n, 4) quantised wheel speeds fl, fr, rl, rr [m/s]
    road: Road


def _wheel_speeds(v: float, delta: float) -> tuple[float, float, float, float]:
    """Speeds [m/s] of the four contact points along each wheel's heading (rigid body, no slip;
    front wheels at their Ackermann angles), rear-axle centre moving at ``v``."""
    L, h = WHEELBASE_M, 0.5 * TRACK_M
    td = math.tan(delta)
    r = v * td / L
    out = []
    for wy in (h, -h):  # front left, front right
        ang = math.atan2(L * td, L - wy * td)
        ux, uy = v - r * wy, r * L
        out.append(ux * math.cos(ang) + uy * math.sin(ang))
    out += [v - r * h, v + r * h]  # rear left, rear right
    return tuple(out)


def simulate(sc: Scenario) -> Run:
    """Integrate the closed loop (planner, PI controller, ECU + powertrain, body)."""
    rng = np.random.default_rng(sc.seed)
    car, ctl, sen = sc.car, sc.controller, sc.sensors
    dt = SIM_DT_S
    n = int(round(sc.duration_s / dt)) + 1
    t = np.arange(n) * dt
    road = make_road(sc, rng)
    v_plan, a_plan = plan_profile(sc, t, rng)
    sw = steering_profile(sc, t, rng)
    delta = STEER_OFFSET_RAD + sw / STEER_RATIO
    k_dead = int(round(car.dead_time_s / dt))
    if abs(k_dead * dt - car.dead_time_s) > 1e-9 or k_dead < 0:
        raise ValueError(f"dead_time_s must be a non-negative multiple of {dt} s")
    tau, Tc, Tf, K = car.lag_s, car.comp_time_s, car.ecu_accel_filter_s, car.gain

    def res_ecu(v):
        return car.ff_res_mps2 + car.ff_res_per_m * v * v

    def res_true(v):
        return car.true_res_mps2 + car.true_res_per_m * v * v

    def rhs(X, u, dl):
        """X = [v, s, x, y, psi, lag, I, a_ecu]; u: delayed request held over the step."""
        v, s, _, _, psi, lag, integ, a_f = X
        r_eff = lag if tau > 0 else u
        th = road.grade_scalar(s)
        vdot = K * (r_eff + integ) + res_ecu(v) - res_true(v) - G_MPS2 * math.sin(th)
        vh = v * math.cos(th)  # horizontal speed
        return (
            vdot,
            v,
            vh * math.cos(psi),
            vh * math.sin(psi),
            v * math.tan(dl) / WHEELBASE_M,
            (u - lag) / tau if tau > 0 else 0.0,
            (r_eff - a_f) / Tc,
            (vdot - a_f) / Tf,
        )

    def rk4(X, u, dl):
        k1 = rhs(X, u, dl)
        k2 = rhs([a + 0.5 * dt * b for a, b in zip(X, k1)], u, dl)
        k3 = rhs([a + 0.5 * dt * b for a, b in zip(X, k2)], u, dl)
        k4 = rhs([a + dt * b for a, b in zip(X, k3)], u, dl)
        return [a + dt / 6.0 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(X, k1, k2, k3, k4)]

    # start in equilibrium at the planner's first speed: the ECU's integrator holds the speed
    v0 = float(v_plan[0])
    I0 = (res_true(v0) - res_ecu(v0) + G_MPS2 * math.sin(road.grade_scalar(0.0))) / K
    X = [v0, 0.0, 0.0, 0.0, float(rng.uniform(-np.pi, np.pi)), 0.0, I0, 0.0]
    V, S, PX, PY, PSI, VD, RS, RE, IN = (np.zeros(n) for _ in range(9))
    # wheel samples at j / rate; the controller reads the latest one that has arrived
    wrate = sen.wheel_rate_hz
    n_w = int(math.floor(t[-1] * wrate)) + 1
    wheel_t = np.arange(n_w) / wrate
    wheel_q = np.zeros((n_w, 4))
    j_next = 0  # next wheel sample to take
    tick = 0  # next controller tick (k / rate_hz)
    r_held = 0.0
    c_int = 0.0  # controller's integral of the speed error [m]
    r_hist = np.zeros(n)
    for i in range(n):
        ti = t[i]
        # wheel samples whose time has come (interpolated in the step that just ended)
        while j_next < n_w and wheel_t[j_next] <= ti + 1e-12:
            tj = wheel_t[j_next]
            if i == 0:
                vj, dj = X[0], delta[0]
            else:
                w = (tj - t[i - 1]) / dt
                vj = V[i - 1] + w * (X[0] - V[i - 1])
                dj = delta[i - 1] + w * (delta[i] - delta[i - 1])
            wheel_q[j_next] = _quantise(np.array(_wheel_speeds(vj, dj)), sen.wheel_speed_step_mps)
            j_next += 1
        # controller update on the first step at or after each tick
        if ti >= tick / ctl.rate_hz - 1e-12:
            while tick / ctl.rate_hz <= ti + 1e-12:
                tick += 1
            j_seen = int(math.floor((ti - sen.wheel_latency_s) * wrate + 1e-9))
            v_meas = float(np.mean(wheel_q[max(j_seen, 0)]))
            e = v_plan[i] - v_meas
            c_new = c_int + e / ctl.rate_hz
            c_new = float(
                np.clip(
                    c_new,
                    -ctl.integral_max_mps2 / ctl.ki_per_s2,
                    ctl.integral_max_mps2 / ctl.ki_per_s2,
                )
            )
            r_raw = a_plan[i] + ctl.kp_per_s * e + ctl.ki_per_s2 * c_new
            r_clip = min(max(r_raw, ctl.accel_min_mps2), ctl.accel_max_mps2)
            if r_clip == r_raw:
                c_int = c_new  # freeze the integral while the request is clipped
            dr = ctl.jerk_max_mps3 / ctl.rate_hz
            r_new = min(max(r_clip, r_held - dr), r_held + dr)
            r_held = float(_quantise(r_new, ctl.step_mps2)) + 0.0  # no -0.0
        r_hist[i] = r_held
        u = r_hist[i - k_dead] if i >= k_dead else 0.0
        V[i], S[i], PX[i], PY[i], PSI[i] = X[0], X[1], X[2], X[3], X[4]
        IN[i] = X[6]
        RS[i] = r_held
        RE[i] = X[5] if tau > 0 else u
        VD[i] = rhs(X, u, delta[i])[0]
        if i < n - 1:
            X = rk4(X, u, float(delta[i]))
    return Run(
        t, V, S, PX, PY, PSI, VD, delta, sw, RS, RE, IN, v_plan, a_plan, wheel_t, wheel_q, road
    )


# ---------------------------------------------------------------------------------- record
def _hold(t_src: np.ndarray, t_grid: np.ndarray, latency_s: float = 0.0) -> np.ndarray:
    """Index of the latest source sample (times ``t_src``) that has arrived by each grid time
    (taken at or before t_grid - latency)."""
    k = np.searchsorted(t_src, t_grid - latency_s + 1e-9, side="right") - 1
    return np.clip(k, 0, len(t_src) - 1)


def record(sc: Scenario, run: Run | None = None) -> dict[str, np.ndarray]:
    """The canonical channels (dict name -> array on the 50 Hz grid)."""
    run = run or simulate(sc)
    sen = sc.sensors
    rng = np.random.default_rng(sc.seed + 1_000_003)
    every = int(round(GRID_DT_S / SIM_DT_S))
    idx = np.arange(0, len(run.t), every)
    tg = run.t[idx]
    m = len(idx)
    ch: dict[str, np.ndarray] = {"time": np.round(tg, 9)}
    ch["steering_wheel_angle"] = _quantise(run.sw[idx], sen.sw_step_rad)
    kw = _hold(run.wheel_t, tg, sen.wheel_latency_s)
    wq = run.wheel_q[kw]
    for c, k in zip(("fl", "fr", "rl", "rr"), range(4)):
        ch[f"wheel_speed_{c}"] = wq[:, k]
    ch["speed"] = _quantise(wq.mean(axis=1), sen.wheel_speed_step_mps)
    yaw = run.v * np.tan(run.delta) / WHEELBASE_M
    ch["yaw_rate"] = yaw[idx] + sen.yaw_noise_radps * rng.standard_normal(m)
    ch["accel_x"] = run.vdot[idx] + sen.accel_noise_mps2 * rng.standard_normal(m)
    # INS / GNSS at 20 Hz, held onto the grid
    ins_every = int(round(1.0 / (sen.ins_rate_hz * SIM_DT_S)))
    ii = np.arange(0, len(run.t), ins_every)
    k = _hold(run.t[ii], tg)
    q = len(ii)
    th = run.road.grade_rad(run.s)
    z = np.concatenate([[0.0], np.cumsum(np.diff(run.s) * np.sin(0.5 * (th[1:] + th[:-1])))])
    ins = {
        "x": run.x[ii] + sen.pos_noise_m * rng.standard_normal(q),
        "y": run.y[ii] + sen.pos_noise_m * rng.standard_normal(q),
        "z": z[ii] + sen.alt_noise_m * rng.standard_normal(q),
        "heading": np.angle(
            np.exp(1j * (run.psi[ii] + sen.heading_noise_rad * rng.standard_normal(q)))
        ),
        "pitch": th[ii] + sen.pitch_noise_rad * rng.standard_normal(q),
        "gps_speed": run.v[ii] * np.cos(th[ii]) + sen.gps_speed_noise_mps * rng.standard_normal(q),
    }
    for c, val in ins.items():
        ch[c] = val[k]
    ch["accel_cmd"] = run.r_sent[idx]
    return {c: ch[c] for c in COLUMNS}


def write_recording(channels: dict[str, np.ndarray], path: str | Path) -> Path:
    """Write a canonical recording CSV (the columns of :data:`COLUMNS` present, in that order)."""
    return ct.write_recording(channels, path, COLUMNS)


def geometry() -> dict:
    """The geometry mapping for hmpc (``vehicle:`` keys of models/params.py)."""
    return {
        "vehicle": {
            "wheelbase_m": WHEELBASE_M,
            "track_front_m": TRACK_M,
            "track_rear_m": TRACK_M,
            "wheel_radius_m": 0.362,
            "mass_kg": 1656.0,
            "source": "tests/indep/acc_truth.py (a 2017 RAV4-like car)",
        }
    }


def scenario(
    dead_time_s: float,
    lag_s: float = 0.0,
    *,
    seed: int = 0,
    duration_s: float = 600.0,
    grade_amp_rad: float = 0.03,
    **car_kw,
) -> Scenario:
    """A scenario with the car's dead time and lag (other Car fields through ``car_kw``)."""
    return Scenario(
        car=Car(dead_time_s=dead_time_s, lag_s=lag_s, **car_kw),
        seed=seed,
        duration_s=duration_s,
        grade_amp_rad=grade_amp_rad,
    )


__all__ = [
    "COLUMNS",
    "SIM_DT_S",
    "Car",
    "Controller",
    "Sensors",
    "Scenario",
    "Road",
    "Run",
    "simulate",
    "record",
    "geometry",
    "scenario",
    "write_recording",
]
