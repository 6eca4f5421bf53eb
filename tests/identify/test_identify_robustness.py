"""`hmpc identify` on recordings the report's car never produced: a part it cannot identify is
named under ``not_identified:`` with the reason (exit 0 while the other part ran, exit 2 in one
line when neither did), never a traceback, and never a parameter file hmpc would refuse.

The recordings are the simulated arcs (known truth, ``params/report_2008.yaml``) with
channels removed or their sign convention reversed, as a by-wire kit or a ROS car delivers
them: no yaw rate and no wheel speeds (only the position replay), a pedal that reads 1 when
released (or is not a pedal: a speed command), a steering sensor or gyro of the opposite sign.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from hmpc.models.logs.recording import Recording
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import simulate_experiment
from hmpc.tools import cli
from _data import REPORT_PARAMS

SEED = 3
WHEEL_SPEEDS = ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")


@pytest.fixture(scope="module")
def arcs() -> Recording:
    return simulate_experiment("arcs", load_params(REPORT_PARAMS), seed=SEED)


def _variant(rec: Recording, drop=(), **change) -> Recording:
    ch = {k: v for k, v in rec.channels.items() if k not in drop}
    for k, fn in change.items():
        ch[k] = fn(ch)
    return Recording(ch, {}, {"path": "variant.csv"})


def _identify(tmp_path, capsys, rec: Recording, *extra):
    path = tmp_path / "rec.csv"
    rec.save(path)
    geo = tmp_path / "geometry.yaml"
    geo.write_text(yaml.safe_dump({"vehicle": {"wheelbase_m": 2.65, "track_front_m": 1.6}}))
    out = tmp_path / "p.yaml"
    rc = cli.main(["identify", str(path), "--vehicle", str(geo), "--out", str(out), *extra])
    cap = capsys.readouterr()
    return rc, cap, out


def test_only_an_untrusted_replay_is_not_identified_not_a_crash(arcs, tmp_path, capsys):
    """Neither yaw rate nor wheel speeds: only the position replay can run, and with its
    reference point not separable (forced here by a zero lever-arm tolerance) it is never
    chosen. Steering is not identified with the reason; the pedals still give eq. 8."""
    rec = _variant(arcs, drop=("yaw_rate",) + WHEEL_SPEEDS)
    rc, cap, out = _identify(tmp_path, capsys, rec, "--steering-threshold", "max_lever_arm_ci_m=0")
    assert rc == 0, cap.err
    assert "Traceback" not in cap.err
    p = load_params(out)
    assert p.steering is None and p.zones
    why = p.not_identified["steering"]
    assert "no trusted steering fit" in why and "position_replay" in why
    assert "yaw_rate" in why and "wheel_speed_fl" in why  # the methods that could not run


def test_neither_part_is_exit_2_in_one_line(arcs, tmp_path, capsys):
    rec = _variant(arcs, drop=("yaw_rate", "accel_pedal", "brake_pedal") + WHEEL_SPEEDS)
    rc, cap, out = _identify(tmp_path, capsys, rec, "--steering-threshold", "max_lever_arm_ci_m=0")
    errors = [ln for ln in cap.err.splitlines() if "error:" in ln]
    assert rc == 2 and len(errors) == 1 and "Traceback" not in cap.err, cap.err
    err = errors[0]
    assert "nothing could be identified" in err and "steering" in err and "accel_pedal" in err
    assert not out.exists()


def test_replay_only_writes_a_file_the_loader_accepts(arcs, tmp_path, capsys):
    """The replay alone has no measured road-wheel angle, so no rms error: the key is left
    out of the file, never written as NaN (which the loader refuses)."""
    rec = _variant(arcs, drop=("yaw_rate",) + WHEEL_SPEEDS)
    rc, cap, out = _identify(tmp_path, capsys, rec)
    assert rc == 0, cap.err
    p = load_params(out, require_model=True)
    assert p.steering.method == "position_replay" and p.steering.rms_error_rad is None


def test_a_reversed_accelerator_is_never_written_as_a_negative_gain(arcs, tmp_path, capsys):
    """A pedal reading 1 when released gives a negative gain in every zone that exercised
    it: the longitudinal part is not identified, naming the sign convention; no file hmpc
    would refuse is written."""
    rec = _variant(arcs, accel_pedal=lambda ch: 1.0 - ch["accel_pedal"])
    rc, cap, out = _identify(tmp_path, capsys, rec)
    assert rc == 0, cap.err
    p = load_params(out)
    assert not p.zones and p.steering is not None
    why = p.not_identified["longitudinal"]
    assert "negative gain" in why and "sign convention of accel_pedal" in why
    assert "not a pedal" in why


def test_a_negative_gain_in_one_zone_is_copied_and_named(arcs, tmp_path, capsys):
    """The pedal reversed above 5 m/s only: the high zone's gain is set aside with the reason
    and copied from the low zone, which stays as identified."""
    v = arcs["speed"]
    rec = _variant(
        arcs, accel_pedal=lambda ch: np.where(v > 5.0, 1.0 - ch["accel_pedal"], ch["accel_pedal"])
    )
    rc, cap, out = _identify(tmp_path, capsys, rec)
    assert rc == 0, cap.err
    p = load_params(out, require_model=True)
    high = next(z for z in p.zones if z.name == "high")
    low = next(z for z in p.zones if z.name == "low")
    assert high.scale_mps2 == low.scale_mps2 > 0 and high.identifiable is False
    why = p.not_identified["longitudinal.zones.high.scale_mps2"]
    assert "negative gain" in why and "copied from zone 'low'" in why


def test_a_reversed_steering_sensor_is_named(arcs, tmp_path, capsys):
    rec = _variant(arcs, steering_wheel_angle=lambda ch: -ch["steering_wheel_angle"])
    rc, cap, out = _identify(tmp_path, capsys, rec)
    assert rc == 0, cap.err
    p = load_params(out)
    assert p.steering is None
    assert "sign convention of steering_wheel_angle" in p.not_identified["steering"]


def test_a_reversed_gyro_sets_the_yaw_rate_fit_aside(arcs, tmp_path, capsys):
    rec = _variant(arcs, yaw_rate=lambda ch: -ch["yaw_rate"])
    rc, cap, out = _identify(tmp_path, capsys, rec, "--json", str(tmp_path / "r.json"))
    assert rc == 0, cap.err
    p = load_params(out)
    assert p.steering.scale > 0 and p.steering.method != "yaw_rate"
    sel = json.loads((tmp_path / "r.json").read_text())["steering"]["selection"]
    assert "sign convention of yaw_rate" in sel["untrusted"]["yaw_rate"]
