"""``candump -L`` lines of one fixed layout, parsed with 64-bit word arithmetic.

A log writes almost every line alike: ``(1533226488.434433) can0 2E4#BE000000A9`` has its
timestamp, interface name and identifier at the same columns on every line; only the payload
length varies, and the identifier is 3 or 8 hex digits. :class:`Layout` is that shape (learnt
from one line); :func:`parse_fixed` reads every line of a group that has it at once: each field
is loaded as a little-endian 64-bit word from the line's start plus a constant offset, then
checked and converted eight characters at a time with integer operations on those words
(decimal digits "SWAR"-style, hex digits likewise). No Python runs per line.

A line passes only if the general parser (``models.logs.candump.parse_lines``) would read it to
the same frame: exactly the layout's digits and dot, ``)`` and the two spaces, a printable name
without spaces, 3 hex digits (at most 0x7FF) or 8 (no error-frame flag) before ``#``, and 0..16
hex digits, an even number, up to the end of the line. Every other line (remote, error and CAN FD
frames, direction flags, other layouts, anything malformed) is left to the general parser.
Timestamps are the same integer of digits over the same power of ten, divided as
``models.logs.textscan.exact_quotient`` divides them: bit-identical to Python's ``float`` of
the text.

Imports only numpy and ``models.logs.textscan``/``models.logs.frames``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hmpc.models.logs.frames import CAN_ERR_FLAG, EFF_MASK, SFF_MAX
from hmpc.models.logs.textscan import HEX, HEX2, POW10_F, TWO53, exact_quotient

#: longest interface name read here (one 64-bit word); longer names take the general parser
MAX_NAME = 8
#: most digits of a timestamp read here: their integer stays below 2**63
MAX_TIME_DIGITS = 18
#: longest timestamp text (digits and dot) the general parser reads
MAX_TIME_CHARS = 24
#: most payload characters of a classic CAN frame (8 bytes, two hex digits each)
MAX_PAYLOAD_CHARS = 16
#: bytes a group's word loads reach before a line start and after it: the caller pads its
#: buffer by at least this much on both sides
REACH = 128

_U = np.uint64
_ALL = _U(0xFFFFFFFFFFFFFFFF)


def _rep(byte: int) -> np.uint64:
    """``byte`` in every byte of a 64-bit word."""
    return _U(byte * 0x0101010101010101)


_M80, _M7F, _M0F, _M30, _M76 = _rep(0x80), _rep(0x7F), _rep(0x0F), _rep(0x30), _rep(0x76)
_M50, _M46, _M20, _M1F, _M19 = _rep(0x50), _rep(0x46), _rep(0x20), _rep(0x1F), _rep(0x19)


def _bytemask(first: int, count: int) -> int:
    """A 64-bit mask of bytes [first, first + count) (byte 0 is the lowest), clipped to 0..7."""
    m = 0
    for i in range(max(first, 0), min(first + count, 8)):
        m |= 0xFF << (8 * i)
    return m


#: payload characters (0..16; 17 for any other count) -> mask of those characters in the
#: first / second 8-character word, and nonzero where the count is no payload (odd, or 17)
_CHARS_LO = np.array([_bytemask(0, min(n, 8)) for n in range(MAX_PAYLOAD_CHARS + 2)], np.uint64)
_CHARS_HI = np.array([_bytemask(0, max(n - 8, 0)) for n in range(MAX_PAYLOAD_CHARS + 2)], np.uint64)
_CHARS_BAD = np.array(
    [n % 2 or n > MAX_PAYLOAD_CHARS for n in range(MAX_PAYLOAD_CHARS + 2)], np.uint64
)


@dataclass(frozen=True)
class Layout:
    """Where the fields of a line sit, counted from its ``(``.

    Attributes:
        time_chars: characters between the parentheses (digits and at most one dot).
        dot: index of the dot within them, -1 without one.
        name_chars: interface name length (1..:data:`MAX_NAME`).
    """

    time_chars: int
    dot: int
    name_chars: int

    @property
    def id_at(self) -> int:
        """Offset of the identifier's first digit."""
        return self.time_chars + 4 + self.name_chars

    @property
    def decimals(self) -> int:
        """Digits after the dot (the power of ten the digits' integer is divided by)."""
        return 0 if self.dot < 0 else self.time_chars - 1 - self.dot


def learn_layout(line: bytes) -> Layout | None:
    """The layout of ``line``, or None when it has none this module reads."""
    close = line.find(b")")
    if not line.startswith(b"(") or close < 2 or line[close + 1 : close + 2] != b" ":
        return None
    text = line[1:close]
    digits = text.replace(b".", b"", 1)
    if (
        len(text) > MAX_TIME_CHARS
        or not digits.isdigit()
        or not digits.isascii()
        or len(digits) > MAX_TIME_DIGITS
    ):
        return None
    end = line.find(b" ", close + 2)
    name = line[close + 2 : end]
    if end < 0 or not 1 <= len(name) <= MAX_NAME or not printable(name):
        return None
    return Layout(len(text), text.find(b"."), len(name))


def printable(name: bytes) -> bool:
    """An interface name this module reads: printable ASCII, no space."""
    return all(0x21 <= c <= 0x7E for c in name)


class _LineWords:
    """64-bit words of a group of lines, each loaded from the line start plus a constant.

    ``word(j)`` holds bytes [start + 8j, start + 8j + 8) of every line (little-endian), built
    from two aligned loads of the padded buffer; ``field(o)`` the 8 bytes at any offset ``o``.
    """

    def __init__(self, aligned: np.ndarray, start: np.ndarray):
        self.aligned = aligned
        self.q = start >> 3
        r = (start & 7).astype(np.uint64) << _U(3)
        self.right, self.left = r, _U(63) - r
        self._raw: dict[int, np.ndarray] = {}
        self._words: dict[int, np.ndarray] = {}

    def _load(self, j: int) -> np.ndarray:
        a = self._raw.get(j)
        if a is None:
            a = self._raw[j] = self.aligned.take(self.q + j)
        return a

    def word(self, j: int) -> np.ndarray:
        w = self._words.get(j)
        if w is None:
            lo = self._load(j) >> self.right
            hi = self._load(j + 1) << _U(1)  # two shifts: no shift by 64 when aligned
            hi <<= self.left
            lo |= hi
            w = self._words[j] = lo
        return w

    def field(self, o: int) -> np.ndarray:
        j, s = o // 8, o % 8
        if s == 0:
            return self.word(j)
        return (self.word(j) >> _U(8 * s)) | (self.word(j + 1) << _U(64 - 8 * s))

    def byte(self, o: int) -> np.ndarray:
        return (self.word(o // 8) >> _U(8 * (o % 8))) & _U(0xFF)

    def bytes_at(self, o: int, n: int) -> np.ndarray:
        """The ``n`` (1..8) bytes at offset ``o``, zero padded above."""
        j, s = o // 8, o % 8
        if s + n <= 8:  # inside one word
            w = self.word(j) >> _U(8 * s) if s else self.word(j)
            return w if s + n == 8 else w & _U(_bytemask(0, n))
        return self.field(o) & _U(_bytemask(0, n))


class _Plan:
    """A layout's constants, worked out once: which bytes of which words are checked for a
    fixed character, and which slices of which fields make up each word of 8 timestamp digits.
    """

    def __init__(self, lay: Layout):
        tc, nc = lay.time_chars, lay.name_chars
        fixed = {0: 0x28, tc + 1: 0x29, tc + 2: 0x20, tc + 3 + nc: 0x20}  # ( ) and two spaces
        if lay.dot >= 0:
            fixed[1 + lay.dot] = 0x2E
        self.fixed = []  # (word, mask, value)
        for j in sorted({o // 8 for o in fixed}):
            mask = sum(0xFF << (8 * (o % 8)) for o in fixed if o // 8 == j)
            val = sum(c << (8 * (o % 8)) for o, c in fixed.items() if o // 8 == j)
            self.fixed.append((j, _U(mask), _U(val)))
        cols = [1 + i for i in range(tc) if i != lay.dot]  # line offsets of the digits
        self.digit_words = []  # ([(field offset, byte mask or None)], fill, power of ten)
        for hi in range(len(cols), 0, -8):  # words of up to 8 digits, least significant first
            lo = max(hi - 8, 0)
            fill = 8 - (hi - lo)  # right-aligned: the leading bytes read as '0'
            parts, i = [], lo
            while i < hi:  # each contiguous run of digits (split at the dot)
                j = i
                while j + 1 < hi and cols[j + 1] == cols[j] + 1:
                    j += 1
                pos = fill + (i - lo)
                mask = _bytemask(pos, j + 1 - i)
                parts.append((cols[i] - pos, None if mask == 0xFFFFFFFFFFFFFFFF else _U(mask)))
                i = j + 1
            self.digit_words.append(
                (
                    parts,
                    _U(_M30 & _U(_bytemask(0, fill))) if fill else None,
                    np.int64(10 ** (len(cols) - hi)),
                )
            )


def _digits(plan: _Plan, lw: _LineWords, err: np.ndarray) -> np.ndarray:
    """The timestamp's digits as one int64 per line; bytes that are not digits set bits of
    ``err``."""
    value: np.ndarray | None = None
    bad: np.ndarray | None = None
    for parts, fill, power in plan.digit_words:
        w: np.ndarray | None = None
        for off, mask in parts:
            part = lw.field(off)
            if mask is not None:
                part = part & mask
            w = part if w is None else w | part
        if fill is not None:
            w = w | fill
        assert w is not None  # every digit word has a part
        x = w - _M30  # digits' values, one per byte, if all were digits
        y = x + _M76  # a byte over 9 sets its high bit here, one under '0' in x itself
        y |= x
        if bad is None:
            bad = y
        else:
            bad |= y
        # pairs, then quadruples, then all eight (most significant digit in the lowest byte)
        x = x * _U(10) + (x >> _U(8))
        x = (
            ((x & _U(0x000000FF000000FF)) * _U(100 + (1000000 << 32)))
            + (((x >> _U(16)) & _U(0x000000FF000000FF)) * _U(1 + (10000 << 32)))
        ) >> _U(32)
        x = x.view(np.int64)
        if value is None:
            value = x
        else:
            x *= power
            value += x
    assert value is not None and bad is not None  # a timestamp has at least one digit word
    bad &= _M80
    err |= bad
    return value


def _hex_nibbles(x: np.ndarray):
    """8 characters per word -> (their hex values, one per byte; 0x80 in each byte that is a
    hex digit)."""
    x7 = x & _M7F
    ascii_ = ~x
    ascii_ &= _M80
    digit = x7 + _M50  # '0'..'9'
    digit &= ~(x7 + _M46)
    x7 |= _M20
    alpha: np.ndarray = x7 + _M1F  # 'a'..'f' or 'A'..'F'
    alpha &= ~(x7 + _M19)
    alpha &= ascii_
    digit |= alpha
    digit &= ascii_
    nib = x & _M0F
    alpha >>= _U(7)
    alpha *= _U(9)
    nib += alpha
    return nib, digit


def _pack_nibbles(nib: np.ndarray) -> np.ndarray:
    """Byte values of 8 hex digits (one per byte, first in the lowest) -> 4 bytes, the value
    of characters 2k and 2k+1 in byte k."""
    y = nib << _U(4)
    y |= nib >> _U(8)
    y &= _U(0x00FF00FF00FF00FF)
    y |= y >> _U(8)
    y &= _U(0x0000FFFF0000FFFF)
    y |= y >> _U(16)
    y &= _U(0xFFFFFFFF)
    return y


@dataclass
class Fixed:
    """What :func:`parse_fixed` read: per line of the group, ``ok`` and the frame's columns
    (meaningful where ``ok``)."""

    ok: np.ndarray  # bool
    t_s: np.ndarray  # float64
    name: np.ndarray  # uint64: the interface name's bytes, zero padded
    arb_id: np.ndarray  # uint32
    ext: np.ndarray  # bool
    dlc: np.ndarray  # uint8
    data: np.ndarray  # uint64: the payload's 8 bytes (little-endian), zero padded


_PLANS: dict[Layout, _Plan] = {}


def parse_fixed(
    lay: Layout, aligned: np.ndarray, base: np.ndarray, start: np.ndarray, end: np.ndarray
) -> Fixed:
    """Read the lines [start, end) (positions in ``base``, the padded buffer whose first
    ``len(aligned) * 8`` bytes ``aligned`` views as uint64) that have layout ``lay``."""
    plan = _PLANS.get(lay)
    if plan is None:
        plan = _PLANS[lay] = _Plan(lay)
    lw = _LineWords(aligned, start)
    tc, i0 = lay.time_chars, lay.id_at
    err = np.zeros(len(start), np.uint64)
    for j, mask, val in plan.fixed:
        e = lw.word(j) & mask
        e ^= val
        err |= e
    nval = _digits(plan, lw, err)
    name = lw.bytes_at(tc + 3, lay.name_chars)
    # identifier: 3 hex digits then '#', or 8 then '#'
    idw = lw.field(i0)
    c3 = ((idw >> _U(24)) & _U(0xFF)) == _U(0x23)
    ext = lw.byte(i0 + 8) == _U(0x23)
    ext &= ~c3
    any_ext = bool(ext.any())
    if any_ext:
        idval, id_ok = _ids(idw, ext, err)
    else:  # 3 digits: two table look-ups (0xFFFF / 0xFF where not hex)
        pair = HEX2.take((idw & _U(0xFFFF)).astype(np.intp))
        last = HEX.take(((idw >> _U(16)) & _U(0xFF)).astype(np.intp))
        err |= (pair >> np.uint16(8)) | (last >> np.uint8(4))
        idval = pair.astype(np.uint32)
        idval <<= np.uint32(4)
        idval |= last
        id_ok = idval <= SFF_MAX
    # payload: 0..16 hex digits after '#' up to the end of the line
    nchars = end - start
    if any_ext:
        nchars -= np.where(ext, i0 + 9, i0 + 4)
        w0 = np.where(ext, lw.field(i0 + 9), lw.field(i0 + 4))
        w1 = np.where(ext, lw.field(i0 + 17), lw.field(i0 + 12))
    else:
        nchars -= i0 + 4
        w0, w1 = lw.field(i0 + 4), lw.field(i0 + 12)
    count = np.minimum(nchars.view(np.uint64), _U(MAX_PAYLOAD_CHARS + 1)).astype(np.intp)
    err |= _CHARS_BAD.take(count)  # negative counts wrapped past 16 above
    lo_mask, hi_mask = _CHARS_LO.take(count), _CHARS_HI.take(count)
    n0, v0 = _hex_nibbles(w0)
    n1, v1 = _hex_nibbles(w1)
    n0 &= lo_mask
    n1 &= hi_mask
    lo_mask &= _M80
    hi_mask &= _M80
    v0 &= lo_mask
    v0 ^= lo_mask
    v1 &= hi_mask
    v1 ^= hi_mask
    err |= v0
    err |= v1
    data = _pack_nibbles(n1)
    data <<= _U(32)
    data |= _pack_nibbles(n0)
    ok = err == 0
    ok &= c3 | ext
    ok &= id_ok
    nval[~ok] = 0  # garbage of malformed lines never reaches the division
    if len(nval) and nval.max() < TWO53:  # exact doubles: one correctly rounded division
        t = nval.astype(np.float64)
        t /= POW10_F[lay.decimals]
    else:
        t = exact_quotient(
            nval,
            np.full(len(start), lay.decimals),
            lambda i: base[start[i] + 1 : start[i] + 1 + tc].tobytes().decode(),
        )
    return Fixed(ok, t, name, idval, ext, (count >> 1).astype(np.uint8), data)


def _ids(idw: np.ndarray, ext: np.ndarray, err: np.ndarray):
    """Identifiers of 3 hex digits, or 8 where ``ext``, at the start of ``idw``: (value,
    whether it is one: at most 0x7FF, or no error-frame flag); bad digits set ``err``."""
    nib, valid = _hex_nibbles(idw)
    need = np.where(ext, _M80, _U(0x808080))
    nib &= np.where(ext, _ALL, _U(0xFFFFFF))
    valid &= need
    valid ^= need
    err |= valid
    idval = _pack_nibbles(nib).astype(np.uint32).byteswap()  # the digits' value, 8 digits
    idval = np.where(ext, idval, idval >> np.uint32(20))
    id_ok = np.where(ext, (idval & np.uint32(CAN_ERR_FLAG)) == 0, idval <= SFF_MAX)
    idval &= np.uint32(EFF_MASK)
    return idval, id_ok
