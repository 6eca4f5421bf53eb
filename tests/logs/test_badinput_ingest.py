"""Bad input to ingest: each case through the library and through `hmpc ingest` (tools.cli.main).

Fatal -> InputError/ParamError, exit 2 with one stderr line naming the file and line/channel/key.
Recoverable -> exit 0, skipped rows counted and reported with their first line numbers.
"""

import gzip
import json
import textwrap

import pytest

from hmpc.models.errors import InputError, ParamError, Problems
from hmpc.models.logs.ingest import ingest_files
from hmpc.tools import cli
from _data import PARAMS_DIR, bundled

MAP17 = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
NAV = bundled("rav4-comma2k19/nav.csv.gz")
IMU = bundled("rav4-comma2k19/imu.csv.gz")

SMALL_MAP = """\
vehicle: test
channels:
  steering_wheel_angle: {message: STEER_ANGLE_SENSOR, expr: STEER_ANGLE + STEER_FRACTION,
                         unit: deg, bus: 0, required: true}
  wheel_speed_fl: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: km/h, bus: 0, required: true}
  speed: {message: WHEEL_SPEEDS,
          expr: (WHEEL_SPEED_FL + WHEEL_SPEED_FR + WHEEL_SPEED_RL + WHEEL_SPEED_RR) / 4,
          unit: km/h, bus: 0, required: true}
  gear: {message: GEAR_PACKET, expr: GEAR, gear: {0: D, 32: P}, bus: 0}
"""


def cli_run(argv, capsys):
    rc = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    return rc, err


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture(scope="module")
def short_log(tmp_path_factory):
    """The first 6000 lines of the real comma log (about 2.6 s of traffic)."""
    lines = gzip.open(bundled("rav4-comma2k19/can.log.gz"), "rt").read().splitlines()[:6000]
    d = tmp_path_factory.mktemp("logs")
    full = d / "short.log"
    full.write_text("\n".join(lines) + "\n")
    no_wheels = d / "no_wheel_speeds.log"  # WHEEL_SPEEDS (0x0AA) removed
    no_wheels.write_text("\n".join(ln for ln in lines if " 0AA#" not in ln) + "\n")
    no_gear = d / "no_gear.log"  # GEAR_PACKET (0x3BC) removed: an optional channel
    no_gear.write_text("\n".join(ln for ln in lines if " 3BC#" not in ln) + "\n")
    return {"full": full, "no_wheels": no_wheels, "no_gear": no_gear}


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


# ----------------------------------------------------------------------------- signal maps
BAD_MAPS = {
    "message not in the DBC": (
        "channels:\n  speed: {message: WHEEL_SPEED_X, expr: WHEEL_SPEED_FL, unit: km/h}\n",
        ":2: key 'channels.speed.message'",
        "WHEEL_SPEED_X",
    ),
    "signal not in the DBC": (
        "channels:\n  speed:\n    message: WHEEL_SPEEDS\n    expr: WHEEL_SPEED_FX / 2\n"
        "    unit: km/h\n",
        ":4: key 'channels.speed.expr'",
        "WHEEL_SPEED_FX",
    ),
    "unknown key in an entry": (
        "channels:\n  speed:\n    message: WHEEL_SPEEDS\n    expr: WHEEL_SPEED_FL\n"
        "    units: km/h\n",
        ":5: key 'channels.speed.units'",
        "unknown key",
    ),
    "unknown top-level key": (
        "vehicle: x\nsignals:\n  speed: {}\n",
        ":2: key 'signals'",
        "unknown key",
    ),
    "unknown channel": (
        "channels:\n  velocity: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: km/h}\n",
        ":2: key 'channels.velocity'",
        "unknown channel",
    ),
}


@pytest.mark.parametrize("case", list(BAD_MAPS), ids=list(BAD_MAPS))
def test_bad_signal_map(case, tmp_path, short_log, comma_dbc, capsys):
    body, where, word = BAD_MAPS[case]
    m = write(tmp_path, "bad.signals.yaml", body)
    with pytest.raises(ParamError) as ei:
        ingest_files(short_log["full"], comma_dbc, m)
    assert str(ei.value).startswith(f"{m}{where}") and word in str(ei.value)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2
    line = error_line(err)
    assert f"{m}{where}" in line and word in line and "Traceback" not in err
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("log_case", ["missing", "garbage"])
def test_bad_map_is_reported_before_a_bad_log(log_case, tmp_path, comma_dbc, capsys):
    """The DBC and the map are parsed while the log is read: when both are bad, the map's
    error is the one reported, as when they were read one after the other."""
    m = write(tmp_path, "bad.signals.yaml", BAD_MAPS["unknown channel"][0])
    log = tmp_path / "bus.log"
    if log_case == "garbage":
        log.write_bytes(b"this is not a CAN log\n" * 50)
    with pytest.raises(ParamError) as ei:
        ingest_files(log, comma_dbc, m)
    assert str(ei.value).startswith(f"{m}:2: key 'channels.velocity'")
    rc, err = cli_run(
        ["ingest", log, "--dbc", comma_dbc, "--signals", m, "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and f"{m}:2" in error_line(err) and "Traceback" not in err
    # with a good map the log's own error is the one reported
    with pytest.raises(InputError) as ei:
        ingest_files(log, comma_dbc, MAP17)
    assert str(ei.value).startswith(str(log))


def test_message_on_two_buses_needs_bus(tmp_path, short_log, comma_dbc, capsys):
    m = write(
        tmp_path,
        "m.yaml",
        """\
        channels:
          speed: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: km/h, required: true}
          brake_pedal: {message: BRAKE_MODULE, expr: BRAKE_PRESSED, unit: fraction}
    """,
    )
    with pytest.raises(InputError, match="channel 'brake_pedal'.*buses 0, 1"):
        ingest_files(short_log["full"], comma_dbc, m)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "channel 'brake_pedal'" in error_line(err)


# ----------------------------------------------------------------------------- channels in the log
def test_required_channel_absent_from_log(tmp_path, short_log, comma_dbc, capsys):
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    log = short_log["no_wheels"]
    with pytest.raises(InputError) as ei:
        ingest_files(log, comma_dbc, m)
    msg = str(ei.value)
    assert msg.startswith(str(log)) and "channel 'wheel_speed_fl'" in msg and "WHEEL_SPEEDS" in msg
    rc, err = cli_run(
        ["ingest", log, "--dbc", comma_dbc, "--signals", m, "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2
    line = error_line(err)
    assert str(log) in line and "channel 'wheel_speed_fl'" in line


def test_optional_channel_absent_is_listed_not_zero_filled(tmp_path, short_log, comma_dbc, capsys):
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    res = ingest_files(short_log["no_gear"], comma_dbc, m)
    assert res.summary["channels_absent"] == ["gear"]
    assert "gear" not in res.recording
    rc, _ = cli_run(
        [
            "ingest",
            short_log["no_gear"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 0
    assert "gear" not in (tmp_path / "r.csv").read_text().splitlines()[0].split(",")


def test_expression_nan_is_recoverable(tmp_path, short_log, comma_dbc, capsys):
    # GAS_PEDAL reads 29 % in some frames of this stretch: 0/0 there, 1 elsewhere
    m = write(
        tmp_path,
        "m.yaml",
        SMALL_MAP + "  accel_pedal: {message: GAS_PEDAL, "
        "expr: (GAS_PEDAL - 29) / (GAS_PEDAL - 29), "
        "unit: fraction, bus: 0}\n",
    )
    p = Problems()
    res = ingest_files(short_log["full"], comma_dbc, m, problems=p)
    item = [i for i in p.to_list() if "expression" in i["kind"]][0]
    assert item["count"] > 0 and item["first"] and "accel_pedal" in item["detail"]
    t, v = res.recording.raw["accel_pedal"]
    assert (v == 1.0).all()
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 0 and "expression gave NaN" in err


# ----------------------------------------------------------------------------- nav and IMU files
def test_nan_inf_in_nav_is_recoverable(tmp_path, comma_log, comma_dbc, capsys):
    lines = gzip.open(NAV, "rt").read().splitlines()
    for i, bad in ((3, "nan"), (100, "inf"), (101, "-inf"), (500, "NaN")):
        f = lines[i].split(",")
        f[5] = bad
        lines[i] = ",".join(f)
    nav = tmp_path / "nav.csv"
    nav.write_text("\n".join(lines) + "\n")
    res = ingest_files(comma_log, comma_dbc, MAP17, nav)
    items = [i for i in res.problems.to_list() if "NaN or inf" in i["kind"]]
    assert items[0]["count"] == 4 and items[0]["first"] == [4, 101, 102, 501]
    assert res.summary["channels"]["gps_speed"]["raw_samples"] == 1200 - 4
    js = tmp_path / "s.json"
    rc, err = cli_run(
        [
            "ingest",
            comma_log,
            "--dbc",
            comma_dbc,
            "--signals",
            MAP17,
            "--nav",
            nav,
            "--out",
            tmp_path / "r.csv",
            "--json",
            js,
        ],
        capsys,
    )
    assert rc == 0
    assert "4 x row with NaN or inf (skipped)" in err and "4, 101, 102, 501" in err
    summary = json.loads(js.read_text())
    assert any(i["count"] == 4 and i["file"] == str(nav) for i in summary["problems"]["items"])


NAV_BAD = {
    "empty": (b"", "empty file"),
    "header only": (
        b"time,lat_deg,lon_deg,alt_m,vel_north,vel_east,vel_down,roll_rad,pitch_rad,heading_rad\n",
        "no nav CSV data rows",
    ),
    "garbage": (bytes(range(256)) * 8, "binary"),
    "missing column": (b"time,lat_deg,lon_deg\n1,37,-122\n", "no column 'alt_m'"),
    "all rows bad": (
        b"time,lat_deg,lon_deg,alt_m,vel_north,vel_east,roll_rad,pitch_rad,"
        b"heading_rad\n"
        b"1,nan,1,1,1,1,1,1,1\n2,x,1,1,1,1,1,1,1\n",
        "no usable nav CSV row",
    ),
}


@pytest.mark.parametrize("case", list(NAV_BAD), ids=list(NAV_BAD))
def test_unusable_nav_file(case, tmp_path, short_log, comma_dbc, capsys):
    content, needle = NAV_BAD[case]
    nav = tmp_path / "nav.csv"
    nav.write_bytes(content)
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    with pytest.raises(InputError, match=needle):
        ingest_files(short_log["full"], comma_dbc, m, nav)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--nav",
            nav,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2
    line = error_line(err)
    assert str(nav) in line and needle in line and "Traceback" not in err


def test_unusable_imu_file(tmp_path, short_log, comma_dbc, capsys):
    imu = tmp_path / "imu.csv"
    imu.write_bytes(b"\x00\x01garbage" * 100)
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--imu",
            imu,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and str(imu) in error_line(err)


def test_bad_column_settings(tmp_path, short_log, comma_dbc, capsys):
    cols = write(tmp_path, "cols.yaml", "nav:\n  latitude: lat\n")
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--nav",
            NAV,
            "--columns",
            cols,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "key 'nav.latitude'" in error_line(err)


# ----------------------------------------------------------------------------- command line
def test_bad_options_and_outputs(tmp_path, short_log, comma_dbc, capsys):
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    base = ["ingest", str(short_log["full"]), "--dbc", str(comma_dbc), "--signals", str(m)]
    with pytest.raises(SystemExit) as ei:  # argparse: exit 2 with usage
        cli.main(base + ["--rate", "-5", "--out", str(tmp_path / "r.csv")])
    assert ei.value.code == 2
    with pytest.raises(SystemExit) as ei:
        cli.main(base + ["--prefer", "yaw_rate=gps", "--out", str(tmp_path / "r.csv")])
    assert ei.value.code == 2
    capsys.readouterr()
    rc, err = cli_run(base + ["--out", tmp_path / "no" / "such" / "dir" / "r.csv"], capsys)
    assert rc == 2 and "cannot write the recording" in error_line(err)
    rc, err = cli_run(
        [
            "ingest",
            tmp_path / "missing.log",
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "missing.log" in error_line(err)
    empty = tmp_path / "empty.log"
    empty.write_text("")
    rc, err = cli_run(
        ["ingest", empty, "--dbc", comma_dbc, "--signals", m, "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and "empty.log" in error_line(err)
    with pytest.raises(ValueError):
        ingest_files(short_log["full"], comma_dbc, m, rate_hz=0)


def test_nav_from_another_day_is_fatal(tmp_path, short_log, comma_dbc, capsys):
    lines = gzip.open(NAV, "rt").read().splitlines()
    shifted = [lines[0]] + [
        f"{float(ln.split(',', 1)[0]) + 86400:.6f},{ln.split(',', 1)[1]}" for ln in lines[1:]
    ]
    nav = tmp_path / "nav_next_day.csv"
    nav.write_text("\n".join(shifted) + "\n")
    m = write(tmp_path, "m.yaml", SMALL_MAP)
    with pytest.raises(InputError, match="does not overlap the CAN log"):
        ingest_files(short_log["full"], comma_dbc, m, nav)
    rc, err = cli_run(
        [
            "ingest",
            short_log["full"],
            "--dbc",
            comma_dbc,
            "--signals",
            m,
            "--nav",
            nav,
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and str(nav) in error_line(err)
    # the right offset makes it usable again (and is reported as given)
    res = ingest_files(short_log["full"], comma_dbc, m, nav, clock_offset_s=-86400.0)
    assert res.summary["clock"]["nav"]["method"] == "given"
    assert res.summary["channels"]["gps_speed"]["valid_fraction"] > 0.9
