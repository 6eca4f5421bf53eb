"""Steering thresholds fit the vehicle: scaled down from the passenger car's for a smaller one
(equal Froude number), settable one by one on the command line, and every sample they drop
counted by reason in the JSON and the terminal.

The small vehicle is a 1:10 model car (F1TENTH: wheelbase 0.33 m, track 0.28 m, the "steering
wheel" is the servo's road-wheel angle, so the scale is ~1) slaloming at 0.8-2.5 m/s, written
by hand from the kinematic bicycle: the passenger car's 1.5 m/s and 1.5 rad/s would drop most
of it for no physical reason.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from hmpc.models.errors import InputError
from hmpc.models.identify.steering import SteeringIdConfig, identify_steering
from hmpc.models.logs.recording import Recording
from hmpc.models.params import Vehicle
from hmpc.models.sim.sensors import wheel_speeds
from hmpc.tools import cli

SMALL = Vehicle(wheelbase_m=0.33, track_front_m=0.28)
OFFSET_RAD, SCALE = 0.01, 1.0


def model_car_slalom(seed: int = 1) -> Recording:
    """25 s at 50 Hz: speed 0.8 -> 2.5 m/s, a 0.8 Hz slalom of +-0.3 rad (servo rate up to
    1.5 rad/s), gyro noise 0.01 rad/s, wheel speeds with 0.005 m/s noise (encoders)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 25.0, 0.02)
    v = 0.8 + 1.7 * t / 25.0
    sw = 0.3 * np.sin(2 * np.pi * 0.8 * t) + 0.05 * np.sin(2 * np.pi * 0.23 * t)
    delta = OFFSET_RAD + SCALE * sw
    b, tr = SMALL.wheelbase_m, SMALL.track_front_m
    yaw = v * np.sin(delta) / b + rng.normal(0.0, 0.01, len(t))
    ws = [w + rng.normal(0.0, 0.005, len(t)) for w in wheel_speeds(v, delta, b, tr, tr)]
    return Recording(
        {
            "time": t,
            "steering_wheel_angle": sw,
            "wheel_speed_fl": ws[0],
            "wheel_speed_fr": ws[1],
            "wheel_speed_rl": ws[2],
            "wheel_speed_rr": ws[3],
            "yaw_rate": yaw,
        },
        {},
        {"path": "model_car.csv"},
    )


def test_thresholds_scale_with_a_smaller_wheelbase_only():
    small = SteeringIdConfig.for_vehicle(SMALL)
    f = 0.33 / 2.65
    ref = SteeringIdConfig()
    assert small.v_min_mps == pytest.approx(ref.v_min_mps * math.sqrt(f))
    assert small.kinematic_speed_mps == pytest.approx(ref.kinematic_speed_mps * math.sqrt(f))
    assert small.sw_rate_max_radps == pytest.approx(ref.sw_rate_max_radps / math.sqrt(f))
    assert small.max_lever_arm_ci_m == pytest.approx(ref.max_lever_arm_ci_m * f)
    assert small.lat_accel_max_mps2 == ref.lat_accel_max_mps2  # friction: the same at any size
    for b in (2.65, 6.0):  # the passenger car and anything longer keep the defaults
        assert SteeringIdConfig.for_vehicle(Vehicle(wheelbase_m=b, track_front_m=1.6)) == ref
    assert SteeringIdConfig.for_vehicle(SMALL, v_min_mps=0.2).v_min_mps == 0.2
    with pytest.raises(ValueError, match="unknown steering threshold"):
        SteeringIdConfig.for_vehicle(SMALL, v_min=0.2)


def test_a_model_car_keeps_its_samples_and_the_drops_are_counted():
    rec = model_car_slalom()
    res = identify_steering(rec, SMALL)
    smp = res.report["samples"]
    # the passenger car's thresholds drop most of the drive (measured 37% kept, 79% with
    # the scaled ones: the rest is lateral acceleration beyond 4 m/s^2 and its guard)
    passenger = identify_steering(rec, SMALL, SteeringIdConfig())
    kept, kept_passenger = (r.report["samples"]["trustworthy"] / len(rec) for r in (res, passenger))
    assert kept > 0.75 and kept_passenger < 0.5, (kept, kept_passenger)
    assert abs(res.scale / SCALE - 1) < 0.02 and abs(res.offset_rad - OFFSET_RAD) < 0.005
    # every sample not trusted is counted under one reason, with its threshold
    dropped = {d["reason"]: d for d in passenger.report["samples"]["dropped"]}
    assert (
        sum(d["samples"] for d in dropped.values())
        == len(rec) - passenger.report["samples"]["trustworthy"]
    )
    assert dropped["slow"]["threshold"] == 1.5 and "slower than 1.5 m/s" in dropped["slow"]["text"]
    assert sum(d["samples"] for d in smp["dropped"]) == len(rec) - smp["trustworthy"]
    assert res.report["thresholds_size_factor"] == pytest.approx(0.33 / 2.65)


def test_too_few_samples_says_why_each_was_dropped():
    rec = model_car_slalom()
    with pytest.raises(InputError) as ei:
        identify_steering(rec, SMALL, SteeringIdConfig(v_min_mps=3.0))
    msg = str(ei.value)
    assert "slower than 3 m/s" in msg and "--steering-threshold" in msg


def test_the_cli_sets_a_threshold_and_prints_the_drops(tmp_path, capsys):
    path = tmp_path / "rec.csv"
    model_car_slalom().save(path)
    geo = tmp_path / "g.yaml"
    geo.write_text(yaml.safe_dump({"vehicle": {"wheelbase_m": 0.33, "track_front_m": 0.28}}))
    out, js = tmp_path / "p.yaml", tmp_path / "r.json"
    rc = cli.main(
        [
            "identify",
            str(path),
            "--vehicle",
            str(geo),
            "--out",
            str(out),
            "--json",
            str(js),
            "--steering-threshold",
            "v_min_mps=1.0",
            "--steering-threshold",
            "cv_folds=4",
        ]
    )
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rep = json.loads(js.read_text())["steering"]
    assert rep["thresholds"]["v_min_mps"] == 1.0 and rep["thresholds"]["cv_folds"] == 4
    assert rep["thresholds"]["sw_rate_max_radps"] > 1.5  # the others stay scaled
    slow = next(d for d in rep["samples"]["dropped"] if d["reason"] == "slow")
    assert f"{slow['samples']} slower than 1 m/s" in cap.out
    with pytest.raises(SystemExit) as ei:  # argparse: usage and one error line, exit 2
        cli.main(
            [
                "identify",
                str(path),
                "--vehicle",
                str(geo),
                "--out",
                str(out),
                "--steering-threshold",
                "v_min=1.0",
            ]
        )
    err = capsys.readouterr().err
    assert ei.value.code == 2 and "v_min_mps" in err and "Traceback" not in err
