"""What the subcommand modules share: option groups, progress lines, JSON output, model loading.

Each ``cmd_*`` module imports from here, never from another ``cmd_*`` module. The helpers
only parse options and print; the work they start lives in ``hmpc.models`` and
``hmpc.controller``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.logs.ingest import DEFAULT_PREFERENCE, ingest_files
from hmpc.models.logs.nav import load_columns
from hmpc.models.params import Params
from hmpc.models.unidentifiable import ACCEPT_UNIDENTIFIABLE_FLAG

from hmpc.controller.build import CONTROLLERS, load_model

__all__ = [
    "CONTROLLERS",
    "STOP_WHY",
    "add_accept_unidentifiable",
    "add_adapt_arguments",
    "add_bus_arguments",
    "add_ingest_options",
    "adapter_for_profile",
    "adapter_from_args",
    "bus_kwargs",
    "finish_adapter",
    "ingest_from_args",
    "load_model_params",
    "positive_float",
    "progress_printer",
    "recording_or_log",
    "report_not_followed",
    "stop_times",
    "write_json",
]


def progress_printer(command: str) -> Callable[[str], None]:
    """A progress callback that prints ``hmpc COMMAND: MSG`` on stderr, at once."""

    def progress(msg: str) -> None:
        print(f"hmpc {command}: {msg}", file=sys.stderr, flush=True)

    return progress


def write_json(path: str | None, payload: dict) -> None:
    """Write a ``--json`` result (stable keys, SI units); InputError naming the file when it
    cannot be written (exit 2, never a traceback)."""
    if path:
        text = json.dumps(payload, indent=2, sort_keys=False, default=_jsonable) + "\n"
        try:
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(text)
        except OSError as exc:
            raise InputError(f"cannot write JSON ({exc.strerror or exc})", path) from None


def _jsonable(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def positive_float(text: str) -> float:
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
    """The options of `hmpc ingest` (also used by commands that take a raw log).

    ``log_required``: a CAN log needs ``--dbc`` and ``--signals`` unless ``--topics`` names a
    ROS recording's topic map (checked by :func:`ingest_from_args`)."""
    p.add_argument(
        "--dbc",
        help="the car's DBC file (optionally .gz)"
        + ("; required for a CAN log" if log_required else ""),
    )
    p.add_argument(
        "--signals",
        metavar="MAP.yaml",
        help="signal map (params/<vehicle>.signals.yaml)"
        + ("; required for a CAN log" if log_required else ""),
    )
    p.add_argument(
        "--topics",
        metavar="MAP.yaml",
        help="topic map (params/*.topics.yaml): the log is a ROS recording -- a ROS 1 "
        ".bag, a ROS 2 bag folder, an .mcap file or a folder of per-topic CSV "
        "exports (bagpy, pandas) -- instead of a CAN log",
    )
    p.add_argument(
        "--nav", metavar="NAV.csv", help="GPS/INS CSV (lat/lon or x/y, velocities, attitude)"
    )
    p.add_argument("--imu", metavar="IMU.csv", help="IMU CSV (gyro + accelerometer)")
    p.add_argument(
        "--columns",
        metavar="COLS.yaml",
        help="column names of the nav/IMU CSVs (sections nav:, imu:); "
        "default: the comma2k19 layout",
    )
    p.add_argument(
        "--rate",
        type=positive_float,
        default=50.0,
        metavar="HZ",
        help="grid rate of the recording [Hz] (default 50)",
    )
    p.add_argument(
        "--clock-offset",
        type=_finite,
        metavar="S",
        help="nav clock offset [s] added to nav times to reach the CAN clock "
        "(default: estimated from CAN speed vs GNSS speed)",
    )
    p.add_argument(
        "--imu-offset",
        type=_finite,
        metavar="S",
        help="IMU clock offset [s] (default: the nav offset, same device; "
        "without nav: estimated from yaw rate)",
    )
    p.add_argument(
        "--gap",
        type=positive_float,
        metavar="S",
        help="gap threshold [s] for every channel (default: max(0.5 s, 5 median "
        "sample periods) per channel)",
    )
    p.add_argument(
        "--no-mount-correction",
        action="store_true",
        help="keep the device heading (do not remove the estimated mount offset)",
    )
    p.add_argument(
        "--prefer",
        type=_prefer,
        action="append",
        default=[],
        metavar="CH=SRC",
        help="source for a channel several sources give, e.g. yaw_rate=can",
    )
    p.add_argument(
        "--dbc-lenient",
        action="store_true",
        help="skip DBC lines cantools cannot parse (each reported with its line) "
        "instead of refusing the DBC; strict by default",
    )


#: options of :func:`add_ingest_options` that apply to CAN logs only (dest -> option)
CAN_ONLY_OPTIONS = {
    "dbc": "--dbc",
    "signals": "--signals",
    "nav": "--nav",
    "imu": "--imu",
    "columns": "--columns",
    "clock_offset": "--clock-offset",
    "imu_offset": "--imu-offset",
    "no_mount_correction": "--no-mount-correction",
    "prefer": "--prefer",
    "dbc_lenient": "--dbc-lenient",
}


def ingest_from_args(args, progress=None):
    """Run models.logs.ingest.ingest_files with the options of :func:`add_ingest_options`, or
    models.logs.topic_ingest.ingest_topics when ``--topics`` names a topic map."""
    if getattr(args, "topics", None):
        return _ingest_topics_from_args(args, progress)
    if not (args.dbc and args.signals):
        raise InputError(
            "a CAN log needs --dbc and --signals (a ROS recording: --topics MAP.yaml)", args.log
        )
    nav_cols = imu_cols = None
    if args.columns:
        nav_cols, imu_cols = load_columns(args.columns)
    return ingest_files(
        args.log,
        args.dbc,
        args.signals,
        nav_path=args.nav,
        imu_path=args.imu,
        rate_hz=args.rate,
        clock_offset_s=args.clock_offset,
        imu_offset_s=args.imu_offset,
        nav_columns=nav_cols,
        imu_columns=imu_cols,
        gap_s=args.gap,
        mount_correction=not args.no_mount_correction,
        prefer=dict(args.prefer),
        dbc_lenient=getattr(args, "dbc_lenient", False),
        progress=progress,
    )


def _ingest_topics_from_args(args, progress):
    """``--topics``: a ROS recording; the CAN-only options are refused (one line each)."""
    from hmpc.models.logs.topic_ingest import ingest_topics

    for dest, option in CAN_ONLY_OPTIONS.items():
        if getattr(args, dest, None):
            raise InputError(
                f"{option} applies to CAN logs, not to a ROS recording read with --topics", args.log
            )
    return ingest_topics(
        args.log, args.topics, rate_hz=args.rate, gap_s=args.gap, progress=progress
    )


def recording_or_log(args, progress):
    """(recording, sources, ingest summary or None) for a subcommand that takes a canonical
    recording or a raw log with the ``hmpc ingest`` options (``args.recording``, ``--dbc``,
    ``--signals``, ``--nav``, ``--imu``, ...); ``progress(msg)`` reports on stderr."""
    from hmpc.models.logs.recording import Recording

    if getattr(args, "topics", None):
        progress("ingesting the ROS recording")
        res = ingest_from_args(
            argparse.Namespace(**{**vars(args), "log": args.recording}), progress=progress
        )
        for line in res.problems.lines():
            progress(line)
        return res.recording, {"log": args.recording, "topics": args.topics}, res.summary
    if args.dbc or args.signals:
        if not (args.dbc and args.signals):
            raise InputError("a raw log needs both --dbc and --signals", args.recording)
        progress("ingesting the raw log")
        res = ingest_from_args(
            argparse.Namespace(**{**vars(args), "log": args.recording}), progress=progress
        )
        for line in res.problems.lines():
            progress(line)
        sources = {
            "log": args.recording,
            "dbc": args.dbc,
            "signals": args.signals,
            "nav": args.nav,
            "imu": args.imu,
        }
        return res.recording, sources, res.summary
    if args.nav or args.imu:
        raise InputError("--nav/--imu need a raw log with --dbc and --signals", args.recording)
    try:
        rec = Recording.load(args.recording)
    except InputError as exc:
        if "not a canonical recording" in exc.reason:
            raise InputError(
                "not a canonical recording (no 'time' column); for a raw CAN log "
                "give --dbc and --signals",
                args.recording,
            ) from None
        raise
    return rec, {"recording": args.recording}, None


def add_accept_unidentifiable(p) -> None:
    """The option that accepts values flagged ``identifiable: false`` (simulate and drive)."""
    p.add_argument(
        ACCEPT_UNIDENTIFIABLE_FLAG,
        action="store_true",
        help="use steering or zone values that identification flagged "
        "'identifiable: false' (refused without it; a warning line each)",
    )


def load_model_params(path, args, command: str) -> Params:
    """:func:`hmpc.controller.build.load_model` with ``--accept-unidentifiable`` from ``args``;
    prints its warning lines on stderr, prefixed ``hmpc COMMAND: warning:``."""
    params, warnings = load_model(
        path, accept_unidentifiable=getattr(args, "accept_unidentifiable", False)
    )
    for line in warnings:
        print(f"hmpc {command}: warning: {line}", file=sys.stderr)
    return params


def add_bus_arguments(p) -> None:
    """The options every loop on a CAN bus shares (``drive``, ``teleop``): the bus, the
    simulated car on its other end, and the model refusal flag."""
    p.add_argument(
        "--bus",
        default="virtual",
        metavar="virtual|socketcan:CHANNEL",
        help="the CAN bus (default virtual: python-can's in-process virtual bus)",
    )
    p.add_argument(
        "--vehicle-sim",
        action="store_true",
        help="run the vehicle simulator node on the other end of the bus",
    )
    add_accept_unidentifiable(p)
    p.add_argument(
        "--plant-params",
        metavar="P2.yaml",
        help="the simulated car's parameters (default: --params)",
    )


#: what an unrequested stop means, for the warning line
STOP_WHY = {
    "feedback_loss": "the car's wheel speeds went stale for more than 3 of their periods; "
    "on a loaded host a stall of the process does this",
    "driver_override": "the driver steered, braked or pressed the accelerator",
    "vehicle_rejects": "the car stopped accepting hmpc's frames",
    "solver_failure": "the controller failed to solve",
    "bus_error": "sending on the bus failed",
    "clock_freeze": "the loop's monotonic clock stopped advancing",
    "clock_jump": "the loop's monotonic clock jumped",
    "deadline_misses": "the loop missed its period several times in a row (a loaded host)",
}


def stop_times(st: dict) -> str:
    """'detected 30.30 s, started 30.30 s, standstill 32.68 s' (run time; '-' when absent)."""
    f = lambda v: "-" if v is None else f"{v:.2f} s"  # noqa: E731
    return (
        f"detected {f(st['detected_t_s'])}, started {f(st['t_s'])}, "
        f"standstill {f(st['standstill_t_s'])}"
    )


def bus_kwargs(text: str) -> dict:
    """``virtual`` -> a private virtual channel; ``socketcan:vcan0`` -> socketcan on vcan0."""
    if text == "virtual":
        return {"interface": "virtual", "channel": f"hmpc-drive-{os.getpid()}"}
    iface, sep, chan = text.partition(":")
    if not sep or not iface or not chan:
        raise InputError(f"--bus '{text}': expected virtual or INTERFACE:CHANNEL")
    return {"interface": iface, "channel": chan}


def add_adapt_arguments(p) -> None:
    """The online model estimator's options (``simulate``, ``drive``, ``teleop``, ``replay``)."""
    p.add_argument(
        "--adapt",
        action="store_true",
        help="learn the model on line (steering map, zone gains, dead times and "
        "lags) and control with what was learned while it is valid; the "
        "JSON's 'adaptation' holds each value's start, end, interval and "
        "convergence time",
    )
    p.add_argument(
        "--learned",
        metavar="FILE",
        help="with --adapt (implied): restore the learned state of this vehicle "
        "from FILE (a parameter file) when it exists, and save it there at "
        "the end",
    )


def adapter_from_args(args, params: Params, period_s: float, command: str, **kw):
    """The run's ``controller.adapt.ModelAdapter`` (None without ``--adapt``/``--learned``),
    restored from ``--learned`` when that file exists (its lines printed on stderr). ``kw``:
    the adapter's keyword arguments (inputs, sensor noise)."""
    from hmpc.controller.adapt import ModelAdapter
    from hmpc.controller.adapt.learned import restore
    from hmpc.models.params import load_params

    path = getattr(args, "learned", None)
    if not (getattr(args, "adapt", False) or path):
        return None
    adapter = ModelAdapter(params, period_s, **kw)
    if path:
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            raise InputError(
                f"cannot write the learned state (--learned: folder '{folder}' "
                "is not a writable folder)",
                path,
            )
        if os.path.exists(path):
            for line in restore(adapter, load_params(path, require_model=True), path):
                print(f"hmpc {command}: restored from {path}: {line}", file=sys.stderr)
        else:
            print(
                f"hmpc {command}: {path} does not exist yet: learning from the model's "
                "values; saved there at the end",
                file=sys.stderr,
            )
    return adapter


def finish_adapter(args, adapter, command: str, run_s: float) -> None:
    """After a run with an adapter: print its fall-backs and a line per learned value on
    stderr, and save the state to ``--learned``."""
    if adapter is None:
        return
    from hmpc.controller.adapt.learned import learned_params, save_learned

    for t, what in adapter.events:
        print(f"hmpc {command}: adaptation at {t:.1f} s: {what}", file=sys.stderr)
    rep = adapter.report(adapter.t0_s)
    for key, e in rep.items():
        if e.get("updates", 1) or e.get("valid"):
            ci = e.get("ci95")
            ci_s = f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci else ""
            conv = e["converged_t_s"]
            unused = "" if e.get("valid") else f" (not used: {e.get('reason', 'not valid')})"
            print(
                f"  adaptation {key}: {e['initial']:.4g} -> {e['final']:.4g}{ci_s}"
                f"{'' if conv is None else f', converged at {conv:.1f} s'}{unused}",
                file=sys.stderr,
            )
    if getattr(args, "learned", None):
        save_learned(learned_params(adapter, run_s=run_s), args.learned)
        print(f"hmpc {command}: learned state saved to {args.learned}", file=sys.stderr)


def adapter_for_profile(args, params: Params, profile, command: str):
    """:func:`adapter_from_args` for a loop on a CAN bus (``drive``, ``teleop``, ``replay
    --mode log``): the drive loop's control period, and the commands the car takes (an
    acceleration request, or pedal positions)."""
    from hmpc.controller.actuation.drive import DriveConfig

    inputs = "accel_cmd" if "accel" in profile.commands else "pedals"
    return adapter_from_args(args, params, DriveConfig().control_period_s, command, inputs=inputs)


def report_not_followed(summary: dict, command: str) -> int:
    """1 (printed why on stderr) when the run's car did not follow its reference, else 0."""
    if summary.get("followed", True):
        return 0
    print(
        f"hmpc {command}: the car did not follow its reference: "
        f"{'; '.join(summary['not_followed'])}",
        file=sys.stderr,
    )
    return 1
