"""An independent ground truth for a pedal-driven car's powertrain: an automatic gearbox, and a
car whose brake the recording does not carry.

Test-only; numpy only, never hmpc: everything here is in this module's own terms (forces,
torques, ratios), not hmpc's zone models. SI units everywhere (names carry them).

**Car** (:class:`Car`, a 1500 kg saloon): the engine gives ``T = pedal * T_max`` [N m] (flat
torque curve) with the pedal pressed; with it released the engine drags,
``T = -c_eb * rpm / 1000`` (engine braking, ``c_eb`` [N m per 1000 rpm]). Through gear g
(:data:`GEAR_RATIOS`, times the final drive) the wheel force is ``T i_g i_f eta / r_w``, so the
pedal's gain and the engine braking both scale with the gear's ratio. The engine turns at
``rpm = 60 v i_g i_f / (2 pi r_w)``, not below idle (800 rpm: a slipping torque converter;
no drive or drag from the engine there but the idle creep ``a_creep``). Shifts
(:class:`Gearbox`): up from g when v exceeds ``v_up[g]``, down when v falls below
``v_down[g] < v_up[g]`` (hysteresis: between the two either gear is engaged, by history); a
shift takes effect at once (no torque interruption). With ``gearbox=False`` the car has one
fixed ratio and no engine braking (an electric car's reduction gear). The body:

    m dv/dt = F_engine - F_brake - m (c_r g + c_d v^2),   F_brake = brake * F_brake_max

**Driver** (:func:`simulate`): a PI controller on a random target speed profile (holds of
4-15 s at 0-22 m/s, raised-cosine ramps, stops), pedal for positive demand, brake when the
demand is below what coasting gives by more than a margin; pedal and brake never together.
With ``Scenario.driver_brakes`` False the driver never brakes (the car coasts down).

**Sensors** (:func:`record`): 50 Hz grid; ``speed`` quantised to 0.01 km/h (CAN);
``accel_pedal`` quantised to 0.5 %; ``brake_pedal`` (0..1, 0.5 %) unless
``Scenario.record_brake`` is False; ``engine_rpm`` (1 rpm steps, 10 rpm noise) when
``Scenario.record_rpm``. Integration: explicit Euler at 500 Hz (the driver and gearbox update
at 50 Hz). Seeded with numpy's ``default_rng``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

G_MPS2 = 9.81
#: gear ratios of a five-speed automatic (a mid-size saloon's) and its final drive
GEAR_RATIOS = (3.5, 2.1, 1.4, 1.0, 0.8)
FINAL_DRIVE = 3.9
IDLE_RPM = 800.0
SIM_DT_S = 0.002
REC_DT_S = 0.02


@dataclass
class Car:
    """The concealed truth (module doc)."""

    mass_kg: float = 1500.0
    wheel_radius_m: float = 0.31
    torque_max_nm: float = 250.0
    #: engine drag [N m per 1000 rpm] with the pedal released
    engine_brake_nm_per_krpm: float = 25.0
    efficiency: float = 0.9
    brake_force_max_n: float = 12000.0
    c_roll: float = 0.012
    c_drag_per_m: float = 2.5e-4
    creep_mps2: float = 0.3
    gearbox: bool = True
    #: fixed ratio (times the final drive) of the car without a gearbox
    fixed_ratio: float = 9.0
    #: shift speeds [m/s] up from gear g (index) and down to it from g + 1
    v_up_mps: tuple = (4.5, 8.0, 12.5, 17.0)
    v_down_mps: tuple = (3.0, 6.0, 10.0, 14.5)

    def ratio(self, gear: int) -> float:
        return GEAR_RATIOS[gear] * FINAL_DRIVE if self.gearbox else self.fixed_ratio

    def rpm(self, v: float, gear: int) -> float:
        return max(IDLE_RPM, 60.0 * v * self.ratio(gear) / (2 * np.pi * self.wheel_radius_m))

    def accel(self, v: float, gear: int, pedal: float, brake: float) -> float:
        k = self.ratio(gear) * self.efficiency / self.wheel_radius_m / self.mass_kg
        rpm = self.rpm(v, gear)
        locked = rpm > IDLE_RPM
        if pedal > 0:
            a = pedal * self.torque_max_nm * k
        elif self.gearbox and locked:
            a = -self.engine_brake_nm_per_krpm * rpm / 1000.0 * k
        else:
            a = 0.0
        if not locked and pedal == 0:
            a += self.creep_mps2 * max(0.0, 1.0 - v / 2.0)
        a -= brake * self.brake_force_max_n / self.mass_kg
        if v > 0.01:
            a -= self.c_roll * G_MPS2 + self.c_drag_per_m * v * v
        return a


class Gearbox:
    """Shift logic with hysteresis (module doc)."""

    def __init__(self, car: Car):
        self.car = car
        self.gear = 0

    def update(self, v: float) -> int:
        c = self.car
        if not c.gearbox:
            return 0
        while self.gear < len(c.v_up_mps) and v > c.v_up_mps[self.gear]:
            self.gear += 1
        while self.gear > 0 and v < c.v_down_mps[self.gear - 1]:
            self.gear -= 1
        return self.gear


@dataclass
class Scenario:
    car: Car = field(default_factory=Car)
    duration_s: float = 300.0
    seed: int = 0
    record_brake: bool = True
    record_rpm: bool = True
    #: the driver brakes (False: only the accelerator, the car coasts to slow down)
    driver_brakes: bool = True


def target_profile(sc: Scenario, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random target speed: holds and raised-cosine ramps, a stop now and then."""
    out = np.zeros_like(t)
    v0, t0 = 0.0, 0.0
    while t0 < t[-1]:
        v1 = 0.0 if rng.random() < 0.2 else float(rng.uniform(2.0, 22.0))
        ramp = max(abs(v1 - v0) / rng.uniform(0.6, 2.0), 1.0)
        hold = float(rng.uniform(4.0, 15.0))
        m = (t >= t0) & (t < t0 + ramp)
        out[m] = v0 + (v1 - v0) * 0.5 * (1 - np.cos(np.pi * (t[m] - t0) / ramp))
        m = (t >= t0 + ramp) & (t < t0 + ramp + hold)
        out[m] = v1
        v0, t0 = v1, t0 + ramp + hold
    return out


@dataclass
class Run:
    t_s: np.ndarray
    v_mps: np.ndarray
    pedal: np.ndarray
    brake: np.ndarray
    gear: np.ndarray
    rpm: np.ndarray


def simulate(sc: Scenario) -> Run:
    rng = np.random.default_rng(sc.seed)
    car = sc.car
    t = np.arange(0.0, sc.duration_s, REC_DT_S)
    vt = target_profile(sc, t, rng)
    box = Gearbox(car)
    n = len(t)
    v_rec, ped, brk, gear, rpm = (np.zeros(n) for _ in range(5))
    v, integ = 0.0, 0.0
    sub = int(round(REC_DT_S / SIM_DT_S))
    for i in range(n):
        g = box.update(v)
        e = vt[i] - v
        integ = float(np.clip(integ + e * REC_DT_S, -3.0, 3.0))
        demand = 0.8 * e + 0.15 * integ + 0.5 * (vt[min(i + 25, n - 1)] - vt[i])
        coast = car.accel(v, g, 0.0, 0.0)
        p = b = 0.0
        if demand > 0.05 and vt[i] > 0.1:
            p = float(
                np.clip(
                    demand
                    * car.mass_kg
                    * car.wheel_radius_m
                    / (car.torque_max_nm * car.ratio(g) * car.efficiency),
                    0.0,
                    1.0,
                )
            )
        elif demand < coast - 0.3 or vt[i] < 0.1:
            b = float(np.clip((coast - demand) * car.mass_kg / car.brake_force_max_n, 0.0, 1.0))
            if vt[i] < 0.1 and v < 0.5:
                b = max(b, 0.3)
        if not sc.driver_brakes:
            b = 0.0
        p, b = np.round(p / 0.005) * 0.005, np.round(b / 0.005) * 0.005
        v_rec[i], ped[i], brk[i], gear[i], rpm[i] = v, p, b, g, car.rpm(v, g)
        for _ in range(sub):
            v = max(0.0, v + car.accel(v, g, p, b) * SIM_DT_S)
    return Run(t, v_rec, ped, brk, gear, rpm)


def record(sc: Scenario, run: Run | None = None) -> dict[str, np.ndarray]:
    """The recording's canonical channels (module doc)."""
    run = run or simulate(sc)
    rng = np.random.default_rng(sc.seed + 1000)
    kmh = 0.01 / 3.6
    ch = {
        "time": run.t_s,
        "speed": np.round(run.v_mps / kmh) * kmh,
        "accel_pedal": run.pedal.copy(),
    }
    if sc.record_brake:
        ch["brake_pedal"] = run.brake.copy()
    if sc.record_rpm:
        ch["engine_rpm"] = np.round(run.rpm + rng.normal(0.0, 10.0, len(run.rpm)))
    return ch


def geometry() -> dict:
    """The geometry file's mapping (``vehicle:`` keys of models/params.py)."""
    car = Car()
    return {
        "vehicle": {
            "wheelbase_m": 2.8,
            "track_front_m": 1.55,
            "track_rear_m": 1.55,
            "wheel_radius_m": car.wheel_radius_m,
            "mass_kg": car.mass_kg,
            "source": "tests/indep/powertrain_truth.py",
        }
    }


def gearbox_scenario(seed: int = 0, duration_s: float = 300.0) -> Scenario:
    return Scenario(Car(), duration_s, seed)


def unrecorded_brake_scenario(seed: int = 0, duration_s: float = 300.0) -> Scenario:
    """A single-ratio car (no gears, no engine braking) whose recording lacks the brake."""
    return Scenario(Car(gearbox=False), duration_s, seed, record_brake=False, record_rpm=False)


# ---- a by-wire car following a speed command ----------------------------------------------


@dataclass
class ByWireCar:
    """A small by-wire car (an F1TENTH-like platform scaled to a road car's speeds) whose
    speed controller is proportional with its motor's force limit: the acceleration asked for,
    ``k_p (speed_cmd(t - d) - v)``, is clipped to +-``accel_limit_mps2`` (both ways: the
    motor brakes regeneratively through the same limit) before the body's resistance."""

    k_p_per_s: float = 2.0
    accel_limit_mps2: float = 1.5
    dead_time_s: float = 0.0
    c_roll_mps2: float = 0.1

    def accel(self, v: float, cmd: float) -> float:
        a = float(
            np.clip(self.k_p_per_s * (cmd - v), -self.accel_limit_mps2, self.accel_limit_mps2)
        )
        return a - (self.c_roll_mps2 if v > 0.01 else 0.0)


def speed_command_record(
    car: ByWireCar, duration_s: float = 300.0, seed: int = 0
) -> dict[str, np.ndarray]:
    """A teleoperated drive: the speed command jumps between random levels (0-12 m/s, held
    3-10 s, as a joystick gives), sampled at 50 Hz and held; the car integrated at 500 Hz;
    ``speed`` quantised to 0.01 km/h, ``speed_cmd`` to 0.01 m/s. No pedal channel."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, REC_DT_S)
    cmd = np.zeros_like(t)
    t0 = 0.0
    while t0 < duration_s:
        hold = float(rng.uniform(3.0, 10.0))
        cmd[(t >= t0) & (t < t0 + hold)] = 0.0 if rng.random() < 0.15 else rng.uniform(1.0, 12.0)
        t0 += hold
    cmd = np.round(cmd / 0.01) * 0.01
    lag = int(round(car.dead_time_s / REC_DT_S))
    v, out = 0.0, np.zeros_like(t)
    sub = int(round(REC_DT_S / SIM_DT_S))
    for i in range(len(t)):
        out[i] = v
        c = cmd[max(i - lag, 0)]
        for _ in range(sub):
            v = max(0.0, v + car.accel(v, c) * SIM_DT_S)
    kmh = 0.01 / 3.6
    return {"time": t, "speed": np.round(out / kmh) * kmh, "speed_cmd": cmd}
