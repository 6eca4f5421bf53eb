"""`hmpc fleet`: many drives at once on a Dask cluster (`fleet run`), and what they say about
each vehicle across drives (`fleet report`); the work lives in hmpc.models.fleet."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from hmpc.models.errors import InputError
from hmpc.models.fleet.store import STEPS
from hmpc.tools.common import write_json

#: what the outputs hold, for the CLI's check of output paths (tools/cli.py)
OUTPUTS = {"json": "the JSON"}


def _steps(text: str) -> tuple:
    steps = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in steps if s not in STEPS]
    if not steps or bad:
        raise argparse.ArgumentTypeError(f"expected steps from {','.join(STEPS)}, got {text!r}")
    return tuple(s for s in STEPS if s in steps)


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of workers, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected at least 1 worker, got {text!r}")
    return n


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="fleet_command", required=True, metavar="run|report")
    r = sub.add_parser(
        "run",
        help="ingest, identify and diagnose every drive of a manifest",
        description="Every drive of MANIFEST (docs/conventions.md, 'Fleet') "
        "through the steps, on a local cluster of worker processes or an "
        "existing Dask scheduler; a drive already finished with the same "
        "inputs and hmpc version is skipped. Exit 0: none failed; 1: some "
        "failed (the rest are done); 2: bad manifest.",
    )
    r.add_argument("manifest", metavar="MANIFEST.csv", help="one row per drive")
    r.add_argument(
        "--out",
        dest="store",
        required=True,
        metavar="STORE",
        help="the store folder (created; one sub-folder per drive)",
    )
    g = r.add_mutually_exclusive_group()
    g.add_argument(
        "--workers",
        type=_workers,
        metavar="N",
        help="local worker processes (default: the machine's cores)",
    )
    g.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="an existing Dask scheduler (dask scheduler + dask worker)",
    )
    r.add_argument(
        "--steps",
        type=_steps,
        default=STEPS,
        metavar="ingest,identify,diagnose",
        help="the steps to run (default all three)",
    )
    r.add_argument("--json", metavar="RUN.json", help="write drives, done, skipped, failed, wall_s")
    q = sub.add_parser(
        "report",
        help="per vehicle and parameter: drives, pooled value, drift",
        description="Per vehicle and parameter: every drive's value with its "
        "interval, the pooled value, drift across drives; vehicles of one "
        "model compared; failed drives.",
    )
    q.add_argument("store", metavar="STORE", help="a store written by hmpc fleet run")
    q.add_argument("--json", metavar="FILE", help="write the report (docs/conventions.md)")
    q.add_argument("--html", metavar="DIR", help="write an HTML report with figures")


def run(args) -> int:
    if args.fleet_command == "run":
        return _run(args)
    return _report(args)


def _run(args) -> int:
    from hmpc.models.fleet.engine import run_fleet

    store = Path(args.store)
    if store.exists() and not store.is_dir():
        raise InputError("cannot write the store (--out: exists and is not a folder)", str(store))
    res = run_fleet(
        args.manifest, store, steps=args.steps, workers=args.workers, scheduler=args.scheduler
    )
    print(
        f"drives {res.drives}: done {len(res.done)}, skipped {len(res.skipped)}, "
        f"failed {len(res.failed)} in {res.wall_s:.1f} s"
    )
    for f in res.failed:
        print(f"failed {f['drive_id']} (exit {f['exit']}): {f['error']}")
    write_json(args.json, res.to_json())
    if res.interrupted:
        print(
            "hmpc fleet: interrupted: the drives not finished were cancelled; every "
            "finished drive is in the store (a rerun does the rest)",
            file=sys.stderr,
        )
        return 130
    return 1 if res.failed else 0


def _report(args) -> int:
    from hmpc.models.fleet.report import build_report, finite_or_none

    rep = finite_or_none(build_report(args.store))
    for vid, v in rep["vehicles"].items():
        print(f"vehicle {vid} ({v['model']}): {v['drives']} drives")
        for key, e in v["parameters"].items():
            ci = e["ci95"]
            ci_s = f" [{ci[0]:.6g}, {ci[1]:.6g}]" if ci else ""
            d = e["drift"]
            d_s = (
                f"  DRIFT ({d['kind']}) from {d['from_drive']}: {d['before']:.6g} -> "
                f"{d['after']:.6g}"
                if d
                else ""
            )
            pooled = "n/a" if e["pooled"] is None else f"{e['pooled']:.6g}"
            print(f"  {key:48s} {pooled}{ci_s}{d_s}")
    for f in rep["failed"]:
        print(f"failed {f['drive_id']} (exit {f['exit']}): {f['error']}")
    if args.html:
        from hmpc.models.fleet.html import write_html

        html = Path(args.html)
        if html.exists() and not html.is_dir():
            raise InputError(
                "cannot write the report (--html: exists and is not a folder)", args.html
            )
        try:
            index = write_html(rep, html)
        except OSError as exc:
            raise InputError(
                f"cannot write the report ({exc.strerror or exc})", args.html
            ) from None
        print(f"wrote {index}")
        rep["html"] = os.path.abspath(index)
    write_json(args.json, rep)
    return 0
