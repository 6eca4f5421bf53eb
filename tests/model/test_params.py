"""The strict parameter-file loader: the keys of docs/conventions.md load, typos and unit-less
keys fail loudly, and every shipped file loads as written."""

import pytest
import yaml

from hmpc.models.errors import ParamError
from hmpc.models.params import dump_params, load_params, parse_params
from hmpc.tools import cli
from _data import PARAMS_DIR

MINIMAL = {
    "vehicle": {"wheelbase_m": 2.65, "track_front_m": 1.6},
    "steering": {"offset_rad": 0.017, "scale": 0.08},
    "longitudinal": {
        "zones": [
            {
                "name": "idle",
                "v_min_mps": 0.0,
                "v_max_mps": 2.0,
                "offset_mps2": 0.3,
                "scale_mps2": 2.0,
                "brake_scale_mps2": 4.0,
            },
            {
                "name": "low",
                "v_min_mps": 2.0,
                "v_max_mps": 5.0,
                "offset_mps2": -0.1,
                "scale_mps2": 2.5,
                "brake_scale_mps2": 5.0,
            },
            {
                "name": "high",
                "v_min_mps": 5.0,
                "v_max_mps": 20.0,
                "offset_mps2": -0.2,
                "scale_mps2": 3.0,
                "brake_scale_mps2": 6.0,
            },
        ]
    },
}


def test_minimal_file_is_a_complete_model(tmp_path):
    p = parse_params(MINIMAL, require_model=True)
    assert p.steering.scale == 0.08 and [z.name for z in p.zones] == ["idle", "low", "high"]
    assert p.zone_for(1.0) == 0 and p.zone_for(2.0) == 0 and p.zone_for(2.01) == 1
    assert p.zone_for(25.0) == -1
    out = tmp_path / "p.yaml"
    dump_params(p, out)
    assert yaml.safe_load(out.read_text()) == MINIMAL  # round trip, nothing added


def test_geometry_only_file_is_not_a_model():
    p = parse_params({"vehicle": MINIMAL["vehicle"]})
    assert not p.is_model
    with pytest.raises(ParamError, match="steering"):
        parse_params({"vehicle": MINIMAL["vehicle"]}, "g.yaml", require_model=True)


@pytest.mark.parametrize(
    "section,key,value,match",
    [
        ("vehicle", "wheelbase", 2.65, "no unit suffix.*wheelbase_m"),
        ("vehicle", "wheelbse_m", 2.65, "unknown key.*wheelbase_m"),
        ("steering", "ofset_rad", 0.0, "unknown key"),
        ("steering", "offset", 0.0, "no unit suffix.*offset_rad"),
        ("steering", "scale", "big", "finite number"),
        ("steering", "scale", float("nan"), "finite number"),
    ],
)
def test_bad_keys_are_rejected_by_name(section, key, value, match):
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    data[section][key] = value
    with pytest.raises(ParamError, match=match) as ei:
        parse_params(data, "car.yaml")
    assert "car.yaml" in str(ei.value) and "\n" not in str(ei.value)


def test_zone_errors():
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    data["longitudinal"]["zones"][1]["v_min_mps"] = 2.5
    with pytest.raises(ParamError, match=r"zones\[1\].v_min_mps"):
        parse_params(data, "car.yaml")
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    del data["longitudinal"]["zones"][0]["brake_scale_mps2"]
    with pytest.raises(ParamError, match=r"zones\[0\].brake_scale_mps2"):
        parse_params(data, "car.yaml")
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    data["controls"] = {}
    with pytest.raises(ParamError, match="unknown section"):
        parse_params(data, "car.yaml")


def test_unreadable_files(tmp_path):
    with pytest.raises(ParamError, match="no such file"):
        load_params(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("vehicle: {wheelbase_m: 2.6\n")
    with pytest.raises(ParamError, match="not valid YAML") as ei:
        load_params(bad)
    assert str(bad) in str(ei.value)


# signal maps (*.signals.yaml) are another format, checked by test_signalmap; topic maps
# (*.topics.yaml) and actuation profiles (*.actuation.yaml) are checked below
PARAM_FILES = sorted(
    p
    for p in PARAMS_DIR.glob("*.yaml")
    if not p.name.endswith((".signals.yaml", ".topics.yaml", ".actuation.yaml"))
)
TOPIC_MAPS = sorted(PARAMS_DIR.glob("*.topics.yaml"))
PROFILES = sorted(PARAMS_DIR.glob("*.actuation.yaml"))
#: the files the CLI's examples, the docs and the other tests name: each glob finds at least these
#: (an empty glob would otherwise turn the parametrised tests below into one silent skip)
NAMED = {
    "parameter files": (
        PARAM_FILES,
        {
            "report_2008.yaml",
            "report_2008_weak_zones.yaml",
            "toyota_rav4_2017.yaml",
            "toyota_rav4_2019.yaml",
            "catvehicle.yaml",
            "f1tenth.yaml",
        },
    ),
    "topic maps": (TOPIC_MAPS, {"catvehicle.topics.yaml", "f1tenth_frictionmaps.topics.yaml"}),
    "actuation profiles": (PROFILES, {"toyota_rav4_2017.actuation.yaml", "bywire.actuation.yaml"}),
}
#: values from the files' own sources, not from the files: the report's eq. 7 and zone
#: boundaries (section IV-C, V), opendbc's wheelbase and steering ratio of each RAV4
SOURCE_VALUES = {
    "report_2008.yaml": {
        "wheelbase_m": 2.65,
        "scale": 0.08,
        "offset_rad": 0.017,
        "zones_mps": [(0.0, 2.0), (2.0, 5.0), (5.0, 20.0)],
    },
    "toyota_rav4_2017.yaml": {"wheelbase_m": 2.65, "steering_ratio": 16.88},
    "toyota_rav4_2019.yaml": {"wheelbase_m": 2.69, "steering_ratio": 14.3},
}


def _plain(value):
    """YAML's lists and the loader's tuples compare alike."""
    return tuple(_plain(v) for v in value) if isinstance(value, (list, tuple)) else value


@pytest.mark.parametrize("kind", sorted(NAMED))
def test_the_shipped_files_are_where_the_tests_look(kind):
    found, named = NAMED[kind]
    assert named <= {p.name for p in found}, f"{kind} missing from {PARAMS_DIR}"


@pytest.mark.parametrize("path", PARAM_FILES, ids=lambda p: p.name)
def test_shipped_parameter_files_load_as_written(path):
    """Every value the file states comes out of the strict loader unchanged (the file read
    with plain YAML is the reference), and the values with a published source match it."""
    raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    p = load_params(path)
    for key, value in raw["vehicle"].items():
        assert _plain(getattr(p.vehicle, key)) == _plain(value), f"vehicle.{key}"
    for key, value in (raw.get("steering") or {}).items():
        assert _plain(getattr(p.steering, key)) == _plain(value), f"steering.{key}"
    zones = (raw.get("longitudinal") or {}).get("zones") or []
    assert [z.name for z in p.zones] == [z["name"] for z in zones]
    for zone, rz in zip(p.zones, zones):
        for key, value in rz.items():
            assert _plain(getattr(zone, key)) == _plain(value), f"{zone.name}.{key}"
    known = SOURCE_VALUES.get(path.name, {})
    for key in ("wheelbase_m", "steering_ratio"):
        if key in known:
            assert getattr(p.vehicle, key) == known[key], key
    for key in ("scale", "offset_rad"):
        if key in known:
            assert getattr(p.steering, key) == known[key], key
    if "zones_mps" in known:
        assert [(z.v_min_mps, z.v_max_mps) for z in p.zones] == known["zones_mps"]


@pytest.mark.parametrize("path", TOPIC_MAPS, ids=lambda p: p.name)
def test_shipped_topic_maps_load_as_written(path):
    """Each channel of the map reads the topic, field and unit the file names."""
    from hmpc.models.logs.topicmap import load_topic_map

    raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    tm = load_topic_map(path)
    assert tm.vehicle == raw.get("vehicle")
    assert set(tm.channels) == set(raw["channels"]) and "speed" in tm.channels
    for name, spec in raw["channels"].items():
        ch = tm.channels[name]
        assert (ch.channel, ch.topic, ch.field, ch.unit) == (
            name,
            spec["topic"],
            spec["field"],
            spec["unit"],
        ), name


@pytest.mark.parametrize("path", PROFILES, ids=lambda p: p.name)
def test_shipped_actuation_profiles_load_as_written(path):
    """Each command goes out in the message and at the rate the file names, on its bus."""
    from hmpc.controller.actuation.profiles import load_profile

    raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    prof = load_profile(path)
    assert (prof.name, prof.bus, prof.steering, prof.limits) == (
        raw["profile"],
        raw["bus"],
        raw["steering"],
        raw["limits"],
    )
    assert set(prof.commands) == set(raw["commands"])
    for role, spec in raw["commands"].items():
        cmd = prof.commands[role]
        assert cmd.message.name == spec["message"] and cmd.rate_hz == spec["rate_hz"], role
        assert cmd.values == spec["values"], role


def test_the_toyota_profile_sends_what_openpilot_sends():
    """Frame ids and rates of the bundled comma minute (opendbc's STEERING_LKA 0x2E4 at
    100 Hz, ACC_CONTROL 0x343 every third 100 Hz frame)."""
    from hmpc.controller.actuation.profiles import load_profile

    prof = load_profile(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml")
    steer, accel = prof.commands["steer_torque"], prof.commands["accel"]
    assert (steer.message.frame_id, steer.rate_hz) == (0x2E4, 100)
    assert accel.message.frame_id == 0x343 and accel.rate_hz == pytest.approx(100 / 3, abs=1e-3)


def test_cli_reports_bad_params_in_one_line(tmp_path, capsys):
    bad = tmp_path / "typo.yaml"
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    data["steering"]["scal"] = 0.08
    bad.write_text(yaml.safe_dump(data))
    rc = cli.main(["simulate", "--params", str(bad), "--scenario", "idle_hold"])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and "typo.yaml" in err and "steering.scal" in err


def test_a_part_that_was_not_identified_is_refused_by_simulate_naming_key_and_reason(
    tmp_path, capsys
):
    """identify writes what it could identify and names the rest under not_identified:; a
    tool that needs the absent part refuses the file in one line naming the key."""
    import yaml as _yaml

    src = _yaml.safe_load((PARAMS_DIR / "report_2008.yaml").read_text())
    part = {
        "vehicle": src["vehicle"],
        "steering": src["steering"],
        "not_identified": {"longitudinal": "no accelerator pedal channel ('accel_pedal')"},
    }
    f = tmp_path / "steering_only.yaml"
    f.write_text(_yaml.safe_dump(part))
    p = load_params(f)  # loads: a partial model is a valid file
    assert p.steering is not None and not p.zones
    assert p.not_identified == {"longitudinal": "no accelerator pedal channel ('accel_pedal')"}
    rc = cli.main(["simulate", "--params", str(f), "--scenario", "idle_hold"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert "longitudinal" in err[0] and "accel_pedal" in err[0] and str(f) in err[0]
    # a part may not be both given and listed as not identified
    part["longitudinal"] = src["longitudinal"]
    f.write_text(_yaml.safe_dump(part))
    with pytest.raises(ParamError, match="not_identified.longitudinal"):
        load_params(f)
