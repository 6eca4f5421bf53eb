"""The recording's CSV writer (columns to text in bulk) writes the very bytes ``csv.writer`` row
by row does, with the cell rules of the canonical CSV: ``time`` as ``%.6f``, numbers as
``repr(float)``, NaN empty, strings as they are (quoted where csv quotes them)."""

import csv
import gzip
import math
import os

import numpy as np
import pytest

from hmpc.models.logs.channels import CHANNELS, STRING_CHANNELS
from hmpc.models.logs import recording
from hmpc.models.logs.recording import write_csv


def _reference(channels: dict, path) -> None:
    """The row-by-row writer: one csv.writer row per sample."""
    names = [c for c in CHANNELS if c in channels] + [c for c in channels if c not in CHANNELS]
    cols = []
    for n in names:
        v = channels[n]
        if n in STRING_CHANNELS:
            cols.append([str(s) for s in v])
        elif n == "time":
            cols.append([f"{x:.6f}" for x in v])
        else:
            cols.append([("" if math.isnan(x) else repr(float(x))) for x in v.astype(float)])
    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "wt", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        w.writerows(zip(*cols))


def _channels(n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    specials = np.array(
        [
            np.nan,
            0.0,
            -0.0,
            np.inf,
            -np.inf,
            1e16,
            1e-5,
            5e-324,
            1e22,
            0.1,
            123456789012345678.0,
            -1.5,
            2.0**60,
        ]
    )
    wild = rng.normal(size=n) * 10.0 ** rng.integers(-8, 20, n)
    pick = rng.random(n) < 0.2
    wild[pick] = rng.choice(specials, size=int(pick.sum()))
    held = np.repeat(rng.choice(specials, size=n // 7 + 1), 7)[:n]  # runs of one value
    flip = np.where(np.arange(n) % 3 == 0, 0.0, -0.0)  # 0.0 and -0.0 alternate
    return {
        "time": 1533226488.439005 + np.arange(n) / 50.0,
        "speed": wild,
        "accel_pedal": held,
        "brake_pedal": flip,
        "gear": np.array(["D", "", "P", 'q"uote', "a,b", "R"], dtype=object)[rng.integers(0, 6, n)],
        "extra_column": rng.normal(size=n),
    }


@pytest.mark.parametrize("n", [0, 1, 2, 7, 1000, 40_000])
def test_write_csv_bytes_equal_the_row_by_row_writer(tmp_path, n):
    ch = _channels(n, seed=n)
    write_csv(ch, tmp_path / "bulk.csv")
    _reference(ch, tmp_path / "rows.csv")
    assert (tmp_path / "bulk.csv").read_bytes() == (tmp_path / "rows.csv").read_bytes()


def test_write_csv_gzip_and_a_single_column(tmp_path):
    ch = _channels(500, seed=3)
    write_csv(ch, tmp_path / "bulk.csv.gz")
    _reference(ch, tmp_path / "rows.csv.gz")
    assert gzip.decompress((tmp_path / "bulk.csv.gz").read_bytes()) == gzip.decompress(
        (tmp_path / "rows.csv.gz").read_bytes()
    )
    for only in ({"time": ch["time"]}, {"gear": np.array(["", "D", ""], dtype=object)}):
        write_csv(only, tmp_path / "one.csv")
        _reference(only, tmp_path / "one_rows.csv")
        assert (tmp_path / "one.csv").read_bytes() == (tmp_path / "one_rows.csv").read_bytes()


@pytest.mark.parametrize("n", [2, 7, 1000, 40_000])
def test_write_csv_split_across_a_child_process_writes_the_same_bytes(tmp_path, n):
    """The second half of the rows turned to text by a forked child: the same file."""
    if not recording._CAN_FORK:
        pytest.skip("write_csv splits the rows across processes on Linux only")
    ch = _channels(n, seed=n + 1)
    write_csv(ch, tmp_path / "split.csv", split_rows=2)
    _reference(ch, tmp_path / "rows.csv")
    assert (tmp_path / "split.csv").read_bytes() == (tmp_path / "rows.csv").read_bytes()
    write_csv(ch, tmp_path / "split.csv.gz", split_rows=2)
    assert (
        gzip.decompress((tmp_path / "split.csv.gz").read_bytes())
        == (tmp_path / "rows.csv").read_bytes()
    )


def test_write_csv_child_failure_falls_back_to_this_process(tmp_path, monkeypatch):
    """A child that fails (here: an error raised only in the child) leaves no trace: the
    parent makes those rows itself and the file is still right."""
    if not recording._CAN_FORK:
        pytest.skip("write_csv splits the rows across processes on Linux only")
    parent = os.getpid()
    real = recording._csv_cells

    def cells_failing_in_child(name, v):
        if os.getpid() != parent:
            raise MemoryError("planted failure in the child")
        return real(name, v)

    monkeypatch.setattr(recording, "_csv_cells", cells_failing_in_child)
    ch = _channels(3000, seed=5)
    write_csv(ch, tmp_path / "split.csv", split_rows=2)
    _reference(ch, tmp_path / "rows.csv")
    assert (tmp_path / "split.csv").read_bytes() == (tmp_path / "rows.csv").read_bytes()
