"""The operator station: script CSV, built-in experiments, keyboard and gamepad mapping, the
TUI, and ``hmpc operator`` end to end against a real receiver on loopback (real time)."""

from __future__ import annotations

import glob
import json
import os
import struct
import subprocess
import sys
import threading

import numpy as np
import pytest

from hmpc.tools.cmd_operator import experiment_script
from rich.console import Console

from hmpc.controller.teleop import link as L
from hmpc.controller.teleop import operator as op
from hmpc.controller.teleop.sink import PlantSink, serve
from hmpc.controller.teleop.tui import parse_keys, render
from hmpc.models.errors import InputError
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import run_experiment

from _data import REPORT_PARAMS

HMPC = [sys.executable, "-m", "hmpc.tools.cli"]

GOOD = (
    "# comment\n"
    "t_s,mode,dead_man,steering_wheel_angle_rad,accel_pedal,brake_pedal,speed_mps,"
    "curvature_1pm\n"
    "0,engage,1,,,,,\n"
    "0.1,pedals,1,0.5,0.2,0,,\n"
    "1.0,references,1,,,,3.0,0.01\n"
    "2.0,handover_mpc,1,,,,,\n"
    "2.5,disengage,0,,,,,\n"
)


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


# -------------------------------------------------------------------------------- scripts
def test_script_holds_rows_and_ends(tmp_path):
    p = tmp_path / "ops.csv"
    p.write_text(GOOD)
    s = op.load_script(p)
    assert s.command_at(0.0).mode == L.Mode.ENGAGE
    assert s.command_at(0.05).mode == L.Mode.ENGAGE
    assert s.command_at(0.1).values == (0.5, 0.2, 0.0)
    assert s.command_at(0.99).mode == L.Mode.PEDALS
    assert s.command_at(1.5).values == (3.0, 0.01, 0.0)
    last = s.command_at(2.55)
    assert last.mode == L.Mode.DISENGAGE and not last.dead_man
    assert s.command_at(2.5 + op.LAST_ROW_HOLD_S) is None


def test_script_round_trip(tmp_path, params):
    s = experiment_script("ramp_sequence", params, seed=3)
    op.write_script(s, tmp_path / "rs.csv")
    back = op.load_script(tmp_path / "rs.csv")
    assert np.array_equal(back.times_s, s.times_s)
    assert [(c.mode, c.values, c.dead_man) for c in back.commands] == [
        (c.mode, c.values, c.dead_man) for c in s.commands
    ]


@pytest.mark.parametrize(
    "text, match",
    [
        ("t_s,mode\n0,engage\n", "missing column 'dead_man'"),
        ("t_s,mode,dead_man,speed\n0,engage,1,3\n", "unknown column 'speed'"),
        ("t_s,mode,dead_man\n0,engage,1\n0.1,pedals,1\n", ":3: a pedals row needs column"),
        ("t_s,mode,dead_man\n0,engage,1\n0,engage,1\n", ":3: t_s 0 does not increase"),
        ("t_s,mode,dead_man\n0.5,engage,1\n", ":2: the first row must be at t_s 0"),
        ("t_s,mode,dead_man\n0,fly,1\n", ":2: unknown mode 'fly'"),
        ("t_s,mode,dead_man\n0,engage,yes\n", ":2: dead_man must be 0 or 1"),
        (
            "t_s,mode,dead_man,accel_pedal,steering_wheel_angle_rad,brake_pedal\n"
            "0,pedals,1,nan,0,0\n",
            ":2: column 'accel_pedal': 'nan' is not finite",
        ),
        ("t_s,mode,dead_man\n0,engage\n", ":2: 2 cells, the header has 3"),
        ("t_s,mode,dead_man\n", "no rows"),
    ],
)
def test_bad_script_one_line_error_naming_file_and_line(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as exc:
        op.load_script(p)
    assert str(p) in str(exc.value)


def test_experiment_scripts_are_the_simulators_driver_inputs(params):
    """Built-in scripts come from the simulator's plan and driver, not a second copy."""
    s = experiment_script("arcs", params, seed=0)
    run = run_experiment("arcs", params, seed=0, rate_hz=50.0, noise="none")
    pedals = [c for c in s.commands if c.mode == L.Mode.PEDALS]
    assert len(pedals) == len(run.recording.channels["time"])
    sw = np.array([c.values[0] for c in pedals])
    assert np.array_equal(sw, run.truth_on_grid("sw_rad"))
    assert s.commands[0].mode == L.Mode.ENGAGE and s.commands[-1].mode == L.Mode.DISENGAGE
    # arcs steer both ways; ramps barely steer but use both pedals
    assert sw.min() < -4.0 and sw.max() > 4.0
    r = experiment_script("ramps", params, seed=0)
    ap = np.array([c.values[1] for c in r.commands if c.mode == L.Mode.PEDALS])
    bp = np.array([c.values[2] for c in r.commands if c.mode == L.Mode.PEDALS])
    assert ap.max() > 0.2 and bp.max() > 0.2 and not np.any((ap > 0) & (bp > 0))


def test_unknown_experiment(params):
    with pytest.raises(InputError, match="unknown experiment 'loops'"):
        experiment_script("loops", params)


# ------------------------------------------------------------------------------- keyboard
def test_keyboard_mapping_and_dead_man_latch():
    k = op.KeyboardOperator()
    assert not k.command_at(0).dead_man  # not engaged: dead-man released
    k.handle_key("e")
    assert [k.command_at(0).mode for _ in range(3)] == [L.Mode.ENGAGE] * 3
    for key in ["up", "up", "w", "left", "a", "a", "right"]:
        k.handle_key(key)
    c = k.command_at(0)
    assert c.mode == L.Mode.PEDALS and c.dead_man
    assert c.values == pytest.approx((0.2, 0.15, 0.0))
    for _ in range(4):
        k.handle_key("s")  # throttle down first, then brake
    assert (k.accel, k.brake) == pytest.approx((0.0, 0.05))
    k.handle_key(" ")
    c = k.command_at(0)
    assert not c.dead_man and c.values[1:] == (0.0, 0.0)
    assert k.handle_key("z") is None
    k.handle_key("q")
    assert k.command_at(0) is None


def test_parse_keys_arrows_and_escape():
    assert parse_keys(b"\x1b[A\x1bOCwq \x1b") == ["up", "right", "w", "q", " ", "esc"]


def test_gamepad_events_and_absence(tmp_path):
    g = op.GamepadOperator()
    ev = struct.Struct("<IhBB")
    g.handle_event(ev.pack(0, 32767, 0x02, 5))  # right trigger pulled
    g.handle_event(ev.pack(0, 32767, 0x02, 0))  # stick full right
    g.handle_event(ev.pack(0, 1, 0x01, 5))  # dead-man button held
    c = g.command_at(0)
    assert c.dead_man and c.values[1] == 1.0 and c.values[0] < 0
    g.handle_event(ev.pack(0, 0, 0x01, 5))
    assert not g.command_at(0).dead_man
    with pytest.raises(op.NoGamepadError, match="no gamepad found"):
        op.find_gamepad(str(tmp_path / "js*"))


def test_tui_renders_telemetry():
    tel = L.Telemetry(
        seq=1,
        t_send_s=100.0,
        engaged=True,
        mpc_in_control=False,
        link_held=True,
        vehicle=L.VehicleStatus(3.25, 0.5, 1, "low", "throttle"),
        stop=L.StopRequest("link_lost", 99.0, 99.2),
        received=10,
        accepted=9,
        delivered=9,
        ignored=0,
        rejected={r: 0 for r in L.REASONS} | {"bad_mac": 1},
        lost=0,
        latency_p50_ms=0.12,
        latency_p99_ms=0.5,
        max_gap_ms=21.0,
        clock_offset_ms=0.05,
    )
    con = Console(width=140, record=True, color_system=None)
    con.print(
        render(
            1.0,
            L.TeleopCommand.pedals(0.5, 0.2, 0.0),
            tel,
            source="keyboard",
            target="127.0.0.1:47700",
            now_wall_s=100.1,
        )
    )
    out = con.export_text()
    for s in (
        "3.25 m/s",
        "low (1)",
        "throttle",
        "bad_mac",
        "p50 0.12 ms",
        "link_lost",
        "dead-man held",
        "accel 0.20",
    ):
        assert s in out, s


# ------------------------------------------------------------------------------------ CLI
def _key(tmp_path):
    p = tmp_path / "op.key"
    subprocess.run(
        HMPC + ["operator", "--key", str(p), "--make-key"], check=True, capture_output=True
    )
    return p


def test_cli_refuses_loose_key_and_missing_gamepad(tmp_path):
    p = _key(tmp_path)
    os.chmod(p, 0o640)
    r = subprocess.run(
        HMPC + ["operator", "--key", str(p), "--script", "x.csv"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "chmod 600" in r.stderr and len(r.stderr.splitlines()) == 1
    os.chmod(p, 0o600)
    r = subprocess.run(
        HMPC + ["operator", "--key", str(p), "--gamepad"], capture_output=True, text=True
    )
    if not glob.glob("/dev/input/js*"):  # this machine has none: the one-line refusal
        assert (
            r.returncode == 2
            and r.stderr.strip()
            == "hmpc operator: error: no gamepad found (no /dev/input/js* device)"
        )
    r = subprocess.run(
        HMPC + ["operator", "--key", str(p), "--make-key"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "exists already" in r.stderr


def test_cli_script_drives_the_stand_in_over_loopback(tmp_path, params):
    """``hmpc operator --script`` in a subprocess, real time, against a receiver and the plant
    stand-in in this process: the commands arrive, the car moves, telemetry comes back."""
    key_path = _key(tmp_path)
    ops = tmp_path / "ops.csv"
    ops.write_text(
        "t_s,mode,dead_man,steering_wheel_angle_rad,accel_pedal,brake_pedal\n"
        "0,engage,1,,,\n0.1,pedals,1,1.0,0.3,0\n1.1,pedals,1,1.0,0,0.3\n"
        "1.6,disengage,1,,,\n"
    )
    rx = L.LinkReceiver(L.load_key(key_path), ("127.0.0.1", 0))
    sink = PlantSink(params)
    done = threading.Event()
    th = threading.Thread(target=serve, args=(rx, sink), kwargs={"until": done.is_set})
    th.start()
    try:
        out = tmp_path / "run.json"
        r = subprocess.run(
            HMPC
            + [
                "operator",
                "--key",
                str(key_path),
                "--connect",
                f"127.0.0.1:{rx.address[1]}",
                "--script",
                str(ops),
                "--json",
                str(out),
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        done.set()
        th.join()
        rx.close()
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    st = rx.stats()
    assert res["end"] == "source_finished"
    assert st["rejected_total"] == 0 and st["accepted"] == res["sent"]
    assert st["stop"]["reason"] == "operator_disengaged"
    log = sink.log.arrays()
    assert log["v_mps"].max() > 0.5  # the throttle moved the car
    assert log["steering_wheel_angle_rad"].max() == pytest.approx(1.0)
    assert res["telemetry_received"] >= 5
    # the operator's screen saw the link measured and the same stop the vehicle recorded
    lat = res["link"]["latency_ms"]
    assert 0.0 <= lat["p50"] <= lat["p99"]
    assert res["stop"]["reason"] == st["stop"]["reason"]
