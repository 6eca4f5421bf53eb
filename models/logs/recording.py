"""The canonical recording: one table, a column per channel, on a uniform time grid.

:class:`Recording` is the in-memory table and its access; reading and validating a file
(:func:`read_channels`) and writing one (:func:`write_csv`, :func:`write_parquet`) are functions
beside it.

Channel names and units are those of ``docs/conventions.md`` (see ``models.logs.channels``).
Columns not available are absent, never zero-filled. Samples inside a gap longer than the
ingest threshold are NaN (``""`` for ``gear``), and the gaps are listed in ``meta['gaps']``.
The raw, un-resampled samples of each channel stay available in ``raw``.
"""

from __future__ import annotations

import csv
import gzip
import io
import zlib
import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hmpc.models.logs.files import open_text
from hmpc.models.errors import InputError
from hmpc.models.logs.channels import CHANNELS, STRING_CHANNELS, VALID_GEARS

#: channels that are fractions 0..1 (CONVENTIONS), and how far past the ends a reading may be
#: (sensor noise) before the file is refused as being in other units (e.g. percent)
FRACTION_CHANNELS = ("accel_pedal", "brake_pedal", "accel_pedal_cmd", "brake_pedal_cmd")
FRACTION_SLACK = 0.05
#: how far one time step may differ from the grid's median step (factor) before the file is
#: refused as not on a uniform grid: rounding and logger jitter pass, a clock jump does not
GRID_TOLERANCE = 1.5


@dataclass
class Recording:
    """A canonical recording.

    Attributes:
        channels: name -> 1-D array on the grid ``channels['time']`` [SI units, see CHANNELS].
        raw: name -> (t_s, values) as sampled by the source, before resampling (may be empty).
        meta: free-form provenance: sources, clock offsets, gaps, rate.
    """

    channels: dict[str, np.ndarray]
    raw: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    @property
    def time(self) -> np.ndarray:
        return self.channels["time"]

    def __contains__(self, name: str) -> bool:
        return name in self.channels

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.channels[name]
        except KeyError:
            raise InputError(
                "required channel is absent from the recording", self.meta.get("path"), channel=name
            ) from None

    def require(self, *names: str) -> None:
        """Raise InputError naming the first of ``names`` that the recording lacks."""
        for n in names:
            if n not in self.channels:
                raise InputError(
                    "required channel is absent from the recording",
                    self.meta.get("path"),
                    channel=n,
                )

    def __len__(self) -> int:
        return int(self.time.shape[0])

    @property
    def rate_hz(self) -> float:
        t = self.time
        return float(1.0 / np.median(np.diff(t))) if len(t) > 1 else float("nan")

    def slice(self, mask) -> Recording:
        """A new recording holding the rows in ``mask`` (raw samples are not sliced)."""
        return Recording({k: v[mask] for k, v in self.channels.items()}, self.raw, dict(self.meta))

    # ------------------------------------------------------------------ I/O
    def to_csv(self, path: str | Path) -> None:
        """Write the canonical CSV (see :func:`write_csv`)."""
        write_csv(self.channels, path)

    def to_parquet(self, path: str | Path) -> None:
        """Write Parquet (see :func:`write_parquet`)."""
        write_parquet(self.channels, path)

    def save(self, path: str | Path) -> None:
        """Write CSV, or Parquet when the name ends in .parquet."""
        if str(path).endswith(".parquet"):
            self.to_parquet(path)
        else:
            self.to_csv(path)

    @classmethod
    def load(cls, path: str | Path, *, allow_extra: bool = False) -> Recording:
        """Read a canonical recording (CSV, CSV.gz or Parquet); see :func:`read_channels`."""
        return cls(read_channels(path, allow_extra=allow_extra), {}, {"path": str(Path(path))})


# ---------------------------------------------------------------------- writing
#: rows from which :func:`write_csv` turns the second half of the rows to text in a forked
#: child process while it does the first half: the text (``repr`` of every number) costs per
#: row, the fork and the pipe once; below this many rows (a minute at 50 Hz is 3000) the split
#: saves too little to matter (``docs/benchmarks.md`` has the hour's figures)
CSV_SPLIT_ROWS = 50_000


def write_csv(
    channels: dict[str, np.ndarray], path: str | Path, *, split_rows: int = CSV_SPLIT_ROWS
) -> None:
    r"""Write the canonical CSV (columns in CONVENTIONS order, unknown extras last).

    Cells: ``time`` as ``f"{x:.6f}"``, numbers as ``repr(float(x))`` (empty for NaN), strings
    as they are, in ``csv.writer``'s dialect (``\r\n`` line ends, minimal quoting). Each column
    is turned to text in one pass and the rows are joined in bulk. From ``split_rows`` rows on
    (and where ``os.fork`` exists) a child process makes the text of the second half of the
    rows meanwhile and hands it back through a pipe (on Linux); the bytes written are the
    same.
    """
    names = [c for c in CHANNELS if c in channels]
    names += [c for c in channels if c not in CHANNELS]
    path = Path(path)
    n = len(channels[names[0]]) if names else 0
    # written beside the target and renamed over it: a failed write (full disk, interrupt)
    # never leaves a half-written recording under the name the user gave
    regular = path.is_file() or not path.exists()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp") if regular else path
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(tmp, "wt", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            if len(names) == 1:  # a one-cell row: csv quotes an empty cell, let it
                w.writerows(zip(*[_csv_cells(names[0], channels[names[0]])]))
            else:
                mid = n // 2 if n >= max(split_rows, 2) and _CAN_FORK else n
                with _RowsInChild(names, channels, mid, n) as child:
                    _write_rows(fh, names, channels, 0, mid)
                    text = child.text()
                    if text is None:  # no child, or it failed: this process does it
                        _write_rows(fh, names, channels, mid, n)
                    else:
                        fh.write(text)
        if tmp != path:
            os.replace(tmp, path)
    finally:
        if tmp != path and tmp.exists():
            tmp.unlink()


#: where :func:`write_csv` may fork: Linux (macOS system libraries are not safe to use in a
#: child forked from a process with threads, and Windows has no fork)
_CAN_FORK = sys.platform.startswith("linux") and hasattr(os, "fork")
#: rows joined into one string per write of :func:`write_csv`
CSV_ROWS_PER_WRITE = 1 << 14


def _rows_text(names: list[str], channels: dict, lo: int, hi: int):
    """The CSV lines of rows [lo, hi), in pieces of :data:`CSV_ROWS_PER_WRITE` rows."""
    whole = lo == 0 and hi == len(channels[names[0]])
    rows = list(
        zip(
            *[
                _csv_cells(name, channels[name] if whole else channels[name][lo:hi])
                for name in names
            ]
        )
    )
    for i in range(0, len(rows), CSV_ROWS_PER_WRITE):
        yield "".join([",".join(r) + "\r\n" for r in rows[i : i + CSV_ROWS_PER_WRITE]])


def _write_rows(fh, names: list[str], channels: dict, lo: int, hi: int) -> None:
    for piece in _rows_text(names, channels, lo, hi):
        fh.write(piece)


class _RowsInChild:
    """The text of rows [lo, hi) made by a forked child process (none when lo == hi).

    The child only turns numbers to text and writes them to a pipe, then leaves with
    ``os._exit`` (no cleanup of the parent's state runs twice); every module it needs is
    imported already, so it takes no lock another thread of the parent could hold.
    :meth:`text` is None when there is no child or it failed; leaving the ``with`` block
    always closes the pipe and reaps the child.
    """

    def __init__(self, names: list[str], channels: dict, lo: int, hi: int):
        self.pid, self.fd = None, None
        if hi <= lo:
            return
        r, w = os.pipe()
        with warnings.catch_warnings():
            # Python >= 3.12 warns about fork in a process with threads (numpy's BLAS pool);
            # the child takes none of their locks, see the class docstring
            warnings.filterwarnings("ignore", ".*fork", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child
            try:
                os.close(r)
                with os.fdopen(w, "wb") as out:
                    for piece in _rows_text(names, channels, lo, hi):
                        out.write(piece.encode("utf-8", "surrogatepass"))
                os._exit(0)
            finally:
                os._exit(1)
        os.close(w)
        self.pid, self.fd = pid, r

    def __enter__(self) -> _RowsInChild:
        return self

    def text(self) -> str | None:
        if self.fd is None:
            return None
        with os.fdopen(self.fd, "rb") as pipe:
            self.fd = None
            data = pipe.read()
        ok = self._reap()
        return data.decode("utf-8", "surrogatepass") if ok else None

    def _reap(self) -> bool:
        pid, self.pid = self.pid, None
        return pid is not None and os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0

    def __exit__(self, *exc) -> None:
        if self.fd is not None:
            os.close(self.fd)  # a child still writing gets EPIPE and leaves
            self.fd = None
        self._reap()


def _csv_cells(name: str, v: np.ndarray) -> list[str]:
    """One column's cells as ``csv.writer`` would write them in a row of several cells."""
    if name in STRING_CHANNELS:
        text = [str(s) for s in v]
        return (
            [_csv_quoted(s) for s in text]
            if any(_CSV_SPECIAL & set(s) for s in set(text))
            else text
        )
    if name == "time":
        return list(map("{:.6f}".format, v.tolist()))
    x = v.astype(float)
    bits = x.view(np.int64)  # bit patterns: 0.0 and -0.0 differ, as their text does
    starts = np.flatnonzero(bits[1:] != bits[:-1]) + 1
    if len(starts) < len(x) // 2:  # a held value: one text per run of equal values
        starts = np.concatenate([[0], starts])
        texts = np.array(_float_cells(x[starts]), dtype=object)
        return np.repeat(texts, np.diff(np.append(starts, len(x)))).tolist()
    return _float_cells(x)


def _float_cells(x: np.ndarray) -> list[str]:
    """``repr(float(v))`` of each value, empty for NaN."""
    cells = list(map(float.__repr__, x.tolist()))
    for i in np.flatnonzero(np.isnan(x)).tolist():
        cells[i] = ""
    return cells


#: characters that make ``csv.writer`` quote a cell (its default dialect)
_CSV_SPECIAL = frozenset(',"\r\n')


def _csv_quoted(cell: str) -> str:
    buf = io.StringIO()
    csv.writer(buf).writerow([cell, ""])
    return buf.getvalue()[:-3]  # without the empty second cell and the line end


def write_parquet(channels: dict[str, np.ndarray], path: str | Path) -> None:
    """Write the channels as a Parquet table (needs the optional pyarrow)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # optional dependency
        raise InputError(
            "writing Parquet needs pyarrow (pip install 'hmpc[parquet]')", str(path)
        ) from None
    pq.write_table(pa.table({k: v for k, v in channels.items()}), str(path))


# ---------------------------------------------------------------------- reading and validation
def read_channels(path: str | Path, *, allow_extra: bool = False) -> dict[str, np.ndarray]:
    """The channels of a canonical recording file (CSV, CSV.gz or Parquet), validated.

    Raises InputError for a missing or empty file, unknown columns (unless
    ``allow_extra``), a column named twice, non-numeric or infinite values, pedals outside
    0..1, unknown gears, or a time column that is not strictly increasing on one uniform grid.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", str(path))
    if path.suffix == ".parquet":
        header, text_cols, first_line = _read_parquet_text(path)
    else:
        header, text_cols, first_line = _read_csv_text(path)
    if "time" not in header:
        raise InputError("no 'time' column: not a canonical recording", str(path), channel="time")
    twice = [h for i, h in enumerate(header) if h in header[:i]]
    if twice:
        raise InputError(
            "column appears twice in the header",
            str(path),
            line=None if first_line is None else first_line - 1,
            channel=twice[0],
        )
    unknown = [h for h in header if h not in CHANNELS]
    if unknown and not allow_extra:
        raise InputError("unknown column (not a canonical channel)", str(path), channel=unknown[0])
    channels = {n: _parse_column(n, text_cols[n], path, first_line) for n in header}
    _check_time(channels["time"], path)
    _check_values(channels, path, first_line)
    return channels


def _read_parquet_text(path: Path) -> tuple[list[str], dict[str, list[str]], None]:
    """Header and columns as text of a Parquet file (no line numbers: the third item is None)."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise InputError("reading Parquet needs pyarrow", str(path)) from None
    tab = pq.read_table(str(path))
    cols = {n: tab.column(n).to_numpy() for n in tab.column_names}
    header = list(cols)
    return header, {n: [str(x) for x in cols[n]] for n in header}, None


def _read_csv_text(path: Path) -> tuple[list[str], dict[str, list[str]], int]:
    """Header and columns as text of a CSV (or .gz) file, and the line of the first row (2)."""
    try:
        with open_text(path, newline="") as fh:
            text = fh.read()
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", str(path)) from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise InputError("empty file", str(path)) from None
    rows = list(reader)
    for i, r in enumerate(rows):
        if len(r) != len(header):
            raise InputError(
                f"expected {len(header)} fields, found {len(r)}", str(path), line=i + 2
            )
    return header, {n: [r[j] for r in rows] for j, n in enumerate(header)}, 2


def _parse_column(name: str, vals: list[str], path: Path, first_line: int | None) -> np.ndarray:
    """A column's text as its array: strings for string channels, floats ("" is NaN) else."""
    if name in STRING_CHANNELS:
        return np.array(vals, dtype=object)
    try:
        return np.array([float(v) if v != "" else np.nan for v in vals])
    except ValueError:
        bad = next(i for i, v in enumerate(vals) if not _is_float(v))
        raise InputError(
            f"value {vals[bad]!r} is not a number",
            str(path),
            line=None if first_line is None else bad + first_line,
            channel=name,
        ) from None


def _check_time(t: np.ndarray, path: Path) -> None:
    """The time column must have rows, be finite, strictly increase and be one uniform grid
    (each step within GRID_TOLERANCE of the median step)."""
    if len(t) == 0:
        raise InputError("no rows", str(path))
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise InputError("time is not finite", str(path), line=bad + 2, channel="time")
    d = np.diff(t)
    if np.any(d <= 0):
        bad = int(np.flatnonzero(d <= 0)[0]) + 1
        raise InputError("time is not strictly increasing", str(path), line=bad + 2, channel="time")
    if len(d):
        # CONVENTIONS: one uniform grid; a gap is rows with empty cells, never a step in time
        step = float(np.median(d))
        off = (d > GRID_TOLERANCE * step) | (d < step / GRID_TOLERANCE)
        if off.any():
            bad = int(np.flatnonzero(off)[0]) + 1
            raise InputError(
                f"time steps {d[bad - 1]:.6g} s where the grid step is {step:.6g} s "
                "(a clock jump?); a recording is on one uniform grid, a gap is "
                "rows with empty cells",
                str(path),
                line=bad + 2,
                channel="time",
            )


def _check_values(channels: dict[str, np.ndarray], path: Path, first_line: int | None) -> None:
    """No infinite number, pedals as fractions 0..1, gears from CONVENTIONS: otherwise
    InputError naming the line and channel of the first bad value (a missing sample, empty
    or NaN, is a gap and allowed)."""

    def fail(name: str, i: int, why: str):
        raise InputError(
            why, str(path), line=None if first_line is None else i + first_line, channel=name
        )

    for name, v in channels.items():
        if name in STRING_CHANNELS:
            if name == "gear":
                bad = [i for i, g in enumerate(v) if g != "" and str(g) not in VALID_GEARS]
                if bad:
                    fail(
                        name,
                        bad[0],
                        f"gear {v[bad[0]]!r} is not one of "
                        f"{', '.join(sorted(VALID_GEARS))} (or empty)",
                    )
            continue
        inf = np.isinf(v)
        if inf.any():
            i = int(np.flatnonzero(inf)[0])
            fail(name, i, f"value {v[i]} is not finite (leave the cell empty for a gap)")
        if name in FRACTION_CHANNELS:
            out = (v < -FRACTION_SLACK) | (v > 1 + FRACTION_SLACK)
            if out.any():
                i = int(np.flatnonzero(out)[0])
                fail(name, i, f"value {v[i]:g} is outside 0..1 (pedals are fractions, not percent)")


def _is_float(v: str) -> bool:
    if v == "":
        return True
    try:
        float(v)
        return True
    except ValueError:
        return False
