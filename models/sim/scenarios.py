"""The report's experiments as named closed-loop scenarios: each a
:class:`~hmpc.models.reference.Reference`.

Named scenarios (section III of the report, plus one for idle speed):

- ``arcs``: clockwise arcs at 2.8 m/s, counter-clockwise at 2.4 m/s, the pair again at
  5.2 m/s, straight in between (III-A.1);
- ``circles``: near-full-lock circles, left then right (III-A.2);
- ``figure8``: figure eights at constant speed in the low zone (III-A.3);
- ``ramps``: straight, speed ramps 0-6-0, 0-4-0, 0-8-0 (III-B.1);
- ``ramp_sequence``: straight, 0-4-8-4-0 (III-B.2);
- ``idle_hold``: straight, hold 1.0 m/s (below the idle speed), then stop and go.

Speed corners are rounded by a moving average (jerk about 1.25 m/s^3, under the
ISO 15622 bound the controller enforces) and curvature changes are rate-limited to what
the steering rate limit can follow.
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Params
from hmpc.models.reference import Reference

#: scenario names accepted by :func:`make_scenario`.
SCENARIOS = ("arcs", "circles", "figure8", "ramps", "ramp_sequence", "idle_hold")

_SAMPLE_DT_S = 0.02  # reference sampling period [s] (the 50 Hz of a canonical recording)


# ---------------------------------------------------------------- building
def _smooth(v: np.ndarray, window_s: float) -> np.ndarray:
    n = max(int(round(window_s / _SAMPLE_DT_S)), 1)
    if n <= 1:
        return v
    pad = np.concatenate([np.full(n, v[0]), v, np.full(n, v[-1])])
    ker = np.ones(n) / n
    out = np.convolve(pad, ker, mode="same")[n:-n]
    return out


def _rate_limit(k: np.ndarray, rate_per_s: float) -> np.ndarray:
    out = np.empty_like(k)
    out[0] = k[0]
    step = rate_per_s * _SAMPLE_DT_S
    for i in range(1, len(k)):
        out[i] = out[i - 1] + max(-step, min(step, k[i] - out[i - 1]))
    return out


def _integrate(
    name: str, speed: np.ndarray, curv_of_s, heading0: float = 0.0, curv_rate_1pmps: float = 0.12
) -> Reference:
    """Integrate the front-point kinematics x' = v cos th, y' = v sin th, th' = v kappa(s).

    ``curv_rate_1pmps``: curvature rate limit [1/m per s]; 0.12 is under the 0.19 that the
    default steering rate (2 pi rad/s x scale 0.08 / wheelbase 2.65 m) can follow.
    """
    n = len(speed)
    t = np.arange(n) * _SAMPLE_DT_S
    ds = speed * _SAMPLE_DT_S
    s = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]))])
    kap_raw = np.array([curv_of_s(si) for si in s])
    kap = _rate_limit(kap_raw, curv_rate_1pmps)
    th = heading0 + np.concatenate([[0.0], np.cumsum(0.5 * (kap[1:] + kap[:-1]) * np.diff(s))])
    x = np.concatenate([[0.0], np.cumsum(np.diff(s) * np.cos(0.5 * (th[1:] + th[:-1])))])
    y = np.concatenate([[0.0], np.cumsum(np.diff(s) * np.sin(0.5 * (th[1:] + th[:-1])))])
    return Reference(t, x, y, th, speed, name=name, curvature_1pm=kap)


def _speed_profile(
    segments: list[tuple[float, float]],
    v0: float = 0.0,
    accel_mps2: float = 1.0,
    smooth_s: float = 0.8,
) -> np.ndarray:
    """Piecewise-linear speed: segments of (target speed [m/s], hold time [s]), ramps at
    ``accel_mps2``, corners rounded by a ``smooth_s`` moving average."""
    v = [v0]
    cur = v0
    for target, hold in segments:
        n_ramp = int(round(abs(target - cur) / accel_mps2 / _SAMPLE_DT_S))
        if n_ramp:
            v.extend(np.linspace(cur, target, n_ramp + 1)[1:])
        v.extend([target] * int(round(hold / _SAMPLE_DT_S)))
        cur = target
    return np.maximum(_smooth(np.array(v, dtype=float), smooth_s), 0.0)


def _lock_radius_m(params: Params | None, fraction: float) -> float:
    """Radius of a circle driven at ``fraction`` of full lock [m]."""
    b = params.vehicle.wheelbase_m if params is not None else 2.65
    off = params.steering.offset_rad if params is not None and params.steering else 0.017
    scale = params.steering.scale if params is not None and params.steering else 0.08
    sw_max = 2.5 * math.pi
    if params is not None:
        if params.limits is not None and params.limits.steering_wheel_angle_max_rad:
            sw_max = params.limits.steering_wheel_angle_max_rad
        elif params.vehicle.steering_wheel_angle_max_rad:
            sw_max = params.vehicle.steering_wheel_angle_max_rad
    delta = abs(scale) * sw_max * fraction - abs(off)  # the weaker side
    delta = max(min(delta, 1.2), 0.05)
    return b / math.sin(delta)


def _piecewise_curvature(pieces: list[tuple[float, float]]):
    """kappa(s) from pieces of (length [m], curvature [1/m]); 0 after the last."""
    edges = np.cumsum([p[0] for p in pieces])
    vals = [p[1] for p in pieces]

    def f(s: float) -> float:
        i = int(np.searchsorted(edges, s, side="right"))
        return vals[i] if i < len(vals) else 0.0

    return f


def make_scenario(name: str, params: Params | None = None) -> Reference:
    """The named scenario (see module doc). ``params`` sizes the full-lock circles."""
    if name == "ramp_sequence":
        v = _speed_profile([(4.0, 4.0), (8.0, 4.0), (4.0, 4.0), (0.0, 3.0)], v0=0.0)
        return _integrate(name, v, lambda s: 0.0)
    if name == "ramps":
        v = _speed_profile(
            [(6.0, 3.0), (0.0, 2.0), (4.0, 3.0), (0.0, 2.0), (8.0, 3.0), (0.0, 2.0)], v0=0.0
        )
        return _integrate(name, v, lambda s: 0.0)
    if name == "idle_hold":
        v = _speed_profile(
            [(1.0, 20.0), (0.0, 5.0), (1.0, 15.0), (0.0, 3.0)], v0=0.0, accel_mps2=0.25
        )
        return _integrate(name, v, lambda s: 0.0)
    if name == "arcs":
        # CW arcs (negative curvature) at 2.8 m/s, CCW at 2.4, the pair at 5.2 m/s; the
        # steering is set back to straight after each arc (III-A.1).
        v = _speed_profile(
            [
                (2.8, 3.0 + 10.0 + 3.0),
                (2.4, 3.0 + 10.0 + 3.0),
                (5.2, 3.0 + 7.0 + 3.0 + 7.0 + 3.0),
                (0.0, 2.0),
            ],
            v0=2.8,
        )
        t = np.arange(len(v)) * _SAMPLE_DT_S
        s = np.concatenate([[0.0], np.cumsum(v[1:] * _SAMPLE_DT_S)])
        s_of_t = lambda tt: float(np.interp(tt, t, s))  # noqa: E731
        # lengths from the speed profile: arc k starts at a time, lasts a time
        r1, r2 = 10.0, 25.0
        t_edges = [
            (3.0, 13.0, -1 / r1),
            (19.0, 29.0, 1 / r1),
            (35.5, 42.5, -1 / r2),
            (45.5, 52.5, 1 / r2),
        ]
        pieces = []
        last = 0.0
        for t0, t1, k in t_edges:
            s0, s1 = s_of_t(t0), s_of_t(t1)
            pieces += [(s0 - last, 0.0), (s1 - s0, k)]
            last = s1
        return _integrate(name, v, _piecewise_curvature(pieces))
    if name == "circles":
        r = _lock_radius_m(params, 0.8)
        vc = 2.5
        v = _speed_profile(
            [(vc, 4.0 + 2 * math.pi * r / vc + 4.0 + 2 * math.pi * r / vc + 3.0), (0.0, 2.0)],
            v0=0.0,
            accel_mps2=0.8,
        )
        lead = 0.5 * vc * vc / 0.8 + 4.0 * vc
        pieces = [(lead, 0.0), (2 * math.pi * r, 1 / r), (4.0 * vc, 0.0), (2 * math.pi * r, -1 / r)]
        return _integrate(name, v, _piecewise_curvature(pieces), curv_rate_1pmps=0.1)
    if name == "figure8":
        r, vc = 8.0, 3.5
        loop = 2 * math.pi * r
        v = _speed_profile([(vc, 3.0 + 2 * loop / vc + 3.0), (0.0, 2.0)], v0=vc)
        pieces = [(3.0 * vc, 0.0), (loop, 1 / r), (loop, -1 / r)]
        return _integrate(name, v, _piecewise_curvature(pieces))
    raise InputError(f"unknown scenario '{name}' (choose from {', '.join(SCENARIOS)})")
