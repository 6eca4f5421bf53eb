"""``hmpc simulate``: closed loop, experiments, JSON keys, plots, bad input (exit 2)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from hmpc.models.errors import InputError
from hmpc.models.logs.recording import Recording
from hmpc.models.sim.scenarios import load_reference_csv, make_scenario, save_reference_csv
from hmpc.tools.cli import main

PARAMS = "params/report_2008.yaml"
KEYS = ("speed_error_rms_mps", "lateral_error_rms_m", "pedal_switches_per_min",
        "zone_transitions_per_min", "solve_time_ms", "steps", "failures")


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
    rc = main(["simulate", "--params", PARAMS, "--reference", str(short_ref), "--out", str(out),
               "--json", str(js), "--plots", str(plots), "--seed", "3"])
    assert rc == 0
    d = json.loads(js.read_text())
    for k in KEYS:
        assert k in d
    assert set(d["solve_time_ms"]) == {"p50", "p99", "max"}
    assert d["steps"] == 80 and d["failures"] == 0
    assert d["speed_error_rms_mps"] < 0.3 and d["lateral_error_rms_m"] < 0.3
    rec = Recording.load(out)
    for ch in ("steering_cmd", "accel_pedal_cmd", "brake_pedal_cmd", "speed", "x", "y"):
        assert ch in rec
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
    rc = main(["simulate", "--params", PARAMS, "--reference", str(short_ref), "--controller",
               "pid", "--plant-params", str(weak), "--json", str(js)])
    assert rc == 0
    d = json.loads(js.read_text())
    assert all(k in d for k in KEYS) and d["controller"] == "pid"
    assert d["plant_params"] == str(weak)


def test_experiment_writes_a_canonical_recording(tmp_path):
    out, js = tmp_path / "exp.csv", tmp_path / "exp.json"
    rc = main(["simulate", "--experiment", "ramp_sequence", "--params", PARAMS, "--out", str(out),
               "--seed", "1", "--json", str(js)])
    assert rc == 0
    rec = Recording.load(out)
    assert "speed" in rec and "accel_pedal" in rec
    assert json.loads(js.read_text())["rows"] == len(rec)


@pytest.mark.parametrize("body, line, what", [
    ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0,1\n0.2,zz,0,1\n", 4, "not a number"),
    ("time,x,y,speed\n0,0,0,1\n0,0.1,0,1\n", 3, "strictly increasing"),
    ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0,-1\n", 3, "speed must be"),
    ("time,x,y,speed\n0,0,0,1\n0.1,0.1,0\n", 3, "expected 4 fields"),
    ("time,x,y,speed\n0,0,0,1\n0.1,nan,0,1\n", 3, "not finite"),
    ("time,x,y\n0,0,0\n", 1, "missing"),
    ("time,x,y,speed,bogus\n0,0,0,1,2\n", 1, "unknown column"),
])
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
