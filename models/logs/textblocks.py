"""A text log read in blocks of whole lines, and the columns its frames are collected in.

:func:`iter_blocks` reads the file a chunk at a time into two buffers in turn while a worker
thread reads (and decompresses) the next chunk and finds its line feeds, so the parser never
waits for the disk or zlib and no block is copied. :class:`FrameSink` holds the frame columns
for the whole file, allocated once; a worker thread touches their memory ahead of the writer
(:meth:`FrameSink.prefault`), so the page faults of first use are not taken in the parse loop.

Imports only numpy, ``models.errors`` and ``models.logs.frames``/``candump_fixed``.
"""

from __future__ import annotations

import mmap
import threading
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, cast
from collections.abc import Callable

import numpy as np

from hmpc.models.logs.files import open_binary
from hmpc.models.errors import InputError
from hmpc.models.logs.candump_fixed import REACH
from hmpc.models.logs.frames import FrameTable

#: zero bytes around each block in the reader's buffer (the bulk reader loads words past a line)
PAD = REACH
#: a "line" longer than this (binary garbage without newlines) is cut into pieces of this size
MAX_LINE_BYTES = 1024 * 1024
#: rows of every column one step of :meth:`FrameSink.prefault` touches (~2 MB of columns)
PREFAULT_ROWS = 1 << 16
#: how far :meth:`FrameSink.prefault` runs ahead of the writer [rows] (~64 MB of columns): a
#: generous estimate of the file's frames is never touched all at once
PREFAULT_AHEAD = 1 << 21


def iter_blocks(
    p: Path, gz: bool, chunk_bytes: int, on_truncated: Callable[[int], None] | None = None
):
    """Yield (base, nl, cut): blocks of whole lines at ``base[PAD:PAD + nl[-1] + 1]``, ``nl``
    their line feeds (the last one's is added when the file lacks it), ``base`` zero padded by
    at least :data:`PAD` bytes on both sides of the block.

    The file is read ``chunk_bytes`` at a time into two buffers in
    turn: a worker thread reads the next chunk and finds its line feeds while the caller
    parses the block before; the unfinished line at a block's end moves to the front of the
    other buffer. A newline-free run longer than :data:`MAX_LINE_BYTES` (binary garbage) is cut
    into pieces; ``cut`` is 1 when the block's final line break was added there, so the caller
    keeps counting lines as the file has them (the pieces share one line number).

    A gzip stream that ends early is read up to where it ends; then ``on_truncated`` is called
    with the decompressed bytes read (the blocks before the cut are yielded as usual; a
    partial last line is yielded too and its parser rejects it like any malformed line).
    """
    room = max(chunk_bytes, MAX_LINE_BYTES) + chunk_bytes + 1
    bufs = [np.zeros(PAD + room + PAD, np.uint8) for _ in range(2)]
    is_lf = [np.empty(chunk_bytes, bool) for _ in range(2)]
    cur, held = 0, 0
    try:
        with open_binary(p, gz) as fh, ThreadPoolExecutor(1) as pool:

            def fill(k: int, held: int):
                """Read the next chunk into buffer k after its ``held`` bytes: (bytes read,
                line feeds among all its bytes)."""
                view = memoryview(cast(Any, bufs[k]))  # numpy's stubs: no buffer before 3.12
                n = fh.readinto(view[PAD + held : PAD + held + chunk_bytes])
                np.equal(bufs[k][PAD + held : PAD + held + n], 10, out=is_lf[k][:n])
                return n, np.flatnonzero(is_lf[k][:n]) + held

            job = pool.submit(fill, cur, held)
            while True:
                n, nl = job.result()
                if n == 0:
                    break
                base, total = bufs[cur], held + n
                if len(nl) == 0:
                    if total <= MAX_LINE_BYTES:
                        held = total
                        job = pool.submit(fill, cur, held)
                        continue
                    base[PAD + total] = 10  # a giant newline-free blob: never valid, cut it
                    job = pool.submit(fill, 1 - cur, 0)
                    yield base, np.array([total]), 1
                    cur, held = 1 - cur, 0
                    continue
                end = int(nl[-1]) + 1
                held = total - end
                bufs[1 - cur][PAD : PAD + held] = base[PAD + end : PAD + total]
                job = pool.submit(fill, 1 - cur, held)
                yield base, nl, 0
                cur = 1 - cur
            truncated = bool(getattr(fh, "truncated", False))
            text_read = int(getattr(fh, "text_bytes", 0))
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read (corrupt file?): {exc}", str(p)) from None
    if truncated and on_truncated is not None:
        on_truncated(text_read)
    if held:
        bufs[cur][PAD + held] = 10
        yield bufs[cur], np.array([held]), 0


def text_bytes(p: Path, gz: bool) -> int:
    """How many bytes of text the file holds: its size, or the size a gzip file's trailer
    gives (modulo 4 GiB; only an estimate)."""
    size = p.stat().st_size
    if not gz or size < 18:
        return size
    with open(p, "rb") as fh:
        fh.seek(-4, 2)
        isize = int.from_bytes(fh.read(4), "little")
    return isize if isize >= size else 8 * size


def _anonymous(shape, dtype) -> np.ndarray:
    """A zeroed array in its own anonymous memory map, page by page as it is first touched.

    numpy asks the kernel for transparent huge pages for arrays this large, and where the
    kernel then compacts memory at fault time (``defrag`` set to ``madvise``, the common
    default) a machine with much page cache spends a large share of the read in those faults
    (``docs/benchmarks.md``); the columns here are written once, in order, so ordinary pages
    lose nothing.
    """
    count = int(np.prod(shape, dtype=np.int64))
    nbytes = max(count * np.dtype(dtype).itemsize, 1)
    return np.frombuffer(mmap.mmap(-1, nbytes), dtype, count).reshape(shape)


class FrameSink:
    """Frames appended part by part to columns allocated once for the whole file (grown if
    the estimate falls short), so no part is copied twice.

    :meth:`prefault`, run in a worker thread, writes zeros to the rows ahead of the writer:
    the rows the writer has reserved and the rows being touched never overlap (a lock and
    ``_claim``), and the writer only waits when it reaches rows being touched at that moment.
    """

    def __init__(self, capacity: int):
        self.n, self.cap, self.width = 0, 0, 8
        self.cols: dict[str, np.ndarray] = {}
        self._cond = threading.Condition()
        self._claim: tuple[int, int] | None = None  # rows the prefault is writing now
        self._closed = False
        self._grow(max(capacity, 1024), 8)

    def _grow(self, cap: int, width: int) -> None:
        old, n = self.cols, self.n
        self.cols = {
            "t_s": _anonymous(cap, np.float64),
            "bus": _anonymous(cap, np.int16),
            "arb_id": _anonymous(cap, np.uint32),
            "is_extended": _anonymous(cap, bool),
            "dlc": _anonymous(cap, np.uint8),
            "data": _anonymous((cap, width), np.uint8),
            "where": _anonymous(cap, np.int64),
        }
        for k, v in old.items():
            if k == "data":
                self.cols[k][:n, : v.shape[1]] = v[:n]
            else:
                self.cols[k][:n] = v[:n]
        self.cap, self.width = cap, width

    def append(self, ch, bus: np.ndarray) -> None:
        k = len(ch.t)
        w = ch.data.shape[1]
        a, b = self.n, self.n + k
        with self._cond:
            while self._claim is not None and (
                b > self.cap or w > self.width or (self._claim[0] < b and a < self._claim[1])
            ):
                self._cond.wait()
            if b > self.cap or w > self.width:
                self._grow(
                    self.cap if b <= self.cap else max(b, self.cap * 3 // 2), max(w, self.width)
                )
            self.n = b  # reserved: the prefault starts past it
            self._cond.notify_all()
        c = self.cols
        c["t_s"][a:b] = ch.t
        c["bus"][a:b] = bus
        c["arb_id"][a:b] = ch.arb_id
        c["is_extended"][a:b] = ch.ext
        c["dlc"][a:b] = ch.dlc
        c["data"][a:b, :w] = ch.data
        c["where"][a:b] = ch.where

    def prefault(self) -> None:
        """Write a zero byte to each memory page of the rows ahead of the writer, up to
        :data:`PREFAULT_AHEAD` rows ahead, until :meth:`close` (run it in a worker thread).
        The columns' pages are zero already (anonymous maps): the write only makes the
        kernel provide each page here rather than in the writer."""
        done = 0
        while True:
            with self._cond:
                while not self._closed and max(done, self.n) >= min(
                    self.n + PREFAULT_AHEAD, self.cap
                ):
                    self._cond.wait()
                if self._closed:
                    return
                a = max(done, self.n)
                b = min(a + PREFAULT_ROWS, self.cap)
                self._claim, cols = (a, b), self.cols
            try:
                for v in cols.values():
                    row = v.strides[0]
                    v.reshape(-1).view(np.uint8)[a * row : b * row : mmap.PAGESIZE] = 0
            finally:
                with self._cond:
                    self._claim = None
                    self._cond.notify_all()
            done = b

    def close(self) -> None:
        """Stop :meth:`prefault` (it returns once its current step is written)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def table(self, path: str) -> FrameTable:
        n, c = self.n, self.cols
        return FrameTable(
            c["t_s"][:n],
            c["bus"][:n],
            c["arb_id"][:n],
            c["is_extended"][:n],
            c["dlc"][:n],
            c["data"][:n],
            c["where"][:n],
            path,
        )
