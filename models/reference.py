"""A reference for closed-loop control: a time-indexed speed profile along a geometric path.

A :class:`Reference` holds samples of time [s], x, y [m] (local ENU, the front-wheel point as
in eq. 1), heading [rad] (the path tangent, i.e. the direction of motion of the front wheel,
from east, counter-clockwise) and speed [m/s]. Controllers follow the speed in time and the
path in space: the lateral error is the distance to the path, not to a moving point.

A reference comes from a reference CSV (:func:`load_reference_csv`), from a recorded drive
(:func:`recording_reference`: the GNSS/INS path, or dead reckoning through eq. 7), from
either by file type (:func:`load_reference`), or from the simulator's named scenarios
(``models.sim.scenarios``). This module is what the controllers and the drive loop take;
it does not import the simulator.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.logs.channels import CHANNELS
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, heading_rate


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
        arrs = [
            np.asarray(a, dtype=float)
            for a in (self.time_s, self.x_m, self.y_m, self.heading_rad, self.speed_mps)
        ]
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
            return (p["x"][0] + s * np.cos(th), p["y"][0] + s * np.sin(th), th, np.zeros_like(s))
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

    def project(
        self, x_m: float, y_m: float, s_hint_m: float, window_m: float = 10.0
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
            return float(dx * math.cos(th) + dy * math.sin(th)), float(
                -dx * math.sin(th) + dy * math.cos(th)
            )
        i0 = int(np.searchsorted(ps, s_hint_m - window_m))
        i1 = int(np.searchsorted(ps, s_hint_m + window_m)) + 1
        i0 = max(min(i0, len(ps) - 2), 0)
        i1 = min(max(i1, i0 + 2), len(ps))
        ax, ay = p["x"][i0 : i1 - 1], p["y"][i0 : i1 - 1]
        bx, by = p["x"][i0 + 1 : i1], p["y"][i0 + 1 : i1]
        ex, ey = bx - ax, by - ay
        L2 = ex * ex + ey * ey
        tt = np.clip(((x_m - ax) * ex + (y_m - ay) * ey) / np.maximum(L2, 1e-12), 0.0, 1.0)
        # past the ends: extend straight
        if i1 - 1 == len(ps) - 1:
            tt[-1] = max(
                ((x_m - ax[-1]) * ex[-1] + (y_m - ay[-1]) * ey[-1]) / max(L2[-1], 1e-12), 0.0
            )
        if i0 == 0:
            tt[0] = min(((x_m - ax[0]) * ex[0] + (y_m - ay[0]) * ey[0]) / max(L2[0], 1e-12), 1.0)
        cx, cy = ax + tt * ex, ay + tt * ey
        d2 = (x_m - cx) ** 2 + (y_m - cy) ** 2
        j = int(np.argmin(d2))
        L = math.sqrt(L2[j]) if L2[j] > 0 else 1.0
        s = ps[i0 + j] + tt[j] * L
        lat = ((y_m - cy[j]) * ex[j] - (x_m - cx[j]) * ey[j]) / L
        return float(s), float(lat)

    def lateral_errors(
        self, x_m: np.ndarray, y_m: np.ndarray, t_s: np.ndarray, window_m: float = 10.0
    ) -> np.ndarray:
        """Signed distance of a driven trajectory to the path [m], lap by lap."""
        out = np.empty(len(x_m))
        s0 = float(self.s_at_time(t_s[0]))
        s = (
            float(self.project(float(x_m[0]), float(y_m[0]), s0, 1e9)[0])
            if self.length_m < 2 * window_m
            else s0
        )
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
            raise InputError(
                "unknown column (expected time, x, y, speed[, heading])", path, line=1, channel=h
            )
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


def _finite_fill(t: np.ndarray, y: np.ndarray, name: str, path: str) -> np.ndarray:
    """``y`` with its non-finite samples interpolated in time; InputError naming the channel
    when fewer than 2 samples are finite."""
    ok = np.isfinite(y)
    if ok.sum() < 2:
        raise InputError("too few finite samples for a reference", path, channel=name)
    return y if ok.all() else np.interp(t, t[ok], y[ok])


def front_speed(rec: Recording) -> np.ndarray:
    """Front-axle-centre speed [m/s]: the front wheels' mean (eq. 1's point), else ``speed``."""
    ch = rec.channels
    if "wheel_speed_fl" in ch and "wheel_speed_fr" in ch:
        v = 0.5 * (ch["wheel_speed_fl"] + ch["wheel_speed_fr"])
        if np.isfinite(v).sum() >= 2:
            return v
    if "speed" not in ch:
        raise InputError(
            "a replay needs the speed (or front wheel speeds)",
            rec.meta.get("path", "recording"),
            channel="speed",
        )
    return ch["speed"]


def recording_reference(
    rec: Recording, params: Params, *, source: str = "auto", name: str = "recording"
) -> Reference:
    """The recorded drive as a :class:`Reference` (time from 0 [s], front-wheel point).

    Args:
        rec: a canonical recording.
        params: the model (eq. 7 turns the steering-wheel angle into the road-wheel angle).
        source: ``nav`` (x, y, heading from GNSS/INS), ``can`` (dead reckoning from the front
            wheel speeds and the steering-wheel angle, as the drive loop's estimator does),
            or ``auto`` (nav when the recording has it).
        name: the reference's name.
    """
    ch = rec.channels
    path = str(rec.meta.get("path", name))
    t = np.asarray(ch["time"], dtype=float)
    v = np.maximum(_finite_fill(t, front_speed(rec), "speed", path), 0.0)
    plant = HybridPlant(params)
    if "steering_wheel_angle" not in ch:
        raise InputError(
            "a replay needs the steering-wheel angle", path, channel="steering_wheel_angle"
        )
    sw = _finite_fill(
        t, np.asarray(ch["steering_wheel_angle"], float), "steering_wheel_angle", path
    )
    delta = np.asarray(plant.road_wheel_angle(sw), dtype=float)
    has_nav = all(k in ch and np.isfinite(ch[k]).sum() >= 2 for k in ("x", "y", "heading"))
    if source == "nav" and not has_nav:
        raise InputError(
            "--reference-source nav needs x, y and heading (ingest with --nav)", path, channel="x"
        )
    if source in ("nav", "auto") and has_nav:
        x = _finite_fill(t, np.asarray(ch["x"], float), "x", path)
        y = _finite_fill(t, np.asarray(ch["y"], float), "y", path)
        psi = np.unwrap(_finite_fill(t, np.asarray(ch["heading"], float), "heading", path))
        # the path tangent is the front wheel's direction of motion: yaw + road-wheel angle
        return Reference(t - t[0], x, y, psi + delta, v, name=name)

    def first_finite(name: str) -> float:
        if name not in ch or not np.isfinite(ch[name]).any():
            return 0.0
        return float(ch[name][np.isfinite(ch[name])][0])

    x0, y0 = first_finite("x"), first_finite("y")
    hd = ch.get("heading")
    psi0 = float(hd[np.isfinite(hd)][0]) if hd is not None and np.isfinite(hd).any() else 0.0
    x, y, psi = dead_reckon(t, v, delta, params.vehicle.wheelbase_m, (x0, y0, psi0))
    return Reference(t - t[0], x, y, psi + delta, v, name=name)


def dead_reckon(t_s, v_mps, delta_rad, wheelbase_m: float, start=(0.0, 0.0, 0.0)):
    """Eq. 1 integrated along samples (midpoint heading), the drive loop's estimator:
    returns x, y [m] of the front-wheel point and the yaw psi [rad]."""
    n = len(t_s)
    x, y, psi = np.zeros(n), np.zeros(n), np.zeros(n)
    x[0], y[0], psi[0] = start
    for i in range(1, n):
        h = t_s[i] - t_s[i - 1]
        v, d = float(v_mps[i]), float(delta_rad[i])
        dpsi = heading_rate(v, d, wheelbase_m, math) * h
        x[i] = x[i - 1] + v * math.cos(psi[i - 1] + 0.5 * dpsi + d) * h
        y[i] = y[i - 1] + v * math.sin(psi[i - 1] + 0.5 * dpsi + d) * h
        psi[i] = psi[i - 1] + dpsi
    return x, y, psi


def load_reference(path: str | Path, params: Params) -> Reference:
    """A reference from ``path``: a reference CSV (time, x, y, speed[, heading]), or a
    canonical recording (any tool that takes a recording accepts one), whose driven path and
    speed become the reference through :func:`recording_reference`."""
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = [h.strip() for h in fh.readline().split(",")]
    except (OSError, UnicodeDecodeError):
        header = []  # load_reference_csv says what is wrong, in one line
    if set(header) - {"time", "x", "y", "speed", "heading"} and set(header) <= set(CHANNELS):
        return recording_reference(Recording.load(path), params, name=Path(path).stem)
    return load_reference_csv(path)
