"""GPS/INS and IMU CSV readers, converted to hmpc's conventions (docs/conventions.md).

:func:`read_nav` reads a GPS/INS solution with configurable column names (:class:`NavColumns`):

- position as WGS84 ``lat/lon[/alt]`` (converted to local ENU with ``pymap3d.geodetic2enu``,
  origin at the first valid fix) or as local ``x/y[/z]`` in metres (taken as ENU);
- horizontal velocity north/east (NED or ENU files give the same two columns; a vertical
  velocity is not needed); ``gps_speed`` = hypot(v_north, v_east). Without velocity columns
  ``gps_speed`` is the central difference of the ENU positions;
- attitude ``roll/pitch/heading`` in NED (heading clockwise from north, the usual INS output)
  or ENU (heading counter-clockwise from east), in rad or deg. hmpc's ``heading`` is ENU:
  ``pi/2 - heading_ned`` wrapped to (-pi, pi]. ``pitch`` is positive nose-up and ``roll``
  positive right side down in both input conventions (and in hmpc's);
- optionally a yaw-rate column (NED: positive clockwise, negated; ENU: kept).

Output channels: ``x, y[, z], heading, pitch, roll, gps_speed[, yaw_rate]`` (those the columns
allow), each as ``(t_s, values)`` in the file's own clock.

:func:`read_imu` reads an IMU CSV (:class:`ImuColumns`; the defaults are the comma2k19 files:
device frame x forward, y right, z down; gyro rad/s; accelerometer m/s^2 including gravity) and
returns ``yaw_rate, accel_x, accel_y`` in ISO 8855 body axes (x forward, y left, z up):

- with an attitude (roll/pitch of the same device, e.g. from :func:`read_nav`), gravity is
  removed exactly: ``a = f + R^T g`` (specific force plus gravity in the device frame), and the
  yaw rate is the Euler heading rate ``(q sin(roll) + r cos(roll)) / cos(pitch)`` (rotation
  about the vertical, not about the tilted device axis), negated into ISO's z-up sense;
- without an attitude, the mean specific force over the whole file, scaled to 9.80665 m/s^2,
  is taken as gravity: this removes the constant mounting tilt but leaves road grade in, and
  also removes the file's mean longitudinal acceleration (said in the returned ``gravity`` note).

Bad input: rows with a non-numeric, NaN or inf value in a used column, or the wrong number of
fields, are skipped, counted and reported with their first line numbers; rows out of time order
are re-sorted and duplicate times dropped (reported). A missing file, an empty or binary file,
a missing column or no usable row raises :class:`InputError` naming the file (and line/column).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import cast

import numpy as np

from hmpc.models.logs.files import read_bytes
from hmpc.models.errors import InputError, ParamError, Problems

from hmpc.models.constants import G_MPS2

KIND_MALFORMED = "malformed row (wrong number of fields or not a number)"
KIND_NONFINITE = "row with NaN or inf (skipped)"
KIND_UNSORTED = "time earlier than the previous row (rows re-sorted by time)"
KIND_DUPLICATE_TIME = "duplicate time (later row dropped)"
KIND_RANGE = "latitude/longitude out of range (row skipped)"

_FRAMES_ATT = ("ned", "enu")
_ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
_RATE_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0}
_ACCEL_UNITS = {"m/s^2": 1.0, "g": G_MPS2}
_IMU_FRAMES = ("frd", "flu")


@dataclass(frozen=True)
class NavColumns:
    """Column names of a GPS/INS CSV and the conventions its values follow.

    A column name of ``None`` means the file has no such column. Either ``lat``+``lon`` or
    ``x``+``y`` must be given. Defaults match ``rav4-comma2k19/nav.csv``.
    """

    time: str = "time"
    lat: str | None = "lat_deg"  # WGS84 latitude [deg]
    lon: str | None = "lon_deg"  # WGS84 longitude [deg]
    alt: str | None = "alt_m"  # height above the ellipsoid [m]
    x: str | None = None  # local east [m] (instead of lat/lon)
    y: str | None = None  # local north [m]
    z: str | None = None  # local up [m]
    vel_north: str | None = "vel_north"  # [m/s]
    vel_east: str | None = "vel_east"  # [m/s]
    roll: str | None = "roll_rad"
    pitch: str | None = "pitch_rad"
    heading: str | None = "heading_rad"
    yaw_rate: str | None = None
    attitude_frame: str = "ned"  # ned: heading clockwise from north; enu: CCW from east
    angle_unit: str = "rad"  # rad | deg (roll, pitch, heading)
    yaw_rate_unit: str = "rad/s"  # rad/s | deg/s

    def check(self, path: str | None = None) -> None:
        """Raise ParamError for inconsistent settings."""
        if self.attitude_frame not in _FRAMES_ATT:
            raise ParamError(
                f"attitude_frame must be ned or enu, got {self.attitude_frame!r}",
                path,
                key="nav.attitude_frame",
            )
        if self.angle_unit not in _ANGLE_UNITS:
            raise ParamError(
                f"angle_unit must be rad or deg, got {self.angle_unit!r}",
                path,
                key="nav.angle_unit",
            )
        if self.yaw_rate_unit not in _RATE_UNITS:
            raise ParamError(
                f"yaw_rate_unit must be rad/s or deg/s, got {self.yaw_rate_unit!r}",
                path,
                key="nav.yaw_rate_unit",
            )
        if (self.lat is None) != (self.lon is None):
            raise ParamError(
                "give both lat and lon, or neither", path, key="nav.lat" if self.lon else "nav.lon"
            )
        if (self.x is None) != (self.y is None):
            raise ParamError(
                "give both x and y, or neither", path, key="nav.x" if self.y else "nav.y"
            )
        geo = self.lat is not None and self.lon is not None
        local = self.x is not None and self.y is not None
        if geo == local:
            raise ParamError(
                "give either lat and lon, or x and y (not both, not neither)",
                path,
                key="nav.lat" if not geo else "nav.x",
            )
        if (self.vel_north is None) != (self.vel_east is None):
            raise ParamError(
                "give both vel_north and vel_east, or neither", path, key="nav.vel_north"
            )


@dataclass(frozen=True)
class ImuColumns:
    """Column names of an IMU CSV and its axes/units. Defaults match ``rav4-comma2k19/imu.csv``."""

    time: str = "time"
    gyro_x: str = "gyro_x"
    gyro_y: str = "gyro_y"
    gyro_z: str = "gyro_z"
    accel_x: str = "accel_x"
    accel_y: str = "accel_y"
    accel_z: str = "accel_z"
    frame: str = "frd"  # frd: x forward, y right, z down; flu: x forward, y left, z up
    gyro_unit: str = "rad/s"  # rad/s | deg/s
    accel_unit: str = "m/s^2"  # m/s^2 | g (specific force, gravity included)

    def check(self, path: str | None = None) -> None:
        if self.frame not in _IMU_FRAMES:
            raise ParamError(f"frame must be frd or flu, got {self.frame!r}", path, key="imu.frame")
        if self.gyro_unit not in _RATE_UNITS:
            raise ParamError(
                f"gyro_unit must be rad/s or deg/s, got {self.gyro_unit!r}",
                path,
                key="imu.gyro_unit",
            )
        if self.accel_unit not in _ACCEL_UNITS:
            raise ParamError(
                f"accel_unit must be m/s^2 or g, got {self.accel_unit!r}",
                path,
                key="imu.accel_unit",
            )


def load_columns(path: str | Path) -> tuple[NavColumns, ImuColumns]:
    """Read column settings from a small YAML file with optional ``nav:`` and ``imu:`` sections.

    Each section holds :class:`NavColumns` / :class:`ImuColumns` fields (``null`` = no such
    column); fields not given keep the comma2k19 defaults. Unknown keys raise ParamError.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError("no such column settings file", str(path))
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        why = getattr(exc, "problem", None) or exc.__class__.__name__
        raise ParamError(
            f"not valid YAML ({why})", str(path), line=None if mark is None else mark.line + 1
        ) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParamError("expected a mapping with 'nav' and/or 'imu' sections", str(path))
    for k in data:
        if k not in ("nav", "imu"):
            raise ParamError("unknown key (expected nav or imu)", str(path), key=str(k))
    out = []
    for section, cls in (("nav", NavColumns), ("imu", ImuColumns)):
        sec = data[section] if section in data else {}
        if sec is None:
            sec = {}
        if not isinstance(sec, dict):
            raise ParamError("expected a mapping", str(path), key=section)
        known = {f.name for f in fields(cls)}
        for k, v in sec.items():
            if k not in known:
                raise ParamError(
                    f"unknown key (expected one of {', '.join(sorted(known))})",
                    str(path),
                    key=f"{section}.{k}",
                )
            if v is not None and not isinstance(v, str):
                raise ParamError(
                    f"expected a column name or null, got {v!r}", str(path), key=f"{section}.{k}"
                )
        cols = cls(**sec)
        cols.check(str(path))
        out.append(cols)
    return cast(NavColumns, out[0]), cast(ImuColumns, out[1])


# --------------------------------------------------------------------------- CSV table
def read_table(
    path: str | Path, problems: Problems, wanted: list[str], *, what: str = "CSV"
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Read the numeric columns ``wanted`` (the first one is time) of a CSV with a header.

    Returns (column -> float64 array, 1-based line number of each kept row), sorted by time,
    duplicate times dropped. Bad rows are skipped and reported in ``problems``.

    Raises:
        InputError: missing/empty/binary file, a wanted column missing from the header, or no
            usable row.
    """
    p = Path(path)
    spath = str(path)
    if not p.is_file():
        raise InputError("no such file" if not p.exists() else "not a regular file", spath)
    try:
        raw = read_bytes(p)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read {what} ({exc.__class__.__name__})", spath) from None
    if not raw.strip():
        raise InputError(f"empty file (no {what} header)", spath)
    # the header decides whether this is a text CSV at all; a garbled data row later on is
    # only a bad row (skipped and reported like any other)
    head_end = raw.find(b"\n", len(raw) - len(raw.lstrip()))
    head = raw if head_end < 0 else raw[:head_end]
    if b"\0" in head:
        raise InputError(f"binary data, not a {what} text file", spath, line=1)
    try:
        head.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"not UTF-8 text: not a {what} file", spath, line=1) from None
    text = raw.decode("utf-8-sig", errors="replace")
    lines = text.splitlines()
    h = 0
    while h < len(lines) and not lines[h].strip():
        h += 1
    header = [c.strip() for c in lines[h].split(",")]
    for c in wanted:
        if c not in header:
            shown = ", ".join(header[:12]) + (" ..." if len(header) > 12 else "")
            raise InputError(f"no column '{c}' in the header ({shown})", spath, line=h + 1)
    idx = [header.index(c) for c in wanted]
    nf = len(header)
    rows: list[list[float]] = []
    where: list[int] = []
    bad: list[int] = []
    nonfinite: list[int] = []
    for i in range(h + 1, len(lines)):
        s = lines[i]
        if not s.strip():
            continue
        parts = s.split(",")
        if len(parts) != nf:
            bad.append(i + 1)
            continue
        try:
            vals = [float(parts[j]) for j in idx]
        except ValueError:
            bad.append(i + 1)
            continue
        if not all(math.isfinite(v) for v in vals):
            nonfinite.append(i + 1)
            continue
        rows.append(vals)
        where.append(i + 1)
    problems.add(KIND_MALFORMED, spath, bad)
    problems.add(KIND_NONFINITE, spath, nonfinite)
    if not rows:
        n_bad = len(bad) + len(nonfinite)
        raise InputError(
            f"no usable {what} row ({n_bad} bad row(s) skipped)"
            if n_bad
            else f"no {what} data rows after the header",
            spath,
            line=(bad + nonfinite)[0] if n_bad else h + 1,
        )
    a = np.asarray(rows, dtype=float)
    w = np.asarray(where, dtype=np.int64)
    t = a[:, 0]
    d = np.diff(t)
    if np.any(d < 0):
        problems.add(KIND_UNSORTED, spath, w[1:][d < 0])
        order = np.argsort(t, kind="stable")
        a, w = a[order], w[order]
        t = a[:, 0]
        d = np.diff(t)
    if np.any(d == 0):
        dup = np.concatenate([[False], d == 0])
        problems.add(KIND_DUPLICATE_TIME, spath, w[dup])
        a, w = a[~dup], w[~dup]
    return {c: a[:, k] for k, c in enumerate(wanted)}, w


def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    out = np.mod(a + np.pi, 2 * np.pi) - np.pi
    out[out == -np.pi] = np.pi
    return out


class NavData(dict):
    """``read_nav``'s result: channel -> (t_s, values), plus what ingest needs besides.

    Attributes:
        path: the nav file.
        origin: (lat_deg, lon_deg, alt_m) of the ENU origin, or None for local x/y input.
        velocity: (t_s, v_east_mps, v_north_mps) or None without velocity columns.
        rows: number of rows used.
    """

    path: str = ""
    origin: tuple | None = None
    velocity: tuple | None = None
    rows: int = 0


def read_nav(path: str | Path, problems: Problems, columns: NavColumns | None = None) -> NavData:
    """Read a GPS/INS CSV into hmpc channels (see module docstring).

    Args:
        path: the CSV (optionally gzip).
        problems: collector for recoverable problems (bad rows, NaN/inf, unsorted times).
        columns: column names and conventions (default: the comma2k19 nav.csv layout).

    Returns:
        :class:`NavData` (a dict channel -> (t_s, values) in SI/ENU).

    Raises:
        InputError: see :func:`read_table`; ParamError for inconsistent ``columns``.
    """
    cols = columns or NavColumns()
    cols.check()
    spath = str(path)
    geo = cols.lat is not None
    wanted = [cols.time]
    for c in (cols.lat, cols.lon, cols.alt) if geo else (cols.x, cols.y, cols.z):
        if c is not None:
            wanted.append(c)
    for c in (cols.vel_north, cols.vel_east, cols.roll, cols.pitch, cols.heading, cols.yaw_rate):
        if c is not None and c not in wanted:
            wanted.append(c)
    data, where = read_table(path, problems, wanted, what="nav CSV")
    t = data[cols.time]
    out = NavData()
    out.path = spath
    if geo:
        assert cols.lat is not None and cols.lon is not None  # cols.check: lat with lon
        lat, lon = data[cols.lat], data[cols.lon]
        ok = (np.abs(lat) <= 90.0) & (lon >= -180.0) & (lon <= 360.0)
        if not ok.all():
            problems.add(KIND_RANGE, spath, where[~ok])
            if not ok.any():
                raise InputError(
                    "no row with a valid latitude/longitude", spath, line=int(where[0]), channel="x"
                )
            data = {k: v[ok] for k, v in data.items()}
            t, where = data[cols.time], where[ok]
            lat, lon = data[cols.lat], data[cols.lon]
        alt = data[cols.alt] if cols.alt is not None else np.zeros_like(lat)
        import pymap3d

        lat0, lon0, alt0 = float(lat[0]), float(lon[0]), float(alt[0])
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, lat0, lon0, alt0)
        out.origin = (lat0, lon0, alt0)
        out["x"] = (t, np.asarray(e, float))
        out["y"] = (t, np.asarray(n, float))
        if cols.alt is not None:
            out["z"] = (t, np.asarray(u, float))
    else:
        assert cols.x is not None and cols.y is not None  # cols.check: x and y without lat
        out["x"] = (t, data[cols.x])
        out["y"] = (t, data[cols.y])
        if cols.z is not None:
            out["z"] = (t, data[cols.z])
    if cols.vel_north is not None:
        assert cols.vel_east is not None  # cols.check: both velocities or neither
        vn, ve = data[cols.vel_north], data[cols.vel_east]
        out.velocity = (t, ve, vn)
        out["gps_speed"] = (t, np.hypot(vn, ve))
    elif len(t) >= 3:  # central differences of the ENU track
        ve = np.gradient(out["x"][1], t)
        vn = np.gradient(out["y"][1], t)
        out.velocity = (t, ve, vn)
        out["gps_speed"] = (t, np.hypot(ve, vn))
    k = _ANGLE_UNITS[cols.angle_unit]
    if cols.roll is not None:
        out["roll"] = (t, data[cols.roll] * k)
    if cols.pitch is not None:
        out["pitch"] = (t, data[cols.pitch] * k)
    if cols.heading is not None:
        h = data[cols.heading] * k
        out["heading"] = (t, _wrap(np.pi / 2 - h if cols.attitude_frame == "ned" else h))
    if cols.yaw_rate is not None:
        r = data[cols.yaw_rate] * _RATE_UNITS[cols.yaw_rate_unit]
        out["yaw_rate"] = (t, -r if cols.attitude_frame == "ned" else r)
    out.rows = int(len(t))
    return out


class ImuData(dict):
    """``read_imu``'s result: channel -> (t_s, values), plus ``gravity`` (what was done),
    ``path`` and ``rows``."""

    path: str = ""
    gravity: str = ""
    rows: int = 0


@dataclass
class ImuRaw:
    """IMU samples in the device frame x forward, y right, z down (SI), file clock.

    Attributes: t_s [s]; p, q, r body rates about x, y, z [rad/s]; fx, fy, fz specific force
    (gravity included) [m/s^2]; path.
    """

    t_s: np.ndarray
    p: np.ndarray
    q: np.ndarray
    r: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    fz: np.ndarray
    path: str = ""

    def yaw_rate_device(self) -> np.ndarray:
        """ISO (z up) yaw rate about the device's own z axis [rad/s] (no attitude)."""
        return -self.r


def read_imu_raw(path: str | Path, problems: Problems, columns: ImuColumns | None = None) -> ImuRaw:
    """Read an IMU CSV into :class:`ImuRaw` (device frame FRD, SI units)."""
    cols = columns or ImuColumns()
    cols.check()
    wanted = [
        cols.time,
        cols.gyro_x,
        cols.gyro_y,
        cols.gyro_z,
        cols.accel_x,
        cols.accel_y,
        cols.accel_z,
    ]
    data, _ = read_table(path, problems, wanted, what="IMU CSV")
    kr, ka = _RATE_UNITS[cols.gyro_unit], _ACCEL_UNITS[cols.accel_unit]
    p, q, r = (data[c] * kr for c in (cols.gyro_x, cols.gyro_y, cols.gyro_z))
    fx, fy, fz = (data[c] * ka for c in (cols.accel_x, cols.accel_y, cols.accel_z))
    if cols.frame == "flu":  # to x forward, y right, z down
        q, r, fy, fz = -q, -r, -fy, -fz
    return ImuRaw(data[cols.time], p, q, r, fx, fy, fz, str(path))


def imu_to_body(raw: ImuRaw, attitude: tuple | None = None) -> ImuData:
    """``yaw_rate, accel_x, accel_y`` in ISO 8855 axes from device-frame samples.

    Args:
        raw: device-frame samples (:func:`read_imu_raw`).
        attitude: ``(t_s, roll_rad, pitch_rad)`` of the same device in the IMU's clock
            (roll right side down, pitch nose up), or None (see module docstring).
    """
    t, q, r, fx, fy, fz = raw.t_s, raw.q, raw.r, raw.fx, raw.fy, raw.fz
    out = ImuData()
    out.path = raw.path
    out.rows = int(len(t))
    if attitude is not None:
        ta, roll_a, pitch_a = (np.asarray(a, float) for a in attitude)
        if len(ta) < 2:
            attitude = None
    if attitude is not None:
        # attitude held constant beyond its ends (the INS may start a little later)
        phi = np.interp(t, ta, roll_a)
        theta = np.interp(t, ta, pitch_a)
        gx = -G_MPS2 * np.sin(theta)
        gy = G_MPS2 * np.sin(phi) * np.cos(theta)
        out.gravity = "removed with the nav roll/pitch of the same device"
    else:
        fbar = np.array([fx.mean(), fy.mean(), fz.mean()])
        norm = float(np.linalg.norm(fbar))
        if norm < 1e-6:
            gx = gy = np.zeros_like(t)
            phi = theta = np.zeros_like(t)
            out.gravity = "not removed (mean specific force is zero)"
        else:
            gb = -fbar * (G_MPS2 / norm)  # gravity in the device frame (z down)
            gx = np.full_like(t, gb[0])
            gy = np.full_like(t, gb[1])
            theta = np.full_like(t, math.asin(max(-1.0, min(1.0, -gb[0] / G_MPS2))))
            phi = np.full_like(t, math.atan2(gb[1], gb[2]))
            out.gravity = (
                "constant tilt removed (mean specific force taken as gravity; road "
                "grade and the file's mean acceleration are not separated)"
            )
    ax = fx + gx
    ay = fy + gy
    psi_dot_ned = (q * np.sin(phi) + r * np.cos(phi)) / np.cos(theta)
    out["yaw_rate"] = (t, -psi_dot_ned)
    out["accel_x"] = (t, ax)
    out["accel_y"] = (t, -ay)
    return out


def read_imu(
    path: str | Path,
    problems: Problems,
    columns: ImuColumns | None = None,
    *,
    attitude: tuple | None = None,
) -> ImuData:
    """Read an IMU CSV into ``yaw_rate, accel_x, accel_y`` (ISO 8855 body axes, SI).

    Args:
        path: the CSV (optionally gzip).
        problems: collector for recoverable problems.
        columns: column names, axes and units (default: the comma2k19 imu.csv layout).
        attitude: ``(t_s, roll_rad, pitch_rad)`` of the same device in the IMU file's clock
            (NED-style angles: roll right side down, pitch nose up), used to remove gravity and
            to turn body rates into the heading rate. Without it, see the module docstring.

    Raises:
        InputError: see :func:`read_table`; ParamError for inconsistent ``columns``.
    """
    return imu_to_body(read_imu_raw(path, problems, columns), attitude)
