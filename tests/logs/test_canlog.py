"""hmpc's CAN log readers against independent readings of the same real frames.

- candump: hmpc's vectorised reader equals python-can's ``LogReader`` frame by frame on the real
  comma minute.
- libpanda: equals Python's ``csv`` module + ``float``/``int``/``bytes.fromhex`` on the real
  VerifiedCAN drive.
- asc/blf/trc/csv/candump (plain and gzip): real frames written with python-can's writers read
  back identically (payloads, ids, bus partition exactly; times to the format's resolution).
"""

import csv
import gzip
import itertools
import shutil

import can
import numpy as np
import pytest

from hmpc.models.logs.canlog import KIND_REMOTE, read_log
from hmpc.models.errors import InputError, Problems


def _messages(path, n=None):
    msgs = list(itertools.islice(can.LogReader(str(path)), n))
    assert msgs
    return msgs


def test_candump_equals_python_can_frame_by_frame(comma_log):
    msgs = _messages(comma_log)
    problems = Problems()
    ft = read_log(comma_log, problems)
    assert len(problems) == 0
    assert len(ft) == len(msgs) == 135468
    assert np.array_equal(ft.t_s, [m.timestamp for m in msgs])  # bit-exact float64
    assert np.array_equal(ft.arb_id, [m.arbitration_id for m in msgs])
    assert np.array_equal(ft.is_extended, [m.is_extended_id for m in msgs])
    assert np.array_equal(ft.dlc, [len(m.data) for m in msgs])
    assert np.array_equal(ft.bus, [int(m.channel[-1]) for m in msgs])  # can0 -> 0, can1 -> 1
    assert all(ft.data[i, : ft.dlc[i]].tobytes() == bytes(m.data) for i, m in enumerate(msgs))
    assert ft.data.shape[1] == 8  # width = longest payload in the file
    assert np.array_equal(ft.where, np.arange(1, len(msgs) + 1))


def test_small_chunks_give_the_same_table(comma_log, tmp_path):
    whole = read_log(comma_log, Problems())
    chunked = read_log(comma_log, Problems(), chunk_bytes=3001)  # lines cut across chunks
    for col in ("t_s", "bus", "arb_id", "is_extended", "dlc", "data", "where"):
        assert np.array_equal(getattr(whole, col), getattr(chunked, col)), col


def test_libpanda_equals_csv_module(vcan_log):
    with gzip.open(vcan_log, "rt", newline="") as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["Time"]) for r in rows])
    order = np.argsort(t, kind="stable")  # the reader returns time order
    problems = Problems()
    ft = read_log(vcan_log, problems)
    assert len(ft) == len(rows) == 68178
    assert np.array_equal(ft.t_s, t[order])  # bit-exact, also for 7-decimal times past 2**53
    assert np.array_equal(ft.where, order + 2)  # line numbers (line 1 is the header)
    assert np.array_equal(ft.bus, [int(rows[i]["Bus"]) for i in order])
    assert np.array_equal(ft.arb_id, [int(rows[i]["MessageID"]) for i in order])
    assert np.array_equal(ft.dlc, [int(rows[i]["MessageLength"]) for i in order])
    assert all(
        ft.data[k, : ft.dlc[k]].tobytes() == bytes.fromhex(rows[i]["Message"])
        for k, i in enumerate(order)
    )
    backwards = [p for p in problems if p.kind.startswith("timestamp earlier")]
    assert sum(p.count for p in backwards) == int(np.sum(np.diff(t) < 0))


def test_libpanda_column_order_from_header(tmp_path):
    """The sweep file's layout: an extra Buffer column in second place."""
    p = tmp_path / "sweep.csv"
    p.write_text(
        "Time,Buffer,Bus,MessageID,Message,MessageLength\n"
        "1583178870.7570062,000040520800d4e7000000000200009e,0,658,000000000200009e,8\n"
        "1583178870.759268,000000301800acc55d084400e0000113,1,384,5d084400e0000113,8\n"
    )
    ft = read_log(p, Problems())
    assert list(ft.t_s) == [1583178870.7570062, 1583178870.759268]
    assert list(ft.bus) == [0, 1] and list(ft.arb_id) == [658, 384]
    assert ft.data[1].tobytes() == bytes.fromhex("5d084400e0000113")


WRITERS = {
    "asc": (can.ASCWriter, 1e-3),  # ASC: trigger-block start has ms resolution
    "blf": (can.BLFWriter, 1e-9),
    "trc": (can.TRCWriter, 1e-6),
    "csv": (can.CSVWriter, 0.0),
    "log": (can.CanutilsLogWriter, 0.0),
}


@pytest.mark.parametrize("fmt", sorted(WRITERS))
@pytest.mark.parametrize("compress", [False, True], ids=["plain", "gz"])
def test_python_can_formats_read_back(comma_log, tmp_path, fmt, compress):
    msgs = _messages(comma_log, 3000)
    for m in msgs:
        m.channel = int(m.channel[-1])
    writer_cls, tol_s = WRITERS[fmt]
    path = tmp_path / f"real.{fmt}"
    writer = writer_cls(str(path))
    for m in msgs:
        writer.on_message_received(m)
    writer.stop()
    if compress:
        gz = tmp_path / f"real.{fmt}.gz"
        with open(path, "rb") as src, gzip.open(gz, "wb") as dst:
            shutil.copyfileobj(src, dst)
        path.unlink()
        path = gz
    problems = Problems()
    ft = read_log(path, problems)
    assert len(problems) == 0, problems.lines()
    assert len(ft) == len(msgs)
    assert np.array_equal(ft.arb_id, [m.arbitration_id for m in msgs])
    assert np.array_equal(ft.is_extended, [m.is_extended_id for m in msgs])
    assert np.array_equal(ft.dlc, [len(m.data) for m in msgs])
    assert all(ft.data[i, : ft.dlc[i]].tobytes() == bytes(m.data) for i, m in enumerate(msgs))
    t = np.array([m.timestamp for m in msgs])
    assert np.max(np.abs(ft.t_s - t)) <= tol_s + 1e-12 * np.max(t)
    orig_bus = np.array([m.channel for m in msgs])
    if fmt == "csv":  # python-can's CSV stores no channel
        assert not ft.bus.any()
    else:  # same partition of frames into buses (TRC numbers channels from 1)
        pairs = set(zip(orig_bus.tolist(), ft.bus.tolist()))
        assert len(pairs) == len(set(orig_bus.tolist())) == len({b for _, b in pairs})


def test_candump_variants_and_bus_names(tmp_path):
    p = tmp_path / "variants.log"
    p.write_text(
        "(1.000000) vcan0 123#DEADBEEF\n"
        "(1.000100) can1 12345678#0102 T\n"  # extended id, direction flag
        "(1.000200) can1 321##1" + "AB" * 12 + "\n"  # CAN FD, flags 1, 12 bytes
        "(1.000300) vcan0 7FF#\n"  # empty payload
        "(1.000400) slcan 100#R\n"  # remote frame: no payload
        "\n"
        "(1.000500) slcan 100#11\r\n"
    )  # CRLF, name without a number
    problems = Problems()
    ft = read_log(p, problems)
    assert list(ft.arb_id) == [0x123, 0x12345678, 0x321, 0x7FF, 0x100]
    assert list(ft.is_extended) == [False, True, False, False, False]
    assert list(ft.dlc) == [4, 2, 12, 0, 1]
    assert ft.data.shape[1] == 12 and ft.data[2].tobytes() == b"\xab" * 12
    assert list(ft.bus) == [0, 1, 1, 0, 2]  # slcan: next free number
    assert list(ft.where) == [1, 2, 3, 4, 7]
    assert [(q.kind, q.count, q.first) for q in problems] == [(KIND_REMOTE, 1, [5])]


def test_format_detection_by_content(tmp_path, comma_log):
    text = gzip.decompress(comma_log.read_bytes())[:20000]
    text = text[: text.rindex(b"\n") + 1]
    for name in ("frames.txt", "frames", "frames.can"):
        p = tmp_path / name
        p.write_bytes(text)
        assert len(read_log(p, Problems())) == text.count(b"\n")
    p = tmp_path / "pandas.txt"
    p.write_text("Time,Bus,MessageID,Message,MessageLength\n1.5,0,705,00,1\n")
    assert list(read_log(p, Problems()).arb_id) == [705]
    p = tmp_path / "x.bin"
    p.write_bytes(b"\x00\x01hello\n")
    with pytest.raises(InputError, match="unknown log format"):
        read_log(p, Problems())


def test_forced_format(tmp_path, comma_log):
    p = tmp_path / "weird.dat"
    p.write_bytes(gzip.decompress(comma_log.read_bytes())[:5000].rsplit(b"\n", 1)[0] + b"\n")
    assert len(read_log(p, Problems(), fmt="candump")) > 50
    with pytest.raises(ValueError):
        read_log(p, Problems(), fmt="nope")
