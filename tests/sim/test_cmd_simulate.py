"""``hmpc simulate``: closed loop, experiments, JSON keys, plots, bad input (exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from _data import REPORT_PARAMS
from hmpc.models.errors import InputError
from hmpc.models.logs.recording import Recording
from hmpc.models.reference import load_reference_csv, save_reference_csv
from hmpc.models.sim.scenarios import make_scenario
from hmpc.tools.cli import main

PARAMS = str(REPORT_PARAMS)
KEYS = (
    "speed_error_rms_mps",
    "lateral_error_rms_m",
    "pedal_switches_per_min",
    "zone_transitions_per_min",
    "solve_time_ms",
    "steps",
    "failures",
    "internal_errors",
)


@pytest.fixture
def short_ref(tmp_path):
    """8 s at 3 m/s along a gentle curve, as a reference CSV (time, x, y, speed)."""
    t = np.arange(0.0, 8.0, 0.05)
    th = 0.02 * t
    v = np.full(len(t), 3.0)
    x = np.concatenate([[0.0], np.cumsum(v[1:] * np.cos(th[1:]) * 0.05)])
    y = np.concatenate([[0.0], np.cumsum(v[1:] * np.sin(th[1:]) * 0.05)])
    path = tmp_path / "ref.csv"
    with open(path, "w") as fh:
        fh.write("time,x,y,speed\n")
        for row in zip(t, x, y, v):
            fh.write(",".join(f"{a:.6f}" for a in row) + "\n")
    return path


def test_closed_loop_json_recording_and_plots(tmp_path, short_ref):
    out, js, plots = tmp_path / "run.csv", tmp_path / "run.json", tmp_path / "plots"
    rc = main(
        [
            "simulate",
            "--params",
            PARAMS,
            "--reference",
            str(short_ref),
            "--out",
            str(out),
            "--json",
            str(js),
            "--plots",
            str(plots),
            "--seed",
            "3",
        ]
    )
    assert rc == 0
    d = json.loads(js.read_text())
    assert set(KEYS) <= set(d)
    assert d["steps"] == 80 and d["failures"] == 0 and d["internal_errors"] == 0
    # measured: speed error RMS 0.034 m/s, lateral 0.0040 m, 1 pedal switch (7.6/min), no
    # zone transition (3 m/s stays in the low zone); bounds with margin 2-2.5x
    assert d["speed_error_rms_mps"] < 0.07 and d["lateral_error_rms_m"] < 0.01
    assert d["pedal_switches_per_min"] <= 8.0 and d["zone_transitions_per_min"] == 0.0
    assert d["details"]["both_pedals_samples"] == 0
    st = d["solve_time_ms"]
    assert 0.0 < st["p50"] <= st["p99"] <= st["max"]
    # the recording is the run: 8 s at 50 Hz, commands within their ranges, the speed held
    # near the 3 m/s reference (measured 2.89-3.03 m/s)
    rec = Recording.load(out)
    assert len(rec) == 398 and rec.rate_hz == pytest.approx(50.0)
    assert np.all((rec["accel_pedal_cmd"] >= 0) & (rec["accel_pedal_cmd"] <= 1))
    assert np.all((rec["brake_pedal_cmd"] >= 0) & (rec["brake_pedal_cmd"] <= 1))
    assert not np.any((rec["accel_pedal_cmd"] > 0) & (rec["brake_pedal_cmd"] > 0))
    assert np.all(np.abs(rec["speed"] - 3.0) < 0.2)
    assert np.all(np.isfinite(rec["steering_cmd"])) and np.all(np.isfinite(rec["x"] + rec["y"]))
    assert sorted(p.name for p in plots.iterdir()) == ["closed_loop.png", "path.png"]
    assert all(p.stat().st_size > 10_000 for p in plots.iterdir())


def test_pid_and_plant_params(tmp_path, short_ref):
    with open(PARAMS) as fh:
        data = yaml.safe_load(fh)
    for z in data["longitudinal"]["zones"]:
        z["scale_mps2"] *= 0.8
        z["brake_scale_mps2"] *= 0.8
    weak = tmp_path / "weak.yaml"
    weak.write_text(yaml.safe_dump(data))
    js = tmp_path / "pid.json"
    rc = main(
        [
            "simulate",
            "--params",
            PARAMS,
            "--reference",
            str(short_ref),
            "--controller",
            "pid",
            "--plant-params",
            str(weak),
            "--json",
            str(js),
        ]
    )
    assert rc == 0
    d = json.loads(js.read_text())
    assert d["controller"] == "pid" and d["plant_params"] == str(weak)
    # the PID tracks the weaker plant (measured speed RMS 0.035 m/s, lateral 0.024 m); its
    # smoothness is held in tests/controller/test_pid_smooth.py.
    assert d["failures"] == 0 and d["internal_errors"] == 0 and d["steps"] == 80
    assert d["speed_error_rms_mps"] < 0.1 and d["lateral_error_rms_m"] < 0.06


def test_experiment_writes_a_canonical_recording(tmp_path):
    out, js = tmp_path / "exp.csv", tmp_path / "exp.json"
    rc = main(
        [
            "simulate",
            "--experiment",
            "ramp_sequence",
            "--params",
            PARAMS,
            "--out",
            str(out),
            "--seed",
            "1",
            "--json",
            str(js),
        ]
    )
    assert rc == 0
    rec = Recording.load(out)
    d = json.loads(js.read_text())
    assert d["rows"] == len(rec) == round(d["duration_s"] * d["rate_hz"]) + 1
    for ch in d["channels"]:
        assert ch in rec, ch
    # a ramp sequence: pedal fractions in 0..1 that actually ramp (measured max 0.585), the
    # speed never below zero beyond sensor quantisation (measured min -0.006 m/s) and reaching
    # about 8 m/s (measured max 8.17 m/s)
    assert np.nanmin(rec["accel_pedal"]) == 0.0 and 0.5 < np.nanmax(rec["accel_pedal"]) <= 1.0
    assert np.nanmin(rec["speed"]) > -0.02 and 7.5 < np.nanmax(rec["speed"]) < 9.0


def test_a_canonical_recording_is_a_reference(tmp_path):
    """CONVENTIONS: any tool that takes a recording accepts one directly. A recording given as
    --reference is followed along its driven path and speed (as ``hmpc replay`` does): the
    MPC on the same model that made the recording tracks it closely."""
    rec = tmp_path / "arcs.csv"
    assert (
        main(
            [
                "simulate",
                "--experiment",
                "arcs",
                "--params",
                PARAMS,
                "--out",
                str(rec),
                "--seed",
                "1",
            ]
        )
        == 0
    )
    js = tmp_path / "run.json"
    assert main(["simulate", "--params", PARAMS, "--reference", str(rec), "--json", str(js)]) == 0
    d = json.loads(js.read_text())
    r = Recording.load(rec)
    assert d["reference"] == "arcs"
    assert d["steps"] * 0.1 == pytest.approx(r.time[-1] - r.time[0], abs=0.2)  # 0.1 s steps
    assert d["failures"] == 0
    assert d["speed_error_rms_mps"] < 0.3 and d["lateral_error_rms_m"] < 0.3


@pytest.mark.parametrize(
    "body, line, what",
    [
        ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0,1\n0.2,zz,0,1\n", 4, "not a number"),
        ("time,x,y,speed\n0,0,0,1\n0,0.1,0,1\n", 3, "strictly increasing"),
        ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0,-1\n", 3, "speed must be"),
        ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0\n", 3, "expected 4 fields"),
        ("time,x,y,speed\n0,0,0,1\n0.1,nan,0,1\n", 3, "not finite"),
        ("time,x,y\n0,0,0\n", 1, "missing"),
        ("time,x,y,speed,bogus\n0,0,0,1,2\n", 1, "unknown column"),
    ],
)
def test_bad_reference_is_exit_2_with_file_and_line(tmp_path, capsys, body, line, what):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(InputError) as err:
        load_reference_csv(path)
    assert err.value.line == line
    rc = main(["simulate", "--params", PARAMS, "--reference", str(path)])
    assert rc == 2
    msg = capsys.readouterr().err.strip().splitlines()
    assert len(msg) == 1 and f"bad.csv:{line}" in msg[0] and what in msg[0]


def test_other_bad_input_is_exit_2(tmp_path, capsys):
    assert main(["simulate", "--params", PARAMS, "--scenario", "nope"]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["simulate", "--params", str(tmp_path / "none.yaml"), "--scenario", "arcs"]) == 2
    assert main(["simulate", "--params", PARAMS, "--experiment", "ramps"]) == 2  # no --out
    assert "--out" in capsys.readouterr().err
    assert main(["simulate", "--params", PARAMS, "--reference", str(tmp_path / "no.csv")]) == 2


def test_reference_csv_round_trip(tmp_path):
    ref = make_scenario("figure8")
    save_reference_csv(ref, tmp_path / "f8.csv")
    back = load_reference_csv(tmp_path / "f8.csv")
    assert np.allclose(back.x_m, ref.x_m) and np.allclose(back.speed_mps, ref.speed_mps)
    assert back.length_m == pytest.approx(ref.length_m)
    # heading computed from the path when the file has none: the tangent of the polyline
    with open(tmp_path / "nohead.csv", "w") as fh:
        fh.write("time,x,y,speed\n0,0,0,1\n1,1,1,1\n2,2,2,1\n")
    assert np.allclose(load_reference_csv(tmp_path / "nohead.csv").heading_rad, np.pi / 4)


def test_sensor_options_reach_the_run_and_the_json(tmp_path, short_ref, capsys):
    """The controller sees the plant through simulated sensors and the estimator;
    their settings are options, echoed in the JSON with the smoothness figures."""
    js = tmp_path / "s.json"
    rc = main(
        [
            "simulate",
            "--params",
            PARAMS,
            "--reference",
            str(short_ref),
            "--json",
            str(js),
            "--sensor-noise-scale",
            "3",
            "--gnss-rate",
            "10",
            "--gnss-latency",
            "0.1",
            "--gnss-outage",
            "2:4",
            "--gnss-outage",
            "5.5:6",
        ]
    )
    assert rc == 0
    d = json.loads(js.read_text())
    assert d["sensors"]["noise_scale"] == 3.0 and d["sensors"]["gnss_rate_hz"] == 10.0
    assert d["sensors"]["gnss_latency_s"] == 0.1
    assert d["sensors"]["gnss_outages_s"] == [[2.0, 4.0], [5.5, 6.0]]
    assert d["sensors"]["position_noise_m"] == 0.02 and d["sensors"]["speed_noise_mps"] == 0.05
    est = d["details"]["estimator"]
    # 8 s at 10 Hz less 2.5 s of outage: about 55 fixes; 25 fell in the outages
    assert 50 <= est["messages"]["gnss"] <= 56 and 24 <= est["messages"]["gnss_outage"] <= 26
    assert est["position_error_rms_m"] < 0.1 and d["failures"] == 0
    rv = d["steering_reversals_per_min"]
    assert set(rv) == {"1deg", "5deg"} and 0.0 <= rv["5deg"] <= rv["1deg"]
    for k in ("steering_rate_rms_radps", "accel_pedal_rate_rms_ps", "brake_pedal_rate_rms_ps"):
        assert d[k] >= 0.0
    assert "smoothness: steering reversals" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, what",
    [
        (["--gnss-outage", "4:2"], "--gnss-outage"),
        (["--gnss-outage", "abc"], "T0:T1"),
        (["--gnss-rate", "0"], "--gnss-rate"),
        (["--sensor-noise-scale", "-1"], "--sensor-noise-scale"),
        (["--position-noise", "-0.1"], "--position-noise"),
    ],
)
def test_bad_sensor_option_is_exit_2(short_ref, capsys, args, what):
    rc = main(["simulate", "--params", PARAMS, "--reference", str(short_ref)] + args)
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0]


def test_effect_option_runs_the_truth_plant_and_refuses_bad_specs(tmp_path, short_ref, capsys):
    """``--effect``: the simulated car has physics the model lacks; the JSON echoes it. An
    uphill grade slows the car against the same run without it. A bad spec exits 2 in one
    line naming the key."""
    out = {}
    for name, extra in (("clean", []), ("grade", ["--effect", "road_grade:grade_rad=0.05"])):
        js = tmp_path / f"{name}.json"
        assert (
            main(
                [
                    "simulate",
                    "--params",
                    PARAMS,
                    "--reference",
                    str(short_ref),
                    "--out",
                    str(tmp_path / f"{name}.csv"),
                    "--json",
                    str(js),
                ]
                + extra
            )
            == 0
        )
        out[name] = json.loads(js.read_text())
    assert out["clean"]["effects"] == []
    assert out["grade"]["effects"] == [{"type": "road_grade", "grade_rad": 0.05}]
    v = {k: Recording.load(tmp_path / f"{k}.csv")["speed"].mean() for k in out}
    assert v["grade"] < v["clean"] - 0.02
    capsys.readouterr()
    rc = main(
        [
            "simulate",
            "--params",
            PARAMS,
            "--reference",
            str(short_ref),
            "--effect",
            "road_grade:slope=0.05",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "'slope'" in err[0]
