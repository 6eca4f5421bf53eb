"""The drive run's candump (``-L`` format, every frame sent and received): written in time
order while the loop runs (:class:`OrderedCandump`), and re-checked after the run against fresh
limit checks (:func:`audit_candump`, the run JSON's ``limit_violations``).
"""

from __future__ import annotations

import math
from pathlib import Path

import can
import numpy as np

from hmpc.models.errors import Problems
from hmpc.models.params import Params

from hmpc.controller.actuation.profiles import ActuationProfile
from hmpc.controller.actuation.safety import (
    AngleCheck,
    AngleLimits,
    ToyotaLimits,
    ToyotaSteerCheck,
    accel_ok,
    pedals_ok,
)


class OrderedCandump:
    """The run's candump, written in time order without work between reading and sending.

    A sent frame is stamped when it is sent, a received one when it reached the bus; a frame
    that arrives while the loop encodes and sends (after its last look at the bus) is read
    on the next tick, after frames stamped later were logged. The loop's calls only keep the
    frame (``on_message_received``); after the tick's frames are sent, ``flush`` writes, in
    time order, those older than the previous tick's first read (every frame that old was
    on the bus then, and has been read: one tick of margin for a sender stamped before it
    queued its frame). ``stop`` writes the rest, sorted, and closes the file."""

    def __init__(self, path: Path):
        self._writer = can.CanutilsLogWriter(str(path), channel="can0")
        self._held: list = []
        self._mark = -math.inf  # the previous tick's first read [s, the frames' clock]
        self._read_at = -math.inf

    def on_message_received(self, msg: can.Message) -> None:
        self._held.append(msg)

    def reading(self, t_s: float) -> None:
        """The tick's first read of the bus starts at ``t_s`` [s, the frames' clock]."""
        self._mark, self._read_at = self._read_at, t_s

    def flush(self) -> None:
        held = self._held
        if not held:
            return
        held.sort(key=lambda m: m.timestamp)  # stable: a tie keeps its logging order
        n = 0
        while n < len(held) and held[n].timestamp < self._mark:
            self._writer.on_message_received(held[n])
            n += 1
        del held[:n]

    def stop(self) -> None:
        self._mark = math.inf
        self.flush()
        self._writer.stop()


def audit_candump(profile: ActuationProfile, params: Params, path: str | Path) -> dict:
    """Re-check every command frame of a drive's candump, read back with hmpc's own reader and
    decoder, with fresh limit checks (independent of the loop's state): the ``limit_violations``
    of the run JSON. Returns {"limit_violations": n, "by_reason": {...}, "frames_checked": n}."""
    from hmpc.models.logs.canlog import read_log

    probs = Problems()
    ft = read_log(path, probs)
    db = profile.db
    tl = ToyotaLimits()
    chk_t = ToyotaSteerCheck(tl)
    al = AngleLimits.from_params(params)
    chk_a = (
        AngleCheck(al, profile.commands["steer_angle"].period_s)
        if "steer_angle" in profile.commands
        else None
    )
    by: dict[str, int] = {}
    checked = 0
    allowed = False
    v = 0.0
    ids = {c.message.frame_id: c for c in profile.commands.values()}
    speed_ch = profile.signal_map.channels["speed"]
    for i in range(len(ft)):
        fid = int(ft.arb_id[i])
        data = bytes(ft.data[i, : ft.dlc[i]])
        t = float(ft.t_s[i])
        try:
            m = db.get_message_by_frame_id(fid)
        except KeyError:
            continue
        if fid in ids:
            spec = ids[fid]
            raw = m.decode(data, decode_choices=False, scaling=False)
            checked += 1
            why = ""
            if spec.role == "steer_torque":
                why = chk_t.check(
                    int(raw[spec.values["steer_torque"]]), bool(raw[spec.enable[0]]), t, allowed
                )
            elif spec.role == "accel":
                s = m.get_signal_by_name(spec.values["accel_mps2"])
                a = raw[spec.values["accel_mps2"]] * s.scale
                why = accel_ok(a, allowed or a == 0.0, tl)
            elif spec.role == "steer_angle":
                s = m.get_signal_by_name(spec.values["steering_wheel_angle_rad"])
                assert chk_a is not None  # the profile has a steer_angle command
                why = chk_a.check(raw[spec.values["steering_wheel_angle_rad"]] * s.scale, v)
            elif spec.role == "pedals":
                sa = m.get_signal_by_name(spec.values["accel_pedal"]).scale
                sb = m.get_signal_by_name(spec.values["brake_pedal"]).scale
                why = pedals_ok(
                    raw[spec.values["accel_pedal"]] * sa, raw[spec.values["brake_pedal"]] * sb, al
                )
            if why:
                by[why] = by.get(why, 0) + 1
            continue
        if m.name == speed_ch.message:
            sig = m.decode(data, decode_choices=False)
            v = float(speed_ch.evaluate({k: np.array([x]) for k, x in sig.items()})[0])
        if m.name == "STEER_TORQUE_SENSOR" and profile.steering == "torque":
            chk_t.eps_torque(m.decode(data, decode_choices=False)["STEER_TORQUE_EPS"])
        it = profile.feedback.get("accepts_long")
        if it is not None and m.name == it.message:
            allowed = it.flag(float(m.decode(data, decode_choices=False)[it.signal]))
    return {"limit_violations": int(sum(by.values())), "by_reason": by, "frames_checked": checked}
