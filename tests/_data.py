"""Where the tests find their data: the repository's own folders, located from this file.

The tests do not ask ``hmpc.tools`` where the data is (nothing imports tools/): a test that
used the package's own lookup could not notice when that lookup breaks.
"""

from __future__ import annotations

from pathlib import Path

REPO_DIR = Path(__file__).resolve().parent.parent
#: gzip copies of ../shared/data, with their licences
DATA_DIR = REPO_DIR / "tools" / "data"
#: vehicle geometry, identified parameters and signal maps
PARAMS_DIR = REPO_DIR / "params"
#: the report's parameters (zone values are placeholders; see the file's header)
REPORT_PARAMS = PARAMS_DIR / "report_2008.yaml"


def bundled(relpath: str) -> Path:
    """Path of a bundled file, e.g. ``bundled('rav4-comma2k19/can.log.gz')``."""
    path = DATA_DIR / relpath
    if not path.is_file():
        raise FileNotFoundError(f"bundled data file missing: {path}")
    return path
