"""The report's experiments (section III) as plans for the simulator's driver: speed and
steering references on the internal grid, built segment by segment (each labelled segment goes
into the recording's meta), or an open-loop pedal programme. ``EXPERIMENTS`` names and
describes them; ``PLANNERS`` builds each from the truth parameters, the internal step [s] and
the plan's random stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from hmpc.models.params import Params
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

#: full lock when the vehicle file has no steering_wheel_angle_max_rad: a RAV4 turns about
#: +-480 deg lock to lock (VerifiedCAN parked sweep, tools/data/rav4-2019-verifiedcan).
DEFAULT_SW_MAX_RAD = 8.4


@dataclass(frozen=True)
class Phase:
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


class Plan:
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
        self.program: list[Phase] | None = None  # open-loop pedal programme

    def add(
        self,
        label: str,
        dur_s: float,
        *,
        v_end: float | None = None,
        sw=0.0,
        low_gear: bool = False,
    ) -> None:
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
        self.segments.append(
            {
                "label": label,
                "t_start_s": round(self.n * self.dt, 6),
                "t_end_s": round((self.n + n) * self.dt, 6),
            }
        )
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
    assert p.steering is not None
    return (delta_rad - p.steering.offset_rad) / p.steering.scale


def sw_max_rad(p: Params) -> float:
    """Full lock [rad]: the vehicle file's ``steering_wheel_angle_max_rad``, else
    ``DEFAULT_SW_MAX_RAD``."""
    m = p.vehicle.steering_wheel_angle_max_rad
    return DEFAULT_SW_MAX_RAD if m is None else float(m)


def _plan_arcs(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    pl.add("standstill", 2.0, sw=0.0)
    blocks = (
        ("cw 2.8 m/s", 2.8, -1.0, (1.0, 2.0, 3.5, 5.0)),
        ("ccw 2.4 m/s", 2.4, +1.0, (1.0, 2.0, 3.5, 5.0)),
        ("cw 5.2 m/s", 5.2, -1.0, (0.6, 1.2, 2.0, 3.0)),
        ("ccw 5.2 m/s", 5.2, +1.0, (0.6, 1.2, 2.0, 3.0)),
    )
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


def _plan_circles(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    sw_max = sw_max_rad(p)
    b = p.vehicle.wheelbase_m
    pl.add("standstill", 2.0, sw=0.0)
    for v in (1.5, 3.5):
        pl.ramp(f"to {v} m/s", v, 0.6 if v > pl.v_now else 0.5, sw=0.0)
        pl.add(f"settle {v} m/s", 2.0, sw=0.0)
        for name, sign in (("cw", -1.0), ("ccw", +1.0)):
            lock = sign * sw_max
            assert p.steering is not None
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


def _plan_figure8(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    b = p.vehicle.wheelbase_m
    v = 3.5
    pl.add("standstill", 2.0, sw=0.0, low_gear=True)
    pl.ramp("to 3.5 m/s", v, 0.7, sw=0.0, low_gear=True)
    radii = rng.uniform(6.5, 10.0, 6)  # six loops: three figure eights
    levels = [
        _sw_for((1.0 if i % 2 == 0 else -1.0) * math.asin(b / r), p) for i, r in enumerate(radii)
    ]
    blend = 2.0  # [s] a human unwinds and winds the wheel over about 2 s
    prev = 0.0
    for i, (r, lev) in enumerate(zip(radii, levels)):
        loop_s = 2.0 * math.pi * r / v
        a0 = prev

        def prof(tau, a0=a0, lev=lev):
            w = 0.5 - 0.5 * np.cos(np.pi * np.clip(tau / blend, 0.0, 1.0))
            return a0 + (lev - a0) * w

        pl.add(
            f"figure8 loop {i + 1} ({'ccw' if lev > prev else 'cw'}, R {r:.1f} m)",
            loop_s,
            sw=prof,
            low_gear=True,
        )
        prev = lev
    pl.add(
        "unwind",
        3.0,
        low_gear=True,
        sw=lambda tau, a0=prev: a0 * (0.5 + 0.5 * np.cos(np.pi * np.clip(tau / 2.0, 0, 1))),
    )
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


def _plan_ramps(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    pl.add("standstill", 2.0, sw=None)
    pl.ramp("idle creep to 1 m/s", 1.0, 0.5, sw=None)
    pl.add("creep 1 m/s (braked against idle)", 4.0, sw=None)
    for top, acc in ((6.0, 0.6), (4.0, 0.5), (8.0, 0.7)):
        pl.ramp(f"ramp up to {top:.0f} m/s", top, acc, sw=None)
        pl.add(f"hold {top:.0f} m/s", 5.0, sw=None)
        pl.ramp(f"ramp down from {top:.0f} m/s", 0.0, acc, sw=None)
        pl.add("standstill", 2.0, sw=None)
    return pl


def _plan_ramp_sequence(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    pl.add("standstill", 2.0, sw=None)
    pl.ramp("idle creep to 1 m/s", 1.0, 0.5, sw=None)
    pl.add("creep 1 m/s (braked against idle)", 3.0, sw=None)
    for pace, acc, hold in (("gentle", 0.5, 4.0), ("brisk", 0.9, 3.0)):
        for v in (4.0, 8.0, 4.0, 0.0):
            pl.ramp(f"{pace} ramp {pl.v_now:.0f}-{v:.0f} m/s", v, acc, sw=None)
            pl.add(f"hold {v:.0f} m/s", hold if v > 0 else 2.0, sw=None)
    return pl


def _plan_open_loop(p: Params, dt: float, rng) -> Plan:
    pl = Plan(dt)
    # (kind, level, end condition): throttle until v >= v_mps or max_s; brake until at rest;
    # coast/hold for dur_s. Levels beat the idle creep of any plausible car (brake >= 0.2).
    pl.program = [
        Phase("hold", level=0.35, dur_s=2.0),
        Phase("throttle", level=0.25, v_mps=6.5, max_s=20.0),
        Phase("coast", dur_s=2.0),
        Phase("brake", level=0.20, max_s=30.0),
        Phase("hold", level=0.35, dur_s=2.0),
        Phase("throttle", level=0.12, v_mps=3.5, max_s=12.0),
        Phase("coast", dur_s=3.0),
        Phase("brake", level=0.25, max_s=30.0),
        Phase("hold", level=0.35, dur_s=2.0),
        Phase("throttle", level=0.45, v_mps=9.0, max_s=15.0),
        Phase("coast", dur_s=1.5),
        Phase("brake", level=0.12, v_mps=4.0, max_s=30.0),
        Phase("brake", level=0.40, max_s=30.0),
        Phase("hold", level=0.35, dur_s=2.0),
        Phase("sweep", level=0.05, level_end=0.40, v_mps=10.0, max_s=12.0),
        Phase("coast", dur_s=2.0),
        Phase("brake", level=0.15, v_mps=4.0, max_s=30.0),
        Phase("coast", dur_s=2.0),
        Phase("brake", level=0.30, max_s=30.0),
        Phase("hold", level=0.35, dur_s=2.0),
    ]
    return pl


PLANNERS = {
    "arcs": _plan_arcs,
    "circles": _plan_circles,
    "figure8": _plan_figure8,
    "ramps": _plan_ramps,
    "ramp_sequence": _plan_ramp_sequence,
    "open_loop": _plan_open_loop,
}
