"""``hmpc info LOG [--dbc DBC] [--json FILE]``: what a CAN log holds.

Prints duration, frames and rates per bus and id (with DBC message names given ``--dbc``), the
largest gap of each id against its median period, clock problems (steps backwards, forward
jumps, duplicates) and malformed lines; recoverable problems go to stderr; ``--json`` gets the
same figures (stable keys, SI units).
"""

from __future__ import annotations

import math
import sys

from hmpc.models.logs.canlog import FORMATS
from hmpc.models.errors import InputError, Problems
from hmpc.tools.common import write_json
from hmpc.models.logs.info import format_info, log_info


def add_arguments(p) -> None:
    p.add_argument(
        "log",
        metavar="LOG",
        help="CAN log: candump -L, libpanda CSV, or any "
        "python-can format (.asc .blf .trc .csv), optionally .gz",
    )
    p.add_argument("--dbc", metavar="DBC", help="DBC file (optionally .gz) for message names")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.add_argument(
        "--format",
        dest="fmt",
        choices=FORMATS,
        help="log format (default: from the suffix and first line)",
    )
    p.add_argument(
        "--jump-s",
        type=float,
        default=1.0,
        metavar="S",
        help="report forward clock jumps longer than S seconds (default 1.0)",
    )


def run(args) -> int:

    if not (math.isfinite(args.jump_s) and args.jump_s > 0):
        raise InputError(f"--jump-s must be a finite number of seconds > 0, got {args.jump_s:g}")
    problems = Problems()
    info = log_info(args.log, problems, dbc_path=args.dbc, fmt=args.fmt, jump_s=args.jump_s)
    print(format_info(info))
    for line in problems.lines():
        print(f"hmpc info: {line}", file=sys.stderr)
    write_json(args.json, info)
    return 0
