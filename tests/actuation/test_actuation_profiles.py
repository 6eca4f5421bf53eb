"""Strict loading of actuation profiles: both shipped profiles load; any unknown key, missing key
or name the DBC lacks is a one-line ParamError naming the file, the line and the key."""

from __future__ import annotations

import shutil

import pytest
import yaml

from _data import PARAMS_DIR
from hmpc.controller.actuation.profiles import load_profile
from hmpc.models.errors import InputError, ParamError

TOY = PARAMS_DIR / "toyota_rav4_2017.actuation.yaml"
BW = PARAMS_DIR / "bywire.actuation.yaml"


def test_both_profiles_load():
    t = load_profile(TOY)
    assert t.steering == "torque" and t.commands["steer_torque"].message.frame_id == 0x2E4
    assert t.commands["steer_torque"].counter_modulo == 64
    assert t.commands["accel"].message.frame_id == 0x343 and t.commands["accel"].counter is None
    b = load_profile(BW)
    assert b.steering == "angle" and set(b.commands) == {"steer_angle", "pedals", "heartbeat"}
    assert b.commands["pedals"].scheme == "crc8_j1850"
    assert b.commands["heartbeat"].rate_hz == 10


def _copy(tmp_path, src, edit):
    """A copy of profile ``src`` (with its signal map and DBC) after ``edit(doc)``."""
    doc = yaml.safe_load(src.read_text())
    edit(doc)
    for f in (doc["signals"],):
        shutil.copy(PARAMS_DIR / f, tmp_path / f)
    if (PARAMS_DIR / doc["dbc"]).is_file():
        shutil.copy(PARAMS_DIR / doc["dbc"], tmp_path / doc["dbc"])
    out = tmp_path / src.name
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


@pytest.mark.parametrize(
    "src,edit,key",
    [
        (TOY, lambda d: d.update(colour="red"), "colour"),
        (
            TOY,
            lambda d: d["commands"]["steer_torque"].update(rate=100),
            "commands.steer_torque.rate",
        ),
        (TOY, lambda d: d["commands"]["accel"].pop("rate_hz"), "commands.accel.rate_hz"),
        (TOY, lambda d: d["commands"]["accel"].update(message="NO_SUCH"), "commands.accel.message"),
        (
            TOY,
            lambda d: d["commands"]["steer_torque"]["values"].update(steer_torque="NOPE"),
            "commands.steer_torque.values.steer_torque",
        ),
        (
            TOY,
            lambda d: d["commands"]["steer_torque"].update(counter="STEER_TORQUE_CMD"),
            "commands.steer_torque.counter",
        ),
        (
            TOY,
            lambda d: d["commands"]["accel"]["checksum"].update(scheme="md5"),
            "commands.accel.checksum.scheme",
        ),
        (TOY, lambda d: d["feedback"].pop("eps_torque"), "feedback"),
        (TOY, lambda d: d.update(limits="none"), "limits"),
        (BW, lambda d: d["commands"].pop("heartbeat"), "commands"),
        (
            BW,
            lambda d: d["feedback"]["gas_pressed"].update(actve=[1]),
            "feedback.gas_pressed.actve",
        ),
    ],
)
def test_bad_profile_names_file_and_key(tmp_path, src, edit, key):
    path = _copy(tmp_path, src, edit)
    with pytest.raises(ParamError) as ei:
        load_profile(path)
    msg = str(ei.value)
    assert str(path) in msg and f"key '{key}'" in msg and "\n" not in msg


def test_missing_profile_is_input_error(tmp_path):
    with pytest.raises(InputError, match="no such actuation profile"):
        load_profile(tmp_path / "nope.actuation.yaml")
