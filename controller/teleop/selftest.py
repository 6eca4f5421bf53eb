"""The link's security cases, run over real loopback UDP sockets (docs/teleop.md's list).

Each case opens a fresh ``LinkReceiver`` on a free loopback port with a simulated clock,
engages it with one valid packet from a real ``OperatorLink`` and then sends the case's
attack datagrams. The receiver is polled in lock step (send a batch, wait until the kernel has
delivered every datagram of it, poll), so every datagram is accounted for: a case row holds
the datagrams sent, how many were rejected (by reason) and how many were delivered to the
host. ``tests/teleop/test_teleop_link.py`` asserts on these rows; ``tools/bench_teleop_link.py``
prints them as a table.
"""

from __future__ import annotations

import random
import select
import socket
import struct

from hmpc.controller.simclock import SimClock
from hmpc.controller.teleop.link import (
    COMMAND_SIZE,
    FLAG_DEAD_MAN,
    KIND_COMMAND,
    PROTOCOL_VERSION,
    LinkConfig,
    LinkReceiver,
    Mode,
    OperatorLink,
    StopRequest,
    TeleopCommand,
    _CMD,
    _mac,
    _us,
)


class LoopbackPair:
    """A receiver on a free loopback port and an operator connected to it, one simulated clock."""

    def __init__(self, key: bytes, config: LinkConfig | None = None, clock: SimClock | None = None):
        self.key = key
        self.clock = clock or SimClock(1000.0)
        self.rx = LinkReceiver(key, ("127.0.0.1", 0), config, clock=self.clock)
        self.op = OperatorLink(key, self.rx.address, clock=self.clock, seq_start=1000)
        self.commands: list[TeleopCommand] = []
        self.stops: list[StopRequest | None] = []

    def pump(self, n_datagrams: int, timeout_s: float = 2.0) -> None:
        """Poll until ``n_datagrams`` more datagrams have been read (lock step)."""
        target = self.rx.received + n_datagrams
        while self.rx.received < target:
            ready, _, _ = select.select([self.rx], [], [], timeout_s)
            if not ready:
                raise RuntimeError(f"loopback lost {target - self.rx.received} datagrams")
            res = self.rx.poll()
            self.commands.extend(res.commands)
            if res.stop:
                self.stops.append(res.stop)

    def send_raw(self, datagrams, sock: socket.socket | None = None, batch: int = 200) -> None:
        """Send raw datagrams from the operator's own socket (a spoofed source: the worst case)
        or from ``sock``, in batches the receiver drains in lock step."""
        s = sock or self.op.sock
        pending = 0
        for d in datagrams:
            if sock is None:
                s.send(d)
            else:
                s.sendto(d, self.rx.address)
            pending += 1
            if pending == batch:
                self.pump(pending)
                pending = 0
        if pending:
            self.pump(pending)

    def send(self, cmd: TeleopCommand) -> bytes:
        pkt = self.op.send(cmd)
        self.pump(1)
        return pkt

    def engage(self) -> None:
        self.send(TeleopCommand(Mode.ENGAGE))

    def close(self) -> None:
        self.op.close()
        self.rx.close()


def _signed(
    key: bytes,
    ver=PROTOCOL_VERSION,
    kind=KIND_COMMAND,
    mode=int(Mode.PEDALS),
    flags=FLAG_DEAD_MAN,
    seq=0,
    t_s=0.0,
    values=(0.0, 0.0, 0.0),
) -> bytes:
    body = _CMD.pack(ver, kind, mode, flags, seq, _us(t_s), *values)
    return body + _mac(key, body)


def _row(pair: LoopbackPair, case: str, datagrams: list[bytes], sock=None) -> dict:
    rx = pair.rx
    rej0, dlv0, rc0 = dict(rx.rejected), rx.delivered, rx.received
    pair.send_raw(datagrams, sock)
    reasons = {r: rx.rejected[r] - rej0[r] for r in rx.rejected if rx.rejected[r] - rej0[r]}
    return {
        "case": case,
        "sent": len(datagrams),
        "received": rx.received - rc0,
        "rejected": sum(reasons.values()),
        "delivered": rx.delivered - dlv0,
        "reasons": reasons,
    }


def random_datagrams(seed: int, n: int, key_free_prefix: bytes) -> list[bytes]:
    """``n`` seeded random datagrams: a third fully random (0..200 bytes), a third exactly the
    command size, a third with a valid header in front of random bytes (reaching the MAC)."""
    rng = random.Random(f"hmpc-teleop-attacks-{seed}")  # a stream of its own, never the key's
    out = []
    for i in range(n):
        k = i % 3
        if k == 0:
            out.append(rng.randbytes(rng.randrange(0, 201)))
        elif k == 1:
            out.append(rng.randbytes(COMMAND_SIZE))
        else:
            out.append(key_free_prefix + rng.randbytes(COMMAND_SIZE - len(key_free_prefix)))
    return out


def run_security_cases(key: bytes, seed: int = 0, n_random: int = 10_000) -> list[dict]:
    """Every attack of the list against a fresh, engaged receiver; one row per case.

    Rows: case, sent, received (by the socket), rejected, delivered (to the host), reasons.
    """
    rows = []
    rng = random.Random(f"hmpc-teleop-attacks-{seed}")  # a stream of its own, never the key's

    def fresh() -> LoopbackPair:
        p = LoopbackPair(key)
        p.engage()
        return p

    def pkt(p: LoopbackPair, **kw) -> bytes:
        """A valid packet from p's operator, not sent (its sequence number is used up)."""
        p.op.seq += 1
        kw.setdefault("seq", p.op.seq)
        kw.setdefault("t_s", p.clock())
        return _signed(key, **kw)

    # wrong key: 100 packets, each under a different random key
    p = fresh()
    wrong = [k for k in (rng.randbytes(32) for _ in range(101)) if k != key][:100]
    dg = [_signed(k, seq=p.op.seq + 1 + i, t_s=p.clock()) for i, k in enumerate(wrong)]
    rows.append(_row(p, "wrong key", dg))
    p.close()

    # one flipped bit: every bit position of one valid packet; then the packet itself passes
    p = fresh()
    good = pkt(p, values=(0.1, 0.2, 0.0))
    dg = []
    for bit in range(COMMAND_SIZE * 8):
        b = bytearray(good)
        b[bit // 8] ^= 1 << (bit % 8)
        dg.append(bytes(b))
    row = _row(p, "one flipped bit (each of 608)", dg)
    d0 = p.rx.delivered
    p.send_raw([good])
    row["original_delivered_after"] = p.rx.delivered - d0
    rows.append(row)
    p.close()

    # replayed: the last accepted packet 10 times, then an earlier one
    p = fresh()
    first = p.send(TeleopCommand.pedals(0.0, 0.1, 0.0))
    last = p.send(TeleopCommand.pedals(0.0, 0.2, 0.0))
    rows.append(_row(p, "replayed packet", [last] * 10 + [first]))
    p.close()

    # reordered: 20 packets, adjacent pairs swapped: the second of each pair arrives late
    p = fresh()
    seqd = [pkt(p, values=(0.0, 0.01 * i, 0.0)) for i in range(20)]
    swapped = []
    for i in range(0, 20, 2):
        swapped += [seqd[i + 1], seqd[i]]
    d0, r0 = p.rx.delivered, sum(p.rx.rejected.values())
    p.send_raw(swapped)
    rows.append(
        {
            "case": "reordered packets (10 late of 20)",
            "sent": 10,
            "received": 10,
            "rejected": sum(p.rx.rejected.values()) - r0,
            "delivered": p.rx.delivered - d0 - 10,
            "reasons": {"old_sequence": sum(p.rx.rejected.values()) - r0},
        }
    )
    p.close()

    # stale and future timestamps (fresh sequence numbers)
    p = fresh()
    win = p.rx.config.freshness_s
    dg = [pkt(p, t_s=p.clock() - win - 0.001 - 0.05 * i) for i in range(10)]
    rows.append(_row(p, "stale timestamp (> 100 ms old)", dg))
    dg = [pkt(p, t_s=p.clock() + p.rx.config.future_tolerance_s + 0.001 + i) for i in range(10)]
    rows.append(_row(p, "timestamp from the future", dg))
    p.close()

    # truncated: every length 0..75 of a valid packet
    p = fresh()
    good = pkt(p)
    rows.append(_row(p, "truncated (each length 0-75)", [good[:n] for n in range(COMMAND_SIZE)]))
    # oversized: valid packet plus trailing bytes, up to the largest UDP datagram
    sizes = [COMMAND_SIZE + 1, COMMAND_SIZE + 32, 512, 1500, 9000, 65507]
    rows.append(
        _row(p, "oversized (77 B - 64 KiB)", [good + bytes(n - COMMAND_SIZE) for n in sizes])
    )
    p.close()

    # authenticated but malformed (a buggy operator holding the key)
    p = fresh()
    nan = float("nan")
    dg = [
        pkt(p, ver=2),
        pkt(p, kind=2),
        pkt(p, mode=0),
        pkt(p, mode=7),
        pkt(p, flags=0x81),
        pkt(p, values=(nan, 0.0, 0.0)),
        pkt(p, values=(0.0, float("inf"), 0.0)),
    ]
    rows.append(_row(p, "malformed, authenticated", dg))
    p.close()

    # a second operator with the right key from another address while one holds the link
    p = fresh()
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    dg = [pkt(p, seq=p.op.seq + 100 + i) for i in range(10)]
    rows.append(_row(p, "second operator (other address)", dg, sock=other))
    other.close()
    p.close()

    # random datagrams
    p = fresh()
    prefix = struct.pack("!BBBB", PROTOCOL_VERSION, KIND_COMMAND, int(Mode.PEDALS), FLAG_DEAD_MAN)
    dg = random_datagrams(seed, n_random, prefix)
    rows.append(_row(p, f"random datagrams (seed {seed})", dg))
    p.close()
    return rows
