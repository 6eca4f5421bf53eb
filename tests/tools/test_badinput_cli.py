"""Bad input at the ``hmpc`` command line, found by an adversarial audit of every subcommand.

Each case (a traceback and exit 1, a silent wrong number, or an output written before the run
was refused, were it not handled) must end with exit 2 and exactly one stderr line naming
the file and the line, channel, key or option (docs/conventions.md), with nothing written.
The cases run ``tools.cli.main`` in-process as tests/tools/test_cli.py does; one runs the installed
console script. Data: the first lines of the real comma2k19 minute and the shipped parameters.
"""

from __future__ import annotations

import gzip
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _data import PARAMS_DIR, REPORT_PARAMS, REPO_DIR, bundled
from hmpc.models.errors import InputError
from hmpc.models.logs.ingest import ingest_files
from hmpc.models.logs.recording import read_channels, write_csv
from hmpc.tools import cli

DBC = bundled("dbc/toyota_rav4_2017.dbc.gz")
MAP17 = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
GEOMETRY = PARAMS_DIR / "toyota_rav4_2017.yaml"
ACTUATION = PARAMS_DIR / "toyota_rav4_2017.actuation.yaml"


def cli_run(argv, capsys) -> tuple[int, str]:
    """Exit status and the one error line of ``hmpc ARGV`` (asserts there is exactly one
    and no traceback)."""
    rc = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1, err
    return rc, lines[0]


@pytest.fixture(scope="module")
def lines():
    """The first 4000 lines of the real comma log (about 1.7 s of traffic)."""
    return gzip.open(bundled("rav4-comma2k19/can.log.gz"), "rt").read().splitlines()[:4000]


@pytest.fixture(scope="module")
def short_log(tmp_path_factory, lines):
    path = tmp_path_factory.mktemp("log") / "short.log"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def rec_rows(tmp_path_factory, short_log):
    """A canonical recording of the short log, as (header, rows of text cells)."""
    res = ingest_files(short_log, DBC, MAP17)
    path = tmp_path_factory.mktemp("rec") / "rec.csv"
    res.recording.save(path)
    text = path.read_text().splitlines()
    return text[0].split(","), [r.split(",") for r in text[1:]]


def write_rec(path: Path, header, rows) -> Path:
    path.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")
    return path


# ----------------------------------------------------------------------------- output paths
@pytest.mark.parametrize("option", ["--json", "--out"])
def test_output_into_a_missing_folder_is_refused_before_any_work(option, tmp_path, capsys):
    """Was: `hmpc info --json nodir/x.json` a traceback; `hmpc simulate --out nodir/x.csv` a
    traceback after the whole simulation; `hmpc identify --json nodir/...` exit 2 only after
    --out had been written."""
    bad = tmp_path / "nodir" / "x.file"
    out = tmp_path / "params.yaml"
    argv = ["identify", bundled("rav4-comma2k19/nav.csv.gz"), "--vehicle", GEOMETRY]
    argv += ["--out", bad] if option == "--out" else ["--out", out, "--json", bad]
    rc, line = cli_run(argv, capsys)
    assert rc == 2
    assert str(bad) in line and option in line and "does not exist" in line
    assert not out.exists() and not bad.parent.exists()  # nothing written, no folder made


def test_info_json_into_a_missing_folder(tmp_path, short_log, capsys):
    bad = tmp_path / "nodir" / "x.json"
    rc, line = cli_run(["info", short_log, "--json", bad], capsys)
    assert rc == 2 and str(bad) in line


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc")
def test_unwritable_output_files(tmp_path, capsys):
    """/proc refuses new files even to root, where os.access says yes."""
    rc, line = cli_run(
        [
            "simulate",
            "--params",
            REPORT_PARAMS,
            "--experiment",
            "ramps",
            "--out",
            "/proc/hmpc_x.csv",
        ],
        capsys,
    )
    assert rc == 2 and "/proc/hmpc_x.csv" in line and "--out" in line
    rc, line = cli_run(
        [
            "drive",
            "--params",
            REPORT_PARAMS,
            "--actuation",
            ACTUATION,
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--duration",
            "1",
            "--candump",
            "/proc/hmpc_x.log",
        ],
        capsys,
    )
    assert rc == 2 and "/proc/hmpc_x.log" in line and "--candump" in line


def test_output_file_that_is_a_folder_and_plots_onto_a_file(tmp_path, capsys):
    rc, line = cli_run(
        ["simulate", "--params", REPORT_PARAMS, "--experiment", "ramps", "--out", tmp_path], capsys
    )
    assert rc == 2 and str(tmp_path) in line and "folder" in line
    afile = tmp_path / "afile"
    afile.write_text("keep me\n")
    rc, line = cli_run(
        [
            "simulate",
            "--params",
            REPORT_PARAMS,
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--plots",
            afile,
        ],
        capsys,
    )
    assert rc == 2 and str(afile) in line and "--plots" in line
    assert afile.read_text() == "keep me\n"


def test_existing_output_is_kept_when_the_write_fails(tmp_path):
    """A recording is written beside its name and renamed over it: a failed write leaves
    the earlier file whole."""
    path = tmp_path / "rec.csv"
    write_csv({"time": np.array([0.0, 0.02]), "speed": np.array([1.0, 2.0])}, path)
    before = path.read_text()

    class Boom:  # a channel whose values fail half-way through the conversion
        def astype(self, _):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_csv({"time": np.array([0.0, 0.02]), "speed": Boom()}, path)
    assert path.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]


# ----------------------------------------------------------------------------- numeric options
@pytest.mark.parametrize(
    "argv, option",
    [
        (["simulate", "--experiment", "ramps", "--rate", "-5"], "--rate"),
        (["simulate", "--experiment", "ramps", "--rate", "0"], "--rate"),
        (["simulate", "--experiment", "ramps", "--rate", "nan"], "--rate"),
        (["simulate", "--scenario", "idle_hold", "--control-period", "-1"], "--control-period"),
        (["simulate", "--scenario", "idle_hold", "--horizon", "nan"], "--horizon"),
    ],
)
def test_simulate_numeric_options(argv, option, tmp_path, capsys):
    """Was: a traceback (exit 1) from numpy or the closed loop."""
    out = tmp_path / "s.csv"
    rc, line = cli_run(argv + ["--params", REPORT_PARAMS, "--out", out], capsys)
    assert rc == 2 and option in line
    assert not out.exists()


@pytest.mark.parametrize("value", ["-1", "nan", "0"])
def test_info_jump_threshold(value, short_log, capsys):
    """Was: exit 0 with every frame reported as a clock jump (-1) or none ever (nan)."""
    rc, line = cli_run(["info", short_log, "--jump-s", value], capsys)
    assert rc == 2 and "--jump-s" in line


@pytest.mark.parametrize("rate, why", [("1e9", "rows"), ("0.001", "fewer than 2 rows")])
def test_ingest_grid_rate(rate, why, tmp_path, short_log, capsys):
    """Was: 1e9 Hz a MemoryError traceback; 0.001 Hz a one-row 'recording' and exit 0."""
    out = tmp_path / "rec.csv"
    rc, line = cli_run(
        ["ingest", short_log, "--dbc", DBC, "--signals", MAP17, "--rate", rate, "--out", out],
        capsys,
    )
    assert rc == 2 and str(short_log) in line and "--rate" in line and why in line
    assert not out.exists()


def test_effect_error_without_a_file_has_no_empty_place(capsys):
    """Was: 'hmpc simulate: error: : key ...' (an empty file name before the key)."""
    rc, line = cli_run(
        [
            "simulate",
            "--params",
            REPORT_PARAMS,
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--effect",
            "road_grade:grade_rad=abc",
        ],
        capsys,
    )
    assert rc == 2 and ": error: : " not in line and "key 'grade_rad'" in line
    assert str(InputError("why", key="k")) == "key 'k': why"
    assert str(InputError("why", line=3)) == "line 3: why"
    assert str(InputError("why", "f.csv", line=3, channel="c")) == "f.csv:3: channel 'c': why"


# ----------------------------------------------------------------------------- CAN log
def test_every_frame_of_a_required_message_too_short(tmp_path, lines, capsys):
    """Was: 'message STEER_ANGLE_SENSOR on bus 0 is not in the log' although it is, 5 bytes
    short of the DBC's 8 in every frame."""
    cut = [ln.split("#")[0] + "#" + ln.split("#")[1][:6] if " 025#" in ln else ln for ln in lines]
    first = next(i for i, ln in enumerate(cut) if " 025#" in ln) + 1
    log = tmp_path / "dlc.log"
    log.write_text("\n".join(cut) + "\n")
    rc, line = cli_run(
        ["ingest", log, "--dbc", DBC, "--signals", MAP17, "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and str(log) in line and "channel 'steering_wheel_angle'" in line
    assert "STEER_ANGLE_SENSOR was dropped" in line and "shorter" in line
    assert f"first at {first})" in line
    assert not (tmp_path / "r.csv").exists()


# ----------------------------------------------------------------------------- recordings
def _corrupt(rec_rows, col, row, value):
    header, rows = rec_rows
    rows = [list(r) for r in rows]
    rows[row][header.index(col)] = value
    return header, rows


@pytest.mark.parametrize(
    "col, value, why",
    [("speed", "inf", "not finite"), ("yaw_rate", "-inf", "not finite"), ("gear", "X", "gear 'X'")],
)
def test_recording_bad_cell_names_line_and_channel(col, value, why, tmp_path, rec_rows, capsys):
    """Was: exit 0 and parameters fitted through an infinite speed / an unknown gear."""
    path = write_rec(tmp_path / "rec.csv", *_corrupt(rec_rows, col, 40, value))
    out = tmp_path / "p.yaml"
    rc, line = cli_run(["identify", path, "--vehicle", GEOMETRY, "--out", out], capsys)
    assert rc == 2 and f"{path}:42: channel '{col}'" in line and why in line
    assert not out.exists()


def test_recording_pedal_in_percent(tmp_path, rec_rows, capsys):
    """Was: exit 0, the accelerator map fitted 100 times too small."""
    header, rows = rec_rows
    i = header.index("accel_pedal")
    rows = [list(r) for r in rows]
    for r in rows:
        r[i] = repr(float(r[i]) * 100) if r[i] else r[i]
    first = next(k for k, r in enumerate(rows) if r[i] and float(r[i]) > 1.05) + 2
    path = write_rec(tmp_path / "rec.csv", header, rows)
    rc, line = cli_run(
        ["identify", path, "--vehicle", GEOMETRY, "--out", tmp_path / "p.yaml"], capsys
    )
    assert rc == 2 and f"{path}:{first}: channel 'accel_pedal'" in line and "0..1" in line


def test_recording_column_twice(tmp_path, rec_rows, capsys):
    """Was: exit 0, the second 'steering_wheel_angle' column (here: the speed) silently used."""
    header, rows = rec_rows
    header = list(header)
    header[header.index("speed")] = "steering_wheel_angle"
    path = write_rec(tmp_path / "rec.csv", header, rows)
    rc, line = cli_run(
        ["identify", path, "--vehicle", GEOMETRY, "--out", tmp_path / "p.yaml"], capsys
    )
    assert rc == 2 and f"{path}:1: channel 'steering_wheel_angle'" in line and "twice" in line
    with pytest.raises(InputError, match="twice"):
        read_channels(path)


def test_recording_clock_jump(tmp_path, rec_rows, capsys):
    """Was: exit 0, a 30 s step in the middle of a 50 Hz grid fitted as if it were one sample
    period of driving (CONVENTIONS: one uniform grid; a gap is rows with empty cells)."""
    header, rows = rec_rows
    rows = [list(r) for r in rows]
    for r in rows[30:]:
        r[0] = f"{float(r[0]) + 30.0:.6f}"
    path = write_rec(tmp_path / "rec.csv", header, rows)
    rc, line = cli_run(["replay", path, "--params", REPORT_PARAMS, "--controller", "pid"], capsys)
    assert rc == 2 and f"{path}:32: channel 'time'" in line and "30.02 s" in line


def test_replay_of_a_folder_says_folder(tmp_path, capsys):
    """Was: 'no such file' for a folder that exists."""
    rc, line = cli_run(["replay", tmp_path, "--params", REPORT_PARAMS], capsys)
    assert rc == 2 and line.endswith(f"{tmp_path}: not a file (a folder)")


# ----------------------------------------------------------------------------- parameter files
@pytest.mark.parametrize(
    "old, new, key",
    [
        ("scale: 0.08}", "scale: -0.08}", "steering.scale"),
        (
            "brake_scale_mps2: 5.0",
            "brake_scale_mps2: -5.0",
            "longitudinal.zones[1].brake_scale_mps2",
        ),
        ("scale_mps2: 3.0", "scale_mps2: -3.0", "longitudinal.zones[2].scale_mps2"),
    ],
)
def test_params_with_a_wrong_sign(old, new, key, tmp_path, capsys):
    """Was: exit 0, a closed loop on a steering map that turns right for left, or on a
    pedal that decelerates (only `--experiment` refused the steering sign)."""
    text = REPORT_PARAMS.read_text()
    assert old in text
    path = tmp_path / "p.yaml"
    path.write_text(text.replace(old, new, 1))
    rc, line = cli_run(
        [
            "simulate",
            "--params",
            path,
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--out",
            tmp_path / "s.csv",
        ],
        capsys,
    )
    assert rc == 2 and f"{path}: key '{key}'" in line and "-" in line
    assert not (tmp_path / "s.csv").exists()


def test_geometry_with_a_negative_mass(tmp_path, capsys):
    path = tmp_path / "v.yaml"
    path.write_text(GEOMETRY.read_text().replace("mass_kg: 1656", "mass_kg: -1656"))
    rc, line = cli_run(
        [
            "identify",
            bundled("rav4-comma2k19/nav.csv.gz"),
            "--vehicle",
            path,
            "--out",
            tmp_path / "p.yaml",
        ],
        capsys,
    )
    assert rc == 2 and f"{path}: key 'vehicle.mass_kg'" in line and "positive" in line


@pytest.mark.parametrize("value", ["7", "0.5"])
def test_actuation_constant_that_does_not_fit_its_signal(value, tmp_path, capsys):
    """Was: an OverflowError traceback from cantools in the drive loop (7), or 0.5 silently
    truncated to 0 in every frame."""
    import shutil

    shutil.copy(MAP17, tmp_path / MAP17.name)  # the profile names its map and DBC beside it
    shutil.copy(DBC, tmp_path / DBC.name)
    text = ACTUATION.read_text()
    assert "SET_ME_1: 1" in text
    prof = tmp_path / "a.actuation.yaml"
    prof.write_text(text.replace("SET_ME_1: 1", f"SET_ME_1: {value}"))
    rc, line = cli_run(
        [
            "drive",
            "--params",
            REPORT_PARAMS,
            "--actuation",
            prof,
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--duration",
            "1",
            "--candump",
            tmp_path / "run.log",
        ],
        capsys,
    )
    assert rc == 2 and str(prof) in line
    assert "key 'commands.steer_torque.constants.SET_ME_1'" in line and "0..1" in line
    assert not (tmp_path / "run.log").exists()


def test_a_bus_that_cannot_be_opened(tmp_path, capsys):
    """Was: an OSError traceback (errno 97 on a host without SocketCAN, 19 without the
    interface) from ``can.Bus`` in the drive loop."""
    rc, line = cli_run(
        [
            "drive",
            "--params",
            REPORT_PARAMS,
            "--actuation",
            ACTUATION,
            "--bus",
            "socketcan:nope0",
            "--scenario",
            "idle_hold",
            "--controller",
            "pid",
            "--duration",
            "1",
            "--candump",
            tmp_path / "run.log",
        ],
        capsys,
    )
    assert rc == 2 and "bus socketcan:nope0: cannot open it" in line


# ----------------------------------------------------------------------------- console script
def test_console_script_one_line_no_traceback(tmp_path, short_log):
    """The installed `hmpc` script itself, as a user runs it."""
    script = Path(sys.executable).parent / "hmpc"
    if not script.is_file():
        script = REPO_DIR / ".venv" / "bin" / "hmpc"
    bad = tmp_path / "nodir" / "x.json"
    p = subprocess.run(
        [str(script), "info", str(short_log), "--json", str(bad)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines() == [
        f"hmpc info: error: {bad}: cannot write JSON (--json: folder '{bad.parent}' does not exist)"
    ]
