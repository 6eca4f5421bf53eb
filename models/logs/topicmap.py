"""Topic maps: which ROS topic and message field make each canonical channel.

One YAML file per recording layout in ``params/`` (``*.topics.yaml``), the ROS counterpart of
a signal map (``models.logs.signalmap``)::

    vehicle: catvehicle                  # text, optional
    note: ...                            # text, optional
    topics:                              # optional: how a topic is stored and stamped
      /gps_odom:
        file: gps_odom.csv               # CSV export only: the topic's file (default below)
        time: Time                       # how its samples are stamped (default below)
        frame: utm 12N                   # its positions/headings: local (default) or UTM grid
    channels:
      speed:
        topic: /catvehicle/vel           # required
        field: linear.x                  # required: dotted path into the message
        unit: m/s                        # required: the field's unit, converted to SI
        scale: 1.0                       # optional: multiplies the field before the unit
        required: true                   # optional (default false): no value -> error
        resample: linear                 # optional: linear | hold
        note: ...                        # optional text
      heading: {topic: /gps_odom, field: orientation, unit: quaternion}

Units are those of :data:`hmpc.models.logs.signalmap.UNITS` (the converted unit must be the
channel's), plus ``quaternion`` for ``heading``, ``pitch`` and ``roll``: ``field`` then names a
quaternion whose ``.x .y .z .w`` are read, and the channel is its yaw (from the frame's x axis,
counter-clockwise), pitch (positive nose-up, ISO 8855; ROS's REP 103 body axes are also x
forward, y left, z up, so its pitch about y is nose-down and is negated) or roll (positive
right side down), in the ZYX (yaw-pitch-roll) order.

``time`` (per topic): ``log`` (a bag's record time of each message; the default for bags),
a field (a ROS time ``{sec, nanosec}``/``{secs, nsecs}``, or a number of seconds, e.g.
``header.stamp``), or a list ``[SECONDS, NANOSECONDS]`` of two fields. A CSV export without
``time`` (or with ``log``) is stamped by its ``Time`` column (bagpy writes the bag's record time
there), else by ``s`` + ``ns`` columns.

``frame`` (per topic): ``local`` -- the topic's ``x``/``y``/``z`` are already metres in a local
right-handed frame with z up (ENU, or a map frame) -- or ``utm <zone><N|S>``: x is easting and
y northing of that UTM zone (``models.logs.utm``). Either way positions become relative to the
first fix with both x and y; on a UTM topic positions and headings are turned from grid to true
north. ``x`` and ``y`` must come from one topic.

``file`` (per topic, CSV exports only): the topic's file name in the export's folder; the
default is the bagpy rule (the topic without its leading ``/``, other ``/`` as ``-``, then
``.csv``). A ``.gz`` beside a missing plain file is read instead. ``models.logs.topiccsv``
describes how a folder holding several recordings is read.

Everything is validated at load time: an unknown top-level key, channel, per-channel or
per-topic key, unit or time/frame form raises :class:`ParamError` naming the map file, the YAML
line and the key -- one line, no traceback.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hmpc.models.errors import InputError, ParamError
from hmpc.models.logs.channels import CHANNELS, STRING_CHANNELS
from hmpc.models.logs.signalmap import (
    HOLD_CHANNELS,
    RESAMPLE_KINDS,
    UNITS,
    _key_lines,
    canonical_unit,
)
from hmpc.models.logs.utm import UtmZone, parse_zone

TOP_KEYS = ("vehicle", "note", "topics", "channels")
CHANNEL_KEYS = ("topic", "field", "unit", "scale", "required", "resample", "note")
TOPIC_KEYS = ("file", "time", "frame", "note")
#: the unit of a field holding an orientation quaternion, and the channels it can make
QUATERNION = "quaternion"
QUATERNION_CHANNELS = ("heading", "pitch", "roll")
#: channels that are positions, made relative to the first fix
POSITION_CHANNELS = ("x", "y", "z")
#: ``time:`` value for a bag's record time
LOG_TIME = "log"
#: a topic's position frame when its entry does not give one
LOCAL_FRAME = "local"


@dataclass(frozen=True)
class TopicSpec:
    """How one topic is stored and stamped.

    Attributes:
        topic: the topic name as the recording spells it.
        file: the CSV export's file name (None: the default rule).
        time: None (the reader's default), ``"log"``, a field, or (seconds field, ns field).
        frame: None for a local frame, or the UTM zone of its positions.
    """

    topic: str
    file: str | None = None
    time: str | tuple[str, str] | None = None
    frame: UtmZone | None = None

    def default_file(self) -> str:
        """bagpy's file name of the topic: ``/a/b`` -> ``a-b.csv``."""
        return self.topic.lstrip("/").replace("/", "-") + ".csv"

    def time_fields(self) -> tuple[str, ...]:
        """The fields its time spec reads (none for ``log`` or the default)."""
        if self.time is None or self.time == LOG_TIME:
            return ()
        return (self.time,) if isinstance(self.time, str) else tuple(self.time)


@dataclass(frozen=True)
class TopicChannel:
    """How one canonical channel is made from one topic's field.

    Attributes:
        channel: canonical channel name (CONVENTIONS).
        topic: topic name.
        field: dotted path into the message (a quaternion for ``unit: quaternion``).
        unit: the field's unit (a key of UNITS, or ``quaternion``).
        factor: SI value = factor * field value (scale included; 1 for a quaternion).
        scale: as written in the map.
        required: an absent or empty channel is an error.
        resample: "linear", "hold", or "angle" (heading, always).
        line: YAML line of the entry (for messages).
    """

    channel: str
    topic: str
    field: str
    unit: str
    factor: float
    scale: float
    required: bool
    resample: str
    note: str | None = None
    line: int | None = None

    def fields(self) -> tuple[str, ...]:
        """The message fields this channel reads."""
        if self.unit == QUATERNION:
            return tuple(f"{self.field}.{c}" for c in "xyzw")
        return (self.field,)

    def describe(self) -> str:
        scale = "" if self.scale == 1.0 else f" x {self.scale:g}"
        return f"{self.topic}: {self.field} [{self.unit}]{scale}"


@dataclass(frozen=True)
class TopicMap:
    """A recording layout's topic map (see module docstring)."""

    path: str
    channels: dict[str, TopicChannel]
    topics: dict[str, TopicSpec]
    vehicle: str | None = None
    note: str | None = None

    def required(self) -> list[str]:
        return [c.channel for c in self.channels.values() if c.required]

    def needs(self) -> dict[str, set[str]]:
        """topic -> the fields the map reads from it (its channels' and its time spec's)."""
        out: dict[str, set[str]] = {}
        for c in self.channels.values():
            out.setdefault(c.topic, set()).update(c.fields())
        for t, fields in out.items():
            fields.update(self.spec(t).time_fields())
        return out

    def spec(self, topic: str) -> TopicSpec:
        """The topic's settings (defaults when the map has no ``topics:`` entry for it)."""
        return self.topics.get(topic) or TopicSpec(topic)


@dataclass
class TopicData:
    """What a reader returns for one topic: its sample times and the requested fields.

    Attributes:
        topic: topic name.
        t_s: sample times [s], one per message (sorted).
        fields: field path -> float values (NaN where a message had no finite value).
        where: the file the topic was read from (bag, MCAP or CSV).
        msgtype: the message type when the recording names it.
        time_source: how ``t_s`` was made (e.g. "log time", "header.stamp", "Time column").
    """

    topic: str
    t_s: np.ndarray
    fields: dict[str, np.ndarray]
    where: str
    msgtype: str | None = None
    time_source: str = ""


# --------------------------------------------------------------------------- loading
def load_topic_map(path: str | Path) -> TopicMap:
    """Load and validate a topic map.

    Raises:
        ParamError: unknown/missing key, unknown channel or unit, bad value; names the file,
            line and key.
        InputError: the file is missing or not text.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such topic map file", str(path))
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(
            f"cannot read the topic map as text ({exc.__class__.__name__})", str(path)
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or exc.__class__.__name__
        raise ParamError(
            f"not valid YAML ({problem})", str(path), line=None if mark is None else mark.line + 1
        ) from None
    return parse_topic_map(data, str(path), _key_lines(text))


def parse_topic_map(data: Any, path: str, lines: dict | None = None) -> TopicMap:
    """Validate an already-parsed YAML document (see :func:`load_topic_map`)."""
    lines = lines or {}

    def err(reason: str, *keys: str) -> ParamError:
        line = None
        for i in range(len(keys), 0, -1):
            line = lines.get(tuple(keys[:i]))
            if line is not None:
                break
        return ParamError(reason, path, line=line, key=".".join(keys) if keys else None)

    if not isinstance(data, dict):
        raise err("a topic map must be a mapping with a 'channels' section")
    for k in data:
        if k not in TOP_KEYS:
            raise err(f"unknown key (expected one of {', '.join(TOP_KEYS)})", str(k))
    chans = data.get("channels")
    if not isinstance(chans, dict) or not chans:
        raise err("'channels' must be a non-empty mapping of channel -> entry", "channels")
    texts = {}
    for k in ("vehicle", "note"):
        if k in data:
            if not isinstance(data[k], str):
                raise err("expected text", k)
            texts[k] = data[k]
    topics = data.get("topics") or {}
    if not isinstance(topics, dict):
        raise err("'topics' must be a mapping of topic -> settings", "topics")
    specs = {str(t): _parse_topic(str(t), e, err) for t, e in topics.items()}
    out = {str(ch): _parse_channel(str(ch), e, err, lines) for ch, e in chans.items()}
    _check_positions(out, err)
    return TopicMap(path, out, specs, texts.get("vehicle"), texts.get("note"))


def _parse_topic(topic: str, entry: Any, err) -> TopicSpec:
    base = ("topics", topic)
    if not isinstance(entry, dict):
        raise err("expected a mapping (file, time, frame)", *base)
    for k in entry:
        if k not in TOPIC_KEYS:
            raise err(f"unknown key (expected one of {', '.join(TOPIC_KEYS)})", *base, str(k))
    file = entry.get("file")
    if file is not None and (not isinstance(file, str) or not file or "/" in file):
        raise err("expected a file name in the export's folder (no '/')", *base, "file")
    time = entry.get("time")
    if isinstance(time, list):
        if len(time) != 2 or not all(isinstance(x, str) and x for x in time):
            raise err("expected [SECONDS_FIELD, NANOSECONDS_FIELD]", *base, "time")
        time = (time[0], time[1])
    elif time is not None and (not isinstance(time, str) or not time):
        raise err(
            f"expected '{LOG_TIME}', a field, or [SECONDS_FIELD, NANOSECONDS_FIELD]", *base, "time"
        )
    frame = entry.get("frame", LOCAL_FRAME)
    zone = None
    if frame != LOCAL_FRAME:
        try:
            zone = parse_zone(frame)
        except ValueError as exc:
            raise err(
                f"frame: '{LOCAL_FRAME}' or {exc}".replace("expected ", ""), *base, "frame"
            ) from None
    if "note" in entry and not isinstance(entry["note"], str):
        raise err("expected text", *base, "note")
    return TopicSpec(topic, file, time, zone)


def _parse_channel(ch: str, entry: Any, err, lines) -> TopicChannel:
    base = ("channels", ch)
    if ch not in CHANNELS or ch == "time":
        close = difflib.get_close_matches(ch, [c for c in CHANNELS if c != "time"], n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise err(f"unknown channel{hint}; channels are those of docs/conventions.md", *base)
    if ch in STRING_CHANNELS:
        raise err(
            f"{ch} cannot be read from a topic (it needs a value table: use a signal map)", *base
        )
    if not isinstance(entry, dict):
        raise err("entry must be a mapping with topic, field, unit", *base)
    for k in entry:
        if k not in CHANNEL_KEYS:
            raise err(f"unknown key (expected one of {', '.join(CHANNEL_KEYS)})", *base, str(k))
    for k in ("topic", "field", "unit"):
        if k not in entry:
            raise err("required key is missing", *base, k)
    topic, fld = entry["topic"], entry["field"]
    if not isinstance(topic, str) or not topic:
        raise err("expected a topic name", *base, "topic")
    if not isinstance(fld, str) or not fld or any(not p for p in fld.split(".")):
        raise err("expected a dotted field path (e.g. twist.linear.x)", *base, "field")
    unit = entry["unit"]
    unit = canonical_unit(str(unit)) if isinstance(unit, (str, int, float)) else unit
    if unit == QUATERNION:
        if ch not in QUATERNION_CHANNELS:
            raise err(f"a quaternion makes only {', '.join(QUATERNION_CHANNELS)}", *base, "unit")
        factor = 1.0
    elif unit not in UNITS:
        raise err(f"unknown unit {unit!r} (known: {', '.join(UNITS)}, {QUATERNION})", *base, "unit")
    else:
        si, factor = UNITS[unit]
        if si != CHANNELS[ch]:
            raise err(
                f"unit '{unit}' converts to {si}, but {ch} is in {CHANNELS[ch]}", *base, "unit"
            )
    scale = entry.get("scale", 1.0)
    if (
        isinstance(scale, bool)
        or not isinstance(scale, (int, float))
        or not math.isfinite(scale)
        or scale == 0
    ):
        raise err(f"scale must be a finite non-zero number, got {scale!r}", *base, "scale")
    if unit == QUATERNION and scale != 1.0:
        raise err("a quaternion cannot be scaled", *base, "scale")
    required = entry.get("required", False)
    if not isinstance(required, bool):
        raise err(f"expected true or false, got {required!r}", *base, "required")
    default_kind = "angle" if ch == "heading" else "hold" if ch in HOLD_CHANNELS else "linear"
    resample = entry.get("resample", default_kind)
    if ch == "heading" and resample != "angle":
        raise err(
            "heading is always resampled as an angle (unwrapped, interpolated, wrapped)",
            *base,
            "resample",
        )
    if ch != "heading" and resample not in RESAMPLE_KINDS:
        raise err(
            f"resample must be one of {', '.join(RESAMPLE_KINDS)}, got {resample!r}",
            *base,
            "resample",
        )
    note = entry.get("note")
    if note is not None and not isinstance(note, str):
        raise err("expected text", *base, "note")
    return TopicChannel(
        ch,
        topic,
        fld,
        unit,
        factor * float(scale),
        float(scale),
        required,
        resample,
        note,
        lines.get(base),
    )


def _check_positions(chans: dict[str, TopicChannel], err) -> None:
    """x and y come together, from one topic (a UTM fix needs both; the origin is one fix)."""
    has = [c for c in ("x", "y") if c in chans]
    if len(has) == 1:
        other = "y" if has[0] == "x" else "x"
        raise err(
            f"{has[0]} without {other}: a position needs both, from one topic", "channels", has[0]
        )
    if len(has) == 2 and chans["x"].topic != chans["y"].topic:
        raise err("x and y must come from one topic (one fix gives both)", "channels", "y", "topic")
