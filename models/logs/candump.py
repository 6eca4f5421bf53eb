"""``candump -L`` text to frames: the lines of a common layout in bulk, the rest line-shaped.

``(1533226488.434433) can0 2E4#BE000000A9``; also ``ID##<flags><data>`` CAN FD frames,
``ID#R`` remote frames and a trailing ``R``/``T`` direction flag.

:func:`parse_lines` is the general parser: it finds each line's spaces, ``#`` and dot by
searching the whole block and reads every field with masked, variable-width gathers, so it
takes any line python-can's reader takes and says why it skips the others.
:class:`CandumpScanner` first reads the lines that share one of a few fixed layouts with
``models.logs.candump_fixed`` (the same frames from far fewer numpy passes per line) and hands
only the other lines to :func:`parse_lines`. Neither runs Python per line.

Imports only numpy and ``models.logs.textscan``/``candump_fixed``/``frames``.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.candump_fixed import REACH, Layout, learn_layout, parse_fixed, printable
from hmpc.models.logs.frames import CAN_ERR_FLAG, EFF_MASK, MAX_PAYLOAD, SFF_MAX
from hmpc.models.logs.textscan import (
    HEX,
    SKIP_ERROR_FRAME,
    SKIP_MALFORMED,
    SKIP_REMOTE,
    Buf,
    Chunk,
    dec_time,
    hex_int,
    line_bounds,
    payload,
    width_of,
)

#: lines parsed by one numpy operation of the bulk path: each of its uint64 temporaries
#: (96 KB) stays below glibc's mmap threshold (128 KB), so it is reused from the heap and
#: the CPU cache instead of being mapped and faulted in afresh
GROUP_LINES = 12_000
#: most layouts a file may have before the rest of its lines all take the general parser
MAX_LAYOUTS = 4
#: fewer lines than this left by the known layouts go straight to the general parser
MIN_LINES_FOR_LAYOUT = 64
#: lines left over that are tried for a new layout (a remote or malformed line has none)
LAYOUT_CANDIDATES = 16
#: distinct interface names per group checked for the bulk path (more: general parser)
MAX_NAMES = 16


def parse_block(b: np.ndarray, line0: int, first_line: int = 1) -> Chunk:
    """Parse one block of ``candump -L`` lines (ending with LF) with :func:`parse_lines`;
    ``line0`` = lines before the block."""
    ls, le = line_bounds(b)
    lineno = line0 + 1 + np.arange(len(ls), dtype=np.int64)
    keep = (le > ls) & (lineno >= first_line)  # blank lines: nothing (python-can skips them too)
    return parse_lines(Buf(b), ls[keep], le[keep], lineno[keep])


def parse_lines(buf: Buf, ls: np.ndarray, le: np.ndarray, lineno: np.ndarray) -> Chunk:
    """The general parser: non-blank lines [ls, le) of ``buf`` with their line numbers."""
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
    ok &= ~fd | ((h + 2 < fe) & (HEX[buf.at(h + 2)] != 255))
    ds = np.where(fd, h + 3, h + 1)
    remote = ok & (ds < fe) & ((buf.at(ds) | 32) == 114)  # 'r' or 'R'
    # id
    idval, ok = hex_int(buf, s1 + 1, h - s1 - 1, ok, 8)
    ext = (h - s1 - 1) > 3
    errframe = ok & ext & ((idval & np.uint64(CAN_ERR_FLAG)) != 0)
    arb = (idval & np.uint64(EFF_MASK)).astype(np.uint32)
    ok &= ext | (arb <= SFF_MAX)
    # interface name
    iflen = s1 - s0 - 1
    ok &= (iflen >= 1) & (iflen <= 16)
    # timestamp
    t, ok = dec_time(buf, ls + 1, s0 - ls - 2, ok)
    # payload
    good = ok & ~remote & ~errframe
    data, dlc, pok = payload(buf, ds, np.where(good, fe - ds, 0), good, MAX_PAYLOAD)
    pok &= fd | (dlc <= 8)  # a classic frame holds at most 8 bytes
    bad = ~ok | (good & ~pok)
    good &= pok
    nw = 8 if width_of(iflen, good, 16) <= 8 else 16
    names = buf.gather(s0[good] + 1, nw)
    names[np.arange(nw) >= iflen[good][:, None]] = 0
    skipped = {
        SKIP_MALFORMED: lineno[bad],
        SKIP_REMOTE: lineno[remote & ok],
        SKIP_ERROR_FRAME: lineno[errframe & ~remote],
    }
    return Chunk(t[good], names, arb[good], ext[good], dlc[good], data[good], lineno[good], skipped)


class CandumpScanner:
    """Blocks of ``candump -L`` text -> :class:`Chunk` parts, one per group of lines, in line
    order. Layouts learnt from a line are kept for the rest of the file."""

    def __init__(self):
        self.layouts: list[Layout] = []

    def __call__(self, base: np.ndarray, pad: int, nl: np.ndarray, line0: int, first_line: int):
        """Parts of the block ``base[pad:pad + nl[-1] + 1]`` (``nl``: its line feeds);
        ``base`` holds at least ``REACH`` bytes of padding on both sides."""
        if pad < REACH or len(base) - (pad + int(nl[-1]) + 1) < REACH:
            raise ValueError("block not padded for the bulk reader")
        aligned = base[: len(base) // 8 * 8].view("<u8")
        for g0 in range(0, len(nl), GROUP_LINES):
            g1 = min(g0 + GROUP_LINES, len(nl))
            le = nl[g0:g1] + pad
            ls = np.empty_like(le)
            ls[0] = pad if g0 == 0 else nl[g0 - 1] + 1 + pad
            ls[1:] = le[:-1] + 1
            le -= (le > ls) & (base.take(le - 1) == 13)  # a CR before the LF is not content
            lineno = line0 + 1 + g0 + np.arange(g1 - g0, dtype=np.int64)
            yield self._group(base, aligned, pad, ls, le, lineno, first_line)

    def _group(self, base, aligned, pad, ls, le, lineno, first_line) -> Chunk:
        keep = (le > ls) & (lineno >= first_line)
        ok = np.zeros(len(ls), bool)
        fx = []  # (rows, Fixed) per layout tried
        for k in range(MAX_LAYOUTS + 1):
            todo = np.flatnonzero(keep & ~ok)
            if len(todo) < (1 if k < len(self.layouts) else MIN_LINES_FOR_LAYOUT):
                break
            if k == len(self.layouts):
                lay = self._new_layout(base, ls, le, todo) if k < MAX_LAYOUTS else None
                if lay is None:
                    break
                self.layouts.append(lay)
            whole = len(todo) == len(ls)
            rows = slice(None) if whole else todo
            f = parse_fixed(self.layouts[k], aligned, base, ls[rows], le[rows])
            _check_names(f, self.layouts[k].name_chars)
            if whole:
                ok = f.ok.copy()
            else:
                ok[todo[f.ok]] = True
            fx.append((rows, f))
        fast = _join_fixed(fx, len(ls), ok, lineno)
        slow = keep & ~ok
        if not slow.any():
            return fast
        lo, hi = int(ls[0]), int(le[-1]) + 1
        sub = parse_lines(Buf(base[lo:hi]), ls[slow] - lo, le[slow] - lo, lineno[slow])
        return _merge(fast, sub)

    def _new_layout(self, base, ls, le, todo) -> Layout | None:
        """A layout not yet known, from one of the first lines left over (None if none)."""
        for i in todo[:LAYOUT_CANDIDATES].tolist():
            lay = learn_layout(base[ls[i] : le[i]].tobytes())
            if lay is not None and lay not in self.layouts:
                return lay
        return None


def _check_names(f, name_chars: int) -> None:
    """Only printable names without spaces take the bulk path: others are left (not ok)."""
    todo = f.ok.copy()
    for _ in range(MAX_NAMES):
        if not todo.any():
            return
        i = int(np.argmax(todo))
        same = todo & (f.name == f.name[i])
        if not printable(int(f.name[i]).to_bytes(8, "little")[:name_chars]):
            f.ok &= ~same
        todo &= ~same
    f.ok &= ~todo


def _join_fixed(fx, n: int, ok: np.ndarray, lineno: np.ndarray) -> Chunk:
    """The bulk path's frames of a group, in line order."""
    if len(fx) == 1 and isinstance(fx[0][0], slice):  # one layout over the whole group
        f = fx[0][1]
        if ok.all():
            cols = (f.t_s, f.name, f.arb_id, f.ext, f.dlc, f.data, lineno)
        else:
            cols = tuple(c[ok] for c in (f.t_s, f.name, f.arb_id, f.ext, f.dlc, f.data, lineno))
    else:
        full: tuple[np.ndarray, ...] = (
            np.zeros(n),
            np.zeros(n, np.uint64),
            np.zeros(n, np.uint32),
            np.zeros(n, bool),
            np.zeros(n, np.uint8),
            np.zeros(n, np.uint64),
        )
        for rows, f in fx:
            idx = np.arange(n)[rows][f.ok]
            for dst, src in zip(full, (f.t_s, f.name, f.arb_id, f.ext, f.dlc, f.data)):
                dst[idx] = src[f.ok]
        cols = tuple(c[ok] for c in full) + (lineno[ok],)
    t, name, arb, ext, dlc, data, where = cols
    return Chunk(
        t,
        np.ascontiguousarray(name).view(np.uint8).reshape(-1, 8),
        arb,
        ext,
        dlc,
        np.ascontiguousarray(data).view(np.uint8).reshape(-1, 8),
        where,
        {},
    )


def _merge(a: Chunk, b: Chunk) -> Chunk:
    """Two parts of one group (disjoint lines) as one, in line order. The payload columns are
    as wide as the wider part's (the general parser widens them for every line it took as
    well-formed so far, even one it then refused)."""
    w = max(a.data.shape[1], b.data.shape[1])
    if len(b.t) == 0:
        data = a.data if a.data.shape[1] == w else np.pad(a.data, ((0, 0), (0, w - 8)))
        return Chunk(a.t, a.bus, a.arb_id, a.ext, a.dlc, data, a.where, b.skipped)
    order = np.argsort(np.concatenate([a.where, b.where]), kind="stable")

    def cat(x, y):
        if x.ndim == 2 and x.shape[1] != y.shape[1]:
            m = max(x.shape[1], y.shape[1])
            x, y = (np.pad(z, ((0, 0), (0, m - z.shape[1]))) for z in (x, y))
        return np.concatenate([x, y])[order]

    return Chunk(
        cat(a.t, b.t),
        cat(a.bus, b.bus),
        cat(a.arb_id, b.arb_id),
        cat(a.ext, b.ext),
        cat(a.dlc, b.dlc),
        cat(a.data, b.data),
        cat(a.where, b.where),
        b.skipped,
    )
