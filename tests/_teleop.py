"""Helpers of the tele-operation loopback tests: the drive loop with the operator link as its
command source (``controller/teleop/vehicle.py``), against the vehicle simulator node on a
fresh python-can virtual channel, fed by an operator thread over real loopback UDP."""

from __future__ import annotations

import itertools
import os
import random
import threading
import time

import numpy as np

from _drive import PROFILES, params
from hmpc.controller.actuation.candump import audit_candump
from hmpc.controller.actuation.drive import DriveConfig, DriveLoop
from hmpc.controller.actuation.profiles import load_profile
from hmpc.controller.actuation.vehicle_node import VehicleNode
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.teleop.link import LinkReceiver, Mode, OperatorLink, TeleopCommand
from hmpc.controller.teleop.operator import Script
from hmpc.controller.teleop.vehicle import TeleopController, handover_config
from hmpc.models.logs.canlog import read_log
from hmpc.models.errors import Problems
from hmpc.models.sim.scenarios import make_scenario

KEY = random.Random(1111).randbytes(32)
_n = itertools.count()
#: the operator starts sending once the loop has polled this many ticks (0.35 s: past the
#: drive loop's engage_at_s, so the operator's engage is not waiting on the loop)
START_POLLS = 35


def script(rows: list[tuple]) -> Script:
    """(t_s, TeleopCommand) rows -> Script."""
    return Script(np.array([r[0] for r in rows]), [r[1] for r in rows], name="test")


def pedals(sw: float, ap: float, bp: float = 0.0, dead_man: bool = True) -> TeleopCommand:
    return TeleopCommand.pedals(sw, ap, bp, dead_man=dead_man)


ENGAGE = TeleopCommand(Mode.ENGAGE)
HANDOVER = TeleopCommand(Mode.HANDOVER_MPC)
TAKE_OVER = TeleopCommand(Mode.TAKE_OVER)
DISENGAGE = TeleopCommand(Mode.DISENGAGE)


class Operator(threading.Thread):
    """Sends ``script``'s command every 20 ms (real time) once the loop polls; optional
    ``attack(link, t_s)`` runs each period too. ``end_packets``: send the operator's end
    (disengage, dead-man released) like ``run_operator``; False: just go silent (a cut link)."""

    def __init__(
        self, src: TeleopController, addr, script: Script, *, attack=None, end_packets: bool = True
    ):
        super().__init__(daemon=True)
        self.src, self.script, self.attack, self.end_packets = src, script, attack, end_packets
        self.link = OperatorLink(KEY, addr)
        self.sent: list[tuple[float, TeleopCommand]] = []  # (wall time, command) of each send
        self.stop_flag = False

    def run(self) -> None:
        while self.src._polls_total < START_POLLS and not self.stop_flag:
            time.sleep(0.005)
        t0 = time.monotonic()
        k = 0
        while not self.stop_flag:
            t = k * 0.02
            cmd = self.script.command_at(t)
            if cmd is None:
                break
            self.link.send(cmd)
            self.sent.append((time.time(), cmd))
            if self.attack is not None:
                self.attack(self.link, t)
            k += 1
            time.sleep(max(t0 + k * 0.02 - time.monotonic(), 0.0))
        if self.end_packets:
            for _ in range(5):
                self.link.send(TeleopCommand(Mode.DISENGAGE, dead_man=False))
                time.sleep(0.02)
        self.link.close()


def teleop_run(
    profile: str,
    ops: Script,
    tmp_path,
    *,
    attack=None,
    end_packets: bool = True,
    scenario: str = "figure8",
    run_s: float = 60.0,
    with_mpc: bool = False,
    config: DriveConfig = DriveConfig(),
):
    """One real-time teleop run; returns (summary, trace, link stats, candump path, operator).
    ``with_mpc``: an MPC to hand over to (otherwise none: a handover would stop the car)."""
    p = params()
    prof = load_profile(PROFILES[profile])
    ref = make_scenario(scenario, p)
    kw = {"interface": "virtual", "channel": f"hmpc-teleop-test-{os.getpid()}-{next(_n)}"}
    node = VehicleNode(prof, p, kw, start_state=ref.initial_state(p))
    rx = LinkReceiver(KEY, ("127.0.0.1", 0))
    mpc = MpcController(p, handover_config(MpcConfig())) if with_mpc else None
    src = TeleopController(rx, p, mpc, run_s=run_s)
    op = Operator(src, rx.address, ops, attack=attack, end_packets=end_packets)
    log = tmp_path / f"teleop-{profile}.log"
    loop = DriveLoop(prof, p, src, ref, kw, log, duration_s=float("inf"), node=node, config=config)
    op.start()
    try:
        res = loop.run()
    finally:
        op.stop_flag = True
        op.join(5.0)
        rx.close()
    s = res.summary
    audit = audit_candump(prof, p, log)
    s["limit_violations"] = audit["limit_violations"]
    s["limit_audit"] = audit
    return s, res.trace, src.stats(), log, op


def command_frames(profile: str, log) -> dict[str, np.ndarray]:
    """The by-wire command frames of a candump, decoded: angle [rad], pedals [1], and the
    enable bits, with their times [s]."""
    prof = load_profile(PROFILES[profile])
    ft = read_log(log, Problems())
    db = prof.db
    ids = {db.get_message_by_name(n).frame_id: n for n in ("BW_STEER_CMD", "BW_PEDAL_CMD")}
    out = {
        "steer_t": [],
        "steer": [],
        "steer_en": [],
        "pedal_t": [],
        "accel": [],
        "brake": [],
        "pedal_en": [],
    }
    for i in range(len(ft)):
        name = ids.get(int(ft.arb_id[i]))
        if name is None:  # only hmpc sends command frames on this bus
            continue
        d = db.get_message_by_name(name).decode(
            bytes(ft.data[i, : ft.dlc[i]]), decode_choices=False
        )
        if name == "BW_STEER_CMD":
            out["steer_t"].append(float(ft.t_s[i]))
            out["steer"].append(d["STEER_ANGLE_CMD"])
            out["steer_en"].append(d["STEER_ENABLE"])
        else:
            out["pedal_t"].append(float(ft.t_s[i]))
            out["accel"].append(d["ACCEL_PEDAL_CMD"])
            out["brake"].append(d["BRAKE_PEDAL_CMD"])
            out["pedal_en"].append(d["ACCEL_ENABLE"])
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}
