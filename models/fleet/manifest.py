"""The fleet manifest (docs/conventions.md, "Fleet"): a CSV with a header, one row per drive,
paths relative to the manifest's folder.

Columns ``vehicle_id``, ``drive_id`` (unique), ``start_time`` (ISO 8601 UTC), ``geometry``
(vehicle YAML) and either ``recording`` (canonical CSV or Parquet) or ``log``, ``dbc``,
``signals`` with the optional ``nav``, ``imu`` (empty cells for absent ones); optional
``model`` (the vehicle model, for the fleet-wide comparison; default the geometry file's name
without its suffixes). A bad manifest is an InputError naming the file, the line and the
column (exit 2).
"""

from __future__ import annotations

import csv
import hashlib
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from hmpc.models.errors import InputError

REQUIRED = ("vehicle_id", "drive_id", "start_time", "geometry")
RAW = ("log", "dbc", "signals")
OPTIONAL_RAW = ("nav", "imu")
#: every column a manifest may hold
COLUMNS = REQUIRED + ("recording",) + RAW + OPTIONAL_RAW + ("model",)
#: the input files of a drive, in the order their hashes enter ``inputs_sha256``
FILE_ROLES = ("geometry", "recording") + RAW + OPTIONAL_RAW

#: ids name folders of the store: letters, digits, ``.``, ``_``, ``-`` (no path separators)
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
#: bytes read at a time when hashing an input file (1 MiB: few system calls, little memory)
_HASH_CHUNK_BYTES = 1 << 20


@dataclass(frozen=True)
class Drive:
    """One manifest row, paths absolute."""

    vehicle_id: str
    drive_id: str
    start_time: str
    files: dict = field(default_factory=dict)  # role -> absolute path (present roles only)
    model: str = ""
    line: int = 0

    @property
    def raw(self) -> bool:
        return "log" in self.files


def _utc(text: str, where: str) -> str:
    """``text`` as ``YYYY-MM-DDTHH:MM:SS[.ffffff]Z`` (UTC), or InputError."""
    t = text.strip()
    try:
        dt = datetime.fromisoformat(t[:-1] + "+00:00" if t.endswith(("Z", "z")) else t)
    except ValueError:
        raise InputError(
            f"{where}: start_time {text!r} is not ISO 8601 (e.g. 2026-01-05T08:00:00Z)"
        ) from None
    if dt.tzinfo is None:
        raise InputError(f"{where}: start_time {text!r} has no time zone (UTC: end it with Z)")
    dt = dt.astimezone(timezone.utc)
    fmt = "%Y-%m-%dT%H:%M:%S.%fZ" if dt.microsecond else "%Y-%m-%dT%H:%M:%SZ"
    return dt.strftime(fmt)


def read_manifest(path) -> list[Drive]:
    """The drives of the manifest at ``path``; InputError naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(
            f"cannot read the manifest ({getattr(exc, 'strerror', None) or exc})", str(path)
        ) from None
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError(
            f"empty manifest (expected a header: {','.join(REQUIRED)},recording)", str(path)
        )
    header = [h.strip() for h in rows[0]]
    for h in header:
        if h not in COLUMNS:
            raise InputError(
                f"line 1: unknown column {h!r} (known: {', '.join(COLUMNS)})", str(path)
            )
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise InputError(f"line 1: missing column(s) {', '.join(missing)}", str(path))
    if "recording" not in header and not all(c in header for c in RAW):
        raise InputError(
            "line 1: needs a 'recording' column or 'log', 'dbc' and 'signals'", str(path)
        )
    base = path.parent
    drives: list[Drive] = []
    seen: dict[str, int] = {}  # drive id -> manifest line
    for i, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InputError(f"line {i}: {len(row)} cells, the header has {len(header)}", str(path))
        cells = {h: c.strip() for h, c in zip(header, row)}
        drives.append(_drive(cells, base, f"{path}: line {i}", i))
        if drives[-1].drive_id in seen:
            raise InputError(
                f"line {i}: drive_id {drives[-1].drive_id!r} repeats line "
                f"{seen[drives[-1].drive_id]}",
                str(path),
            )
        seen[drives[-1].drive_id] = i
    if not drives:
        raise InputError("no drives (only a header)", str(path))
    return drives


def _drive(cells: dict, base: Path, where: str, line: int) -> Drive:
    for c in ("vehicle_id", "drive_id"):
        if not _ID.match(cells[c]):
            raise InputError(
                f"{where}: {c} {cells[c]!r} must be letters, digits, '.', '_' or "
                "'-' (it names a folder of the store)"
            )
    for c in REQUIRED:
        if not cells[c]:
            raise InputError(f"{where}: empty {c}")
    rec = cells.get("recording", "")
    raw = [c for c in RAW if cells.get(c, "")]
    if rec and raw:
        raise InputError(
            f"{where}: both 'recording' and {', '.join(raw)} given (one drive is "
            "a canonical recording or a raw log)"
        )
    if not rec and len(raw) != len(RAW):
        lacking = [c for c in RAW if not cells.get(c, "")]
        raise InputError(f"{where}: no 'recording', and the raw log lacks {', '.join(lacking)}")
    if rec and any(cells.get(c, "") for c in OPTIONAL_RAW):
        raise InputError(f"{where}: nav/imu go with a raw log, not with a recording")
    files = {}
    for role in FILE_ROLES:
        v = cells.get(role, "")
        if v:
            files[role] = str((base / v).resolve())
    model = cells.get("model", "") or Path(cells["geometry"]).name.split(".")[0]
    return Drive(
        cells["vehicle_id"], cells["drive_id"], _utc(cells["start_time"], where), files, model, line
    )


def file_sha256(path: str) -> str:
    """The sha256 of a file's bytes (hex); InputError naming the file when it cannot be read."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(_HASH_CHUNK_BYTES):
                h.update(chunk)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    return h.hexdigest()


def inputs_digest(drive: Drive, file_hashes: dict) -> str:
    """One sha256 over what a drive's result depends on: its row (vehicle, start time, model)
    and each input file's hash by role (a moved file with the same bytes keeps the digest)."""
    h = hashlib.sha256()
    h.update(f"{drive.vehicle_id}\n{drive.drive_id}\n{drive.start_time}\n{drive.model}\n".encode())
    for role in FILE_ROLES:
        if role in file_hashes:
            h.update(f"{role}={file_hashes[role]}\n".encode())
    return h.hexdigest()
