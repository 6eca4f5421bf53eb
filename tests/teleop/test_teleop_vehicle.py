"""The vehicle side's command source (controller/teleop/vehicle.py) without the drive loop: a
real receiver on loopback UDP, a simulated clock, and the source's ``poll``/``step`` called as
the drive loop calls them; and ``hmpc teleop``'s refusals of bad input."""

from __future__ import annotations

import inspect
import math
import os
import random
import select
import socket

import numpy as np
import pytest

from _data import PARAMS_DIR, REPORT_PARAMS
from hmpc.controller.base import ControlResult, Controller, Status
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.teleop.link import LinkReceiver, Mode, OperatorLink, TeleopCommand
from hmpc.controller.simclock import SimClock
from hmpc.controller.teleop.vehicle import (
    HOLD_BRAKE,
    TeleopController,
    anchored_reference,
    arc_reference,
)
from hmpc.models.params import load_params
from hmpc.models.sim.scenarios import make_scenario
from hmpc.tools.cli import main

KEY = random.Random(1112).randbytes(32)
DT = 0.02


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


@pytest.fixture(scope="module")
def mpc(params):
    return MpcController(params, MpcConfig())


class Rig:
    """Receiver + operator on loopback, one simulated clock, the source polled in lock step.
    The loop's clock runs 1000 s behind the wall clock (so conversions are visible)."""

    def __init__(self, params, mpc=None, run_s=None):
        self.clock = SimClock(5000.0)
        self.rx = LinkReceiver(KEY, ("127.0.0.1", 0), clock=self.clock)
        self.op = OperatorLink(KEY, self.rx.address, clock=self.clock, seq_start=10)
        self.src = TeleopController(self.rx, params, mpc, run_s=run_s, wall_clock=self.clock)
        self.ref = make_scenario("figure8", params)
        self.x = self.ref.initial_state(params)
        self.src.step(self.x, self.ref, 0.0)  # the drive loop's warm-up call
        self.src.reset()

    @property
    def t(self) -> float:
        return self.clock() - 4000.0

    def send(self, cmd: TeleopCommand, ticks: int = 1):
        """Send ``cmd``, advance one tick (10 ms) and poll; then poll ``ticks - 1`` more."""
        self.op.send(cmd)
        select.select([self.rx], [], [], 2.0)
        return self.idle(ticks)

    def idle(self, ticks: int = 1):
        gate = None
        for _ in range(ticks):
            self.clock.advance(0.01)
            gate = self.src.poll(
                self.t,
                loop_state="engaged",
                speed_mps=float(self.x[3]),
                steering_wheel_angle_rad=0.0,
            )
        return gate

    def step(self):
        return self.src.step(self.x, self.ref, self.t)

    def close(self):
        self.op.close()
        self.rx.close()


@pytest.fixture
def rig(params):
    r = Rig(params)
    yield r
    r.close()


def test_is_a_controller(rig):
    """A built source meets the contract (controller/base.py): keyword-only ``stop`` and
    ``obstacle_distance_m``, a name, and a step that answers with a ControlResult; before the
    operator engages, that answer is a hold on the brake."""
    src = rig.src
    assert isinstance(src, Controller) and src.name == "teleop"
    sig = inspect.signature(src.step)
    for name in ("stop", "obstacle_distance_m"):
        assert sig.parameters[name].kind is inspect.Parameter.KEYWORD_ONLY, name
    r = src.step(rig.x, rig.ref, rig.t, stop=False, obstacle_distance_m=None)
    assert isinstance(r, ControlResult) and r.traceback is None
    assert r.status == Status.HOLD and r.command == Command(0.0, 0.0, HOLD_BRAKE)


def test_engages_only_on_the_operators_engage_then_holds(rig):
    assert rig.idle().engage is False
    assert rig.send(TeleopCommand.pedals(0.5, 0.3, 0.0)).engage is False  # not engaged: ignored
    assert rig.rx.ignored_not_engaged == 1
    g = rig.send(TeleopCommand(Mode.ENGAGE))
    assert g.engage is True and g.stop == ""
    res = rig.step()  # engaged, no driving command yet
    assert res.status == Status.HOLD
    assert res.command == Command(0.0, 0.0, HOLD_BRAKE)
    assert rig.src.history == ["hold"]


def test_pedals_go_through_the_same_limits_as_the_mpcs(rig, params):
    lim = ActuatorLimits.from_params(params)
    rig.send(TeleopCommand(Mode.ENGAGE))
    prev = rig.step().command
    rig.send(TeleopCommand.pedals(20.0, 1.0, 0.0))  # far past every limit
    res = rig.step()
    z = params.zones[res.zone]
    assert res.status == Status.OK
    assert res.command == apply_limits(Command(20.0, 1.0, 0.0), prev, lim, DT, z)
    assert (
        res.command.steering_wheel_angle_rad
        <= prev.steering_wheel_angle_rad + lim.steering_wheel_rate_max_radps * DT + 1e-12
    )
    for _ in range(200):
        res = rig.step()
    assert res.command.steering_wheel_angle_rad == pytest.approx(lim.steering_wheel_angle_max_rad)
    assert res.command.accel_pedal <= (lim.accel_max_mps2 - z.offset_mps2) / z.scale_mps2 + 1e-12
    rig.send(TeleopCommand.pedals(0.0, 0.6, 0.4))  # both pedals: the brake wins
    res = rig.step()
    assert res.command.accel_pedal == 0.0 and res.command.brake_pedal > 0.0


def test_released_dead_man_asks_for_a_stop_on_the_loops_clock(rig):
    rig.send(TeleopCommand(Mode.ENGAGE))
    rig.send(TeleopCommand.pedals(0.0, 0.2, 0.0))
    t_release = rig.t + 0.01
    g = rig.send(TeleopCommand.pedals(0.0, 0.9, 0.0, dead_man=False))
    assert g.stop == "dead_man_released" and g.engage is False
    ev = rig.src.stats()["stop"]
    assert ev["reason"] == "dead_man_released"
    assert ev["event_t_s"] == pytest.approx(t_release) and ev["detected_t_s"] == ev["event_t_s"]
    assert rig.src.last.values == (0.0, 0.2, 0.0)  # the releasing packet's throttle: never


def test_lost_link_asks_for_a_stop_after_200_ms(rig):
    rig.send(TeleopCommand(Mode.ENGAGE))
    rig.send(TeleopCommand.pedals(0.0, 0.2, 0.0))
    t_last = rig.t
    gates = [rig.idle() for _ in range(25)]
    first = next(i for i, g in enumerate(gates) if g.stop)
    assert gates[first].stop == "link_lost"
    assert first + 1 in (20, 21)  # the 20th silent 10 ms tick (21st: float rounding)
    ev = rig.src.stats()["stop"]
    assert ev["event_t_s"] == pytest.approx(t_last)
    assert 0.2 - 1e-9 <= ev["detected_t_s"] - ev["event_t_s"] <= 0.21 + 1e-9
    assert all(not g.stop for g in gates[first + 1 :])  # asked once


def test_duration_ends_the_run(params):
    r = Rig(params, run_s=1000.05)  # the rig's loop clock starts at 1000 s
    try:
        assert r.idle(3).stop == "" and r.idle(3).stop == "duration"
    finally:
        r.close()


def test_handover_to_the_mpc_and_take_over(params, mpc):
    r = Rig(params, mpc)
    try:
        r.x = np.array([3.0, -2.0, 0.4, 2.0])
        r.send(TeleopCommand(Mode.ENGAGE))
        r.send(TeleopCommand.pedals(0.1, 0.2, 0.0))
        assert r.step().status == Status.OK
        r.send(TeleopCommand(Mode.HANDOVER_MPC))
        res = r.step()
        assert res.status in (Status.SOLVED, Status.SOLVED_INACCURATE)
        a = r.src._anchor
        assert (a.x_m[0], a.y_m[0], a.heading_rad[0]) == pytest.approx((3.0, -2.0, 0.4))
        assert a.speed_mps[0] >= 2.0 and a.time_s[0] == pytest.approx(r.t)
        r.send(TeleopCommand.pedals(0.1, 0.2, 0.0))  # the operator keeps the link alive
        assert r.step().status.ok and r.src.history[-1] == "mpc"
        r.send(TeleopCommand(Mode.TAKE_OVER))
        r.send(TeleopCommand.pedals(0.3, 0.1, 0.0))
        res = r.step()
        assert res.status == Status.OK and r.src.history[-3:] == ["mpc", "mpc", "operator"]
        s = r.src.stats()
        assert s["handovers"] == 1 and s["take_overs"] == 1 and s["steps"]["mpc"] == 2
    finally:
        r.close()


def test_handover_without_a_controller_is_a_controlled_stop(rig):
    rig.send(TeleopCommand(Mode.ENGAGE))
    rig.send(TeleopCommand(Mode.HANDOVER_MPC))
    res = rig.step()
    assert res.status == Status.CONTROLLED_STOP and not res.ok


def test_references_are_followed_by_the_mpc_on_an_arc(params, mpc):
    r = Rig(params, mpc)
    try:
        r.x = np.array([0.0, 0.0, 0.0, 3.0])
        r.send(TeleopCommand(Mode.ENGAGE))
        r.send(TeleopCommand.references(3.0, 0.05))
        res = r.step()
        assert res.status.ok and r.src.history == ["references"]
        arc = r.src._arc
        assert arc.speed_mps[0] == 3.0 and arc.curvature_1pm[0] == 0.05
        for _ in range(10):
            r.send(TeleopCommand.references(3.0, 0.05), ticks=2)
            res = r.step()
        assert res.command.steering_wheel_angle_rad > 0.0  # a left arc: steer left
    finally:
        r.close()


def test_arc_reference_geometry():
    a = arc_reference([1.0, 2.0, math.pi / 2, 0.0], 2.0, 0.1, 5.0, duration_s=math.pi * 10 / 2)
    assert a.time_s[0] == 5.0 and (a.x_m[0], a.y_m[0]) == pytest.approx((1.0, 2.0))
    # half a circle of radius 10 m, left from heading north: ends 20 m west
    assert (a.x_m[-1], a.y_m[-1]) == pytest.approx((-19.0, 2.0), abs=0.05)
    assert a.heading_rad[-1] == pytest.approx(3 * math.pi / 2, abs=0.01)
    s = arc_reference([0.0, 0.0, 0.0, 0.0], 1.0, 0.0, 0.0, duration_s=2.0)
    assert (s.x_m[-1], s.y_m[-1]) == pytest.approx((2.0, 0.0))


def test_anchored_reference_joins_at_the_cars_speed(params):
    ref = make_scenario("figure8", params)
    x = np.array([10.0, 20.0, -1.0, 1.5])
    a = anchored_reference(ref, x, 7.0)
    i = int(np.argmax(ref.speed_mps >= 1.5))
    assert a.speed_mps[0] == ref.speed_mps[i] and len(a.time_s) == len(ref.time_s) - i
    assert (a.x_m[0], a.y_m[0], a.heading_rad[0], a.time_s[0]) == pytest.approx((10, 20, -1, 7))
    # a rigid motion: distances along the path are kept
    d0 = np.hypot(np.diff(ref.x_m[i:]), np.diff(ref.y_m[i:]))
    assert np.allclose(np.hypot(np.diff(a.x_m), np.diff(a.y_m)), d0)


def test_link_json_keys(rig):
    rig.send(TeleopCommand(Mode.ENGAGE))
    for _ in range(5):
        rig.send(TeleopCommand.pedals(0.0, 0.1, 0.0), ticks=2)
    rig.idle(8)  # one 100 ms gap (10 ticks)
    rig.send(TeleopCommand.pedals(0.0, 0.1, 0.0))
    s = rig.src.stats()
    for k in ("accepted", "rejected", "rejected_total", "latency_ms", "gaps", "steps", "stop"):
        assert k in s
    assert set(s["latency_ms"]) == {"p50", "p99"} and s["accepted"] == 7
    assert s["gaps"]["count"] == 1 and s["gaps"]["max_ms"] == pytest.approx(100.0)


# ------------------------------------------------------------------------------- CLI
def _teleop(tmp_path, key, *extra):
    return main(
        [
            "teleop",
            "--params",
            str(REPORT_PARAMS),
            "--actuation",
            str(PARAMS_DIR / "bywire.actuation.yaml"),
            "--key",
            str(key),
            "--vehicle-sim",
            "--candump",
            str(tmp_path / "run.log"),
            "--duration",
            "0.5",
            *extra,
        ]
    )


def _key(tmp_path, mode=0o600):
    p = tmp_path / "key"
    p.write_text(KEY.hex() + "\n")
    os.chmod(p, mode)
    return p


def test_cli_refuses_a_key_others_can_read(tmp_path, capsys):
    assert _teleop(tmp_path, _key(tmp_path, 0o644)) == 2
    err = capsys.readouterr().err
    assert "key" in err and "chmod 600" in err and len(err.strip().splitlines()) == 1


def test_cli_refuses_a_bad_or_busy_address(tmp_path, capsys):
    key = _key(tmp_path)
    assert _teleop(tmp_path, key, "--listen", "nowhere:port") == 2
    assert "--listen nowhere:port" in capsys.readouterr().err
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    try:
        port = busy.getsockname()[1]
        assert _teleop(tmp_path, key, "--listen", f"127.0.0.1:{port}") == 2
        assert f"--listen 127.0.0.1:{port}" in capsys.readouterr().err
    finally:
        busy.close()
