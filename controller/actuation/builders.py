"""Frame builders: one small pure function per outgoing message (docs/style.md 2).

Each takes physical command values, the enable state and the rolling counter, and returns the
``can.Message`` to send: the profile's constants, the command signals, the enable bits and the
counter are encoded with cantools (raw values, see :func:`encode_command`), then the checksum
byte is written. No state, no bus: the drive loop (``drive.py``) owns counters and the bus.

Raises :class:`EncodeError` (a ``ValueError``) when a value is not finite or does not fit its
signal: a frame is never wrapped around or silently clipped here; the limits are applied before
(``safety.py``), and a value that still does not fit is a bug to stop on.
"""

from __future__ import annotations

import math

import can

from hmpc.controller.actuation.checksums import SCHEMES
from hmpc.controller.actuation.profiles import CommandSpec


class EncodeError(ValueError):
    """A command value that cannot be encoded in its signal (not finite, or out of its range)."""


def _raw(sig, value: float) -> int:
    """Physical value -> raw integer of ``sig`` (round half away from zero), range-checked."""
    v = float(value)
    if not math.isfinite(v):
        raise EncodeError(f"{sig.name}: value {value!r} is not finite")
    x = (v - sig.offset) / sig.scale
    raw = int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)
    lo, hi = (
        (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1)
        if sig.is_signed
        else (0, (1 << sig.length) - 1)
    )
    if not lo <= raw <= hi:
        raise EncodeError(
            f"{sig.name}: value {v:g} does not fit {sig.length} bits "
            f"({'signed' if sig.is_signed else 'unsigned'}, scale {sig.scale:g})"
        )
    return raw


def encode_command(
    spec: CommandSpec, quantities: dict[str, float], enabled: bool, counter: int | None
) -> can.Message:
    """The frame of ``spec`` carrying ``quantities`` (quantity -> physical value).

    Args:
        spec: the profile's command (message, signals, counter, checksum, constants).
        quantities: every quantity of the spec's role, in SI/DBC units.
        enabled: enable bits set (1) or cleared (0).
        counter: the rolling counter value (taken modulo its range); None for messages without.

    Raises:
        EncodeError: a value not finite or out of its signal's range; a counter missing.
    """
    msg = spec.message
    sigs = {s.name: s for s in msg.signals}
    raw: dict[str, int] = {s.name: 0 for s in msg.signals}
    raw.update({k: int(v) for k, v in spec.constants.items()})
    for q, sname in spec.values.items():
        if q not in quantities:
            raise EncodeError(f"{msg.name}: quantity '{q}' missing")
        raw[sname] = _raw(sigs[sname], quantities[q])
    for sname in spec.enable:
        raw[sname] = 1 if enabled else 0
    if spec.counter is not None:
        if counter is None:
            raise EncodeError(f"{msg.name}: needs a counter value")
        raw[spec.counter] = int(counter) % spec.counter_modulo
    data = bytearray(msg.encode(raw, scaling=False, padding=False, strict=False))
    if spec.checksum is not None:
        assert spec.scheme is not None  # the profile loader sets both or neither
        data[-1] = SCHEMES[spec.scheme](msg.frame_id, data, len(data))
    return can.Message(
        arbitration_id=msg.frame_id,
        data=bytes(data),
        dlc=len(data),
        is_extended_id=msg.is_extended_frame,
    )


# ------------------------------------------------------------------------------ Toyota
def steering_lka(
    spec: CommandSpec, steer_torque: float, steer_request: bool, counter: int
) -> can.Message:
    """``STEERING_LKA`` (0x2E4): EPS torque request [raw units, +-1500], request bit, 6-bit
    counter, Toyota checksum."""
    return encode_command(spec, {"steer_torque": steer_torque}, steer_request, counter)


def acc_control(spec: CommandSpec, accel_mps2: float) -> can.Message:
    """``ACC_CONTROL`` (0x343): acceleration request [m/s^2], Toyota checksum, no counter."""
    return encode_command(spec, {"accel_mps2": accel_mps2}, True, None)


# ------------------------------------------------------------------------ by-wire kit
def bw_steer_cmd(
    spec: CommandSpec, steering_wheel_angle_rad: float, enable: bool, counter: int
) -> can.Message:
    """``BW_STEER_CMD``: steering-wheel angle [rad], enable bit, 4-bit counter, CRC-8."""
    return encode_command(
        spec, {"steering_wheel_angle_rad": steering_wheel_angle_rad}, enable, counter
    )


def bw_pedal_cmd(
    spec: CommandSpec, accel_pedal: float, brake_pedal: float, enable: bool, counter: int
) -> can.Message:
    """``BW_PEDAL_CMD``: accelerator and brake positions [0..1], enable bits, counter, CRC-8."""
    return encode_command(
        spec, {"accel_pedal": accel_pedal, "brake_pedal": brake_pedal}, enable, counter
    )


def bw_heartbeat(spec: CommandSpec, engage: bool, counter: int) -> can.Message:
    """``BW_HEARTBEAT``: engage request bit, counter, CRC-8."""
    return encode_command(spec, {}, engage, counter)


def decode_command(spec: CommandSpec, data: bytes) -> dict:
    """Raw signal values of a command frame (the vehicle node's and the tests' view)."""
    return spec.message.decode(bytes(data), decode_choices=False, scaling=False)
