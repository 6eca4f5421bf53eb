"""The bulk candump reader (``models.logs.candump``/``candump_fixed``) against python-can's
reader and against the reference reader (``models.logs.canlog_reference``: every line through
the general parser), frame for frame and problem for problem.

- python-can: a generated log of well-formed frames of many shapes (standard and extended
  ids, 0..8 payload bytes, upper and lower case hex, several interfaces, direction flags, CRLF)
  and malformed lines python-can refuses, read line by line by ``can.io.CanutilsLogReader``:
  hmpc keeps exactly its data frames (times bit for bit, ids, payloads, line numbers) and
  reports exactly the lines it refuses as malformed; plain and gzip, whole and in small chunks.
  (The bundled comma minute against ``can.LogReader``: ``test_canlog.py``; here it is checked
  that every one of its lines takes the bulk path.)
- reference: seeded random logs (mixed layouts, corrupted lines, remote/error/FD frames,
  duplicates, steps back, clock jumps, binary garbage) and both bundled logs give the same
  FrameTable (dtypes and widths included) and the same problems.
"""

import gzip
import io
import random

import can
import numpy as np
import pytest

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs import candump
from hmpc.models.logs.canlog import KIND_MALFORMED, read_log
from hmpc.models.logs.canlog_reference import read_log_reference
from hmpc.models.logs.candump_fixed import Layout, learn_layout

COLUMNS = ("t_s", "bus", "arb_id", "is_extended", "dlc", "data", "where")


def _same(path, **kw):
    """read_log and read_log_reference agree on ``path``: frames, problems, or the error."""
    p1, p2 = Problems(), Problems()
    try:
        a = read_log(path, p1, **kw)
    except InputError as exc:
        with pytest.raises(InputError) as ref:
            read_log_reference(path, p2, **kw)
        assert str(ref.value) == str(exc)
        return None
    b = read_log_reference(path, p2, **kw)
    for col in COLUMNS:
        x, y = getattr(a, col), getattr(b, col)
        assert x.dtype == y.dtype and x.shape == y.shape, (col, x.dtype, y.dtype, x.shape, y.shape)
        assert np.array_equal(x, y), col
    assert p1.to_list() == p2.to_list()
    return a


# ----------------------------------------------------------------------------- python-can
def _good_line(r: random.Random, t: float) -> str:
    name = r.choice(["can0", "can0", "can0", "can1", "vcan2"])
    if r.random() < 0.75:
        ident = f"{r.randrange(0x800):03X}"
    else:
        ident = f"{r.randrange(1 << 29):08X}"
    data = "".join(f"{r.randrange(256):02X}" for _ in range(r.choice([0, 1, 2, 5, 7, 8, 8, 8])))
    if r.random() < 0.2:
        data, ident = data.lower(), ident.lower()
    flag = r.choice(["", "", "", "", " R", " T"])
    return f"({t:.6f}) {name} {ident}#{data}{flag}"


#: lines python-can's reader refuses (it raises), and hmpc reports as malformed
BAD_LINES = [
    "garbage",
    "(1533226488.434433) can0",
    "(1533226488.434433) can0 12Z#00",
    "(1533226488.434433) can0 123#0G",
    "(1533226488.434433) can0 123#00 extra words",
    "1533226488.434433 can0",
]


def _generated(seed: int, n: int = 3000) -> list[str]:
    r = random.Random(seed)
    t = 1533226488.0 + r.random()
    lines = []
    for _ in range(n):
        t += r.choice([0.0001, 0.0005, 0.001])
        roll = r.random()
        if roll < 0.03:
            lines.append(r.choice(BAD_LINES))
        elif roll < 0.04:
            lines.append("")
        else:
            lines.append(_good_line(r, t) + ("\r" if roll > 0.98 else ""))
    return lines


def _python_can(lines: list[str]):
    """Per line: python-can's message (data frames only), None for a refused line."""
    out = []
    for text in lines:
        try:
            msgs = list(can.io.CanutilsLogReader(io.StringIO(text + "\n")))
        except (ValueError, IndexError):
            out.append(None)
            continue
        out.append(msgs[0] if msgs else "blank")
    return out


@pytest.mark.parametrize("gz", [False, True])
@pytest.mark.parametrize("chunk_bytes", [None, 4099])
def test_bulk_reader_equals_python_can_with_malformed_lines(tmp_path, gz, chunk_bytes):
    lines = _generated(seed=20)
    body = ("\n".join(lines) + "\n").encode()
    path = tmp_path / ("gen.log.gz" if gz else "gen.log")
    path.write_bytes(gzip.compress(body) if gz else body)
    problems = Problems()
    kw = {} if chunk_bytes is None else {"chunk_bytes": chunk_bytes}
    ft = read_log(path, problems, **kw)
    ref = _python_can(lines)
    want = [(i + 1, m) for i, m in enumerate(ref) if isinstance(m, can.Message)]
    refused = [i + 1 for i, m in enumerate(ref) if m is None]
    assert refused and len(want) > 2500
    assert len(ft) == len(want)
    assert np.array_equal(ft.where, [i for i, _ in want])
    assert np.array_equal(ft.t_s, [m.timestamp for _, m in want])  # bit for bit
    assert np.array_equal(ft.arb_id, [m.arbitration_id for _, m in want])
    assert np.array_equal(ft.is_extended, [m.is_extended_id for _, m in want])
    assert np.array_equal(ft.dlc, [len(m.data) for _, m in want])
    assert np.array_equal(ft.bus, [int(m.channel[-1]) for _, m in want])
    assert all(ft.data[k, : ft.dlc[k]].tobytes() == bytes(m.data) for k, (_, m) in enumerate(want))
    bad = [p for p in problems if p.kind == KIND_MALFORMED]
    assert len(bad) == 1 and bad[0].count == len(refused)
    assert bad[0].first == refused[: Problems.MAX_FIRST]
    _same(path, **kw)


def test_comma_minute_takes_the_bulk_path(comma_log, monkeypatch):
    general = []
    real = candump.parse_lines
    monkeypatch.setattr(
        candump, "parse_lines", lambda buf, ls, *a: general.append(len(ls)) or real(buf, ls, *a)
    )
    ft = read_log(comma_log, Problems())
    assert len(ft) == 135468 and sum(general) == 0
    with gzip.open(comma_log, "rb") as fh:
        first = fh.readline().rstrip(b"\n")
    assert learn_layout(first) == Layout(17, 10, 4)


# ----------------------------------------------------------------------------- reference reader
def _random_line(r: random.Random, t: float, one_layout: bool) -> bytes:
    layouts = ["%010d.%06d", "%d.%06d", "%d.%03d", "%d", "%d.", "%05d.%09d", "%010d.%08d"]
    lay = (
        r.choice(["%010d.%06d", "%010d.%08d"])
        if one_layout and r.random() < 0.97
        else r.choice(layouts)
    )  # 18 digits: past 2**53, the exact long-double division
    sec, frac = int(t), int((t % 1) * 1e6)
    if "%08" in lay:
        frac = frac * 100 + r.randrange(100)
    ts = (lay % (sec, frac % 1000 if "%03" in lay else frac)) if lay.count("%") == 2 else lay % sec
    name = (
        "can0"
        if one_layout and r.random() < 0.9
        else r.choice(
            [
                "can0",
                "can1",
                "vcan0",
                "can10",
                "slcan0",
                "x",
                "ab#c",
                "averyveryverylongname0",
                "c\x01n0",
                "can\xff",
            ]
        )
    )
    roll = r.random()
    if roll < 0.6:
        ident = f"{r.randrange(0x800):03X}" if r.random() < 0.9 else f"{r.randrange(0x1000):03x}"
    elif roll < 0.85:
        ident = f"{r.choice([r.randrange(1 << 29), r.randrange(1 << 32)]):08X}"
    else:
        ident = f"{r.randrange(1 << 20):X}"
    data = "".join(f"{r.randrange(256):02X}" for _ in range(r.choice([0, 3, 8, 8, 8, 9, 12])))
    if r.random() < 0.2:
        data = data.lower()
    sep, roll = "#", r.random()
    if roll < 0.04:
        data = "R"
    elif roll < 0.07:
        sep, data = "##", f"{r.randrange(16):X}" + data
    elif roll < 0.09:
        data = data[:-1]
    line = f"({ts}) {name} {ident}{sep}{data}{r.choice(['', '', '', ' R', ' T', ' x'])}"
    out = line.encode("latin-1")
    if r.random() < 0.05:
        i = r.randrange(len(out))
        out = out[:i] + bytes([r.choice(b"0aF#(). \x00\xff\r-")]) + out[i + 1 :]
    if r.random() < 0.02:
        out = out[: r.randrange(len(out) + 1)]
    return out


def _random_log(seed: int, n: int, one_layout: bool) -> bytes:
    r = random.Random(seed)
    t = 1533226488.0 + r.random()
    lines = []
    for _ in range(n):
        t += r.choice([0.0, 0.0, 0.001, -0.001, 0.002, 1.5]) if r.random() < 0.3 else 0.0001
        lines.append(_random_line(r, t, one_layout) + (b"\r" if r.random() < 0.05 else b""))
        if r.random() < 0.01:
            lines.append(lines[-2] if len(lines) > 1 else b"")  # an exact duplicate
    return b"\n".join(lines) + (b"\n" if seed % 2 else b"")


@pytest.mark.parametrize("seed", range(12))
def test_bulk_reader_equals_reference_on_random_logs(tmp_path, seed):
    path = tmp_path / "r.log"
    path.write_bytes(_random_log(seed, 400 + 700 * seed, one_layout=seed % 2 == 0))
    _same(path)
    _same(path, chunk_bytes=1009 + 97 * seed)


def test_bulk_reader_equals_reference_across_groups_and_garbage(tmp_path):
    """More lines than one group of the bulk path, a giant newline-free blob, gzip."""
    body = _random_log(99, 2 * candump.GROUP_LINES + 500, one_layout=True)
    blob = random.Random(1).randbytes(3 * 1024 * 1024).replace(b"\n", b"x")
    path = tmp_path / "big.log"
    path.write_bytes(body + b"\n" + blob + b"\n" + body)
    _same(path)
    _same(path, chunk_bytes=300_001)
    gz = tmp_path / "big.log.gz"
    gz.write_bytes(gzip.compress(path.read_bytes()))
    _same(gz)


def test_bundled_logs_equal_the_reference(comma_log, vcan_log):
    assert len(_same(comma_log)) == 135468
    assert len(_same(vcan_log)) == 68178


def test_frame_sink_grows_widens_and_prefaults_without_touching_rows():
    """The frame columns (anonymous maps, a worker writing a byte per page ahead of the
    writer) hold exactly what was appended, through a capacity estimate that falls short and
    a wider payload part way; unused payload bytes read as zero."""
    from concurrent.futures import ThreadPoolExecutor

    from hmpc.models.logs import textblocks
    from hmpc.models.logs.textscan import Chunk

    rng = np.random.default_rng(7)
    parts = []
    for k, (n, width) in enumerate([(700, 8), (3000, 8), (50, 64), (9000, 8), (1, 16)]):
        dlc = rng.integers(0, width + 1, n).astype(np.uint8)
        data = rng.integers(0, 256, (n, width)).astype(np.uint8)
        data[np.arange(width) >= dlc[:, None]] = 0
        parts.append(
            Chunk(
                rng.random(n) + k,
                None,
                rng.integers(0, 0x800, n).astype(np.uint32),
                rng.random(n) < 0.5,
                dlc,
                data,
                np.arange(n, dtype=np.int64) + 10 * k,
                {},
            )
        )
    sink = textblocks.FrameSink(1024)
    with ThreadPoolExecutor(1) as pool:
        pool.submit(sink.prefault)
        for k, ch in enumerate(parts):
            sink.append(ch, np.full(len(ch.t), k, np.int16))
        sink.close()
    ft = sink.table("x.log")
    n = sum(len(ch.t) for ch in parts)
    assert len(ft) == n and ft.data.shape == (n, 64)
    assert np.array_equal(ft.t_s, np.concatenate([ch.t for ch in parts]))
    assert np.array_equal(
        ft.bus, np.concatenate([np.full(len(ch.t), k) for k, ch in enumerate(parts)])
    )
    assert np.array_equal(ft.arb_id, np.concatenate([ch.arb_id for ch in parts]))
    assert np.array_equal(ft.is_extended, np.concatenate([ch.ext for ch in parts]))
    assert np.array_equal(ft.where, np.concatenate([ch.where for ch in parts]))
    want = np.concatenate([np.pad(ch.data, ((0, 0), (0, 64 - ch.data.shape[1]))) for ch in parts])
    assert np.array_equal(ft.data, want) and np.array_equal(
        ft.dlc, np.concatenate([c.dlc for c in parts])
    )
