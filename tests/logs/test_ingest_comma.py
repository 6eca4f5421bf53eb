"""Acceptance: `hmpc ingest` of the real comma2k19 RAV4 minute with nav and IMU.

Golden data from an independent source: comma's own decoding of the same frames
(reference_decoded.csv, reference_steering.csv) and the INS's own NED velocities.
"""

import gzip
import hashlib
import json

import numpy as np
import pytest

from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.ingest import ingest_files
from hmpc.models.logs.recording import Recording
from hmpc.tools import cli
from _data import PARAMS_DIR, bundled

MAP17 = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
NAV = bundled("rav4-comma2k19/nav.csv.gz")
IMU = bundled("rav4-comma2k19/imu.csv.gz")
KMH = 1 / 3.6


def csv_columns(path):
    with gzip.open(path, "rt") as fh:
        return np.genfromtxt(fh, delimiter=",", names=True)


@pytest.fixture(scope="module")
def run(comma_log, comma_dbc, tmp_path_factory):
    """The acceptance command, through the real CLI."""
    out = tmp_path_factory.mktemp("comma")
    rec_path, json_path = out / "rec.csv", out / "summary.json"
    rc = cli.main(
        [
            "ingest",
            str(comma_log),
            "--dbc",
            str(comma_dbc),
            "--signals",
            str(MAP17),
            "--nav",
            str(NAV),
            "--imu",
            str(IMU),
            "--out",
            str(rec_path),
            "--json",
            str(json_path),
        ]
    )
    assert rc == 0
    return Recording.load(rec_path), json.loads(json_path.read_text())


@pytest.fixture(scope="module")
def lib(comma_log, comma_dbc):
    """The same through the library (raw samples), heading kept as the device measured it."""
    return ingest_files(
        comma_log,
        comma_dbc,
        MAP17,
        NAV,
        IMU,
        mount_correction=False,
        prefer={"accel_x": "can", "yaw_rate": "can"},
    )


@pytest.fixture(scope="module")
def resolution(comma_dbc):
    """Resolution of each checked channel in SI, from the DBC's own scale factors."""
    db = load_dbc(comma_dbc)
    ws = db.get_message_by_name("WHEEL_SPEEDS").get_signal_by_name("WHEEL_SPEED_FL").scale
    sa = db.get_message_by_name("STEER_ANGLE_SENSOR")
    frac = sa.get_signal_by_name("STEER_FRACTION").scale
    ratio = sa.get_signal_by_name("STEER_ANGLE").scale / frac  # the coarse step is 15 fractions
    assert ratio == pytest.approx(round(ratio))
    return {"wheel_speed_mps": ws * KMH, "steering_rad": np.radians(frac)}


def test_recording_file_is_canonical(run, comma_log, comma_dbc):
    rec, summary = run
    for ch in (
        "steering_wheel_angle",
        "wheel_speed_fl",
        "wheel_speed_fr",
        "wheel_speed_rl",
        "wheel_speed_rr",
        "speed",
        "accel_pedal",
        "brake_pedal",
        "gear",
        "engine_rpm",
        "yaw_rate",
        "accel_x",
        "accel_y",
        "x",
        "y",
        "z",
        "heading",
        "pitch",
        "roll",
        "gps_speed",
        "accel_cmd",
    ):
        assert ch in rec, ch
        assert summary["channels"][ch]["unit"]
    dt = np.diff(rec.time)
    assert np.allclose(dt, 0.02, atol=1e-6)
    assert summary["rate_hz"] == 50.0 and summary["samples"] == len(rec)
    assert 59.5 < summary["duration_s"] < 60.5
    files = {"log": comma_log, "dbc": comma_dbc, "signals": MAP17, "nav": NAV, "imu": IMU}
    for name, path in files.items():  # each input's provenance: the sha256 of its bytes
        assert summary["sources"][name]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert set(rec["gear"]) <= {"D", ""} and (rec["gear"] == "D").mean() > 0.9
    assert summary["gaps"] == {}


@pytest.mark.parametrize("wheel", ["fl", "fr", "rl", "rr"])
def test_wheel_speeds_equal_comma_decoding_to_the_resolution(lib, run, resolution, wheel):
    ref = csv_columns(bundled("rav4-comma2k19/reference_decoded.csv.gz"))
    t, v = lib.recording.raw[f"wheel_speed_{wheel}"]
    # every reference row is one of our decoded frames (same timestamps)
    idx = np.searchsorted(t, ref["time"])
    idx = np.clip(idx, 0, len(t) - 1)
    assert np.abs(t[idx] - ref["time"]).max() < 1e-6
    err = np.abs(v[idx] - ref[f"wheel_speed_{wheel}_mps"])
    assert err.max() <= resolution["wheel_speed_mps"] / 2, err.max()
    # the resampled channel equals the reference interpolated the same way
    rec, _ = run
    m = (rec.time >= ref["time"][0]) & (rec.time <= ref["time"][-1])
    want = np.interp(rec.time[m], ref["time"], ref[f"wheel_speed_{wheel}_mps"])
    err = np.abs(rec[f"wheel_speed_{wheel}"][m] - want)
    assert np.nanmax(err) <= resolution["wheel_speed_mps"] / 2


def test_steering_equals_comma_decoding_to_the_resolution(lib, run, resolution):
    ref = csv_columns(bundled("rav4-comma2k19/reference_steering.csv.gz"))
    t, v = lib.recording.raw["steering_wheel_angle"]
    idx = np.clip(np.searchsorted(t, ref["time"]), 0, len(t) - 1)
    assert np.abs(t[idx] - ref["time"]).max() < 1e-6
    err = np.abs(v[idx] - np.radians(ref["steering_wheel_angle_deg"]))
    assert err.max() <= resolution["steering_rad"] / 2
    assert np.ptp(ref["steering_wheel_angle_deg"]) > 5  # the check sees real steering
    rec, _ = run
    m = (rec.time >= ref["time"][0]) & (rec.time <= ref["time"][-1])
    want = np.radians(np.interp(rec.time[m], ref["time"], ref["steering_wheel_angle_deg"]))
    err = np.abs(rec["steering_wheel_angle"][m] - want)
    assert np.nanmax(err) <= resolution["steering_rad"] / 2


def test_speed_is_the_wheel_speed_mean_the_map_names(lib, run):
    rec, summary = run
    ref = csv_columns(bundled("rav4-comma2k19/reference_decoded.csv.gz"))
    t, v = lib.recording.raw["speed"]
    idx = np.clip(np.searchsorted(t, ref["time"]), 0, len(t) - 1)
    assert np.abs(v[idx] - ref["mean_wheel_speed_mps"]).max() < 0.01 * KMH
    assert "WHEEL_SPEEDS" in summary["speed_source"]
    assert summary["channels"]["speed"]["source"].startswith("can: WHEEL_SPEEDS")
    # the wheel-speed mean reads slightly below GNSS (tyre radius), as documented in the map
    assert 0.98 < summary["speed_vs_gps"]["ratio_mean"] < 1.0


def test_heading_agrees_with_course_over_ground(run, lib):
    """Within 3 deg above 5 m/s once the constant mount offset is removed (offset reported)."""
    rec, summary = run
    mount = summary["heading_mount"]
    assert mount["applied"] is True
    assert 0.1 < abs(mount["offset_deg"]) < 3.0  # a real, small mounting offset
    nav = csv_columns(NAV)
    off = summary["clock"]["nav"]["offset_s"]
    t_nav = nav["time"] + off
    # ENU, from the NED velocities
    course = np.unwrap(np.arctan2(nav["vel_north"], nav["vel_east"]))
    speed = np.hypot(nav["vel_north"], nav["vel_east"])
    g = rec.time
    m = (g >= t_nav[0]) & (g <= t_nav[-1]) & np.isfinite(rec["heading"])
    m[m] &= np.interp(g[m], t_nav, speed) > 5.0
    assert m.sum() > 2500
    d = np.angle(np.exp(1j * (rec["heading"][m] - np.interp(g[m], t_nav, course))))
    assert np.degrees(np.abs(d)).max() < 3.0
    # without the correction the device heading differs by exactly the reported offset
    raw = lib.recording["heading"][m]
    d_raw = np.angle(np.exp(1j * (raw - rec["heading"][m] - mount["offset_rad"])))
    assert np.abs(d_raw).max() < 1e-9
    assert lib.summary["heading_mount"]["applied"] is False


def test_clock_offsets_reported(run):
    _, summary = run
    nav = summary["clock"]["nav"]
    assert nav["ok"] and nav["correlation_peak"] > 0.99 and abs(nav["offset_s"]) < 0.1
    assert "GNSS speed" in nav["method"]
    imu = summary["clock"]["imu"]
    assert imu["method"] == "same device as nav" and imu["offset_s"] == nav["offset_s"]
    chk = summary["clock"]["checks"]["imu_residual_vs_nav_by_yaw_rate"]
    assert chk["ok"] and abs(chk["offset_s"]) < 0.02  # IMU and INS do share a clock


def test_imu_channels_are_body_frame_and_agree_with_the_car(run, lib):
    rec, summary = run
    assert summary["channels"]["accel_x"]["source"].startswith("imu")
    assert "removed" in summary["imu_gravity"]
    ok = np.isfinite(rec["accel_x"]) & np.isfinite(rec["speed"])
    k = np.ones(15) / 15
    dv = np.convolve(np.gradient(np.where(ok, rec["speed"], 0), rec.time), k, "same")
    ax = np.convolve(np.where(ok, rec["accel_x"], 0), k, "same")
    sl = slice(20, -20)
    assert np.corrcoef(ax[sl], dv[sl])[0, 1] > 0.9
    # yaw rate: + = left, like the steering wheel
    m = np.isfinite(rec["yaw_rate"]) & np.isfinite(rec["steering_wheel_angle"])
    assert np.corrcoef(rec["yaw_rate"][m], rec["steering_wheel_angle"][m])[0, 1] > 0.5


def test_can_kinematics_signs_in_the_2017_map(lib):
    """The map's sign flip makes CAN accel_x positive forward, and CAN yaw rate is + left."""
    rec = lib.recording
    assert lib.summary["channels"]["accel_x"]["source"].startswith("can: KINEMATICS")
    k = np.ones(15) / 15
    ok = np.isfinite(rec["accel_x"]) & np.isfinite(rec["speed"])
    dv = np.convolve(np.gradient(np.where(ok, rec["speed"], 0), rec.time), k, "same")[20:-20]
    ax = np.convolve(np.where(ok, rec["accel_x"], 0), k, "same")[20:-20]
    assert np.corrcoef(ax, dv)[0, 1] > 0.75
    th = np.unwrap(np.nan_to_num(rec["heading"]))
    hr = np.convolve(np.gradient(th, rec.time), k, "same")[20:-20]
    yr = np.convolve(np.nan_to_num(rec["yaw_rate"]), k, "same")[20:-20]
    assert np.corrcoef(yr, hr)[0, 1] > 0.8


def test_unknown_ids_reported_not_fatal(run):
    _, summary = run
    items = summary["information"]
    unknown = [i for i in items if "not in the DBC" in i["kind"]]
    # frames of ids the DBC does not define are information, not problems
    assert not [i for i in summary["problems"]["items"] if "not in the DBC" in i["kind"]]
    assert unknown and unknown[0]["count"] > 0 and unknown[0]["first"]
