"""Signal maps: safe expression parsing, unit conversion, signs, gear tables, strict validation."""

import math
import textwrap

import numpy as np
import pytest
from hypothesis import given, seed, settings, strategies as st

from hmpc.models.logs.dbc import load_dbc
from hmpc.models.errors import ParamError
from hmpc.models.logs.signalmap import UNITS, load_signal_map, parse_expr
from _data import PARAMS_DIR

MAP17 = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
MAP19 = PARAMS_DIR / "toyota_rav4_2019.signals.yaml"


@pytest.fixture(scope="module")
def db17(comma_dbc):
    return load_dbc(comma_dbc)


@pytest.fixture(scope="module")
def db19(vcan_dbc):
    return load_dbc(vcan_dbc)


def write_map(tmp_path, body: str, name="m.signals.yaml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(body))
    return p


# ----------------------------------------------------------------------------- shipped maps
@pytest.mark.parametrize("path,dbname", [(MAP17, "db17"), (MAP19, "db19")])
def test_shipped_maps_load_against_their_dbc(path, dbname, request):
    smap = load_signal_map(path, request.getfixturevalue(dbname))
    for ch in (
        "steering_wheel_angle",
        "wheel_speed_fl",
        "wheel_speed_fr",
        "wheel_speed_rl",
        "wheel_speed_rr",
        "speed",
        "accel_pedal",
        "brake_pedal",
        "gear",
        "engine_rpm",
        "yaw_rate",
        "accel_x",
        "accel_y",
        "accel_cmd",
    ):
        assert ch in smap.channels
    assert set(smap.required()) == {
        "steering_wheel_angle",
        "wheel_speed_fl",
        "wheel_speed_fr",
        "wheel_speed_rl",
        "wheel_speed_rr",
        "speed",
    }
    # speed is the wheel-speed mean (openpilot's vEgoRaw), not the SPEED (speedometer) message
    sp = smap.channels["speed"]
    assert sp.message == "WHEEL_SPEEDS"
    assert set(sp.expr.signals) == {
        "WHEEL_SPEED_FL",
        "WHEEL_SPEED_FR",
        "WHEEL_SPEED_RL",
        "WHEEL_SPEED_RR",
    }
    v = sp.evaluate({s: np.array([36.0, 72.0]) for s in sp.expr.signals})
    np.testing.assert_allclose(v, [10.0, 20.0])
    # steering: 1.5 deg coarse + 0.1 deg fraction, + = left, deg -> rad
    sw = smap.channels["steering_wheel_angle"]
    out = sw.evaluate(
        {"STEER_ANGLE": np.array([-4.5, 3.0]), "STEER_FRACTION": np.array([0.7, -0.3])}
    )
    np.testing.assert_allclose(out, np.radians([-3.8, 2.7]))
    assert smap.buses() == {0}


def test_2017_accelerations_are_sign_flipped_2019_not(db17, db19):
    m17 = load_signal_map(MAP17, db17)
    m19 = load_signal_map(MAP19, db19)
    assert m17.channels["accel_x"].sign == -1 and m19.channels["accel_x"].sign == 1
    np.testing.assert_allclose(
        m17.channels["accel_x"].evaluate({"ACCEL_X": np.array([1.5])}), [-1.5]
    )


def test_gear_table(db17):
    gear = load_signal_map(MAP17, db17).channels["gear"]
    out = gear.evaluate({"GEAR": np.array([0, 32, 16, 8, 1, 5])})
    assert list(out) == ["D", "P", "R", "N", "S", ""]


# ----------------------------------------------------------------------------- expressions
def test_expression_arithmetic_and_precedence():
    a, b, c = np.array([1.0, -2.0]), np.array([4.0, 8.0]), np.array([3.0, 0.5])
    env = {"A": a, "B": b, "C": c}
    cases = {
        "A + B / 2 - -C": a + b / 2 + c,
        "(A + B) * C": (a + b) * c,
        "-A * 2.5e-1": -a * 0.25,
        "abs(A) + max(B, C) - min(B, C)": np.abs(a) + np.maximum(b, c) - np.minimum(b, c),
        "+A": a,
    }
    for text, want in cases.items():
        np.testing.assert_allclose(parse_expr(text, {"A", "B", "C"})(env), want)
    e = parse_expr("B / A", {"A", "B"})
    assert e.signals == ("B", "A")
    with pytest.raises(ValueError, match="reads no signal"):
        parse_expr("7", {"A"})


@pytest.mark.parametrize(
    "text,why",
    [
        ("__import__('os').system('echo no')", "not allowed"),
        ("A.real", "not allowed"),
        ("A[0]", "not allowed"),
        ("A ** 2", "not allowed"),
        ("A if B else C", "not allowed"),
        ("A < B", "not allowed"),
        ("lambda: A", "not allowed"),
        ("'text'", "not a finite number"),
        ("True + A", "not a finite number"),
        ("open('x')", "function 'open' is not allowed"),
        ("abs(A, B)", "takes 1 argument"),
        ("max(A, key=B)", "keyword"),
        ("D + A", "signal 'D' is not in the message"),
        ("A +", "not valid arithmetic"),
        ("", "empty"),
        ("A" + " + A" * 300, "longer than"),
        ("(" * 40 + "A" + ")" * 40 + " + A" * 40, "parts"),
    ],
)
def test_expression_whitelist_rejects(text, why):
    with pytest.raises(ValueError, match=why):
        parse_expr(text, {"A", "B", "C"})


@seed(20240611)
@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="AB()+-*/.,0123456789e_ absmxin'\"[]:;=<>!\\\n\t", max_size=60))
def test_expression_parser_only_raises_valueerror(text):
    """Random text never escapes as anything but ValueError (and never runs code)."""
    try:
        e = parse_expr(text, {"A", "B"})
    except ValueError:
        return
    out = e({"A": np.array([1.0, 2.0]), "B": np.array([0.5, 0.0])})
    assert out.shape == (2,)


# ----------------------------------------------------------------------------- units
@pytest.mark.parametrize(
    "unit,raw,si",
    [
        ("km/h", 36.0, 10.0),
        ("mph", 10.0, 4.4704),
        ("deg", 180.0, math.pi),
        ("deg/s", 90.0, math.pi / 2),
        ("%", 50.0, 0.5),
        ("fraction", 0.25, 0.25),
        ("g", 1.0, 9.80665),
    ],
)
def test_unit_conversion(tmp_path, db17, unit, raw, si):
    channel = {
        "km/h": "wheel_speed_fl",
        "mph": "speed",
        "deg": "steering_wheel_angle",
        "deg/s": "yaw_rate",
        "%": "accel_pedal",
        "fraction": "brake_pedal",
        "g": "accel_x",
    }[unit]
    p = write_map(
        tmp_path,
        f"""
        channels:
          {channel}: {{message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: "{unit}", sign: -1}}
    """,
    )
    cm = load_signal_map(p, db17).channels[channel]
    assert UNITS[unit][0] in ("m/s", "rad", "rad/s", "1", "m/s^2")
    np.testing.assert_allclose(cm.evaluate({"WHEEL_SPEED_FL": np.array([raw])}), [-si])


# ----------------------------------------------------------------------------- strict validation
BAD_MAPS = [
    ("unknown top-level key", "vehicle: x\nchanels: {}\n", "key 'chanels'", 2),
    (
        "unknown channel",
        "channels:\n  steer_angle: {message: STEER_ANGLE_SENSOR, expr: STEER_ANGLE, unit: deg}\n",
        "key 'channels.steer_angle'",
        2,
    ),
    (
        "unknown per-channel key",
        "channels:\n  speed:\n    message: WHEEL_SPEEDS\n    expr: WHEEL_SPEED_FL\n"
        "    unit: km/h\n    scale: 2\n",
        "key 'channels.speed.scale'",
        6,
    ),
    (
        "message not in the DBC",
        "channels:\n  speed: {message: WHEEL_SPEED, expr: WHEEL_SPEED_FL, unit: km/h}\n",
        "key 'channels.speed.message'",
        2,
    ),
    (
        "signal not in the message",
        "channels:\n  speed:\n    message: WHEEL_SPEEDS\n    expr: WHEEL_SPEED_FL + SPEED\n"
        "    unit: km/h\n",
        "signal 'SPEED' is not in the message 'WHEEL_SPEEDS'",
        4,
    ),
    (
        "unknown unit",
        "channels:\n  speed: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: kmhr}\n",
        "unknown unit 'kmhr'",
        2,
    ),
    (
        "unit of the wrong dimension",
        "channels:\n  steering_wheel_angle: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, "
        "unit: km/h}\n",
        "converts to m/s",
        2,
    ),
    (
        "missing unit",
        "channels:\n  speed: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL}\n",
        "key 'channels.speed.unit'",
        2,
    ),
    (
        "bad sign",
        "channels:\n  speed: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: km/h, sign: 2}\n",
        "sign must be 1 or -1",
        2,
    ),
    (
        "bad bus",
        "channels:\n  speed: {message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: km/h, "
        "bus: can0}\n",
        "bus must be",
        2,
    ),
    (
        "bad gear letter",
        "channels:\n  gear:\n    message: GEAR_PACKET\n    expr: GEAR\n    gear: {0: Drive}\n",
        "key 'channels.gear.gear.0'",
        5,
    ),
    (
        "gear without a table",
        "channels:\n  gear: {message: GEAR_PACKET, expr: GEAR}\n",
        "key 'channels.gear.gear'",
        2,
    ),
    (
        "eval attempt",
        "channels:\n  speed: {message: WHEEL_SPEEDS, expr: \"__import__('os')\", unit: km/h}\n",
        "key 'channels.speed.expr'",
        2,
    ),
    ("not YAML", "channels: [\n", "not valid YAML", None),
    ("no channels", "vehicle: x\n", "'channels' section is missing", None),
]


@pytest.mark.parametrize("what,body,needle,line", BAD_MAPS, ids=[b[0] for b in BAD_MAPS])
def test_bad_maps_are_rejected_with_file_line_and_key(tmp_path, db17, what, body, needle, line):
    p = write_map(tmp_path, body)
    with pytest.raises(ParamError) as ei:
        load_signal_map(p, db17)
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith(str(p))
    assert needle in msg
    if line is not None:
        assert msg.startswith(f"{p}:{line}:")


@pytest.mark.parametrize(
    "alias,canonical",
    [
        ("kph", "km/h"),
        ("km/hr", "km/h"),
        ("kmh", "km/h"),
        ("degree", "deg"),
        ("deg/sec", "deg/s"),
        ("m/s2", "m/s^2"),
        ("percent", "%"),
    ],
)
def test_unit_spellings_found_in_field_dbcs_convert_like_their_canonical_unit(alias, canonical):
    """opendbc's DBCs say ``kph``; a map copied from them must load and convert exactly as
    ``km/h`` does, while an unknown spelling stays an error."""
    from hmpc.models.logs.signalmap import UNITS, canonical_unit

    assert canonical_unit(alias) == canonical
    assert UNITS[canonical_unit(alias)] == UNITS[canonical]
    assert canonical_unit("furlong/fortnight") not in UNITS


def test_a_map_written_in_kph_decodes_like_km_h(tmp_path, db17):
    from hmpc.models.logs.signalmap import load_signal_map

    got = {}
    for unit in ("km/h", "kph"):
        p = tmp_path / f"{unit.replace('/', '_')}.yaml"
        p.write_text(
            f"channels:\n  speed: {{message: WHEEL_SPEEDS, expr: WHEEL_SPEED_FL, unit: {unit}}}\n"
        )
        got[unit] = load_signal_map(p, db17).channels["speed"]
    assert got["kph"].factor == pytest.approx(1 / 3.6) == got["km/h"].factor
