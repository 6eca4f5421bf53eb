"""The fleet store (docs/conventions.md, "Fleet"): one folder per drive, each written whole.

Layout::

    STORE/drives/<drive_id>/recording.parquet   canonical recording (step ingest)
    STORE/drives/<drive_id>/params.yaml         parameter file (identify; + diagnose's extensions)
    STORE/drives/<drive_id>/diagnosis.json      the `hmpc diagnose --json` payload (diagnose)
    STORE/drives/<drive_id>/report/index.html   the drive's diagnosis report (diagnose)
    STORE/drives/<drive_id>/values.parquet      the drive's rows of the per-drive table
    STORE/drives/<drive_id>/status.json         inputs' sha256, hmpc version, exit, error, timings
    STORE/.tmp/                                 drives being written (removed at the next run)

A drive's folder is written under ``STORE/.tmp`` and renamed into place when complete, so a
folder under ``drives/`` is always whole: an interrupted run leaves only finished drives.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from pathlib import Path

DRIVES = "drives"
TMP = ".tmp"
STATUS = "status.json"
RECORDING = "recording.parquet"
PARAMS = "params.yaml"
DIAGNOSIS = "diagnosis.json"
REPORT = "report"
VALUES = "values.parquet"
#: the steps a run may take, in order
STEPS = ("ingest", "identify", "diagnose")


def drive_dir(store, drive_id: str) -> Path:
    return Path(store) / DRIVES / drive_id


def new_tmp_dir(store, drive_id: str) -> Path:
    """A fresh folder under ``STORE/.tmp`` to write a drive's results into."""
    d = Path(store) / TMP / f"{drive_id}.{uuid.uuid4().hex}"
    d.mkdir(parents=True)
    return d


def commit(tmp: Path, store, drive_id: str) -> Path:
    """Move the finished folder ``tmp`` to the drive's place, replacing an older result: the
    old folder is renamed aside first and removed after, so the place holds the old result or
    the new one, whole, at every instant but the one between two renames."""
    final = drive_dir(store, drive_id)
    final.parent.mkdir(parents=True, exist_ok=True)
    aside = None
    if final.exists():
        aside = Path(store) / TMP / f"{drive_id}.old.{uuid.uuid4().hex}"
        os.replace(final, aside)
    os.replace(tmp, final)
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)
    return final


def clear_tmp(store) -> None:
    """Remove what an interrupted run left under ``STORE/.tmp``."""
    shutil.rmtree(Path(store) / TMP, ignore_errors=True)


def read_status(store, drive_id: str) -> dict | None:
    """A drive's status.json, or None when absent or unreadable (then the drive is redone)."""
    try:
        return json.loads((drive_dir(store, drive_id) / STATUS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def write_json_file(path: Path, payload: dict) -> None:
    path.write_text(json.dumps(payload, indent=2, default=_plain) + "\n", encoding="utf-8")


def _plain(obj):
    if hasattr(obj, "item"):
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)


def finished(status: dict | None, inputs_sha256: str, version: str, steps) -> bool:
    """True when ``status`` is a finished result (exit 0) of the same inputs, the same hmpc
    version and at least the steps asked for."""
    return (
        status is not None
        and status.get("exit") == 0
        and status.get("inputs_sha256") == inputs_sha256
        and status.get("hmpc_version") == version
        and set(steps) <= set(status.get("steps", ()))
    )
