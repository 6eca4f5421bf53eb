"""CSV exports of ROS topics: a folder holding one CSV file (optionally .gz) per topic.

This is what bagpy writes (``catvehicle-vel.csv`` for ``/catvehicle/vel``: a ``Time`` column
of epoch seconds, then the message's fields as dotted column names) and what a pandas export
of a logger's callbacks writes (an unnamed index column, ``s`` and ``ns`` stamp columns, then
one column per field). A topic map (``models.logs.topicmap``) names each topic's file
(``topics.<topic>.file``, default the bagpy rule) and, when neither ``Time`` nor ``s`` + ``ns``
is there, its time columns. A map's field is the column name.

The recording argument is the export's folder; or a file-name prefix inside it, ``DIR/DS5_``,
when one folder holds several recordings whose files differ by a prefix
(``DS2_commandData.csv``, ``DS5_commandData.csv``); or one of the recording's files, whose
prefix is then taken. A folder alone is read when its files have no prefix, or one prefix;
several prefixes are refused, listing them.

Bad input: a topic without its file or a field without its column raises :class:`InputError`
naming the file and the topic/field. A row with more cells than the header, a non-number in a
used cell or an unusable time is skipped, counted and reported with its line; when more than
:data:`MAX_MALFORMED_FRACTION` of a file's rows are so, or none is usable, the file is refused
(InputError naming the file, the first bad line, the topic and the field). A row with fewer
cells than the header has no value in its missing trailing columns (as pandas reads it), which
is reported once per file as information; empty and ``nan`` cells are no value.
"""

from __future__ import annotations

import csv
import io
import math
import zlib
from pathlib import Path

import numpy as np

from hmpc.models.logs.files import open_text
from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.topicmap import LOG_TIME, TopicData, TopicMap, TopicSpec

#: more malformed rows than this fraction of a file: the file is not the layout the map says
MAX_MALFORMED_FRACTION = 0.5
#: time columns tried, in order, when the map gives none: (columns, description)
AUTO_TIME: tuple[tuple[tuple[str, ...], str], ...] = (
    (("Time",), "Time column"),
    (("s", "ns"), "s + ns columns"),
    (("time",), "time column"),
)

KIND_MALFORMED = "malformed row (skipped)"
KIND_SHORT_ROWS = "rows with fewer cells than the header (missing trailing cells: no value)"
KIND_UNSORTED = "time earlier than the previous row (rows re-sorted by time)"


def resolve_export(path: str | Path, tmap: TopicMap) -> dict[str, Path]:
    """topic -> its CSV file, for a folder, ``DIR/PREFIX`` or one file of the recording.

    Raises:
        InputError: no such folder; no file for a topic; a folder of several recordings.
    """
    path = Path(path)
    specs = [tmap.spec(t) for t in tmap.needs()]
    if path.is_dir():
        folder, prefix = path, None
    elif path.is_file():
        folder, prefix = path.parent, _prefix_of(path, specs)
    elif path.parent.is_dir() and path.name:
        folder, prefix = path.parent, path.name
    else:
        raise InputError("no such file or folder", str(path))
    if prefix is None:
        prefix = _only_prefix(folder, specs)
    out = {}
    for s in specs:
        f = _file_of(folder, prefix, s)
        if f is None:
            raise InputError(
                f"topic '{s.topic}': no file {prefix}{_name(s)}[.gz] in the export "
                f"(set topics.{s.topic}.file in {tmap.path} if it is named otherwise)",
                str(folder),
            )
        out[s.topic] = f
    return out


def _name(spec: TopicSpec) -> str:
    return spec.file or spec.default_file()


def _candidates(name: str) -> tuple[str, ...]:
    return (name, name + ".gz") if not name.endswith(".gz") else (name,)


def _file_of(folder: Path, prefix: str, spec: TopicSpec) -> Path | None:
    for c in _candidates(_name(spec)):
        if (folder / (prefix + c)).is_file():
            return folder / (prefix + c)
    return None


def _prefix_of(path: Path, specs: list[TopicSpec]) -> str:
    for s in specs:
        for c in _candidates(_name(s)):
            if path.name.endswith(c):
                return path.name[: -len(c)]
    raise InputError(
        "not one of the topic files the map names (" + ", ".join(_name(s) for s in specs) + ")",
        str(path),
    )


def _only_prefix(folder: Path, specs: list[TopicSpec]) -> str:
    """The one file-name prefix under which ``folder`` holds every topic's file ("" first)."""
    if all(_file_of(folder, "", s) for s in specs):
        return ""
    names = [p.name for p in folder.iterdir() if p.is_file()]
    common: set[str] | None = None
    for s in specs:
        found = {n[: -len(c)] for n in names for c in _candidates(_name(s)) if n.endswith(c)}
        if not found:
            return ""  # that topic's file is missing: resolve_export names it
        common = found if common is None else common & found
    assert common is not None  # a topic map has at least one topic
    if len(common) > 1:
        listed = ", ".join(sorted(common))
        raise InputError(
            f"the folder holds several recordings (file-name prefixes {listed}); "
            f"name one as {folder / sorted(common)[0]}",
            str(folder),
        )
    return next(iter(common)) if common else ""


def read_export(files: dict[str, Path], tmap: TopicMap, problems: Problems) -> dict[str, TopicData]:
    """Every topic the map reads, from its CSV file (see the module docstring)."""
    return {
        t: read_topic_csv(files[t], tmap.spec(t), fields, problems, tmap.path)
        for t, fields in tmap.needs().items()
    }


def _read_text(path: Path) -> str:
    try:
        with open_text(path, newline="") as fh:
            text = fh.read()
            if getattr(fh.buffer.raw, "truncated", False):
                raise EOFError("the gzip stream ends early")
            return text
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as exc:
        raise InputError(f"cannot read as CSV text ({exc.__class__.__name__})", str(path)) from None


def _time_columns(
    spec: TopicSpec, header: list[str], where: str, map_path: str
) -> tuple[tuple[str, ...], str]:
    if spec.time is None or spec.time == LOG_TIME:
        for cols, what in AUTO_TIME:
            if all(c in header for c in cols):
                return cols, what
        raise InputError(
            f"topic '{spec.topic}': no time column (Time, or s and ns); name it "
            f"with topics.{spec.topic}.time in {map_path}",
            where,
        )
    cols = spec.time_fields()
    return cols, (f"{cols[0]} column" if len(cols) == 1 else f"{cols[0]} + {cols[1]} columns")


def read_topic_csv(
    path: Path,
    spec: TopicSpec,
    fields: set[str],
    problems: Problems,
    map_path: str = "the topic map",
) -> TopicData:
    """One topic's CSV file: sample times [s] and the requested columns as floats."""
    where = str(path)
    reader = csv.reader(io.StringIO(_read_text(path)))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise InputError(f"topic '{spec.topic}': empty file", where) from None
    except csv.Error as exc:
        raise InputError(f"topic '{spec.topic}': not CSV ({exc})", where, line=1) from None
    tcols, tdesc = _time_columns(spec, header, where, map_path)
    wanted = sorted(fields)
    index = {}
    for name in list(tcols) + wanted:
        if name not in header:
            raise InputError(
                f"topic '{spec.topic}': field '{name}' is not a column (columns: "
                f"{', '.join(h for h in header if h) or 'none'})",
                where,
                line=1,
            )
        if header.count(name) > 1:
            raise InputError(f"topic '{spec.topic}': column '{name}' appears twice", where, line=1)
        index[name] = header.index(name)
    t, rows, bad, first_bad, short, min_len = [], [], [], None, 0, len(header)
    n_rows = 0
    try:
        for n_rows, row in enumerate(reader, start=1):
            line = n_rows + 1
            if not row:
                n_rows -= 1
                continue
            if len(row) > len(header):
                bad.append(line)
                first_bad = first_bad or (line, f"{len(row)} cells, header has {len(header)}")
                continue
            short += len(row) < len(header)
            min_len = min(min_len, len(row))
            vals, why = _row_values(row, index, tcols, wanted)
            if why:
                bad.append(line)
                first_bad = first_bad or (line, why)
                continue
            t.append(vals[0])
            rows.append(vals[1:])
    except csv.Error as exc:
        raise InputError(f"topic '{spec.topic}': not CSV ({exc})", where, line=n_rows + 2) from None
    if n_rows and (len(bad) > MAX_MALFORMED_FRACTION * n_rows or not t):
        raise InputError(
            f"topic '{spec.topic}': {len(bad)} of {n_rows} rows are malformed "
            f"(first: {first_bad[1]})"
            if first_bad
            else f"topic '{spec.topic}': no usable row",
            where,
            line=first_bad[0] if first_bad else None,
        )
    if not t:
        raise InputError(f"topic '{spec.topic}': no data row", where)
    if bad:
        assert first_bad is not None  # recorded with the first bad row
        problems.add(
            KIND_MALFORMED,
            where,
            bad[: Problems.MAX_FIRST],
            count=len(bad),
            detail=f"topic '{spec.topic}': {first_bad[1]}",
        )
    if short:
        problems.add(
            KIND_SHORT_ROWS,
            where,
            count=short,
            info=True,
            detail=f"topic '{spec.topic}': at most {min_len} of {len(header)} cells; "
            f"columns {', '.join(header[min_len:])} have no value there",
        )
    ta = np.asarray(t, float)
    va = np.asarray(rows, float).reshape(len(rows), len(wanted))
    if np.any(np.diff(ta) < 0):
        problems.add(
            KIND_UNSORTED, where, count=int(np.sum(np.diff(ta) < 0)), detail=f"topic '{spec.topic}'"
        )
    order = np.argsort(ta, kind="stable")
    out = {name: va[order, i] for i, name in enumerate(wanted)}
    return TopicData(spec.topic, ta[order], out, where, None, tdesc)


def _row_values(
    row: list[str], index: dict[str, int], tcols: tuple[str, ...], wanted: list[str]
) -> tuple[list[float], str | None]:
    """[time, *wanted values] of a row, or the reason it is malformed."""

    def cell(name: str) -> str:
        j = index[name]
        return row[j].strip() if j < len(row) else ""

    vals = []
    try:
        parts = [float(cell(c)) for c in tcols]
    except ValueError:
        return [], f"time {', '.join(repr(cell(c)) for c in tcols)} is not a number"
    ts = parts[0] + (parts[1] / 1e9 if len(parts) > 1 else 0.0)
    if not math.isfinite(ts):
        return [], "time is not finite"
    vals.append(ts)
    for name in wanted:
        text = cell(name)
        if text == "" or text.lower() == "nan":
            vals.append(math.nan)
            continue
        try:
            vals.append(float(text))
        except ValueError:
            return [], f"field '{name}' value {text!r} is not a number"
    return vals, None
