"""``hmpc info``: figures checked against an independent count of the real comma minute
(python-can's reader + plain Python), a gap cut into one id, and the CLI/JSON contract."""

import collections
import gzip
import json

import can
import numpy as np
import pytest

from hmpc.models.logs.dbc import load_dbc
from hmpc.models.errors import Problems
from hmpc.models.logs.info import format_info, log_info
from hmpc.tools.cli import main

KEYS = [
    "file",
    "format",
    "frames",
    "start_s",
    "end_s",
    "duration_s",
    "rate_hz",
    "buses",
    "ids",
    "clock",
    "malformed_lines",
    "malformed_where",
    "remote_frames",
    "remote_where",
    "error_frames",
    "error_where",
    "dbc",
    "problems",
    "information",
]


@pytest.fixture(scope="module")
def pycan_msgs(comma_log):
    return list(can.LogReader(str(comma_log)))


def test_counts_rates_and_gaps_against_python_can(comma_log, comma_dbc, pycan_msgs):
    info = log_info(comma_log, Problems(), dbc_path=comma_dbc)
    assert list(info) == KEYS
    t = np.array([m.timestamp for m in pycan_msgs])
    assert info["frames"] == len(pycan_msgs) == 135468
    assert info["duration_s"] == t[-1] - t[0]
    assert info["rate_hz"] == pytest.approx(len(t) / (t[-1] - t[0]), rel=1e-12)
    per_bus = collections.Counter(int(m.channel[-1]) for m in pycan_msgs)
    assert {b["bus"]: b["frames"] for b in info["buses"]} == dict(per_bus)
    per_id = collections.defaultdict(list)
    for m in pycan_msgs:
        per_id[(int(m.channel[-1]), m.arbitration_id)].append(m.timestamp)
    assert len(info["ids"]) == len(per_id)
    names = {m.frame_id: m.name for m in load_dbc(comma_dbc).messages}
    for e in info["ids"]:
        ts = np.array(per_id[(e["bus"], e["id"])])
        assert e["frames"] == len(ts)
        dt = np.diff(ts)
        assert e["median_period_s"] == pytest.approx(float(np.median(dt)), abs=1e-12)
        assert e["max_gap_s"] == pytest.approx(float(dt.max()), abs=1e-12)
        assert e["message"] == names.get(e["id"])
    by_name = {e["message"]: e for e in info["ids"] if e["message"]}
    # the data README: steering angle and wheel speeds ~83 Hz, gas pedal ~33 Hz (here 31.5)
    assert by_name["STEER_ANGLE_SENSOR"]["rate_hz"] == pytest.approx(83, abs=1)
    assert by_name["WHEEL_SPEEDS"]["rate_hz"] == pytest.approx(83, abs=1)
    assert by_name["GAS_PEDAL"]["rate_hz"] == pytest.approx(32, abs=1.5)
    assert info["clock"]["backwards"] == 0 and info["clock"]["jumps"] == 0
    assert info["dbc"]["frames_known_id"] + info["dbc"]["frames_unknown_id"] == len(t)
    text = format_info(info)
    assert "STEER_ANGLE_SENSOR" in text and "135468 frames" in text


def test_a_gap_cut_into_one_id_is_found(comma_log, tmp_path):
    with gzip.open(comma_log, "rb") as fh:
        lines = fh.read().split(b"\n")[:-1]
    ts = [float(ln[1 : ln.index(b")")]) for ln in lines]
    t0 = ts[0]
    # drop GAS_PEDAL (0x2C1) frames between 20 s and 22.5 s: a 2.5 s hole in a ~32 ms stream
    keep = [ln for ln, t in zip(lines, ts) if not (b" 2C1#" in ln and 20.0 <= t - t0 < 22.5)]
    p = tmp_path / "gap.log"
    p.write_bytes(b"\n".join(keep) + b"\n")
    info = log_info(p, Problems())
    gas = next(e for e in info["ids"] if e["id"] == 0x2C1 and e["bus"] == 0)
    assert gas["max_gap_s"] == pytest.approx(2.5, abs=0.07)
    assert gas["max_gap_periods"] > 50
    assert gas["gaps"] == 1
    assert 20.0 - 0.07 <= gas["max_gap_start_s"] - t0 < 20.0
    other = next(e for e in info["ids"] if e["id"] == 0x2E4 and e["bus"] == 0)
    assert other["max_gap_periods"] < 5


def test_cli_json_equals_library(comma_log, comma_dbc, tmp_path, capsys):
    out_json = tmp_path / "info.json"
    rc = main(["info", str(comma_log), "--dbc", str(comma_dbc), "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert rc == 0
    payload = json.loads(out_json.read_text())
    lib = json.loads(json.dumps(log_info(comma_log, Problems(), dbc_path=comma_dbc)))
    assert payload == lib
    assert "STEER_ANGLE_SENSOR" in out and "bus 0: 66234 frames" in out


def test_info_on_libpanda_and_a_python_can_format(vcan_log, vcan_dbc, comma_log, tmp_path, capsys):
    rc = main(["info", str(vcan_log), "--dbc", str(vcan_dbc)])
    out, err = capsys.readouterr()
    assert rc == 0 and "libpanda" in out and "68178 frames" in out
    msgs = list(can.LogReader(str(comma_log)))[:1000]
    p = tmp_path / "x.blf"
    w = can.BLFWriter(str(p))
    for m in msgs:
        w.on_message_received(m)
    w.stop()
    rc = main(["info", str(p)])
    out, err = capsys.readouterr()
    assert rc == 0 and "blf, 1000 frames" in out
