"""The drive loop's view of the car: the feedback frames decoded with ingest's own signal map
and decoder (``models.logs.signalmap`` / ``models.logs.decode``: one source of truth for what a
frame means) into the latest canonical channels (wheel speeds, steering-wheel angle, yaw rate)
and the profile's status items (the car accepting commands, driver override, EPS torque).

It also learns the wheel speeds' period from their arrival times: the watchdog's stale-feedback
rule counts in those periods.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from hmpc.models.errors import Problems
from hmpc.models.logs.decode import decode_frames
from hmpc.models.logs.frames import FrameTable

from hmpc.controller.actuation.profiles import ActuationProfile
from hmpc.controller.actuation.safety import ToyotaLimits


class Feedback:
    """Latest decoded feedback: canonical channels (signal map) and status items (profile)."""

    def __init__(self, profile: ActuationProfile):
        self.profile = profile
        self.smap = profile.signal_map
        self.names = profile.feedback_messages()
        self.channels: dict[str, tuple[float, float]] = {}  # channel -> (t_s, SI value)
        self.items: dict[str, tuple[float, float]] = {}  # item -> (t_s, value)
        self.eps = deque([0.0] * ToyotaLimits().eps_samples, maxlen=ToyotaLimits().eps_samples)
        self.ws_times: deque = deque(maxlen=40)  # ticks that decoded wheel speeds [s]
        self.ws_counts: deque = deque(maxlen=40)  # wheel-speed frames in each of them
        self.problems = Problems()
        by_msg: dict[str, list] = {}
        for ch in self.smap.channels.values():
            if ch.gear is None:
                by_msg.setdefault(ch.message, []).append(ch)
        self._maps = by_msg
        self._items: dict[str, list] = {}
        for it in profile.feedback.values():
            self._items.setdefault(it.message, []).append(it)
        self.ids = {profile.db.get_message_by_name(n).frame_id for n in self.names}
        ws = profile.signal_map.channels.get("speed")
        self.speed_msg = ws.message if ws is not None else None

    def update(self, msgs: list, t_s: float) -> list[str]:
        """Decode this tick's frames; returns the message names seen."""
        msgs = [m for m in msgs if m.arbitration_id in self.ids]
        if not msgs:
            return []
        n = len(msgs)
        data = np.zeros((n, 8), np.uint8)
        for i, m in enumerate(msgs):
            data[i, : len(m.data)] = np.frombuffer(bytes(m.data), np.uint8)[:8]
        ft = FrameTable(
            np.full(n, t_s),
            np.zeros(n, np.int16),
            np.array([m.arbitration_id for m in msgs], np.uint32),
            np.zeros(n, bool),
            np.array([len(m.data) for m in msgs], np.uint8),
            data,
            np.arange(1, n + 1, dtype=np.int64),
            "<bus>",
        )
        present = {self.profile.db.get_message_by_frame_id(i).name for i in set(ft.arb_id.tolist())}
        dec = decode_frames(
            ft, self.profile.db, self.problems, names=[x for x in self.names if x in present]
        )
        for name, d in dec.items():
            if len(d) == 0:
                continue
            for ch in self._maps.get(name, ()):
                if ch.bus is not None and ch.bus != 0:
                    continue
                v = ch.evaluate(d.signals)[-1]
                if np.isfinite(v):
                    self.channels[ch.channel] = (t_s, float(v))
            for it in self._items.get(name, ()):
                vals = d.signals[it.signal]
                self.items[it.name] = (t_s, float(vals[-1]))
                if it.name == "eps_torque":
                    for x in vals:
                        self.eps.append(float(x) * ToyotaLimits().eps_torque_factor)
            if name == self.speed_msg:
                # one arrival time per tick, with the number of frames that tick: frames
                # decoded twice in a tick (step 2 and the last look before encoding) must not
                # add zero intervals, and two frames in one tick are two periods
                if self.ws_times and self.ws_times[-1] == t_s:
                    self.ws_counts[-1] += len(d)
                else:
                    self.ws_times.append(t_s)
                    self.ws_counts.append(len(d))
        return list(dec)

    def wheel_speed_period(self) -> float | None:
        """The wheel speeds' period [s] learned from the last ~40 ticks that decoded them:
        their time span over the frames after the first tick. The median interval between
        such ticks would be quantised to the 10 ms tick (83 Hz Toyota frames arrive 10 or
        20 ms apart: median 10 ms, the stale rule's 3 periods 30 ms instead of 36 ms)."""
        if len(self.ws_times) <= 5:
            return None
        n = sum(self.ws_counts) - self.ws_counts[0]
        return (self.ws_times[-1] - self.ws_times[0]) / n if n > 0 else None

    def value(self, channel: str, default: float = math.nan) -> float:
        x = self.channels.get(channel)
        return default if x is None else x[1]

    def flag(self, item: str) -> bool:
        it = self.profile.feedback.get(item)
        x = self.items.get(item)
        return False if it is None or x is None else it.flag(x[1])

    def item(self, item: str, default: float = 0.0) -> float:
        x = self.items.get(item)
        return default if x is None else x[1]
