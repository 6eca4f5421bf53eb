"""Raw logs to one canonical recording: CAN (+ DBC + signal map), GPS/INS and IMU.

:func:`ingest_files` does, in order (each step a function a test can call):

1. (:func:`read_can`) load the DBC (``models.logs.dbc``) and the vehicle's signal map
   (``models.logs.signalmap``), validated against each other;
2. read the CAN log (``models.logs.canlog``) and decode only the messages the map uses
   (``models.logs.decode``), on the buses it names; evaluate each channel's expression, convert
   to SI and apply its sign. A required channel without a sample raises :class:`InputError`
   naming the channel and the log;
3. (:func:`read_nav_stage`) read the nav file (``models.logs.nav``) and put it on the CAN clock: the
   offset is given, or estimated by cross-correlating CAN ``speed`` with GNSS ground speed
   (``models.logs.align``);
4. estimate the heading mount offset (device heading minus course over ground above
   :data:`MOUNT_MIN_SPEED_MPS`) and, unless ``mount_correction=False``, subtract it from
   ``heading`` and rotate the IMU's horizontal accelerations by it, so both describe the car body;
5. (:func:`read_imu_stage`) read the IMU, put it on the CAN clock (same device as the nav file:
   the nav offset; without nav: yaw-rate cross-correlation with CAN; or given) and convert it to
   ISO body axes, removing gravity with the nav attitude;
6. choose one source per channel (:data:`DEFAULT_PREFERENCE`, :func:`choose_sources`),
   resample everything onto a uniform grid spanning the time all required CAN channels cover
   (:func:`grid_for`, :func:`resample_channels`, ``models.logs.resample``) and mark gaps.

The result carries the recording (``raw`` keeps each chosen channel's samples, on the CAN clock,
before resampling), the recoverable problems, and a summary with stable keys (see
:func:`ingest_files`) that ``hmpc ingest --json`` writes as is.
"""

from __future__ import annotations

import hashlib
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable

import numpy as np

from hmpc import __version__
from hmpc.models.logs.align import OffsetEstimate, estimate_offset
from hmpc.models.logs.canlog import detect_format, read_log
from hmpc.models.logs.channels import CHANNELS, STRING_CHANNELS
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.decode import decode_frames
from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.nav import (
    ImuColumns,
    NavColumns,
    NavData,
    imu_to_body,
    read_imu_raw,
    read_nav,
)
from hmpc.models.logs.recording import Recording
from hmpc.models.logs.resample import gap_threshold_s, make_grid, resample
from hmpc.models.logs.signalmap import SignalMap, load_signal_map

#: samples above this ground speed [m/s] estimate the heading mount offset (course over ground
#: is meaningless when nearly stopped; 5 m/s is the acceptance criterion's threshold).
MOUNT_MIN_SPEED_MPS = 5.0
#: fewer samples than this above the speed threshold: no mount estimate (1 s of 20 Hz nav).
MOUNT_MIN_SAMPLES = 20
#: search window of the clock estimates [s]: loggers on one car rarely disagree by more.
MAX_LAG_S = 5.0

#: channel -> sources in order of preference, for channels several sources can give.
#: The INS yaw rate (when the nav file has one) and the IMU beat CAN KINEMATICS, whose yaw rate
#: is biased (-0.41 deg/s on the comma RAV4) and whose accelerations include road grade.
DEFAULT_PREFERENCE: dict[str, tuple[str, ...]] = {
    "yaw_rate": ("nav", "imu", "can"),
    "accel_x": ("imu", "can"),
    "accel_y": ("imu", "can"),
}
SOURCES = ("can", "nav", "imu")

KIND_NONFINITE_EXPR = "signal map expression gave NaN/inf (sample dropped)"
KIND_UNKNOWN_GEAR = "gear value not in the map's gear table (sample dropped)"
KIND_NO_CLOCK = "clock offset not estimated (0 s used)"


@dataclass
class IngestResult:
    """What :func:`ingest_files` returns."""

    recording: Recording
    problems: Problems
    summary: dict


def _usable_offset(est: OffsetEstimate, path, problems: Problems) -> OffsetEstimate:
    """An estimate that failed falls back to 0 s, and the fallback is reported for ``path``."""
    if est.ok:
        return est
    problems.add(KIND_NO_CLOCK, str(path), count=1, detail=est.note)
    return OffsetEstimate(0.0, est.peak, est.samples, est.method, False, est.note)


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (provenance of every input hmpc reads).

    A folder (a ROS bag folder, a CSV topic export) hashes as the SHA-256 of its files' relative
    paths and SHA-256s, one ``path sha256`` line each in sorted order, so that a changed,
    added or renamed file changes it.
    """
    path = Path(path)
    if path.is_dir():
        lines = [
            f"{f.relative_to(path).as_posix()} {sha256_file(f)}\n"
            for f in sorted(path.rglob("*"))
            if f.is_file()
        ]
        return hashlib.sha256("".join(lines).encode()).hexdigest()
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _source(path, sha256: str | None = None) -> dict | None:
    if path is None:
        return None
    return {"path": str(path), "sha256": sha256_file(path) if sha256 is None else sha256}


def _wrap(a):
    return np.mod(np.asarray(a, float) + np.pi, 2 * np.pi) - np.pi


def estimate_heading_mount(
    t_s, heading_rad, vel_east, vel_north, *, min_speed_mps: float = MOUNT_MIN_SPEED_MPS
) -> dict | None:
    """Constant offset between the device heading and the course over ground (ENU).

    Args:
        t_s: sample times [s] (same rows for all arrays).
        heading_rad: ENU heading [rad].
        vel_east: ground velocity east [m/s].
        vel_north: ground velocity north [m/s].
        min_speed_mps: only samples faster than this are used.

    Returns:
        ``{offset_rad, offset_deg, samples, residual_rms_deg, residual_max_deg,
        min_speed_mps}`` (offset = heading - course, circular mean), or None with too few
        samples.
    """
    ve, vn, h = (np.asarray(a, float) for a in (vel_east, vel_north, heading_rad))
    m = np.hypot(ve, vn) > min_speed_mps
    m &= np.isfinite(h)
    if int(m.sum()) < MOUNT_MIN_SAMPLES:
        return None
    d = _wrap(h[m] - np.arctan2(vn[m], ve[m]))
    off = float(np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d))))
    res = _wrap(d - off)
    return {
        "offset_rad": off,
        "offset_deg": math.degrees(off),
        "samples": int(m.sum()),
        "residual_rms_deg": math.degrees(float(np.sqrt(np.mean(res**2)))),
        "residual_max_deg": math.degrees(float(np.max(np.abs(res)))),
        "min_speed_mps": float(min_speed_mps),
    }


Series = tuple[np.ndarray, np.ndarray]  # (t_s on the CAN clock, values)


@dataclass
class CanStage:
    """Step 2's result: the signal map and each CAN channel's samples (before resampling)."""

    smap: SignalMap
    channels: dict[str, Series]  # channel -> (t_s, values), dropped samples removed
    describe: dict[str, str]  # channel -> "can: <message.signal expression>"
    absent: list[str]  # optional channels of the map without a usable sample
    log_format: str = ""  # the CAN log format detected (models.logs.canlog.FORMATS)


@dataclass
class NavStage:
    """Step 3-4's result: nav channels on the CAN clock (heading mount-corrected if asked)."""

    nav: NavData | None  # as read, on its own clock
    channels: dict[str, Series]
    offset_s: float  # added to nav times to reach the CAN clock [s]
    clock: dict | None  # OffsetEstimate.to_dict() of the nav clock
    mount: dict | None  # estimate_heading_mount(...) + "applied"
    checks: dict  # clock checks by yaw rate (name -> OffsetEstimate.to_dict())


@dataclass
class ImuStage:
    """Step 5's result: IMU channels in ISO body axes on the CAN clock."""

    channels: dict[str, Series]
    clock: dict | None
    gravity: object | None  # ImuData.gravity (how gravity was removed)
    checks: dict


@dataclass
class Resampled:
    """Step 6's result: the grid and every chosen channel on it."""

    channels: dict[str, np.ndarray]  # "time" and each channel on the grid
    gaps: dict[str, list]  # channel -> [{start_s, end_s, duration_s}]
    info: dict[str, dict]  # channel -> summary["channels"] entry


def ingest_files(
    log_path,
    dbc_path,
    signals_path,
    nav_path=None,
    imu_path=None,
    rate_hz: float = 50.0,
    clock_offset_s: float | None = None,
    imu_offset_s: float | None = None,
    nav_columns: NavColumns | None = None,
    gap_s: float | None = None,
    problems: Problems | None = None,
    *,
    imu_columns: ImuColumns | None = None,
    mount_correction: bool = True,
    prefer: dict[str, str] | None = None,
    max_lag_s: float = MAX_LAG_S,
    dbc_lenient: bool = False,
    progress: Callable[[str], None] | None = None,
) -> IngestResult:
    """Ingest a CAN log (+ optional nav and IMU CSVs) into a canonical recording.

    Args:
        log_path: CAN log (any format ``models.logs.canlog`` reads).
        dbc_path: the car's DBC (optionally .gz).
        signals_path: the vehicle's signal map YAML.
        nav_path: GPS/INS CSV (columns: ``nav_columns``), optional.
        imu_path: IMU CSV (columns: ``imu_columns``), optional.
        rate_hz: grid rate of the recording [Hz].
        clock_offset_s: nav clock offset [s] added to nav times to reach the CAN clock; None
            estimates it by cross-correlating CAN speed with GNSS speed.
        imu_offset_s: IMU clock offset [s] to the CAN clock; None: the nav offset (same device)
            when there is a nav file, else estimated from yaw rate against CAN.
        nav_columns: the nav file's column layout (default: the comma2k19 files).
        imu_columns: the IMU file's column layout (default: the comma2k19 files).
        gap_s: gap threshold [s] for every channel; None: per channel, see ``models.logs.resample``.
        problems: collector to add to (a new one by default).
        mount_correction: subtract the estimated heading mount offset from ``heading`` and rotate
            the IMU accelerations by it (reported either way).
        prefer: channel -> source ("can", "nav", "imu") overriding :data:`DEFAULT_PREFERENCE`.
        max_lag_s: search window of the clock estimates [s].
        dbc_lenient: skip (and report one by one) DBC lines cantools cannot parse, instead of
            refusing the DBC (see :func:`hmpc.models.logs.dbc.load_dbc`).
        progress: called with a short text at each stage (the CLI prints it on stderr).

    Returns:
        :class:`IngestResult`. Summary keys: ``hmpc_version, vehicle, sources`` (path +
        sha256 of log, dbc, signals, nav, imu), ``start_s, end_s, duration_s, rate_hz,
        samples, channels`` (name -> unit, source, resample, raw_samples, raw_rate_hz,
        valid_fraction, gap_threshold_s), ``channels_absent, speed_source, speed_vs_gps,
        clock`` (reference, nav, imu: offset_s, correlation_peak, method, ok; checks),
        ``heading_mount`` (offset_rad/deg, residual, applied; None without nav heading),
        ``imu_gravity, nav_origin, gaps`` (channel -> [{start_s, end_s, duration_s}]),
        ``problems`` (total, items). Times are on the CAN log's clock [s].

    Raises:
        InputError: unreadable/empty inputs, a required channel absent from the log, a message
            on several buses without ``bus:`` in the map, nothing usable in nav/IMU.
        ParamError: a bad signal map (unknown key/channel/message/signal/unit).
        ValueError: a non-positive ``rate_hz`` or ``gap_s``, unknown ``prefer`` entries.
    """
    preference = _check_options(rate_hz, gap_s, prefer)
    problems = Problems() if problems is None else problems
    say = progress or (lambda _msg: None)
    # the log, much the largest input, is hashed in a worker thread while it is parsed
    hasher = ThreadPoolExecutor(1)
    log_sha256 = hasher.submit(sha256_file, log_path)
    hasher.shutdown(wait=False)  # its thread ends with the hash
    can = read_can(log_path, dbc_path, signals_path, problems, say, dbc_lenient=dbc_lenient)
    nav = NavStage(None, {}, 0.0, None, None, {})
    if nav_path is not None:
        nav = read_nav_stage(
            nav_path,
            can.channels,
            problems,
            say,
            columns=nav_columns,
            offset_s=clock_offset_s,
            mount_correction=mount_correction,
            max_lag_s=max_lag_s,
        )
    imu = ImuStage({}, None, None, {})
    if imu_path is not None:
        imu = read_imu_stage(
            imu_path,
            can.channels,
            nav,
            problems,
            say,
            columns=imu_columns,
            offset_s=imu_offset_s,
            mount_correction=mount_correction,
            max_lag_s=max_lag_s,
        )
    raw, origin = choose_sources(can, nav.channels, imu.channels, preference, nav_path, imu_path)
    say(f"resampling {len(raw)} channels at {rate_hz:g} Hz")
    grid = grid_for(can, rate_hz, str(log_path))
    _check_overlap(grid, (("nav", nav.channels, nav_path), ("IMU", imu.channels, imu_path)))
    res = resample_channels(raw, origin, can.smap, grid, gap_s)
    summary = _summary(
        log_path,
        dbc_path,
        signals_path,
        nav_path,
        imu_path,
        rate_hz,
        can,
        nav,
        imu,
        res,
        problems,
        log_sha256.result(),
    )
    meta = dict(summary)
    meta["path"] = str(log_path)
    return IngestResult(Recording(res.channels, raw, meta), problems, summary)


def _check_options(rate_hz, gap_s, prefer) -> dict[str, tuple[str, ...]]:
    """Step 0: validate the numeric options; the source preference with ``prefer`` applied."""
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz!r}")
    if gap_s is not None and not (math.isfinite(gap_s) and gap_s > 0):
        raise ValueError(f"gap_s must be a positive number, got {gap_s!r}")
    preference = dict(DEFAULT_PREFERENCE)
    for ch, src in (prefer or {}).items():
        if ch not in DEFAULT_PREFERENCE or src not in DEFAULT_PREFERENCE[ch]:
            raise ValueError(
                f"cannot prefer {src!r} for {ch!r}; choices: "
                + ", ".join(f"{c}: {'/'.join(s)}" for c, s in DEFAULT_PREFERENCE.items())
            )
        preference[ch] = (src,) + tuple(s for s in DEFAULT_PREFERENCE[ch] if s != src)
    return preference


def read_can(
    log_path,
    dbc_path,
    signals_path,
    problems: Problems,
    say: Callable[[str], None],
    *,
    dbc_lenient: bool = False,
) -> CanStage:
    """Steps 1-2: DBC and signal map, read and decode the CAN log, evaluate every channel.

    Raises:
        InputError: as :func:`ingest_files` (a required channel without a sample, a message on
            several buses without ``bus:``, no channel of the map in the log).
    """
    say(f"loading DBC {dbc_path} and signal map {signals_path}")
    # the DBC and the map (pure Python) are parsed in a worker thread while this one reads the
    # log (mostly inside numpy, which lets it run); their errors and problems still come first
    dbc_problems, log_problems = Problems(), Problems()

    def load_map():
        db = load_dbc(dbc_path, lenient=dbc_lenient, problems=dbc_problems)
        return db, load_signal_map(signals_path, db)

    with ThreadPoolExecutor(1) as pool:
        setup = pool.submit(load_map)
        try:
            log_format = detect_format(log_path)
            say(f"reading CAN log {log_path} ({log_format})")
            frames = read_log(log_path, log_problems, fmt=log_format)
        except BaseException:
            exc = setup.exception()
            if exc is not None:  # a bad DBC or map is reported before the log
                raise exc from None
            raise
        db, smap = setup.result()
    problems.merge(dbc_problems)
    problems.merge(log_problems)
    say(f"decoding {len(frames)} frames ({', '.join(smap.messages())})")
    decoded = decode_frames(
        frames, db, problems, names=smap.messages(), buses=smap.buses(), dbc_path=str(dbc_path)
    )
    stage = CanStage(smap, {}, {}, [], log_format)
    log_s = str(log_path)
    for ch, cm in smap.channels.items():
        dm = decoded[cm.message] if cm.message in decoded else None
        series = _can_channel(ch, cm, dm, smap.path, log_s, problems)
        if series is None:
            stage.absent.append(ch)
            continue
        stage.channels[ch] = series
        stage.describe[ch] = "can: " + cm.describe()
    if not stage.channels:
        raise InputError("no channel of the signal map is in the log", log_s)
    return stage


def _can_channel(ch: str, cm, dm, map_path, log_s: str, problems: Problems) -> Series | None:
    """One signal-map channel from its decoded message ``dm``: (t_s, values) with the dropped
    samples (NaN/inf expression, unknown gear) counted and removed; None when an optional
    channel has no valid sample. A required one raises InputError instead."""
    if dm is None or len(dm) == 0:
        sel = np.zeros(0, bool)
    elif cm.bus is None:
        sel = np.ones(len(dm), bool)
        buses = np.unique(dm.bus)
        if len(buses) > 1:
            raise InputError(
                f"message {cm.message} is on buses {', '.join(str(int(b)) for b in buses)}; "
                f"say which with 'bus:' in {map_path}",
                log_s,
                channel=ch,
            )
    else:
        sel = dm.bus == cm.bus
    if not sel.any():
        bus = "" if cm.bus is None else f" on bus {cm.bus}"
        if cm.required:
            if dm is not None and len(dm) == 0:  # its frames were all refused by decoding
                dropped = [p for p in problems if p.detail.startswith(f"{cm.message} (")]
                first = dropped[0] if dropped else None
                why = f"every frame of message {cm.message} was dropped" + (
                    f" ({first.count} x {first.kind}, first at {first.first[0]})"
                    if first and first.first
                    else " as undecodable"
                )
            elif dm is not None and len(dm):
                why = (
                    f"message {cm.message} is not on bus {cm.bus} (it is on bus "
                    f"{', '.join(str(int(b)) for b in np.unique(dm.bus))})"
                )
            else:
                why = f"message {cm.message}{bus} is not in the log"
            raise InputError(f"required channel has no sample: {why}", log_s, channel=ch)
        return None
    vals = cm.evaluate({s: dm.signals[s][sel] for s in cm.expr.signals})
    t = dm.t_s[sel]
    where = dm.where[sel]
    if cm.gear is not None:
        bad = vals == ""
        if bad.any():
            raw_bad = np.unique(
                np.rint(cm.expr({s: dm.signals[s][sel][bad] for s in cm.expr.signals}))
            )
            problems.add(
                KIND_UNKNOWN_GEAR,
                log_s,
                where[bad][: Problems.MAX_FIRST],
                count=int(bad.sum()),
                detail=f"{ch}: raw value(s) {', '.join(f'{v:g}' for v in raw_bad[:8])}",
            )
    else:
        bad = ~np.isfinite(vals)
        if bad.any():
            problems.add(
                KIND_NONFINITE_EXPR,
                log_s,
                where[bad][: Problems.MAX_FIRST],
                count=int(bad.sum()),
                detail=f"{ch} = {cm.expr.text}",
            )
    if bad.all():
        if cm.required:
            raise InputError(
                "required channel has no valid sample (every value was dropped)", log_s, channel=ch
            )
        return None
    return t[~bad], vals[~bad]


def read_nav_stage(
    nav_path,
    can: dict[str, Series],
    problems: Problems,
    say: Callable[[str], None],
    *,
    columns: NavColumns | None,
    offset_s: float | None,
    mount_correction: bool,
    max_lag_s: float,
) -> NavStage:
    """Steps 3-4: read the nav file, put it on the CAN clock (``offset_s`` given, or CAN speed
    against GNSS speed), estimate the heading mount offset and remove it if asked."""
    say(f"reading nav {nav_path}")
    nav = read_nav(nav_path, problems, columns)
    if offset_s is not None:
        est = OffsetEstimate(float(offset_s), method="given")
    elif "speed" in can and "gps_speed" in nav:
        est = estimate_offset(
            *can["speed"], *nav["gps_speed"], max_lag_s=max_lag_s, what="CAN speed vs GNSS speed"
        )
    else:
        est = OffsetEstimate(
            0.0, method="none", ok=False, note="no CAN speed or no GNSS speed to correlate"
        )
    est = _usable_offset(est, nav_path, problems)
    stage = NavStage(
        nav,
        {ch: (t + est.offset_s, v) for ch, (t, v) in nav.items()},
        est.offset_s,
        est.to_dict(),
        None,
        {},
    )
    if "heading" in nav and nav.velocity is not None:
        tv, ve, vn = nav.velocity
        stage.mount = estimate_heading_mount(tv, nav["heading"][1], ve, vn)
        if stage.mount is not None:
            stage.mount["applied"] = bool(mount_correction)
            if mount_correction:
                th, h = stage.channels["heading"]
                stage.channels["heading"] = (th, _wrap(h - stage.mount["offset_rad"]))
    if "heading" in stage.channels and "yaw_rate" in can:
        th, h = stage.channels["heading"]
        hr = np.gradient(np.unwrap(h), th)
        chk = estimate_offset(
            *can["yaw_rate"], th, hr, max_lag_s=max_lag_s, what="CAN yaw rate vs nav heading rate"
        )
        stage.checks["nav_residual_by_yaw_rate"] = chk.to_dict()
    return stage


def read_imu_stage(
    imu_path,
    can: dict[str, Series],
    nav: NavStage,
    problems: Problems,
    say: Callable[[str], None],
    *,
    columns: ImuColumns | None,
    offset_s: float | None,
    mount_correction: bool,
    max_lag_s: float,
) -> ImuStage:
    """Step 5: read the IMU, put it on the CAN clock (given; the nav offset, same device; or
    CAN yaw rate against the IMU's), convert to ISO body axes with the nav attitude, and rotate
    the accelerations by the heading mount offset when it was removed from the heading."""
    say(f"reading IMU {imu_path}")
    raw_imu = read_imu_raw(imu_path, problems, columns)
    if offset_s is not None:
        est = OffsetEstimate(float(offset_s), method="given")
    elif nav.nav is not None:
        assert nav.clock is not None  # a nav file has its clock estimate
        est = OffsetEstimate(
            nav.offset_s,
            nav.clock["correlation_peak"] or float("nan"),
            method="same device as nav",
            ok=True,
        )
    elif "yaw_rate" in can:
        est = estimate_offset(
            *can["yaw_rate"],
            raw_imu.t_s,
            raw_imu.yaw_rate_device(),
            max_lag_s=max_lag_s,
            what="CAN yaw rate vs IMU yaw rate",
        )
    else:
        est = OffsetEstimate(
            0.0, method="none", ok=False, note="no nav file and no CAN yaw rate to correlate"
        )
    est = _usable_offset(est, imu_path, problems)
    imu_off = est.offset_s
    attitude = None
    if nav.nav is not None and "roll" in nav.nav and "pitch" in nav.nav:
        tr = nav.nav["roll"][0] + nav.offset_s - imu_off  # nav times on the IMU's clock
        attitude = (tr, nav.nav["roll"][1], nav.nav["pitch"][1])
    body = imu_to_body(raw_imu, attitude)
    stage = ImuStage(
        {ch: (t + imu_off, v) for ch, (t, v) in body.items()}, est.to_dict(), body.gravity, {}
    )
    if nav.mount is not None and mount_correction:
        d = nav.mount["offset_rad"]
        t, ax = stage.channels["accel_x"]
        _, ay = stage.channels["accel_y"]
        c, s = math.cos(d), math.sin(d)
        stage.channels["accel_x"] = (t, c * ax - s * ay)
        stage.channels["accel_y"] = (t, s * ax + c * ay)
    if "heading" in nav.channels:
        th, h = nav.channels["heading"]
        chk = estimate_offset(
            th,
            np.gradient(np.unwrap(h), th),
            *stage.channels["yaw_rate"],
            max_lag_s=max_lag_s,
            what="nav heading rate vs IMU yaw rate",
        )
        stage.checks["imu_residual_vs_nav_by_yaw_rate"] = chk.to_dict()
    return stage


def choose_sources(
    can: CanStage,
    navc: dict[str, Series],
    imuc: dict[str, Series],
    preference: dict[str, tuple[str, ...]],
    nav_path,
    imu_path,
) -> tuple[dict[str, Series], dict[str, str]]:
    """Step 6a: one source per channel, in CONVENTIONS order: (raw samples, source text)."""
    by_source = {"can": can.channels, "nav": navc, "imu": imuc}
    raw: dict[str, Series] = {}
    origin: dict[str, str] = {}
    names = set(can.channels) | set(navc) | set(imuc)
    for ch in [c for c in CHANNELS if c in names]:
        for src in preference.get(ch, SOURCES):
            if ch in by_source[src]:
                raw[ch] = by_source[src][ch]
                origin[ch] = (
                    can.describe[ch]
                    if src == "can"
                    else f"{src}: {_path_of(src, nav_path, imu_path)}"
                )
                break
    return raw, origin


#: the most rows a recording's grid may have (10 h at 1 kHz; ~2 GB per 25 channels)
MAX_GRID_ROWS = 36_000_000


def grid_for(can: CanStage, rate_hz: float, log_s: str) -> np.ndarray:
    """Step 6b: the uniform grid [s] over the time every required CAN channel covers (all CAN
    channels if none is required), so its first and last rows hold every required channel;
    other channels are NaN outside their span."""
    core = [can.channels[c] for c in can.smap.required() if c in can.channels] or list(
        can.channels.values()
    )
    t_start = max(float(t[0]) for t, _ in core)
    t_end = min(float(t[-1]) for t, _ in core)
    if t_end <= t_start:
        raise InputError("the required channels do not overlap in time", log_s)
    rows = (t_end - t_start) * float(rate_hz) + 1
    if rows > MAX_GRID_ROWS:
        raise InputError(
            f"--rate {rate_hz:g} Hz over {t_end - t_start:.1f} s would make "
            f"{rows:.3g} rows (at most {MAX_GRID_ROWS:,}); choose a lower rate",
            log_s,
        )
    if rows < 2:
        raise InputError(
            f"--rate {rate_hz:g} Hz over {t_end - t_start:.2f} s gives fewer than "
            "2 rows; choose a higher rate",
            log_s,
        )
    return make_grid(t_start, t_end, float(rate_hz))


def _check_overlap(grid: np.ndarray, others) -> None:
    """A nav or IMU file that misses the grid entirely means a wrong clock: InputError."""
    t_start, t_end = float(grid[0]), float(grid[-1])
    for src, chans, path in others:
        if chans:
            t = next(iter(chans.values()))[0]
            if t[-1] < t_start or t[0] > t_end:
                raise InputError(
                    f"the {src} file does not overlap the CAN log in time ({src} "
                    f"{t[0]:.3f}..{t[-1]:.3f} s, CAN {t_start:.3f}..{t_end:.3f} s on the CAN "
                    "clock); "
                    "give the clock offset (--clock-offset / --imu-offset)",
                    str(path),
                )


def resample_channels(
    raw: dict[str, Series], origin: dict[str, str], smap, grid: np.ndarray, gap_s: float | None
) -> Resampled:
    """Step 6c: every chosen channel on the grid (kind by channel and source), gaps marked."""
    out = Resampled({"time": grid}, {}, {})
    for ch, (t, v) in raw.items():
        if ch in STRING_CHANNELS:
            kind = "string"
        elif ch == "heading":
            kind = "angle"
        elif ch in smap.channels and origin[ch].startswith("can"):
            kind = smap.channels[ch].resample
        else:
            kind = "linear"
        d = np.diff(t)
        med = np.median(d) if len(d) else None
        # with every step positive, their median is also the median of the positive steps
        thr = gap_threshold_s(
            t, gap_s, median_step_s=float(med) if med is not None and d.min() > 0 else None
        )
        values, g = resample(t, v, grid, kind, gap_s, threshold_s=thr)
        out.channels[ch] = values
        if g:
            out.gaps[ch] = [x.to_dict() for x in g]
        valid = (values != "") if ch in STRING_CHANNELS else np.isfinite(values)
        out.info[ch] = {
            "unit": CHANNELS[ch],
            "source": origin[ch],
            "resample": kind,
            "raw_samples": int(len(t)),
            "raw_rate_hz": float(1.0 / med) if med is not None and med > 0 else None,
            "valid_fraction": float(np.mean(valid)) if len(valid) else 0.0,
            "gap_threshold_s": thr,
        }
    return out


def speed_vs_gps(channels: dict[str, np.ndarray]) -> dict | None:
    """CAN ``speed`` against GNSS ground speed above :data:`MOUNT_MIN_SPEED_MPS` (>= 10 rows)."""
    if "speed" not in channels or "gps_speed" not in channels:
        return None
    a, b = channels["speed"], channels["gps_speed"]
    m = np.isfinite(a) & np.isfinite(b) & (b > MOUNT_MIN_SPEED_MPS)
    if m.sum() < 10:
        return None
    return {
        "ratio_mean": float(np.mean(a[m]) / np.mean(b[m])),
        "rms_difference_mps": float(np.sqrt(np.mean((a[m] - b[m]) ** 2))),
        "samples": int(m.sum()),
    }


def _summary(
    log_path,
    dbc_path,
    signals_path,
    nav_path,
    imu_path,
    rate_hz: float,
    can: CanStage,
    nav: NavStage,
    imu: ImuStage,
    res: Resampled,
    problems: Problems,
    log_sha256: str | None = None,
) -> dict:
    """Step 7: the summary with the stable keys listed in :func:`ingest_files`."""
    smap, grid, navd = can.smap, res.channels["time"], nav.nav
    speed_source = smap.channels["speed"].describe() if "speed" in smap.channels else None
    return {
        "hmpc_version": __version__,
        "vehicle": smap.vehicle,
        "log_format": can.log_format,  # as detected from the content, whatever the extension
        "sources": {
            "log": _source(log_path, log_sha256),
            "dbc": _source(dbc_path),
            "signals": _source(signals_path),
            "nav": _source(nav_path),
            "imu": _source(imu_path),
        },
        "start_s": float(grid[0]),
        "end_s": float(grid[-1]),
        "duration_s": float(grid[-1] - grid[0]),
        "rate_hz": float(rate_hz),
        "samples": int(len(grid)),
        "channels": res.info,
        "channels_absent": can.absent,
        "speed_source": speed_source,
        "speed_vs_gps": speed_vs_gps(res.channels),
        "clock": {
            "reference": "CAN log",
            "nav": nav.clock,
            "imu": imu.clock,
            "checks": {**nav.checks, **imu.checks},
        },
        "heading_mount": nav.mount,
        "imu_gravity": imu.gravity,
        "nav_origin": None
        if navd is None or navd.origin is None
        else {"lat_deg": navd.origin[0], "lon_deg": navd.origin[1], "alt_m": navd.origin[2]},
        "gaps": res.gaps,
        "problems": {"total": int(problems.total()), "items": problems.to_list()},
        # counted apart from the problems: frames whose ids the DBC does not define
        "information": problems.info_list(),
    }


def _path_of(src: str, nav_path, imu_path) -> str:
    return str(nav_path) if src == "nav" else str(imu_path)
