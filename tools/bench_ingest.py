"""Ingest benchmark: one hour of a 2.3 kHz CAN bus, end to end, against the previous reader in
the same run; and the decoder against per-frame cantools on the same frames.

    .venv/bin/python -m hmpc.tools.bench_ingest              # the hour (about 8.1 M frames)
    .venv/bin/python -m hmpc.tools.bench_ingest --minutes 5  # a quick run
    .venv/bin/python -m hmpc.tools.bench_ingest --baseline-rev 7f46875  # + that commit's code
    .venv/bin/python -m hmpc.tools.bench_ingest --repeat 3   # each ingest's fastest of 3 runs

1. Builds the log by tiling the real comma minute (tools/data/rav4-comma2k19/can.log.gz) into an
   uncompressed candump -L file in a temporary directory, shifting each tile's timestamps by one
   minute. (A gzip log adds its decompression, about 1-2 s for the hour, which the reader does
   in a worker thread while it parses; the figures here are for the plain text.)
2. (a) Times the ingest, each run in its own child process (wall time, and the child's own
   peak memory from ``os.wait4``):
   - the library call ``hmpc.models.logs.ingest.ingest_files(log, dbc, signals, rate_hz=50.0)``
     in a child that imports only that module (the target's figure);
   - the same call with the reference reader, ``models.logs.canlog_reference`` (every line
     through the general parser, the blocks' tables joined at the end: the previous code
     path), the baseline; and, with ``--baseline-rev REV``, the library call of the code at git
     revision REV (extracted with ``git archive``), e.g. the commit before the bulk reader;
   - the command a user runs, ``hmpc ingest LOG --dbc --signals --rate 50 --out REC.csv --json
     S.json``, end to end (interpreter start-up, the import of every subcommand, the ingest, the
     CSV and JSON writes, the exit).
   With ``--repeat N`` each of these runs N times, the variants interleaved so each sees the
   same load, and each one's fastest run counts (the load average at its end is printed).
   Prints each, the ratio baseline / now, and the verdicts. Beside each wall time: the CPU
   time of all threads, and of the main thread alone (start-up included): the wall time the
   call would take with a free core whenever a thread of it could run.
3. (b) Reads the same file in this process and decodes every frame of every DBC message with
   hmpc's vectorised path (twice; the faster call counts, as per-frame cantools runs warm),
   and the first ``--cantools-frames`` (default 200 000) frames one by
   one with ``db.decode_message(..., decode_choices=False, scaling=True)`` (ids the DBC lacks
   skipped by a dict lookup, as the fast path skips them); prints decoded frames/s of both and
   their ratio. Also hmpc's reader against python-can's ``LogReader`` on a subset.

Targets: the hour ingested by the library call in at most 3 s (wall, child process, Python
start-up included); by ``hmpc ingest`` end to end in under 30 s; under 2 GB peak memory;
decoding at least 20x per-frame cantools. Progress goes to stderr, results to stdout. The
machine's load average is printed with the results: on a shared machine every wall time
stretches with it.
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

TARGET_RATIO = 20.0  # fast path at least 20x per-frame cantools
TARGET_WALL_S = 3.0  # the hour ingested by the library call in at most 3 s
TARGET_CLI_S = 30.0  # the hour ingested by `hmpc ingest` end to end in under 30 s
TARGET_RSS_B = 2 * 1024**3  # under 2 GB peak memory


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
    fields = np.frombuffer(b"".join(raw[s + 1 : s + 1 + width] for s in ls[:3]), f"S{width}")
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
from hmpc.models.logs import ingest
if sys.argv[4:] == ["reference"]:
    from hmpc.models.logs.canlog_reference import read_log_reference
    ingest.read_log = read_log_reference
t1 = time.perf_counter()
marks = []
result = ingest.ingest_files(sys.argv[1], sys.argv[2], sys.argv[3], rate_hz=50.0,
                             progress=lambda msg: marks.append((time.perf_counter(), msg)))
t2 = time.perf_counter()
setup = next((t for t, msg in marks if msg.startswith("reading CAN log")), t1) - t1
rec = getattr(result, "recording", result)
channels = getattr(rec, "channels", {})
rows = int(len(channels["time"])) if "time" in channels else None
print(json.dumps({"import_s": t1 - t0, "ingest_s": t2 - t1, "setup_s": setup, "rows": rows,
                  "channels": len(channels), "result": type(result).__name__,
                  "main_cpu_s": time.thread_time()}))
"""


def run_child(cmd: list[str], cwd: Path, env: dict | None = None) -> dict:
    """Run ``cmd`` as a child: its wall time and its own peak RSS (``os.wait4``)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([str(c) for c in cmd], cwd=cwd, stdout=out, stderr=err, env=env)
        _pid, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return {
            "wall_s": wall,
            "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_rss_b": usage.ru_maxrss * 1024,
            "returncode": proc.returncode,
            "stdout": out.read().decode(errors="replace"),
            "stderr": err.read().decode(errors="replace"),
        }


def run_ingest(
    log: Path, dbc: Path, signals: Path, *, reference: bool = False, code: Path | None = None
) -> dict:
    """``ingest_files`` in a child process that imports only it: wall time and peak RSS.
    ``reference``: with the reference reader; ``code``: a folder holding another ``hmpc``
    package to import instead of this one."""
    env = None
    if code is not None:
        env = dict(
            os.environ,
            PYTHONPATH=os.pathsep.join(
                [str(code)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
            ),
        )
    res = run_child(
        [sys.executable, "-c", CHILD, log, dbc, signals] + (["reference"] if reference else []),
        log.parent,
        env,
    )
    out = {k: res[k] for k in ("wall_s", "cpu_s", "peak_rss_b", "returncode")}
    if res["returncode"] != 0:
        out["error"] = (res["stderr"].strip().splitlines() or ["?"])[-1]
        return out
    out.update(json.loads(res["stdout"].strip().splitlines()[-1]))
    return out


def extract_revision(rev: str, into: Path) -> None:
    """The ``hmpc`` package at git revision ``rev`` of this checkout, extracted to
    ``into/hmpc`` (``into`` goes on PYTHONPATH)."""
    pkg = into / "hmpc"
    pkg.mkdir()
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", "--format=tar", rev], capture_output=True, check=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(pkg)], input=archive, check=True)


def hmpc_command() -> list[str]:
    """The ``hmpc`` console script beside this interpreter, as a user runs it."""
    script = Path(sys.executable).with_name("hmpc")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "hmpc"]


def run_cli_ingest(log: Path, dbc: Path, signals: Path) -> dict:
    """``hmpc ingest ... --out REC.csv --json S.json`` end to end (start-up, every
    subcommand's import, the ingest, the CSV and JSON writes, the exit), and ``hmpc --version``
    alone (the start-up)."""
    rec, js = log.with_suffix(".rec.csv"), log.with_suffix(".summary.json")
    res = run_child(
        [
            *hmpc_command(),
            "ingest",
            log,
            "--dbc",
            dbc,
            "--signals",
            signals,
            "--rate",
            "50",
            "--out",
            rec,
            "--json",
            js,
        ],
        log.parent,
    )
    out = {k: res[k] for k in ("wall_s", "cpu_s", "peak_rss_b", "returncode")}
    if res["returncode"] != 0:
        out["error"] = (res["stderr"].strip().splitlines() or ["?"])[-1]
        return out
    out["csv_mb"] = rec.stat().st_size / 1e6
    out["startup_s"] = min(
        run_child([*hmpc_command(), "--version"], log.parent)["wall_s"] for _ in range(3)
    )
    rec.unlink()
    return out


def cantools_rate(frames, db, n_max: int) -> tuple[int, int, float]:
    """Per-frame cantools over the first ``n_max`` frames of the stream, like the fast path:
    frames whose id the DBC lacks are skipped by a dict lookup, the others go through
    ``db.decode_message(id, payload, decode_choices=False, scaling=True)``.
    Returns (frames in the subset, frames decoded, seconds)."""
    known = {(m.frame_id, m.is_extended_frame) for m in db.messages}
    n = min(len(frames), n_max)
    stream = [
        (
            int(frames.arb_id[i]),
            bool(frames.is_extended[i]),
            frames.data[i, : frames.dlc[i]].tobytes(),
        )
        for i in range(n)
    ]
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


def _report_ingest(runs: list[tuple[str, dict]], cli: dict, minutes: int) -> list[tuple]:
    """Print the ingest figures of (a); -> verdicts. A shorter run than the hour is scaled:
    the ingest after its DBC and signal map are loaded times 60 / minutes, the one-off
    start-up, imports and loading as measured."""
    scale = 60.0 / minutes
    note = "" if minutes == 60 else f" (estimated from {minutes} min)"

    def hour(r: dict) -> float:
        return r["wall_s"] + (r["ingest_s"] - r["setup_s"]) * (scale - 1)

    ing = runs[0][1]
    for name, r in runs:
        print(
            f"ingest, library call, {name}: wall {r['wall_s']:.2f} s (child process incl. "
            f"Python start-up; ingest_files() itself {r['ingest_s']:.2f} s, its imports "
            f"{r['import_s']:.2f} s), CPU {r['cpu_s']:.2f} s (all threads; the main "
            f"thread's {r.get('main_cpu_s', float('nan')):.2f} s), peak memory "
            f"{r['peak_rss_b'] / 1e6:.0f} MB; recording: {r.get('rows')} rows x "
            f"{r.get('channels')} channels at 50 Hz; load average {r['load1']:.1f}"
        )
    for name, r in runs[1:]:
        print(
            f"  {name} / now: wall {hour(r):.2f} s / {hour(ing):.2f} s = "
            f"{hour(r) / hour(ing):.1f}x{note}; CPU {r['cpu_s'] / ing['cpu_s']:.1f}x"
        )
    print(
        f"ingest, `hmpc ingest` end to end (what the user runs): wall "
        f"{cli['wall_s']:.2f} s, CPU {cli['cpu_s']:.2f} s (all threads and processes), "
        f"peak memory {cli['peak_rss_b'] / 1e6:.0f} MB; "
        f"{cli['csv_mb']:.0f} MB CSV written; `hmpc --version` alone "
        f"{cli['startup_s']:.2f} s (start-up: every subcommand imported); load average "
        f"{cli['load1']:.1f}"
    )
    print(
        f"  CLI - library call: +{cli['wall_s'] - ing['ingest_s']:.2f} s (start-up, imports, "
        f"CSV and JSON writes, exit)"
    )
    cli_hour = cli["wall_s"] + (ing["ingest_s"] - ing["setup_s"]) * (scale - 1)
    lib_hour = hour(ing)
    print(
        f"  one hour{note}: library call {lib_hour:.2f} s (target <= {TARGET_WALL_S:g} s: "
        f"target/now {TARGET_WALL_S / lib_hour:.2f}x), CLI {cli_hour:.1f} s"
    )
    peak = max(ing["peak_rss_b"], cli["peak_rss_b"])
    return [
        (
            f"hour ingested <= {TARGET_WALL_S:g} s (library)",
            "PASS" if lib_hour <= TARGET_WALL_S else "MISS",
            f"{lib_hour:.2f} s{note}",
        ),
        (
            f"hour ingested < {TARGET_CLI_S:g} s (CLI)",
            "PASS" if cli_hour < TARGET_CLI_S else "MISS",
            f"{cli_hour:.1f} s{note}",
        ),
        (
            f"peak memory < {TARGET_RSS_B / 1024**3:g} GB",
            "PASS" if peak < TARGET_RSS_B else "MISS",
            f"{peak / 1e6:.0f} MB" + ("" if minutes == 60 else f" for {minutes} min"),
        ),
    ]


def _faster(r: dict, than: dict) -> bool:
    """``r`` ran and took less wall time than ``than`` (or ``than`` failed)."""
    if r["returncode"] != 0:
        return False
    return than["returncode"] != 0 or r["wall_s"] < than["wall_s"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=int, default=60, help="minutes of bus to build (60)")
    ap.add_argument(
        "--cantools-frames",
        type=int,
        default=200_000,
        help="frames decoded by per-frame cantools (a subset; default 200000)",
    )
    ap.add_argument("--skip-ingest", action="store_true", help="only the reader/decoder part")
    ap.add_argument("--keep", metavar="DIR", help="build the log in DIR and keep it")
    ap.add_argument(
        "--baseline-rev",
        metavar="REV",
        help="also time the library call of the code at this git revision",
    )
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        metavar="N",
        help="run each ingest N times, interleaved, and keep each one's fastest "
        "(on a shared machine the load changes from run to run)",
    )
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
    print(
        f"log: {log.name}: {n_frames:,} frames, {span_s:.0f} s, {size_mb:.0f} MB "
        f"({n_frames / span_s:.0f} frames/s of bus)"
    )

    results = {"frames": n_frames, "span_s": span_s, "size_mb": size_mb}
    verdicts = []
    # (a) the library call (now, and with the reference reader), and the command a user runs,
    # each in its own child process
    if not args.skip_ingest:
        with tempfile.TemporaryDirectory(prefix="baseline_", dir=work) as code:
            variants = [("now", {}), ("reference reader", {"reference": True})]
            if args.baseline_rev:
                extract_revision(args.baseline_rev, Path(code))
                variants.append((f"git {args.baseline_rev}", {"code": Path(code)}))
            best: dict[str, dict] = {}
            cli: dict | None = None
            for k in range(args.repeat):  # interleaved: each variant sees the same load
                for name, kw in variants:
                    progress(
                        f"ingest_files() in a child process, {name} (run {k + 1}/{args.repeat}) ..."
                    )
                    r = run_ingest(log, dbc, signals, **kw)
                    r["load1"] = os.getloadavg()[0]
                    if name not in best or _faster(r, best[name]):
                        best[name] = r
                progress("`hmpc ingest ... --out REC.csv --json S.json` end to end ...")
                c = run_cli_ingest(log, dbc, signals)
                c["load1"] = os.getloadavg()[0]
                if cli is None or _faster(c, cli):
                    cli = c
        runs = [(name, best[name]) for name, _ in variants]
        ing, ref = best["now"], best["reference reader"]
        results.update({"ingest": ing, "reference": ref, "cli": cli})
        failed = [
            (name, r.get("error")) for name, r in runs + [("CLI", cli)] if r["returncode"] != 0
        ]
        if failed:
            print("ingest: FAILED (" + "; ".join(f"{n}: {e}" for n, e in failed) + ")")
            verdicts.append(("hour ingested", "MISS", "ingest failed"))
        else:
            verdicts += _report_ingest(runs, cli, args.minutes)

    # (b) reader and decoder on the same frames, same run
    progress("reading the log with hmpc's candump reader ...")
    problems = Problems()
    t0 = time.perf_counter()
    frames = read_log(log, problems)
    t_read = time.perf_counter() - t0
    print(
        f"read (hmpc, vectorised): {len(frames):,} frames in {t_read:.2f} s = "
        f"{len(frames) / t_read:,.0f} frames/s"
    )
    n_sub = min(args.cantools_frames, len(frames))
    progress(f"python-can LogReader on the first {n_sub:,} lines ...")
    import can

    t0 = time.perf_counter()
    k = sum(1 for _ in itertools.islice(can.LogReader(str(log)), n_sub))
    t_pc = time.perf_counter() - t0
    print(
        f"read (python-can LogReader, first {k:,} lines): {k / t_pc:,.0f} frames/s; "
        f"hmpc/python-can = {(len(frames) / t_read) / (k / t_pc):.1f}x"
    )

    db = load_dbc(dbc)
    decoded = None
    progress("decoding every frame of every DBC message with the fast path (twice) ...")
    t_calls = []
    for _ in range(2):  # the first call also takes its outputs' fresh memory from the system
        del decoded
        t0 = time.perf_counter()
        decoded = decode_frames(frames, db, Problems())
        t_calls.append(time.perf_counter() - t0)
    t_fast = min(t_calls)
    n_fast = sum(len(m) for m in decoded.values())
    fast_fps = n_fast / t_fast
    progress(f"per-frame cantools on the first {args.cantools_frames:,} frames ...")
    n_sub, n_ct, t_ct = cantools_rate(frames, db, args.cantools_frames)
    ct_fps = n_ct / t_ct
    ratio = fast_fps / ct_fps
    print(
        f"decode (hmpc fast path, all {len(frames):,} frames): {n_fast:,} frames of "
        f"{len(decoded)} messages decoded in {t_fast:.2f} s = {fast_fps:,.0f} decoded frames/s "
        f"(the faster of two calls: {t_calls[0]:.2f} s, {t_calls[1]:.2f} s)"
    )
    print(
        f"decode (cantools decode_message per frame, the first {n_sub:,} frames only): "
        f"{n_ct:,} decoded in {t_ct:.2f} s = {ct_fps:,.0f} decoded frames/s"
    )
    print(f"decode ratio hmpc/cantools: {ratio:.1f}x")
    verdicts.append(
        (
            f"decode >= {TARGET_RATIO:g}x cantools",
            "PASS" if ratio >= TARGET_RATIO else "MISS",
            f"{ratio:.1f}x",
        )
    )
    results.update(
        {
            "read_s": t_read,
            "fast_frames": n_fast,
            "fast_s": t_fast,
            "cantools_frames": n_ct,
            "cantools_s": t_ct,
            "ratio": ratio,
        }
    )

    print(
        f"\nload average while running: {', '.join(f'{x:.1f}' for x in os.getloadavg())} "
        f"on {os.cpu_count()} CPUs"
    )
    print("targets:")
    for name, verdict, value in verdicts:
        print(f"  {verdict:4s}  {name:28s} {value}")
    if tmpdir is not None:
        del frames, decoded
        tmpdir.cleanup()
    return 0 if all(v == "PASS" for _, v, _ in verdicts) else 1


if __name__ == "__main__":
    sys.exit(main())
