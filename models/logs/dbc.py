"""Load a CAN database (DBC) with cantools, turning its errors into hmpc's :class:`InputError`.

``load_dbc("toyota_rav4_2017.dbc.gz")`` -> ``cantools.database.can.Database``. Gzip files are
decompressed; the text is parsed with ``cantools.database.load_string(text, database_format="dbc",
strict=False)`` (opendbc's DBCs hold overlapping mux-free signals that strict mode rejects;
the data README prescribes ``strict=False``).
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path
from typing import cast

from hmpc.models.logs.files import read_bytes
from hmpc.models.errors import InputError


#: most statements ``lenient`` mode may skip before it gives up (a file that needs more is
#: not a DBC with a few bad lines)
MAX_SKIPPED_LINES = 200


def load_dbc(path, *, strict: bool = False, lenient: bool = False, problems=None):
    """Load a DBC file (optionally ``.gz``).

    Args:
        path: the DBC file.
        strict: cantools' strict mode (rejects overlapping signals and signals outside the
            message); off by default, as the shared data README prescribes.
        lenient: skip the lines cantools cannot parse (e.g. a comment without a signal name,
            a pseudo message id wider than the frame format), one at a time, each reported in
            ``problems`` with its line number and cantools' reason; the default is to refuse
            the file (strict parsing, loosened only by this named flag: hmpc's
            ``--dbc-lenient``).
        problems: :class:`hmpc.models.errors.Problems` collector for what ``lenient`` skipped.

    Returns:
        The cantools database.

    Raises:
        InputError: missing, empty, not a DBC, or a syntax error (naming the line when cantools
            gives it), or a database without any message.
    """
    import cantools  # heavy import, only when a DBC is used

    p = Path(path)
    spath = str(path)
    if not p.is_file():
        raise InputError("no such DBC file" if not p.exists() else "not a regular file", spath)
    try:
        raw = read_bytes(p)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"cannot read DBC: {exc}", spath) from None
    if not raw.strip():
        raise InputError("empty DBC file", spath)
    if b"\0" in raw[:4096]:
        raise InputError("not a DBC file (binary content)", spath)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("cp1252", errors="replace")  # cantools' own default for DBC files
    lines = text.split("\n")
    skipped = 0
    while True:
        try:
            # a DBC loads as a CAN database (load_string's other result type is for CDD files)
            db = cast(
                cantools.database.can.Database,
                cantools.database.load_string(
                    "\n".join(lines), database_format="dbc", strict=strict
                ),
            )
            break
        # cantools raises ParseError, ValueError, KeyError, ... on bad DBCs
        except Exception as exc:
            msg = " ".join(str(exc).split())
            m = re.search(r"line (\d+)", msg)
            line = int(m.group(1)) if m else None
            if (
                not lenient
                or line is None
                or not 1 <= line <= len(lines)
                or not lines[line - 1].strip()
                or skipped >= MAX_SKIPPED_LINES
            ):
                hint = "" if lenient else " (--dbc-lenient skips such lines, reporting each)"
                raise InputError(f"not a valid DBC: {msg}{hint}", spath, line=line) from None
            if problems is not None:
                problems.add(
                    f"DBC line {line} skipped (--dbc-lenient: cantools cannot parse it)",
                    spath,
                    line,
                    detail=f"{lines[line - 1].strip()[:80]!r}: {msg}",
                )
            lines[line - 1] = ""  # keep the numbering of the lines after it
            skipped += 1
    if not db.messages:
        raise InputError("DBC defines no message", spath)
    return db
