"""libpanda/strym CSV text to frames: ``Time,Bus,MessageID,Message[,MessageLength][,...]``.

Decimal id, hex payload; the columns are found by header name (``models.logs.canlog`` reads
the header), extra columns are ignored. Every field is read with the masked, variable-width
gathers of ``models.logs.textscan`` (no Python loop per line). Imports only numpy and
``models.logs.textscan``/``frames``.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.frames import EFF_MASK, MAX_PAYLOAD, SFF_MAX
from hmpc.models.logs.textscan import (
    SKIP_MALFORMED,
    Buf,
    Chunk,
    dec_int,
    dec_time,
    line_bounds,
    payload,
)


class LibpandaChunkParser:
    """Parse blocks of libpanda CSV lines whose columns are given by the header."""

    def __init__(self, cols: dict):
        self.cols = cols

    def __call__(self, b: np.ndarray, line0: int, first_line: int) -> Chunk:
        c = self.cols
        ls, le = line_bounds(b)
        lineno = line0 + 1 + np.arange(len(ls), dtype=np.int64)
        keep = (le > ls) & (lineno >= first_line)  # blank lines and the header
        ls, le, lineno = ls[keep], le[keep], lineno[keep]
        buf = Buf(b)
        cp = buf.positions_of(44, pad=c["ncols"] + 1)
        ic = np.searchsorted(cp, ls)
        ok = (np.searchsorted(cp, le) - ic) == c["ncols"] - 1

        def field(j: int) -> tuple[np.ndarray, np.ndarray]:
            start = ls if j == 0 else cp[ic + j - 1] + 1
            end = le if j == c["ncols"] - 1 else cp[ic + j]
            return start, np.where(ok, end - start, 0)

        t, ok = dec_time(buf, *field(c["Time"]), ok)
        bus, ok = dec_int(buf, *field(c["Bus"]), ok, 4)
        mid, ok = dec_int(buf, *field(c["MessageID"]), ok, 10)
        ok &= mid <= EFF_MASK
        s, n = field(c["Message"])
        data, dlc, ok = payload(buf, s, np.where(ok, n, 0), ok, MAX_PAYLOAD)
        if c["MessageLength"] is not None:
            ml, ok = dec_int(buf, *field(c["MessageLength"]), ok, 3)
            ok &= ml == dlc
        return Chunk(
            t[ok],
            bus[ok],
            mid[ok].astype(np.uint32),
            mid[ok] > SFF_MAX,
            dlc[ok],
            data[ok],
            lineno[ok],
            {SKIP_MALFORMED: lineno[~ok]},
        )

    def scan(self, base: np.ndarray, pad: int, nl: np.ndarray, line0: int, first_line: int):
        """The block ``base[pad:pad + nl[-1] + 1]`` as one part (the bulk readers' interface)."""
        yield self(base[pad : pad + int(nl[-1]) + 1], line0, first_line)
