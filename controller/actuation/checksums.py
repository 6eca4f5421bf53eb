"""Frame integrity codes: Toyota's additive checksum and CRC-8 SAE J1850, each implemented once.

Both are pure functions of the frame's arbitration id and payload; the builders
(``builders.py``) write them, the vehicle simulator node (``vehicle_node.py``) checks them like
an ECU would.
"""

from __future__ import annotations


def toyota_checksum(arb_id: int, payload: bytes | bytearray, length: int | None = None) -> int:
    """Toyota's checksum byte: (id low byte + id high byte + length + payload[:-1]) mod 256.

    Checked against every ``STEERING_LKA`` (0x2E4) and ``ACC_CONTROL`` (0x343) frame openpilot
    sent in the bundled comma2k19 minute (tests/actuation/test_actuation_golden.py), e.g.
    ``2E4#BE000000A9``: 0x02 + 0xE4 + 5 + 0xBE = 0x1A9 -> 0xA9.

    Args:
        arb_id: 11-bit arbitration id.
        payload: the frame's bytes, the checksum byte last (its value is ignored).
        length: the DLC [bytes] (default ``len(payload)``).
    """
    n = len(payload) if length is None else int(length)
    s = (arb_id & 0xFF) + ((arb_id >> 8) & 0xFF) + n
    for b in payload[: n - 1]:
        s += b
    return s & 0xFF


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ poly) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table.append(c)
    return tuple(table)


#: CRC-8 SAE J1850: polynomial x^8 + x^4 + x^3 + x^2 + 1 (0x1D), init 0xFF, final xor 0xFF,
#: not reflected (the AUTOSAR "CRC8" of SWS_CRCLibrary; check value 0x4B for b"123456789").
_J1850 = _crc8_table(0x1D)


def crc8_j1850(data: bytes | bytearray) -> int:
    """CRC-8 SAE J1850 of ``data`` (check value: ``crc8_j1850(b"123456789") == 0x4B``)."""
    c = 0xFF
    for b in data:
        c = _J1850[c ^ b]
    return c ^ 0xFF


def bywire_crc(arb_id: int, payload: bytes | bytearray, length: int | None = None) -> int:
    """The by-wire kit's CRC: CRC-8 SAE J1850 over the id (2 bytes, big-endian) and
    payload[:-1] (the CRC byte is the last byte), so a frame copied to another id fails."""
    n = len(payload) if length is None else int(length)
    return crc8_j1850(bytes(((arb_id >> 8) & 0xFF, arb_id & 0xFF)) + bytes(payload[: n - 1]))


#: scheme name (as written in an actuation profile) -> function(arb_id, payload) -> int
SCHEMES = {"toyota": toyota_checksum, "crc8_j1850": bywire_crc}
