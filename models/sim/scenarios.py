"""Reference trajectories for closed-loop runs: the report's experiments as named scenarios.

A :class:`Reference` is a time-indexed speed profile along a geometric path: samples of
time [s], x, y [m] (local ENU, the front-wheel point as in eq. 1), heading [rad] (the
path tangent, i.e. the direction of motion of the front wheel, from east,
counter-clockwise) and speed [m/s]. Controllers follow the speed in time and the path in
space: the lateral error is the distance to the path, not to a moving point.

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

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Params

#: scenario names accepted by :func:`make_scenario`.
SCENARIOS = ("arcs", "circles", "figure8", "ramps", "ramp_sequence", "idle_hold")

_SAMPLE_DT_S = 0.02  # reference sampling period [s] (the 50 Hz of a canonical recording)


@dataclass
class Reference:
    """A reference trajectory (arrays of equal length, time strictly increasing).

    Attributes:
        time_s, x_m, y_m, heading_rad, speed_mps: the samples (see module doc).
        name: scenario name or file path.
        curvature_1pm: path curvature at each sample [1/m] (computed when not given).
    """

    time_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    speed_mps: np.ndarray
    name: str = "reference"
    curvature_1pm: np.ndarray | None = None
    _path: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        arrs = [np.asarray(a, dtype=float) for a in
                (self.time_s, self.x_m, self.y_m, self.heading_rad, self.speed_mps)]
        n = len(arrs[0])
        if n < 2 or any(len(a) != n for a in arrs):
            raise ValueError("Reference needs >= 2 samples and arrays of equal length")
        if not all(np.all(np.isfinite(a)) for a in arrs):
            raise ValueError("Reference samples must be finite")
        if np.any(np.diff(arrs[0]) <= 0):
            raise ValueError("Reference time must be strictly increasing")
        if np.any(arrs[4] < 0):
            raise ValueError("Reference speed must be >= 0 (no reversing)")
        self.time_s, self.x_m, self.y_m, self.heading_rad, self.speed_mps = arrs
        self.heading_rad = np.unwrap(self.heading_rad)
        self._build_path()

    # ------------------------------------------------------------------ path
    def _build_path(self) -> None:
        """Arc-length parametrised path through the distinct positions."""
        dx, dy = np.diff(self.x_m), np.diff(self.y_m)
        ds = np.hypot(dx, dy)
        keep = np.concatenate([[True], ds > 1e-6])
        px, py, th = self.x_m[keep], self.y_m[keep], self.heading_rad[keep]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(px), np.diff(py)))])
        if self.curvature_1pm is not None:
            kap = np.asarray(self.curvature_1pm, dtype=float)[keep]
        elif len(s) >= 3:
            kap = np.gradient(th, s)
        else:
            kap = np.zeros(len(s))
        # arc length of every time sample (monotone: standstill samples share one value)
        s_time = np.concatenate([[0.0], np.cumsum(ds)])
        self._path = {"s": s, "x": px, "y": py, "th": th, "k": kap, "s_time": s_time}

    @property
    def length_m(self) -> float:
        return float(self._path["s"][-1])

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    def speed_at(self, t_s) -> np.ndarray:
        """Reference speed at time(s) t [m/s] (held beyond the ends)."""
        return np.interp(t_s, self.time_s, self.speed_mps)

    def s_at_time(self, t_s) -> np.ndarray:
        """Arc length the reference has reached at time t [m]."""
        return np.interp(t_s, self.time_s, self._path["s_time"])

    def point_at(self, s_m) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Path point at arc length(s) s: x [m], y [m], tangent [rad], curvature [1/m].

        Beyond the ends the path continues straight along the end tangent.
        """
        p = self._path
        s = np.asarray(s_m, dtype=float)
        ps = p["s"]
        if len(ps) == 1:
            th = np.full_like(s, p["th"][0])
            return (p["x"][0] + s * np.cos(th), p["y"][0] + s * np.sin(th), th,
                    np.zeros_like(s))
        sc = np.clip(s, ps[0], ps[-1])
        x = np.interp(sc, ps, p["x"])
        y = np.interp(sc, ps, p["y"])
        th = np.interp(sc, ps, p["th"])
        k = np.interp(sc, ps, p["k"])
        extra = s - sc
        x = x + extra * np.cos(th)
        y = y + extra * np.sin(th)
        k = np.where(extra != 0, 0.0, k)
        return x, y, th, k

    def project(self, x_m: float, y_m: float, s_hint_m: float, window_m: float = 10.0
                ) -> tuple[float, float]:
        """Closest path point to (x, y) within ``s_hint +- window``.

        Returns (s [m], signed lateral error [m], left of the path positive). The window
        keeps the projection on the right lap of a path that crosses itself.
        """
        p = self._path
        ps = p["s"]
        if len(ps) == 1:
            th = p["th"][0]
            dx, dy = x_m - p["x"][0], y_m - p["y"][0]
            return float(dx * math.cos(th) + dy * math.sin(th)), \
                float(-dx * math.sin(th) + dy * math.cos(th))
        i0 = int(np.searchsorted(ps, s_hint_m - window_m))
        i1 = int(np.searchsorted(ps, s_hint_m + window_m)) + 1
        i0 = max(min(i0, len(ps) - 2), 0)
        i1 = min(max(i1, i0 + 2), len(ps))
        ax, ay = p["x"][i0:i1 - 1], p["y"][i0:i1 - 1]
        bx, by = p["x"][i0 + 1:i1], p["y"][i0 + 1:i1]
        ex, ey = bx - ax, by - ay
        L2 = ex * ex + ey * ey
        tt = np.clip(((x_m - ax) * ex + (y_m - ay) * ey) / np.maximum(L2, 1e-12), 0.0, 1.0)
        # past the ends: extend straight
        if i1 - 1 == len(ps) - 1:
            tt[-1] = max(((x_m - ax[-1]) * ex[-1] + (y_m - ay[-1]) * ey[-1]) / max(L2[-1], 1e-12), 0.0)
        if i0 == 0:
            tt[0] = min(((x_m - ax[0]) * ex[0] + (y_m - ay[0]) * ey[0]) / max(L2[0], 1e-12), 1.0)
        cx, cy = ax + tt * ex, ay + tt * ey
        d2 = (x_m - cx) ** 2 + (y_m - cy) ** 2
        j = int(np.argmin(d2))
        L = math.sqrt(L2[j]) if L2[j] > 0 else 1.0
        s = ps[i0 + j] + tt[j] * L
        lat = ((y_m - cy[j]) * ex[j] - (x_m - cx[j]) * ey[j]) / L
        return float(s), float(lat)

    def lateral_errors(self, x_m: np.ndarray, y_m: np.ndarray, t_s: np.ndarray,
                       window_m: float = 10.0) -> np.ndarray:
        """Signed distance of a driven trajectory to the path [m], lap by lap."""
        out = np.empty(len(x_m))
        s = float(self.project(float(x_m[0]), float(y_m[0]), self.s_at_time(t_s[0]), 1e9)[0]) \
            if self.length_m < 2 * window_m else float(self.s_at_time(t_s[0]))
        for i in range(len(x_m)):
            s, out[i] = self.project(float(x_m[i]), float(y_m[i]), s, window_m)
        return out

    def initial_state(self, params: Params | None = None) -> np.ndarray:
        """Plant state [x, y, psi, v] that starts on the reference.

        psi is the tangent minus the road-wheel angle that follows the start curvature.
        """
        k0 = float(self._path["k"][0])
        delta = 0.0
        if params is not None:
            delta = math.asin(max(-0.99, min(0.99, k0 * params.vehicle.wheelbase_m)))
        return np.array([self.x_m[0], self.y_m[0], self.heading_rad[0] - delta, self.speed_mps[0]])


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


def _integrate(name: str, speed: np.ndarray, curv_of_s, heading0: float = 0.0,
               curv_rate_1pmps: float = 0.12) -> Reference:
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


def _speed_profile(segments: list[tuple[float, float]], v0: float = 0.0, accel_mps2: float = 1.0,
                   smooth_s: float = 0.8) -> np.ndarray:
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
        v = _speed_profile([(6.0, 3.0), (0.0, 2.0), (4.0, 3.0), (0.0, 2.0), (8.0, 3.0),
                            (0.0, 2.0)], v0=0.0)
        return _integrate(name, v, lambda s: 0.0)
    if name == "idle_hold":
        v = _speed_profile([(1.0, 20.0), (0.0, 5.0), (1.0, 15.0), (0.0, 3.0)], v0=0.0,
                           accel_mps2=0.25)
        return _integrate(name, v, lambda s: 0.0)
    if name == "arcs":
        # CW arcs (negative curvature) at 2.8 m/s, CCW at 2.4, the pair at 5.2 m/s; the
        # steering is set back to straight after each arc (III-A.1).
        v = _speed_profile([(2.8, 3.0 + 10.0 + 3.0), (2.4, 3.0 + 10.0 + 3.0),
                            (5.2, 3.0 + 7.0 + 3.0 + 7.0 + 3.0), (0.0, 2.0)], v0=2.8)
        t = np.arange(len(v)) * _SAMPLE_DT_S
        s = np.concatenate([[0.0], np.cumsum(v[1:] * _SAMPLE_DT_S)])
        s_of_t = lambda tt: float(np.interp(tt, t, s))  # noqa: E731
        # lengths from the speed profile: arc k starts at a time, lasts a time
        r1, r2 = 10.0, 25.0
        t_edges = [(3.0, 13.0, -1 / r1), (19.0, 29.0, 1 / r1), (35.5, 42.5, -1 / r2),
                   (45.5, 52.5, 1 / r2)]
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
        v = _speed_profile([(vc, 4.0 + 2 * math.pi * r / vc + 4.0 + 2 * math.pi * r / vc + 3.0),
                            (0.0, 2.0)], v0=0.0, accel_mps2=0.8)
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


def load_reference_csv(path: str | Path) -> Reference:
    """Read a reference CSV with columns time [s], x [m], y [m], speed [m/s] (heading [rad]
    optional; computed from the path when absent). Strict: unknown columns, non-numbers,
    non-finite values, time not increasing and negative speed raise InputError naming the
    file and line.
    """
    path = str(path)
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    if not rows:
        raise InputError("empty file", path)
    header = [h.strip() for h in rows[0]]
    allowed = {"time", "x", "y", "speed", "heading"}
    for h in header:
        if h not in allowed:
            raise InputError("unknown column (expected time, x, y, speed[, heading])", path,
                             line=1, channel=h)
    for need in ("time", "x", "y", "speed"):
        if need not in header:
            raise InputError("required column is missing", path, line=1, channel=need)
    cols: dict[str, list[float]] = {h: [] for h in header}
    for i, r in enumerate(rows[1:], start=2):
        if not r or all(not c.strip() for c in r):
            continue
        if len(r) != len(header):
            raise InputError(f"expected {len(header)} fields, found {len(r)}", path, line=i)
        for h, c in zip(header, r):
            try:
                val = float(c)
            except ValueError:
                raise InputError(f"value {c!r} is not a number", path, line=i, channel=h) from None
            if not math.isfinite(val):
                raise InputError(f"value {c!r} is not finite", path, line=i, channel=h)
            if h == "speed" and val < 0:
                raise InputError("speed must be >= 0", path, line=i, channel=h)
            cols[h].append(val)
        if len(cols["time"]) >= 2 and cols["time"][-1] <= cols["time"][-2]:
            raise InputError("time is not strictly increasing", path, line=i, channel="time")
    if len(cols["time"]) < 2:
        raise InputError("a reference needs at least 2 rows", path)
    t = np.array(cols["time"])
    x, y, v = np.array(cols["x"]), np.array(cols["y"]), np.array(cols["speed"])
    if "heading" in cols:
        th = np.array(cols["heading"])
    else:
        th = _heading_from_path(x, y)
    return Reference(t - t[0], x, y, th, v, name=path)


def _heading_from_path(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Tangent of the polyline; standstill samples take the heading of the next motion."""
    dx, dy = np.diff(x), np.diff(y)
    moving = np.hypot(dx, dy) > 1e-6
    th = np.zeros(len(x))
    if not moving.any():
        return th
    seg = np.arctan2(dy, dx)
    idx = np.flatnonzero(moving)
    # each sample takes the heading of the next moving segment (the last one at the end)
    nxt = np.searchsorted(idx, np.arange(len(x)), side="left")
    nxt = np.minimum(nxt, len(idx) - 1)
    th = np.unwrap(seg[idx[nxt]])
    return th


def save_reference_csv(ref: Reference, path: str | Path) -> None:
    """Write ``ref`` as time, x, y, heading, speed (readable by :func:`load_reference_csv`)."""
    with open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "x", "y", "heading", "speed"])
        for row in zip(ref.time_s, ref.x_m, ref.y_m, ref.heading_rad, ref.speed_mps):
            w.writerow([repr(float(v)) for v in row])
