"""CAN log readers: every log a vehicle engineer brings, to one :class:`FrameTable`.

Formats (``fmt`` names):

``candump``
    ``candump -L`` text, ``(1533226488.434433) can0 2E4#BE000000A9`` (also ``ID##<flags><data>``
    CAN FD frames and ``ID#R`` remote frames, and a trailing ``R``/``T`` direction flag).
    Parsed by hmpc's own vectorised reader (no Python loop per line).
``libpanda``
    The libpanda/strym CSV layout ``Time,Bus,MessageID,Message[,MessageLength][,...]``
    (decimal id, hex payload; columns found by header name, extra columns ignored).
    Parsed by hmpc's own vectorised reader.
``asc``, ``blf``, ``trc``, ``csv`` (python-can's CSV), ``mf4``, ``sqlite``
    Read through python-can's own readers.

Any of these may be gzip-compressed (``.gz``). Without ``fmt`` the format comes from the file
suffix, confirmed (or, for an unknown suffix, found) by looking at the first line.

Bad input (``../shared/CONVENTIONS.md``): malformed lines (truncated, garbled, non-hex, binary
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

import gzip
import zlib
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.frames import MAX_PAYLOAD, FrameTable

#: formats read by hmpc's own vectorised text readers
TEXT_FORMATS = ("candump", "libpanda")
#: formats read through python-can's readers -> (reader class name, binary file?)
PYTHON_CAN_FORMATS = {"asc": ("ASCReader", False), "blf": ("BLFReader", True),
                      "trc": ("TRCReader", False), "csv": ("CSVReader", False),
                      "mf4": ("MF4Reader", True), "sqlite": ("SqliteReader", True)}
FORMATS = TEXT_FORMATS + tuple(PYTHON_CAN_FORMATS)
_SUFFIX_FORMAT = {".asc": "asc", ".blf": "blf", ".trc": "trc", ".mf4": "mf4", ".db": "sqlite"}

# Problem kinds (stable strings: ``hmpc info`` and --json key on them).
KIND_MALFORMED = "malformed line (skipped)"
KIND_REMOTE = "remote frame (no payload, dropped)"
KIND_ERROR_FRAME = "error frame (dropped)"
KIND_DUPLICATE = "duplicate frame (same time, bus, id and payload; dropped)"
KIND_BACKWARDS = "timestamp earlier than the previous frame (frames re-sorted by time, kept)"
KIND_JUMP = "clock jump forward (frames kept)"
#: kinds whose frames were dropped (the rest are kept and only reported)
DROPPED_KINDS = (KIND_MALFORMED, KIND_REMOTE, KIND_ERROR_FRAME, KIND_DUPLICATE)

#: bytes read per chunk by the text readers: big enough to amortise numpy calls, small enough
#: that the per-chunk index arrays (~60 int64 per line) stay near 100 MB.
CHUNK_BYTES = 8 * 1024 * 1024
#: a "line" longer than this (binary garbage without newlines) is cut into pieces of this size
MAX_LINE_BYTES = 1024 * 1024

_CAN_ERR_FLAG = 0x20000000  # SocketCAN error-frame flag in the 32-bit id
_EFF_MASK = 0x1FFFFFFF      # 29-bit identifier
_SFF_MAX = 0x7FF            # 11-bit identifier

_HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    _HEX[_c] = 10 + _i
_DEC = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789"):
    _DEC[_c] = _i
del _i, _c
_POW10_I = 10 ** np.arange(19, dtype=np.int64)
_POW10_F = 10.0 ** np.arange(25)
_POW10_LD = np.longdouble(10) ** np.arange(25).astype(np.longdouble)
#: two hex digits (as a little-endian uint16 of their bytes) -> byte value, 0xFFFF if not hex
_HEX2 = np.where((_HEX[np.arange(65536) & 0xFF] < 16) & (_HEX[np.arange(65536) >> 8] < 16),
                 _HEX[np.arange(65536) & 0xFF].astype(np.uint16) * 16 + _HEX[np.arange(65536) >> 8],
                 0xFFFF).astype(np.uint16)
_LONGDOUBLE_OK = np.finfo(np.longdouble).nmant >= 63  # x87 80-bit or IEEE quad
_TWO53 = 2 ** 53


# ----------------------------------------------------------------------------- entry point
def read_log(path, problems: Problems, *, fmt: str | None = None, jump_s: float = 1.0,
             chunk_bytes: int = CHUNK_BYTES) -> FrameTable:
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
        table = _read_text(p, gz, problems, _parse_candump_chunk, first_line=1,
                           chunk_bytes=chunk_bytes, what="candump -L")
    elif fmt == "libpanda":
        cols, header_lines = _libpanda_columns(p, head)
        parser = _LibpandaChunkParser(cols)
        table = _read_text(p, gz, problems, parser, first_line=1 + header_lines,
                           chunk_bytes=chunk_bytes, what="libpanda CSV")
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
    gz = _is_gzip(p)
    head = _head(p, gz)
    if not head.strip():
        raise InputError("empty file (no CAN frame)", spath)
    if fmt is None:
        fmt = _detect_format(p, gz, head)
    return p, gz, head, fmt


def _is_gzip(p: Path) -> bool:
    with open(p, "rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def _open_bytes(p: Path, gz: bool):
    return gzip.open(p, "rb") if gz else open(p, "rb")


def _head(p: Path, gz: bool, n: int = 4096) -> bytes:
    try:
        with _open_bytes(p, gz) as fh:
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
        raise InputError("unknown log format: a .csv file whose header is neither libpanda's "
                         "'Time,Bus,MessageID,Message' nor python-can's "
                         "'timestamp,arbitration_id,...'", str(p), line=1)
    raise InputError(f"unknown log format (suffix {suffix or 'none'!r}); hmpc reads candump -L, "
                     "libpanda CSV and python-can's .asc/.blf/.trc/.csv/.mf4/.db, optionally .gz",
                     str(p))


# ----------------------------------------------------------------------------- text readers
def _iter_chunks(p: Path, gz: bool, chunk_bytes: int):
    """Yield (block, cut) with blocks that end at a line break (the last one gets one).

    A newline-free run longer than :data:`MAX_LINE_BYTES` (binary garbage) is cut into
    pieces; ``cut`` is 1 when the block's final line break was added there, so the caller
    keeps counting lines as the file has them (the pieces share one line number).
    """
    rest = b""
    try:
        with _open_bytes(p, gz) as fh:
            while True:
                block = fh.read(chunk_bytes)
                if not block:
                    break
                buf = rest + block if rest else block
                cut = buf.rfind(b"\n")
                if cut < 0:
                    if len(buf) <= MAX_LINE_BYTES:
                        rest = buf
                        continue
                    yield buf + b"\n", 1  # a giant newline-free blob: never valid, cut it
                    rest = b""
                    continue
                yield buf[:cut + 1], 0
                rest = buf[cut + 1:]
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read (corrupt or truncated file?): {exc}", str(p)) from None
    if rest:
        yield rest + b"\n", 0


def _line_bounds(b: np.ndarray):
    """Start and end (exclusive, without CR) of every line in ``b`` (which ends with LF)."""
    nl = np.flatnonzero(b == 10)
    ls = np.empty_like(nl)
    ls[:1] = 0
    ls[1:] = nl[:-1] + 1
    le = nl.copy()
    cr = (le > ls) & (b[np.maximum(le - 1, 0)] == 13)
    le -= cr
    return ls, le


class _Buf:
    """A block of bytes, zero padded on both sides, with cheap fixed-width row gathers.

    ``gather(start, w)`` returns ``b[start + j]`` for j < w as an (n, w) uint8 array by fancy
    indexing a sliding-window *view* of the padded block: one index per row, not per byte.
    Starts are clipped into the padding, so rows of malformed lines may hold junk but never
    index outside the block.
    """

    PAD = 2 * MAX_PAYLOAD + 64

    def __init__(self, b: np.ndarray):
        self.b = b
        self.n = len(b)
        self.padded = np.zeros(self.n + 2 * self.PAD, np.uint8)
        self.padded[self.PAD:self.PAD + self.n] = b
        self._win: dict[int, np.ndarray] = {}

    def gather(self, start: np.ndarray, width: int) -> np.ndarray:
        width = max(int(width), 1)
        if width > self.PAD:
            raise ValueError("gather wider than the padding")
        win = self._win.get(width)
        if win is None:
            win = self._win[width] = sliding_window_view(self.padded, width)
        return win[np.clip(start + self.PAD, 0, self.n + self.PAD)]

    def at(self, pos: np.ndarray) -> np.ndarray:
        return self.padded[np.clip(pos + self.PAD, 0, len(self.padded) - 1)]

    def positions_of(self, char: int, pad: int = 3) -> np.ndarray:
        """Positions of ``char``, padded with sentinels far beyond the end."""
        pos = np.flatnonzero(self.b == char)
        return np.concatenate([pos, np.full(pad, self.n + 4 * self.PAD, pos.dtype)])


def _width(length: np.ndarray, ok: np.ndarray, cap: int) -> int:
    """Widest field among the good lines (at least 1, at most ``cap``)."""
    return int(min(max(int(length[ok].max()) if ok.any() else 1, 1), cap))


def _hex_int(buf: _Buf, start, length, ok, cap=8):
    """Hex numbers of 1..cap digits in [start, start+length); -> (uint64, ok)."""
    width = _width(length, ok, cap)
    g = _HEX[buf.gather(start + length - width, width)]  # right-aligned
    inside = np.arange(width) >= (width - length)[:, None]
    ok = ok & (length >= 1) & (length <= width) & ~np.any(inside & (g == 255), axis=1)
    nib = np.where(inside, g, 0).astype(np.uint64)
    shifts = (4 * np.arange(width - 1, -1, -1)).astype(np.uint64)
    return np.bitwise_or.reduce(nib << shifts, axis=1), ok


def _dec_int(buf: _Buf, start, length, ok, cap):
    """Decimal integers of 1..cap (<= 18) digits; -> (int64, ok)."""
    width = _width(length, ok, cap)
    g = _DEC[buf.gather(start + length - width, width)]
    inside = np.arange(width) >= (width - length)[:, None]
    ok = ok & (length >= 1) & (length <= width) & ~np.any(inside & (g == 255), axis=1)
    d = np.where(inside, g, 0).astype(np.int64)
    return d @ _POW10_I[width - 1::-1], ok


def _exact_quotient(nval: np.ndarray, k: np.ndarray, text_of) -> np.ndarray:
    """``nval / 10**k`` rounded once, i.e. exactly Python's ``float(text)`` of the decimal.

    ``nval`` below 2**53 and ``10**k`` are exact doubles, so one IEEE division is correctly
    rounded. Larger ``nval`` go through long double with a check for the rare tie where
    rounding twice could differ; those, and platforms without a wide long double, use
    ``float(text_of(i))``.
    """
    t = nval.astype(np.float64) / _POW10_F[k]
    slow = np.flatnonzero(nval >= _TWO53)
    if len(slow):
        if _LONGDOUBLE_OK:
            q = nval[slow].astype(np.longdouble) / _POW10_LD[k[slow]]
            tf = q.astype(np.float64)
            diff2 = 2 * np.abs(q - tf.astype(np.longdouble))
            ulp_up = np.spacing(np.abs(tf)).astype(np.longdouble)
            ulp_dn = np.abs(tf - np.nextafter(tf, 0)).astype(np.longdouble)
            t[slow] = tf
            slow = slow[(diff2 == ulp_up) | (diff2 == ulp_dn)]
        for i in slow:
            t[i] = float(text_of(i))
    return t


def _dec_time(buf: _Buf, start, length, ok):
    """Decimal timestamps ``digits[.digits]`` -> (t_s float64 bit-identical to ``float``, ok).

    Lines sharing the layout of the first good line (same length, dot at the same place, the
    usual case) are read with one fixed-width gather; up to a few more layouts likewise;
    the rest by the general masked reader.
    """
    n = len(start)
    t = np.zeros(n)
    tok = np.zeros(n, bool)
    dots = buf.positions_of(46)
    dotoff = dots[np.searchsorted(dots, start)] - start
    dotoff = np.where(dotoff < length, dotoff, -1)  # -1: no dot
    todo = ok & (length >= 1) & (length <= 24)
    for _ in range(8):  # a few common layouts, each with one gather
        if not todo.any():
            break
        i0 = int(np.argmax(todo))
        L0, D0 = int(length[i0]), int(dotoff[i0])
        rows = np.flatnonzero(todo & (length == L0) & (dotoff == D0))
        todo[rows] = False
        cols = np.flatnonzero(np.arange(L0) != D0)
        if len(cols) == 0 or len(cols) > 18:
            continue  # left not ok (a bare '.') or too many digits: general reader below
        g = buf.gather(start[rows], L0)[:, cols] - np.uint8(48)
        good = np.all(g < 10, axis=1)
        rows, g = rows[good], g[good]
        nval = g.astype(np.int64) @ _POW10_I[len(cols) - 1::-1]
        k = np.full(len(rows), 0 if D0 < 0 else L0 - 1 - D0)
        t[rows] = _exact_quotient(nval, k, lambda i, r=rows: _text(buf, start[r[i]], length[r[i]]))
        tok[rows] = True
    rest = np.flatnonzero(ok & ~tok & (length >= 1) & (length <= 24))
    if len(rest):
        tr, okr = _dec_time_general(buf, start[rest], length[rest])
        t[rest] = tr
        tok[rest] = okr
    return t, tok


def _text(buf: _Buf, start: int, length: int) -> str:
    return buf.b[start:start + length].tobytes().decode("ascii")


def _dec_time_general(buf: _Buf, start, length):
    """Masked reader for timestamps of any layout (1..24 chars, at most one dot)."""
    width = int(min(max(int(length.max()), 1), 24))
    g = buf.gather(start + length - width, width)
    j = np.arange(width)
    inside = j >= (width - length)[:, None]
    isdot = inside & (g == 46)
    ndot = isdot.sum(axis=1)
    d = _DEC[g]
    isdigit = inside & (d != 255)
    ndig = isdigit.sum(axis=1)
    ok = ((length >= 1) & (length <= width) & (ndot <= 1) & (ndig >= 1) & (ndig <= 18)
          & np.all(~inside | isdigit | isdot, axis=1))
    r = width - 1 - j
    k = np.where(ndot == 1, width - 1 - np.argmax(isdot, axis=1), 0)
    power = r[None, :] - ((r[None, :] > k[:, None]) & (ndot == 1)[:, None])
    dd = np.where(isdigit & ok[:, None], d, 0).astype(np.int64)
    nval = np.sum(dd * _POW10_I[np.clip(power, 0, 18)], axis=1)
    t = _exact_quotient(nval, k, lambda i: _text(buf, start[i], length[i]))
    return t, ok


def _payload(buf: _Buf, ds, nchars, ok, max_bytes):
    """Hex payloads of ``nchars`` hex digits at ``ds``; -> (uint8 (n, w), dlc uint8, ok)."""
    ok = ok & (nchars % 2 == 0) & (nchars >= 0) & (nchars <= 2 * max_bytes)
    dlc = np.where(ok, nchars // 2, 0)
    width = int(dlc.max()) if len(dlc) else 0
    data = np.zeros((len(ds), max(width, 8)), np.uint8)  # at least a classic frame's 8 bytes
    if width == 0:
        return data, dlc.astype(np.uint8), ok
    pairs = _HEX2[buf.gather(ds, 2 * width).view("<u2")]  # (n, width): byte or 0xFFFF
    inside = np.arange(width) < dlc[:, None]
    ok &= ~np.any(inside & (pairs == 0xFFFF), axis=1)
    data[:, :width] = np.where(inside, pairs, 0)
    return data, dlc.astype(np.uint8), ok


class _Chunk:
    """Frames parsed from one block, plus the line numbers of the lines it skipped.

    ``bus`` is either int bus numbers or (n, 8|16) uint8 interface names for :class:`_BusMapper`.
    """

    def __init__(self, t, bus, arb_id, ext, dlc, data, where, skipped):
        self.t, self.bus, self.arb_id, self.ext = t, bus, arb_id, ext
        self.dlc, self.data, self.where, self.skipped = dlc, data, where, skipped


def _parse_candump_chunk(b: np.ndarray, line0: int, first_line: int = 1) -> _Chunk:
    """Parse one block of ``candump -L`` lines; ``line0`` = lines before the block."""
    ls, le = _line_bounds(b)
    lineno = line0 + 1 + np.arange(len(ls), dtype=np.int64)
    keep = (le > ls) & (lineno >= first_line)  # blank lines carry nothing (python-can skips them too)
    ls, le, lineno = ls[keep], le[keep], lineno[keep]
    buf = _Buf(b)
    sp = buf.positions_of(32)
    hs = buf.positions_of(35)
    isp = np.searchsorted(sp, ls)
    nsp = np.searchsorted(sp, le) - isp
    s0, s1, s2 = sp[isp], sp[isp + 1], sp[isp + 2]
    flag3 = (nsp == 3) & (le - s2 == 2)
    if flag3.any():
        fc = buf.at(s2 + 1)
        flag3 &= (fc == 82) | (fc == 84) | (fc == 114) | (fc == 116)  # R T r t
    ok = (buf.at(ls) == 40) & ((nsp == 2) | flag3) & (buf.at(s0 - 1) == 41)
    fe = np.where(nsp == 3, s2, le)  # end of the ID#DATA field
    h = hs[np.searchsorted(hs, s1)]
    ok &= h < fe
    fd = ok & (buf.at(h + 1) == 35) & (h + 1 < fe)
    ok &= ~fd | ((h + 2 < fe) & (_HEX[buf.at(h + 2)] != 255))
    ds = np.where(fd, h + 3, h + 1)
    remote = ok & (ds < fe) & ((buf.at(ds) | 32) == 114)  # 'r' or 'R'
    # id
    idval, ok = _hex_int(buf, s1 + 1, h - s1 - 1, ok, 8)
    ext = (h - s1 - 1) > 3
    errframe = ok & ext & ((idval & np.uint64(_CAN_ERR_FLAG)) != 0)
    arb = (idval & np.uint64(_EFF_MASK)).astype(np.uint32)
    ok &= ext | (arb <= _SFF_MAX)
    # interface name
    iflen = s1 - s0 - 1
    ok &= (iflen >= 1) & (iflen <= 16)
    # timestamp
    t, ok = _dec_time(buf, ls + 1, s0 - ls - 2, ok)
    # payload
    good = ok & ~remote & ~errframe
    data, dlc, pok = _payload(buf, ds, np.where(good, fe - ds, 0), good, MAX_PAYLOAD)
    pok &= fd | (dlc <= 8)  # a classic frame holds at most 8 bytes
    bad = ~ok | (good & ~pok)
    good &= pok
    nw = 8 if _width(iflen, good, 16) <= 8 else 16
    names = buf.gather(s0[good] + 1, nw)
    names[np.arange(nw) >= iflen[good][:, None]] = 0
    skipped = {KIND_MALFORMED: lineno[bad], KIND_REMOTE: lineno[remote & ok],
               KIND_ERROR_FRAME: lineno[errframe & ~remote]}
    return _Chunk(t[good], names, arb[good], ext[good], dlc[good], data[good],
                  lineno[good], skipped)


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
        raise InputError(f"libpanda CSV header lacks column(s) {', '.join(missing)}", str(p),
                         line=nblank + 1)
    cols = {c: names.index(c) for c in ("Time", "Bus", "MessageID", "Message")}
    cols["MessageLength"] = names.index("MessageLength") if "MessageLength" in names else None
    cols["ncols"] = len(names)
    return cols, nblank + 1


class _LibpandaChunkParser:
    """Parse blocks of libpanda CSV lines whose columns are given by the header."""

    def __init__(self, cols: dict):
        self.cols = cols

    def __call__(self, b: np.ndarray, line0: int, first_line: int) -> _Chunk:
        c = self.cols
        ls, le = _line_bounds(b)
        lineno = line0 + 1 + np.arange(len(ls), dtype=np.int64)
        keep = (le > ls) & (lineno >= first_line)  # blank lines and the header
        ls, le, lineno = ls[keep], le[keep], lineno[keep]
        buf = _Buf(b)
        cp = buf.positions_of(44, pad=c["ncols"] + 1)
        ic = np.searchsorted(cp, ls)
        ok = (np.searchsorted(cp, le) - ic) == c["ncols"] - 1

        def field(j):
            start = ls if j == 0 else cp[ic + j - 1] + 1
            end = le if j == c["ncols"] - 1 else cp[ic + j]
            return start, np.where(ok, end - start, 0)

        t, ok = _dec_time(buf, *field(c["Time"]), ok)
        bus, ok = _dec_int(buf, *field(c["Bus"]), ok, 4)
        mid, ok = _dec_int(buf, *field(c["MessageID"]), ok, 10)
        ok &= mid <= _EFF_MASK
        s, n = field(c["Message"])
        data, dlc, ok = _payload(buf, s, np.where(ok, n, 0), ok, MAX_PAYLOAD)
        if c["MessageLength"] is not None:
            ml, ok = _dec_int(buf, *field(c["MessageLength"]), ok, 3)
            ok &= ml == dlc
        return _Chunk(t[ok], bus[ok], mid[ok].astype(np.uint32), mid[ok] > _SFF_MAX,
                      dlc[ok], data[ok], lineno[ok], {KIND_MALFORMED: lineno[~ok]})


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
            if digits and int(text[-digits:]) not in taken and int(text[-digits:]) < 2 ** 15:
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


def _read_text(p: Path, gz: bool, problems: Problems, parser, *, first_line: int,
               chunk_bytes: int, what: str) -> FrameTable:
    spath = str(p)
    mapper = _BusMapper()
    parts = []
    skipped: dict[str, list] = {}
    line0 = 0
    for block, cut in _iter_chunks(p, gz, chunk_bytes):
        b = np.frombuffer(block, np.uint8)
        nlines = int(np.count_nonzero(b == 10))
        ch = parser(b, line0, first_line)
        line0 += nlines - cut
        for kind, lines in ch.skipped.items():
            if len(lines):
                skipped.setdefault(kind, []).append(lines)
        bus = ch.bus.astype(np.int16) if ch.bus.ndim == 1 else mapper.map(ch.bus)
        parts.append(FrameTable(ch.t, bus, ch.arb_id, ch.ext, ch.dlc, ch.data, ch.where, spath))
        del ch, b, block
    for kind in DROPPED_KINDS:
        if kind in skipped:
            lines = np.concatenate(skipped[kind])
            problems.add(kind, spath, lines[:Problems.MAX_FIRST], count=len(lines),
                         detail=f"not a valid {what} line" if kind == KIND_MALFORMED else "")
    table = FrameTable.concat(parts) if parts else FrameTable.empty(spath)
    table.path = spath
    if len(table) == 0:
        bad = skipped.get(KIND_MALFORMED)
        first = int(np.concatenate(bad)[0]) if bad else None
        raise InputError(f"no usable CAN frame: not a {what} log, or every line is malformed",
                         spath, line=first)
    return table


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
    try:
        if gz:
            if fmt == "sqlite":
                raise InputError("a gzip-compressed sqlite log cannot be read; decompress it",
                                 spath)
            fh = gzip.open(p, "rb" if binary else "rt", encoding=None if binary else "utf-8",
                           errors=None if binary else "replace")
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
        raise InputError(f"python-can's {cls_name} failed after {frame_no} frames: "
                         f"{type(exc).__name__}: {exc}", spath, frame=frame_no + 1) from None
    finally:
        if fh is not None:
            fh.close()
    problems.add(KIND_REMOTE, spath, remote[:Problems.MAX_FIRST], count=len(remote))
    problems.add(KIND_ERROR_FRAME, spath, errf[:Problems.MAX_FIRST], count=len(errf))
    if not t:
        raise InputError(f"no usable CAN frame in this {fmt} log", spath)
    # bus numbers: int channels as they are, names by their trailing number
    mapper = _BusMapper()
    busmap = {}
    for ch in names:
        if isinstance(ch, (int, np.integer)) and not isinstance(ch, bool) and 0 <= ch < 2 ** 15:
            busmap[ch] = mapper.names[b"\0int%d" % ch] = int(ch)
    for ch in names:
        if ch not in busmap:
            busmap[ch] = mapper.number_of(str(ch).encode("utf-8"))
    width = max(8, max(len(d) for d in payloads))
    data = np.zeros((len(payloads), width), np.uint8)
    for i, d in enumerate(payloads):
        data[i, :len(d)] = np.frombuffer(d, np.uint8)
    return FrameTable(np.asarray(t, np.float64), np.asarray([busmap[c] for c in bus], np.int16),
                      np.asarray(arb, np.uint32), np.asarray(ext, bool),
                      np.asarray(dlc, np.uint8), data, np.asarray(where, np.int64), spath)


# ----------------------------------------------------------------------------- clock checks
def _clock_checks(ft: FrameTable, problems: Problems, jump_s: float) -> FrameTable:
    """Sort by time (reporting steps backwards), drop exact duplicates, report forward jumps."""
    spath = ft.path
    if not np.all(np.isfinite(ft.t_s)):
        bad = ~np.isfinite(ft.t_s)
        problems.add(KIND_MALFORMED, spath, ft.where[bad][:Problems.MAX_FIRST],
                     count=int(bad.sum()), detail="timestamp is not a finite number")
        ft = ft.take(~bad)
        if len(ft) == 0:
            raise InputError("no frame with a finite timestamp", spath)
    dt = np.diff(ft.t_s)
    back = np.flatnonzero(dt < 0) + 1
    if len(back):
        problems.add(KIND_BACKWARDS, spath, ft.where[back[:Problems.MAX_FIRST]], count=len(back),
                     detail=f"largest step back {-dt.min():.6g} s")
        order = np.argsort(ft.t_s, kind="stable")
        ft = ft.take(order)
        dt = np.diff(ft.t_s)
    # exact duplicates can only sit among frames that share a timestamp
    same = np.flatnonzero(dt == 0)
    if len(same):
        drop = _duplicates(ft, same)
        if len(drop):
            problems.add(KIND_DUPLICATE, spath, np.sort(ft.where[drop])[:Problems.MAX_FIRST],
                         count=len(drop))
            keep = np.ones(len(ft), bool)
            keep[drop] = False
            ft = ft.take(keep)
            dt = np.diff(ft.t_s)
    jumps = np.flatnonzero(dt > jump_s) + 1
    if len(jumps):
        problems.add(KIND_JUMP, spath, ft.where[jumps[:Problems.MAX_FIRST]], count=len(jumps),
                     detail=f"gap between consecutive frames over {jump_s:g} s, "
                            f"largest {dt.max():.6g} s")
    return ft


def _duplicates(ft: FrameTable, same: np.ndarray) -> np.ndarray:
    """Rows that repeat an earlier row exactly (time, bus, id, flags, payload).

    ``same``: rows i with t[i] == t[i+1] (the table is sorted by time). Each frame is
    compared with the frames before it in its run of equal timestamps, exactly (no hashing).
    """
    mark = np.zeros(len(ft), bool)
    mark[same] = True
    mark[same + 1] = True
    cand = np.flatnonzero(mark)
    t = ft.t_s[cand]
    meta = (ft.arb_id[cand].astype(np.uint64) | (ft.is_extended[cand].astype(np.uint64) << 29)
            | (ft.dlc[cand].astype(np.uint64) << 32)
            | (ft.bus[cand].astype(np.uint16).astype(np.uint64) << 40))
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
    if runlen.max() > 32:  # long runs of one timestamp: sort whole rows instead
        key = np.concatenate([t.view(np.uint8).reshape(-1, 8), meta.view(np.uint8).reshape(-1, 8),
                              padded], axis=1)
        _, first = np.unique(key.view(np.dtype((np.void, key.shape[1]))).ravel(),
                             return_index=True)
        dup[:] = True
        dup[first] = False
        return cand[dup]
    for d in range(1, int(runlen.max())):
        eq = (runid[d:] == runid[:-d]) & (meta[d:] == meta[:-d])
        eq &= np.all(words[d:] == words[:-d], axis=1)
        dup[d:] |= eq
    return cand[dup]
