"""End to end in real time: the drive loop drives the vehicle simulator node over python-can's
virtual bus, both profiles, a few seconds of figure8 and of ramp_sequence. Tracking within 2x
of the same closed loop without a bus (hmpc simulate's loop), no limit violated (audited from
the candump read back by hmpc's own reader), every command frame accepted by the node, and
``hmpc ingest`` reads the run back."""

from __future__ import annotations

import json

import pytest

from _data import PARAMS_DIR
from _drive import drive, simulate_baseline
from hmpc.tools.cli import main

pytestmark = pytest.mark.realtime

RUN_S = 6.0


# The Toyota node's ACC has a 0.25 s powertrain lag that the report_2008 model lacks; the
# Toyota runs give the MPC that lag as identify/diagnose would report it (``extensions:
# actuator_lag``, tests/_drive.py controller_params). Without it, ramp_sequence tracked
# 0.226 m/s RMS against 2 x simulate's 0.108 = 0.217 (the MPC's pedal smoothing terms cost
# speed tracking through the lag); with it 0.206..0.208 (3 runs; most of the rest is the
# start from rest under the jerk limit).


@pytest.mark.parametrize("profile", ["toyota", "bywire"])
@pytest.mark.parametrize("scenario", ["figure8", "ramp_sequence"])
def test_drive_tracks_like_simulate(profile, scenario, tmp_path):
    res, _ = drive(profile, scenario, RUN_S, tmp_path)
    s = res.summary
    base = simulate_baseline(scenario, RUN_S + 0.3)
    print(
        profile,
        scenario,
        {k: s[k] for k in ("speed_error_rms_mps", "lateral_error_rms_m")},
        "simulate:",
        {k: base[k] for k in ("speed_error_rms_mps", "lateral_error_rms_m")},
    )
    assert s["stop"]["reason"] == "duration"
    assert s["stop"]["standstill_t_s"] is not None
    assert s["stop"]["standstill_t_s"] >= s["stop"]["t_s"]
    assert s["limit_violations"] == 0 and s["limit_audit"]["frames_checked"] > 100
    assert s["frames_rejected_by_vehicle"] == 0
    assert sum(s["node"]["accepted"].values()) == sum(s["frames_sent"].values())
    assert s["failures"] == 0
    # 2x the bus-free loop; 1 cm and 1 cm/s floors: the CAN resolution of speed and angle
    assert s["speed_error_rms_mps"] <= max(2 * base["speed_error_rms_mps"], 0.01)
    assert s["lateral_error_rms_m"] <= max(2 * base["lateral_error_rms_m"], 0.01)


def test_cli_drive_json_and_ingest_reads_the_run(tmp_path):
    log, out = tmp_path / "run.log", tmp_path / "run.json"
    rc = main(
        [
            "drive",
            "--params",
            str(PARAMS_DIR / "report_2008.yaml"),
            "--actuation",
            str(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml"),
            "--vehicle-sim",
            "--scenario",
            "figure8",
            "--duration",
            "2",
            "--candump",
            str(log),
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    j = json.loads(out.read_text())
    for key in (
        "steps",
        "loop_period_ms",
        "deadline_misses",
        "frames_sent",
        "frames_rejected_by_vehicle",
        "limit_clips",
        "limit_violations",
        "engaged_s",
        "stop",
        "speed_error_rms_mps",
        "lateral_error_rms_m",
        "pedal_switches_per_min",
        "zone_transitions_per_min",
        "solve_time_ms",
        "failures",
    ):
        assert key in j, key
    assert set(j["stop"]) == {"reason", "t_s", "detected_t_s", "standstill_t_s"}
    assert set(j["loop_period_ms"]) == {"p50", "p99", "max"}
    assert j["limit_violations"] == 0 and j["frames_sent"]["STEERING_LKA"] > 150
    rec = tmp_path / "rec.csv"
    rc = main(
        [
            "ingest",
            str(log),
            "--dbc",
            str(PARAMS_DIR.parent / "tools/data/dbc/toyota_rav4_2017.dbc.gz"),
            "--signals",
            str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml"),
            "--out",
            str(rec),
        ]
    )
    assert rc == 0
    head = rec.read_text().splitlines()[0].split(",")
    assert {"time", "speed", "steering_wheel_angle", "accel_cmd"} <= set(head)


def test_cli_bad_fault_is_exit_2(tmp_path, capsys):
    rc = main(
        [
            "drive",
            "--params",
            str(PARAMS_DIR / "report_2008.yaml"),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--vehicle-sim",
            "--scenario",
            "figure8",
            "--fault",
            "meteor@1",
            "--candump",
            str(tmp_path / "x.log"),
        ]
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert "meteor@1" in err and len(err.strip().splitlines()) == 1  # one line, no traceback


def test_cli_no_car_on_the_bus_is_exit_2(tmp_path, capsys):
    """Nothing answers on the bus: the loop never engages, sends no request, and says so."""
    rc = main(
        [
            "drive",
            "--params",
            str(PARAMS_DIR / "report_2008.yaml"),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--scenario",
            "figure8",
            "--duration",
            "1",
            "--candump",
            str(tmp_path / "x.log"),
            "--json",
            str(tmp_path / "x.json"),
        ]
    )
    assert rc == 2
    assert "never engaged" in capsys.readouterr().err
    j = json.loads((tmp_path / "x.json").read_text())
    assert j["steps"] == 0 and j["stop"]["reason"] == "no_feedback" and j["limit_violations"] == 0


def test_cli_warns_when_the_run_stops_the_car_by_itself(tmp_path, capsys):
    """A stop nobody asked for (here an injected feedback loss) is said on stderr, with the
    time it happened and the run time asked for: the figures printed cover a shorter run."""
    rc = main(
        [
            "drive",
            "--params",
            str(PARAMS_DIR / "report_2008.yaml"),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--vehicle-sim",
            "--scenario",
            "figure8",
            "--duration",
            "4",
            "--fault",
            "feedback_loss@1.5",
            "--candump",
            str(tmp_path / "x.log"),
            "--json",
            str(tmp_path / "x.json"),
        ]
    )
    assert rc == 0
    err = capsys.readouterr().err
    assert "warning: the run stopped the car by itself (feedback_loss at" in err
    assert "of 4.0 s asked" in err
    assert json.loads((tmp_path / "x.json").read_text())["stop"]["reason"] == "feedback_loss"
