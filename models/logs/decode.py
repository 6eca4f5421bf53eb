"""Decode CAN frames with a DBC: all frames of one message at once, bit-exact against cantools.

:func:`decode_frames` takes the frames of each DBC message (by id and extended flag, on the
chosen buses) and decodes them together with numpy: little-endian (Intel) and big-endian
(Motorola, DBC "sawtooth" bit numbering) signals, signed and unsigned, IEEE float signals,
scale and offset. The arithmetic is the one cantools does per frame (``raw * scale + offset``
in float64, or in exact integers for integer scale/offset), so every value equals
``db.decode_message(frame_id, data, decode_choices=False, scaling=True)`` bit for bit
(``tests/logs/test_decode.py`` checks this on every frame of both real logs). What the fast path
does not cover (multiplexed messages, signals spanning more than 8 bytes of a CAN FD payload,
integer scalings whose products could pass 2**63) falls back to cantools frame by frame.

One deliberate difference: when a DBC's signals overlap (opendbc's ``PCS_HUD``), cantools'
whole-message codec cannot unpack the message at all (``DecodeError: unpacking failed``) and
:func:`decode_frames_cantools` reports every such frame as undecodable; the fast path reads each
signal from its own bits as the DBC defines it (tests check it against cantools decoding each
signal alone).

:func:`decode_frames_cantools` is the plain per-frame cantools path with the same outputs: the
reference for tests and the baseline of ``tools/bench_ingest.py``.

Bad input: frames whose payload is shorter than the DBC length are skipped, counted and
reported (kind :data:`KIND_SHORT`); longer payloads decode the DBC's bytes and are reported
(:data:`KIND_LONG`); frames of ids the DBC does not define are counted (:data:`KIND_UNKNOWN_ID`,
not an error); frames cantools cannot decode are skipped and reported (:data:`KIND_UNDECODABLE`).
Asking for a message the DBC does not define raises :class:`InputError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.frames import FrameTable

KIND_SHORT = "payload shorter than DBC length (not decoded)"
KIND_LONG = "payload longer than DBC length (extra bytes ignored)"
KIND_UNKNOWN_ID = "frame id not in the DBC (not decoded)"
KIND_UNDECODABLE = "frame does not decode (cantools DecodeError; not decoded)"

#: at most this many messages are selected by one boolean mask each; more -> one sort
_MASK_MESSAGES = 12
#: at most this many buses are selected by one comparison each; more -> np.isin
_MASK_BUSES = 8
_SFF_IDS = 0x800  # number of 11-bit identifiers
_OFF_BUS = 0xFFFF  # message code of frames on buses not selected
#: rows decoded per block: the gathered columns of a block (~12 MB) stay in a typical L3 cache
_BLOCK_ROWS = 1 << 19


@dataclass
class DecodedMessage:
    """All decoded frames of one DBC message, in time order.

    Attributes:
        name: DBC message name.
        frame_id: arbitration id.
        t_s: receive time of each frame [s] (the log's clock).
        bus: bus number of each frame.
        where: 1-based source line / frame number of each frame.
        signals: signal name -> physical values (float64, DBC units, choices not applied;
            NaN where a multiplexed signal is absent from a frame).
    """

    name: str
    frame_id: int
    t_s: np.ndarray
    bus: np.ndarray
    where: np.ndarray
    signals: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def decode_frames(
    frames: FrameTable,
    db,
    problems: Problems,
    *,
    names=None,
    buses=None,
    dbc_path: str | None = None,
) -> dict[str, DecodedMessage]:
    """Decode frames with a cantools database, vectorised per message.

    Args:
        frames: the log's frames (time order).
        db: a cantools database (:func:`models.logs.dbc.load_dbc`).
        problems: collector for recoverable problems (short/long payloads, unknown ids, ...).
        names: decode only these message names (default: every DBC message present).
        buses: decode only frames on these bus numbers (default: all buses).
        dbc_path: the DBC file, named in errors.

    Returns:
        message name -> :class:`DecodedMessage`. With ``names`` every requested message is
        present (empty when the log has none of its frames); without, only messages with frames.

    Raises:
        InputError: a requested message name is not in the DBC.
    """
    return _decode(frames, db, problems, names, buses, dbc_path, fast=True)


def decode_frames_cantools(
    frames: FrameTable,
    db,
    problems: Problems,
    *,
    names=None,
    buses=None,
    dbc_path: str | None = None,
) -> dict[str, DecodedMessage]:
    """Same as :func:`decode_frames`, decoding every frame with ``db.decode_message``."""
    return _decode(frames, db, problems, names, buses, dbc_path, fast=False)


def message_index(frames: FrameTable, db) -> np.ndarray:
    """Per frame, the index of its message in ``db.messages`` (-1 where the DBC lacks the id)."""
    return _message_codes(frames, db).astype(np.int64) - 1


# ----------------------------------------------------------------------------- grouping
def _bus_mask(frames: FrameTable, buses):
    if buses is None:
        return np.ones(len(frames), bool)
    wanted = np.asarray(list(buses), dtype=np.int64)
    if len(wanted) > _MASK_BUSES:
        return np.isin(frames.bus, wanted)
    mask = np.zeros(len(frames), bool)
    for b in wanted.tolist():  # a few buses: one comparison each, no sort
        mask |= frames.bus == b
    return mask


def _message_codes(frames: FrameTable, db) -> np.ndarray:
    """Per frame: 1 + index of its message in ``db.messages``, 0 if the DBC lacks the id."""
    n_msg = len(db.messages)
    if n_msg >= _OFF_BUS - 1:
        raise InputError("DBC defines too many messages (over 65533)")
    lut = np.zeros(_SFF_IDS, np.uint16)
    ext_keys, ext_codes = [], []
    for i, m in enumerate(db.messages):
        if m.is_extended_frame:
            ext_keys.append(int(m.frame_id))
            ext_codes.append(i + 1)
        elif 0 <= m.frame_id < _SFF_IDS:
            lut[m.frame_id] = i + 1
    arb = frames.arb_id
    ext = frames.is_extended
    std_ok = ~ext & (arb < _SFF_IDS)
    code = np.where(std_ok, lut[arb & (_SFF_IDS - 1)], 0).astype(np.uint16)
    if ext_keys and ext.any():
        order = np.argsort(ext_keys)
        keys = np.asarray(ext_keys, np.uint32)[order]
        codes = np.asarray(ext_codes, np.uint16)[order]
        rows = np.flatnonzero(ext)
        pos = np.minimum(np.searchsorted(keys, arb[rows]), len(keys) - 1)
        hit = keys[pos] == arb[rows]
        code[rows[hit]] = codes[pos[hit]]
    return code


def _decode(frames, db, problems, names, buses, dbc_path, fast):
    index = {m.name: i for i, m in enumerate(db.messages)}
    if names is None:
        wanted = list(range(len(db.messages)))
    else:
        wanted = []
        for name in names:
            if name not in index:
                raise InputError(f"message {name!r} is not in the DBC", dbc_path, key=name)
            wanted.append(index[name])
        wanted = list(dict.fromkeys(wanted))  # a name given twice is decoded once
    code = _message_codes(frames, db)
    if buses is not None:
        code[~_bus_mask(frames, buses)] = _OFF_BUS
    _report_unknown(frames, code, problems)
    # Work through the log in blocks of rows small enough that a block's columns stay in the
    # CPU cache while they are gathered per message; each message's pieces are copied into
    # columns sized for all its frames.
    plans = {i: (_fast_plan(db.messages[i]) if fast else None) for i in wanted}
    counts = np.bincount(code, minlength=_OFF_BUS + 1)
    pieces = {i: _Pieces(int(counts[i + 1])) for i in wanted}
    n = len(frames)
    for lo in range(0, max(n, 1), _BLOCK_ROWS):
        hi = min(n, lo + _BLOCK_ROWS)
        block = code[lo:hi]
        if len(wanted) <= _MASK_MESSAGES:  # a few messages: one mask each
            for i in wanted:
                idx = np.flatnonzero(block == i + 1)
                if len(idx):
                    part = _Rows.take(frames, idx + lo)
                    pieces[i].append(_decode_message(part, db.messages[i], problems, plans[i]))
            continue
        # many messages: a stable radix sort of the block's 16-bit codes groups each message's
        # frames (in time order); gather them once, each message is then a slice
        rows = np.flatnonzero((block != 0) & (block != _OFF_BUS))
        kcode = block[rows]
        order = np.argsort(kcode, kind="stable")
        bounds = np.concatenate(
            [[0], np.cumsum(np.bincount(kcode, minlength=len(db.messages) + 1)[1:])]
        )
        known = _Rows.take(frames, rows[order] + lo)
        for i in wanted:
            a, b = int(bounds[i]), int(bounds[i + 1])
            if b > a:
                pieces[i].append(
                    _decode_message(known.slice(a, b), db.messages[i], problems, plans[i])
                )
    out: dict[str, DecodedMessage] = {}
    for i in wanted:
        msg = db.messages[i]
        if not pieces[i].n_pieces:
            if names is None:
                continue
            pieces[i].append(
                _decode_message(_Rows.take(frames, np.zeros(0, np.int64)), msg, problems, plans[i])
            )
        out[msg.name] = pieces[i].joined()
    return out


class _Pieces:
    """One message's decoded pieces, block by block, joined into columns allocated once for
    ``capacity`` frames (the message's frames in the log; fewer when some are refused)."""

    def __init__(self, capacity: int):
        self.capacity, self.n, self.n_pieces = capacity, 0, 0
        self.first: DecodedMessage | None = None
        self.cols: dict | None = None

    def append(self, piece: DecodedMessage) -> None:
        self.n_pieces += 1
        if self.first is None:
            self.first = piece
            return
        if self.cols is None:  # a second piece: start the joined columns with the first
            f = self.first
            self.cols = {
                k: np.empty(self.capacity, v.dtype)
                for k, v in [("t_s", f.t_s), ("bus", f.bus), ("where", f.where)]
                + [(("s", name), v) for name, v in f.signals.items()]
            }
            self._put(f)
        self._put(piece)

    def _put(self, p: DecodedMessage) -> None:
        a, b = self.n, self.n + len(p)
        assert self.cols is not None  # allocated by append
        for k, v in [("t_s", p.t_s), ("bus", p.bus), ("where", p.where)] + [
            (("s", name), v) for name, v in p.signals.items()
        ]:
            self.cols[k][a:b] = v
        self.n = b

    def joined(self) -> DecodedMessage:
        assert self.first is not None  # every message gets at least one piece
        if self.cols is None:
            return self.first
        f, c, n = self.first, self.cols, self.n
        return DecodedMessage(
            f.name,
            f.frame_id,
            c["t_s"][:n],
            c["bus"][:n],
            c["where"][:n],
            {name: c[("s", name)][:n] for name in f.signals},
        )


def _first_true(mask: np.ndarray, n: int) -> np.ndarray:
    """Indices of the first ``n`` True entries, scanning only as far as needed."""
    step = 4096
    start = 0
    found: list = []
    while start < len(mask) and len(found) < n:
        found.extend((start + np.flatnonzero(mask[start : start + step])).tolist())
        start += step
        step *= 4
    return np.asarray(found[:n], dtype=np.int64)


def _report_unknown(frames: FrameTable, code: np.ndarray, problems: Problems) -> None:
    """Count frames (on the chosen buses) whose id no DBC message claims."""
    unknown = code == 0
    n_unknown = int(np.count_nonzero(unknown))
    if not n_unknown:
        return
    arb, ext = frames.arb_id, frames.is_extended
    std = ~ext & (arb < _SFF_IDS)
    std_ids = (
        np.flatnonzero(np.bincount(arb[unknown & std], minlength=_SFF_IDS))
        if n_unknown < len(code) // 4
        else np.flatnonzero(
            np.bincount(arb & (_SFF_IDS - 1), weights=unknown & std, minlength=_SFF_IDS)
        )
    )
    other = unknown & ~std
    ukeys = np.concatenate([std_ids, np.unique(arb[other]) if other.any() else []]).astype(np.int64)
    shown = ", ".join(f"0x{int(k):X}" for k in ukeys[:8])
    problems.add(
        KIND_UNKNOWN_ID,
        frames.path,
        frames.where[_first_true(unknown, Problems.MAX_FIRST)],
        count=n_unknown,
        detail=f"{len(ukeys)} distinct id(s): {shown}{' ...' if len(ukeys) > 8 else ''}",
        info=True,
    )  # normal on any real bus: information, not a problem


@dataclass
class _Rows:
    """The columns decoding needs, for the frames of one message (or of all known ones)."""

    t_s: np.ndarray
    bus: np.ndarray
    where: np.ndarray
    dlc: np.ndarray
    data: np.ndarray  # (n, width) uint8
    path: str

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @classmethod
    def take(cls, frames: FrameTable, rows: np.ndarray) -> _Rows:
        """Gather rows; 8-byte payloads travel as one uint64 each (much faster)."""
        if frames.data.shape[1] == 8 and frames.data.flags.c_contiguous:
            data = frames.data.view("<u8")[:, 0][rows].view(np.uint8).reshape(-1, 8)
        else:
            data = frames.data[rows]
        return cls(
            frames.t_s[rows],
            frames.bus[rows],
            frames.where[rows],
            frames.dlc[rows],
            data,
            frames.path,
        )

    def slice(self, lo: int, hi: int) -> _Rows:
        return _Rows(
            self.t_s[lo:hi],
            self.bus[lo:hi],
            self.where[lo:hi],
            self.dlc[lo:hi],
            self.data[lo:hi],
            self.path,
        )

    def mask(self, keep: np.ndarray) -> _Rows:
        return _Rows(
            self.t_s[keep],
            self.bus[keep],
            self.where[keep],
            self.dlc[keep],
            self.data[keep],
            self.path,
        )


# ----------------------------------------------------------------------------- one message
def _decode_message(part: _Rows, msg, problems: Problems, plan) -> DecodedMessage:
    """Decode ``part``: the frames of one message, in time order (``plan`` None: cantools)."""
    path = part.path
    length = int(msg.length)
    short = part.dlc < length
    if short.any():
        problems.add(
            KIND_SHORT,
            path,
            part.where[short][: Problems.MAX_FIRST],
            count=int(short.sum()),
            detail=f"{msg.name} (0x{msg.frame_id:X}) needs {length} bytes",
        )
        part = part.mask(~short)
    long_ = part.dlc > length
    if long_.any():
        problems.add(
            KIND_LONG,
            path,
            part.where[long_][: Problems.MAX_FIRST],
            count=int(long_.sum()),
            detail=f"{msg.name} (0x{msg.frame_id:X}) has {length} bytes in the DBC",
        )
    if plan is not None and length <= 8 and part.data.shape[1] == 8:
        # one 8-byte word per frame; bytes past the DBC length are never read by a plan
        le = np.ascontiguousarray(part.data).view("<u8")[:, 0]
        signals = _decode_fast(None, plan, {0: (le, le.byteswap())})
    else:
        data = np.zeros((len(part), length), np.uint8)
        w = min(length, part.data.shape[1])
        data[:, :w] = part.data[:, :w]
        if plan is not None:
            signals = _decode_fast(data, plan)
        else:
            signals, ok = _decode_cantools(data, msg)
            if not ok.all():
                problems.add(
                    KIND_UNDECODABLE,
                    path,
                    part.where[~ok][: Problems.MAX_FIRST],
                    count=int((~ok).sum()),
                    detail=f"{msg.name} (0x{msg.frame_id:X})",
                )
                signals = {k: v[ok] for k, v in signals.items()}
                part = part.mask(ok)
    return DecodedMessage(msg.name, int(msg.frame_id), part.t_s, part.bus, part.where, signals)


def _decode_cantools(data: np.ndarray, msg):
    """Per-frame cantools decoding -> (signals with NaN where absent, ok mask)."""
    from cantools.database.errors import DecodeError

    n = len(data)
    names = [s.name for s in msg.signals]
    cols = {name: np.full(n, np.nan) for name in names}
    ok = np.ones(n, bool)
    for i in range(n):
        try:
            values = msg.decode(data[i].tobytes(), decode_choices=False, scaling=True)
        except (DecodeError, ValueError, KeyError, TypeError, OverflowError):
            ok[i] = False
            continue
        for name, v in values.items():
            cols[name][i] = v
    return cols, ok


# ----------------------------------------------------------------------------- fast path
@dataclass(frozen=True)
class _SignalPlan:
    """How to read one signal from the message's 64-bit words (see :func:`_fast_plan`)."""

    name: str
    window: int  # first payload byte of the 8-byte window
    little: bool
    shift: int  # right shift of the window word
    length: int  # bits
    signed: bool
    is_float: bool
    kind: str  # 'identity' | 'float' (raw*scale+offset) | 'int' (exact integer)
    scale: float | int
    offset: float | int


def _fast_plan(msg):
    """A plan per signal, or None when the message needs cantools (mux, odd layouts)."""
    from cantools.database.conversion import (
        IdentityConversion,
        LinearConversion,
        LinearIntegerConversion,
        NamedSignalConversion,
    )

    if msg.is_multiplexed() or getattr(msg, "is_container", False):
        return None
    length = int(msg.length)
    plans = []
    for sig in msg.signals:
        conv = sig.conversion
        if isinstance(conv, NamedSignalConversion):
            conv = conv._conversion  # choices are not applied (decode_choices=False)
        n = int(sig.length)
        if n < 1 or n > 64:
            return None
        if conv.is_float and n not in (32, 64):
            return None
        if sig.byte_order == "little_endian":
            first_bit = int(sig.start)  # LSB, counting from bit 0 of byte 0
            lo_byte, hi_byte = first_bit // 8, (first_bit + n - 1) // 8
        else:
            msb = (sig.start // 8) * 8 + (7 - sig.start % 8)  # network (stream) bit number
            first_bit = int(msb)
            lo_byte, hi_byte = first_bit // 8, (first_bit + n - 1) // 8
        if hi_byte >= length or hi_byte - lo_byte >= 8:
            return None
        window = max(0, min(lo_byte, length - 8))
        if sig.byte_order == "little_endian":
            shift = first_bit - 8 * window
            little = True
        else:
            shift = 64 - (first_bit - 8 * window + n)
            little = False
        if isinstance(conv, IdentityConversion):
            kind, scale, offset = "identity", 1, 0
        elif isinstance(conv, LinearIntegerConversion):
            kind, scale, offset = "int", int(conv.scale), int(conv.offset)
            if (2**n) * abs(scale) + abs(offset) >= 2**62:
                return None  # integer product could overflow int64
        elif isinstance(conv, LinearConversion):
            kind, scale, offset = "float", conv.scale, conv.offset
            if not isinstance(scale, (int, float)) or not isinstance(offset, (int, float)):
                return None
            if not conv.is_float and isinstance(scale, int) and (2**n) * abs(scale) >= 2**53:
                return None  # cantools multiplies exact Python ints; float64 could round here
        else:
            return None
        plans.append(
            _SignalPlan(
                sig.name,
                window,
                little,
                shift,
                n,
                bool(sig.is_signed),
                bool(conv.is_float),
                kind,
                scale,
                offset,
            )
        )
    return plans


def _words(data: np.ndarray, window: int):
    """(little-endian, big-endian) uint64 of payload bytes [window, window+8), zero padded."""
    n, length = data.shape
    if window == 0 and length == 8:
        block = np.ascontiguousarray(data)
    else:
        block = np.zeros((n, 8), np.uint8)
        take = data[:, window : window + 8]
        block[:, : take.shape[1]] = take
    le = block.view("<u8")[:, 0]
    be = block.view(">u8")[:, 0].astype(np.uint64)
    return le, be


def _decode_fast(
    data: np.ndarray | None, plans, words: dict | None = None
) -> dict[str, np.ndarray]:
    """Signals from payload bytes ``data`` (n, length), or from prepared 8-byte ``words``.

    A signal occupies bits [shift, shift + length) of its 64-bit window word; shifting it
    left to the top and back right (arithmetic for signed signals) extracts and sign-extends
    it in two passes.
    """
    words = {} if words is None else words
    out = {}
    for p in plans:
        if p.window not in words:
            assert data is not None  # without payload bytes, every window's words are given
            words[p.window] = _words(data, p.window)
        le, be = words[p.window]
        word = le if p.little else be
        top = 64 - p.shift - p.length  # bits above the signal
        raw = word << np.uint64(top) if top else word
        if p.signed and not p.is_float:
            value = (
                raw.view(np.int64) >> np.int64(64 - p.length)
                if p.length < 64
                else raw.view(np.int64)
            )
        else:
            value = raw >> np.uint64(64 - p.length) if p.length < 64 else raw
        if p.is_float:
            with np.errstate(invalid="ignore"):  # signalling NaNs widen quietly, as in Python
                out[p.name] = (
                    value.astype(np.uint32).view(np.float32)
                    if p.length == 32
                    else value.view(np.float64)
                ).astype(np.float64)
            if p.kind == "float":
                out[p.name] *= p.scale
                out[p.name] += p.offset
        elif p.kind == "identity":
            out[p.name] = value.astype(np.float64)
        elif p.kind == "int":
            ival = value.astype(np.int64)
            ival *= np.int64(p.scale)
            ival += np.int64(p.offset)
            out[p.name] = ival.astype(np.float64)
        else:
            v = value.astype(np.float64)
            v *= p.scale
            v += p.offset
            out[p.name] = v
    return out
