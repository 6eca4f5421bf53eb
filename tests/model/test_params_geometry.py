"""The loader refuses a geometry no road vehicle has (a wheelbase in millimetres) in one line
naming the file, the key and the likely unit; the writer never leaves a file the loader would
refuse (checked before writing, written under a temporary name and renamed)."""

import pytest
import yaml

from hmpc.models.errors import ParamError
from hmpc.models.params import Params, Steering, Vehicle, dump_params, load_params, parse_params
from hmpc.tools import cli


@pytest.mark.parametrize(
    "vehicle,key,unit",
    [
        (
            {"wheelbase_m": 2650, "track_front_m": 1.6},
            "vehicle.wheelbase_m",
            "millimetres (2.65 m)",
        ),
        (
            {"wheelbase_m": 2.65, "track_front_m": 160},
            "vehicle.track_front_m",
            "centimetres (1.6 m)",
        ),
        (
            {"wheelbase_m": 2.65, "track_front_m": 1.6, "track_rear_m": 1600},
            "vehicle.track_rear_m",
            "millimetres (1.6 m)",
        ),
        (
            {"wheelbase_m": 2.65, "track_front_m": 1.6, "wheel_radius_m": 362},
            "vehicle.wheel_radius_m",
            "millimetres (0.362 m)",
        ),
    ],
)
def test_implausible_lengths_name_the_key_and_the_likely_unit(vehicle, key, unit):
    with pytest.raises(ParamError) as ei:
        parse_params({"vehicle": vehicle}, "car.yaml")
    msg = str(ei.value)
    assert ei.value.key == key and "car.yaml" in msg and unit in msg and "\n" not in msg


def test_track_to_wheelbase_ratio_is_checked():
    """Both lengths in range, but in different units: a 2.65 m wheelbase with a 0.16 m track."""
    with pytest.raises(ParamError, match="different units or swapped") as ei:
        parse_params({"vehicle": {"wheelbase_m": 2.65, "track_front_m": 0.16}}, "car.yaml")
    assert ei.value.key == "vehicle.track_front_m"


@pytest.mark.parametrize(
    "vehicle",
    [
        {"wheelbase_m": 0.33, "track_front_m": 0.28},  # a 1:10 model car (F1TENTH)
        {"wheelbase_m": 2.65, "track_front_m": 1.6},  # the report's car
        {"wheelbase_m": 6.5, "track_front_m": 2.05},  # a long bus
    ],
)
def test_real_vehicles_from_1_10_models_to_buses_load(vehicle):
    assert parse_params({"vehicle": vehicle}).vehicle.wheelbase_m == vehicle["wheelbase_m"]


def test_identify_refuses_a_geometry_in_millimetres_in_one_line(tmp_path, capsys):
    geo = tmp_path / "mm.yaml"
    geo.write_text(yaml.safe_dump({"vehicle": {"wheelbase_m": 2650, "track_front_m": 1600}}))
    rec = tmp_path / "rec.csv"
    rec.write_text("time,steering_wheel_angle\n0,0\n0.02,0\n")
    out = tmp_path / "p.yaml"
    rc = cli.main(["identify", str(rec), "--vehicle", str(geo), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "mm.yaml" in err and "wheelbase_m" in err and "millimetres" in err
    assert not out.exists()


def test_dump_refuses_what_the_loader_refuses_and_leaves_nothing(tmp_path):
    """A negative zone gain breaks a loader rule: nothing is written, no temporary file is
    left, and an existing file at the path is untouched."""
    p = parse_params(
        {
            "vehicle": {"wheelbase_m": 2.65, "track_front_m": 1.6},
            "longitudinal": {
                "zones": [
                    {
                        "name": "all",
                        "v_min_mps": 0.0,
                        "v_max_mps": 20.0,
                        "offset_mps2": 0.0,
                        "scale_mps2": 2.0,
                        "brake_scale_mps2": 5.0,
                    }
                ]
            },
        }
    )
    p.zones[0].scale_mps2 = -15.8
    out = tmp_path / "p.yaml"
    with pytest.raises(ParamError, match="not written") as ei:
        dump_params(p, out)
    assert ei.value.key == "longitudinal.zones[0].scale_mps2"
    assert list(tmp_path.iterdir()) == []
    out.write_text("vehicle: {wheelbase_m: 2.65, track_front_m: 1.6}\n")
    with pytest.raises(ParamError):
        dump_params(p, out)
    assert load_params(out).zones == [] and sorted(tmp_path.iterdir()) == [out]


def test_dump_refuses_a_nan_and_a_negative_steering_scale(tmp_path):
    veh = Vehicle(wheelbase_m=2.65, track_front_m=1.6)
    for st, key in (
        (
            Steering(offset_rad=0.0, scale=0.05, rms_error_rad=float("nan")),
            "steering.rms_error_rad",
        ),
        (Steering(offset_rad=0.0, scale=-0.05), "steering.scale"),
    ):
        with pytest.raises(ParamError) as ei:
            dump_params(Params(vehicle=veh, steering=st), tmp_path / "p.yaml")
        assert ei.value.key == key
    assert list(tmp_path.iterdir()) == []
