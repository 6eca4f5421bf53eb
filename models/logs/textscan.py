"""Vectorised scanning of text CAN logs: line bounds, fixed-width gathers, hex and decimal
fields, and decimal timestamps read bit-identically to Python's ``float``.

The readers of ``models.logs.candump`` and ``models.logs.libpanda`` build on these; every
function works on whole columns of lines at once (no Python loop per line). Imports only numpy
and ``models.logs.frames``.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hmpc.models.logs.frames import MAX_PAYLOAD

#: why a parser skipped a line (``models.logs.canlog`` names each as a problem kind)
SKIP_MALFORMED, SKIP_REMOTE, SKIP_ERROR_FRAME = "malformed", "remote", "error frame"
SKIPPED = (SKIP_MALFORMED, SKIP_REMOTE, SKIP_ERROR_FRAME)

#: byte -> its value as a hex digit, 255 if not one
HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    HEX[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    HEX[_c] = 10 + _i
#: byte -> its value as a decimal digit, 255 if not one
DEC = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789"):
    DEC[_c] = _i
del _i, _c
POW10_I = 10 ** np.arange(19, dtype=np.int64)
POW10_F = 10.0 ** np.arange(25)
POW10_LD = np.longdouble(10) ** np.arange(25).astype(np.longdouble)
#: two hex digits (as a little-endian uint16 of their bytes) -> byte value, 0xFFFF if not hex
HEX2 = np.where(
    (HEX[np.arange(65536) & 0xFF] < 16) & (HEX[np.arange(65536) >> 8] < 16),
    HEX[np.arange(65536) & 0xFF].astype(np.uint16) * 16 + HEX[np.arange(65536) >> 8],
    0xFFFF,
).astype(np.uint16)
LONGDOUBLE_OK = np.finfo(np.longdouble).nmant >= 63  # x87 80-bit or IEEE quad
TWO53 = 2**53


def line_bounds(b: np.ndarray):
    """Start and end (exclusive, without CR) of every line in ``b`` (which ends with LF)."""
    nl = np.flatnonzero(b == 10)
    ls = np.empty_like(nl)
    ls[:1] = 0
    ls[1:] = nl[:-1] + 1
    le = nl.copy()
    cr = (le > ls) & (b[np.maximum(le - 1, 0)] == 13)
    le -= cr
    return ls, le


class Buf:
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
        self.padded[self.PAD : self.PAD + self.n] = b
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


def width_of(length: np.ndarray, ok: np.ndarray, cap: int) -> int:
    """Widest field among the good lines (at least 1, at most ``cap``)."""
    return int(min(max(int(length[ok].max()) if ok.any() else 1, 1), cap))


def hex_int(buf: Buf, start, length, ok, cap=8):
    """Hex numbers of 1..cap digits in [start, start+length); -> (uint64, ok)."""
    width = width_of(length, ok, cap)
    g = HEX[buf.gather(start + length - width, width)]  # right-aligned
    inside = np.arange(width) >= (width - length)[:, None]
    ok = ok & (length >= 1) & (length <= width) & ~np.any(inside & (g == 255), axis=1)
    nib = np.where(inside, g, 0).astype(np.uint64)
    shifts = (4 * np.arange(width - 1, -1, -1)).astype(np.uint64)
    return np.bitwise_or.reduce(nib << shifts, axis=1), ok


def dec_int(buf: Buf, start, length, ok, cap):
    """Decimal integers of 1..cap (<= 18) digits; -> (int64, ok)."""
    width = width_of(length, ok, cap)
    g = DEC[buf.gather(start + length - width, width)]
    inside = np.arange(width) >= (width - length)[:, None]
    ok = ok & (length >= 1) & (length <= width) & ~np.any(inside & (g == 255), axis=1)
    d = np.where(inside, g, 0).astype(np.int64)
    return d @ POW10_I[width - 1 :: -1], ok


def exact_quotient(nval: np.ndarray, k: np.ndarray, text_of) -> np.ndarray:
    """``nval / 10**k`` rounded once, i.e. exactly Python's ``float(text)`` of the decimal.

    ``nval`` below 2**53 and ``10**k`` are exact doubles, so one IEEE division is correctly
    rounded. Larger ``nval`` go through long double with a check for the rare tie where
    rounding twice could differ; those, and platforms without a wide long double, use
    ``float(text_of(i))``.
    """
    t = nval.astype(np.float64) / POW10_F[k]
    slow = np.flatnonzero(nval >= TWO53)
    if len(slow):
        if LONGDOUBLE_OK:
            q = nval[slow].astype(np.longdouble) / POW10_LD[k[slow]]
            tf = q.astype(np.float64)
            diff2 = 2 * np.abs(q - tf.astype(np.longdouble))
            ulp_up = np.spacing(np.abs(tf)).astype(np.longdouble)
            ulp_dn = np.abs(tf - np.nextafter(tf, 0)).astype(np.longdouble)
            t[slow] = tf
            slow = slow[(diff2 == ulp_up) | (diff2 == ulp_dn)]
        for i in slow:
            t[i] = float(text_of(i))
    return t


def dec_time(buf: Buf, start, length, ok):
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
        nval = g.astype(np.int64) @ POW10_I[len(cols) - 1 :: -1]
        k = np.full(len(rows), 0 if D0 < 0 else L0 - 1 - D0)
        t[rows] = exact_quotient(nval, k, lambda i, r=rows: text_at(buf, start[r[i]], length[r[i]]))
        tok[rows] = True
    rest = np.flatnonzero(ok & ~tok & (length >= 1) & (length <= 24))
    if len(rest):
        tr, okr = dec_time_general(buf, start[rest], length[rest])
        t[rest] = tr
        tok[rest] = okr
    return t, tok


def text_at(buf: Buf, start: int, length: int) -> str:
    return buf.b[start : start + length].tobytes().decode("ascii")


def dec_time_general(buf: Buf, start, length):
    """Masked reader for timestamps of any layout (1..24 chars, at most one dot)."""
    width = int(min(max(int(length.max()), 1), 24))
    g = buf.gather(start + length - width, width)
    j = np.arange(width)
    inside = j >= (width - length)[:, None]
    isdot = inside & (g == 46)
    ndot = isdot.sum(axis=1)
    d = DEC[g]
    isdigit = inside & (d != 255)
    ndig = isdigit.sum(axis=1)
    ok = (
        (length >= 1)
        & (length <= width)
        & (ndot <= 1)
        & (ndig >= 1)
        & (ndig <= 18)
        & np.all(~inside | isdigit | isdot, axis=1)
    )
    r = width - 1 - j
    k = np.where(ndot == 1, width - 1 - np.argmax(isdot, axis=1), 0)
    power = r[None, :] - ((r[None, :] > k[:, None]) & (ndot == 1)[:, None])
    dd = np.where(isdigit & ok[:, None], d, 0).astype(np.int64)
    nval = np.sum(dd * POW10_I[np.clip(power, 0, 18)], axis=1)
    t = exact_quotient(nval, k, lambda i: text_at(buf, start[i], length[i]))
    return t, ok


def payload(buf: Buf, ds, nchars, ok, max_bytes):
    """Hex payloads of ``nchars`` hex digits at ``ds``; -> (uint8 (n, w), dlc uint8, ok)."""
    ok = ok & (nchars % 2 == 0) & (nchars >= 0) & (nchars <= 2 * max_bytes)
    dlc = np.where(ok, nchars // 2, 0)
    width = int(dlc.max()) if len(dlc) else 0
    data = np.zeros((len(ds), max(width, 8)), np.uint8)  # at least a classic frame's 8 bytes
    if width == 0:
        return data, dlc.astype(np.uint8), ok
    pairs = HEX2[buf.gather(ds, 2 * width).view("<u2")]  # (n, width): byte or 0xFFFF
    inside = np.arange(width) < dlc[:, None]
    ok &= ~np.any(inside & (pairs == 0xFFFF), axis=1)
    data[:, :width] = np.where(inside, pairs, 0)
    return data, dlc.astype(np.uint8), ok


class Chunk:
    """Frames parsed from one block, plus the line numbers of the lines it skipped.

    ``bus`` is either int bus numbers or (n, 8|16) uint8 zero-padded interface names (which
    ``models.logs.canlog`` numbers). ``skipped``: one of :data:`SKIPPED` -> line numbers.
    """

    def __init__(self, t, bus, arb_id, ext, dlc, data, where, skipped):
        self.t, self.bus, self.arb_id, self.ext = t, bus, arb_id, ext
        self.dlc, self.data, self.where, self.skipped = dlc, data, where, skipped
