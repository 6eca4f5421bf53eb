"""The tele-operation link: packets, HMAC-SHA256, key files, the vehicle-side receiver.

The operator station sends one command packet per period (50 Hz) over UDP to the vehicle
(default ``127.0.0.1:47700``, ``docs/conventions.md``); the vehicle answers with telemetry
packets (vehicle state and link statistics) at a lower rate. Both directions are authenticated
with the same pre-shared key.

Authentication. HMAC-SHA256 from the standard library (``hmac``/``hashlib``), not an AEAD:
the threat on a LAN or loopback is forgery and replay of commands that reach a CAN bus;
confidentiality of pedal and steering values is not required, so encryption would add a
dependency (``cryptography``) for nothing. The tag is the full 32-byte HMAC-SHA256 over every
byte before it, compared with ``hmac.compare_digest`` (constant time). Replay is stopped by the
sequence number (strictly increasing per key, see below) and the freshness window, both inside
the authenticated bytes.

Command packet, 76 bytes, network byte order (``struct`` ``"!"``):

    offset size field
    0      1    version        PROTOCOL_VERSION (1)
    1      1    kind           1 = command (2 = telemetry: a telemetry packet replayed as a
                               command is refused even though the key is the same)
    2      1    mode           Mode: 1 pedals, 2 references, 3 engage, 4 disengage,
                               5 hand over to the MPC, 6 take over from the MPC
    3      1    flags          bit 0: dead-man held; other bits must be 0
    4      8    seq            uint64, strictly increasing
    12     8    t_send_us      int64, sender's clock [us]
    20     24   values         3 x float64: pedals: steering-wheel angle [rad], accel pedal
                               [1], brake pedal [1]; references: speed [m/s], curvature
                               [1/m], 0; other modes: 0, 0, 0
    44     32   mac            HMAC-SHA256(key, bytes 0..43)

Telemetry packet (``TELEMETRY_SIZE`` bytes): see ``_TEL`` below, same header and MAC.

Sequence numbers. The operator starts its sequence at its wall clock in microseconds and adds
one per packet, so a restarted operator (or the next operator after a lost link) continues
above every number the vehicle has seen, without keeping state on disk. The receiver never
resets its last sequence number while it runs.

Clocks. The freshness check compares the packet's send time with the receiver's clock: a
packet older than ``LinkConfig.freshness_s`` (100 ms) or more than ``future_tolerance_s``
ahead is refused. Both ends use the wall clock (``time.time``). On loopback it is the same
clock, so the age is the true transport-plus-queueing delay. On two machines the clocks must
be synchronised (chrony/NTP on a LAN keeps them within about 1 ms, PTP better); the receiver
reports ``clock_offset_ms`` (the smallest receive-minus-send time seen, an upper bound of the
offset plus the fastest delivery) so a bad sync shows. hmpc deliberately does NOT learn the
offset from the first authenticated packet: after a receiver restart the first packet could be
a recorded packet of an earlier session, and learning the offset from it would make the whole
replayed recording look fresh.

Receiver. ``LinkReceiver.poll(now_s)`` drains the non-blocking socket once per control
period, at most ``max_datagrams_per_poll`` datagrams (so a flood cannot stretch the period;
the rest wait in the kernel buffer). Each datagram is checked in this order and the first
failure is its rejection reason (counted, never passed on):

    oversized        longer than a command packet
    truncated        shorter than a command packet
    bad_mac          HMAC does not verify (wrong key, any flipped bit)
    malformed        authenticated, but wrong version/kind/mode/flags or non-finite values
    second_operator  authenticated, from another source address while one operator holds
                     the link
    replayed         sequence number equal to the last accepted one
    old_sequence     sequence number below the last accepted one (replayed or reordered)
    stale            older than the freshness window
    future           send time ahead of the receiver's clock by more than the tolerance

The receiver is a small state machine: pedal and reference commands are delivered only while
engaged (an ENGAGE packet with the dead-man held engages). Stop requests (``StopRequest``,
latched until the next ENGAGE): ``link_lost`` (no valid packet for ``timeout_s`` = 200 ms, ten
20 ms periods), ``dead_man_released`` (a valid packet with the dead-man flag clear) and
``operator_disengaged``. The link timeout counts from the last valid packet *read*, and is
checked before and after each drain: fresh packets starved behind a flood in the socket queue
do not hide the silence the car has seen. The host (the drive loop) turns a stop request into a
controlled stop. A lost link also releases the link holder so another operator may take it.

Latency (``tools/bench_teleop_link.py``, loopback, 2-core development machine): p50 0.22 ms,
p99 0.32 ms from the operator's send to the receiver's read; a receiver polled by a 50 Hz loop
adds the wait for the next period (up to 20 ms, depending on the two loops' phase).
"""

from __future__ import annotations

import enum
import errno
import hashlib
import hmac
import math
import socket
import struct
import time
from dataclasses import dataclass, field
from collections.abc import Callable

import numpy as np

from hmpc.controller.teleop.keys import MIN_KEY_BYTES as MIN_KEY_BYTES
from hmpc.controller.teleop.keys import KeyFileError as KeyFileError
from hmpc.controller.teleop.keys import create_key as create_key
from hmpc.controller.teleop.keys import load_key as load_key

PROTOCOL_VERSION = 1
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 47700
MAC_SIZE = 32

KIND_COMMAND = 1
KIND_TELEMETRY = 2
FLAG_DEAD_MAN = 0x01


class Mode(enum.IntEnum):
    """What a command packet asks for."""

    PEDALS = 1  #: values = steering-wheel angle [rad], accel pedal [1], brake pedal [1]
    REFERENCES = 2  #: values = speed [m/s], curvature [1/m], 0
    ENGAGE = 3  #: start accepting commands (dead-man held)
    DISENGAGE = 4  #: the operator ends the run: controlled stop
    HANDOVER_MPC = 5  #: the MPC drives; the operator keeps the dead-man and the link alive
    TAKE_OVER = 6  #: the operator drives again


#: rejection reasons, in the order they are checked (also the order in telemetry)
REASONS = (
    "oversized",
    "truncated",
    "bad_mac",
    "malformed",
    "second_operator",
    "replayed",
    "old_sequence",
    "stale",
    "future",
)

_CMD = struct.Struct("!BBBBQqddd")
COMMAND_SIZE = _CMD.size + MAC_SIZE  # 76
#: version, kind, flags (bit 0 engaged, bit 1 MPC in control, bit 2 link held), 0, seq,
#: t_send_us, speed [m/s], steering-wheel angle [rad], zone index (-1 unknown), 0, zone name,
#: pedal mode, stop t [s] (NaN: none), stop detected t [s], stop reason, received, accepted,
#: delivered, ignored (not engaged), rejected per REASONS, lost (sequence gaps), latency p50
#: and p99 [ms], max gap between valid packets [ms], clock offset bound [ms]
_TEL = struct.Struct("!BBBBQqddbb8s8sdd24sIIII" + "I" * len(REASONS) + "I" + "ffff")
TELEMETRY_SIZE = _TEL.size + MAC_SIZE
_BUF_SIZE = 65536  # any UDP datagram fits: an oversized one is seen whole, never cut short


def parse_address(text: str, default_port: int = DEFAULT_PORT) -> tuple[str, int]:
    """``HOST:PORT`` (or ``HOST``) to a (host, port) pair; ValueError when malformed."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(default_port)
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"address {text!r} is not HOST:PORT")
    return host, int(port)


# --------------------------------------------------------------------------- packets
def _mac(key: bytes, body: bytes | bytearray | memoryview) -> bytes:
    return hmac.digest(key, body, hashlib.sha256)


def _us(t_s: float) -> int:
    return int(round(t_s * 1e6))


@dataclass(frozen=True)
class TeleopCommand:
    """One operator command, as sent and as delivered by the receiver.

    Attributes:
        mode: what it asks for (``Mode``).
        values: three numbers whose meaning depends on ``mode`` (module docstring).
        dead_man: the operator's dead-man switch is held.
        seq: sequence number (set by the sender). t_send_s: sender's clock [s].
        t_recv_s: receiver's clock when read [s] (NaN on the operator side).
    """

    mode: Mode
    values: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dead_man: bool = True
    seq: int = 0
    t_send_s: float = math.nan
    t_recv_s: float = math.nan

    @classmethod
    def pedals(
        cls,
        steering_wheel_angle_rad: float,
        accel_pedal: float,
        brake_pedal: float,
        dead_man: bool = True,
    ) -> TeleopCommand:
        return cls(
            Mode.PEDALS,
            (float(steering_wheel_angle_rad), float(accel_pedal), float(brake_pedal)),
            dead_man,
        )

    @classmethod
    def references(
        cls, speed_mps: float, curvature_1pm: float, dead_man: bool = True
    ) -> TeleopCommand:
        return cls(Mode.REFERENCES, (float(speed_mps), float(curvature_1pm), 0.0), dead_man)


def encode_command(key: bytes, cmd: TeleopCommand, seq: int, t_send_s: float) -> bytes:
    """The 76-byte authenticated command packet (pure function)."""
    body = _CMD.pack(
        PROTOCOL_VERSION,
        KIND_COMMAND,
        int(cmd.mode),
        FLAG_DEAD_MAN if cmd.dead_man else 0,
        int(seq),
        _us(t_send_s),
        *cmd.values,
    )
    return body + _mac(key, body)


@dataclass(frozen=True)
class VehicleStatus:
    """What the vehicle side tells the operator besides link statistics.

    Attributes:
        speed_mps, steering_wheel_angle_rad: measured [m/s], [rad] (NaN unknown).
        zone: zone index (-1 unknown); zone_name: e.g. ``idle``; pedal_mode: ``throttle``,
        ``brake``, ``coast`` or ``hold``; engaged / mpc_in_control: who drives.
    """

    speed_mps: float = math.nan
    steering_wheel_angle_rad: float = math.nan
    zone: int = -1
    zone_name: str = ""
    pedal_mode: str = ""


@dataclass(frozen=True)
class StopRequest:
    """The receiver asks the host for a controlled stop.

    Attributes:
        reason: ``link_lost``, ``dead_man_released`` or ``operator_disengaged``.
        t_s: when it happened (link lost: the last valid packet's read time) [s].
        detected_t_s: when the receiver reported it [s].
    """

    reason: str
    t_s: float
    detected_t_s: float

    def to_dict(self) -> dict:
        return {"reason": self.reason, "t_s": self.t_s, "detected_t_s": self.detected_t_s}


@dataclass(frozen=True)
class Telemetry:
    """A decoded telemetry packet (operator side)."""

    seq: int
    t_send_s: float
    engaged: bool
    mpc_in_control: bool
    link_held: bool
    vehicle: VehicleStatus
    stop: StopRequest | None
    received: int
    accepted: int
    delivered: int
    ignored: int
    rejected: dict[str, int]
    lost: int
    latency_p50_ms: float
    latency_p99_ms: float
    max_gap_ms: float
    clock_offset_ms: float


def _s(text: str, n: int) -> bytes:
    return text.encode("ascii", errors="replace")[:n]


def _unstr(b: bytes) -> str:
    return b.rstrip(b"\0").decode("ascii", errors="replace")


def encode_telemetry(
    key: bytes,
    seq: int,
    t_send_s: float,
    *,
    engaged: bool,
    mpc_in_control: bool,
    link_held: bool,
    vehicle: VehicleStatus,
    stop: StopRequest | None,
    stats: dict,
) -> bytes:
    """An authenticated telemetry packet (pure function); ``stats`` as ``LinkReceiver.stats``."""
    flags = (1 if engaged else 0) | (2 if mpc_in_control else 0) | (4 if link_held else 0)
    zone = vehicle.zone if -128 <= vehicle.zone <= 127 else -1
    lat = stats["latency_ms"]
    body = _TEL.pack(
        PROTOCOL_VERSION,
        KIND_TELEMETRY,
        flags,
        0,
        int(seq),
        _us(t_send_s),
        float(vehicle.speed_mps),
        float(vehicle.steering_wheel_angle_rad),
        zone,
        0,
        _s(vehicle.zone_name, 8),
        _s(vehicle.pedal_mode, 8),
        stop.t_s if stop else math.nan,
        stop.detected_t_s if stop else math.nan,
        _s(stop.reason if stop else "", 24),
        stats["received"],
        stats["accepted"],
        stats["delivered"],
        stats["ignored_not_engaged"],
        *(stats["rejected"][r] for r in REASONS),
        stats["lost"],
        _nan(lat["p50"]),
        _nan(lat["p99"]),
        _nan(stats["max_gap_ms"]),
        _nan(stats["clock_offset_ms"]),
    )
    return body + _mac(key, body)


def _nan(x) -> float:
    return math.nan if x is None else float(x)


def _none(x: float):
    return None if math.isnan(x) else x


def decode_telemetry(key: bytes, data: bytes) -> Telemetry | None:
    """A verified telemetry packet, or None (wrong size, bad MAC, wrong version or kind)."""
    if len(data) != TELEMETRY_SIZE:
        return None
    body, tag = data[:-MAC_SIZE], data[-MAC_SIZE:]
    if not hmac.compare_digest(_mac(key, body), tag):
        return None
    f = _TEL.unpack(body)
    if f[0] != PROTOCOL_VERSION or f[1] != KIND_TELEMETRY:
        return None
    (
        _,
        _,
        flags,
        _,
        seq,
        t_us,
        v,
        sw,
        zone,
        _,
        zname,
        pmode,
        stop_t,
        stop_det,
        reason,
        received,
        accepted,
        delivered,
        ignored,
    ) = f[:19]
    n = len(REASONS)
    rej = dict(zip(REASONS, f[19 : 19 + n]))
    lost, p50, p99, gap, off = f[19 + n :]
    reason_s = _unstr(reason)
    return Telemetry(
        seq=seq,
        t_send_s=t_us * 1e-6,
        engaged=bool(flags & 1),
        mpc_in_control=bool(flags & 2),
        link_held=bool(flags & 4),
        vehicle=VehicleStatus(v, sw, zone, _unstr(zname), _unstr(pmode)),
        stop=StopRequest(reason_s, stop_t, stop_det) if reason_s else None,
        received=received,
        accepted=accepted,
        delivered=delivered,
        ignored=ignored,
        rejected=rej,
        lost=lost,
        latency_p50_ms=p50,
        latency_p99_ms=p99,
        max_gap_ms=gap,
        clock_offset_ms=off,
    )


# -------------------------------------------------------------------------- receiver
@dataclass(frozen=True)
class LinkConfig:
    """Receiver settings (units in the names, reasons in comments)."""

    # Freshness window: 100 ms. A packet is sent every 20 ms; a LAN or loopback delivers in
    # well under 1 ms, so 100 ms is five periods of margin for scheduling jitter, and a
    # replayed packet is useless after it (its sequence number is refused anyway).
    freshness_s: float = 0.100
    # Send times ahead of the receiver's clock by more than this are refused: 50 ms is far
    # beyond a synchronised LAN clock error (about 1 ms with chrony) and well inside the window.
    future_tolerance_s: float = 0.050
    # No valid packet for 200 ms -> stop (ten 20 ms periods).
    timeout_s: float = 0.200
    # Work per poll is bounded: a datagram that reaches the HMAC costs about 6 us in Python
    # (measured on the 2-core development machine), so 512 take about 3 ms, a seventh of a
    # 20 ms period. A flood beyond 512 per period fills the queue ahead of the operator's
    # packets and ends in a link_lost stop: a flood cannot be prevented here, only made safe.
    max_datagrams_per_poll: int = 512
    # Kernel receive buffer asked for [bytes]: room for a burst while the loop computes
    # (Linux caps it at net.core.rmem_max).
    rcvbuf_bytes: int = 1 << 22
    # Latencies kept for the p50/p99 figures (a ring buffer; the last 4096 packets, 82 s).
    latency_window: int = 4096

    def __post_init__(self):
        for name in ("freshness_s", "future_tolerance_s", "timeout_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"LinkConfig.{name} must be positive and finite, got {v!r}")
        if self.max_datagrams_per_poll < 1 or self.latency_window < 1:
            raise ValueError("LinkConfig: max_datagrams_per_poll and latency_window must be >= 1")


@dataclass
class PollResult:
    """What one ``LinkReceiver.poll`` found.

    Attributes:
        commands: the commands passed on to the host, oldest first.
        stop: a stop request raised in this poll (None: none new).
        datagrams: datagrams read in this poll (<= ``max_datagrams_per_poll``).
        budget_exhausted: the poll stopped at its budget; more may be waiting.
    """

    commands: list[TeleopCommand] = field(default_factory=list)
    stop: StopRequest | None = None
    datagrams: int = 0
    budget_exhausted: bool = False


class LinkReceiver:
    """The vehicle side of the link (module docstring): a non-blocking UDP socket drained by
    ``poll`` once per control period.

    Args:
        key: the pre-shared key (``load_key``).
        bind: (host, port) to listen on; port 0 picks a free port (see ``address``).
        config: ``LinkConfig``.
        clock: the receiver's clock [s] (default ``time.time``; tests inject simulated time).
    """

    def __init__(
        self,
        key: bytes,
        bind: tuple[str, int] = (DEFAULT_HOST, DEFAULT_PORT),
        config: LinkConfig | None = None,
        clock: Callable[[], float] = time.time,
    ):
        if len(key) < MIN_KEY_BYTES:
            raise ValueError(f"key must have at least {MIN_KEY_BYTES} bytes")
        self._key = bytes(key)
        self.config = config or LinkConfig()
        self.clock = clock
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.config.rcvbuf_bytes)
            self.sock.bind(bind)
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self._buf = bytearray(_BUF_SIZE)
        self._view = memoryview(self._buf)
        # state
        self.holder: tuple[str, int] | None = None
        self.engaged = False
        self.mpc_in_control = False
        self.stop: StopRequest | None = None
        self._last_seq = -1
        self._last_valid_s: float | None = None
        self._tel_seq = time.time_ns() // 1000
        # statistics
        self.received = 0
        self.accepted = 0
        self.delivered = 0
        self.ignored_not_engaged = 0
        self.lost = 0
        self.polls = 0
        self.polls_budget_exhausted = 0
        self.rejected = {r: 0 for r in REASONS}
        self._lat = np.zeros(self.config.latency_window)
        self._n_lat = 0
        self._max_gap_s = 0.0
        self._min_offset_s = math.inf

    # ------------------------------------------------------------------ plumbing
    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port)."""
        return self.sock.getsockname()

    def fileno(self) -> int:
        return self.sock.fileno()

    def close(self) -> None:
        self.sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --------------------------------------------------------------------- poll
    def poll(self, now_s: float | None = None) -> PollResult:
        """Drain up to ``max_datagrams_per_poll`` datagrams; check the link timeout.

        Args:
            now_s: the receiver's time [s], used for freshness, latency and the timeout of
                every datagram read in this poll (default: ``clock()`` read at the poll for
                the timeout and again at each datagram for its freshness and latency).
        """
        now = self.clock() if now_s is None else float(now_s)
        out = PollResult()
        self.polls += 1
        # The timeout counts from the last valid packet READ: checked before the drain too, so
        # fresh packets that were starved in the queue (a flood) cannot hide the silence the
        # car has seen; and after it, so a quiet poll reports at once.
        self._check_timeout(now, out)
        budget = self.config.max_datagrams_per_poll
        while out.datagrams < budget:
            try:
                n, addr = self.sock.recvfrom_into(self._buf)
            except BlockingIOError:
                break
            except OSError as exc:  # e.g. ICMP port unreachable reported on a UDP socket
                if exc.errno in (errno.ECONNREFUSED, errno.ENETUNREACH, errno.EHOSTUNREACH):
                    continue
                raise
            out.datagrams += 1
            self.received += 1
            # the receive time of THIS datagram: one may have arrived after the poll began
            # (read once, a later datagram would show a negative latency)
            t_rx = self.clock() if now_s is None else now
            got = self._check(n, addr, t_rx)
            if isinstance(got, str):
                self.rejected[got] += 1
                continue
            self._accept(got, addr, t_rx, out)
        else:
            out.budget_exhausted = True
            self.polls_budget_exhausted += 1
        self._check_timeout(now, out)
        return out

    def _check(self, n: int, addr, now: float) -> TeleopCommand | str:
        """The command in the buffer, or the reason it is refused (module docstring order)."""
        if n > COMMAND_SIZE:
            return "oversized"
        if n < COMMAND_SIZE:
            return "truncated"
        body = self._view[: _CMD.size]
        if not hmac.compare_digest(_mac(self._key, body), self._view[_CMD.size : COMMAND_SIZE]):
            return "bad_mac"
        ver, kind, mode, flags, seq, t_us, v0, v1, v2 = _CMD.unpack_from(self._buf)
        if (
            ver != PROTOCOL_VERSION
            or kind != KIND_COMMAND
            or flags & ~FLAG_DEAD_MAN
            or mode not in _MODES
            or not (math.isfinite(v0) and math.isfinite(v1) and math.isfinite(v2))
        ):
            return "malformed"
        if self.holder is not None and addr != self.holder:
            return "second_operator"
        if seq == self._last_seq:
            return "replayed"
        if seq < self._last_seq:
            return "old_sequence"
        age = now - t_us * 1e-6
        if age > self.config.freshness_s:
            return "stale"
        if age < -self.config.future_tolerance_s:
            return "future"
        return TeleopCommand(
            Mode(mode), (v0, v1, v2), bool(flags & FLAG_DEAD_MAN), seq, t_us * 1e-6, now
        )

    def _accept(self, cmd: TeleopCommand, addr, now: float, out: PollResult) -> None:
        self.accepted += 1
        if self.holder is not None and self._last_seq >= 0 and cmd.seq > self._last_seq + 1:
            self.lost += cmd.seq - self._last_seq - 1
        if self._last_valid_s is not None and self.holder is not None:
            self._max_gap_s = max(self._max_gap_s, now - self._last_valid_s)
        self.holder = addr
        self._last_seq = cmd.seq
        self._last_valid_s = now
        age = now - cmd.t_send_s
        self._lat[self._n_lat % len(self._lat)] = age
        self._n_lat += 1
        self._min_offset_s = min(self._min_offset_s, age)

        if cmd.mode == Mode.DISENGAGE:  # the operator ends the run (dead-man held or not)
            if self.engaged:
                self._raise_stop("operator_disengaged", now, now, out)
                self.delivered += 1
                out.commands.append(cmd)
            else:
                self.ignored_not_engaged += 1
            return
        if not cmd.dead_man:
            if self.engaged:
                self._raise_stop("dead_man_released", now, now, out)
            else:
                self.ignored_not_engaged += 1
            return
        if cmd.mode == Mode.ENGAGE:
            self.engaged, self.mpc_in_control, self.stop = True, False, None
        elif not self.engaged:
            self.ignored_not_engaged += 1
            return
        elif cmd.mode == Mode.HANDOVER_MPC:
            self.mpc_in_control = True
        elif cmd.mode == Mode.TAKE_OVER:
            self.mpc_in_control = False
        self.delivered += 1
        out.commands.append(cmd)

    def _raise_stop(self, reason: str, t_s: float, now: float, out: PollResult) -> None:
        self.engaged = False
        self.mpc_in_control = False
        self.stop = StopRequest(reason, t_s, now)
        out.stop = self.stop

    def _check_timeout(self, now: float, out: PollResult) -> None:
        if self.holder is None or self._last_valid_s is None:
            return
        if now - self._last_valid_s >= self.config.timeout_s:
            if self.engaged:
                self._raise_stop("link_lost", self._last_valid_s, now, out)
            self.holder = None  # another operator may take the link (still stopped)

    # ---------------------------------------------------------------- reporting
    def stats(self) -> dict:
        """Link statistics (JSON-ready; the ``link`` object of ``hmpc teleop``'s run JSON)."""
        n = min(self._n_lat, len(self._lat))
        if n:
            p50, p99 = np.percentile(self._lat[:n], [50, 99]) * 1e3
            lat: dict[str, float | None] = {
                "p50": round(float(p50), 4),
                "p99": round(float(p99), 4),
            }
        else:
            lat = {"p50": None, "p99": None}  # no packet: no latency
        return {
            "received": self.received,
            "accepted": self.accepted,
            "delivered": self.delivered,
            "ignored_not_engaged": self.ignored_not_engaged,
            "rejected": dict(self.rejected),
            "rejected_total": sum(self.rejected.values()),
            "lost": self.lost,
            "latency_ms": lat,
            "max_gap_ms": round(self._max_gap_s * 1e3, 3) if self.accepted > 1 else None,
            "clock_offset_ms": (
                round(self._min_offset_s * 1e3, 4) if math.isfinite(self._min_offset_s) else None
            ),
            "polls": self.polls,
            "polls_budget_exhausted": self.polls_budget_exhausted,
            "stop": self.stop.to_dict() if self.stop else None,
        }

    def send_telemetry(self, vehicle: VehicleStatus, now_s: float | None = None) -> bool:
        """Send one telemetry packet to the operator holding the link (False: nobody holds it)."""
        if self.holder is None:
            return False
        now = self.clock() if now_s is None else float(now_s)
        self._tel_seq += 1
        pkt = encode_telemetry(
            self._key,
            self._tel_seq,
            now,
            engaged=self.engaged,
            mpc_in_control=self.mpc_in_control,
            link_held=True,
            vehicle=vehicle,
            stop=self.stop,
            stats=self.stats(),
        )
        try:
            self.sock.sendto(pkt, self.holder)
        except (BlockingIOError, OSError):
            return False  # telemetry is best effort; never stalls the control loop
        return True


_MODES = frozenset(int(m) for m in Mode)


# -------------------------------------------------------------------------- operator
class OperatorLink:
    """The operator station's end: sends commands, receives telemetry.

    Args:
        key: the pre-shared key. connect: the vehicle's (host, port).
        clock: sender's clock [s] (default ``time.time``; see the module docstring on clocks).
        seq_start: first sequence number (default: wall clock in microseconds).
    """

    def __init__(
        self,
        key: bytes,
        connect: tuple[str, int] = (DEFAULT_HOST, DEFAULT_PORT),
        clock: Callable[[], float] = time.time,
        seq_start: int | None = None,
    ):
        if len(key) < MIN_KEY_BYTES:
            raise ValueError(f"key must have at least {MIN_KEY_BYTES} bytes")
        self._key = bytes(key)
        self.clock = clock
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(connect)  # also filters: only the vehicle's address is received
        self.sock.setblocking(False)
        self.seq = (time.time_ns() // 1000) if seq_start is None else int(seq_start)
        self.sent = 0
        self.telemetry: Telemetry | None = None
        self.telemetry_received = 0
        self.telemetry_rejected = 0
        self._tel_seq = -1

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def send(self, cmd: TeleopCommand, now_s: float | None = None) -> bytes:
        """Send ``cmd`` with the next sequence number; return the packet sent."""
        self.seq += 1
        pkt = encode_command(self._key, cmd, self.seq, self.clock() if now_s is None else now_s)
        try:
            self.sock.send(pkt)
        except (BlockingIOError, ConnectionRefusedError):
            pass  # nobody listening yet / buffer full: the vehicle's timeout handles it
        self.sent += 1
        return pkt

    def poll_telemetry(self) -> Telemetry | None:
        """Read all waiting telemetry; keep the newest valid one (``self.telemetry``)."""
        while True:
            try:
                data = self.sock.recv(_BUF_SIZE)
            except (BlockingIOError, ConnectionRefusedError):
                break
            tel = decode_telemetry(self._key, data)
            if tel is None or tel.seq <= self._tel_seq:
                self.telemetry_rejected += 1
                continue
            self._tel_seq = tel.seq
            self.telemetry = tel
            self.telemetry_received += 1
        return self.telemetry

    def close(self) -> None:
        self.sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
