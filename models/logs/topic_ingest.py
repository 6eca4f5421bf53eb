"""A ROS recording (bag, MCAP or CSV export) and a topic map to one canonical recording.

:func:`ingest_topics` does, in order:

1. load the topic map (``models.logs.topicmap``);
2. read every topic it names: bags and MCAP with ``models.logs.rosbag``, CSV exports (a folder,
   ``DIR/PREFIX`` or one of its files) with ``models.logs.topiccsv``;
3. make each channel: the field times its scale and unit factor (SI), or a quaternion's
   yaw/pitch/roll (:func:`quaternion_angles`); positions relative to the first fix with both x
   and y, turned from UTM grid to local ENU on a UTM topic (``models.logs.utm``), whose
   headings are turned by the same grid convergence;
4. resample onto a uniform grid over the time every required channel covers (every channel
   when none is required; ``models.logs.ingest.grid_for``, ``models.logs.resample``) and mark
   gaps.

Times stay those of the recording (epoch seconds for ROS stamps). The result is the
:class:`~hmpc.models.logs.ingest.IngestResult` CAN ingest returns: the same Recording and a
summary with the same keys (``log_format`` is ``ros1 bag``, ``ros2 bag``, ``mcap`` or ``csv
export``; ``clock``, ``heading_mount``, ``imu_gravity`` and ``nav_origin`` are empty), plus
``topics`` (per topic: file, messages, type, time source, span) and ``position_origin``.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast
from collections.abc import Callable

import numpy as np

from hmpc import __version__
from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.channels import CHANNELS
from hmpc.models.logs.ingest import CanStage, IngestResult, grid_for, sha256_file, speed_vs_gps
from hmpc.models.logs.recording import Recording
from hmpc.models.logs.resample import gap_threshold_s, resample
from hmpc.models.logs.rosbag import bag_kind, read_bag
from hmpc.models.logs.topiccsv import read_export, resolve_export
from hmpc.models.logs.topicmap import QUATERNION, TopicChannel, TopicData, TopicMap, load_topic_map
from hmpc.models.logs.utm import grid_to_local, utm_to_geodetic

CSV_EXPORT = "csv export"

Series = tuple[np.ndarray, np.ndarray]


def ingest_topics(
    path,
    topics_path,
    rate_hz: float = 50.0,
    gap_s: float | None = None,
    problems: Problems | None = None,
    progress: Callable[[str], None] | None = None,
) -> IngestResult:
    """Ingest a ROS recording into a canonical recording.

    Args:
        path: a ROS 1 ``.bag``, a ROS 2 bag folder (or ``.db3``), an ``.mcap`` file, or a CSV
            export (folder, ``DIR/PREFIX`` or one of its files).
        topics_path: the topic map YAML.
        rate_hz: grid rate of the recording [Hz].
        gap_s: gap threshold [s] for every channel; None: per channel (``models.logs.resample``).
        problems: collector to add to (a new one by default).
        progress: called with a short text at each stage.

    Raises:
        InputError: unreadable recording, a topic or field the map names that it lacks, a
            required channel without a value, no overlap of the required channels.
        ParamError: a bad topic map.
        ValueError: a non-positive ``rate_hz`` or ``gap_s``.
    """
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz!r}")
    if gap_s is not None and not (math.isfinite(gap_s) and gap_s > 0):
        raise ValueError(f"gap_s must be a positive number, got {gap_s!r}")
    problems = Problems() if problems is None else problems
    say = progress or (lambda _msg: None)
    say(f"loading topic map {topics_path}")
    tmap = load_topic_map(topics_path)
    path = Path(path)
    kind = bag_kind(path)
    say(f"reading {kind or CSV_EXPORT} {path} ({len(tmap.needs())} topics)")
    if kind is None:
        kind = CSV_EXPORT
        files = resolve_export(path, tmap)
        data = read_export(files, tmap, problems)
    else:
        files = None
        data = read_bag(path, tmap, problems)
    raw, origin, absent = make_channels(tmap, data, str(path))
    say(f"resampling {len(raw)} channels at {rate_hz:g} Hz")
    # grid_for reads only a stage's .smap and .channels
    grid = grid_for(cast(CanStage, SimpleNamespace(smap=tmap, channels=raw)), rate_hz, str(path))
    chans, gaps, info = resample_topics(raw, tmap, grid, gap_s)
    summary: dict[str, Any] = {
        "hmpc_version": __version__,
        "vehicle": tmap.vehicle,
        "log_format": kind,
        "sources": {"log": _sources(path, files), "topics": _source(Path(topics_path))},
        "start_s": float(grid[0]),
        "end_s": float(grid[-1]),
        "duration_s": float(grid[-1] - grid[0]),
        "rate_hz": float(rate_hz),
        "samples": int(len(grid)),
        "channels": info,
        "channels_absent": absent,
        "speed_source": tmap.channels["speed"].describe() if "speed" in raw else None,
        "speed_vs_gps": speed_vs_gps(chans),
        "clock": {"reference": "recording", "nav": None, "imu": None, "checks": {}},
        "heading_mount": None,
        "imu_gravity": None,
        "nav_origin": None,
        "position_origin": origin,
        "topics": {t: _topic_summary(d) for t, d in data.items()},
        "gaps": gaps,
        "problems": {"total": int(problems.total()), "items": problems.to_list()},
        "information": problems.info_list(),
    }
    meta = dict(summary)
    meta["path"] = str(path)
    return IngestResult(Recording(chans, raw, meta), problems, summary)


def quaternion_angles(qx, qy, qz, qw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roll, pitch, yaw) [rad] of unit quaternions in ZYX order, ISO 8855 signs.

    Yaw is from the frame's x axis, counter-clockwise; roll positive right side down; pitch
    positive nose-up (the negated rotation about ROS's left-pointing y axis). Quaternions are
    normalised first; a zero one gives NaN.
    """
    q = np.vstack([np.asarray(a, float) for a in (qx, qy, qz, qw)])
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / np.linalg.norm(q, axis=0)
    x, y, z, w = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = -np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def _values(c: TopicChannel, d: TopicData) -> np.ndarray:
    """A channel's SI values on its topic's samples (NaN where a message had none)."""
    if c.unit == QUATERNION:
        roll, pitch, yaw = quaternion_angles(*(d.fields[f] for f in c.fields()))
        return {"heading": yaw, "pitch": pitch, "roll": roll}[c.channel]
    return d.fields[c.field] * c.factor


def make_channels(
    tmap: TopicMap, data: dict[str, TopicData], where: str
) -> tuple[dict[str, Series], dict | None, list[str]]:
    """Step 3: channel -> (t_s, SI values) with only finite samples, the position origin
    (None without x/y), and the optional channels without a value."""
    vals = {ch: _values(c, data[c.topic]) for ch, c in tmap.channels.items()}
    origin = None
    if "x" in vals:
        origin = _to_local(tmap, data, vals)
    raw: dict[str, Series] = {}
    absent: list[str] = []
    for ch in [c for c in CHANNELS if c in tmap.channels]:
        c, d = tmap.channels[ch], data[tmap.channels[ch].topic]
        ok = np.isfinite(vals[ch]) & np.isfinite(d.t_s)
        if not ok.any():
            if c.required:
                raise InputError(
                    f"required channel has no value: topic '{c.topic}' field "
                    f"'{c.field}' has {len(d.t_s)} messages and no finite value",
                    d.where,
                    channel=ch,
                )
            absent.append(ch)
            continue
        raw[ch] = (d.t_s[ok], vals[ch][ok])
    if not raw:
        raise InputError("no channel of the topic map has a value in the recording", where)
    return raw, origin, absent


def _to_local(
    tmap: TopicMap, data: dict[str, TopicData], vals: dict[str, np.ndarray]
) -> dict | None:
    """Positions relative to the first fix with x and y (UTM turned to local ENU), in place;
    the origin's description, or None when no fix has both."""
    cx = tmap.channels["x"]
    d, spec = data[cx.topic], tmap.spec(cx.topic)
    x, y = vals["x"], vals["y"]
    fix = np.flatnonzero(np.isfinite(x) & np.isfinite(y) & np.isfinite(d.t_s))
    if not len(fix):
        return None
    i0 = int(fix[0])
    x0, y0 = float(x[i0]), float(y[i0])
    out = {
        "topic": cx.topic,
        "t_s": float(d.t_s[i0]),
        "frame": str(spec.frame or "local"),
        "x_m": x0,
        "y_m": y0,
    }
    if spec.frame is not None:
        gp = utm_to_geodetic(x0, y0, spec.frame)
        vals["x"], vals["y"] = grid_to_local(x, y, spec.frame, gp)
        out.update(
            {"lat_deg": gp.lat_deg, "lon_deg": gp.lon_deg, "convergence_rad": gp.convergence_rad}
        )
        if "heading" in tmap.channels and tmap.channels["heading"].topic == cx.topic:
            # a heading on the grid is from grid east: turned to true east like the positions
            vals["heading"] = _wrap(vals["heading"] - gp.convergence_rad)
    else:
        vals["x"], vals["y"] = x - x0, y - y0
    if "z" in vals:
        z = vals["z"]
        cz = tmap.channels["z"]
        zi = (
            i0
            if cz.topic == cx.topic and np.isfinite(z[i0])
            else next(iter(np.flatnonzero(np.isfinite(z))), None)
        )
        if zi is not None:
            out["z_m"] = float(z[zi])
            vals["z"] = z - float(z[zi])
    return out


def resample_topics(
    raw: dict[str, Series], tmap: TopicMap, grid: np.ndarray, gap_s: float | None
) -> tuple[dict[str, np.ndarray], dict, dict]:
    """Step 4: every channel on the grid, its gaps and its summary entry."""
    chans: dict[str, np.ndarray] = {"time": grid}
    gaps: dict[str, list] = {}
    info: dict[str, dict] = {}
    for ch, (t, v) in raw.items():
        c = tmap.channels[ch]
        values, g = resample(t, v, grid, c.resample, gap_s)
        chans[ch] = values
        if g:
            gaps[ch] = [x.to_dict() for x in g]
        d = np.diff(t)
        info[ch] = {
            "unit": CHANNELS[ch],
            "source": "topic " + c.describe(),
            "resample": c.resample,
            "raw_samples": int(len(t)),
            "raw_rate_hz": float(1.0 / np.median(d)) if len(d) and np.median(d) > 0 else None,
            "valid_fraction": float(np.mean(np.isfinite(values))) if len(values) else 0.0,
            "gap_threshold_s": gap_threshold_s(t, gap_s),
        }
    return chans, gaps, info


def _source(path: Path) -> dict:
    return {"path": str(path), "sha256": sha256_file(path)}


def _sources(path: Path, files: dict[str, Path] | None) -> dict:
    """Provenance of the recording: its file, or every file of a bag folder or CSV export."""
    if path.is_file() and files is None:
        return _source(path)
    members = (
        sorted(set(files.values())) if files else sorted(p for p in path.iterdir() if p.is_file())
    )
    return {"path": str(path), "files": [_source(p) for p in members]}


def _topic_summary(d: TopicData) -> dict:
    return {
        "file": d.where,
        "messages": int(len(d.t_s)),
        "type": d.msgtype,
        "time": d.time_source,
        "start_s": float(d.t_s[0]) if len(d.t_s) else None,
        "end_s": float(d.t_s[-1]) if len(d.t_s) else None,
    }
