"""The ``hmpc`` console script: one module per subcommand, all logic in the library.

Exit status (../shared/CONVENTIONS.md): 0 success, 2 bad input (one line on stderr naming
the file and the line, frame or channel), 1 internal failure.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import traceback

from threadpoolctl import threadpool_limits

from hmpc import __version__
from hmpc.models.errors import HmpcError, InputError

#: subcommand -> module under tools/ that provides ``add_arguments(p)`` and ``run(args) -> int``.
SUBCOMMANDS = {
    "info": ("hmpc.tools.cmd_info", "what a CAN log holds: frames and rates per bus/ID, gaps, clock problems"),
    "ingest": ("hmpc.tools.cmd_ingest", "raw CAN/nav/IMU logs to one canonical recording"),
    "identify": ("hmpc.tools.cmd_identify", "recover the report's steering and accelerator models"),
    "simulate": ("hmpc.tools.cmd_simulate", "simulate an experiment or run the closed loop"),
    "drive": ("hmpc.tools.cmd_drive", "the real-time actuation loop on a CAN bus"),
    "diagnose": ("hmpc.tools.cmd_diagnose", "where model and recording differ, the missing physics named"),
    "teleop": ("hmpc.tools.cmd_teleop", "the vehicle side of tele-operation: the drive loop fed by the authenticated operator link"),
    "operator": ("hmpc.tools.cmd_operator", "the tele-operation station: scripted, experiment, keyboard or gamepad operator"),
    "replay": ("hmpc.tools.cmd_replay", "offline closed-loop replay of a recorded drive: on the plant, or its log through the drive loop"),
}


class MissingSubcommandError(ImportError):
    """A subcommand in SUBCOMMANDS whose module cannot be found (an internal failure, exit 1)."""


def build_parser() -> argparse.ArgumentParser:
    """The ``hmpc`` parser with every subcommand in SUBCOMMANDS.

    Raises:
        MissingSubcommandError: a subcommand's module is not installed.
    """
    parser = argparse.ArgumentParser(prog="hmpc", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"hmpc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (modname, helptext) in SUBCOMMANDS.items():
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            # A declared subcommand without its module is a broken install or a typo in
            # SUBCOMMANDS, never a subcommand to drop quietly from --help.
            raise MissingSubcommandError(
                f"subcommand {name!r}: its module {modname} is missing") from exc
        p = sub.add_parser(name, help=helptext, description=helptext)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def write_json(path: str | None, payload: dict) -> None:
    """Write a ``--json`` result (stable keys, SI units)."""
    if path:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(payload, fh, indent=2, sort_keys=False, default=_jsonable)
            fh.write("\n")


def _jsonable(obj):
    import numpy as np
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
    except MissingSubcommandError as exc:
        traceback.print_exc()
        print(f"hmpc: internal error: {exc} (a bug in hmpc's install; please report it)",
              file=sys.stderr)
        return 1
    args = parser.parse_args(argv)
    try:
        # one BLAS thread: hmpc's matrices are small (states <= 7, fits of ~10 columns, the
        # QPs in OSQP's own C), where OpenBLAS's threads only add latency (a 3x3 DARE: 33 ms
        # median with two threads on a loaded 2-core machine, 1.1 ms on one)
        with threadpool_limits(limits=1, user_api="blas"):
            return int(args._run(args) or 0)
    except InputError as exc:
        print(f"hmpc {args.command}: error: {exc.one_line()}", file=sys.stderr)
        return 2
    except HmpcError as exc:
        print(f"hmpc {args.command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"hmpc {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception:  # internal failure: keep the traceback for the bug report
        traceback.print_exc()
        print(f"hmpc {args.command}: internal error (a bug in hmpc; please report it)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
