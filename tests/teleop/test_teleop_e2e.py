"""Operator -> link -> receiver -> limits -> hybrid plant, on loopback, without the drive loop.

The operator station's real send loop (``run_operator``) and the vehicle stand-in
(``PlantSink``: ``apply_limits`` then ``HybridPlant``) share one simulated clock; every packet
goes through real loopback UDP sockets and the authenticated receiver.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.teleop.link import LinkReceiver, OperatorLink
from hmpc.tools.cmd_operator import experiment_script
from hmpc.controller.teleop.operator import END_PACKETS, load_script, run_operator
from hmpc.controller.simclock import SimClock
from hmpc.controller.teleop.sink import PlantSink, lockstep_vehicle
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import run_experiment
from _data import REPORT_PARAMS

KEY = random.Random(1011).randbytes(32)


def _drive(script, params):
    clk = SimClock(1000.0)
    rx = LinkReceiver(KEY, ("127.0.0.1", 0), clock=clk)
    op = OperatorLink(KEY, rx.address, clock=clk)
    sink = PlantSink(params)
    try:
        summary = run_operator(script, op, clock=clk, sleep=lockstep_vehicle(rx, sink, clk))
        return summary, rx.stats(), sink
    finally:
        op.close()
        rx.close()


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


@pytest.fixture(scope="module")
def arcs(params):
    script = experiment_script("arcs", params, seed=0)
    summary, stats, sink = _drive(script, params)
    truth = run_experiment("arcs", params, seed=0, rate_hz=50.0, noise="none")
    return script, summary, stats, sink, truth


def test_arcs_link_is_clean_and_ends_with_a_stop(arcs):
    script, summary, stats, sink, _ = arcs
    assert summary.end == "source_finished"
    assert stats["rejected_total"] == 0 and stats["lost"] == 0
    assert stats["accepted"] == summary.sent  # every packet sent arrived
    # all delivered up to the disengage; its 4 repeats and the 5 end packets find the link
    # disengaged and are counted, not passed on
    assert stats["ignored_not_engaged"] == 4 + END_PACKETS
    assert stats["delivered"] == summary.sent - stats["ignored_not_engaged"]
    assert stats["delivered"] > len(script.commands)  # rows are held over periods
    assert stats["stop"]["reason"] == "operator_disengaged"
    assert sink.standstill_t_s is not None and sink.state[3] == 0.0
    assert summary.telemetry_received > 1000  # 10 Hz over 113 s
    assert summary.last_telemetry.stop.reason == "operator_disengaged"


def test_arcs_motion_matches_the_experiment(arcs):
    """Speed and heading follow the simulator's own run of the experiment on the same model."""
    script, summary, stats, sink, truth = arcs
    log = sink.log.arrays()
    lead = 5  # five engage periods before the first pedal row
    v_true = truth.truth_on_grid("v_mps")
    psi_true = np.unwrap(truth.truth_on_grid("psi_rad"))
    n = len(v_true)
    v = log["v_mps"][lead : lead + n]
    psi = np.unwrap(log["psi_rad"][lead : lead + n])
    assert math.sqrt(np.mean((v - v_true) ** 2)) < 0.15
    assert abs(v.max() - 5.2) < 0.4  # the 5.2 m/s arcs were driven
    dpsi, dpsi_true = psi - psi[0], psi_true - psi_true[0]
    assert np.max(np.abs(dpsi - dpsi_true)) < 0.1
    # each arc step turns the car the way the report's experiment does: cw steps yaw right
    t = log["t_s"][lead : lead + n] - log["t_s"][lead]
    checked = 0
    for seg in truth.recording.meta["segments"]:
        label = seg["label"]
        if "step" not in label:
            continue
        sel = (t >= seg["t_start_s"]) & (t < seg["t_end_s"])
        turn = psi[sel][-1] - psi[sel][0]
        assert (turn < -0.05) if " cw " in f" {label} " else (turn > 0.05), (label, turn)
        checked += 1
    assert checked == 16


def test_arcs_commands_went_through_the_limits(arcs, params):
    _, _, _, sink, _ = arcs
    log = sink.log.arrays()
    lim = ActuatorLimits.from_params(params)
    assert not np.any((log["accel_pedal"] > 0) & (log["brake_pedal"] > 0))
    dsw = np.abs(np.diff(log["steering_wheel_angle_rad"]))
    assert dsw.max() <= lim.steering_wheel_rate_max_radps * sink.dt_s + 1e-9


def test_operator_full_throttle_is_capped_by_the_controller_limits(tmp_path, params):
    """A script that floors the throttle: the plant sees the MPC's limits, not the script."""
    p = tmp_path / "floor.csv"
    p.write_text(
        "t_s,mode,dead_man,steering_wheel_angle_rad,accel_pedal,brake_pedal\n"
        "0,engage,1,,,\n0.1,pedals,1,20,1.0,0\n4.1,pedals,1,0,1.0,1.0\n"
        "5.1,disengage,1,,,\n"
    )
    summary, stats, sink = _drive(load_script(p), params)
    log = sink.log.arrays()
    lim = ActuatorLimits.from_params(params)
    ap = log["accel_pedal"]
    assert np.max(np.diff(ap)) <= lim.accel_pedal_rate_max_ps * sink.dt_s + 1e-9
    zones = params.zones
    for z, a in zip(log["zone"].astype(int), ap):
        cap = (lim.accel_max_mps2 - zones[z].offset_mps2) / zones[z].scale_mps2
        assert a <= cap + 1e-9
    assert np.max(np.abs(log["steering_wheel_angle_rad"])) <= lim.steering_wheel_angle_max_rad
    both = (log["t_s"] >= 4.2) & (log["t_s"] < 5.0)  # throttle and brake asked together
    assert np.all(log["accel_pedal"][both] == 0) and np.all(log["brake_pedal"][both] > 0)
    assert stats["stop"]["reason"] == "operator_disengaged"


def test_ramp_sequence_speeds_follow_the_experiment(params):
    script = experiment_script("ramp_sequence", params, seed=0)
    summary, stats, sink = _drive(script, params)
    truth = run_experiment("ramp_sequence", params, seed=0, rate_hz=50.0, noise="none")
    v_true = truth.truth_on_grid("v_mps")
    v = sink.log.arrays()["v_mps"][5 : 5 + len(v_true)]
    assert math.sqrt(np.mean((v - v_true) ** 2)) < 0.15
    assert abs(v.max() - 8.0) < 0.5 and stats["rejected_total"] == 0
    zones = set(sink.log.arrays()["zone"].astype(int))
    assert zones == {0, 1, 2}  # all three zones driven


@pytest.mark.parametrize("how", ["cut", "dead_man"])
def test_cut_link_or_released_dead_man_stops_the_car(params, how):
    """Drive the arcs for 20 s, then cut the link (no more packets) or release the dead-man:
    the stop request comes within 200 ms + 2 periods and the stand-in brakes to standstill
    within the controlled-stop deceleration."""
    from hmpc.controller.teleop.link import TeleopCommand

    script = experiment_script("arcs", params, seed=0)
    clk = SimClock(1000.0)
    rx = LinkReceiver(KEY, ("127.0.0.1", 0), clock=clk)
    op = OperatorLink(KEY, rx.address, clock=clk)
    sink = PlantSink(params)
    step = lockstep_vehicle(rx, sink, clk)  # waits for the period's packet
    step_silent = lockstep_vehicle(rx, sink, clk, wait_s=0.0)  # after the cut: nothing comes
    period = sink.dt_s
    try:
        k = 0
        while k * period < 20.0:
            op.send(script.command_at(k * period))
            step(period)
            k += 1
        t_event = clk()
        if how == "dead_man":
            op.send(TeleopCommand.pedals(0.0, 0.3, 0.0, dead_man=False))
            step(period)
        v_event = float(sink.state[3])
        for _ in range(int(15.0 / period)):
            step_silent(period)
    finally:
        op.close()
        rx.close()
    assert v_event > 2.0
    stop = sink.stop
    assert stop.reason == {"cut": "link_lost", "dead_man": "dead_man_released"}[how]
    assert stop.detected_t_s - (t_event - period) <= 0.2 + 2 * period + 1e-9
    assert sink.standstill_t_s is not None and sink.state[3] == 0.0
    log = sink.log.arrays()
    lim = ActuatorLimits.from_params(params)
    stopping = log["stopping"] > 0
    accel = np.diff(log["v_mps"]) / period
    assert accel[stopping[:-1]].min() >= -lim.controlled_stop_decel_max_mps2 - 1e-6
    assert np.all(log["accel_pedal"][stopping] == 0)
