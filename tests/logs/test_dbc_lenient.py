"""A DBC that breaks cantools' parser is refused by default, naming the line and the flag; with
``--dbc-lenient`` the bad lines are skipped and reported one by one, and everything else decodes
exactly as with the clean DBC. The ingest JSON names the log format it detected,
whatever the file is called."""

from __future__ import annotations

import gzip
import json
import shutil

import numpy as np
import pytest

from _data import DATA_DIR, PARAMS_DIR
from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.recording import Recording
from hmpc.tools.cli import main

COMMA = DATA_DIR / "rav4-comma2k19"
DBC = DATA_DIR / "dbc/toyota_rav4_2017.dbc.gz"
# what opendbc's generated DBCs hold that cantools cannot parse: a comment with no signal name
BAD_LINES = [
    'CM_ SG_ 869 "a signal comment without the signal name";',
    'CM_ SG_ 1553 "another one";',
]


@pytest.fixture(scope="module")
def broken_dbc(tmp_path_factory):
    text = gzip.decompress(DBC.read_bytes()).decode("utf-8", errors="replace").split("\n")
    at = [len(text) // 3, 2 * len(text) // 3]
    for k, (i, bad) in enumerate(zip(at, BAD_LINES)):
        text.insert(i + k, bad)
    p = tmp_path_factory.mktemp("dbc") / "broken.dbc"
    p.write_text("\n".join(text))
    return p, [i + k + 1 for k, i in enumerate(at)]  # 1-based line numbers of the bad lines


def test_refused_by_default_naming_the_line_and_the_flag(broken_dbc):
    path, lines = broken_dbc
    with pytest.raises(InputError) as exc:
        load_dbc(path)
    one = exc.value.one_line()
    assert f"{path}:{lines[0]}" in one and "--dbc-lenient" in one


def test_lenient_skips_each_bad_line_and_keeps_every_message(broken_dbc):
    path, lines = broken_dbc
    problems = Problems()
    db = load_dbc(path, lenient=True, problems=problems)
    clean = load_dbc(DBC)
    assert sorted(m.name for m in db.messages) == sorted(m.name for m in clean.messages)
    skipped = [p for p in problems if "skipped" in p.kind]
    assert [p.first for p in skipped] == [[n] for n in lines]
    assert all("without the signal name" in p.detail or "another one" in p.detail for p in skipped)


def test_ingest_with_the_flag_equals_the_clean_dbc_and_names_the_format(broken_dbc, tmp_path):
    path, lines = broken_dbc
    log = tmp_path / "capture.dat.gz"  # an unusual name: the format comes from the content
    shutil.copy(COMMA / "can.log.gz", log)
    sig = str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml")
    assert (
        main(
            [
                "ingest",
                str(log),
                "--dbc",
                str(path),
                "--signals",
                sig,
                "--out",
                str(tmp_path / "x.csv"),
            ]
        )
        == 2
    )
    out = {}
    for name, dbc, extra in (("lenient", path, ["--dbc-lenient"]), ("clean", DBC, [])):
        rc = main(
            [
                "ingest",
                str(log),
                "--dbc",
                str(dbc),
                "--signals",
                sig,
                *extra,
                "--out",
                str(tmp_path / f"{name}.csv"),
                "--json",
                str(tmp_path / f"{name}.json"),
            ]
        )
        assert rc == 0
        out[name] = (
            Recording.load(tmp_path / f"{name}.csv"),
            json.loads((tmp_path / f"{name}.json").read_text()),
        )
    (rl, jl), (rc_, jc) = out["lenient"], out["clean"]
    assert jl["log_format"] == jc["log_format"] == "candump"
    for ch in ("steering_wheel_angle", "wheel_speed_fl", "speed", "accel_pedal"):
        np.testing.assert_array_equal(rl[ch], rc_[ch])
    reported = [i for i in jl["problems"]["items"] if "skipped" in i["kind"]]
    assert sorted(i["first"][0] for i in reported) == lines
