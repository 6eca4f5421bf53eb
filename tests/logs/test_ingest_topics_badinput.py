"""Bad ROS recordings and topic maps: exit 2 with one line naming the file and the topic/field
(or the map's line and key), never a traceback; recoverable rows are skipped and counted.

Also the geometry the topic ingest relies on: the UTM inverse against published conversions and
local ENU from the UTM grid, and quaternion angles with ISO 8855 signs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from hmpc.models.errors import InputError, ParamError
from hmpc.models.logs.topic_ingest import ingest_topics, quaternion_angles
from hmpc.models.logs.topicmap import load_topic_map
from hmpc.models.logs.utm import UtmZone, grid_to_local, parse_zone, utm_to_geodetic
from hmpc.tools import cli

MAP = {
    "vehicle": "toy",
    "channels": {
        "speed": {"topic": "/car/vel", "field": "linear.x", "unit": "m/s"},
        "speed_cmd": {"topic": "/car/cmd", "field": "linear.x", "unit": "km/h"},
    },
}


def _export(folder, rows=40, bad_rows=()):
    """A bagpy-style export: /car/vel and /car/cmd at 20 Hz."""
    folder.mkdir(exist_ok=True)
    for name, scale in (("car-vel.csv", 1.0), ("car-cmd.csv", 3.6)):
        lines = ["Time,linear.x,linear.y,angular.z"]
        for i in range(rows):
            v = "oops" if i in bad_rows else f"{scale * 0.1 * i:.3f}"
            lines.append(f"{1464818234.0 + 0.05 * i:.4f},{v},0.0,0.0")
        (folder / name).write_text("\n".join(lines) + "\n")
    return folder


def _map(tmp_path, data=None, text=None):
    path = tmp_path / "toy.topics.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(data or MAP, sort_keys=False))
    return path


def cli_error(argv, capsys) -> tuple[int, str]:
    """Exit status and the one error line of ``hmpc ARGV`` (no traceback, exactly one line)."""
    rc = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1, err
    return rc, lines[0]


def test_toy_export_ingests(tmp_path):
    res = ingest_topics(_export(tmp_path / "rec"), _map(tmp_path), rate_hz=20)
    rec = res.recording
    assert np.allclose(rec["speed_cmd"], rec["speed"], atol=1e-9)  # km/h converted
    assert res.summary["log_format"] == "csv export" and res.problems.total() == 0


def test_unknown_topic_names_folder_and_topic(tmp_path, capsys):
    data = yaml.safe_load(yaml.safe_dump(MAP))
    data["channels"]["speed"]["topic"] = "/car/velocity"
    rc, line = cli_error(
        [
            "ingest",
            _export(tmp_path / "rec"),
            "--topics",
            _map(tmp_path, data),
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "rec" in line and "topic '/car/velocity'" in line
    assert "car-velocity.csv" in line and not (tmp_path / "r.csv").exists()


def test_missing_field_names_file_topic_and_field(tmp_path, capsys):
    data = yaml.safe_load(yaml.safe_dump(MAP))
    data["channels"]["speed"]["field"] = "twist.linear.x"
    rc, line = cli_error(
        [
            "ingest",
            _export(tmp_path / "rec"),
            "--topics",
            _map(tmp_path, data),
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "car-vel.csv" in line
    assert "topic '/car/vel'" in line and "field 'twist.linear.x'" in line


@pytest.mark.parametrize(
    "entry, key, why",
    [
        ({"unit": "furlong/fortnight"}, "channels.speed.unit", "unknown unit"),
        ({"unit": "deg"}, "channels.speed.unit", "converts to rad"),
        ({"unit": "quaternion"}, "channels.speed.unit", "quaternion makes only"),
        ({"scale": 0}, "channels.speed.scale", "non-zero"),
        ({"colour": "red"}, "channels.speed.colour", "unknown key"),
        ({"resample": "cubic"}, "channels.speed.resample", "resample must be"),
    ],
)
def test_bad_map_entry_names_map_line_and_key(entry, key, why, tmp_path, capsys):
    data = yaml.safe_load(yaml.safe_dump(MAP))
    data["channels"]["speed"].update(entry)
    path = _map(tmp_path, data)
    rc, line = cli_error(
        ["ingest", _export(tmp_path / "rec"), "--topics", path, "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and f"{path}:" in line and f"key '{key}'" in line and why in line


@pytest.mark.parametrize(
    "text, key",
    [
        ("channels: {speed: {topic: a, field: b, unit: m/s}}\nvehicles: x\n", "vehicles"),
        ("channels: {sped: {topic: a, field: b, unit: m/s}}\n", "channels.sped"),
        ("channels: {speed: {topic: a, unit: m/s}}\n", "channels.speed.field"),
        ("channels: {gear: {topic: a, field: b, unit: m/s}}\n", "channels.gear"),
        ("channels: {x: {topic: a, field: b, unit: m}}\n", "channels.x"),
        (
            "channels: {x: {topic: a, field: b, unit: m}, y: {topic: c, field: d, unit: m}}\n",
            "channels.y.topic",
        ),
        (
            "topics: {a: {frame: utm 61N}}\nchannels: {speed: {topic: a, field: b, unit: m/s}}\n",
            "topics.a.frame",
        ),
        (
            "topics: {a: {time: [s]}}\nchannels: {speed: {topic: a, field: b, unit: m/s}}\n",
            "topics.a.time",
        ),
        (
            "topics: {a: {file: x/y.csv}}\nchannels: {speed: {topic: a, field: b, unit: m/s}}\n",
            "topics.a.file",
        ),
    ],
)
def test_map_is_validated_strictly(text, key, tmp_path):
    with pytest.raises(ParamError) as err:
        load_topic_map(_map(tmp_path, text=text))
    assert f"key '{key}'" in err.value.one_line()


def test_one_malformed_row_is_skipped_counted_and_reported(tmp_path, capsys):
    rc = cli.main(
        [
            "ingest",
            str(_export(tmp_path / "rec", bad_rows=(7,))),
            "--topics",
            str(_map(tmp_path)),
            "--out",
            str(tmp_path / "r.csv"),
            "--rate",
            "20",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err
    # reported with the file, the line (row 7 is line 9) and the topic and field
    assert "car-vel.csv" in err and "9" in err and "topic '/car/vel'" in err
    assert "field 'linear.x' value 'oops' is not a number" in err


def test_mostly_malformed_file_is_refused(tmp_path, capsys):
    rc, line = cli_error(
        [
            "ingest",
            _export(tmp_path / "rec", bad_rows=range(5, 40)),
            "--topics",
            _map(tmp_path),
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "car-vel.csv:7:" in line and "topic '/car/vel'" in line
    assert "35 of 40 rows are malformed" in line and "field 'linear.x'" in line


def test_row_with_too_many_cells_is_malformed(tmp_path):
    folder = _export(tmp_path / "rec")
    with open(folder / "car-vel.csv", "a") as fh:
        fh.write("1464818236.0,1,2,3,4\n")
    res = ingest_topics(folder, _map(tmp_path), rate_hz=20)
    [p] = list(res.problems)
    assert p.count == 1 and p.first == [42] and "5 cells, header has 4" in p.detail


def test_no_time_column_names_the_topic_and_the_key(tmp_path, capsys):
    folder = _export(tmp_path / "rec")
    text = (folder / "car-vel.csv").read_text().replace("Time,", "stamp,", 1)
    (folder / "car-vel.csv").write_text(text)
    rc, line = cli_error(
        ["ingest", folder, "--topics", _map(tmp_path), "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and "car-vel.csv" in line and "topics./car/vel.time" in line


def test_required_channel_without_value(tmp_path, capsys):
    data = yaml.safe_load(yaml.safe_dump(MAP))
    data["channels"]["yaw_rate"] = {
        "topic": "/car/vel",
        "field": "angular.z",
        "unit": "rad/s",
        "required": True,
    }
    folder = _export(tmp_path / "rec")
    text = (folder / "car-vel.csv").read_text().replace(",0.0\n", ",nan\n")
    (folder / "car-vel.csv").write_text(text)
    rc, line = cli_error(
        ["ingest", folder, "--topics", _map(tmp_path, data), "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and "channel 'yaw_rate'" in line and "field 'angular.z'" in line


def test_optional_channel_without_value_is_absent_not_zero(tmp_path):
    data = yaml.safe_load(yaml.safe_dump(MAP))
    data["channels"]["yaw_rate"] = {"topic": "/car/vel", "field": "angular.z", "unit": "rad/s"}
    folder = _export(tmp_path / "rec")
    text = (folder / "car-vel.csv").read_text().replace(",0.0\n", ",\n")
    (folder / "car-vel.csv").write_text(text)
    res = ingest_topics(folder, _map(tmp_path, data), rate_hz=20)
    assert "yaw_rate" not in res.recording and res.summary["channels_absent"] == ["yaw_rate"]


def test_can_options_are_refused_with_topics(tmp_path, capsys):
    rc, line = cli_error(
        [
            "ingest",
            _export(tmp_path / "rec"),
            "--topics",
            _map(tmp_path),
            "--nav",
            tmp_path / "nav.csv",
            "--out",
            tmp_path / "r.csv",
        ],
        capsys,
    )
    assert rc == 2 and "--nav applies to CAN logs" in line


def test_can_log_without_dbc_or_topics(tmp_path, capsys):
    log = tmp_path / "x.log"
    log.write_text("(1.0) can0 123#00\n")
    rc, line = cli_error(["ingest", log, "--out", tmp_path / "r.csv"], capsys)
    assert rc == 2 and "--dbc and --signals" in line and "--topics" in line


def test_not_a_bag(tmp_path, capsys):
    bag = tmp_path / "drive.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)))
    rc, line = cli_error(
        ["ingest", bag, "--topics", _map(tmp_path), "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and "drive.bag" in line and "cannot read as a ros1 bag" in line


def _bag(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Twist = ts.types["geometry_msgs/msg/Twist"]
    V3 = ts.types["geometry_msgs/msg/Vector3"]
    path = tmp_path / "t.bag"
    with Writer(path) as w:
        c = w.add_connection("/car/vel", "geometry_msgs/msg/Twist", typestore=ts)
        for i in range(20):
            msg = Twist(V3(0.1 * i, 0.0, 0.0), V3(0.0, 0.0, 0.0))
            w.write(c, 10**18 + i * 50_000_000, ts.serialize_ros1(msg, "geometry_msgs/msg/Twist"))
    return path


def test_bag_unknown_topic_and_missing_field(tmp_path, capsys):
    bag = _bag(tmp_path)
    rc, line = cli_error(
        ["ingest", bag, "--topics", _map(tmp_path), "--out", tmp_path / "r.csv"], capsys
    )  # MAP also reads /car/cmd
    assert rc == 2 and "t.bag" in line and "topic '/car/cmd' is not in the recording" in line
    data = {"channels": {"speed": {"topic": "/car/vel", "field": "linear.q", "unit": "m/s"}}}
    rc, line = cli_error(
        ["ingest", bag, "--topics", _map(tmp_path, data), "--out", tmp_path / "r.csv"], capsys
    )
    assert rc == 2 and "t.bag" in line and "field 'linear.q'" in line
    assert "'q' not among x, y, z" in line
    data["channels"]["speed"]["field"] = "linear"
    with pytest.raises(InputError, match="field 'linear' is not a number"):
        ingest_topics(bag, _map(tmp_path, data))


# ------------------------------------------------------------------ geometry
@pytest.mark.parametrize(
    "en, zone, latlon",
    [
        # published conversions of an independent implementation (the Elixir `utm` package's
        # documented examples, WGS84)
        ((634980.0, 6632172.0), UtmZone(32, True), (59.805241567229885, 11.40618711509996)),
        (
            (391984.4643429378, 6464146.921846279),
            UtmZone(50, False),
            (-31.95351191012423, 115.8570480011093),
        ),
    ],
)
def test_utm_inverse_matches_published_conversions(en, zone, latlon):
    p = utm_to_geodetic(*en, zone)
    assert p.lat_deg == pytest.approx(latlon[0], abs=1e-7)  # about 1 cm
    assert p.lon_deg == pytest.approx(latlon[1], abs=1e-7)


@pytest.mark.parametrize("d_e, d_n", [(100.0, 0.0), (0.0, 100.0), (-70.0, 70.0), (800.0, -600.0)])
def test_utm_local_frame_is_true_distance_and_bearing(d_e, d_n):
    """A grid offset becomes local ENU whose length is the grid length over the point scale
    (0.9996 near the central meridian, within 0.05 %) and whose bearing is the grid bearing
    turned by the convergence at the fix (within 0.01 deg)."""
    zone = parse_zone("utm 12N")
    e0, n0 = 505759.7077873536, 3564595.323613051  # the CAT Vehicle's first fix
    o = utm_to_geodetic(e0, n0, zone)
    x, y = grid_to_local(e0 + d_e, n0 + d_n, zone, o)
    assert math.hypot(x, y) == pytest.approx(math.hypot(d_e, d_n) / 0.9996, rel=5e-4)
    grid_bearing = math.atan2(d_e, d_n)
    assert math.atan2(x, y) == pytest.approx(
        grid_bearing + o.convergence_rad, abs=math.radians(0.01)
    )
    # east of zone 12's central meridian (-111 deg) in the north: grid north lies clockwise
    assert 0 < math.degrees(o.convergence_rad) < 0.1


def test_quaternion_angles_iso_signs():
    # yaw 30 deg left, nose up 5 deg, right side down 2 deg, built as ROS (pitch about y-left)
    roll, pitch, yaw = math.radians(2), math.radians(5), math.radians(30)
    r, p, y = roll / 2, -pitch / 2, yaw / 2
    q = (
        math.sin(r) * math.cos(p) * math.cos(y) - math.cos(r) * math.sin(p) * math.sin(y),
        math.cos(r) * math.sin(p) * math.cos(y) + math.sin(r) * math.cos(p) * math.sin(y),
        math.cos(r) * math.cos(p) * math.sin(y) - math.sin(r) * math.sin(p) * math.cos(y),
        math.cos(r) * math.cos(p) * math.cos(y) + math.sin(r) * math.sin(p) * math.sin(y),
    )
    got = quaternion_angles(*(np.array([2 * c]) for c in q))  # not normalised on purpose
    assert np.allclose([g[0] for g in got], [roll, pitch, yaw], atol=1e-12)
    assert np.isnan(quaternion_angles(*(np.zeros(1),) * 4)[2][0])
