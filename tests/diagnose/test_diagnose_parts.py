"""`hmpc diagnose` diagnoses what a recording supports, and writes only files hmpc accepts.

- a 20 s slalom at 50 Hz (four wheel speeds, yaw rate, steering-wheel angle, no pedals): exit 0
  with the lateral part; a part the recording cannot support is named under ``not_diagnosed``
  and printed; exit 2 with one line only when no part can run;
- ``--params-out`` with a steering dead time (numpy scalars once broke the YAML writer, leaving a
  0-byte file), written under a temporary name and loaded back before it replaces anything; the
  given file's ``identifiable: false`` flags and ``not_identified`` entries stay; a part not
  diagnosed is named under ``not_identified``, never written;
- the overall verdict (the model does not describe a vehicle whose speed the recorded pedal does
  not drive); understeer's separability is "not testable" on a straight line; the steering
  thresholds scale with the vehicle and the dropped samples are counted by reason.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

import _slalom
from _data import REPORT_PARAMS
from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.diagnose.diagnose import diagnose
from hmpc.models.errors import InputError
from hmpc.models.logs.recording import Recording
from hmpc.models.params import load_params
from hmpc.tools import cli

VEHICLE = load_params(REPORT_PARAMS).vehicle


def _cli(argv, capsys):
    rc = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    assert "Traceback" not in out.err, out.err
    return rc, out


def test_short_slalom_without_pedals_diagnoses_its_lateral_part(tmp_path, capsys):
    """A 20 s slalom with no pedals exits 0 with the lateral part diagnosed
    and the longitudinal part named as not diagnosed (no input: none is filled in); with pedals
    at 15 s the longitudinal model (20 s of moving data) is named as not diagnosed for its
    length; each is printed, in the JSON and in the parameter file's not_identified, which hmpc
    loads back."""
    for dur, pedals in ((20.0, False), (15.0, True)):
        rec = _slalom.drive(duration_s=dur, pedals=pedals, path=f"slalom{dur:g}.csv")
        csv = tmp_path / f"slalom{dur:g}.csv"
        rec.to_csv(csv)
        js, p2, html = tmp_path / f"d{dur:g}.json", tmp_path / f"p{dur:g}.yaml", tmp_path / "r"
        rc, out = _cli(
            [
                "diagnose",
                csv,
                "--vehicle",
                REPORT_PARAMS,
                "--json",
                js,
                "--params-out",
                p2,
                "--report",
                html,
            ],
            capsys,
        )
        assert rc == 0, out.err
        j = json.loads(js.read_text())
        assert "steering" not in j["not_diagnosed"]
        assert j["channels"]["heading"]["heldout_rmse_baseline"] > 0.0
        assert (html / "index.html").exists()
        p = load_params(p2)
        assert p.steering is not None and p.steering.scale == pytest.approx(_slalom.SCALE, rel=0.05)
        why = j["not_diagnosed"]["longitudinal"]
        if pedals:
            assert "too little moving data" in why and "needs 20 s" in why
        else:
            assert why.startswith("no longitudinal input") and "accel_pedal" in why
        assert f"not diagnosed: longitudinal: {why}" in out.out
        assert not p.zones and "longitudinal" in p.not_identified
        assert j["longitudinal_input"] is None


def test_no_part_supported_exits_2_in_one_line_and_writes_nothing(tmp_path, capsys):
    t = np.arange(0, 30, 0.02)
    Recording(
        {"time": t, "speed": np.zeros_like(t), "accel_pedal": np.zeros_like(t)}, meta={}
    ).to_csv(tmp_path / "still.csv")
    js, p2 = tmp_path / "d.json", tmp_path / "p.yaml"
    rc, out = _cli(
        [
            "diagnose",
            tmp_path / "still.csv",
            "--vehicle",
            REPORT_PARAMS,
            "--json",
            js,
            "--params-out",
            p2,
        ],
        capsys,
    )
    err = out.err.strip().splitlines()
    assert rc == 2 and "nothing to diagnose" in err[-1] and "still.csv" in err[-1]
    assert "longitudinal: too little moving data" in err[-1] and "steering:" in err[-1]
    assert not js.exists() and not p2.exists()


def test_steering_dead_time_writes_a_parameter_file_hmpc_loads(tmp_path, capsys):
    """A steering actuator_delay (a numpy scalar from the grid search) is written as a plain
    number; nothing else but the file appears in the folder (no temporary left behind)."""
    rec = _slalom.drive(duration_s=60.0, steer_delay_s=0.2, pedals=True)
    rec.to_csv(tmp_path / "rec.csv")
    out = tmp_path / "out"
    out.mkdir()
    rc, res = _cli(
        [
            "diagnose",
            tmp_path / "rec.csv",
            "--vehicle",
            REPORT_PARAMS,
            "--params-out",
            out / "p2.yaml",
        ],
        capsys,
    )
    assert rc == 0, res.err
    assert sorted(x.name for x in out.iterdir()) == ["p2.yaml"]
    p = load_params(out / "p2.yaml", require_model=True)
    assert p.steering.dead_time_s == pytest.approx(0.2, abs=0.03)
    assert "actuator_delay" in p.extensions
    assert "np.float64" not in (out / "p2.yaml").read_text()


def test_params_text_refuses_what_the_loader_refuses():
    """The file is checked with the loader's rules before anything is written: an extension
    the catalogue does not know is refused naming the key (exit 2), never written."""
    from hmpc.tools.cmd_diagnose import params_text

    p = load_params(REPORT_PARAMS)
    p.steering.dead_time_s = np.float64(0.15)
    assert "dead_time_s: 0.15" in params_text(p, "p2.yaml")
    p.extensions = {"no_such_effect": {"steering": {"x": 1.0}}}
    with pytest.raises(InputError, match="extensions.no_such_effect"):
        params_text(p, "p2.yaml")


def test_given_status_flags_stay_in_the_written_file(tmp_path, capsys):
    """identify's flags (steering and a zone identifiable: false, a zone value under
    not_identified) stay flagged in what --params-out writes, though diagnose refits them."""
    given = yaml.safe_load(REPORT_PARAMS.read_text())
    given["steering"].update(identifiable=False, note="NOT identifiable: too little steering")
    z = given["longitudinal"]["zones"][2]
    z.update(identifiable=False, note="offset known only to +-0.3 m/s^2")
    given["not_identified"] = {f"longitudinal.zones.{z['name']}.offset_mps2": "too wide"}
    gp = tmp_path / "given.yaml"
    gp.write_text(yaml.safe_dump(given))
    _slalom.drive(duration_s=60.0, pedals=True).to_csv(tmp_path / "rec.csv")
    rc, res = _cli(
        [
            "diagnose",
            tmp_path / "rec.csv",
            "--vehicle",
            REPORT_PARAMS,
            "--params",
            gp,
            "--params-out",
            tmp_path / "p2.yaml",
        ],
        capsys,
    )
    assert rc == 0, res.err
    p = load_params(tmp_path / "p2.yaml", require_model=True)
    assert p.steering.identifiable is False and "too little steering" in p.steering.note
    assert p.zones[2].identifiable is False and "+-0.3" in p.zones[2].note
    assert p.not_identified == given["not_identified"]


def test_verdict_names_a_model_that_does_not_describe_the_vehicle():
    """A recorded pedal that does not drive the car (the speed follows something else): the
    verdict is printed first and names the speed with its factor over the noise floor; a car
    the model describes gets the opposite verdict."""
    rec = _slalom.drive(duration_s=90.0, pedals=True)
    good = diagnose(rec, VEHICLE)
    assert good.verdict["model_describes_vehicle"] is True
    rng = np.random.default_rng(5)
    rec.channels["accel_pedal"] = np.repeat(rng.uniform(0.0, 0.5, len(rec) // 100 + 1), 100)[
        : len(rec)
    ]
    bad = diagnose(rec, VEHICLE)
    v = bad.verdict
    assert v["model_describes_vehicle"] is False
    sp = v["channels"]["speed"]
    assert sp["misses"] and sp["factor"] >= 10 and sp["skill"] < 0.5
    assert v["text"].startswith("this model does not describe this vehicle: speed error")
    assert bad.to_json()["verdict"]["channels"]["speed"]["factor"] == pytest.approx(
        sp["rmse"] / sp["noise_floor"]
    )
    from hmpc.tools.cmd_diagnose import summary_lines

    assert summary_lines(bad)[0] == f"verdict: {v['text']}"


def test_understeer_is_not_testable_on_a_straight_line():
    dg = diagnose(_slalom.drive(duration_s=60.0, straight=True, pedals=True), VEHICLE)
    sep = dg.channels["heading"]["understeer_vs_ratio"]
    assert sep["testable"] is False and sep["separable"] is False
    assert "not testable" in sep["verdict"] and "lateral acceleration" in sep["verdict"]
    assert "likelihood_ratio" not in sep


def test_steering_thresholds_scale_with_the_vehicle_and_drops_are_counted():
    """A 1:10 car (wheelbase 0.33 m) trusts steering samples from sqrt(0.33 / 2.65) of a
    passenger car's speeds (equal Froude number, as identification scales them); every dropped
    sample is counted under its reason and the terminal prints them."""
    small = load_params(REPORT_PARAMS).vehicle
    small.wheelbase_m = 0.3302
    cfg, ref = DiagnoseConfig.for_vehicle(small), DiagnoseConfig()
    f = math.sqrt(0.3302 / 2.65)
    assert cfg.v_steer_min_mps == pytest.approx(ref.v_steer_min_mps * f)
    assert cfg.v_move_min_mps == pytest.approx(ref.v_move_min_mps * f)
    assert DiagnoseConfig.for_vehicle(VEHICLE) == ref
    with pytest.raises(ValueError, match="unknown diagnose threshold"):
        DiagnoseConfig.for_vehicle(VEHICLE, v_min=1.0)
    rec = _slalom.drive(duration_s=40.0, pedals=True)
    rec.channels["wheel_speed_rl"][:250] = np.nan  # 5 s without one rear wheel
    dg = diagnose(rec, VEHICLE)
    ss = dg.steering_samples
    assert ss["dropped"]["channel missing (NaN)"] == 250
    assert ss["angle_fit"] + sum(ss["dropped"].values()) == ss["total"]
    from hmpc.tools.cmd_diagnose import summary_lines

    assert any(
        line.startswith("  steering samples:") and "channel missing (NaN): 250" in line
        for line in summary_lines(dg)
    )
