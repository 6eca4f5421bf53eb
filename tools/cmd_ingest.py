"""`hmpc ingest`: raw CAN log (+ GPS/INS, IMU) to one canonical recording (models.ingest)."""
from __future__ import annotations

import argparse
import math
import sys

from hmpc.models.errors import InputError
from hmpc.models.logs.ingest import DEFAULT_PREFERENCE, ingest_files
from hmpc.models.logs.nav import load_columns


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _finite(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _prefer(text: str) -> tuple[str, str]:
    ch, sep, src = text.partition("=")
    if not sep or ch not in DEFAULT_PREFERENCE or src not in DEFAULT_PREFERENCE[ch]:
        choices = "; ".join(f"{c}={'|'.join(s)}" for c, s in DEFAULT_PREFERENCE.items())
        raise argparse.ArgumentTypeError(f"expected CHANNEL=SOURCE ({choices}), got {text!r}")
    return ch, src


def add_ingest_options(p: argparse.ArgumentParser, *, log_required: bool = True) -> None:
    """The options of `hmpc ingest` (also used by commands that take a raw log)."""
    p.add_argument("--dbc", required=log_required, help="the car's DBC file (optionally .gz)")
    p.add_argument("--signals", required=log_required, metavar="MAP.yaml",
                   help="signal map (params/<vehicle>.signals.yaml)")
    p.add_argument("--nav", metavar="NAV.csv", help="GPS/INS CSV (lat/lon or x/y, velocities, attitude)")
    p.add_argument("--imu", metavar="IMU.csv", help="IMU CSV (gyro + accelerometer)")
    p.add_argument("--columns", metavar="COLS.yaml",
                   help="column names of the nav/IMU CSVs (sections nav:, imu:); "
                        "default: the comma2k19 layout")
    p.add_argument("--rate", type=_positive, default=50.0, metavar="HZ",
                   help="grid rate of the recording [Hz] (default 50)")
    p.add_argument("--clock-offset", type=_finite, metavar="S",
                   help="nav clock offset [s] added to nav times to reach the CAN clock "
                        "(default: estimated from CAN speed vs GNSS speed)")
    p.add_argument("--imu-offset", type=_finite, metavar="S",
                   help="IMU clock offset [s] (default: the nav offset, same device; "
                        "without nav: estimated from yaw rate)")
    p.add_argument("--gap", type=_positive, metavar="S",
                   help="gap threshold [s] for every channel (default: max(0.5 s, 5 median "
                        "sample periods) per channel)")
    p.add_argument("--no-mount-correction", action="store_true",
                   help="keep the device heading (do not remove the estimated mount offset)")
    p.add_argument("--prefer", type=_prefer, action="append", default=[], metavar="CH=SRC",
                   help="source for a channel several sources give, e.g. yaw_rate=can")
    p.add_argument("--dbc-lenient", action="store_true",
                   help="skip DBC lines cantools cannot parse (each reported with its line) "
                        "instead of refusing the DBC; strict by default")


#: what ``--out`` holds, for the CLI's check of output paths (tools/cli.py)
OUTPUTS = {"out": "the recording"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG", help="CAN log (candump -L, .asc, .blf, .trc, python-can "
                                              ".csv, libpanda CSV; optionally .gz)")
    add_ingest_options(p)
    p.add_argument("--out", required=True, metavar="REC.csv",
                   help="canonical recording to write (.csv, .csv.gz, or .parquet with pyarrow)")
    p.add_argument("--json", metavar="FILE", help="write the summary (stable keys, SI units)")


def ingest_from_args(args, progress=None):
    """Run models.ingest.ingest_files with the options of :func:`add_ingest_options`."""
    nav_cols = imu_cols = None
    if args.columns:
        nav_cols, imu_cols = load_columns(args.columns)
    return ingest_files(args.log, args.dbc, args.signals, nav_path=args.nav, imu_path=args.imu,
                        rate_hz=args.rate, clock_offset_s=args.clock_offset,
                        imu_offset_s=args.imu_offset, nav_columns=nav_cols,
                        imu_columns=imu_cols, gap_s=args.gap,
                        mount_correction=not args.no_mount_correction,
                        prefer=dict(args.prefer), dbc_lenient=getattr(args, "dbc_lenient", False),
                        progress=progress)


def _progress(msg: str) -> None:
    print(f"hmpc ingest: {msg}", file=sys.stderr, flush=True)


def summary_lines(summary: dict) -> list[str]:
    """The short human summary printed on stdout."""
    s = summary
    out = [f"log format: {s['log_format']}",
           f"vehicle {s['vehicle'] or '?'}: {s['duration_s']:.2f} s, {s['samples']} samples "
           f"at {s['rate_hz']:g} Hz, {len(s['channels'])} channels"]
    for ch, info in s["channels"].items():
        gaps = len(s["gaps"].get(ch, []))
        out.append(f"  {ch:22s} [{info['unit']}] {100 * info['valid_fraction']:5.1f}% valid"
                   f"{f', {gaps} gap(s)' if gaps else ''}  <- {info['source']}")
    if s["channels_absent"]:
        out.append("absent (optional, not in the log): " + ", ".join(s["channels_absent"]))
    out.append(f"speed: {s['speed_source']}")
    if s["speed_vs_gps"]:
        r = s["speed_vs_gps"]
        out.append(f"speed / GNSS speed above 5 m/s: {r['ratio_mean']:.4f} "
                   f"(rms difference {r['rms_difference_mps']:.3f} m/s)")
    for src in ("nav", "imu"):
        c = s["clock"][src]
        if c:
            peak = "" if c["correlation_peak"] is None else f", peak {c['correlation_peak']:.3f}"
            out.append(f"clock offset {src}: {c['offset_s']:+.3f} s ({c['method']}{peak})"
                       + ("" if c["ok"] else f" NOT OK: {c['note']}"))
    m = s["heading_mount"]
    if m:
        out.append(f"heading mount offset: {m['offset_deg']:+.2f} deg (heading - course over "
                   f"ground above {m['min_speed_mps']:g} m/s, residual rms "
                   f"{m['residual_rms_deg']:.2f} deg, {'removed' if m['applied'] else 'kept'})")
    if s["imu_gravity"]:
        out.append(f"IMU gravity: {s['imu_gravity']}")
    out.append(f"problems: {s['problems']['total']} recoverable (details on stderr)"
               if s["problems"]["total"] else "problems: none")
    for i in s.get("information", []):
        out.append(f"information: {i['count']} {i['kind']} ({i['detail']})")
    return out


def run(args) -> int:
    from hmpc.tools.cli import write_json

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


def recording_or_log(args, progress):
    """(recording, sources, ingest summary or None) for a subcommand that takes a canonical
    recording or a raw log with the ``hmpc ingest`` options (``args.recording``, ``--dbc``,
    ``--signals``, ``--nav``, ``--imu``, ...); ``progress(msg)`` reports on stderr."""
    from hmpc.models.logs.recording import Recording

    if args.dbc or args.signals:
        if not (args.dbc and args.signals):
            raise InputError("a raw log needs both --dbc and --signals", args.recording)
        progress("ingesting the raw log")
        res = ingest_from_args(argparse.Namespace(**{**vars(args), "log": args.recording}),
                               progress=progress)
        for line in res.problems.lines():
            progress(line)
        sources = {"log": args.recording, "dbc": args.dbc, "signals": args.signals,
                   "nav": args.nav, "imu": args.imu}
        return res.recording, sources, res.summary
    if args.nav or args.imu:
        raise InputError("--nav/--imu need a raw log with --dbc and --signals", args.recording)
    try:
        rec = Recording.load(args.recording)
    except InputError as exc:
        if "not a canonical recording" in exc.reason:
            raise InputError("not a canonical recording (no 'time' column); for a raw CAN log "
                             "give --dbc and --signals", args.recording) from None
        raise
    return rec, {"recording": args.recording}, None
