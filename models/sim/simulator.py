"""hmpc's ground-truth simulator: the report's experiments (section III) on a known plant.

``simulate_experiment(name, params)`` drives the hybrid plant of ``models.plant`` (eqs. 1, 7
and 8 with the parameters you give, the truth) through one of the report's experiments and
returns a complete canonical recording: CAN channels quantised as the RAV4's DBC encodes them
and sent at the real message rates, INS channels with the noise of a survey-grade GNSS/INS
(``models.sensors``). ``meta`` holds the truth (parameters, seed, effects, segments, sensor
biases). Concealed physics (dead times, lags, drag, grade, wheel-radius error, clock offset)
is added with ``effects`` (``models.effects``); the default run has none.

How a run is made:

- The plant is stepped at an internal rate of at least 100 Hz that is a whole multiple of the
  output rate (100 Hz for the default 50 Hz), inputs held over each step.
- A driver produces the inputs. Steering: the steering wheel follows a reference (a scripted
  profile, or a human lane-keeper holding the road's direction with small random corrections)
  through a first-order lag of ``DriverConfig.steer_tau_s`` with a rate limit. Speed: a PI
  speed controller with feed-forward and a slow human-like dither, mapped to throttle OR brake
  (never both: one pedal is released to zero before the other is pressed) with pedal rate
  limits; at rest with a zero speed reference it holds the brake. The open-loop experiment
  plays a pedal programme instead (levels held until a speed is reached or the car stops).
- The truth zone is chosen by speed without hysteresis (``params.hysteresis_mps`` if the file
  sets it): zone (v_min, v_max] as in ``../shared/CONVENTIONS.md``, so identification by speed
  sees the model that acted. At rest the plant holds the car (no rolling backwards), so samples
  at v = 0 do not follow eq. 8.
- The INS reference point is the front-axle centre: eq. 1's (x, y). ENU origin at the start,
  initial heading drawn from the seed.

Noise levels: ``"typical"`` (quantisation, message rates, timing jitter, sensor noise and
biases), ``"quantised"`` (quantisation and message rates only, no random errors), ``"none"``
(ideal sensors: every channel is the truth at the grid time, nothing quantised or delayed;
eq. 1, 7 and 8 hold exactly on it, effects aside).

Runs are repeatable: the same name, parameters, seed, rate, noise and effects give an identical
recording (numpy ``SeedSequence(seed)`` feeds separate streams for plan, driver, CAN and INS).
A run takes about 0.1-0.2 s for 80-130 s of driving.

Building blocks for other runs (closed loops with hidden physics, diagnosis): :class:`TruthPlant`
(the hybrid plant plus effects, stepped by anyone) and :func:`measure` (CAN and INS sensors of
any truth on a uniform grid). ``run_experiment`` returns the recording with its truth
(:class:`SimRun`), ``coverage`` says what a run exercised (also in ``meta['coverage']``).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from hmpc.models.logs.channels import CHANNELS
from hmpc.models.sim.effect_base import Effect
from hmpc.models.errors import InputError, ParamError
from hmpc.models.params import Params, Steering, Vehicle, Zone
from hmpc.models.plant import HybridPlant, StepResult
from hmpc.models.logs.recording import Recording
from hmpc.models.sim import sensors as sn

#: experiment name -> what it does (the report's section III).
EXPERIMENTS: dict[str, str] = {
    "arcs": "III-A.1 steering reference steps, each returning to 0: clockwise at 2.8 m/s, "
            "counter-clockwise at 2.4 m/s, then the pair at 5.2 m/s",
    "circles": "III-A.2 steering ramped to full lock, one full circle held, back to straight: "
               "clockwise then counter-clockwise, at 1.5 m/s (idle creep, braked) and 3.5 m/s",
    "figure8": "III-A.3 figure eights at about 3.5 m/s in Low gear, human-like smooth steering "
               "and speed",
    "ramps": "III-B.1 speed ramps 0-6-0, 0-4-0 and 0-8-0 with holds (after an idle creep), "
             "steering near straight with small human corrections",
    "ramp_sequence": "III-B.2 speed ramp sequence 0-4, 4-8, 8-4, 4-0 with holds, twice (gentle, "
                     "then brisk), steering near straight",
    "open_loop": "III-B.3 throttle and brake open loop: accelerate, coast, brake to a halt, "
                 "repeated at several pedal levels and a slow throttle sweep",
}

NOISE_LEVELS = ("typical", "quantised", "none")
#: full lock when the vehicle file has no steering_wheel_angle_max_rad: a RAV4 turns about
#: +-480 deg lock to lock (VerifiedCAN parked sweep, ../shared/data/rav4-2019-verifiedcan).
DEFAULT_SW_MAX_RAD = 8.4
#: default geometry for random_params: the report's values (params/report_2008.yaml).
DEFAULT_VEHICLE = {"wheelbase_m": 2.65, "track_front_m": 1.6}
MIN_INTERNAL_RATE_HZ = 100.0


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


# ------------------------------------------------------------------------------ params
def random_params(seed: int, vehicle: Vehicle | None = None) -> Params:
    """A plausible random truth set for a car (seeded): what identification must recover.

    Steering offset uniform in +-0.03 rad, scale in 0.05..0.1. Zones idle [0,2], low (2,5],
    high (5,20] m/s: idle offset +0.15..+0.45 m/s^2 (idle creep), low -0.25..0.0 and high
    -0.45..-0.15 m/s^2 (rolling and aerodynamic drag); throttle scales 1.5..3.0 / 2.0..3.5 /
    2.0..3.5 m/s^2 per full pedal; brake scales 3..6 / 4..7 / 5..8 m/s^2 per full pedal.
    ``vehicle`` defaults to the report's geometry (wheelbase 2.65 m, track 1.6 m).
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))
    veh = vehicle if vehicle is not None else Vehicle(**DEFAULT_VEHICLE)
    u = lambda lo, hi: round(float(rng.uniform(lo, hi)), 4)  # noqa: E731 (readable table below)
    steering = Steering(offset_rad=u(-0.03, 0.03), scale=u(0.05, 0.10))
    table = (("idle", 0.0, 2.0, (0.15, 0.45), (1.5, 3.0), (3.0, 6.0)),
             ("low", 2.0, 5.0, (-0.25, 0.0), (2.0, 3.5), (4.0, 7.0)),
             ("high", 5.0, 20.0, (-0.45, -0.15), (2.0, 3.5), (5.0, 8.0)))
    zones = [Zone(name=n, v_min_mps=lo, v_max_mps=hi, offset_mps2=u(*o), scale_mps2=u(*s),
                  brake_scale_mps2=u(*b)) for n, lo, hi, o, s, b in table]
    return Params(vehicle=veh, steering=steering, zones=zones,
                  provenance={"source": "hmpc.models.sim.simulator.random_params", "seed": int(seed)})


# ------------------------------------------------------------------------------- plans
@dataclass(frozen=True)
class _Phase:
    """One phase of an open-loop pedal programme.

    ``throttle``: hold ``level`` until v >= ``v_mps`` or ``max_s`` [s]; ``sweep``: throttle
    from ``level`` to ``level_end`` over ``max_s``, until v >= ``v_mps``; ``brake``: hold
    ``level`` until v <= ``v_mps`` (0: at rest) or ``max_s``; ``coast`` (no pedal) and
    ``hold`` (brake ``level``) for ``dur_s``.
    """

    kind: str
    level: float = 0.0
    level_end: float = 0.0
    v_mps: float = 0.0
    max_s: float = 0.0
    dur_s: float = 0.0

    @property
    def longest_s(self) -> float:
        return self.dur_s if self.kind in ("coast", "hold") else self.max_s


class _Plan:
    """Speed and steering references on the internal grid, built segment by segment.

    ``sw`` of a segment: a number (steering-wheel angle [rad]), a callable of the segment's
    local time [s] returning angles, or None (human lane keeping).
    """

    def __init__(self, dt_s: float):
        self.dt = dt_s
        self.v: list[np.ndarray] = []
        self.a: list[np.ndarray] = []
        self.sw: list[np.ndarray] = []
        self.low_gear: list[np.ndarray] = []
        self.segments: list[dict] = []
        self.n = 0
        self.v_now = 0.0
        self.program: list[_Phase] | None = None  # open-loop pedal programme

    def add(self, label: str, dur_s: float, *, v_end: float | None = None, sw=0.0,
            low_gear: bool = False) -> None:
        n = max(int(round(dur_s / self.dt)), 1)
        tau = np.arange(n) * self.dt
        v0 = self.v_now
        v1 = v0 if v_end is None else float(v_end)
        dur = n * self.dt
        self.v.append(v0 + (v1 - v0) * tau / dur)
        self.a.append(np.full(n, (v1 - v0) / dur))
        if sw is None:
            self.sw.append(np.full(n, np.nan))
        elif callable(sw):
            self.sw.append(np.asarray(sw(tau), dtype=float))
        else:
            self.sw.append(np.full(n, float(sw)))
        self.low_gear.append(np.full(n, low_gear))
        self.segments.append({"label": label, "t_start_s": round(self.n * self.dt, 6),
                              "t_end_s": round((self.n + n) * self.dt, 6)})
        self.n += n
        self.v_now = v1

    def ramp(self, label: str, v_end: float, accel_mps2: float, **kw) -> None:
        self.add(label, abs(v_end - self.v_now) / accel_mps2, v_end=v_end, **kw)

    def arrays(self):
        cat = np.concatenate
        return cat(self.v), cat(self.a), cat(self.sw), cat(self.low_gear)


def _lin(a: float, b: float, dur_s: float):
    """Steering profile: linear from a to b over dur_s [rad]."""
    return lambda tau: a + (b - a) * np.clip(tau / dur_s, 0.0, 1.0)


def _sw_for(delta_rad: float, p: Params) -> float:
    """Steering-wheel angle [rad] that gives road-wheel angle ``delta_rad`` (eq. 7 inverted)."""
    return (delta_rad - p.steering.offset_rad) / p.steering.scale


def _sw_max(p: Params) -> float:
    m = p.vehicle.steering_wheel_angle_max_rad
    return DEFAULT_SW_MAX_RAD if m is None else float(m)


def _plan_arcs(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    pl.add("standstill", 2.0, sw=0.0)
    blocks = (("cw 2.8 m/s", 2.8, -1.0, (1.0, 2.0, 3.5, 5.0)),
              ("ccw 2.4 m/s", 2.4, +1.0, (1.0, 2.0, 3.5, 5.0)),
              ("cw 5.2 m/s", 5.2, -1.0, (0.6, 1.2, 2.0, 3.0)),
              ("ccw 5.2 m/s", 5.2, +1.0, (0.6, 1.2, 2.0, 3.0)))
    for label, v, sign, steps in blocks:
        if abs(pl.v_now - v) > 1e-9:
            pl.ramp(f"to {v} m/s", v, 0.8 if v > pl.v_now else 0.5, sw=0.0)
        pl.add(f"settle {v} m/s", 2.0, sw=0.0)
        for s in steps:
            pl.add(f"arc {label} step {sign * s:+.1f} rad", 3.0, sw=sign * s)
            pl.add(f"arc {label} back to 0", 2.5, sw=0.0)
    pl.ramp("brake to rest", 0.0, 1.0, sw=0.0)
    pl.add("standstill", 2.0, sw=0.0)
    return pl


def _plan_circles(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    sw_max = _sw_max(p)
    b = p.vehicle.wheelbase_m
    pl.add("standstill", 2.0, sw=0.0)
    for v in (1.5, 3.5):
        pl.ramp(f"to {v} m/s", v, 0.6 if v > pl.v_now else 0.5, sw=0.0)
        pl.add(f"settle {v} m/s", 2.0, sw=0.0)
        for name, sign in (("cw", -1.0), ("ccw", +1.0)):
            lock = sign * sw_max
            delta = abs(p.steering.offset_rad + p.steering.scale * lock)
            hold = 2.0 * math.pi * b / (v * math.sin(min(delta, 1.2)))  # one full circle
            pl.add(f"circle {name} {v} m/s ramp to lock", 4.0, sw=_lin(0.0, lock, 4.0))
            pl.add(f"circle {name} {v} m/s full lock", hold, sw=lock)
            pl.add(f"circle {name} {v} m/s back to straight", 4.0, sw=_lin(lock, 0.0, 4.0))
            pl.add(f"straight {v} m/s", 2.0, sw=0.0)
    pl.ramp("brake to rest", 0.0, 0.8, sw=0.0)
    pl.add("standstill", 2.0, sw=0.0)
    return pl


def _ou(rng, n: int, sigma: float, tau_s: float, dt_s: float) -> np.ndarray:
    return sn.gauss_markov(rng, n, sigma, tau_s, dt_s)


def _smooth_noise(rng, n: int, sigma: float, tau_s: float, dt_s: float) -> np.ndarray:
    """A smooth random signal (rms ``sigma``): Gauss-Markov ``tau_s`` through a second lag of
    ``tau_s / 2``, so its derivative is bounded (a human's speed wander, not white noise)."""
    x = _ou(rng, n, sigma, tau_s, dt_s)
    a = 1.0 - math.exp(-dt_s / (0.5 * tau_s))
    y = lfilter([a], [1.0, a - 1.0], x, zi=[(1.0 - a) * x[0]])[0] if n else x
    rms = float(np.sqrt(np.mean(y * y))) if n else 0.0
    return y * (sigma / rms) if rms > 0 else y


def _plan_figure8(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    b = p.vehicle.wheelbase_m
    v = 3.5
    pl.add("standstill", 2.0, sw=0.0, low_gear=True)
    pl.ramp("to 3.5 m/s", v, 0.7, sw=0.0, low_gear=True)
    radii = rng.uniform(6.5, 10.0, 6)  # six loops: three figure eights
    levels = [_sw_for((1.0 if i % 2 == 0 else -1.0) * math.asin(b / r), p)
              for i, r in enumerate(radii)]
    blend = 2.0  # [s] a human unwinds and winds the wheel over about 2 s
    prev = 0.0
    for i, (r, lev) in enumerate(zip(radii, levels)):
        loop_s = 2.0 * math.pi * r / v
        a0 = prev

        def prof(tau, a0=a0, lev=lev):
            w = 0.5 - 0.5 * np.cos(np.pi * np.clip(tau / blend, 0.0, 1.0))
            return a0 + (lev - a0) * w
        pl.add(f"figure8 loop {i + 1} ({'ccw' if lev > prev else 'cw'}, R {r:.1f} m)", loop_s,
               sw=prof, low_gear=True)
        prev = lev
    pl.add("unwind", 3.0, low_gear=True,
           sw=lambda tau, a0=prev: a0 * (0.5 + 0.5 * np.cos(np.pi * np.clip(tau / 2.0, 0, 1))))
    pl.ramp("brake to rest", 0.0, 0.8, sw=0.0, low_gear=True)
    pl.add("standstill", 2.0, sw=0.0, low_gear=True)
    v_ref, a_ref, sw, low = pl.arrays()
    # human: steering corrections and a speed that wanders a little around 3.5 m/s
    weight = np.clip(v_ref / v, 0.0, 1.0)  # the wander fades in and out with the speed
    sw_noise = _ou(rng, len(sw), 0.12, 0.8, dt)
    pl.sw = [np.where(v_ref > 0.5, sw + sw_noise, sw)]
    dv = _smooth_noise(rng, len(v_ref), 0.25, 4.0, dt) * weight
    pl.v = [v_ref + dv]
    pl.a = [a_ref + np.gradient(dv, dt)]
    pl.low_gear = [low]
    return pl


def _plan_ramps(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    pl.add("standstill", 2.0, sw=None)
    pl.ramp("idle creep to 1 m/s", 1.0, 0.5, sw=None)
    pl.add("creep 1 m/s (braked against idle)", 4.0, sw=None)
    for top, acc in ((6.0, 0.6), (4.0, 0.5), (8.0, 0.7)):
        pl.ramp(f"ramp up to {top:.0f} m/s", top, acc, sw=None)
        pl.add(f"hold {top:.0f} m/s", 5.0, sw=None)
        pl.ramp(f"ramp down from {top:.0f} m/s", 0.0, acc, sw=None)
        pl.add("standstill", 2.0, sw=None)
    return pl


def _plan_ramp_sequence(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    pl.add("standstill", 2.0, sw=None)
    pl.ramp("idle creep to 1 m/s", 1.0, 0.5, sw=None)
    pl.add("creep 1 m/s (braked against idle)", 3.0, sw=None)
    for pace, acc, hold in (("gentle", 0.5, 4.0), ("brisk", 0.9, 3.0)):
        for v in (4.0, 8.0, 4.0, 0.0):
            pl.ramp(f"{pace} ramp {pl.v_now:.0f}-{v:.0f} m/s", v, acc, sw=None)
            pl.add(f"hold {v:.0f} m/s", hold if v > 0 else 2.0, sw=None)
    return pl


def _plan_open_loop(p: Params, dt: float, rng) -> _Plan:
    pl = _Plan(dt)
    # (kind, level, end condition): throttle until v >= v_mps or max_s; brake until at rest;
    # coast/hold for dur_s. Levels beat the idle creep of any plausible car (brake >= 0.2).
    pl.program = [
        _Phase("hold", level=0.35, dur_s=2.0),
        _Phase("throttle", level=0.25, v_mps=6.5, max_s=20.0),
        _Phase("coast", dur_s=2.0),
        _Phase("brake", level=0.20, max_s=30.0),
        _Phase("hold", level=0.35, dur_s=2.0),
        _Phase("throttle", level=0.12, v_mps=3.5, max_s=12.0),
        _Phase("coast", dur_s=3.0),
        _Phase("brake", level=0.25, max_s=30.0),
        _Phase("hold", level=0.35, dur_s=2.0),
        _Phase("throttle", level=0.45, v_mps=9.0, max_s=15.0),
        _Phase("coast", dur_s=1.5),
        _Phase("brake", level=0.12, v_mps=4.0, max_s=30.0),
        _Phase("brake", level=0.40, max_s=30.0),
        _Phase("hold", level=0.35, dur_s=2.0),
        _Phase("sweep", level=0.05, level_end=0.40, v_mps=10.0, max_s=12.0),
        _Phase("coast", dur_s=2.0),
        _Phase("brake", level=0.15, v_mps=4.0, max_s=30.0),
        _Phase("coast", dur_s=2.0),
        _Phase("brake", level=0.30, max_s=30.0),
        _Phase("hold", level=0.35, dur_s=2.0),
    ]
    return pl


_PLANNERS = {"arcs": _plan_arcs, "circles": _plan_circles, "figure8": _plan_figure8,
             "ramps": _plan_ramps, "ramp_sequence": _plan_ramp_sequence,
             "open_loop": _plan_open_loop}


# ------------------------------------------------------------------------------ truth
@dataclass
class Truth:
    """The plant's truth on the internal grid (index k = time k * dt_s); inputs held over a step.

    Arrays: ``t_s``; state at the start of each step ``x_m, y_m, psi_rad, v_mps``; measured
    inputs ``sw_rad, accel_pedal, brake_pedal``; what the plant acted on after effects
    ``sw_eff_rad, accel_pedal_eff, brake_pedal_eff``; ``delta_rad`` (eq. 7 of sw_eff),
    ``yaw_rate_radps`` (eq. 1), ``zone`` (index into params.zones), ``accel_model_mps2``
    (eq. 8 of the effective pedals in that zone), ``accel_extra_mps2`` (effects),
    ``accel_mps2`` (applied, with the standstill clamp), ``grade_rad``, ``z_m``, ``low_gear``.
    """

    dt_s: float
    arrays: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __len__(self) -> int:
        return len(self.arrays["t_s"])


@dataclass
class SimRun:
    """A simulated recording with its truth.

    Attributes:
        recording: the canonical recording (what identification sees).
        truth: the plant's truth on the internal grid.
        grid_index: recording row i is truth index ``grid_index[i]`` (same instant).
    """

    recording: Recording
    truth: Truth
    grid_index: np.ndarray = field(repr=False)

    def truth_on_grid(self, name: str) -> np.ndarray:
        """A truth array at the recording's sample times."""
        return self.truth[name][self.grid_index]


def _check_args(name: str, params: Params, rate_hz: float, noise: str, effects) -> None:
    if name not in EXPERIMENTS:
        raise InputError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})",
                         None, key="experiment")
    if noise not in NOISE_LEVELS:
        raise InputError(f"unknown noise level {noise!r} (known: {', '.join(NOISE_LEVELS)})",
                         None, key="noise")
    if not isinstance(params, Params) or not params.is_model:
        raise ParamError("the simulator needs a complete model (steering and longitudinal zones)",
                         getattr(params, "path", None), key="steering")
    if params.steering.scale <= 0:
        raise ParamError("steering scale must be positive", params.path, key="steering.scale")
    if not (isinstance(rate_hz, numbers.Real) and math.isfinite(rate_hz)
            and 1.0 <= rate_hz <= 1000.0):
        raise ValueError(f"rate_hz must be within 1..1000 Hz, got {rate_hz!r}")
    for e in effects:
        if not isinstance(e, Effect):
            raise TypeError(f"effects must be models.effects.Effect instances, got {e!r}")


@dataclass
class TruthStep:
    """One step of :class:`TruthPlant`: the plant's result and what it acted on.

    Attributes:
        result: ``models.plant.StepResult`` (new state, zone, applied acceleration [m/s^2]).
        u_eff: inputs after the effects (steering-wheel angle [rad], accel pedal, brake pedal).
        accel_model_mps2: eq. 8 of ``u_eff`` in the zone used [m/s^2].
        accel_extra_mps2: the effects' extra acceleration [m/s^2].
    """

    result: StepResult
    u_eff: tuple[float, float, float]
    accel_model_mps2: float
    accel_extra_mps2: float


class TruthPlant:
    """The hybrid plant with concealed effects: what the experiments (and any closed loop that
    wants hidden physics) drive. Fixed step ``dt_s`` [s] (the effects' delays count steps).

    The zone is chosen by speed without hysteresis unless ``params.hysteresis_mps`` is set
    (a real car has no zone memory; identification assigns zones by speed).

    Args:
        params: the truth (complete model). effects: ``models.effects.Effect`` list (reset here).
        dt_s: step [s].
    """

    def __init__(self, params: Params, effects: list[Effect] | None = None, dt_s: float = 0.01):
        self.plant = HybridPlant(params, hysteresis_mps=(params.hysteresis_mps or 0.0))
        self.params = params
        self.dt_s = float(dt_s)
        self.effects = list(effects or [])
        for e in self.effects:
            e.start(self.dt_s, params)
        self.zone: int | None = None
        self._steer = [e for e in self.effects if type(e).steering is not Effect.steering]
        self._pedal = [e for e in self.effects if type(e).pedals is not Effect.pedals]
        self._accel = [e for e in self.effects
                       if type(e).accel_extra_mps2 is not Effect.accel_extra_mps2]
        self.grade_rad = float(sum(e.grade_rad() for e in self.effects))

    def step(self, state, u) -> TruthStep:
        """Advance one step from ``state`` (x, y, psi, v) with measured inputs ``u``
        (steering-wheel angle [rad], accel pedal, brake pedal) held over it."""
        sw_e, th_e, br_e = float(u[0]), float(u[1]), float(u[2])
        v = float(state[3])
        for e in self._steer:
            sw_e = e.steering(sw_e, v)
        for e in self._pedal:
            th_e, br_e = e.pedals(th_e, br_e)
        u_e = (sw_e, th_e, br_e)
        a_x = 0.0
        for e in self._accel:
            a_x += e.accel_extra_mps2(state, u_e)
        res = self.plant.step(state, u_e, self.dt_s, self.zone, a_x)
        self.zone = res.zone
        return TruthStep(res, u_e, self.plant.accel(res.zone, th_e, br_e), a_x)


def _phase_segment(ph: _Phase, t0_s: float, t1_s: float) -> dict:
    what = {"throttle": f"throttle {ph.level:.2f}", "sweep": f"throttle sweep {ph.level:.2f}-"
            f"{ph.level_end:.2f}", "brake": f"brake {ph.level:.2f}", "hold": f"hold brake "
            f"{ph.level:.2f} at rest", "coast": "coast (no pedal)"}[ph.kind]
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
_TRUTH_NAMES = ("x_m", "y_m", "psi_rad", "v_mps", "sw_rad", "sw_eff_rad", "accel_pedal",
                "brake_pedal", "accel_pedal_eff", "brake_pedal_eff", "zone", "accel_model_mps2",
                "accel_extra_mps2", "accel_mps2", "grade_rad")


def _drive_refs(plan: _Plan, dt: float, rng, driver: DriverConfig) -> _DriveRefs:
    """The references of ``plan`` and the driver's noise (drawn from ``rng`` in this order:
    dither, then lane-keeping noise)."""
    open_loop = plan.program is not None
    if open_loop:
        n_max = int(round(sum(ph.longest_s for ph in plan.program) / dt)) + 1
        v_ref = a_ref = np.zeros(0)
        sw_ref = np.full(n_max, np.nan)
        low = np.zeros(n_max, dtype=bool)
    else:
        v_ref, a_ref, sw_ref, low = plan.arrays()
        n_max = len(v_ref)
    dither = (np.zeros(n_max) if open_loop
              else _ou(rng, n_max, driver.dither, driver.dither_tau_s, dt))
    lane_noise = _ou(rng, n_max, driver.lane_noise_rad, driver.lane_noise_tau_s, dt)
    return _DriveRefs(open_loop, n_max, v_ref, a_ref, sw_ref, low, dither, lane_noise)


def _drive(params: Params, plan: _Plan, dt: float, rng, effects: list[Effect],
           driver: DriverConfig, psi0: float) -> Truth:
    """Run the driver and the plant; return the truth on the internal grid."""
    truth_plant = TruthPlant(params, effects, dt)
    plant = truth_plant.plant
    off, scl = plant.offset_rad, plant.scale
    sw_max = _sw_max(params)
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


def _programme_pedals(plan: _Plan, d: _DriverState, t: float,
                      v: float) -> tuple[float, float] | None:
    """The open-loop programme's pedal targets (throttle, brake) at time ``t`` [s] and speed
    ``v`` [m/s], advancing ``d``'s phase (and ``plan.segments``) as phases end; None when the
    programme has finished."""
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


def _speed_pedals(d: _DriverState, driver: DriverConfig, vr: float, v: float, a_ref: float,
                  dither: float, dt: float) -> tuple[float, float]:
    """The human speed controller's pedal targets (throttle, brake): hold the brake at rest,
    else feed-forward plus PI on the speed error with dither, through the pedal dead bands."""
    if vr <= 0.05 and v < 0.3:  # at rest: hold the car on the brake
        d.integ = 0.0
        return 0.0, driver.hold_brake
    err = vr - v
    i_max = _KI_LIMIT / driver.ki_per_m
    d.integ = min(max(d.integ + err * dt, -i_max), i_max)
    u = (driver.ff_per_mps2 * a_ref + driver.kp_per_mps * err
         + driver.ki_per_m * d.integ + dither)
    if u > driver.deadband:
        return min(u - driver.deadband, 1.0), 0.0
    if u < -driver.brake_deadband:
        return 0.0, min(-u - driver.brake_deadband, 1.0)
    return 0.0, 0.0


def _move_feet(d: _DriverState, want: tuple[float, float], t: float, driver: DriverConfig,
               dth_max: float, dbr_max: float) -> None:
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


def _truth(rec: dict[str, np.ndarray], n: int, dt: float, off: float, scl: float, b: float,
           low: np.ndarray) -> Truth:
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


# ---------------------------------------------------------------------------- sensors
def measure(truth: Truth, params: Params, rate_hz: float, noise: str, effects: list[Effect],
            rng_can: np.random.Generator, rng_ins: np.random.Generator
            ) -> tuple[dict, dict, dict, np.ndarray]:
    """What the car's CAN and the INS report about ``truth`` (``models.sensors``).

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
        raise ValueError(f"rate_hz {rate_hz} is not the truth rate {1 / dt:g} Hz over a whole "
                         "number")
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
    sensor_truth = {"can_clock_offset_s": c, "wheel_speed_scale": ws,
                    "yaw_rate_bias_radps": 0.0, "accel_x_bias_mps2": 0.0, "accel_y_bias_mps2": 0.0}
    ins = _measure_ins(tr, dt, b, noise, rng_ins, sensor_truth)
    for name, val in ins.items():
        raw[name] = (t.copy(), val)
        ch[name] = val[idx]  # the INS grid contains the output grid: hold = the sample itself
    ordered = {k: ch[k] for k in CHANNELS if k in ch}
    return ordered, raw, sensor_truth, idx


def _measure_can(tr: dict, veh, t_r: float, grid: np.ndarray, idx: np.ndarray, noise: str,
                 c: float, ws: float, rng_can: np.random.Generator, ch: dict, raw: dict) -> None:
    """The CAN channels of :func:`measure` into ``ch`` (on ``grid``) and ``raw`` (at message
    times): exact samples at ``noise="none"``, else periodic messages with random phase
    (and jitter and noise at ``"typical"``), DBC-quantised and held on the grid. ``c``: CAN
    clock offset [s]; ``ws``: wheel-speed scale."""
    t = tr["t_s"]
    # ---- CAN truth signals on the internal grid (continuous, SI)
    fl, fr, rl, rr = sn.wheel_speeds(tr["v_mps"], tr["delta_rad"], veh.wheelbase_m,
                                     veh.track_front_m, t_r)
    can_truth = {
        "steering_wheel_angle": tr["sw_rad"],
        "wheel_speed_fl": fl * ws, "wheel_speed_fr": fr * ws,
        "wheel_speed_rl": rl * ws, "wheel_speed_rr": rr * ws,
        "accel_pedal": tr["accel_pedal"], "brake_pedal": tr["brake_pedal"],
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


def _measure_ins(tr: dict, dt: float, b: float, noise: str, rng_ins: np.random.Generator,
                 sensor_truth: dict) -> dict[str, np.ndarray]:
    """The INS channels of :func:`measure` at the internal rate, reference point = the
    front-axle centre; at ``noise="typical"`` with ``InsNoise`` errors, whose biases are
    written into ``sensor_truth``."""
    t = tr["t_s"]
    ddelta = np.gradient(tr["delta_rad"], dt) if len(t) > 1 else np.zeros(len(t))
    ax, ay = sn.ins_body_accel(tr["v_mps"], tr["accel_mps2"], tr["delta_rad"], ddelta, b)
    ins = {"yaw_rate": tr["yaw_rate_radps"].copy(), "accel_x": ax, "accel_y": ay,
           "x": tr["x_m"].copy(), "y": tr["y_m"].copy(), "z": tr["z_m"].copy(),
           "heading": tr["psi_rad"].copy(),
           "pitch": tr["grade_rad"] + sn.PITCH_PER_ACCEL * ax,
           "roll": sn.ROLL_PER_LATERAL_ACCEL * ay,
           "gps_speed": tr["v_mps"].copy()}
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
        bias_ax, bias_ay = np.clip(rng_ins.normal(0.0, nz.accel_bias_mps2, 2),
                                   -nz.accel_bias_max_mps2, nz.accel_bias_max_mps2)
        ins["yaw_rate"] += bias_r + rng_ins.normal(0.0, nz.yaw_rate_radps, n)
        ins["accel_x"] += bias_ax + rng_ins.normal(0.0, nz.accel_mps2, n)
        ins["accel_y"] += bias_ay + rng_ins.normal(0.0, nz.accel_mps2, n)
        ins["gps_speed"] = np.abs(ins["gps_speed"] + rng_ins.normal(0.0, nz.gps_speed_mps, n))
        sensor_truth.update(yaw_rate_bias_radps=bias_r, accel_x_bias_mps2=float(bias_ax),
                            accel_y_bias_mps2=float(bias_ay))
    ins["heading"] = np.angle(np.exp(1j * ins["heading"]))  # wrap to (-pi, pi]
    ins["heading"][ins["heading"] <= -np.pi] = np.pi
    return ins


# -------------------------------------------------------------------------------- API
def run_experiment(name: str, params: Params, *, seed: int = 0, rate_hz: float = 50.0,
                   noise: str = "typical", effects: list[Effect] | None = None,
                   driver: DriverConfig | None = None) -> SimRun:
    """Simulate experiment ``name`` on the truth ``params``; return the recording and the truth.

    Args:
        name: a key of ``EXPERIMENTS``.
        params: the truth: a complete model (steering and zones); geometry from ``vehicle``
            (``track_rear_m`` defaults to ``track_front_m``, full lock to 8.4 rad).
        seed: seeds the driver's randomness, CAN phases/noise and INS noise (printed in meta).
        rate_hz: output grid rate [Hz].
        noise: ``"typical"``, ``"quantised"`` or ``"none"`` (module docstring).
        effects: concealed physics (``models.effects``); None or [] for none.
        driver: driver and speed-controller settings (default ``DriverConfig()``).

    Raises:
        InputError: unknown experiment or noise level. ParamError: incomplete params.
        ValueError: rate out of 1..1000 Hz.
    """
    effects = list(effects or [])
    _check_args(name, params, rate_hz, noise, effects)
    driver = driver or DriverConfig()
    m = max(int(math.ceil(MIN_INTERNAL_RATE_HZ / rate_hz - 1e-9)), 1)
    dt = 1.0 / (m * rate_hz)
    ss = np.random.SeedSequence(int(seed))
    rng_plan, rng_drive, rng_can, rng_ins = (np.random.default_rng(s) for s in ss.spawn(4))
    psi0 = float(rng_plan.uniform(-math.pi, math.pi))
    plan = _PLANNERS[name](params, dt, rng_plan)
    truth = _drive(params, plan, dt, rng_drive, effects, driver, psi0)
    ch, raw, sensor_truth, idx = measure(truth, params, rate_hz, noise, effects, rng_can, rng_ins)
    segments = plan.segments
    meta = {
        "source": "hmpc simulator (models.sim)",
        "experiment": name,
        "description": EXPERIMENTS[name],
        "seed": int(seed),
        "noise": noise,
        "rate_hz": float(rate_hz),
        "internal_rate_hz": float(m * rate_hz),
        "duration_s": float(ch["time"][-1]),
        "params": params.to_dict(),
        "effects": [e.describe() for e in effects],
        "sensor_truth": sensor_truth,
        "ins_point": "front-axle centre (the report's eq. 1 point)",
        "initial_heading_rad": psi0,
        "segments": segments,
        "gaps": [],
    }
    run = SimRun(Recording(ch, raw, meta), truth, idx)
    meta["coverage"] = coverage(run)
    return run


def simulate_experiment(name: str, params: Params, *, seed: int = 0, rate_hz: float = 50.0,
                        noise: str = "typical", effects: list[Effect] | None = None) -> Recording:
    """A complete canonical recording of experiment ``name`` on the truth ``params``.

    See :func:`run_experiment` for the arguments; ``meta`` holds the truth (``params``,
    ``seed``, ``experiment``, ``effects``, ``sensor_truth``, ``segments``, ``coverage``).
    """
    return run_experiment(name, params, seed=seed, rate_hz=rate_hz, noise=noise,
                          effects=effects).recording


def coverage(run: SimRun) -> dict:
    """What a run exercised, from the truth: per zone, seconds moving with throttle, brake or
    neither; steering-wheel angle range per speed band. JSON-friendly."""
    tr = run.truth.arrays
    dt = run.truth.dt_s
    zones = run.recording.meta["params"]["longitudinal"]["zones"]
    moving = tr["v_mps"] > 0.05
    th, br = tr["accel_pedal"] > 0, tr["brake_pedal"] > 0
    out_z = {}
    for i, z in enumerate(zones):
        inz = moving & (tr["zone"] == i)
        out_z[z["name"]] = {
            "moving_s": round(float(inz.sum() * dt), 2),
            "throttle_s": round(float((inz & th).sum() * dt), 2),
            "brake_s": round(float((inz & br).sum() * dt), 2),
            "coast_s": round(float((inz & ~th & ~br).sum() * dt), 2),
            "throttle_max": round(float(tr["accel_pedal"][inz].max()), 3) if inz.any() else 0.0,
            "brake_max": round(float(tr["brake_pedal"][inz].max()), 3) if inz.any() else 0.0,
        }
    bands = {}
    v = tr["v_mps"]
    for lo, hi in ((0.5, 2.0), (2.0, 5.0), (5.0, 20.0)):
        sel = (v > lo) & (v <= hi)
        if sel.any():
            bands[f"{lo:g}-{hi:g} m/s"] = {
                "sw_min_rad": round(float(tr["sw_rad"][sel].min()), 3),
                "sw_max_rad": round(float(tr["sw_rad"][sel].max()), 3),
                "seconds": round(float(sel.sum() * dt), 2)}
    return {"duration_s": round(float(len(v) * dt), 2), "v_max_mps": round(float(v.max()), 3),
            "zones": out_z, "steering_by_speed": bands}
