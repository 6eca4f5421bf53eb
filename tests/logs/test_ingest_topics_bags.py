"""ROS recordings written with the ROS libraries' own writers ingest to the simulator's truth.

A 30 s figure-eight from hmpc's simulator (no sensor noise) is written as a ROS 1 bag
(rosbags.rosbag1.Writer), a ROS 2 bag with sqlite3 and with MCAP storage (rosbags.rosbag2.Writer),
an MCAP file with ROS 2 (CDR) schemas (mcap_ros2.writer.Writer) and an MCAP file with ROS 1
schemas (mcap's writer, ``ros1msg``), each holding the same five topics at their own rates:

- ``/odom`` nav_msgs/Odometry, 50 Hz, stamped in its header 13 ms before it was recorded:
  position (ENU), orientation (yaw = heading, pitch and roll, ROS REP 103 signs), forward speed;
- ``/imu`` sensor_msgs/Imu, 50 Hz: yaw rate, body accelerations;
- ``/cmd_vel`` geometry_msgs/Twist (no header), 10 Hz: the speed, as a command;
- ``/steering`` std_msgs/Float64, 25 Hz: the steering-wheel angle in degrees.

Each is ingested with one topic map (``time: header.stamp`` for ``/odom``) and compared with the
simulator's recording at the grid times.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from _data import REPORT_PARAMS

from hmpc.models.logs.topic_ingest import ingest_topics
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import simulate_experiment

rosbags = pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from rosbags.typesys.store import Nodetype  # noqa: E402

#: the bag's clock: a ROS time in seconds where the drive starts
EPOCH_NS = 1_000_000_000_000
#: /odom's header stamp precedes its record time by this (a recorder's delay) [ns]
RECORD_DELAY_NS = 13_000_000
RATE_HZ = 50.0
SECONDS = 30.0

MAP = {
    "vehicle": "sim",
    "topics": {"/odom": {"time": "header.stamp"}},
    "channels": {
        "speed": {
            "topic": "/odom",
            "field": "twist.twist.linear.x",
            "unit": "m/s",
            "required": True,
        },
        "x": {"topic": "/odom", "field": "pose.pose.position.x", "unit": "m"},
        "y": {"topic": "/odom", "field": "pose.pose.position.y", "unit": "m"},
        "heading": {"topic": "/odom", "field": "pose.pose.orientation", "unit": "quaternion"},
        "pitch": {"topic": "/odom", "field": "pose.pose.orientation", "unit": "quaternion"},
        "roll": {"topic": "/odom", "field": "pose.pose.orientation", "unit": "quaternion"},
        "yaw_rate": {"topic": "/imu", "field": "angular_velocity.z", "unit": "rad/s"},
        "accel_x": {"topic": "/imu", "field": "linear_acceleration.x", "unit": "m/s^2"},
        "accel_y": {"topic": "/imu", "field": "linear_acceleration.y", "unit": "m/s^2"},
        "speed_cmd": {"topic": "/cmd_vel", "field": "linear.x", "unit": "m/s", "resample": "hold"},
        "steering_wheel_angle": {"topic": "/steering", "field": "data", "unit": "deg"},
    },
}
TYPES = {
    "/odom": "nav_msgs/msg/Odometry",
    "/imu": "sensor_msgs/msg/Imu",
    "/cmd_vel": "geometry_msgs/msg/Twist",
    "/steering": "std_msgs/msg/Float64",
}
#: every how many simulator samples a topic is published
EVERY = {"/odom": 1, "/imu": 1, "/cmd_vel": 5, "/steering": 2}


@pytest.fixture(scope="module")
def truth():
    rec = simulate_experiment(
        "figure8", load_params(REPORT_PARAMS), seed=3, rate_hz=RATE_HZ, noise="none"
    )
    n = int(SECONDS * RATE_HZ)
    return {k: np.asarray(v[:n]) for k, v in rec.channels.items() if k != "gear"}


def _quaternion(roll, pitch_noseup, yaw):
    """ZYX quaternion (x, y, z, w) with ROS signs: the rotation about y is nose-down."""
    r, p, y = roll / 2, -pitch_noseup / 2, yaw / 2
    cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def _make(ts, typename: str, values: dict):
    """A rosbags message of ``typename`` with ``values`` (nested dicts), zeros elsewhere."""
    _, fields = ts.fielddefs[typename]
    kw = {}
    for name, (ntype, detail) in fields:
        v = values.get(name)
        if ntype == Nodetype.NAME:
            kw[name] = _make(ts, detail, v or {})
        elif ntype == Nodetype.BASE:
            kw[name] = (
                ""
                if detail[0] == "string"
                else type(0.0 if detail[0].startswith("float") else 0)(v or 0)
            )
        elif ntype == Nodetype.ARRAY:
            kw[name] = np.zeros(detail[1], dtype=np.float64)
        else:
            kw[name] = np.zeros(0, dtype=np.float64)
    return ts.types[typename](**kw)


def _messages(ts, tr):
    """(topic, record time ns, message) for the whole drive, in record-time order."""
    out = []
    for i, t in enumerate(tr["time"]):
        t_ns = EPOCH_NS + int(round(t * 1e9))
        stamp = {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}
        q = _quaternion(tr["roll"][i], tr["pitch"][i], tr["heading"][i])
        out.append(
            (
                "/odom",
                t_ns + RECORD_DELAY_NS,
                _make(
                    ts,
                    TYPES["/odom"],
                    {
                        "header": {"stamp": stamp},
                        "pose": {
                            "pose": {
                                "position": {"x": tr["x"][i], "y": tr["y"][i]},
                                "orientation": dict(zip("xyzw", q)),
                            }
                        },
                        "twist": {"twist": {"linear": {"x": tr["speed"][i]}}},
                    },
                ),
            )
        )
        out.append(
            (
                "/imu",
                t_ns,
                _make(
                    ts,
                    TYPES["/imu"],
                    {
                        "header": {"stamp": stamp},
                        "orientation": {"w": 1.0},
                        "angular_velocity": {"z": tr["yaw_rate"][i]},
                        "linear_acceleration": {"x": tr["accel_x"][i], "y": tr["accel_y"][i]},
                    },
                ),
            )
        )
        if i % EVERY["/cmd_vel"] == 0:  # 1 ms before its grid tick: the hold is unambiguous
            out.append(
                (
                    "/cmd_vel",
                    t_ns - 1_000_000,
                    _make(ts, TYPES["/cmd_vel"], {"linear": {"x": tr["speed"][i]}}),
                )
            )
        if i % EVERY["/steering"] == 0:
            out.append(
                (
                    "/steering",
                    t_ns,
                    _make(
                        ts,
                        TYPES["/steering"],
                        {"data": math.degrees(tr["steering_wheel_angle"][i])},
                    ),
                )
            )
    return sorted(out, key=lambda m: m[1])


def _write_ros1_bag(path, tr):
    from rosbags.rosbag1 import Writer

    ts = get_typestore(Stores.ROS1_NOETIC)
    path = path / "drive.bag"
    with Writer(path) as w:
        conns = {t: w.add_connection(t, ty, typestore=ts) for t, ty in TYPES.items()}
        for topic, t_ns, msg in _messages(ts, tr):
            w.write(conns[topic], t_ns, ts.serialize_ros1(msg, TYPES[topic]))
    return path


def _write_ros2_bag(path, tr, storage):
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = path / f"drive_{storage}"
    with Writer(path, version=9, storage_plugin=getattr(StoragePlugin, storage.upper())) as w:
        conns = {t: w.add_connection(t, ty, typestore=ts) for t, ty in TYPES.items()}
        for topic, t_ns, msg in _messages(ts, tr):
            w.write(conns[topic], t_ns, ts.serialize_cdr(msg, TYPES[topic]))
    return path


def _write_mcap_ros2(path, tr):
    from mcap_ros2.writer import Writer

    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = path / "drive_ros2.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        schemas = {
            t: w.register_msgdef(ty, ts.generate_msgdef(ty, ros_version=2)[0])
            for t, ty in TYPES.items()
        }
        for topic, t_ns, msg in _messages(ts, tr):
            w.write_message(topic, schemas[topic], _as_dict(msg), log_time=t_ns, publish_time=t_ns)
        w.finish()
    return path


def _as_dict(msg):
    """A rosbags message as the nested dicts and lists mcap_ros2's writer encodes."""
    if hasattr(msg, "__dataclass_fields__"):
        return {
            k: _as_dict(getattr(msg, k)) for k in msg.__dataclass_fields__ if not k.startswith("_")
        }
    return msg.tolist() if isinstance(msg, np.ndarray) else msg


def _write_mcap_ros1(path, tr):
    from mcap.writer import Writer

    ts = get_typestore(Stores.ROS1_NOETIC)
    path = path / "drive_ros1.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros1", library="hmpc tests")
        chans = {}
        for t, ty in TYPES.items():
            name = ty.replace("/msg/", "/")
            sid = w.register_schema(
                name=name,
                encoding="ros1msg",
                data=ts.generate_msgdef(ty, ros_version=1)[0].encode(),
            )
            chans[t] = w.register_channel(topic=t, message_encoding="ros1", schema_id=sid)
        for topic, t_ns, msg in _messages(ts, tr):
            w.add_message(
                channel_id=chans[topic],
                log_time=t_ns,
                publish_time=t_ns,
                data=ts.serialize_ros1(msg, TYPES[topic]),
            )
        w.finish()
    return path


WRITERS = {
    "ros1_bag": _write_ros1_bag,
    "ros2_bag_sqlite3": lambda p, tr: _write_ros2_bag(p, tr, "sqlite3"),
    "ros2_bag_mcap": lambda p, tr: _write_ros2_bag(p, tr, "mcap"),
    "mcap_ros2": _write_mcap_ros2,
    "mcap_ros1": _write_mcap_ros1,
}
KINDS = {
    "ros1_bag": "ros1 bag",
    "ros2_bag_sqlite3": "ros2 bag",
    "ros2_bag_mcap": "ros2 bag",
    "mcap_ros2": "mcap",
    "mcap_ros1": "mcap",
}


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_written_recording_ingests_to_the_truth(fmt, truth, tmp_path):
    bag = WRITERS[fmt](tmp_path, truth)
    tmap = tmp_path / "sim.topics.yaml"
    tmap.write_text(yaml.safe_dump(MAP))
    res = ingest_topics(bag, tmap, rate_hz=RATE_HZ)
    rec, s = res.recording, res.summary
    assert s["log_format"] == KINDS[fmt] and res.problems.total() == 0
    t_rel = rec.time - EPOCH_NS * 1e-9
    # the grid starts at /odom's first header stamp (speed is required), not its record time
    assert t_rel[0] == pytest.approx(truth["time"][0], abs=1e-9)
    n = len(rec)
    assert n == len(truth["time"])
    assert np.allclose(t_rel, truth["time"], atol=1e-6)
    for ch in ("speed", "yaw_rate", "accel_x", "accel_y"):
        assert np.allclose(rec[ch], truth[ch], atol=1e-9, equal_nan=False), ch
    for ch in ("x", "y"):  # relative to the first fix, local frame
        assert np.allclose(rec[ch], truth[ch] - truth[ch][0], atol=1e-9), ch
    for ch in ("heading", "pitch", "roll"):
        d = np.angle(np.exp(1j * (rec[ch] - truth[ch])))
        assert np.max(np.abs(d)) < 1e-9, ch
    # 25 Hz steering in degrees: exact on its samples, interpolated between them
    sw = rec["steering_wheel_angle"]
    tsw = truth["steering_wheel_angle"]
    assert np.allclose(sw[::2], tsw[::2], atol=1e-12)
    mid = np.arange(1, n - 1, 2)
    assert np.allclose(sw[mid], (tsw[mid - 1] + tsw[mid + 1]) / 2, atol=1e-12)
    assert math.isnan(sw[-1]) == ((n - 1) % 2 == 1)  # no extrapolation past the last sample
    # 10 Hz command, held: each grid row holds the latest command at or before it, up to the
    # last command's time (never past it: the last command, 1 ms before row `last`, ends it)
    k = EVERY["/cmd_vel"]
    last = (n - 1) // k * k
    held = truth["speed"][(np.arange(last) // k) * k]
    assert np.array_equal(rec["speed_cmd"][:last], held)
    assert np.all(np.isnan(rec["speed_cmd"][last:]))
    assert s["topics"]["/odom"]["time"] == "header.stamp"
    assert s["topics"]["/imu"]["time"] == "log time"
    assert s["position_origin"]["frame"] == "local"
