"""A recorded log as a CAN bus on a simulated clock: the drive loop's log replay.

:class:`ReplayBus` is a ``can.BusABC`` registered with python-can as the interface
``hmpc_replay`` (entry point ``can.interface`` in pyproject.toml, python-can's plugin
mechanism), so the drive loop opens it like any other bus (``can.Bus(interface="hmpc_replay",
...)``) and stays the only owner of a bus. It behaves like a real bus on a clock that only
moves when the loop sleeps (:class:`SimClock`):

- ``recv(timeout)`` returns the next logged frame whose time has come on the simulated clock,
  in log order; with a timeout and nothing due, it waits (advances the clock) until the next
  frame or the timeout, as a real bus blocks;
- ``send(msg)`` records a copy stamped with the simulated time (what hmpc would have sent).

Nothing depends on the wall clock, so the same log and the same controller give the same frames
byte for byte (openpilot's process replay does the same for its processes).
"""

from __future__ import annotations

import copy
import hashlib

import can
import numpy as np

from hmpc.models.logs.frames import FrameTable

from hmpc.controller.simclock import SimClock


class ReplaySource:
    """The frames a replay bus serves: one bus of a log, in time order, minus the ids the loop
    itself sends (in the car those would be hmpc's own frames, not the recorded sender's).

    Args:
        frames: the log (``models.logs.canlog.read_log``).
        bus: the log's bus number to serve (the actuation profile's bus).
        exclude_ids: arbitration ids not served (the profile's command messages).
    """

    def __init__(self, frames: FrameTable, bus: int, exclude_ids=()):
        keep = frames.bus == int(bus)
        if len(exclude_ids):
            keep &= ~np.isin(frames.arb_id, np.asarray(list(exclude_ids), dtype=np.uint32))
        idx = np.flatnonzero(keep)
        order = np.argsort(frames.t_s[idx], kind="stable")
        idx = idx[order]
        self.t_s = frames.t_s[idx].astype(float)
        self.arb_id = frames.arb_id[idx]
        self.is_extended = frames.is_extended[idx]
        self.dlc = frames.dlc[idx]
        self.data = frames.data[idx]
        self.pos = 0
        self.sent: list[can.Message] = []

    def __len__(self) -> int:
        return len(self.t_s)

    def next_time(self) -> float | None:
        """Time of the next frame not yet served [s], None when the log is exhausted."""
        return float(self.t_s[self.pos]) if self.pos < len(self.t_s) else None

    def pop(self, channel) -> can.Message:
        i = self.pos
        self.pos += 1
        n = int(self.dlc[i])
        return can.Message(
            timestamp=float(self.t_s[i]),
            arbitration_id=int(self.arb_id[i]),
            is_extended_id=bool(self.is_extended[i]),
            dlc=n,
            data=bytes(self.data[i, :n]),
            channel=channel,
            is_rx=True,
        )

    def sent_sha256(self, decimals: int = 4) -> str:
        """sha256 over every sent frame's id, data and timestamp rounded to ``decimals`` [s]:
        equal for two runs that sent the same bytes at the same simulated times."""
        h = hashlib.sha256()
        for m in self.sent:
            h.update(
                f"{m.arbitration_id:08x} {bytes(m.data).hex()} "
                f"{m.timestamp:.{decimals}f}\n".encode()
            )
        return h.hexdigest()


class ReplayBus(can.BusABC):
    """python-can interface ``hmpc_replay``: a :class:`ReplaySource` on a :class:`SimClock`.

    Args:
        channel: a name for the bus (shown in ``channel_info``).
        source: the frames to serve; it also keeps the frames sent.
        clock: the simulated clock shared with the drive loop.
    """

    def __init__(self, channel=None, *, source: ReplaySource, clock: SimClock, **kwargs):
        if not isinstance(source, ReplaySource) or clock is None:
            raise can.CanInitializationError(
                "hmpc_replay needs source=ReplaySource and clock=SimClock"
            )
        self.source = source
        self.clock = clock
        self.channel_info = f"hmpc replay {channel or ''}".strip()
        self._channel = channel
        super().__init__(channel=channel, **kwargs)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame due on the simulated clock; with ``timeout`` > 0 (or None: forever)
        the clock advances to the next frame when it falls within the timeout."""
        while True:
            nxt = self.source.next_time()
            if nxt is None:
                if timeout:
                    self.clock.sleep(timeout)
                return None
            now = self.clock.time()
            if nxt <= now:
                msg = self.source.pop(self._channel)
                if self._matches_filters(msg):
                    return msg
                continue
            if timeout is not None and nxt - now > timeout:
                self.clock.sleep(timeout)
                return None
            self.clock.sleep(nxt - now)

    def _recv_internal(self, timeout):  # recv() is overridden: the clock is simulated
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Record a copy of ``msg`` stamped with the simulated time."""
        m = copy.copy(msg)
        m.data = bytearray(msg.data)
        m.timestamp = self.clock.time()
        self.source.sent.append(m)

    def shutdown(self) -> None:
        super().shutdown()
