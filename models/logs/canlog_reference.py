"""The reference CAN log reader: every text line through the general parser, for tests and
``tools/bench_ingest.py`` only.

:func:`read_log_reference` reads a log as :func:`hmpc.models.logs.canlog.read_log` does, with
the same results, but the plain way: each block of the file is copied out of the read, parsed
whole by the general line parsers (``models.logs.candump.parse_block``,
``models.logs.libpanda.LibpandaChunkParser``), the blocks' tables are joined at the end, and
the clock checks run over whole columns (duplicates compared exactly in every run of equal
timestamps, without a hash screen). Tests hold the bulk reader to it; the benchmark times it
as the baseline. Nothing else should call it.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.candump import parse_block
from hmpc.models.logs.canlog import (
    _SKIP_KIND,
    CHUNK_BYTES,
    DROPPED_KINDS,
    KIND_BACKWARDS,
    KIND_DUPLICATE,
    KIND_JUMP,
    KIND_MALFORMED,
    _BusMapper,
    _libpanda_columns,
    _read_python_can,
    _resolve,
)
from hmpc.models.logs.frames import FrameTable
from hmpc.models.logs.libpanda import LibpandaChunkParser
from hmpc.models.logs.files import open_binary
from hmpc.models.logs.textblocks import MAX_LINE_BYTES


def read_log_reference(
    path,
    problems: Problems,
    *,
    fmt: str | None = None,
    jump_s: float = 1.0,
    chunk_bytes: int = CHUNK_BYTES,
) -> FrameTable:
    """Same arguments, result and problems as :func:`hmpc.models.logs.canlog.read_log`."""
    p, gz, head, fmt = _resolve(path, fmt)
    if fmt == "candump":
        table = _read_text(
            p, gz, problems, parse_block, first_line=1, chunk_bytes=chunk_bytes, what="candump -L"
        )
    elif fmt == "libpanda":
        cols, header_lines = _libpanda_columns(p, head)
        table = _read_text(
            p,
            gz,
            problems,
            LibpandaChunkParser(cols),
            first_line=1 + header_lines,
            chunk_bytes=chunk_bytes,
            what="libpanda CSV",
        )
    else:
        table = _read_python_can(p, gz, fmt, problems)
    return _clock_checks(table, problems, jump_s)


def _iter_chunks(p: Path, gz: bool, chunk_bytes: int):
    """Yield (block, cut) with blocks that end at a line break (the last one gets one).

    A newline-free run longer than :data:`MAX_LINE_BYTES` (binary garbage) is cut into
    pieces; ``cut`` is 1 when the block's final line break was added there, so the caller
    keeps counting lines as the file has them (the pieces share one line number).
    """
    rest = b""
    try:
        with open_binary(p, gz) as fh:
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
                yield buf[: cut + 1], 0
                rest = buf[cut + 1 :]
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read (corrupt or truncated file?): {exc}", str(p)) from None
    if rest:
        yield rest + b"\n", 0


def _read_text(
    p: Path, gz: bool, problems: Problems, parser, *, first_line: int, chunk_bytes: int, what: str
) -> FrameTable:
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
        for why, lines in ch.skipped.items():
            if len(lines):
                skipped.setdefault(_SKIP_KIND[why], []).append(lines)
        bus = ch.bus.astype(np.int16) if ch.bus.ndim == 1 else mapper.map(ch.bus)
        parts.append(FrameTable(ch.t, bus, ch.arb_id, ch.ext, ch.dlc, ch.data, ch.where, spath))
        del ch, b, block
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
    table = FrameTable.concat(parts) if parts else FrameTable.empty(spath)
    table.path = spath
    if len(table) == 0:
        bad = skipped.get(KIND_MALFORMED)
        first = int(np.concatenate(bad)[0]) if bad else None
        raise InputError(
            f"no usable CAN frame: not a {what} log, or every line is malformed", spath, line=first
        )
    return table


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
    dt = np.diff(ft.t_s)
    back = np.flatnonzero(dt < 0) + 1
    if len(back):
        problems.add(
            KIND_BACKWARDS,
            spath,
            ft.where[back[: Problems.MAX_FIRST]],
            count=len(back),
            detail=f"largest step back {-dt.min():.6g} s",
        )
        order = np.argsort(ft.t_s, kind="stable")
        ft = ft.take(order)
        dt = np.diff(ft.t_s)
    # exact duplicates can only sit among frames that share a timestamp
    same = np.flatnonzero(dt == 0)
    if len(same):
        drop = _duplicates(ft, same)
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
            dt = np.diff(ft.t_s)
    jumps = np.flatnonzero(dt > jump_s) + 1
    if len(jumps):
        problems.add(
            KIND_JUMP,
            spath,
            ft.where[jumps[: Problems.MAX_FIRST]],
            count=len(jumps),
            detail=f"gap between consecutive frames over {jump_s:g} s, largest {dt.max():.6g} s",
        )
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
    if runlen.max() > 32:  # long runs of one timestamp: sort whole rows instead
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
