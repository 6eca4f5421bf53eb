"""``hmpc teleop``'s loop end to end in real time: an operator thread sends over real loopback
UDP to the authenticated receiver, the drive loop (``controller/actuation/drive.py``) runs the
operator's commands (``controller/teleop/vehicle.py``) through the limits and encoders onto
python-can's virtual bus, and the vehicle simulator node drives. Times in the assertions are
the loop's own (as in test_drive_faults.py), never wall-clock durations of the test.

The acceptance run (the scripted operator drives ramp_sequence and arcs; ``hmpc identify`` on
the candump recovers the simulated car) takes about 70 s; the others about 5 s each."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest
import yaml

from _data import PARAMS_DIR, REPORT_PARAMS
from _drive import params
from _teleop import (
    DISENGAGE,
    ENGAGE,
    HANDOVER,
    KEY,
    TAKE_OVER,
    command_frames,
    pedals,
    script,
    teleop_run,
)
from hmpc.controller.actuation.drive import DriveConfig
from hmpc.controller.actuation.watchdog import WatchdogConfig
from hmpc.controller.teleop.link import LinkConfig, Mode, _CMD, _mac, _us
from hmpc.controller.teleop.operator import ENGAGE_LEAD_S
from hmpc.tools.cmd_operator import experiment_script
from hmpc.tools.cli import main

pytestmark = pytest.mark.realtime

PERIOD_S = DriveConfig().control_period_s
TIMEOUT_S = LinkConfig().timeout_s
#: what an attacker would like to put on the bus: full lock right, floored throttle
EVIL = (-2.0, 1.0, 0.0)


def _packet(key: bytes, seq: int, t_s: float, values, mode=Mode.PEDALS, flags=1) -> bytes:
    body = _CMD.pack(1, 1, int(mode), flags, seq, _us(t_s), *values)
    return body + _mac(key, body)


def test_rejected_packets_never_reach_the_bus(tmp_path):
    """While the operator drives (0.4 rad, throttle 0.15), forged packets carrying full lock and
    a floored throttle arrive every period: bad MAC (tampered values, a wrong key), an old
    sequence number, a stale timestamp, a second operator with the right key. Every one is
    rejected and counted; no command frame on the bus carries anything but the operator's."""
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    wrong_key = bytes(32)

    def attack(link, t):
        if t < 0.2:
            return
        now = time.time()
        good = _packet(KEY, link.seq, now, (0.4, 0.15, 0.0))
        tampered = _CMD.pack(1, 1, 1, 1, link.seq + 1, _us(now), *EVIL) + good[_CMD.size :]
        dgs = [
            tampered,  # bad_mac
            _packet(wrong_key, link.seq + 1, now, EVIL),  # bad_mac
            _packet(KEY, link.seq - 5, now, EVIL),  # old_sequence
            _packet(KEY, link.seq + 10_000, now - 0.5, EVIL),  # stale
            _packet(KEY, link.seq + 20_000, now, EVIL),
        ]  # second_operator
        for d in dgs[:4]:
            link.sock.send(d)  # from the operator's own address: spoofed
        other.sendto(dgs[4], link.sock.getpeername())

    ops = script([(0.0, ENGAGE), (0.1, pedals(0.4, 0.15)), (2.1, DISENGAGE)])
    try:
        s, tr, lk, log, op = teleop_run("bywire", ops, tmp_path, attack=attack)
    finally:
        other.close()
    print(s["stop"], lk["rejected"], lk["latency_ms"], s["deadline_misses"], s["loop_period_ms"])
    assert s["stop"]["reason"] == "operator_disengaged"  # the link was never lost
    rej = lk["rejected"]
    for reason in ("bad_mac", "old_sequence", "stale", "second_operator"):
        assert rej[reason] >= 80, reason
    assert lk["accepted"] == op.link.sent  # every operator packet, no more
    f = command_frames("bywire", log)
    on = f["steer_en"] > 0.5
    assert on.sum() > 150  # 100 Hz for about 2 s
    assert f["steer"][on].min() >= -1e-3 and f["steer"][on].max() <= 0.4 + 1e-3
    assert f["accel"].max() <= 0.15 + 1e-3
    assert np.isclose(f["steer"][on], 0.4, atol=1e-3).sum() > 80  # the operator's angle
    assert s["limit_violations"] == 0 and s["frames_rejected_by_vehicle"] == 0


def test_cut_link_stops_within_timeout_plus_two_periods(tmp_path):
    """The operator goes silent at 1.6 s (no end packets): a link_lost controlled stop whose
    first frame leaves within 200 ms + 2 control periods of the last packet sent."""
    ops = script([(0.0, ENGAGE), (0.1, pedals(0.0, 0.25)), (1.5, pedals(0.0, 0.25))])
    s, tr, lk, log, op = teleop_run("bywire", ops, tmp_path, end_packets=False)
    st = s["stop"]
    t_cut_wall = op.sent[-1][0]
    ev = lk["stop"]
    print(st, ev, lk["gaps"])
    assert st["reason"] == "link_lost" and ev["reason"] == "link_lost"
    # never before the timeout: measured from the last packet read (loop clock)
    assert ev["detected_t_s"] - ev["event_t_s"] >= TIMEOUT_S - 1e-6
    assert st["detected_t_s"] == pytest.approx(ev["detected_t_s"], abs=1e-3)
    # the stop's first frame, from the cut (the last send, converted to the loop's clock; the
    # conversion is good to the time between a tick and its poll, under 2 ms)
    t_cut = op.src.loop_time(t_cut_wall)
    print("stop's first frame after the cut [s]:", round(st["t_s"] - t_cut, 4))
    assert 0.0 <= st["t_s"] - t_cut <= TIMEOUT_S + 2 * PERIOD_S + 0.002
    assert st["standstill_t_s"] is not None and st["standstill_t_s"] > st["t_s"]
    assert s["limit_violations"] == 0
    assert lk["accepted"] == op.link.sent


def test_released_dead_man_stops_within_two_periods(tmp_path):
    """Toyota profile: the dead-man released at 1.5 s: a controlled stop starting within 2
    control periods of the releasing packet's arrival; its throttle never applies."""
    ops = script([(0.0, ENGAGE), (0.1, pedals(0.0, 0.25)), (1.5, pedals(0.0, 0.9, dead_man=False))])
    s, tr, lk, log, op = teleop_run("toyota", ops, tmp_path)
    st, ev = s["stop"], lk["stop"]
    print(st, ev)
    assert st["reason"] == "dead_man_released" and ev["reason"] == "dead_man_released"
    assert 0.0 <= st["t_s"] - ev["event_t_s"] <= 2 * PERIOD_S + 1e-6
    assert st["standstill_t_s"] is not None and st["standstill_t_s"] >= st["t_s"]
    eng = np.asarray(tr["engaged"]) > 0.5
    assert np.asarray(tr["ap_cmd"])[eng].max() <= 0.25 + 1e-9
    assert s["limit_violations"] == 0 and s["frames_rejected_by_vehicle"] == 0


def test_handover_to_the_mpc_and_back(tmp_path):
    """The operator drives straight, hands over to the MPC (figure8, joined at the car's speed)
    for 1.5 s while keeping the link alive, takes over with new pedals, then disengages."""
    ops = script(
        [
            (0.0, ENGAGE),
            (0.1, pedals(0.0, 0.25)),
            (1.5, HANDOVER),
            (1.56, pedals(0.0, 0.25)),
            (3.0, TAKE_OVER),
            (3.06, pedals(0.3, 0.1)),
            (3.8, DISENGAGE),
        ]
    )
    # The MPC's first steps after a handover are cold (a new reference, no plan to warm
    # them): 2-10 ms each on the quiet 2-core machine, 50-80 ms while it carried a load of 10,
    # when three late steps in a row tripped the watchdog's deadline stop (tested for itself in
    # test_drive_faults.py). Here the rule is widened to 10 so the test measures the handover.
    cfg = DriveConfig(watchdog=WatchdogConfig(deadline_misses_to_stop=10))
    s, tr, lk, log, op = teleop_run("bywire", ops, tmp_path, with_mpc=True, config=cfg)
    print(s["stop"], lk["steps"], lk["handovers"], lk["take_overs"], s["deadline_misses"])
    assert s["stop"]["reason"] == "operator_disengaged"
    assert lk["handovers"] == 1 and lk["take_overs"] == 1
    assert 60 <= lk["steps"]["mpc"] <= 85  # 1.5 s at 50 Hz
    eng = np.asarray(tr["engaged"]) > 0.5
    sw, ap = np.asarray(tr["sw_cmd"])[eng], np.asarray(tr["ap_cmd"])[eng]
    who = np.array(op.src.history)
    assert len(who) == len(sw)
    mpc = who == "mpc"
    # the MPC drove: commands of its own (figure8 steers), all from solved steps
    assert np.abs(sw[mpc]).max() > 0.05 or np.abs(ap[mpc] - 0.25).max() > 0.05
    after = np.flatnonzero(mpc)[-1] + 1
    back = who[after:]
    assert len(back) > 30 and set(back) == {"operator"}
    assert sw[-1] == pytest.approx(0.3) and ap[-1] == pytest.approx(0.1)
    assert s["limit_violations"] == 0 and s["failures"] == 0


def _pedal_rows(name: str, t_from_s: float, t_to_s: float):
    """The pedal rows of a built-in experiment script between two of its times [s], from 0."""
    s = experiment_script(name, params(), seed=0)
    return [
        (t - ENGAGE_LEAD_S - t_from_s, c)
        for t, c in zip(s.times_s, s.commands)
        if c.mode == Mode.PEDALS and t_from_s <= t - ENGAGE_LEAD_S <= t_to_s
    ]


#: the parts of the report's experiments the acceptance drives (times [s] in each): the gentle
#: ramps of ramp_sequence (every zone, throttle and brake, idle creep braked, back to a
#: standstill) and arcs up to its second clockwise step at 2.8 m/s (the steering map); 65 s in
#: all. A shorter cut (1-49 s and 2-13 s), run while the 2 cores carried a load of 13, left the
#: idle zone thin: its offset came out at 2x
RAMP_SEQUENCE_S = (0.0, 49.0)
ARCS_S = (0.0, 16.0)


@pytest.mark.long
def test_loopback_identification_recovers_the_car(tmp_path):
    """The scripted operator drives ramp_sequence and arcs through the
    link into the simulator node (by-wire kit: continuous pedal positions on the bus); ``hmpc
    identify`` on the candump recovers params/report_2008.yaml: steering offset and scale
    within 2 %, every zone coefficient within 5 %. About 70 s of real time."""
    rows = [(0.0, ENGAGE)]
    rows += [(ENGAGE_LEAD_S + t, c) for t, c in _pedal_rows("ramp_sequence", *RAMP_SEQUENCE_S)]
    t0 = rows[-1][0] + 0.02
    rows += [(t0 + t, c) for t, c in _pedal_rows("arcs", *ARCS_S)]
    rows.append((rows[-1][0] + 0.02, DISENGAGE))
    for _attempt in range(2):  # once more after a host stall (tests/_drive.py's rule)
        s, tr, lk, log, op = teleop_run("bywire", script(rows), tmp_path, run_s=200.0)
        print(s["stop"], s["deadline_misses"], lk["latency_ms"], lk["gaps"])
        if s["stop"]["reason"] != "deadline_misses":
            break
        print(f"host stall: deadline_misses at t = {s['stop']['t_s']} s; run again")
    assert s["stop"]["reason"] == "operator_disengaged"
    assert s["limit_violations"] == 0 and lk["rejected_total"] == 0
    out = tmp_path / "id.yaml"
    rc = main(
        [
            "identify",
            str(log),
            "--dbc",
            str(PARAMS_DIR / "hmpc_bywire.dbc"),
            "--signals",
            str(PARAMS_DIR / "hmpc_bywire.signals.yaml"),
            "--vehicle",
            str(REPORT_PARAMS),
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    got = yaml.safe_load(out.read_text())
    truth = params()
    st = got["steering"]
    print("steering", st["offset_rad"], st["scale"], st["method"])
    assert st["scale"] == pytest.approx(truth.steering.scale, rel=0.02)
    assert st["offset_rad"] == pytest.approx(truth.steering.offset_rad, rel=0.02)
    zones = {z["name"]: z for z in got["longitudinal"]["zones"]}
    for z in truth.zones:
        g = zones[z.name]
        print(z.name, g["offset_mps2"], g["scale_mps2"], g["brake_scale_mps2"])
        for key in ("offset_mps2", "scale_mps2", "brake_scale_mps2"):
            assert g[key] == pytest.approx(getattr(z, key), rel=0.05), (z.name, key)
