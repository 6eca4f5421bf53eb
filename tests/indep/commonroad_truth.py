"""An independent ground truth for ``hmpc identify``, built on CommonRoad's vehicle models.

Nothing here comes from hmpc's own simulator (``hmpc.models.sim``): the vehicle motion is
integrated with the PyPI package ``commonroad-vehicle-models`` (TUM, BSD licence), its
kinematic single-track model ``vehicle_dynamics_ks`` (state ``[sx, sy, delta, v, psi]``, the
reference point is the REAR-axle centre, ``v`` the rear-axle speed) or its single-track model
with tyres ``vehicle_dynamics_st`` (state ``[sx, sy, delta, v, psi, psi_dot, beta]`` at the
centre of gravity), with CommonRoad's parameter set 2 (BMW 320i: wheelbase 2.579 m, tracks
1.387 / 1.364 m). It differs from hmpc's simulator in three ways:

- **reference point**: the INS position, heading, ground speed and accelerations are those of
  the rear-axle centre, the centre of gravity, the front-axle centre or any lever arm
  ``(x, y)`` [m] in body axes from the rear-axle centre (``Scenario.ref_point``);
- **driver**: a speed-tracking PI driver that coasts, or switches between throttle and brake
  with hysteresis, with a foot lag and a smooth pedal dither; the steering wheel follows a
  smooth schedule (a 0.045-0.06 Hz sine plus slower random sines, flattened at the tops),
  scaled to +-180 deg and more at 2-5.5 m/s and to a 2.5 m/s^2 lateral acceleration above,
  with straight segments in which the driver holds the car straight (steering wheel at
  ``-offset / scale``); the model family "ks" also offers ``accel_point="rear"`` (the zone
  law on the rear-axle speed, the model's own state);
- **sensors**: CAN quantisation as on a RAV4 (wheel speeds 0.01 km/h; steering angle 1.5 deg
  plus a 0.1 deg fraction; pedals 0.5 %), INS white noise, recording rates 10/50/100 Hz, and
  channel groups that can be left out (:data:`GROUPS`).

**The truth** is exactly the report's family, with no concealed effect and no dead time:
road-wheel angle = ``steer_offset_rad + steer_scale * steering-wheel angle`` (the model's
steering state ``delta`` equals it at every sample; ``Scenario.steer_delay_s`` > 0 delays the
road wheels behind the recorded steering-wheel angle, a known dead time for the tests), and
per speed zone (idle [0, 2], low (2, 5], high (5, 20] m/s, sharp boundaries, the zone taken
at the start of each 10 ms step) the acceleration of the FRONT-axle-centre speed ``v_F``
(the report's eq. 1 point F; the speed hmpc derives from the front wheels) is
``offset + scale * accel_pedal - brake_scale * brake_pedal``. For the kinematic model the
rear-axle speed is ``v_R = v_F cos(delta)``, so the model is driven with
``dv_R/dt = a cos(delta) - v_F sin(delta) d(delta)/dt``; at rest the car is held (no rolling
backwards). For the single-track model with tyres there is no no-slip point F: the zone law
acts on its own speed ``v`` (centre of gravity), a documented difference of that family.

**Concealed physics** (``Scenario.effects``, :class:`Effects`; none by default) puts each effect
of hmpc's diagnosis catalogue into this generator's own terms, never through hmpc: pedal and
steering dead times and lags (the powertrain, brakes or road wheels act on the recorded
pedals / steering-wheel angle late), a cubic rack, understeer (kinematic model: the road wheels
act as delta L / (L + K v^2); single-track model with tyres: through its front and rear
cornering coefficients, K = (1/C_Sf - 1/C_Sr) / (mu g), with a right-hand side equal to the
library's but with the two coefficients separate), aerodynamic drag and rolling resistance, a
road profile (gravity along the road, the INS altitude ``z`` and ``pitch`` recorded), a
speed-regulating idle torque with the throttle released, CAN wheel speeds scaled, a clock offset
of the CAN channels against the INS channels, and, outside the catalogue, throttle and brake
gains scaled in the second half (a heavier car). tests/indep/diagnose_matrix.py diagnoses one
recording per effect.

**Wheel speeds** are physical for the model: each wheel's speed is the component, along the
wheel's heading, of the body velocity at that wheel's contact point (velocity of the
reference point plus yaw rate x lever); the front wheels point at their Ackermann angles
(``tan(delta_i) = L tan(delta) / (L - y_i tan(delta))``), so with no tyre slip each equals the
contact point's speed; the rear axle has its own track.

Generation is seeded and takes about 0.5 s per 240 s recording (fixed-step RK4 at 100 Hz on
the library's right-hand side; the tyre model sub-steps at low speed). Import it from the
tests as ``from indep import commonroad_truth`` (tests/ is on sys.path; no __init__.py).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
from vehiclemodels.vehicle_dynamics_ks import vehicle_dynamics_ks
from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st

#: Channel groups that a recording may lack, and the canonical channels each removes.
GROUPS: dict[str, tuple[str, ...]] = {
    "accel_pedal": ("accel_pedal",),
    "brake_pedal": ("brake_pedal",),
    "wheel_speeds": ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"),
    "speed": ("speed",),
    "yaw_rate": ("yaw_rate",),
    "position": ("x", "y", "heading"),
    "ins": ("yaw_rate", "accel_x", "accel_y", "x", "y", "z", "heading", "pitch", "gps_speed"),
}

#: Column order of a canonical recording (docs/conventions.md), for the channels made here.
COLUMNS = (
    "time",
    "steering_wheel_angle",
    "wheel_speed_fl",
    "wheel_speed_fr",
    "wheel_speed_rl",
    "wheel_speed_rr",
    "speed",
    "accel_pedal",
    "brake_pedal",
    "yaw_rate",
    "accel_x",
    "accel_y",
    "x",
    "y",
    "z",
    "heading",
    "pitch",
    "gps_speed",
)

#: [s] integration and driver step (100 Hz; the recording rates divide it).
SIM_DT_S = 0.01
#: [m] wheelbase of CommonRoad's parameter set 2 (used by the steering schedule's envelope).
VEH_L_M = float(parameters_vehicle2().a + parameters_vehicle2().b)


# ---------------------------------------------------------------------------------- truth
@dataclass(frozen=True)
class ZoneTruth:
    """accel [m/s^2] = offset_mps2 + scale_mps2 * accel_pedal - brake_scale_mps2 * brake_pedal."""

    name: str
    v_min_mps: float
    v_max_mps: float
    offset_mps2: float
    scale_mps2: float
    brake_scale_mps2: float


@dataclass(frozen=True)
class Truth:
    """The parameters a recording is generated with (the report's family, nothing hidden)."""

    name: str
    steer_offset_rad: float
    steer_scale: float
    zones: tuple[ZoneTruth, ...]

    def zone_index(self, v_mps: float) -> int:
        """Zone whose (v_min, v_max] holds v (the first includes 0); the last above its v_max."""
        for i, z in enumerate(self.zones):
            if v_mps <= z.v_max_mps:
                return i
        return len(self.zones) - 1

    def accel_mps2(
        self, v_mps: float, accel_pedal: float, brake_pedal: float, zone: int | None = None
    ) -> float:
        """The zone law at speed ``v_mps`` (or in zone index ``zone`` when given)."""
        z = self.zones[self.zone_index(v_mps) if zone is None else zone]
        return z.offset_mps2 + z.scale_mps2 * accel_pedal - z.brake_scale_mps2 * brake_pedal


def _zones(idle, low, high) -> tuple[ZoneTruth, ...]:
    return (
        ZoneTruth("idle", 0.0, 2.0, *idle),
        ZoneTruth("low", 2.0, 5.0, *low),
        ZoneTruth("high", 5.0, 20.0, *high),
    )


#: Three parameter sets in plausible ranges (steering ratio 11-17; idle creep positive, drag
#: negative at speed; throttle 1-3 m/s^2 per unit pedal; brake 4.5-8 m/s^2 per unit pressure).
TRUTHS: dict[str, Truth] = {
    "A": Truth(
        "A", 0.010, 0.0800, _zones((0.35, 1.20, 5.0), (-0.10, 2.00, 6.5), (-0.30, 2.60, 7.5))
    ),
    "B": Truth(
        "B", -0.015, 0.0650, _zones((0.25, 1.00, 4.5), (-0.05, 1.70, 6.0), (-0.25, 2.21, 7.0))
    ),
    "C": Truth(
        "C", 0.020, 0.0900, _zones((0.45, 1.50, 5.5), (-0.15, 2.30, 7.0), (-0.40, 3.00, 8.0))
    ),
}


# -------------------------------------------------------------------------------- scenario
@dataclass(frozen=True)
class Sensors:
    """The sensor set (quantisation as on a RAV4's CAN; INS noise as 1-sigma white noise)."""

    #: [Hz] recording rate: 10, 50 or 100 (divides the 100 Hz simulation).
    rate_hz: float = 50.0
    #: channel groups left out (keys of :data:`GROUPS`).
    omit: frozenset = frozenset()
    #: [m/s] WHEEL_SPEEDS step 0.01 km/h.
    wheel_speed_step_mps: float = 0.01 / 3.6
    #: [deg] STEER_ANGLE step 1.5 deg and STEER_FRACTION step 0.1 deg (range +-0.7 deg).
    sw_coarse_deg: float = 1.5
    sw_fine_deg: float = 0.1
    #: [1] GAS_PEDAL step 0.5 %; brake pressure normalised, step 1 %.
    pedal_step: float = 0.005
    brake_step: float = 0.01
    #: INS: position [m], heading [rad], yaw rate [rad/s], accelerations [m/s^2], speed [m/s].
    pos_noise_m: float = 0.02
    heading_noise_rad: float = 0.002
    yaw_noise_radps: float = 0.002
    accel_noise_mps2: float = 0.05
    gps_speed_noise_mps: float = 0.02

    def __post_init__(self):
        bad = set(self.omit) - set(GROUPS)
        if bad:
            raise ValueError(f"unknown channel group(s) {sorted(bad)}; known: {sorted(GROUPS)}")
        if abs(round(1.0 / (self.rate_hz * SIM_DT_S)) * self.rate_hz * SIM_DT_S - 1.0) > 1e-9:
            raise ValueError(f"rate_hz must divide {1 / SIM_DT_S:g} Hz, got {self.rate_hz}")


REF_POINTS = ("rear", "cog", "front")


@dataclass(frozen=True)
class Effects:
    """Physics concealed from the report's family, each in this generator's own terms (all off
    by default). Units in the names; each parameter is given as hmpc's catalogue defines it, so
    a test can compare the recovered figure with it (the definitions are physics, not hmpc's
    code: nothing here imports hmpc).

    Actuators: ``pedal_delay_s`` / ``pedal_lag_s`` (the powertrain and brakes act on the pedals
    late, or through a first-order lag; the recorded pedals are the driver's feet);
    ``steer_lag_s`` (the road wheels follow the steering wheel through a first-order lag; the
    dead time is :attr:`Scenario.steer_delay_s`).
    Steering map: ``rack_cubic_per_rad2`` k3 (road-wheel angle = offset + scale (sw + k3 sw^3),
    negative: the rack saturates); ``understeer_rad_per_mps2`` K (kinematic model: the road
    wheels act as delta L / (L + K v^2), the steady state of a linear single-track car with
    understeer gradient K). For the single-track model with tyres, understeer is not set
    here but through its tyres (``st_C_Sf`` / ``st_C_Sr``): K = (1/C_Sf - 1/C_Sr) / (mu g)
    (:func:`st_understeer_gradient`).
    Resistances (on the zone law's speed): ``drag_per_m`` c (- c v^2), ``roll_per_s`` r (- r v).
    Road: ``grade_amp_rad`` and ``grade_wavelength_m``: a road profile with grade
    theta(s) = amp (0.6 sin(2 pi s / lambda) + 0.4 sin(2 pi s / (0.37 lambda) + 1)) along the
    distance s travelled; gravity adds - g sin(theta) to the acceleration, the INS records the
    altitude z(s) = int sin(theta) ds and the pitch (nose-up positive: uphill).
    Idle: ``creep_accel_mps2`` a0 and ``creep_speed_mps`` v_c: a speed-regulating idle torque
    a0 max(0, 1 - v / v_c) while the throttle the powertrain sees is released.
    Sensors: ``wheel_scale`` k (CAN wheel speeds, and the speed from them, read k times the
    truth: a rolling radius 1/k of the ECU's nominal); ``can_clock_offset_s`` c (CAN samples
    are stamped c later than the INS stamps the same instant: speed_CAN(t) = truth(t - c)).
    Outside the catalogue: ``gain_factor_second_half`` f (a heavier car: from half the
    duration on every zone's throttle and brake gains are f times the truth's).
    """

    pedal_delay_s: float = 0.0
    pedal_lag_s: float = 0.0
    steer_lag_s: float = 0.0
    rack_cubic_per_rad2: float = 0.0
    understeer_rad_per_mps2: float = 0.0
    st_C_Sf: float | None = None
    st_C_Sr: float | None = None
    drag_per_m: float = 0.0
    roll_per_s: float = 0.0
    grade_amp_rad: float = 0.0
    grade_wavelength_m: float = 300.0
    creep_accel_mps2: float = 0.0
    creep_speed_mps: float = 2.0
    wheel_scale: float = 1.0
    can_clock_offset_s: float = 0.0
    gain_factor_second_half: float = 1.0

    def grade_rad(self, s_m):
        """Road grade [rad] at distance travelled ``s_m``."""
        w = 2 * np.pi / self.grade_wavelength_m
        return self.grade_amp_rad * (0.6 * np.sin(w * s_m) + 0.4 * np.sin(w / 0.37 * s_m + 1.0))


G_MPS2 = 9.81  # the library's gravity (vehicle_dynamics_st)


def st_understeer_gradient(C_Sf: float, C_Sr: float, p=None) -> float:
    """Understeer gradient K [rad/(m/s^2)] of the single-track model with tyres: axle cornering
    stiffnesses C_f = mu C_Sf m g l_r / L, C_r = mu C_Sr m g l_f / L [N/rad] (static loads) in
    K = m / L (l_r / C_f - l_f / C_r) = (1 / C_Sf - 1 / C_Sr) / (mu g)."""
    p = p or vehicle_params()
    return (1.0 / C_Sf - 1.0 / C_Sr) / (p.tire.p_dy1 * G_MPS2)


def st_C_Sf_for(K: float, p=None) -> float:
    """Front C_Sf [1/rad] giving understeer gradient K with the library's rear C_Sr."""
    p = p or vehicle_params()
    C_Sr = -p.tire.p_ky1 / p.tire.p_dy1
    return 1.0 / (K * p.tire.p_dy1 * G_MPS2 + 1.0 / C_Sr)


def _st_rhs(x, u, p, C_Sf, C_Sr):
    """``vehicle_dynamics_st`` with separate front and rear cornering coefficients (the library
    takes both from ``p.tire.p_ky1``); the same equations, including its kinematic switch
    below 0.1 m/s, which is delegated to the library."""
    if abs(x[3]) < 0.1:
        return vehicle_dynamics_st(x, u, p)
    g, mu = G_MPS2, p.tire.p_dy1
    lf, lr, h, m, I_z = p.a, p.b, p.h_s, p.m, p.I_z
    u1, u2 = u
    Ff, Fr = C_Sf * (g * lr - u2 * h), C_Sr * (g * lf + u2 * h)
    L = lr + lf
    return [
        x[3] * math.cos(x[6] + x[4]),
        x[3] * math.sin(x[6] + x[4]),
        u1,
        u2,
        x[5],
        -mu * m / (x[3] * I_z * L) * (lf**2 * Ff + lr**2 * Fr) * x[5]
        + mu * m / (I_z * L) * (lr * Fr - lf * Ff) * x[6]
        + mu * m / (I_z * L) * lf * Ff * x[2],
        (mu / (x[3] ** 2 * L) * (Fr * lr - Ff * lf) - 1) * x[5]
        - mu / (x[3] * L) * (Fr + Ff) * x[6]
        + mu / (x[3] * L) * Ff * x[2],
    ]


@dataclass(frozen=True)
class Scenario:
    """One recording: model family, reference point of the INS, duration, seed, sensors."""

    truth: Truth
    #: "ks" (kinematic single-track, rear axle) or "st" (single-track with tyres, CoG).
    model: str = "ks"
    #: "rear", "cog", "front" or a lever arm (x, y) [m] in body axes from the rear-axle centre.
    ref_point: object = "rear"
    duration_s: float = 240.0
    seed: int = 0
    sensors: Sensors = field(default_factory=Sensors)
    #: [m/s^2] lateral acceleration the steering schedule aims at (below hmpc's 4 m/s^2 limit).
    lat_accel_mps2: float = 2.5
    #: [rad] largest steering-wheel angle of the schedule (about 206 deg).
    sw_max_rad: float = 3.6
    #: kinematic model only: the speed the zone law accelerates, "front" (the front-axle
    #: centre, the report's eq. 1 point F: the report's family) or "rear" (the model's own
    #: state, the rear-axle speed; then the front-axle speed hmpc derives from the front wheels
    #: has d/dt = a / cos(delta) + v_R tan(delta) d(delta)/dt / cos(delta) instead).
    accel_point: str = "front"
    #: [s] steering dead time: the road wheels follow the recorded steering-wheel angle this
    #: much later (a multiple of the 10 ms step; 0 = the report's family, no dead time).
    steer_delay_s: float = 0.0
    #: concealed physics (:class:`Effects`; none by default)
    effects: Effects = field(default_factory=Effects)


def vehicle_params():
    """CommonRoad parameter set 2 (BMW 320i), with the car held at rest (no reversing)."""
    p = parameters_vehicle2()
    p.longitudinal.v_min = 0.0
    return p


def lever_arm_m(ref_point, p=None) -> tuple[float, float]:
    """(x, y) [m] of the reference point in body axes from the rear-axle centre."""
    p = p or vehicle_params()
    if isinstance(ref_point, str):
        if ref_point not in REF_POINTS:
            raise ValueError(f"ref_point must be one of {REF_POINTS} or (x, y), got {ref_point!r}")
        return {"rear": (0.0, 0.0), "cog": (p.b, 0.0), "front": (p.a + p.b, 0.0)}[ref_point]
    x, y = ref_point
    return float(x), float(y)


def geometry(p=None, *, ref_point=None) -> dict:
    """The geometry file's mapping (``vehicle:`` keys of models/params.py); with ``ref_point``
    also ``nav_lever_arm_m`` (CONVENTIONS' optional key)."""
    p = p or vehicle_params()
    veh = {
        "wheelbase_m": float(p.a + p.b),
        "track_front_m": float(p.T_f),
        "track_rear_m": float(p.T_r),
        "wheel_radius_m": float(p.R_w),
        "mass_kg": float(p.m),
        "cg_to_rear_axle_m": float(p.b),
        "source": "CommonRoad vehicle models, parameter set 2 (BMW 320i)",
    }
    if ref_point is not None:
        veh["nav_lever_arm_m"] = list(lever_arm_m(ref_point, p))
    return {"vehicle": veh}


# ---------------------------------------------------------------------------------- driver
def _speed_targets(rng: np.random.Generator, duration_s: float):
    """Piecewise-constant target speeds [m/s] with steering flags: stops, idle creep, low and
    high-zone cruising; the steering is active only in segments at 2.5-8 m/s."""
    segs = []
    t = 0.0
    pattern = [
        "stop",
        "low",
        "low",
        "idle",
        "high",
        "low",
        "stop",
        "high",
        "high",
        "idle",
        "low",
        "stop",
    ]
    k = 0
    while t < duration_s:
        kind = (
            pattern[k % len(pattern)]
            if k < len(pattern)
            else rng.choice(["stop", "idle", "low", "low", "high", "high"])
        )
        k += 1
        dur = float(rng.uniform(8.0, 14.0))
        if kind == "stop":
            v, steer = 0.0, False
            dur = float(rng.uniform(3.0, 5.0))
        elif kind == "idle":
            v, steer = float(rng.uniform(1.0, 1.8)), False
        elif kind == "low":
            v, steer = float(rng.uniform(2.6, 4.8)), bool(rng.random() < 0.75)
        else:
            v = float(rng.uniform(5.5, 13.0))
            steer = v <= 8.0 and bool(rng.random() < 0.6)
        segs.append((t, t + dur, v, steer))
        t += dur
    return segs


def _driver_profiles(sc: Scenario, n: int, rng: np.random.Generator):
    """Per 100 Hz step: the driver's reference speed and its rate, the steering gate,
    the steering-wheel schedule [rad], and a pedal dither."""
    dt = SIM_DT_S
    t = np.arange(n) * dt
    segs = _speed_targets(rng, sc.duration_s + 1.0)
    v_tgt = np.zeros(n)
    gate_raw = np.zeros(n)
    for t0, t1, v, steer in segs:
        m = (t >= t0) & (t < t1)
        v_tgt[m] = v
        gate_raw[m] = 1.0 if steer else 0.0
    # the driver's intended profile: rate-limited (+1.0 / -1.5 m/s^2)
    v_ref = np.zeros(n)
    for i in range(1, n):
        dv = np.clip(v_tgt[i] - v_ref[i - 1], -1.5 * dt, 1.0 * dt)
        v_ref[i] = v_ref[i - 1] + dv
    a_ref = np.gradient(v_ref, dt)
    # steering gate: 3 s raised-cosine ramps in and out of steering segments
    k = int(3.0 / dt)
    ker = 0.5 - 0.5 * np.cos(np.linspace(0, 2 * np.pi, 2 * k + 1))
    gate = np.clip(np.convolve(gate_raw, ker / ker.sum(), mode="same"), 0.0, 1.0)
    # unit steering schedule: a slow sine (0.045-0.06 Hz: both signs within every steering
    # segment) plus slower random sines, flattened at the tops to dwell at large angles
    f0, ph0 = rng.uniform(0.045, 0.06), rng.uniform(0, 2 * np.pi)
    f = rng.uniform(0.012, 0.03, 4)
    ph = rng.uniform(0, 2 * np.pi, 4)
    s = 1.3 * np.sin(2 * np.pi * f0 * t + ph0) + 0.1 * np.sin(
        2 * np.pi * f[:, None] * t[None, :] + ph[:, None]
    ).sum(0)
    s = np.clip(s, -1.0, 1.0)
    s = np.convolve(s, np.ones(101) / 101, mode="same")  # round the clipped tops (1 s)
    L = VEH_L_M
    v_env = np.maximum(np.convolve(v_ref, np.ones(301) / 301, mode="same") + 0.5, 2.0)
    env = np.minimum(
        sc.sw_max_rad, np.arctan(sc.lat_accel_mps2 * L / v_env**2) / abs(sc.truth.steer_scale)
    )
    sw_straight = -sc.truth.steer_offset_rad / sc.truth.steer_scale
    sw = sw_straight + gate * env * s
    # pedal dither: 0.2-1 Hz sines, +-0.03 (a foot is not a servo)
    fd = rng.uniform(0.2, 1.0, 4)
    pd = rng.uniform(0, 2 * np.pi, 4)
    dither = 0.015 * np.sin(2 * np.pi * fd[:, None] * t[None, :] + pd[:, None]).sum(0)
    return v_ref, a_ref, sw, dither


class PIDriver:
    """Speed-tracking PI driver: acceleration demand -> coast, throttle or brake.

    The pedal mapping is the driver's rough belief (2.5 m/s^2 per unit throttle, 7 m/s^2 per
    unit brake, 0.1 throttle to hold speed), not the truth; the integral corrects it. The
    driver is on the throttle above a demand of +0.05 m/s^2, brakes below -0.45 m/s^2 and
    releases the brake above -0.15 m/s^2 (hysteresis), coasts in between; the foot follows
    with a 0.15 s lag.
    """

    kp_per_s = 0.8
    ki_per_s2 = 0.2
    tau_foot_s = 0.15

    def __init__(self, dt_s: float):
        self.dt = dt_s
        self.integ = 0.0
        self.mode = "coast"
        self.ap = 0.0
        self.bp = 0.0

    def step(self, v_ref: float, a_ref: float, v: float, dither: float) -> tuple[float, float]:
        e = v_ref - v
        if v_ref <= 0.0 and v < 0.3:
            # hold the car at rest
            self.integ = 0.0
            self.mode = "brake"
            ap_t, bp_t = 0.0, 0.3
        else:
            self.integ = float(np.clip(self.integ + e * self.dt, -2.0, 2.0))
            u = a_ref + self.kp_per_s * e + self.ki_per_s2 * self.integ
            if self.mode == "brake":
                if u > -0.15:
                    self.mode = "coast"
            elif u < -0.45:
                self.mode = "brake"
            if self.mode != "brake":
                self.mode = "throttle" if u > 0.05 else "coast"
            if self.mode == "throttle":
                ap_t, bp_t = float(np.clip(0.1 + u / 2.5 + dither, 0.0, 1.0)), 0.0
            elif self.mode == "brake":
                ap_t, bp_t = 0.0, float(np.clip(-u / 7.0 + dither, 0.0, 1.0))
            else:
                ap_t, bp_t = 0.0, 0.0
        g = self.dt / (self.tau_foot_s + self.dt)
        self.ap += g * (ap_t - self.ap)
        self.bp += g * (bp_t - self.bp)
        # a released pedal reads exactly zero
        if ap_t == 0.0 and self.ap < 0.004:
            self.ap = 0.0
        if bp_t == 0.0 and self.bp < 0.004:
            self.bp = 0.0
        return self.ap, self.bp


# ------------------------------------------------------------------------------ simulation
@dataclass
class Run:
    """The true states at the 100 Hz simulation steps (SI units; body axes ISO 8855)."""

    t: np.ndarray
    state: np.ndarray  # model state per step
    delta: np.ndarray  # road-wheel angle [rad]
    delta_rate: np.ndarray  # [rad/s] over the step that starts here
    sw: np.ndarray  # steering-wheel angle [rad]
    ap: np.ndarray
    bp: np.ndarray
    v_front: np.ndarray  # front-axle-centre speed [m/s] (KS: exact eq. 1 speed)
    accel_truth: np.ndarray  # zone law's acceleration [m/s^2] applied over the step
    model: str
    accel_point: str = "front"
    s: np.ndarray | None = None  # distance travelled [m] (rear axle / CoG)
    ap_eff: np.ndarray | None = None  # pedals as the powertrain and brakes act on them
    bp_eff: np.ndarray | None = None


def _rk4(f, x, h):
    k1 = f(x)
    k2 = f([xi + 0.5 * h * ki for xi, ki in zip(x, k1)])
    k3 = f([xi + 0.5 * h * ki for xi, ki in zip(x, k2)])
    k4 = f([xi + h * ki for xi, ki in zip(x, k3)])
    return [xi + h / 6.0 * (a + 2 * b + 2 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4)]


def _lag(x: np.ndarray, tau_s: float, dt: float) -> np.ndarray:
    """First-order lag 1 / (tau s + 1) of a signal held over each step (exact discretisation),
    starting at rest on its first value."""
    if tau_s <= 0:
        return x
    al = 1.0 - math.exp(-dt / tau_s)
    out = np.empty_like(x)
    y = x[0]
    for i in range(len(x)):
        out[i] = y  # the output during step i: what the lag has reached so far
        y = y + al * (x[i] - y)
    return out


def _steps(name: str, value_s: float, dt: float) -> int:
    k = int(round(value_s / dt))
    if abs(k * dt - value_s) > 1e-9:
        raise ValueError(f"{name} must be a multiple of {dt} s, got {value_s}")
    return k


def simulate(sc: Scenario) -> Run:
    """Integrate the CommonRoad model under the PI driver (seeded by ``sc.seed``)."""
    if sc.model not in ("ks", "st"):
        raise ValueError(f"model must be 'ks' or 'st', got {sc.model!r}")
    if sc.accel_point not in ("front", "rear"):
        raise ValueError(f"accel_point must be 'front' or 'rear', got {sc.accel_point!r}")
    rng = np.random.default_rng(sc.seed)
    p = vehicle_params()
    fx = sc.effects
    dt = SIM_DT_S
    L = p.a + p.b
    n = int(round(sc.duration_s / dt)) + 1
    v_ref, a_ref, sw, dither = _driver_profiles(sc, n, rng)
    tr = sc.truth
    k_delay = _steps("steer_delay_s", sc.steer_delay_s, dt)
    if k_delay < 0:
        raise ValueError(f"steer_delay_s must be non-negative, got {sc.steer_delay_s}")
    sw_wheels = np.concatenate([np.full(k_delay, sw[0]), sw[: n - k_delay]]) if k_delay else sw
    sw_wheels = _lag(sw_wheels, fx.steer_lag_s, dt)
    sw_rack = sw_wheels + fx.rack_cubic_per_rad2 * sw_wheels**3
    delta_map = tr.steer_offset_rad + tr.steer_scale * sw_rack
    d_rate_map = np.append(np.diff(delta_map) / dt, 0.0)
    if np.max(np.abs(d_rate_map)) > p.steering.v_max:
        raise ValueError("steering schedule faster than the model's steering-rate limit")
    if np.max(np.abs(delta_map)) > p.steering.max:
        raise ValueError("steering schedule beyond the model's steering-angle limit")
    K_us = fx.understeer_rad_per_mps2 if sc.model == "ks" else 0.0
    if sc.model == "ks" and (fx.st_C_Sf is not None or fx.st_C_Sr is not None):
        raise ValueError("st_C_Sf / st_C_Sr are tyre parameters of the model 'st'")
    if sc.model == "st" and fx.understeer_rad_per_mps2:
        raise ValueError("the model 'st' understeers through its tyres (st_C_Sf, st_C_Sr)")
    C_lib = -p.tire.p_ky1 / p.tire.p_dy1
    C_Sf = C_lib if fx.st_C_Sf is None else fx.st_C_Sf
    C_Sr = C_lib if fx.st_C_Sr is None else fx.st_C_Sr
    k_ped = _steps("pedal_delay_s", fx.pedal_delay_s, dt)
    al_ped = 1.0 - math.exp(-dt / fx.pedal_lag_s) if fx.pedal_lag_s > 0 else 1.0
    t_change = 0.5 * sc.duration_s
    driver = PIDriver(dt)
    nx = 5 if sc.model == "ks" else 7
    X = np.zeros((n, nx))
    x = [0.0] * nx
    x[2] = delta_map[0]
    ap_a, bp_a, vF_a, acc_a, s_a, delta, d_rate = (np.zeros(n) for _ in range(7))
    ape_a, bpe_a = np.zeros(n), np.zeros(n)
    pe = [0.0, 0.0]  # pedals as the powertrain and brakes see them (after delay, lag)
    s_m = 0.0

    def law(v, ap, bp, zi, gf, s_now):
        """The applied acceleration [m/s^2] on the zone law's speed ``v``."""
        a0 = tr.accel_mps2(v, 0.0, 0.0, zi)
        a = a0 + gf * (tr.accel_mps2(v, ap, bp, zi) - a0)
        a -= fx.drag_per_m * v * v + fx.roll_per_s * v
        if fx.creep_accel_mps2 and ap < 0.01:
            a += fx.creep_accel_mps2 * max(0.0, 1.0 - v / fx.creep_speed_mps)
        if fx.grade_amp_rad:
            a -= G_MPS2 * math.sin(float(fx.grade_rad(s_now)))
        return a

    def steer_eff(i, v_rear):
        return delta_map[i] * L / (L + K_us * v_rear * v_rear) if K_us else delta_map[i]

    for i in range(n):
        delta[i] = steer_eff(i, x[3])
        x[2] = float(delta[i])  # the steering state is the truth map exactly (piecewise linear)
        X[i] = x
        s_a[i] = s_m
        if sc.model == "ks":
            vF = x[3] / math.cos(x[2])
        else:
            vF = x[3]
        v_law = vF if sc.model == "ks" and sc.accel_point == "front" else x[3]
        ap, bp = driver.step(v_ref[i], a_ref[i], v_law, dither[i])
        ap_a[i], bp_a[i], vF_a[i] = ap, bp, vF
        j = i - k_ped
        ap_d, bp_d = (ap_a[j], bp_a[j]) if j >= 0 else (0.0, 0.0)
        pe[0] += al_ped * (ap_d - pe[0]) if fx.pedal_lag_s > 0 else ap_d - pe[0]
        pe[1] += al_ped * (bp_d - pe[1]) if fx.pedal_lag_s > 0 else bp_d - pe[1]
        ape, bpe = pe
        ape_a[i], bpe_a[i] = ape, bpe
        gf = fx.gain_factor_second_half if i * dt >= t_change else 1.0
        zi = tr.zone_index(v_law)  # the zone holds over the step (no blend inside RK4)
        s_now = s_m
        acc_a[i] = law(v_law, ape, bpe, zi, gf, s_now)
        if i == n - 1:
            break
        u1 = float(steer_eff(i + 1, x[3]) - delta[i]) / dt
        d_rate[i] = u1
        if sc.model == "ks" and sc.accel_point == "rear":

            def f(xs, ape=ape, bpe=bpe, u1=u1, zi=zi, gf=gf, s_now=s_now):
                u2 = law(xs[3], ape, bpe, zi, gf, s_now)
                if xs[3] <= 0.0 and u2 < 0.0:
                    u2 = 0.0
                return vehicle_dynamics_ks(xs, [u1, u2], p)
        elif sc.model == "ks":

            def f(xs, ape=ape, bpe=bpe, u1=u1, zi=zi, gf=gf, s_now=s_now):
                vf = xs[3] / math.cos(xs[2])
                a = law(vf, ape, bpe, zi, gf, s_now)
                u2 = a * math.cos(xs[2]) - vf * math.sin(xs[2]) * u1
                if xs[3] <= 0.0 and u2 < 0.0:
                    u2 = 0.0
                return vehicle_dynamics_ks(xs, [u1, u2], p)
        else:

            def f(xs, ape=ape, bpe=bpe, u1=u1, zi=zi, gf=gf, s_now=s_now):
                a = law(xs[3], ape, bpe, zi, gf, s_now)
                if xs[3] <= 0.0 and a < 0.0:
                    a = 0.0
                return _st_rhs(xs, [u1, a], p, C_Sf, C_Sr)

        nsub = 1
        if sc.model == "st" and 0.1 <= x[3] < 1.5:
            # the tyre terms' eigenvalues grow as ~ -215/v [1/s] (parameter set 2), and RK4 is
            # stable for h |lambda| < 2.78: substeps of at most 0.01 v [s] keep it well inside
            nsub = int(math.ceil(dt / (0.01 * x[3] + 1e-4)))
        h = dt / nsub
        v0 = x[3]
        for _ in range(nsub):
            x = _rk4(f, x, h)
            if x[3] < 0.0:
                x[3] = 0.0
                if sc.model == "st":
                    x[5] = 0.0
                    x[6] = 0.0
        s_m += 0.5 * (v0 + x[3]) * dt
    # the library's acceleration limits must never bind, or the truth would not be the law
    lon = p.longitudinal
    pos_limit = lon.a_max * lon.v_switch / np.maximum(X[:, 3], lon.v_switch)
    if np.any(acc_a > 0.9 * pos_limit) or np.any(acc_a < -0.9 * lon.a_max):
        raise ValueError("the zone law reaches the model's acceleration limits")
    return Run(
        np.arange(n) * dt,
        X,
        delta,
        d_rate,
        sw,
        ap_a,
        bp_a,
        vF_a,
        acc_a,
        sc.model,
        sc.accel_point,
        s_a,
        ape_a,
        bpe_a,
    )


def _kinematics(run: Run, p, ref_xy):
    """World position, heading, body velocity and body acceleration of the reference point,
    yaw rate, and the four wheel speeds, per simulation step."""
    L = p.a + p.b
    X = run.state
    psi = X[:, 4]
    delta = run.delta
    if run.model == "ks":
        vR = X[:, 3]
        r = vR * np.tan(delta) / L
        # rear-axle centre: body velocity (vR, 0)
        vx0, vy0 = vR, np.zeros_like(vR)
        o_x, o_y = 0.0, 0.0  # origin of the state's position: rear-axle centre
        # body acceleration of the rear-axle centre and yaw acceleration, from the applied law
        if run.accel_point == "rear":
            vdot = run.accel_truth
        else:
            vdot = run.accel_truth * np.cos(delta) - run.v_front * np.sin(delta) * run.delta_rate
        vdot = np.where((vR <= 0.0) & (vdot < 0.0), 0.0, vdot)
        rdot = (vdot * np.tan(delta) + vR * run.delta_rate / np.cos(delta) ** 2) / L
        ax0, ay0 = vdot, vR * r
    else:
        v, beta = X[:, 3], X[:, 6]
        r = X[:, 5]
        vx0, vy0 = v * np.cos(beta), v * np.sin(beta)
        o_x, o_y = p.b, 0.0  # the state's position is the centre of gravity
        ax0 = ay0 = rdot = None
    px, py = ref_xy[0] - o_x, ref_xy[1] - o_y
    c, s = np.cos(psi), np.sin(psi)
    xw = X[:, 0] + c * px - s * py
    yw = X[:, 1] + s * px + c * py
    vpx, vpy = vx0 - r * py, vy0 + r * px
    if ax0 is not None:
        apx = ax0 - rdot * py - r * r * px
        apy = ay0 + rdot * px - r * r * py
    else:
        # body-frame acceleration of the point from its world velocity (central differences)
        vwx, vwy = c * vpx - s * vpy, s * vpx + c * vpy
        awx, awy = np.gradient(vwx, SIM_DT_S), np.gradient(vwy, SIM_DT_S)
        apx, apy = c * awx + s * awy, -s * awx + c * awy
    # wheels: contact points from the rear-axle centre, Ackermann steer angles at the front
    tan_d = np.tan(delta)
    wheels = {
        "fl": (L, p.T_f / 2),
        "fr": (L, -p.T_f / 2),
        "rl": (0.0, p.T_r / 2),
        "rr": (0.0, -p.T_r / 2),
    }
    ws = {}
    for k, (wx, wy) in wheels.items():
        qx, qy = wx - o_x, wy - o_y
        ux, uy = vx0 - r * qy, vy0 + r * qx
        ang = np.arctan2(L * tan_d, L - wy * tan_d) if k[0] == "f" else np.zeros_like(tan_d)
        ws[k] = ux * np.cos(ang) + uy * np.sin(ang)
    return {
        "x": xw,
        "y": yw,
        "heading": psi,
        "vx": vpx,
        "vy": vpy,
        "ax": apx,
        "ay": apy,
        "yaw_rate": r,
        "wheels": ws,
    }


def _quantise(x, step):
    return np.round(np.asarray(x) / step) * step


def _steer_can_rad(sw_rad: np.ndarray, coarse_deg: float, fine_deg: float) -> np.ndarray:
    """STEER_ANGLE (coarse steps) + STEER_FRACTION (fine steps, |frac| <= 0.7 deg)."""
    deg = np.degrees(sw_rad)
    coarse = np.round(deg / coarse_deg) * coarse_deg
    frac = np.clip(np.round((deg - coarse) / fine_deg) * fine_deg, -0.7, 0.7)
    return np.radians(coarse + frac)


def record(sc: Scenario, run: Run | None = None) -> dict[str, np.ndarray]:
    """The canonical channels of the recording (dict name -> array), absent groups left out."""
    run = run or simulate(sc)
    p = vehicle_params()
    sen = sc.sensors
    kin = _kinematics(run, p, lever_arm_m(sc.ref_point, p))
    every = int(round(1.0 / (sen.rate_hz * SIM_DT_S)))
    idx = np.arange(0, len(run.t), every)
    rng = np.random.default_rng(sc.seed + 1_000_003)
    fx = sc.effects
    ch: dict[str, np.ndarray] = {"time": run.t[idx]}
    # CAN samples stamped at t hold the car at t - c (c = CAN clock minus INS clock)
    k_off = int(round(fx.can_clock_offset_s / SIM_DT_S))
    ic = np.clip(idx - k_off, 0, len(run.t) - 1)
    ch["steering_wheel_angle"] = _steer_can_rad(run.sw[ic], sen.sw_coarse_deg, sen.sw_fine_deg)
    ws_true = {k: fx.wheel_scale * np.maximum(v[ic], 0.0) for k, v in kin["wheels"].items()}
    wsq = {k: _quantise(v, sen.wheel_speed_step_mps) for k, v in ws_true.items()}
    for k in ("fl", "fr", "rl", "rr"):
        ch[f"wheel_speed_{k}"] = wsq[k]
    ch["speed"] = _quantise(np.mean(list(ws_true.values()), axis=0), sen.wheel_speed_step_mps)
    ch["accel_pedal"] = _quantise(run.ap[ic], sen.pedal_step)
    ch["brake_pedal"] = _quantise(run.bp[ic], sen.brake_step)
    m = len(idx)
    ch["yaw_rate"] = kin["yaw_rate"][idx] + sen.yaw_noise_radps * rng.standard_normal(m)
    ch["accel_x"] = kin["ax"][idx] + sen.accel_noise_mps2 * rng.standard_normal(m)
    ch["accel_y"] = kin["ay"][idx] + sen.accel_noise_mps2 * rng.standard_normal(m)
    ch["x"] = kin["x"][idx] + sen.pos_noise_m * rng.standard_normal(m)
    ch["y"] = kin["y"][idx] + sen.pos_noise_m * rng.standard_normal(m)
    hd = kin["heading"][idx] + sen.heading_noise_rad * rng.standard_normal(m)
    ch["heading"] = np.angle(np.exp(1j * hd))  # wrapped to (-pi, pi]
    ch["gps_speed"] = np.hypot(
        kin["vx"][idx], kin["vy"][idx]
    ) + sen.gps_speed_noise_mps * rng.standard_normal(m)
    if fx.grade_amp_rad and run.s is not None:
        # the road profile: altitude z(s) = int sin(theta) ds, pitch = theta (nose up uphill)
        th = fx.grade_rad(run.s)
        z = np.concatenate([[0.0], np.cumsum(np.diff(run.s) * np.sin(0.5 * (th[1:] + th[:-1])))])
        rz = np.random.default_rng(sc.seed + 2_000_003)
        ch["z"] = z[idx] + sen.pos_noise_m * rz.standard_normal(m)
        ch["pitch"] = th[idx] + sen.heading_noise_rad * rz.standard_normal(m)
    for g in sen.omit:
        for c in GROUPS[g]:
            ch.pop(c, None)
    return ch


def write_recording(
    channels: dict[str, np.ndarray], path: str | Path, columns: tuple[str, ...] = COLUMNS
) -> Path:
    """Write a canonical recording CSV (CONVENTIONS column names in the order of ``columns``;
    absent = no column)."""
    path = Path(path)
    names = [c for c in columns if c in channels]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        cols = [[f"{v:.6f}" for v in channels["time"]]] + [
            [repr(float(v)) for v in channels[c]] for c in names[1:]
        ]
        w.writerows(zip(*cols))
    return path


def write_geometry(path: str | Path, *, ref_point=None) -> Path:
    """Write the geometry YAML (with ``nav_lever_arm_m`` only when ``ref_point`` is given)."""
    path = Path(path)
    path.write_text(yaml.safe_dump(geometry(ref_point=ref_point), sort_keys=False))
    return path


def make(out_dir: str | Path, name: str, sc: Scenario) -> tuple[Path, Path]:
    """Simulate ``sc`` and write ``NAME.csv`` and ``NAME.geometry.yaml`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec = write_recording(record(sc), out / f"{name}.csv")
    geo = write_geometry(out / f"{name}.geometry.yaml")
    return rec, geo


def scenario(truth: str = "A", *, seed: int | None = None, **kw) -> Scenario:
    """A scenario for truth set ``truth`` ("A", "B", "C"); its seed defaults to one per set."""
    sens = {k: kw.pop(k) for k in list(kw) if k in Sensors.__dataclass_fields__}
    seeds = {"A": 11, "B": 22, "C": 33}
    return Scenario(
        TRUTHS[truth],
        seed=seeds[truth] if seed is None else seed,
        sensors=Sensors(**{**sens, "omit": frozenset(sens.get("omit", ()))}),
        **kw,
    )


__all__ = [
    "GROUPS",
    "TRUTHS",
    "Truth",
    "ZoneTruth",
    "Sensors",
    "Scenario",
    "REF_POINTS",
    "Effects",
    "st_understeer_gradient",
    "st_C_Sf_for",
    "simulate",
    "record",
    "write_recording",
    "write_geometry",
    "geometry",
    "make",
    "scenario",
    "lever_arm_m",
    "vehicle_params",
    "SIM_DT_S",
]
