"""ROS recordings read without a ROS install: ROS 1 ``.bag``, ROS 2 bag folders, MCAP files.

- ROS 1 bags and ROS 2 bags (a folder with ``metadata.yaml``, sqlite3 or MCAP storage, or one
  ``.db3`` storage file) are read and their messages deserialised with ``rosbags``
  (``AnyReader``, from the message definitions the bag carries; a ROS 2 bag that carries none
  falls back to the standard Humble message types).
- ``.mcap`` files are read with ``mcap``, decoded with ``mcap-ros2-support`` (CDR, ``ros2msg``
  schemas) or ``mcap-ros1-support`` (``ros1msg`` schemas) from the schemas in the file.

:func:`read_bag` returns, for every topic a topic map reads (``models.logs.topicmap``), its
sample times and the requested fields as float arrays (:class:`TopicData`). A field is a dotted
path of message attributes; a ROS time (``sec``/``nanosec`` or ``secs``/``nsecs``) reads as
seconds, a bool as 0/1.

Bad input: a topic the map names that the recording lacks, or a field its messages lack, raises
:class:`InputError` naming the file and the topic (and field) -- a map is written for one layout,
and a typo must not silently drop a channel. A message that does not deserialise is skipped,
counted and reported.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

import numpy as np

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.topicmap import LOG_TIME, TopicData, TopicMap

KIND_UNDECODABLE = "message does not deserialise (skipped)"

ROS1_BAG, ROS2_BAG, MCAP = "ros1 bag", "ros2 bag", "mcap"


def bag_kind(path: Path) -> str | None:
    """``ros1 bag``, ``ros2 bag``, ``mcap``, or None when ``path`` is none of them."""
    if path.is_file():
        suffix = path.suffix.lower()
        return {".bag": ROS1_BAG, ".mcap": MCAP, ".db3": ROS2_BAG}.get(suffix)
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return ROS2_BAG
    return None


def read_bag(path: str | Path, tmap: TopicMap, problems: Problems) -> dict[str, TopicData]:
    """Every topic ``tmap`` reads, from a bag or MCAP file (see the module docstring).

    Raises:
        InputError: not a readable bag, a missing topic or field, a field that is not a number.
    """
    path = Path(path)
    kind = bag_kind(path)
    if kind == MCAP:
        return _read_mcap(path, tmap, problems)
    if kind is None:
        raise InputError(
            "not a ROS 1 .bag, a ROS 2 bag folder (metadata.yaml) or an .mcap file", str(path)
        )
    return _read_rosbags(path, kind, tmap, problems)


class _Collector:
    """One topic's samples: resolves each field on the first message, then reads values."""

    def __init__(self, topic: str, fields: set[str], tspec, where: str):
        self.topic, self.where, self.tspec = topic, where, tspec
        self.fields = sorted(fields)
        self.t: list[float] = []
        self.rows: list[list[float]] = []
        self.msgtype: str | None = None

    def add(self, log_time_ns: int, msg: Any, msgtype: str | None) -> None:
        if self.msgtype is None:
            self.msgtype = msgtype
            for f in self.fields:  # the first message decides: a missing field is a map error
                _value(msg, f, self)
        self.rows.append([_value(msg, f, self) for f in self.fields])
        self.t.append(self._time(log_time_ns, msg))

    def _time(self, log_time_ns: int, msg: Any) -> float:
        ts = self.tspec.time
        if ts is None or ts == LOG_TIME:
            return log_time_ns / 1e9
        if isinstance(ts, str):
            return _value(msg, ts, self)
        return _value(msg, ts[0], self) + _value(msg, ts[1], self) / 1e9

    def result(self) -> TopicData:
        ts = self.tspec.time
        source = (
            "log time"
            if ts is None or ts == LOG_TIME
            else ts
            if isinstance(ts, str)
            else f"{ts[0]} + {ts[1]} ns"
        )
        t = np.asarray(self.t, float)
        vals = np.asarray(self.rows, float).reshape(len(self.rows), len(self.fields))
        order = np.argsort(t, kind="stable")
        return TopicData(
            self.topic,
            t[order],
            {f: vals[order, i] for i, f in enumerate(self.fields)},
            self.where,
            self.msgtype,
            source,
        )


def _value(msg: Any, path: str, col: _Collector) -> float:
    """The number at ``path`` in ``msg``; InputError naming file, topic and field otherwise."""
    obj = msg
    for part in path.split("."):
        if not hasattr(obj, part):
            have = ", ".join(_attrs(obj)) or "no fields"
            raise InputError(
                f"topic '{col.topic}': field '{path}' is not in its messages "
                f"({col.msgtype or type(msg).__name__}: '{part}' not among {have})",
                col.where,
            )
        obj = getattr(obj, part)
    return _number(obj, path, col)


def _number(obj: Any, path: str, col: _Collector) -> float:
    if isinstance(obj, (bool, np.bool_)):
        return float(obj)
    if isinstance(obj, (int, float, np.integer, np.floating)):
        return float(obj)
    for sec, nsec in (("sec", "nanosec"), ("secs", "nsecs")):
        if hasattr(obj, sec) and hasattr(obj, nsec):
            return float(getattr(obj, sec)) + float(getattr(obj, nsec)) / 1e9
    raise InputError(
        f"topic '{col.topic}': field '{path}' is not a number "
        f"(it is {type(obj).__name__}: {', '.join(_attrs(obj)) or 'no fields'})",
        col.where,
    )


def _attrs(obj: Any) -> list[str]:
    """The field names of a deserialised message (rosbags dataclasses, genpy and mcap-ros2
    objects), for error messages."""
    for name in ("__dataclass_fields__", "__slots__"):
        names = getattr(obj, name, None)
        if names:
            return [n for n in names if not n.startswith("_")]
    return [n for n in vars(obj) if not n.startswith("_")] if hasattr(obj, "__dict__") else []


def _missing_topics(tmap: TopicMap, have: set[str], where: str) -> None:
    for topic in tmap.needs():
        if topic not in have:
            close = difflib.get_close_matches(topic, sorted(have), n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            listed = ", ".join(sorted(have)[:12]) + (" ..." if len(have) > 12 else "")
            raise InputError(
                f"topic '{topic}' is not in the recording{hint} (it has: {listed or 'no topics'})",
                where,
            )


def _collectors(tmap: TopicMap, where: str) -> dict[str, _Collector]:
    return {t: _Collector(t, f, tmap.spec(t), where) for t, f in tmap.needs().items()}


def _read_rosbags(
    path: Path, kind: str, tmap: TopicMap, problems: Problems
) -> dict[str, TopicData]:
    """ROS 1 bags and ROS 2 bags through rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    where = str(path)
    cols = _collectors(tmap, where)
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        with reader:
            _missing_topics(tmap, {c.topic for c in reader.connections}, where)
            conns = [c for c in reader.connections if c.topic in cols]
            for i, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except AnyReaderError as exc:
                    problems.add(KIND_UNDECODABLE, where, i + 1, detail=f"{conn.topic}: {exc}")
                    continue
                cols[conn.topic].add(t_ns, msg, conn.msgtype)
    except InputError:
        raise
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise InputError(f"cannot read as a {kind} ({_why(exc)})", where) from None
    return {t: c.result() for t, c in cols.items()}


def _read_mcap(path: Path, tmap: TopicMap, problems: Problems) -> dict[str, TopicData]:
    """MCAP through mcap, decoded by the ROS 2 (CDR) and ROS 1 decoders."""
    from mcap.exceptions import DecoderNotFoundError, McapError
    from mcap.reader import make_reader
    from mcap_ros1.decoder import DecoderFactory as Ros1Decoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    where = str(path)
    cols = _collectors(tmap, where)
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh, decoder_factories=[Ros2Decoders(), Ros1Decoders()])
            summary = reader.get_summary()
            if summary is not None:
                _missing_topics(tmap, {c.topic for c in summary.channels.values()}, where)
            seen: set[str] = set()
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=list(cols)
            ):
                seen.add(channel.topic)
                cols[channel.topic].add(
                    message.log_time, decoded, schema.name if schema is not None else None
                )
            if summary is None:  # an unindexed file: the topics are known once read
                _missing_topics(tmap, seen, where)
    except InputError:
        raise
    except DecoderNotFoundError as exc:
        raise InputError(
            f"a topic's message encoding cannot be decoded ({_why(exc)}); "
            "hmpc reads ROS 1 and ROS 2 (CDR) messages",
            where,
        ) from None
    except (McapError, OSError, ValueError, KeyError, EOFError) as exc:
        raise InputError(f"cannot read as MCAP ({_why(exc)})", where) from None
    return {t: c.result() for t, c in cols.items()}


def _why(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or exc.__class__.__name__
    return text if len(text) <= 200 else text[:197] + "..."
