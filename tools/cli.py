"""The ``hmpc`` console script: one module per subcommand, all logic in the library.

Exit status (docs/conventions.md): 0 success, 2 bad input (one line on stderr naming
the file and the line, frame or channel), 1 internal failure.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from pathlib import Path

from threadpoolctl import threadpool_limits

from hmpc import __version__
from hmpc.models.errors import HmpcError, InputError

#: subcommand -> module under tools/ that provides ``add_arguments(p)`` and ``run(args) -> int``.
SUBCOMMANDS = {
    "info": (
        "hmpc.tools.cmd_info",
        "what a CAN log holds: frames and rates per bus/ID, gaps, clock problems",
    ),
    "ingest": ("hmpc.tools.cmd_ingest", "raw CAN/nav/IMU logs to one canonical recording"),
    "identify": ("hmpc.tools.cmd_identify", "recover the report's steering and accelerator models"),
    "simulate": ("hmpc.tools.cmd_simulate", "simulate an experiment or run the closed loop"),
    "drive": ("hmpc.tools.cmd_drive", "the real-time actuation loop on a CAN bus"),
    "diagnose": (
        "hmpc.tools.cmd_diagnose",
        "where model and recording differ, the missing physics named",
    ),
    "teleop": (
        "hmpc.tools.cmd_teleop",
        "the vehicle side of tele-operation: the drive loop fed by the authenticated operator link",
    ),
    "operator": (
        "hmpc.tools.cmd_operator",
        "the tele-operation station: scripted, experiment, keyboard or gamepad operator",
    ),
    "fleet": (
        "hmpc.tools.cmd_fleet",
        "many drives on a Dask cluster (run), and each vehicle across its drives: pooled "
        "values, drift (report)",
    ),
    "replay": (
        "hmpc.tools.cmd_replay",
        "offline closed-loop replay of a recorded drive: on the plant, or its log through "
        "the drive loop",
    ),
}


class MissingSubcommandError(ImportError):
    """A subcommand in SUBCOMMANDS whose module cannot be found (an internal failure, exit 1)."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``hmpc`` parser with every subcommand in SUBCOMMANDS.

    Args:
        command: the subcommand about to run: only its module is imported and only its
            options are added (the others are listed with their help text), so a command
            does not pay for importing every other command's libraries at start-up. None
            builds every subcommand's options (``hmpc COMMAND --help`` of any command).

    Raises:
        MissingSubcommandError: a subcommand's module is not installed.
    """
    parser = argparse.ArgumentParser(
        prog="hmpc",
        description="Recover a car's steering and accelerator models from its own "
        "CAN and GNSS/INS data (UC Berkeley EECS-2008-92) and drive it with a hybrid-mode MPC. "
        "'hmpc COMMAND --help' describes each command.",
    )
    parser.add_argument("--version", action="version", version=f"hmpc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (modname, helptext) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=helptext, description=helptext)
        if command is not None and name != command:
            continue
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            # A declared subcommand without its module is a broken install or a typo in
            # SUBCOMMANDS, never a subcommand to drop quietly from --help.
            raise MissingSubcommandError(
                f"subcommand {name!r}: its module {modname} is missing"
            ) from exc
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _outputs=getattr(mod, "OUTPUTS", {}))
    return parser


def _chosen(argv: list[str]) -> str | None:
    """The subcommand ``argv`` names (its first word that is not an option), if any."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in SUBCOMMANDS else None
    return None


#: argparse destinations that name a file a subcommand writes, and a folder it fills, with
#: what they hold: checked before the work starts, so a typo in an output path costs nothing
#: and leaves no other output half-done (e.g. --out written, then --json refused). A
#: subcommand module may name its outputs more precisely in ``OUTPUTS`` ({dest: noun}).
OUTPUT_FILES = {
    "out": "the output",
    "json": "JSON",
    "candump": "the candump log",
    "params_out": "the parameter file",
    "write_script": "the script",
}
OUTPUT_DIRS = {"plots": "the plots", "report": "the report"}


def _option(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def check_output_file(path: str, option: str, what: str = "the output") -> None:
    """InputError naming ``path`` when the file cannot be created or overwritten."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"cannot write {what} ({option}: is a folder, expected a file)", path)
    parent = p.parent
    if not parent.is_dir():
        raise InputError(f"cannot write {what} ({option}: folder '{parent}' does not exist)", path)
    if p.exists():
        if not os.access(p, os.W_OK):
            raise InputError(f"cannot write {what} ({option}: permission denied)", path)
        return
    try:  # create and remove: the only test that also holds for root and /proc
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise InputError(f"cannot write {what} ({option}: {exc.strerror or exc})", path) from None
    os.close(fd)
    os.unlink(p)


def check_output_dir(path: str, option: str, what: str = "the output") -> None:
    """InputError naming ``path`` when it is a file, or its nearest existing ancestor is not
    a writable folder."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"cannot write {what} ({option}: exists and is not a folder)", path)
    anc = p
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir() or not os.access(anc, os.W_OK):
        raise InputError(f"cannot write {what} ({option}: '{anc}' is not a writable folder)", path)


def check_outputs(args: argparse.Namespace) -> None:
    """Every output path of ``args`` checked before the subcommand runs (InputError)."""
    names = getattr(args, "_outputs", {})
    for table, check in ((OUTPUT_FILES, check_output_file), (OUTPUT_DIRS, check_output_dir)):
        for dest, what in table.items():
            value = getattr(args, dest, None)
            if isinstance(value, str) and value:
                check(value, _option(dest), names.get(dest, what))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _chosen(argv)
    try:
        # no subcommand named (``hmpc``, ``hmpc --help``): the overview needs no module
        parser = build_parser(command) if command is not None else build_parser("")
    except MissingSubcommandError as exc:
        traceback.print_exc()
        print(
            f"hmpc: internal error: {exc} (a bug in hmpc's install; please report it)",
            file=sys.stderr,
        )
        return 1
    args = parser.parse_args(argv)
    try:
        # one BLAS thread: hmpc's matrices are small (states <= 7, fits of ~10 columns, the
        # QPs in OSQP's own C), where OpenBLAS's threads only add latency (a 3x3 DARE: 33 ms
        # median with two threads on a loaded 2-core machine, 1.1 ms on one)
        check_outputs(args)
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
        print(
            f"hmpc {args.command}: internal error (a bug in hmpc; please report it)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
