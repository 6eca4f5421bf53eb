"""CAN log readers: every log a vehicle engineer brings, to one :class:`FrameTable`.

Formats (``fmt`` names):

``candump``
    ``candump -L`` text, ``(1533226488.434433) can0 2E4#BE000000A9`` (also ``ID##<flags><data>``
    CAN FD frames and ``ID#R`` remote frames, and a trailing ``R``/``T`` direction flag).
    Parsed by ``models.logs.candump``: the lines of a common layout in bulk, the rest by a
    general vectorised parser (no Python loop per line either way).
``libpanda``
    The libpanda/strym CSV layout ``Time,Bus,MessageID,Message[,MessageLength][,...]``
    (decimal id, hex payload; columns found by header name, extra columns ignored).
    Parsed by ``models.logs.libpanda`` (vectorised).
``asc``, ``blf``, ``trc``, ``csv`` (python-can's CSV), ``mf4``, ``sqlite``
    Read through python-can's own readers.

Any of these may be gzip-compressed (``.gz``). Without ``fmt`` the format comes from the file
suffix, confirmed (or, for an unknown suffix, found) by looking at the first line.

Bad input (``docs/conventions.md``): malformed lines (truncated, garbled, non-hex, binary
garbage) are skipped, counted and reported with their first line numbers in a
:class:`~models.errors.Problems` collector; so are remote and error frames (no payload to decode)
and exact duplicate frames. Timestamps going backwards are re-sorted (stable) and reported;
forward clock jumps longer than ``jump_s`` are reported (frames kept). An empty file, a file with
no usable frame or an unknown format raises :class:`~models.errors.InputError` naming the file
(and the line or frame where it applies).

``FrameTable.bus`` is the number at the end of the interface name (``can1`` -> 1, ``vcan0`` -> 0);
a name without a number, or whose number another name already took, gets the next free number.
"""

from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.candump import CandumpScanner
from hmpc.models.logs.frames import MAX_PAYLOAD, FrameTable
from hmpc.models.logs.libpanda import LibpandaChunkParser
from hmpc.models.logs.files import open_text
from hmpc.models.logs.files import is_gzip, open_binary
from hmpc.models.logs.textblocks import PAD, FrameSink, iter_blocks, text_bytes
from hmpc.models.logs.textscan import SKIP_ERROR_FRAME, SKIP_MALFORMED, SKIP_REMOTE

#: formats read by hmpc's own vectorised text readers
TEXT_FORMATS = ("candump", "libpanda")
#: formats read through python-can's readers -> (reader class name, binary file?)
PYTHON_CAN_FORMATS = {
    "asc": ("ASCReader", False),
    "blf": ("BLFReader", True),
    "trc": ("TRCReader", False),
    "csv": ("CSVReader", False),
    "mf4": ("MF4Reader", True),
    "sqlite": ("SqliteReader", True),
}
FORMATS = TEXT_FORMATS + tuple(PYTHON_CAN_FORMATS)
_SUFFIX_FORMAT = {".asc": "asc", ".blf": "blf", ".trc": "trc", ".mf4": "mf4", ".db": "sqlite"}

# Problem kinds (stable strings: ``hmpc info`` and --json key on them).
KIND_MALFORMED = "malformed line (skipped)"
KIND_REMOTE = "remote frame (no payload, dropped)"
KIND_ERROR_FRAME = "error frame (dropped)"
KIND_DUPLICATE = "duplicate frame (same time, bus, id and payload; dropped)"
KIND_BACKWARDS = "timestamp earlier than the previous frame (frames re-sorted by time, kept)"
KIND_JUMP = "clock jump forward (frames kept)"
KIND_TRUNCATED = "the gzip stream ends early: the log is cut there (the frames before it are read)"
#: kinds whose frames were dropped (the rest are kept and only reported)
DROPPED_KINDS = (KIND_MALFORMED, KIND_REMOTE, KIND_ERROR_FRAME, KIND_DUPLICATE)

#: bytes read per chunk by the text readers: big enough to amortise numpy calls, small enough
#: that the per-chunk index arrays (~60 int64 per line of the general parser) stay near 100 MB.
CHUNK_BYTES = 8 * 1024 * 1024


# ----------------------------------------------------------------------------- entry point
def read_log(
    path,
    problems: Problems,
    *,
    fmt: str | None = None,
    jump_s: float = 1.0,
    chunk_bytes: int = CHUNK_BYTES,
) -> FrameTable:
    """Read a CAN log into a :class:`FrameTable`, sorted by time.

    Args:
        path: the log file (any format in this module's docstring, optionally ``.gz``).
        problems: collector for recoverable problems (malformed lines, duplicates, clock).
        fmt: force a format (one of :data:`FORMATS`) instead of detecting it.
        jump_s: forward gaps between consecutive frames longer than this [s] are reported as
            clock jumps.
        chunk_bytes: bytes per chunk of the text readers (memory/speed trade-off).

    Returns:
        The frames; ``where`` holds the 1-based source line (candump, libpanda) or frame
        number (formats read through python-can).

    Raises:
        InputError: missing/empty/unreadable file, unknown format, or no usable frame.
    """
    p, gz, head, fmt = _resolve(path, fmt)
    if fmt == "candump":
        table = _read_text(
            p,
            gz,
            problems,
            CandumpScanner(),
            first_line=1,
            chunk_bytes=chunk_bytes,
            what="candump -L",
        )
    elif fmt == "libpanda":
        cols, header_lines = _libpanda_columns(p, head)
        table = _read_text(
            p,
            gz,
            problems,
            LibpandaChunkParser(cols).scan,
            first_line=1 + header_lines,
            chunk_bytes=chunk_bytes,
            what="libpanda CSV",
        )
    else:
        table = _read_python_can(p, gz, fmt, problems)
    return _clock_checks(table, problems, jump_s)


def detect_format(path) -> str:
    """The format :func:`read_log` would use for ``path`` (one of :data:`FORMATS`).

    Raises:
        InputError: missing or empty file, or an unknown format.
    """
    return _resolve(path, None)[3]


def _resolve(path, fmt):
    p = Path(path)
    spath = str(path)
    if not p.exists():
        raise InputError("no such file", spath)
    if not p.is_file():
        raise InputError("not a regular file", spath)
    if fmt is not None and fmt not in FORMATS:
        raise ValueError(f"unknown log format {fmt!r}; expected one of {', '.join(FORMATS)}")
    gz = is_gzip(p)
    head = _head(p, gz)
    if not head.strip():
        raise InputError("empty file (no CAN frame)", spath)
    if fmt is None:
        fmt = _detect_format(p, gz, head)
    return p, gz, head, fmt


def _head(p: Path, gz: bool, n: int = 4096) -> bytes:
    try:
        with open_binary(p, gz) as fh:
            return fh.read(n)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read: {exc}", str(p)) from None


def _first_line(head: bytes) -> bytes:
    for line in head.splitlines():
        if line.strip():
            return line.strip()
    return b""


def _looks_candump(head: bytes) -> bool:
    """Any of the first lines shaped like ``(time) name ID#...``."""
    for line in head.splitlines()[:20]:
        line = line.strip()
        if line.startswith(b"(") and b") " in line and b"#" in line:
            return True
    return False


def _looks_libpanda(head: bytes) -> bool:
    names = [c.strip().decode("ascii", "replace") for c in _first_line(head).split(b",")]
    return {"Time", "Bus", "MessageID", "Message"} <= set(names)


def _looks_python_can_csv(head: bytes) -> bool:
    return _first_line(head).lower().startswith(b"timestamp,arbitration_id")


def _detect_format(p: Path, gz: bool, head: bytes) -> str:
    """Format from the suffix (``.gz`` stripped), confirmed by the first line for text logs."""
    suffixes = [s.lower() for s in p.suffixes]
    if gz and suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    suffix = suffixes[-1] if suffixes else ""
    if suffix in _SUFFIX_FORMAT:
        return _SUFFIX_FORMAT[suffix]
    if _looks_libpanda(head):
        return "libpanda"
    if suffix == ".log":  # python-can's convention: .log is candump -L
        return "candump"
    if _looks_candump(head):
        return "candump"
    if _looks_python_can_csv(head):
        return "csv"
    if suffix == ".csv":
        raise InputError(
            "unknown log format: a .csv file whose header is neither libpanda's "
            "'Time,Bus,MessageID,Message' nor python-can's "
            "'timestamp,arbitration_id,...'",
            str(p),
            line=1,
        )
    raise InputError(
        f"unknown log format (suffix {suffix or 'none'!r}); hmpc reads candump -L, "
        "libpanda CSV and python-can's .asc/.blf/.trc/.csv/.mf4/.db, optionally .gz",
        str(p),
    )


# ----------------------------------------------------------------------------- text readers
#: why a text parser skipped a line -> the problem kind reported
_SKIP_KIND = {
    SKIP_MALFORMED: KIND_MALFORMED,
    SKIP_REMOTE: KIND_REMOTE,
    SKIP_ERROR_FRAME: KIND_ERROR_FRAME,
}
#: the frame columns are first sized for this many times the lines the first block promises
_CAPACITY_MARGIN = 1.05


def _read_text(
    p: Path, gz: bool, problems: Problems, scan, *, first_line: int, chunk_bytes: int, what: str
) -> FrameTable:
    """Read a text log block by block; ``scan(base, pad, nl, line0, first_line)`` yields each
    block's frames as parts in line order (``models.logs.candump``/``libpanda``)."""
    spath = str(p)
    mapper = _BusMapper()
    sink = None
    skipped: dict[str, list] = {}
    line0 = 0
    cut_at: list[int] = []
    with ThreadPoolExecutor(1) as pool:
        try:
            for base, nl, cut in iter_blocks(p, gz, chunk_bytes, on_truncated=cut_at.append):
                if sink is None:
                    per_byte = len(nl) / (int(nl[-1]) + 1)
                    sink = FrameSink(int(text_bytes(p, gz) * per_byte * _CAPACITY_MARGIN))
                    pool.submit(sink.prefault)  # the columns' first-touch page faults, ahead
                for ch in scan(base, PAD, nl, line0, first_line):
                    for why, lines in ch.skipped.items():
                        if len(lines):
                            skipped.setdefault(_SKIP_KIND[why], []).append(lines)
                    bus = ch.bus.astype(np.int16) if ch.bus.ndim == 1 else mapper.map(ch.bus)
                    sink.append(ch, bus)
                line0 += len(nl) - cut
        finally:
            if sink is not None:
                sink.close()
    for kind in DROPPED_KINDS:
        if kind in skipped:
            lines = np.concatenate(skipped[kind])
            problems.add(
                kind,
                spath,
                lines[: Problems.MAX_FIRST],
                count=len(lines),
                detail=f"not a valid {what} line" if kind == KIND_MALFORMED else "",
            )
    if cut_at:
        problems.add(
            KIND_TRUNCATED,
            spath,
            line0 + first_line - 1,
            detail=f"after {cut_at[0]} bytes of text, in line {line0 + first_line - 1}",
        )
    table = sink.table(spath) if sink is not None else FrameTable.empty(spath)
    if len(table) == 0:
        bad = skipped.get(KIND_MALFORMED)
        first = int(np.concatenate(bad)[0]) if bad else None
        raise InputError(
            f"no usable CAN frame: not a {what} log, or every line is malformed", spath, line=first
        )
    return table


def _libpanda_columns(p: Path, head: bytes):
    """Column indices of the libpanda header -> ({name: index, 'ncols': n}, header lines)."""
    nblank = 0
    for line in head.splitlines():
        if line.strip():
            break
        nblank += 1
    names = [c.strip().decode("ascii", "replace") for c in _first_line(head).split(b",")]
    missing = [c for c in ("Time", "Bus", "MessageID", "Message") if c not in names]
    if missing:
        raise InputError(
            f"libpanda CSV header lacks column(s) {', '.join(missing)}", str(p), line=nblank + 1
        )
    cols: dict[str, int | None] = {
        c: names.index(c) for c in ("Time", "Bus", "MessageID", "Message")
    }
    cols["MessageLength"] = names.index("MessageLength") if "MessageLength" in names else None
    cols["ncols"] = len(names)
    return cols, nblank + 1


class _BusMapper:
    """Interface names -> bus numbers, stable over the whole file (see module docstring)."""

    def __init__(self):
        self.names: dict[bytes, int] = {}

    def number_of(self, name: bytes) -> int:
        num = self.names.get(name)
        if num is None:
            text = name.decode("latin-1")
            digits = len(text) - len(text.rstrip("0123456789"))
            taken = set(self.names.values())
            if digits and int(text[-digits:]) not in taken and int(text[-digits:]) < 2**15:
                num = int(text[-digits:])
            else:
                num = max(taken | {-1}) + 1
            self.names[name] = num
        return num

    def map(self, names: np.ndarray) -> np.ndarray:
        """(n, 8|16) zero-padded names -> int16 bus numbers."""
        n, w = names.shape
        out = np.empty(n, np.int16)
        if n == 0:
            return out
        words = names.view("<u8")
        if w == 8 and words[0, 0] == words[-1, 0] and (words[:, 0] == words[0, 0]).all():
            out.fill(self.number_of(names[0].tobytes().rstrip(b"\0")))  # one interface
            return out
        key = words[:, 0] if w == 8 else words[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ words[:, 1]
        todo = np.ones(n, bool)
        while todo.any():
            i = int(np.argmax(todo))
            m = todo & (key == key[i])
            if w > 8:  # hashed key: confirm byte for byte
                m &= np.all(names == names[i], axis=1)
            out[m] = self.number_of(names[i].tobytes().rstrip(b"\0"))
            todo &= ~m
        return out


# ----------------------------------------------------------------------------- python-can
def _read_python_can(p: Path, gz: bool, fmt: str, problems: Problems) -> FrameTable:
    import can  # python-can: imported here, only needed for these formats

    spath = str(p)
    cls_name, binary = PYTHON_CAN_FORMATS[fmt]
    # ASC: absolute times (trigger-block start + offsets; the header has ms resolution), so
    # they line up with nav/IMU clocks like every other format's
    kwargs = {"relative_timestamp": False} if fmt == "asc" else {}
    cls = getattr(can, cls_name, None)
    if cls is None:
        raise InputError(f"python-can cannot read {fmt} files here ({cls_name} missing)", spath)
    t, bus, arb, ext, dlc, where, payloads = [], [], [], [], [], [], []
    remote, errf = [], []
    names: dict = {}
    frame_no = 0
    fh = None
    reader = None
    try:
        if gz:
            if fmt == "sqlite":
                raise InputError(
                    "a gzip-compressed sqlite log cannot be read; decompress it", spath
                )
            fh = open_binary(p, True) if binary else open_text(p, errors="replace")
            reader = cls(fh, **kwargs)
        elif fmt == "blf":  # python-can's BLFReader leaves the file it opens open on a bad header
            fh = open_binary(p, False)
            reader = cls(fh, **kwargs)
        else:
            reader = cls(spath, **kwargs)
        for msg in reader:
            frame_no += 1
            if msg.is_error_frame:
                errf.append(frame_no)
                continue
            if msg.is_remote_frame:
                remote.append(frame_no)
                continue
            data = bytes(msg.data or b"")
            if len(data) > MAX_PAYLOAD:
                problems.add(KIND_MALFORMED, spath, frame_no, detail="payload over 64 bytes")
                continue
            ch = msg.channel
            if ch is None:
                ch = 0
            if ch not in names:
                names[ch] = len(names)
            t.append(msg.timestamp)
            bus.append(ch)
            arb.append(msg.arbitration_id)
            ext.append(bool(msg.is_extended_id))
            dlc.append(len(data))
            where.append(frame_no)
            payloads.append(data)
    except InputError:
        raise
    except ImportError as exc:
        raise InputError(f"reading {fmt} files needs an extra package: {exc}", spath) from None
    except Exception as exc:  # python-can's readers raise many types on corrupt files
        raise InputError(
            f"python-can's {cls_name} failed after {frame_no} frames: {type(exc).__name__}: {exc}",
            spath,
            frame=frame_no + 1,
        ) from None
    finally:
        if reader is not None:
            reader.stop()  # closes the file the reader opened, also after a failure
        if fh is not None:
            fh.close()
    gzr = getattr(getattr(fh, "buffer", None), "raw", fh)
    if getattr(gzr, "truncated", False):
        assert gzr is not None
        problems.add(
            KIND_TRUNCATED,
            spath,
            frame_no,
            detail=f"after {gzr.text_bytes} bytes of text, after frame {frame_no}",
        )
    problems.add(KIND_REMOTE, spath, remote[: Problems.MAX_FIRST], count=len(remote))
    problems.add(KIND_ERROR_FRAME, spath, errf[: Problems.MAX_FIRST], count=len(errf))
    if not t:
        raise InputError(f"no usable CAN frame in this {fmt} log", spath)
    # bus numbers: int channels as they are, names by their trailing number
    mapper = _BusMapper()
    busmap = {}
    for ch in names:
        if isinstance(ch, (int, np.integer)) and not isinstance(ch, bool) and 0 <= ch < 2**15:
            busmap[ch] = mapper.names[b"\0int%d" % ch] = int(ch)
    for ch in names:
        if ch not in busmap:
            busmap[ch] = mapper.number_of(str(ch).encode("utf-8"))
    width = max(8, max(len(d) for d in payloads))
    table = np.zeros((len(payloads), width), np.uint8)
    for i, d in enumerate(payloads):
        table[i, : len(d)] = np.frombuffer(d, np.uint8)
    return FrameTable(
        np.asarray(t, np.float64),
        np.asarray([busmap[c] for c in bus], np.int16),
        np.asarray(arb, np.uint32),
        np.asarray(ext, bool),
        np.asarray(dlc, np.uint8),
        table,
        np.asarray(where, np.int64),
        spath,
    )


# ----------------------------------------------------------------------------- clock checks
#: rows per block of the clock checks: the block's temporaries stay in the CPU cache
_CHECK_ROWS = 1 << 14
#: runs of one timestamp longer than this compare whole rows, time bytes included (a sort),
#: instead of each frame against the ones before it in its run
_LONG_RUN = 32


def _clock_checks(ft: FrameTable, problems: Problems, jump_s: float) -> FrameTable:
    """Sort by time (reporting steps backwards), drop exact duplicates, report forward jumps."""
    spath = ft.path
    if not np.all(np.isfinite(ft.t_s)):
        bad = ~np.isfinite(ft.t_s)
        problems.add(
            KIND_MALFORMED,
            spath,
            ft.where[bad][: Problems.MAX_FIRST],
            count=int(bad.sum()),
            detail="timestamp is not a finite number",
        )
        ft = ft.take(~bad)
        if len(ft) == 0:
            raise InputError("no frame with a finite timestamp", spath)
    steps = _Steps(ft.t_s, jump_s)
    if len(steps.back):
        assert steps.dt_min is not None  # a step back is a negative step
        problems.add(
            KIND_BACKWARDS,
            spath,
            ft.where[steps.back[: Problems.MAX_FIRST]],
            count=len(steps.back),
            detail=f"largest step back {-steps.dt_min:.6g} s",
        )
        order = np.argsort(ft.t_s, kind="stable")
        ft = ft.take(order)
        steps = _Steps(ft.t_s, jump_s)
    # exact duplicates can only sit among frames that share a timestamp
    if len(steps.same):
        drop = _duplicates(ft, steps.same)
        if len(drop):
            problems.add(
                KIND_DUPLICATE,
                spath,
                np.sort(ft.where[drop])[: Problems.MAX_FIRST],
                count=len(drop),
            )
            keep = np.ones(len(ft), bool)
            keep[drop] = False
            ft = ft.take(keep)
            steps = _Steps(ft.t_s, jump_s)
    if len(steps.jumps):
        problems.add(
            KIND_JUMP,
            spath,
            ft.where[steps.jumps[: Problems.MAX_FIRST]],
            count=len(steps.jumps),
            detail=f"gap between consecutive frames over "
            f"{jump_s:g} s, largest {steps.dt_max:.6g} s",
        )
    return ft


class _Steps:
    """The steps ``dt = diff(t_s)``, block by block: rows after a step back (``back``), rows i
    with t[i] == t[i+1] (``same``), rows after a step over ``jump_s`` (``jumps``), and the
    smallest and largest step."""

    def __init__(self, t: np.ndarray, jump_s: float):
        back, same, jumps = [], [], []
        self.dt_min: float | None = None
        self.dt_max: float | None = None
        n = len(t) - 1
        buf = np.empty(min(max(n, 0), _CHECK_ROWS))
        for a in range(0, n, _CHECK_ROWS):
            b = min(a + _CHECK_ROWS, n)
            d = np.subtract(t[a + 1 : b + 1], t[a:b], out=buf[: b - a])
            lo, hi = d.min(), d.max()
            if lo < 0:
                back.append(np.flatnonzero(d < 0) + (a + 1))
            if lo <= 0:
                same.append(np.flatnonzero(d == 0) + a)
            if hi > jump_s:
                jumps.append(np.flatnonzero(d > jump_s) + (a + 1))
            self.dt_min = lo if self.dt_min is None else min(self.dt_min, lo)
            self.dt_max = hi if self.dt_max is None else max(self.dt_max, hi)
        empty = np.zeros(0, np.int64)
        self.back, self.same, self.jumps = (
            np.concatenate(x) if x else empty for x in (back, same, jumps)
        )


def _duplicates(ft: FrameTable, same: np.ndarray) -> np.ndarray:
    """Rows that repeat an earlier row exactly (time, bus, id, flags, payload).

    ``same``: rows i with t[i] == t[i+1] (the table is sorted by time); a streak of consecutive
    i is one run of frames sharing a timestamp. Block by block, a 64-bit hash of each frame
    (bus, id, flags, length, payload) screens the runs: two equal frames hash alike, so only
    the runs where two frames share a hash can hold duplicates, and only those are compared
    exactly (:func:`_duplicates_exact`).
    """
    suspects, longest = [], 0
    pos, m = 0, len(same)
    while pos < m:
        end = _streak_end(same, min(pos + _CHECK_ROWS, m))
        s = same[pos:end]
        brk = np.flatnonzero(s[1:] != s[:-1] + 1)  # last element of each streak but the final
        last = np.append(brk, len(s) - 1)
        longest = max(longest, int(np.diff(np.append(-1, last)).max()))
        sid = np.zeros(len(s), np.int64)
        sid[brk + 1] = 1
        np.cumsum(sid, out=sid)
        rows = np.concatenate([s, s[last] + 1])
        rid = np.concatenate([sid, np.arange(len(last))])
        key = (rid.astype(np.uint64) << np.uint64(32)) | (_frame_hash(ft, rows) >> np.uint64(32))
        key.sort(kind="stable")
        twice = key[1:][key[1:] == key[:-1]]
        if len(twice):
            suspects.append(rows[np.isin(rid, np.unique(twice >> np.uint64(32)))])
        pos = end
    if not suspects:
        return np.zeros(0, np.int64)
    return _duplicates_exact(ft, np.unique(np.concatenate(suspects)), longest + 1 > _LONG_RUN)


def _streak_end(same: np.ndarray, end: int) -> int:
    """The first index at or after ``end`` that starts a new streak of ``same`` (or its end)."""
    m = len(same)
    while end < m:
        w = same[end - 1 : end + 1023]
        brk = np.flatnonzero(w[1:] != w[:-1] + 1)
        if len(brk):
            return end + int(brk[0])
        end += len(w) - 1
    return m


def _frame_hash(ft: FrameTable, rows: np.ndarray) -> np.ndarray:
    """A 64-bit hash of each row's bus, id, flags, length and payload (not its time)."""
    h = (
        ft.arb_id.take(rows).astype(np.uint64)
        | (ft.is_extended.take(rows).astype(np.uint64) << np.uint64(29))
        | (ft.dlc.take(rows).astype(np.uint64) << np.uint64(32))
        | (ft.bus.take(rows).astype(np.uint16).astype(np.uint64) << np.uint64(40))
    )
    data = ft.data
    if data.shape[1] == 8 and data.flags.c_contiguous:
        words = data.view("<u8")[:, 0].take(rows)[:, None]
    else:
        padded = np.zeros((len(rows), -(-data.shape[1] // 8) * 8), np.uint8)
        padded[:, : data.shape[1]] = data[rows]
        words = padded.view("<u8")
    for j in range(words.shape[1]):
        h *= np.uint64(0x9E3779B97F4A7C15)
        h ^= words[:, j]
        h ^= h >> np.uint64(29)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(32)
    return h


def _duplicates_exact(ft: FrameTable, cand: np.ndarray, long_runs: bool) -> np.ndarray:
    """Rows of ``cand`` (whole runs of one timestamp, sorted) that repeat an earlier row
    exactly. With ``long_runs`` (some run of the table over :data:`_LONG_RUN` frames) whole
    rows are sorted, time bytes included; otherwise each frame is compared with the frames
    before it in its run (no hashing either way)."""
    t = ft.t_s[cand]
    meta = (
        ft.arb_id[cand].astype(np.uint64)
        | (ft.is_extended[cand].astype(np.uint64) << 29)
        | (ft.dlc[cand].astype(np.uint64) << 32)
        | (ft.bus[cand].astype(np.uint16).astype(np.uint64) << 40)
    )
    width = ft.data.shape[1]
    padded = np.zeros((len(cand), -(-width // 8) * 8), np.uint8)
    padded[:, :width] = ft.data[cand]
    words = padded.view("<u8")  # (m, ceil(width/8))
    # run starts within cand: a new run where the time differs from the previous candidate
    newrun = np.ones(len(cand), bool)
    newrun[1:] = t[1:] != t[:-1]
    runid = np.cumsum(newrun)
    runlen = np.bincount(runid)
    dup = np.zeros(len(cand), bool)
    if long_runs:  # long runs of one timestamp: sort whole rows instead
        key = np.concatenate(
            [t.view(np.uint8).reshape(-1, 8), meta.view(np.uint8).reshape(-1, 8), padded], axis=1
        )
        _, first = np.unique(key.view(np.dtype((np.void, key.shape[1]))).ravel(), return_index=True)
        dup[:] = True
        dup[first] = False
        return cand[dup]
    for d in range(1, int(runlen.max())):
        eq = (runid[d:] == runid[:-d]) & (meta[d:] == meta[:-d])
        eq &= np.all(words[d:] == words[:-d], axis=1)
        dup[d:] |= eq
    return cand[dup]
