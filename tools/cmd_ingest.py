"""`hmpc ingest`: raw CAN log (+ GPS/INS, IMU) to one canonical recording (models.logs.ingest), or
a ROS recording with a topic map (``--topics``, models.logs.topic_ingest)."""

from __future__ import annotations

import argparse
import sys

from hmpc.models.errors import InputError
from hmpc.tools.common import add_ingest_options, ingest_from_args, progress_printer, write_json


#: what ``--out`` holds, for the CLI's check of output paths (tools/cli.py)
OUTPUTS = {"out": "the recording"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log",
        metavar="LOG",
        help="CAN log (candump -L, .asc, .blf, .trc, python-can "
        ".csv, libpanda CSV; optionally .gz), or with "
        "--topics a ROS recording (.bag, ROS 2 bag folder, "
        ".mcap, folder of topic CSVs)",
    )
    add_ingest_options(p)
    p.add_argument(
        "--out",
        required=True,
        metavar="REC.csv",
        help="canonical recording to write (.csv, .csv.gz, or .parquet with pyarrow)",
    )
    p.add_argument("--json", metavar="FILE", help="write the summary (stable keys, SI units)")


_progress = progress_printer("ingest")


def summary_lines(summary: dict) -> list[str]:
    """The short human summary printed on stdout."""
    s = summary
    out = [
        f"log format: {s['log_format']}",
        f"vehicle {s['vehicle'] or '?'}: {s['duration_s']:.2f} s, {s['samples']} samples "
        f"at {s['rate_hz']:g} Hz, {len(s['channels'])} channels",
    ]
    for ch, info in s["channels"].items():
        gaps = len(s["gaps"].get(ch, []))
        out.append(
            f"  {ch:22s} [{info['unit']}] {100 * info['valid_fraction']:5.1f}% valid"
            f"{f', {gaps} gap(s)' if gaps else ''}  <- {info['source']}"
        )
    if s["channels_absent"]:
        out.append("absent (optional, not in the log): " + ", ".join(s["channels_absent"]))
    out.append(f"speed: {s['speed_source']}")
    if s["speed_vs_gps"]:
        r = s["speed_vs_gps"]
        out.append(
            f"speed / GNSS speed above 5 m/s: {r['ratio_mean']:.4f} "
            f"(rms difference {r['rms_difference_mps']:.3f} m/s)"
        )
    for src in ("nav", "imu"):
        c = s["clock"][src]
        if c:
            peak = "" if c["correlation_peak"] is None else f", peak {c['correlation_peak']:.3f}"
            out.append(
                f"clock offset {src}: {c['offset_s']:+.3f} s ({c['method']}{peak})"
                + ("" if c["ok"] else f" NOT OK: {c['note']}")
            )
    m = s["heading_mount"]
    if m:
        out.append(
            f"heading mount offset: {m['offset_deg']:+.2f} deg (heading - course over "
            f"ground above {m['min_speed_mps']:g} m/s, residual rms "
            f"{m['residual_rms_deg']:.2f} deg, {'removed' if m['applied'] else 'kept'})"
        )
    if s["imu_gravity"]:
        out.append(f"IMU gravity: {s['imu_gravity']}")
    out.append(
        f"problems: {s['problems']['total']} recoverable (details on stderr)"
        if s["problems"]["total"]
        else "problems: none"
    )
    for i in s.get("information", []):
        out.append(f"information: {i['count']} {i['kind']} ({i['detail']})")
    return out


def run(args) -> int:

    res = ingest_from_args(args, progress=_progress)
    try:
        res.recording.save(args.out)
    except OSError as exc:
        raise InputError(f"cannot write the recording ({exc.strerror or exc})", args.out) from None
    for line in res.problems.lines():
        print(f"hmpc ingest: {line}", file=sys.stderr)
    for line in summary_lines(res.summary):
        print(line)
    print(f"wrote {args.out}")
    if args.json:
        payload = dict(res.summary)
        payload["output"] = str(args.out)
        try:
            write_json(args.json, payload)
        except OSError as exc:
            raise InputError(f"cannot write JSON ({exc.strerror or exc})", args.json) from None
    return 0
