"""Acceptance: `hmpc ingest` of the real VerifiedCAN 2019 RAV4 stop-and-go drive (CAN only)."""

import json

import numpy as np
import pytest

from hmpc.models.logs.recording import Recording
from hmpc.tools import cli
from _data import PARAMS_DIR

MAP19 = PARAMS_DIR / "toyota_rav4_2019.signals.yaml"


@pytest.fixture(scope="module")
def run(vcan_log, vcan_dbc, tmp_path_factory):
    out = tmp_path_factory.mktemp("vcan")
    rec_path, json_path = out / "rec.csv", out / "summary.json"
    argv = [
        "ingest",
        str(vcan_log),
        "--dbc",
        str(vcan_dbc),
        "--signals",
        str(MAP19),
        "--out",
        str(rec_path),
        "--json",
        str(json_path),
    ]
    return cli.main(argv), rec_path, json_path


def test_ingest_succeeds_and_reports_undecodable_frames(run, capsys):
    rc, rec_path, json_path = run
    assert rc == 0
    summary = json.loads(json_path.read_text())
    items = summary["problems"]["items"]
    undecoded = [i for i in summary["information"] if "not in the DBC" in i["kind"]]
    assert undecoded, summary["information"]
    assert undecoded[0]["count"] > 1000 and len(undecoded[0]["first"]) == 5
    # frames the DBC does not define are information: counted apart, not in the problem total
    assert not [i for i in items if "not in the DBC" in i["kind"]]
    assert summary["problems"]["total"] == sum(i["count"] for i in items)
    assert summary["clock"]["nav"] is None and summary["heading_mount"] is None


def test_speeds_span_the_three_zones(run):
    _, rec_path, json_path = run
    rec = Recording.load(rec_path)
    v = rec["speed"]
    assert np.nanmin(v) < 0.05  # standing still in the queue
    assert 12.5 < np.nanmax(v) < 13.5  # "0-13 m/s"
    for lo, hi in ((0, 2), (2, 5), (5, 20)):  # idle, low and high zones all have data
        assert np.sum((v > lo) & (v <= hi)) > 100
    for w in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"):
        assert np.nanmax(np.abs(rec[w] - v)) < 1.0
    assert 110 < json.loads(json_path.read_text())["duration_s"] < 120


def test_can_acceleration_sign_and_pedals(run):
    _, rec_path, _ = run
    rec = Recording.load(rec_path)
    ok = np.isfinite(rec["speed"]) & np.isfinite(rec["accel_x"])
    # compare on contiguous valid stretches only (the logger drops frames: NaN gaps)
    dv = np.gradient(np.where(ok, rec["speed"], np.nan), rec.time)
    good = ok & np.isfinite(dv)
    k = np.ones(11) / 11
    a = np.convolve(np.where(good, rec["accel_x"], 0), k, "same")
    b = np.convolve(np.where(good, dv, 0), k, "same")
    assert np.corrcoef(a[good], b[good])[0, 1] > 0.8  # + = forward in the 2019 map
    ped = rec["accel_pedal"][np.isfinite(rec["accel_pedal"])]
    assert 0 <= ped.min() and ped.max() <= 1 and ped.max() > 0.1
    assert set(rec["gear"]) <= {"D", ""}


def test_logger_dropouts_are_gaps_not_interpolated(run):
    _, rec_path, json_path = run
    rec = Recording.load(rec_path)
    summary = json.loads(json_path.read_text())
    gaps = summary["gaps"]["wheel_speed_fl"]
    assert len(gaps) >= 3
    for gap in gaps:
        inside = (rec.time > gap["start_s"]) & (rec.time < gap["end_s"])
        assert inside.any() and np.isnan(rec["wheel_speed_fl"][inside]).all()
        assert gap["duration_s"] > summary["channels"]["wheel_speed_fl"]["gap_threshold_s"]
    # a larger threshold bridges them
    out = rec_path.parent / "rec_gap2.csv"
    argv = [
        "ingest",
        summary["sources"]["log"]["path"],
        "--dbc",
        summary["sources"]["dbc"]["path"],
        "--signals",
        str(MAP19),
        "--gap",
        "2.0",
        "--out",
        str(out),
    ]
    assert cli.main(argv) == 0
    assert np.isfinite(Recording.load(out)["wheel_speed_fl"]).all()
