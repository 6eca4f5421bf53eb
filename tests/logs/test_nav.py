"""GPS/INS and IMU readers: ENU conversion, heading convention, gravity removal, bad rows."""

import gzip
import math
import os
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings, strategies as st

from hmpc.models.errors import InputError, ParamError, Problems
from hmpc.models.logs.nav import (
    ImuColumns,
    NavColumns,
    imu_to_body,
    load_columns,
    read_imu,
    read_imu_raw,
    read_nav,
)
from _data import bundled

NAV = bundled("rav4-comma2k19/nav.csv.gz")
IMU = bundled("rav4-comma2k19/imu.csv.gz")


def raw_csv(path):
    """The file as numpy columns, read independently of hmpc's reader."""
    with gzip.open(path, "rt") as fh:
        return np.genfromtxt(fh, delimiter=",", names=True)


@pytest.fixture(scope="module")
def nav():
    p = Problems()
    out = read_nav(NAV, p)
    assert p.total() == 0
    return out


def test_nav_channels_and_enu_origin(nav):
    assert set(nav) == {"x", "y", "z", "heading", "pitch", "roll", "gps_speed"}
    t, x = nav["x"]
    assert len(t) == 1200 and x[0] == pytest.approx(0, abs=1e-6)
    assert nav["y"][1][0] == pytest.approx(0, abs=1e-6)
    assert nav.origin[0] == pytest.approx(37.721000009)


def test_enu_positions_follow_the_ned_velocities(nav):
    """x is east and y is north: their derivatives equal the file's vel_east / vel_north."""
    ref = raw_csv(NAV)
    t = nav["x"][0]
    vx = np.gradient(nav["x"][1], t)
    vy = np.gradient(nav["y"][1], t)
    assert np.sqrt(np.mean((vx - ref["vel_east"]) ** 2)) < 0.15
    assert np.sqrt(np.mean((vy - ref["vel_north"]) ** 2)) < 0.15
    np.testing.assert_allclose(nav["gps_speed"][1], np.hypot(ref["vel_north"], ref["vel_east"]))
    # track length against a flat-earth haversine of the same fixes (independent formula)
    lat, lon = np.radians(ref["lat_deg"]), np.radians(ref["lon_deg"])
    r_earth = 6371008.8
    a = (
        np.sin(np.diff(lat) / 2) ** 2
        + np.cos(lat[:-1]) * np.cos(lat[1:]) * np.sin(np.diff(lon) / 2) ** 2
    )
    hav = np.sum(2 * r_earth * np.arcsin(np.sqrt(a)))
    enu = np.sum(np.hypot(np.diff(nav["x"][1]), np.diff(nav["y"][1])))
    assert enu == pytest.approx(hav, rel=5e-3)


def test_heading_is_enu_ccw_from_east(nav):
    ref = raw_csv(NAV)
    want = np.pi / 2 - ref["heading_rad"]
    d = np.angle(np.exp(1j * (nav["heading"][1] - want)))
    assert np.abs(d).max() < 1e-9
    assert np.all(np.abs(nav["heading"][1]) <= np.pi)
    # and it points along the ENU velocity (mount offset of about a degree aside)
    course = np.arctan2(ref["vel_north"], ref["vel_east"])
    assert np.degrees(np.abs(np.angle(np.exp(1j * (nav["heading"][1] - course))))).max() < 3


def test_local_xy_enu_attitude_in_degrees(tmp_path):
    p = tmp_path / "local.csv"
    p.write_text("t,e,n,hdg_deg,yr_dps\n0.0,0,0,90,10\n0.1,1,0,180,10\n0.2,2,0.5,-170,-5\n")
    cols = NavColumns(
        time="t",
        lat=None,
        lon=None,
        alt=None,
        x="e",
        y="n",
        vel_north=None,
        vel_east=None,
        roll=None,
        pitch=None,
        heading="hdg_deg",
        yaw_rate="yr_dps",
        attitude_frame="enu",
        angle_unit="deg",
        yaw_rate_unit="deg/s",
    )
    out = read_nav(p, Problems(), cols)
    np.testing.assert_allclose(out["heading"][1], np.radians([90, 180, -170]))
    np.testing.assert_allclose(out["yaw_rate"][1], np.radians([10, 10, -5]))
    np.testing.assert_allclose(out["gps_speed"][1][0], 10.0)  # central differences of x/y
    assert "z" not in out and "roll" not in out


def test_ned_yaw_rate_is_negated(tmp_path):
    p = tmp_path / "ned.csv"
    p.write_text("time,lat,lon,r\n0,37.0,-122.0,0.1\n1,37.0001,-122.0,0.2\n")
    cols = NavColumns(
        lat="lat",
        lon="lon",
        alt=None,
        vel_north=None,
        vel_east=None,
        roll=None,
        pitch=None,
        heading=None,
        yaw_rate="r",
    )
    out = read_nav(p, Problems(), cols)
    np.testing.assert_allclose(out["yaw_rate"][1], [-0.1, -0.2])
    assert out["y"][1][1] == pytest.approx(11.1, abs=0.1)  # 0.0001 deg of latitude north


def test_nan_and_inf_rows_are_skipped_counted_and_located(tmp_path):
    lines = gzip.open(NAV, "rt").read().splitlines()
    f = lines[5].split(",")
    f[1] = "nan"
    lines[5] = ",".join(f)
    lines[9] = lines[9].rsplit(",", 1)[0] + ",-inf"
    lines[12] = lines[12] + ",extra"
    p = tmp_path / "nav_nan.csv"
    p.write_text("\n".join(lines) + "\n")
    probs = Problems()
    out = read_nav(p, probs)
    assert len(out["x"][0]) == 1200 - 3
    items = {i["kind"]: i for i in probs.to_list()}
    nonfinite = [i for k, i in items.items() if "NaN" in k][0]
    malformed = [i for k, i in items.items() if "malformed" in k][0]
    assert nonfinite["count"] == 2 and nonfinite["first"] == [6, 10]
    assert malformed["count"] == 1 and malformed["first"] == [13]


def test_unsorted_and_duplicate_times(tmp_path):
    p = tmp_path / "n.csv"
    p.write_text("time,x,y\n0.0,0,0\n0.2,2,0\n0.1,1,0\n0.2,5,5\n")
    probs = Problems()
    out = read_nav(
        p,
        probs,
        NavColumns(
            lat=None,
            lon=None,
            alt=None,
            x="x",
            y="y",
            vel_north=None,
            vel_east=None,
            roll=None,
            pitch=None,
            heading=None,
        ),
    )
    np.testing.assert_allclose(out["x"][0], [0.0, 0.1, 0.2])
    np.testing.assert_allclose(out["x"][1], [0, 1, 2])
    kinds = " ".join(i["kind"] for i in probs.to_list())
    assert "re-sorted" in kinds and "duplicate" in kinds


@pytest.mark.parametrize(
    "content,needle",
    [
        (b"", "empty file"),
        (b"\n\n", "empty file"),
        (b"time,lat_deg\n", "no column 'lon_deg'"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00IHDR", "not a nav CSV"),
        (b"\x00\x01\x02\n1,2,3\n", "binary"),
        (
            b"time,lat_deg,lon_deg,alt_m,vel_north,vel_east,roll_rad,pitch_rad,heading_rad\n",
            "no nav CSV data rows",
        ),
        (
            b"time,lat_deg,lon_deg,alt_m,vel_north,vel_east,roll_rad,pitch_rad,heading_rad\n"
            b"1,nan,nan,nan,nan,nan,nan,nan,nan\nx,y\n",
            "no usable nav CSV row",
        ),
        (b"\xff\xfe\xfa garbage", "not UTF-8"),
    ],
)
def test_unusable_nav_files_raise_inputerror(tmp_path, content, needle):
    p = tmp_path / "bad.csv"
    p.write_bytes(content)
    with pytest.raises(InputError) as ei:
        read_nav(p, Problems())
    assert needle in str(ei.value) and str(p) in str(ei.value)
    assert "\n" not in str(ei.value)


def test_missing_nav_file():
    with pytest.raises(InputError, match="no such file"):
        read_nav("/nonexistent/nav.csv", Problems())


# ----------------------------------------------------------------------------- IMU
@pytest.fixture(scope="module")
def imu_body(nav):
    att = (nav["roll"][0], nav["roll"][1], nav["pitch"][1])
    return read_imu(IMU, Problems(), attitude=att)


def _on(t_grid, t, v):
    return np.interp(t_grid, t, v)


def test_imu_accel_x_matches_gnss_speed_derivative(nav, imu_body):
    """Gravity removed with the nav attitude: accel_x is dv/dt of the GNSS speed (slope ~1)."""
    tg, v = nav["gps_speed"]
    g = np.arange(tg[0] + 1, tg[-1] - 1, 0.05)
    dv = np.gradient(_on(g, tg, v), g)
    ti, ax = imu_body["accel_x"]
    k = np.ones(9) / 9  # 0.45 s moving average on both
    a = np.convolve(_on(g, ti, ax), k, "same")[10:-10]
    b = np.convolve(dv, k, "same")[10:-10]
    assert np.corrcoef(a, b)[0, 1] > 0.95
    slope = np.polyfit(b, a, 1)[0]
    assert 0.9 < slope < 1.1
    assert abs(np.mean(a - b)) < 0.2  # the 3 deg mount pitch (0.5 m/s^2) is gone


def test_imu_yaw_rate_is_iso_positive_left(nav, imu_body):
    th, h = nav["heading"]
    hr = np.gradient(np.unwrap(h), th)
    ti, r = imu_body["yaw_rate"]
    g = np.arange(th[0] + 1, th[-1] - 1, 0.05)
    k = np.ones(5) / 5  # 0.25 s moving average on both (differentiated 20 Hz heading is noisy)
    a = np.convolve(_on(g, ti, r), k, "same")[5:-5]
    b = np.convolve(_on(g, th, hr), k, "same")[5:-5]
    assert np.corrcoef(a, b)[0, 1] > 0.9
    assert 0.9 < np.polyfit(b, a, 1)[0] < 1.1


def test_imu_without_attitude_removes_constant_tilt():
    out = read_imu(IMU, Problems())
    assert "constant tilt" in out.gravity
    ax = out["accel_x"][1]
    # the mean specific force (scaled to g) is taken as gravity: what is left has a mean of
    # |f| - g along it, a few cm/s^2 for this phone, instead of the 0.57 m/s^2 mount tilt
    assert abs(np.mean(ax)) < 0.05
    assert abs(np.mean(out["accel_y"][1])) < 0.05
    assert abs(np.mean(read_imu_raw(IMU, Problems()).fx)) > 0.5


def test_imu_flu_frame_and_units(tmp_path):
    """The same motion written in FLU/deg/g gives the same ISO outputs as FRD/rad/m/s^2."""
    t = np.arange(5) * 0.01
    rng = np.random.default_rng(7)
    p_, q_, r_ = rng.normal(0, 0.1, (3, 5))
    fx, fy = rng.normal(0, 1, (2, 5))
    fz = -9.80665 + rng.normal(0, 0.1, 5)
    frd = tmp_path / "frd.csv"
    flu = tmp_path / "flu.csv"
    head = "time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n"
    frd.write_text(
        head
        + "".join(
            f"{a},{b},{c},{d},{e},{f},{g}\n"
            for a, b, c, d, e, f, g in zip(t, p_, q_, r_, fx, fy, fz)
        )
    )
    flu.write_text(
        "ts,wx,wy,wz,ax,ay,az\n"
        + "".join(
            f"{a},{math.degrees(b)},{-math.degrees(c)},{-math.degrees(d)},"
            f"{e / 9.80665},{-f / 9.80665},{-g / 9.80665}\n"
            for a, b, c, d, e, f, g in zip(t, p_, q_, r_, fx, fy, fz)
        )
    )
    cols = ImuColumns(
        time="ts",
        gyro_x="wx",
        gyro_y="wy",
        gyro_z="wz",
        accel_x="ax",
        accel_y="ay",
        accel_z="az",
        frame="flu",
        gyro_unit="deg/s",
        accel_unit="g",
    )
    a = read_imu(frd, Problems())
    b = read_imu(flu, Problems(), cols)
    for ch in ("yaw_rate", "accel_x", "accel_y"):
        np.testing.assert_allclose(a[ch][1], b[ch][1], atol=1e-9)
    # level, at rest: yaw rate is -gyro_z (FRD z down), accel_y is -f_y
    raw = read_imu_raw(frd, Problems())
    level = imu_to_body(raw, (t, np.zeros(5), np.zeros(5)))
    np.testing.assert_allclose(level["yaw_rate"][1], -r_)
    np.testing.assert_allclose(level["accel_y"][1], -fy)
    np.testing.assert_allclose(level["accel_x"][1], fx)


def test_column_settings_yaml(tmp_path):
    p = tmp_path / "cols.yaml"
    p.write_text("nav:\n  time: t\n  heading: yaw\n  attitude_frame: enu\nimu:\n  frame: flu\n")
    nc, ic = load_columns(p)
    assert nc.time == "t" and nc.heading == "yaw" and nc.attitude_frame == "enu"
    assert nc.lat == "lat_deg" and ic.frame == "flu" and ic.gyro_x == "gyro_x"
    p.write_text("nav:\n  heading_col: yaw\n")
    with pytest.raises(ParamError, match="nav.heading_col"):
        load_columns(p)
    p.write_text("nav:\n  attitude_frame: nwu\n")
    with pytest.raises(ParamError, match="attitude_frame"):
        load_columns(p)
    p.write_text("gps:\n  time: t\n")
    with pytest.raises(ParamError, match="key 'gps'"):
        load_columns(p)


# ----------------------------------------------------------------------------- property test
_NAV_LINES = gzip.open(NAV, "rt").read().splitlines()[:30]


@seed(20240611)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(
            st.integers(0, 29),
            st.sampled_from(["truncate", "garbage", "drop_field", "nan", "empty", "swap", "bytes"]),
            st.integers(0, 200),
        ),
        max_size=12,
    )
)
def test_corrupted_nav_files_only_raise_inputerror(edits):
    """Random corruption of real nav lines: a result or InputError, nothing else escapes."""
    lines = list(_NAV_LINES)
    junk = ["\x00\x01", "\ufffd", ",,,", "1e999", "--", "0x1F", "\t"]
    for i, how, k in edits:
        s = lines[i]
        if how == "truncate":
            lines[i] = s[: k % (len(s) + 1)]
        elif how == "garbage":
            c = k % (len(s) + 1)
            lines[i] = s[:c] + junk[k % len(junk)] + s[c:]
        elif how == "drop_field":
            f = s.split(",")
            del f[k % len(f)]
            lines[i] = ",".join(f)
        elif how == "nan":
            f = s.split(",")
            f[k % len(f)] = ["nan", "inf", "-inf", ""][k % 4]
            lines[i] = ",".join(f)
        elif how == "empty":
            lines[i] = ""
        elif how == "swap":
            j = k % len(lines)
            lines[i], lines[j] = lines[j], lines[i]
        else:
            lines[i] = bytes([k % 256, (k * 7) % 256]).decode("latin-1")
    with tempfile.TemporaryDirectory() as d:
        p = os.path.join(d, "nav.csv")
        with open(p, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines))
        try:
            out = read_nav(p, Problems())
        except InputError as exc:
            assert "\n" not in str(exc) and p in str(exc)
            return
        t = out["x"][0]
        assert len(t) >= 1 and np.all(np.diff(t) > 0)
        for ch, (_t, v) in out.items():
            assert np.all(np.isfinite(v)), ch


@pytest.mark.parametrize(
    "given,key",
    [
        ({"lon": None, "x": "x", "y": "y"}, "nav.lon"),
        ({"lat": None, "lon": None, "x": "x"}, "nav.y"),
    ],
)
def test_half_a_position_pair_is_refused_naming_the_missing_key(given, key):
    """lat without lon (or x without y) is a mapping mistake, named before any file is read."""
    cols = NavColumns(**given)
    with pytest.raises(ParamError) as exc:
        cols.check("cols.yaml")
    assert exc.value.key == key
