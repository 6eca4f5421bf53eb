"""Ingest benchmark (issue 2): one hour of a 2.3 kHz CAN bus, end to end, and the decoder
against per-frame cantools on the same frames in the same run.

    .venv/bin/python tools/bench_ingest.py              # the hour (about 8.1 M frames)
    .venv/bin/python tools/bench_ingest.py --minutes 5  # a quick run

1. Builds the log by tiling the real comma minute (tools/data/rav4-comma2k19/can.log.gz) into a
   candump -L file in a temporary directory, shifting each tile's timestamps by one minute.
2. (a) Runs ``models.ingest.ingest_files(log, dbc, signals, rate_hz=50.0)`` in a child process:
   wall time and peak memory (the child's ``ru_maxrss`` via ``RUSAGE_CHILDREN``).
3. (b) Reads the same file in this process and decodes every frame of every DBC message with
   hmpc's vectorised path, and the first ``--cantools-frames`` (default 200 000) frames one by
   one with ``db.decode_message(..., decode_choices=False, scaling=True)`` (ids the DBC lacks
   skipped by a dict lookup, as the fast path skips them); prints decoded frames/s of both and
   their ratio. Also hmpc's reader against python-can's ``LogReader`` on a subset.

Targets: decoding >= 20x cantools; the hour ingested in < 30 s and < 2 GB peak memory.
Progress goes to stderr, results to stdout.
"""
from __future__ import annotations

import argparse
import gzip
import itertools
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

from hmpc.models.logs.canlog import read_log  # noqa: E402
from hmpc.models.logs.dbc import load_dbc  # noqa: E402
from hmpc.models.logs.decode import decode_frames  # noqa: E402
from hmpc.models.errors import Problems  # noqa: E402
from hmpc.tools.datafiles import PARAMS_DIR, bundled  # noqa: E402

TARGET_RATIO = 20.0      # issue 2: fast path at least 20x per-frame cantools
TARGET_WALL_S = 30.0     # issue 2: the hour ingested in under 30 s
TARGET_RSS_B = 2 * 1024 ** 3  # issue 2: under 2 GB peak memory


def progress(msg: str) -> None:
    print(f"[bench_ingest] {msg}", file=sys.stderr, flush=True)


def build_log(out: Path, minutes: int) -> tuple[int, float]:
    """Tile the real minute ``minutes`` times into ``out``; -> (frames, span [s])."""
    raw = gzip.decompress(bundled("rav4-comma2k19/can.log.gz").read_bytes())
    b = np.frombuffer(raw, np.uint8)
    nl = np.flatnonzero(b == 10)
    ls = np.concatenate([[0], nl[:-1] + 1])
    close = np.array([raw.index(b")", s) for s in ls[:1]])  # layout check on the first line
    width = int(close[0] - ls[0] - 1)
    fields = np.frombuffer(b"".join(raw[s + 1:s + 1 + width] for s in ls[:3]), "S%d" % width)
    if width != 17 or not all(f[10:11] == b"." for f in fields):
        raise SystemExit("unexpected timestamp layout in the bundled minute")
    # every line's timestamp as integer microseconds (digits at fixed columns 1..17)
    cols = np.array([1 + i for i in range(17) if i != 10])
    digits = (b[ls[:, None] + cols] - 48).astype(np.int64)
    if np.any((digits < 0) | (digits > 9)) or np.any(b[ls + 11] != 46) or np.any(b[ls + 18] != 41):
        raise SystemExit("bundled minute has lines of another layout")
    t_us = digits @ (10 ** np.arange(15, -1, -1, dtype=np.int64))
    n = len(ls)
    period_us = int(round((t_us[-1] - t_us[0]) / (n - 1)))
    tile_us = int(t_us[-1] - t_us[0]) + period_us
    idx = ls[:, None] + cols  # where the 16 digits of each line's time go
    with open(out, "wb") as fh:
        for k in range(minutes):
            tile = b.copy()
            tk = t_us + k * tile_us
            d = (tk[:, None] // (10 ** np.arange(15, -1, -1, dtype=np.int64))) % 10
            tile[idx] = (d + 48).astype(np.uint8)
            fh.write(tile.tobytes())
            if (k + 1) % 10 == 0 or k + 1 == minutes:
                progress(f"built {k + 1}/{minutes} minutes ({(k + 1) * n:,} frames)")
    return n * minutes, minutes * tile_us * 1e-6


CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from hmpc.models.logs.ingest import ingest_files
t1 = time.perf_counter()
result = ingest_files(sys.argv[1], sys.argv[2], sys.argv[3], rate_hz=50.0)
t2 = time.perf_counter()
rec = getattr(result, "recording", result)
channels = getattr(rec, "channels", {})
rows = int(len(channels["time"])) if "time" in channels else None
print(json.dumps({"import_s": t1 - t0, "ingest_s": t2 - t1, "rows": rows,
                  "channels": len(channels), "result": type(result).__name__}))
"""


def run_ingest(log: Path, dbc: Path, signals: Path) -> dict:
    """``ingest_files`` in a child process: wall time and peak RSS of the child."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", CHILD, str(log), str(dbc), str(signals)],
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out = {"wall_s": wall, "peak_rss_b": peak_kib * 1024, "returncode": proc.returncode,
           "rss_before_kib": before}
    if proc.returncode != 0:
        out["error"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return out
    out.update(json.loads(proc.stdout.strip().splitlines()[-1]))
    return out


def cantools_rate(frames, db, n_max: int) -> tuple[int, int, float]:
    """Per-frame cantools over the first ``n_max`` frames of the stream, like the fast path:
    frames whose id the DBC lacks are skipped by a dict lookup, the others go through
    ``db.decode_message(id, payload, decode_choices=False, scaling=True)``.
    Returns (frames in the subset, frames decoded, seconds)."""
    known = {(m.frame_id, m.is_extended_frame) for m in db.messages}
    n = min(len(frames), n_max)
    stream = [(int(frames.arb_id[i]), bool(frames.is_extended[i]),
               frames.data[i, :frames.dlc[i]].tobytes()) for i in range(n)]
    decoded = 0
    t0 = time.perf_counter()
    for fid, ext, payload in stream:
        if (fid, ext) not in known:
            continue
        try:
            db.decode_message(fid, payload, decode_choices=False, scaling=True)
            decoded += 1
        except Exception:  # short payloads; messages with overlapping signals (PCS_HUD)
            pass
    return n, decoded, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=int, default=60, help="minutes of bus to build (60)")
    ap.add_argument("--cantools-frames", type=int, default=200_000,
                    help="frames decoded by per-frame cantools (a subset; default 200000)")
    ap.add_argument("--skip-ingest", action="store_true", help="only the reader/decoder part")
    ap.add_argument("--keep", metavar="DIR", help="build the log in DIR and keep it")
    args = ap.parse_args(argv)

    dbc = bundled("dbc/toyota_rav4_2017.dbc.gz")
    signals = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
    tmpdir = tempfile.TemporaryDirectory(prefix="hmpc_bench_") if not args.keep else None
    work = Path(args.keep or tmpdir.name)
    work.mkdir(parents=True, exist_ok=True)
    log = work / f"rav4_{args.minutes}min.log"
    progress(f"building {args.minutes} minute(s) of candump in {log}")
    n_frames, span_s = build_log(log, args.minutes)
    size_mb = log.stat().st_size / 1e6
    print(f"log: {log.name}: {n_frames:,} frames, {span_s:.0f} s, {size_mb:.0f} MB "
          f"({n_frames / span_s:.0f} frames/s of bus)")

    results = {"frames": n_frames, "span_s": span_s, "size_mb": size_mb}
    verdicts = []
    # (a) end to end, in a child process
    if not args.skip_ingest:
        progress("ingesting end to end in a child process (models.ingest.ingest_files) ...")
        ing = run_ingest(log, dbc, signals)
        results["ingest"] = ing
        if ing["returncode"] != 0:
            print(f"ingest: FAILED ({ing.get('error')})")
            verdicts.append(("hour ingested", "MISS", "ingest failed"))
        else:
            scale = 60.0 / args.minutes
            print(f"ingest: wall {ing['wall_s']:.2f} s (child process incl. Python start-up; "
                  f"ingest_files() itself {ing['ingest_s']:.2f} s, imports {ing['import_s']:.2f} s), "
                  f"peak memory {ing['peak_rss_b'] / 1e6:.0f} MB; recording: {ing.get('rows')} rows x "
                  f"{ing.get('channels')} channels at 50 Hz")
            # a shorter run: scale the ingest itself, keep the one-off start-up as measured
            startup = ing["wall_s"] - ing["ingest_s"]
            wall_hour = ing["wall_s"] if args.minutes == 60 else startup + ing["ingest_s"] * scale
            note = "" if args.minutes == 60 else f" (estimated from {args.minutes} min)"
            verdicts.append((f"hour ingested < {TARGET_WALL_S:g} s", 
                             "PASS" if wall_hour < TARGET_WALL_S else "MISS",
                             f"{wall_hour:.1f} s{note}"))
            verdicts.append((f"peak memory < {TARGET_RSS_B / 1024 ** 3:g} GB",
                             "PASS" if ing["peak_rss_b"] < TARGET_RSS_B else "MISS",
                             f"{ing['peak_rss_b'] / 1e6:.0f} MB"
                             + ("" if args.minutes == 60 else f" for {args.minutes} min")))

    # (b) reader and decoder on the same frames, same run
    progress("reading the log with hmpc's candump reader ...")
    problems = Problems()
    t0 = time.perf_counter()
    frames = read_log(log, problems)
    t_read = time.perf_counter() - t0
    print(f"read (hmpc, vectorised): {len(frames):,} frames in {t_read:.2f} s = "
          f"{len(frames) / t_read:,.0f} frames/s")
    n_sub = min(args.cantools_frames, len(frames))
    progress(f"python-can LogReader on the first {n_sub:,} lines ...")
    import can
    t0 = time.perf_counter()
    k = sum(1 for _ in itertools.islice(can.LogReader(str(log)), n_sub))
    t_pc = time.perf_counter() - t0
    print(f"read (python-can LogReader, first {k:,} lines): {k / t_pc:,.0f} frames/s; "
          f"hmpc/python-can = {(len(frames) / t_read) / (k / t_pc):.1f}x")

    db = load_dbc(dbc)
    progress("decoding every frame of every DBC message with the fast path ...")
    t0 = time.perf_counter()
    decoded = decode_frames(frames, db, Problems())
    t_fast = time.perf_counter() - t0
    n_fast = sum(len(m) for m in decoded.values())
    fast_fps = n_fast / t_fast
    progress(f"per-frame cantools on the first {args.cantools_frames:,} frames ...")
    n_sub, n_ct, t_ct = cantools_rate(frames, db, args.cantools_frames)
    ct_fps = n_ct / t_ct
    ratio = fast_fps / ct_fps
    print(f"decode (hmpc fast path, all {len(frames):,} frames): {n_fast:,} frames of "
          f"{len(decoded)} messages decoded in {t_fast:.2f} s = {fast_fps:,.0f} decoded frames/s")
    print(f"decode (cantools decode_message per frame, the first {n_sub:,} frames only): "
          f"{n_ct:,} decoded in {t_ct:.2f} s = {ct_fps:,.0f} decoded frames/s")
    print(f"decode ratio hmpc/cantools: {ratio:.1f}x")
    verdicts.append((f"decode >= {TARGET_RATIO:g}x cantools", "PASS" if ratio >= TARGET_RATIO
                     else "MISS", f"{ratio:.1f}x"))
    results.update({"read_s": t_read, "fast_frames": n_fast, "fast_s": t_fast,
                    "cantools_frames": n_ct, "cantools_s": t_ct, "ratio": ratio})

    print("\ntargets:")
    for name, verdict, value in verdicts:
        print(f"  {verdict:4s}  {name:28s} {value}")
    if tmpdir is not None:
        del frames, decoded
        tmpdir.cleanup()
    return 0 if all(v == "PASS" for _, v, _ in verdicts) else 1


if __name__ == "__main__":
    sys.exit(main())
