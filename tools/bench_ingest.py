"""Ingest benchmark (issue 2): one hour of a 2.3 kHz CAN bus, end to end, and the decoder
against per-frame cantools on the same frames in the same run.

    .venv/bin/python -m hmpc.tools.bench_ingest              # the hour (about 8.1 M frames)
    .venv/bin/python -m hmpc.tools.bench_ingest --minutes 5  # a quick run

1. Builds the log by tiling the real comma minute (tools/data/rav4-comma2k19/can.log.gz) into a
   candump -L file in a temporary directory, shifting each tile's timestamps by one minute.
2. (a) Times the ingest twice, each in its own child process (wall time, and the child's own
   peak memory from ``os.wait4``): the library call ``hmpc.models.logs.ingest.ingest_files(log,
   dbc, signals, rate_hz=50.0)`` in a child that imports only that module; and the command a
   user runs, ``hmpc ingest LOG --dbc --signals --rate 50 --out REC.csv --json S.json``, end to
   end (interpreter start-up, the import of every subcommand, the ingest, the CSV and JSON
   writes, the exit). Prints both, their ratio, and the ratio to the target; the target's
   verdict uses the CLI figure.
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
import os
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


def run_child(cmd: list[str], cwd: Path) -> dict:
    """Run ``cmd`` as a child: its wall time and its own peak RSS (``os.wait4``)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([str(c) for c in cmd], cwd=cwd, stdout=out, stderr=err)
        _pid, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return {"wall_s": wall, "peak_rss_b": usage.ru_maxrss * 1024,
                "returncode": proc.returncode, "stdout": out.read().decode(errors="replace"),
                "stderr": err.read().decode(errors="replace")}


def run_ingest(log: Path, dbc: Path, signals: Path) -> dict:
    """``ingest_files`` in a child process that imports only it: wall time and peak RSS."""
    res = run_child([sys.executable, "-c", CHILD, log, dbc, signals], log.parent)
    out = {k: res[k] for k in ("wall_s", "peak_rss_b", "returncode")}
    if res["returncode"] != 0:
        out["error"] = (res["stderr"].strip().splitlines() or ["?"])[-1]
        return out
    out.update(json.loads(res["stdout"].strip().splitlines()[-1]))
    return out


def hmpc_command() -> list[str]:
    """The ``hmpc`` console script beside this interpreter, as a user runs it."""
    script = Path(sys.executable).with_name("hmpc")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "hmpc"]


def run_cli_ingest(log: Path, dbc: Path, signals: Path) -> dict:
    """``hmpc ingest ... --out REC.csv --json S.json`` end to end (start-up, every
    subcommand's import, the ingest, the CSV and JSON writes, the exit), and ``hmpc --version``
    alone (the start-up)."""
    rec, js = log.with_suffix(".rec.csv"), log.with_suffix(".summary.json")
    res = run_child([*hmpc_command(), "ingest", log, "--dbc", dbc, "--signals", signals,
                     "--rate", "50", "--out", rec, "--json", js], log.parent)
    out = {k: res[k] for k in ("wall_s", "peak_rss_b", "returncode")}
    if res["returncode"] != 0:
        out["error"] = (res["stderr"].strip().splitlines() or ["?"])[-1]
        return out
    out["csv_mb"] = rec.stat().st_size / 1e6
    out["startup_s"] = min(run_child([*hmpc_command(), "--version"], log.parent)["wall_s"]
                           for _ in range(3))
    rec.unlink()
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
    # (a) the library call alone, and the command a user runs, each in its own child process
    if not args.skip_ingest:
        scale = 60.0 / args.minutes
        note = "" if args.minutes == 60 else f" (estimated from {args.minutes} min)"
        progress("ingest_files() in a child process that imports only models.logs.ingest ...")
        ing = run_ingest(log, dbc, signals)
        results["ingest"] = ing
        progress("`hmpc ingest ... --out REC.csv --json S.json` end to end ...")
        cli = run_cli_ingest(log, dbc, signals)
        results["cli"] = cli
        if ing["returncode"] != 0 or cli["returncode"] != 0:
            print(f"ingest: FAILED (library: {ing.get('error')}; CLI: {cli.get('error')})")
            verdicts.append(("hour ingested", "MISS", "ingest failed"))
        else:
            print(f"ingest, library: wall {ing['wall_s']:.2f} s (child process incl. Python "
                  f"start-up; ingest_files() itself {ing['ingest_s']:.2f} s, its imports "
                  f"{ing['import_s']:.2f} s), peak memory {ing['peak_rss_b'] / 1e6:.0f} MB; "
                  f"recording: {ing.get('rows')} rows x {ing.get('channels')} channels at 50 Hz")
            print(f"ingest, `hmpc ingest` end to end (what the user runs): wall "
                  f"{cli['wall_s']:.2f} s, peak memory {cli['peak_rss_b'] / 1e6:.0f} MB; "
                  f"{cli['csv_mb']:.0f} MB CSV written; `hmpc --version` alone "
                  f"{cli['startup_s']:.2f} s")
            print(f"  CLI / library call: {cli['wall_s'] / ing['ingest_s']:.2f}x "
                  f"(+{cli['wall_s'] - ing['ingest_s']:.2f} s: start-up, imports, CSV and "
                  f"JSON writes, exit)")
            # a shorter run: scale the ingest itself, keep the one-off start-up as measured
            lib_fixed = ing["wall_s"] - ing["ingest_s"]
            lib_hour = ing["wall_s"] if args.minutes == 60 else lib_fixed + ing["ingest_s"] * scale
            cli_fixed = cli["startup_s"]
            cli_hour = (cli["wall_s"] if args.minutes == 60
                        else cli_fixed + (cli["wall_s"] - cli_fixed) * scale)
            print(f"  one hour{note}: CLI {cli_hour:.1f} s, library {lib_hour:.1f} s; target "
                  f"< {TARGET_WALL_S:g} s: ratio target/CLI {TARGET_WALL_S / cli_hour:.2f}x, "
                  f"target/library {TARGET_WALL_S / lib_hour:.2f}x")
            verdicts.append((f"hour ingested < {TARGET_WALL_S:g} s (CLI)",
                             "PASS" if cli_hour < TARGET_WALL_S else "MISS",
                             f"{cli_hour:.1f} s{note}"))
            peak = max(ing["peak_rss_b"], cli["peak_rss_b"])
            verdicts.append((f"peak memory < {TARGET_RSS_B / 1024 ** 3:g} GB",
                             "PASS" if peak < TARGET_RSS_B else "MISS",
                             f"{peak / 1e6:.0f} MB"
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
