"""The vehicle simulator node as an ECU: on a real python-can virtual bus it accepts good
command frames, ignores and counts frames with a bad checksum/CRC or a skipped counter, faults
on a command beyond the car's own limits, and publishes its feedback messages."""

from __future__ import annotations

import itertools
import os
import time

import can
import pytest

from _data import PARAMS_DIR, REPORT_PARAMS
from hmpc.controller.actuation import builders
from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.actuation.vehicle_node import VehicleNode
from hmpc.models.params import load_params

pytestmark = pytest.mark.realtime

_n = itertools.count()


def _node(profile_file):
    prof = load_profile(PARAMS_DIR / profile_file)
    p = load_params(REPORT_PARAMS, require_model=True)
    kw = {"interface": "virtual", "channel": f"node-test-{os.getpid()}-{next(_n)}"}
    node = VehicleNode(prof, p, kw, start_state=[0, 0, 0, 3.0])
    return prof, node, kw


def _settle(node, want, timeout_s=3.0):
    """Wait (bounded) until the node has handled ``want`` command frames (no timing asserted)."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if sum(node.stats.accepted.values()) + sum(node.stats.rejected.values()) >= want:
            return
        time.sleep(0.01)


def test_toyota_node_checks_checksum_counter_and_limits():
    prof, node, kw = _node("toyota_rav4_2017.actuation.yaml")
    spec = prof.commands["steer_torque"]
    node.start()
    bus = can.Bus(**kw)
    try:
        good = [builders.steering_lka(spec, 0, True, c) for c in range(5)]
        for m in good:
            bus.send(m)
        bad_ck = builders.steering_lka(spec, 0, True, 5)
        bad_ck.data[-1] ^= 0xFF
        bus.send(bad_ck)  # checksum wrong
        bus.send(builders.steering_lka(spec, 0, True, 9))  # counter skips 5..8
        bus.send(builders.steering_lka(spec, 0, True, 10))  # in sequence again
        bus.send(builders.steering_lka(spec, 500, True, 11))  # +500 in one frame: EPS fault
        _settle(node, 9)
        seen, want = (
            set(),
            {
                "WHEEL_SPEEDS",
                "STEER_ANGLE_SENSOR",
                "STEER_TORQUE_SENSOR",
                "EPS_STATUS",
                "PCM_CRUISE",
            },
        )
        t_end = time.monotonic() + 2.0
        while time.monotonic() < t_end and not want <= seen:
            m = bus.recv(timeout=0.1)
            if m is not None:
                seen.add(prof.db.get_message_by_frame_id(m.arbitration_id).name)
    finally:
        bus.shutdown()
        node.stop()
    assert node.stats.accepted["STEERING_LKA"] == 6
    assert node.stats.rejected == {"checksum": 1, "counter": 1, "car_limit": 1}
    assert any("EPS" in w for _, w in node.stats.faults)
    assert want <= seen


def test_bywire_node_checks_crc_and_refuses_both_pedals():
    prof, node, kw = _node("bywire.actuation.yaml")
    spec = prof.commands["pedals"]
    node.start()
    bus = can.Bus(**kw)
    try:
        bus.send(builders.bw_pedal_cmd(spec, 0.1, 0.0, True, 0))
        bad = builders.bw_pedal_cmd(spec, 0.1, 0.0, True, 1)
        bad.data[0] ^= 0x01  # payload corrupted: CRC fails
        bus.send(bad)
        bus.send(builders.bw_pedal_cmd(spec, 0.1, 0.0, True, 1))
        both = builders.encode_command(spec, {"accel_pedal": 0.2, "brake_pedal": 0.2}, True, 2)
        bus.send(both)  # throttle with brake: fault
        _settle(node, 4)
    finally:
        bus.shutdown()
        node.stop()
    assert node.stats.accepted["BW_PEDAL_CMD"] == 2
    assert node.stats.rejected == {"checksum": 1, "car_limit": 1}
