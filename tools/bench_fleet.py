"""Fleet benchmark: N simulated ten-minute drives of three cars (one with a concealed drift)
through ``hmpc fleet run`` (ingest, identify, diagnose) on 1 and 2 local workers and on a
Dask scheduler with two workers started as separate processes.

    .venv/bin/python -m hmpc.tools.bench_fleet                       # 12 drives of 10 min
    .venv/bin/python -m hmpc.tools.bench_fleet --drives 6 --minutes 3 --steps ingest,identify

1. Simulates the drives (``models.fleet.simfleet``: the report's experiments in turn, each
   vehicle a random truth; vehicle C's pedal gains fall 20 % from its third drive; not timed).
2. Runs the fleet on one local worker: the baseline (one drive after another, as a loop of
   single commands would), then on two local workers: hmpc's figure. Prints throughput in
   drive-hours per wall-hour for both, the ratio (speed-up) and the scaling efficiency
   (speed-up / workers), and each worker's peak resident memory.
3. Reruns the two-worker store: every drive skipped, the rerun's wall time beside the run's.
4. Starts ``dask scheduler`` and two ``dask worker`` processes, runs the same drives there,
   and compares the per-drive parameter tables (sha256 of the table as DuckDB returns it):
   the same results whichever worker ran a drive.
5. Reports the drift found on vehicle C (from which drive, after/before).

Each run's wall time includes starting its cluster (a LocalCluster: a few seconds). Progress
goes to stderr, results to stdout; ``--json`` writes them.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hmpc.models.fleet.engine import run_fleet
from hmpc.models.fleet.report import build_report, query_values
from hmpc.models.fleet.simfleet import SimVehicle, write_fleet
from hmpc.models.fleet.store import STEPS

#: three cars (seeds of their random truths); C's pedal gains fall 20 % from its third drive
VEHICLES = [
    SimVehicle("A", 11),
    SimVehicle("B", 22),
    SimVehicle("C", 33, drift_from=3, pedal_factor=0.8),
]
#: how long to wait for the scheduler's address file [s]: its start-up is a second or two
_SCHEDULER_START_S = 60.0


def _say(msg: str) -> None:
    print(f"bench_fleet: {msg}", file=sys.stderr, flush=True)


def _table_sha256(store) -> str:
    return hashlib.sha256(repr(query_values(store)).encode()).hexdigest()


def _run(manifest, store, steps, **kw) -> dict:
    res = run_fleet(manifest, store, steps=steps, **kw)
    if res.failed:
        raise SystemExit(f"bench_fleet: drives failed: {res.failed}")
    peaks: dict = {}
    for s in res.statuses.values():
        peaks[s["worker"]] = max(peaks.get(s["worker"], 0.0), s["worker_peak_rss_mb"])
    return {
        "wall_s": res.wall_s,
        "done": len(res.done),
        "skipped": len(res.skipped),
        "peak_rss_mb_per_worker": sorted(peaks.values()),
    }


def _scheduler_run(manifest, store, steps, tmp: Path) -> dict:
    dask = [sys.executable, "-m", "dask"]
    sched_file = tmp / "scheduler.json"
    procs = [
        subprocess.Popen(
            dask
            + [
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(sched_file),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        t_end = time.monotonic() + _SCHEDULER_START_S
        while not (sched_file.exists() and sched_file.stat().st_size):
            if time.monotonic() > t_end:
                raise SystemExit("bench_fleet: the dask scheduler did not start")
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    dask
                    + [
                        "worker",
                        "--scheduler-file",
                        str(sched_file),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                        "--host",
                        "127.0.0.1",
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        out = _run(manifest, store, steps, scheduler=address)
        out["address"] = address
        return out
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drives", type=int, default=12, help="drives in all (default 12)")
    ap.add_argument("--minutes", type=float, default=10.0, help="minutes per drive (10)")
    ap.add_argument("--steps", default=",".join(STEPS), help="steps (default all three)")
    ap.add_argument("--keep", metavar="DIR", help="keep the drives and stores in DIR")
    ap.add_argument("--json", metavar="FILE", help="write the figures")
    a = ap.parse_args(argv)
    steps = tuple(s for s in STEPS if s in a.steps.split(","))
    per_vehicle = max(1, a.drives // len(VEHICLES))
    tmp = Path(a.keep or tempfile.mkdtemp(prefix="bench_fleet_"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        _say(f"simulating {per_vehicle * len(VEHICLES)} drives of {a.minutes:g} min")
        manifest = write_fleet(tmp / "drives", VEHICLES, per_vehicle, duration_s=60.0 * a.minutes)
        n = per_vehicle * len(VEHICLES)
        drive_h = sum(_duration_h(p) for p in sorted((tmp / "drives").glob("*.parquet")))
        _say("1 local worker (the baseline)")
        one = _run(manifest, tmp / "store1", steps, workers=1)
        _say("2 local workers")
        two = _run(manifest, tmp / "store2", steps, workers=2)
        _say("rerun of the 2-worker store (every drive skipped)")
        rerun = _run(manifest, tmp / "store2", steps, workers=2)
        _say("scheduler + 2 worker processes")
        sched = _scheduler_run(manifest, tmp / "store3", steps, tmp)
        hashes = {k: _table_sha256(tmp / k) for k in ("store1", "store2", "store3")}
        rep = build_report(tmp / "store2")
        drift = {k: e["drift"] for k, e in rep["vehicles"]["C"]["parameters"].items() if e["drift"]}
        false = [
            (v, k)
            for v in ("A", "B")
            for k, e in rep["vehicles"][v]["parameters"].items()
            if e["drift"]
        ]
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    thr1 = drive_h / (one["wall_s"] / 3600.0)
    thr2 = drive_h / (two["wall_s"] / 3600.0)
    thr_s = drive_h / (sched["wall_s"] / 3600.0)
    res = {
        "drives": n,
        "drive_hours": drive_h,
        "steps": list(steps),
        "one_worker": {**one, "drive_h_per_h": thr1},
        "two_workers": {**two, "drive_h_per_h": thr2},
        "scheduler_two_workers": {**sched, "drive_h_per_h": thr_s},
        "speedup": thr2 / thr1,
        "scaling_efficiency": thr2 / thr1 / 2,
        "rerun_wall_s": rerun["wall_s"],
        "rerun_skipped": rerun["skipped"],
        "tables_equal": len(set(hashes.values())) == 1,
        "table_sha256": hashes,
        "drift_found_on_C": drift,
        "drift_on_A_B": false,
    }
    print(f"{n} drives, {drive_h:.2f} drive-hours, steps {','.join(steps)}")
    print(f"baseline 1 local worker : {one['wall_s']:8.1f} s wall, {thr1:7.1f} drive-h per h")
    print(
        f"hmpc 2 local workers    : {two['wall_s']:8.1f} s wall, {thr2:7.1f} drive-h per h; "
        f"ratio {thr2 / thr1:.2f}x, scaling efficiency {100 * thr2 / thr1 / 2:.0f} %"
    )
    print(
        f"scheduler + 2 workers   : {sched['wall_s']:8.1f} s wall, {thr_s:7.1f} drive-h per h; "
        f"ratio to the baseline {thr_s / thr1:.2f}x"
    )
    print(
        f"peak memory per worker [MB]: 1 worker {one['peak_rss_mb_per_worker']}, "
        f"2 workers {two['peak_rss_mb_per_worker']}, scheduler's workers "
        f"{sched['peak_rss_mb_per_worker']}"
    )
    print(
        f"rerun: {rerun['skipped']} of {n} skipped in {rerun['wall_s']:.2f} s "
        f"({100 * rerun['wall_s'] / two['wall_s']:.1f} % of the run)"
    )
    print(
        f"per-drive tables identical across the three runs: {res['tables_equal']} "
        f"(sha256 {hashes['store1'][:16]})"
    )
    for k, d in sorted(drift.items()):
        print(
            f"C drift {k}: {d['kind']} from {d['from_drive']}, after/before "
            f"{d['after'] / d['before']:.3f}"
        )
    print(f"drift reported on A or B (no change there): {false or 'none'}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0 if res["tables_equal"] and rerun["skipped"] == n else 1


def _duration_h(path: Path) -> float:
    import pyarrow.parquet as pq

    t = pq.read_table(path, columns=["time"]).column("time")
    return (t[len(t) - 1].as_py() - t[0].as_py()) / 3600.0


if __name__ == "__main__":
    sys.exit(main())
