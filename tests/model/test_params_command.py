"""The parameter-file keys of command-driven cars (docs/conventions.md, parameter files):
``steering.input``, ``longitudinal.input`` and the command zone gains, accepted, refused with the
key named, and refused by tools that need the pedal model."""

from __future__ import annotations

import copy

import pytest

from hmpc.models.errors import ParamError
from hmpc.models.params import dump_params, load_params, parse_params

GOOD = {
    "vehicle": {"wheelbase_m": 0.33, "track_front_m": 0.28},
    "steering": {"offset_rad": 0.001, "scale": 0.9, "input": "steering_cmd"},
    "longitudinal": {
        "input": "speed_cmd",
        "dead_time_s": 0.1,
        "zones": [
            {
                "name": "idle",
                "v_min_mps": 0.0,
                "v_max_mps": 0.71,
                "offset_mps2": 0.1,
                "speed_cmd_gain_ps": 1.5,
                "identifiable": False,
            },
            {
                "name": "low",
                "v_min_mps": 0.71,
                "v_max_mps": 1.8,
                "offset_mps2": 0.2,
                "speed_cmd_gain_ps": 1.2,
                "speed_cmd_gain_ci95_ps": [0.9, 1.5],
            },
            {
                "name": "high",
                "v_min_mps": 1.8,
                "v_max_mps": 7.1,
                "offset_mps2": 0.3,
                "speed_cmd_gain_ps": 1.0,
            },
        ],
    },
    "not_identified": {"longitudinal.zones.idle.speed_cmd_gain_ps": "copied from zone 'low'"},
}


def test_a_command_model_loads_and_round_trips(tmp_path):
    p = parse_params(copy.deepcopy(GOOD))
    assert p.command_input == "speed_cmd" and not p.zones
    assert [z.speed_cmd_gain_ps for z in p.command_zones] == [1.5, 1.2, 1.0]
    assert p.command_zones[1].speed_cmd_gain_ci95_ps == (0.9, 1.5)
    assert p.steering.input == "steering_cmd"
    dump_params(p, tmp_path / "p.yaml")
    q = load_params(tmp_path / "p.yaml")
    assert q.to_dict() == p.to_dict()


def test_an_accel_cmd_model_loads():
    d = copy.deepcopy(GOOD)
    d["longitudinal"]["input"] = "accel_cmd"
    del d["not_identified"]
    for z in d["longitudinal"]["zones"]:
        z["accel_cmd_gain"] = z.pop("speed_cmd_gain_ps")
        z.pop("speed_cmd_gain_ci95_ps", None)
    p = parse_params(d)
    assert p.command_input == "accel_cmd" and p.command_zones[0].accel_cmd_gain == 1.5


@pytest.mark.parametrize(
    "edit, key",
    [
        (
            lambda d: d["longitudinal"]["zones"][1].update(speed_cmd_gain_ps=-0.2),
            "longitudinal.zones[1].speed_cmd_gain_ps",
        ),
        (
            lambda d: d["longitudinal"]["zones"][2].pop("speed_cmd_gain_ps"),
            "longitudinal.zones[2].speed_cmd_gain_ps",
        ),
        (
            lambda d: d["longitudinal"]["zones"][0].update(accel_cmd_gain=1.0),
            "longitudinal.zones[0].accel_cmd_gain",
        ),
        (lambda d: d["longitudinal"].pop("input"), "longitudinal.zones[0].speed_cmd_gain_ps"),
        (lambda d: d["longitudinal"].update(input="throttle"), "longitudinal.input"),
        (lambda d: d["steering"].update(input="steering_wheel"), "steering.input"),
        (
            lambda d: d["longitudinal"]["zones"][0].update(speed_cmd_gain=1.0),
            "longitudinal.zones[0].speed_cmd_gain",
        ),
    ],
)
def test_a_broken_command_model_is_refused_naming_the_key(edit, key):
    d = copy.deepcopy(GOOD)
    edit(d)
    with pytest.raises(ParamError) as ei:
        parse_params(d, "p.yaml")
    assert f"key '{key}'" in str(ei.value)


def test_the_missing_unit_is_named():
    d = copy.deepcopy(GOOD)
    d["longitudinal"]["zones"][0]["speed_cmd_gain"] = d["longitudinal"]["zones"][0].pop(
        "speed_cmd_gain_ps"
    )
    with pytest.raises(ParamError, match="no unit suffix.*speed_cmd_gain_ps"):
        parse_params(d, "p.yaml")


def test_tools_that_need_the_pedal_model_refuse_it_in_one_line():
    with pytest.raises(ParamError) as ei:
        parse_params(copy.deepcopy(GOOD), "p.yaml", require_model=True)
    msg = str(ei.value)
    assert "\n" not in msg
    assert "key 'longitudinal.zones[0].speed_cmd_gain_ps'" in msg and "pedal model" in msg
