"""Tele-operation link on loopback: the security case table and the link latency.

    .venv/bin/python tools/bench_teleop_link.py [--seconds S] [--seed N]

1. Security cases (``controller.teleop.selftest``): datagrams sent, rejected (by reason) and
   delivered, for every attack of the selftest's list.
2. Latency, operator process -> vehicle process on 127.0.0.1, 50 Hz for ``--seconds``:
   - hmpc's link, receiver reading at once (waits on the socket): transport + HMAC + checks;
   - hmpc's link, receiver polled by a 50 Hz loop as the drive loop does (adds the queueing
     until the next period, up to 20 ms);
   - baseline in the same run: the same 76-byte datagrams unauthenticated, raw socket.
   Latency = receiver's read time - operator's send time (one clock: the same machine).
3. Receiver cost per datagram (10,000 random datagrams drained at once).
"""

from __future__ import annotations

import argparse
import random
import select
import socket
import struct
import subprocess
import sys
import time

import numpy as np

from hmpc.controller.teleop import link as L
from hmpc.controller.teleop.selftest import random_datagrams, run_security_cases

_SENDER = r"""
import socket, struct, sys, time
from hmpc.controller.teleop import link as L
port, n, kind, key = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], bytes.fromhex(sys.argv[4])
op = L.OperatorLink(key, ("127.0.0.1", port))
raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sys.stdin.readline()
t0 = time.monotonic()
for k in range(n):
    if kind == "hmpc":
        op.send(L.TeleopCommand.pedals(0.0, 0.1, 0.0) if k else L.TeleopCommand(L.Mode.ENGAGE))
    else:
        raw.sendto(struct.pack("!d", time.time()) + bytes(68), ("127.0.0.1", port))
    time.sleep(max(t0 + (k + 1) * 0.02 - time.monotonic(), 0.0))
"""


def _sender(port: int, n: int, kind: str, key: bytes) -> subprocess.Popen:
    p = subprocess.Popen(
        [sys.executable, "-c", _SENDER, str(port), str(n), kind, key.hex()],
        stdin=subprocess.PIPE,
        text=True,
    )
    time.sleep(0.5)  # let the interpreter start before the clock of the run starts
    p.stdin.write("go\n")
    p.stdin.flush()
    return p


def _pct(a) -> str:
    a = np.asarray(a) * 1e3
    return f"p50 {np.percentile(a, 50):7.3f} ms  p99 {np.percentile(a, 99):7.3f} ms"


def latency_immediate(key: bytes, n: int) -> tuple[np.ndarray, dict]:
    rx = L.LinkReceiver(key, ("127.0.0.1", 0), L.LinkConfig(latency_window=n + 10))
    p = _sender(rx.address[1], n, "hmpc", key)
    while p.poll() is None or select.select([rx], [], [], 0)[0]:
        if select.select([rx], [], [], 0.2)[0]:
            rx.poll()
    st = rx.stats()
    lat = rx._lat[: min(rx._n_lat, len(rx._lat))].copy()
    rx.close()
    return lat, st


def latency_loop(key: bytes, n: int) -> tuple[np.ndarray, dict]:
    rx = L.LinkReceiver(key, ("127.0.0.1", 0), L.LinkConfig(latency_window=n + 10))
    p = _sender(rx.address[1], n, "hmpc", key)
    t0 = time.monotonic()
    k = 0
    while p.poll() is None:
        rx.poll()
        k += 1
        time.sleep(max(t0 + k * 0.02 - time.monotonic(), 0.0))
    rx.poll()
    st = rx.stats()
    lat = rx._lat[: min(rx._n_lat, len(rx._lat))].copy()
    rx.close()
    return lat, st


def latency_raw(key: bytes, n: int) -> np.ndarray:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    p = _sender(s.getsockname()[1], n, "raw", key)
    out = []
    while p.poll() is None or select.select([s], [], [], 0)[0]:
        if select.select([s], [], [], 0.2)[0]:
            data = s.recv(2048)
            out.append(time.time() - struct.unpack("!d", data[:8])[0])
    s.close()
    return np.array(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="latency run length [s]")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    key = random.Random(args.seed).randbytes(32)

    print(f"security cases on loopback (seed {args.seed})")
    print("| case | sent | rejected | delivered | reasons |")
    print("|---|---|---|---|---|")
    for r in run_security_cases(key, seed=args.seed):
        reasons = ", ".join(f"{k} {v}" for k, v in r["reasons"].items())
        print(f"| {r['case']} | {r['sent']} | {r['rejected']} | {r['delivered']} | {reasons} |")

    n = int(args.seconds * 50)
    print(f"\nlatency, operator process -> vehicle process on 127.0.0.1, {n} packets at 50 Hz")
    lat_i, st_i = latency_immediate(key, n)
    lat_l, st_l = latency_loop(key, n)
    lat_r = latency_raw(key, n)
    print(
        f"  hmpc link, read at once          {_pct(lat_i)}  (accepted {st_i['accepted']}, "
        f"rejected {st_i['rejected_total']})"
    )
    print(
        f"  hmpc link, 50 Hz receive loop    {_pct(lat_l)}  (accepted {st_l['accepted']}, "
        f"rejected {st_l['rejected_total']})"
    )
    print(f"  baseline: raw UDP, no HMAC       {_pct(lat_r)}")
    ratio = np.percentile(lat_i, 50) / np.percentile(lat_r, 50)
    print(f"  ratio hmpc/raw (p50)             {ratio:.2f}")

    rx = L.LinkReceiver(key, ("127.0.0.1", 0), L.LinkConfig(max_datagrams_per_poll=20000))
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dg = random_datagrams(args.seed, 10_000, struct.pack("!BBBB", 1, 1, 1, 1))
    got = 0
    cost = 0.0
    for i in range(0, len(dg), 1000):
        for d in dg[i : i + 1000]:
            s.sendto(d, rx.address)
        time.sleep(0.05)
        t = time.perf_counter()
        got += rx.poll().datagrams
        cost += time.perf_counter() - t
    print(
        f"\nreceiver cost: {got} random datagrams in {cost * 1e3:.1f} ms = "
        f"{cost / max(got, 1) * 1e6:.2f} us each (budget {L.LinkConfig().max_datagrams_per_poll}"
        f" per 20 ms poll)"
    )
    rx.close()
    s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
