"""A block of CAN frames held as numpy columns (one row per frame).

Readers (``models.logs.canlog``) produce a :class:`FrameTable`; decoders
(``models.logs.decode``) consume it. Rows keep the 1-based line (text logs) or frame number
(binary logs) of the source so every later problem can be reported where it came from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: bytes stored per frame; CAN FD payloads of up to 64 bytes fit.
MAX_PAYLOAD = 64
CAN_ERR_FLAG = 0x20000000  # SocketCAN error-frame flag in the 32-bit id
EFF_MASK = 0x1FFFFFFF  # 29-bit identifier
SFF_MAX = 0x7FF  # 11-bit identifier


@dataclass
class FrameTable:
    """CAN frames as columns.

    Attributes:
        t_s: receive time [s], float64, in the log's own clock.
        bus: bus/channel number, int16.
        arb_id: arbitration id, uint32.
        is_extended: 29-bit id flag, bool.
        dlc: payload length [bytes], uint8.
        data: payload bytes, uint8 array of shape (n, width), zero padded to ``width``.
        where: 1-based source line (text) or frame number (binary) of each row, int64.
        path: the file the frames came from.
    """

    t_s: np.ndarray
    bus: np.ndarray
    arb_id: np.ndarray
    is_extended: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    where: np.ndarray
    path: str = ""

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @classmethod
    def empty(cls, path: str = "", width: int = 8) -> FrameTable:
        return cls(
            np.zeros(0),
            np.zeros(0, np.int16),
            np.zeros(0, np.uint32),
            np.zeros(0, bool),
            np.zeros(0, np.uint8),
            np.zeros((0, width), np.uint8),
            np.zeros(0, np.int64),
            path,
        )

    def take(self, idx) -> FrameTable:
        """Rows selected by a boolean mask or an index array."""
        return FrameTable(
            self.t_s[idx],
            self.bus[idx],
            self.arb_id[idx],
            self.is_extended[idx],
            self.dlc[idx],
            self.data[idx],
            self.where[idx],
            self.path,
        )

    @classmethod
    def concat(cls, parts: list[FrameTable]) -> FrameTable:
        if not parts:
            return cls.empty()
        width = max(p.data.shape[1] for p in parts)
        datas = [
            p.data
            if p.data.shape[1] == width
            else np.pad(p.data, ((0, 0), (0, width - p.data.shape[1])))
            for p in parts
        ]
        return cls(
            np.concatenate([p.t_s for p in parts]),
            np.concatenate([p.bus for p in parts]),
            np.concatenate([p.arb_id for p in parts]),
            np.concatenate([p.is_extended for p in parts]),
            np.concatenate([p.dlc for p in parts]),
            np.concatenate(datas),
            np.concatenate([p.where for p in parts]),
            parts[0].path,
        )
