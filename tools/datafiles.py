"""Where the bundled real data lives: tools/data/ (gzip copies of ../shared/data)."""

from __future__ import annotations

from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent / "data"
REPO_DIR = Path(__file__).resolve().parent.parent
PARAMS_DIR = REPO_DIR / "params"


def bundled(relpath: str) -> Path:
    """Path of a bundled file, e.g. ``bundled('rav4-comma2k19/can.log.gz')``."""
    return DATA_DIR / relpath
