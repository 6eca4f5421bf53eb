"""``hmpc replay`` on the bundled comma2k19 minute (a 2017 RAV4 with openpilot engaged from 9.0 s).

- reference mode: the MPC on the plant identified from the minute, along the minute's path and
  speed: finite KPIs within bounds measured on this data (with margin), and the plots;
- log mode: the minute's frames through the drive loop (profile toyota_rav4_2017) on a simulated
  clock, against openpilot's ACC_CONTROL and STEERING_LKA on bus 0;
- determinism: two log replays give the same sha256, a changed controller a different one;
- bad input: one line, exit 2.

Bounds, measured (mpc, parameters identified from the minute): reference mode speed error RMS
0.156 m/s, lateral 0.010 m, 0 failures; log mode ACCEL_CMD correlation +0.86 (RMS difference
0.29 m/s^2) over 51 s engaged, hmpc's steering-wheel angle command against the measured angle
+0.80, 0 limit violations.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import can
import numpy as np
import pytest

from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.replay import log_replay
from hmpc.models.reference import recording_reference
from hmpc.models.errors import Problems
from hmpc.models.logs.canlog import read_log
from hmpc.models.logs.recording import Recording
from hmpc.models.params import load_params
from hmpc.tools.cli import main
from hmpc.controller.build import make_controller

from _data import PARAMS_DIR, bundled

CAN = bundled("rav4-comma2k19/can.log.gz")
NAV = bundled("rav4-comma2k19/nav.csv.gz")
ACTUATION = PARAMS_DIR / "toyota_rav4_2017.actuation.yaml"
ALLOW = "--accept-unidentifiable"  # the minute's steering is flagged not identifiable


@pytest.fixture(scope="module")
def identified(tmp_path_factory, comma_ingest):
    """The minute ingested (conftest's shared ingest, saved as ``hmpc ingest --out`` saves it),
    and the plant identified from it (what a user does first)."""
    d = tmp_path_factory.mktemp("replay")
    rec, params = d / "rec.csv", d / "params.yaml"
    comma_ingest.recording.save(rec)
    assert (
        main(
            [
                "identify",
                str(rec),
                "--vehicle",
                str(PARAMS_DIR / "toyota_rav4_2017.yaml"),
                "--out",
                str(params),
            ]
        )
        == 0
    )
    return rec, params


def test_reference_replay_comma_minute(identified, tmp_path):
    rec, params = identified
    out, plots = tmp_path / "ref.json", tmp_path / "plots"
    assert (
        main(
            [
                "replay",
                str(rec),
                "--params",
                str(params),
                ALLOW,
                "--json",
                str(out),
                "--plots",
                str(plots),
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    assert r["mode"] == "reference" and r["controller"] == "mpc"
    k, car = r["kpis"]["controller"], r["kpis"]["car"]
    for v in (
        k["speed_error_rms_mps"],
        k["lateral_error_rms_m"],
        k["pedal_switches_per_min"],
        k["zone_transitions_per_min"],
        car["pedal_switches_per_min"],
    ):
        assert np.isfinite(v)
    assert k["failures"] == 0 and k["internal_errors"] == 0
    assert k["speed_error_rms_mps"] < 0.4  # measured 0.168
    assert k["lateral_error_rms_m"] < 0.05  # measured 0.010
    assert car["zone_transitions_per_min"] == 0  # 8-20 m/s: the high zone throughout
    d = r["differences"]
    assert d["speed_mps"]["correlation"] > 0.95  # measured 0.998
    assert d["speed_mps"]["samples"] == 3000  # 60 s at 50 Hz
    assert len(r["windows"]["speed_mps"]) == 3
    ws = r["windows"]["speed_mps"]
    assert all(a["rms"] >= b["rms"] for a, b in zip(ws, ws[1:]))
    assert all(
        ws[i]["t1_s"] <= ws[j]["t0_s"] or ws[j]["t1_s"] <= ws[i]["t0_s"]
        for i in range(3)
        for j in range(i + 1, 3)
    )
    assert r["compared"]
    for f in r["plots"]:
        assert (tmp_path / "plots").exists() and Path(f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_log_replay_against_openpilot(identified, tmp_path):
    """The whole minute through the drive loop; the CLI's JSON."""
    _, params = identified
    out, plots, dump = tmp_path / "log.json", tmp_path / "plots", tmp_path / "run.log"
    assert (
        main(
            [
                "replay",
                str(CAN),
                "--mode",
                "log",
                "--actuation",
                str(ACTUATION),
                "--nav",
                str(NAV),
                "--params",
                str(params),
                ALLOW,
                "--json",
                str(out),
                "--plots",
                str(plots),
                "--candump",
                str(dump),
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    assert r["mode"] == "log"
    # the hash is the documented digest of the frames the run sent (the profile's command
    # messages in its candump, as python-can reads it): id, data, timestamp to 4 decimals
    ids = {c.message.frame_id for c in load_profile(ACTUATION).commands.values()}
    sent = [m for m in can.LogReader(str(dump)) if m.arbitration_id in ids]
    digest = hashlib.sha256(
        b"".join(
            f"{m.arbitration_id:08x} {bytes(m.data).hex()} {m.timestamp:.4f}\n".encode()
            for m in sent
        )
    )
    assert r["hash"]["timestamp_decimals"] == 4 and r["hash"]["frames"] == len(sent) > 5000
    assert r["hash"]["sha256"] == digest.hexdigest()
    acc = r["differences"]["ACC_CONTROL.ACCEL_CMD"]
    lka = r["differences"]["STEERING_LKA.STEER_TORQUE_CMD"]
    sw = r["differences"]["steering_wheel_angle_cmd_rad"]
    # openpilot engaged from 9.0 s to the end: about 51 s compared, for both messages
    for name in ("ACC_CONTROL.ACCEL_CMD", "STEERING_LKA.STEER_TORQUE_CMD"):
        assert 45 < r["engaged_s"][name]["both"] <= 51.5
    # the MPC tracks the speed openpilot's requests produced: its request follows openpilot's
    assert acc["correlation"] > 0.5  # measured +0.86
    assert acc["rms_difference"] < 0.6  # measured 0.29 m/s^2
    # hmpc's angle command follows the angle openpilot steered
    assert sw["correlation"] > 0.3  # measured +0.80
    # every frame within the panda's Toyota limits (re-checked from the loop's candump)
    assert r["limit_violations"] == 0
    assert lka["hmpc_abs_max"] <= 1500  # panda TOYOTA_MAX_TORQUE
    assert lka["samples"] > 4000
    assert r["kpis"]["failures"] == 0
    assert Path(r["plots"][0]).read_bytes()[:4] == b"\x89PNG"


@pytest.fixture(scope="module")
def short_log(identified):
    """The minute's first 16 s (openpilot engages at 9.0 s): the determinism runs."""
    rec_path, params_path = identified
    params = load_params(params_path, require_model=True)
    frames = read_log(CAN, Problems())
    frames = frames.take(np.flatnonzero(frames.t_s < frames.t_s[0] + 16.0))
    ref = recording_reference(Recording.load(rec_path), params, source="can")
    return frames, params, ref


def _hash(short_log, **kw) -> dict:
    frames, params, ref = short_log
    ctl = make_controller("mpc", params, accept_unidentifiable=True, **kw)
    r = log_replay(frames, load_profile(ACTUATION), params, ctl, ref)
    return r.summary["hash"]


def test_log_replay_is_deterministic(short_log):
    a, b = _hash(short_log), _hash(short_log)
    assert a["frames"] > 1000
    assert a == b


def test_changed_controller_changes_the_hash(short_log):
    assert _hash(short_log)["sha256"] != _hash(short_log, dt_s=0.1)["sha256"]


def test_replay_bus_serves_the_log_on_the_simulated_clock():
    """python-can opens the replay bus by its interface name (the entry point); recv serves the
    frames due on the simulated clock in order, waits (advances the clock) only within its
    timeout, and send records with the simulated time."""
    import can

    from hmpc.controller.actuation.replay_bus import ReplaySource
    from hmpc.controller.simclock import SimClock

    frames = read_log(CAN, Problems())
    frames = frames.take(np.flatnonzero(frames.t_s < frames.t_s[0] + 0.2))
    src = ReplaySource(frames, 0, exclude_ids=(0x2E4,))
    assert 0 < len(src) < int((frames.bus == 0).sum())
    assert not np.any(src.arb_id == 0x2E4)
    clock = SimClock(src.t_s[0])
    with can.Bus(interface="hmpc_replay", channel="t", source=src, clock=clock) as bus:
        first = bus.recv(timeout=0.0)
        assert first.timestamp == src.t_s[0] and first.arbitration_id == src.arb_id[0]
        due = int(np.sum(src.t_s <= clock.time()))
        got = 1
        while bus.recv(timeout=0.0) is not None:
            got += 1
        assert got == due  # nothing from the future without waiting
        t = clock.time()
        m = bus.recv(timeout=0.05)  # waits for the next frame, not the whole timeout
        assert m is not None and clock.time() == m.timestamp and t < m.timestamp < t + 0.05
        bus.send(can.Message(arbitration_id=0x343, data=bytes(8), is_extended_id=False))
        assert src.sent[-1].timestamp == clock.time()
        while bus.recv(timeout=0.0) is not None or src.next_time() is not None:
            clock.sleep(0.01)
        t = clock.time()
        assert bus.recv(timeout=0.5) is None and clock.time() == t + 0.5  # exhausted: times out


def _write_candump(path, frames) -> None:
    with open(path, "w") as fh:
        for i in range(len(frames)):
            data = bytes(frames.data[i, : frames.dlc[i]]).hex().upper()
            fh.write(
                f"({frames.t_s[i]:.6f}) can{int(frames.bus[i])} "
                f"{int(frames.arb_id[i]):03X}#{data}\n"
            )


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if "error:" in ln]  # warnings may precede it
    assert len(lines) == 1
    return lines[0]


def test_bad_input(identified, tmp_path, capsys):
    _, params = identified
    base = ["--params", str(params), ALLOW]
    line = _one_line_error(capsys, ["replay", str(tmp_path / "nope.log"), *base])
    assert "nope.log" in line
    line = _one_line_error(capsys, ["replay", str(CAN), "--mode", "log", *base])
    assert "--actuation" in line
    frames = read_log(CAN, Problems())
    # a log without the wheel speeds the loop needs as feedback
    no_ws = tmp_path / "no_wheel_speeds.log"
    _write_candump(
        no_ws,
        frames.take(np.flatnonzero((frames.arb_id != 0xAA) & (frames.t_s < frames.t_s[0] + 12))),
    )
    line = _one_line_error(
        capsys, ["replay", str(no_ws), "--mode", "log", "--actuation", str(ACTUATION), *base]
    )
    assert "WHEEL_SPEEDS" in line and "no_wheel_speeds.log" in line
    # a log in which the car never accepts commands (openpilot engages at 9.0 s)
    early = tmp_path / "before_engagement.log"
    _write_candump(early, frames.take(np.flatnonzero(frames.t_s < frames.t_s[0] + 8)))
    line = _one_line_error(
        capsys, ["replay", str(early), "--mode", "log", "--actuation", str(ACTUATION), *base]
    )
    assert "never accepts commands" in line and "PCM_CRUISE.CRUISE_ACTIVE" in line
