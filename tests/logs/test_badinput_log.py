"""Every log-related case of bad input (docs/conventions.md): recoverable problems are
skipped, counted and reported with their first line numbers (CLI exit 0); fatal ones raise
InputError naming the file and line/frame (CLI exit 2, one line on stderr, no traceback).
Built from real lines of the comma minute and the real DBC.
"""

import gzip
import json

import numpy as np
import pytest

from hmpc.models.logs.canlog import (
    KIND_BACKWARDS,
    KIND_DUPLICATE,
    KIND_JUMP,
    KIND_MALFORMED,
    read_log,
)
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.decode import KIND_LONG, KIND_SHORT, KIND_UNKNOWN_ID, decode_frames
from hmpc.models.errors import InputError, Problems
from hmpc.tools.cli import main

N_LINES = 400


@pytest.fixture(scope="module")
def real_lines(comma_log):
    """The first lines of the real comma log (bytes, without newline)."""
    with gzip.open(comma_log, "rb") as fh:
        return [fh.readline().rstrip(b"\n") for _ in range(N_LINES)]


def _log(tmp_path, lines, name="bad.log"):
    p = tmp_path / name
    p.write_bytes(b"\n".join(lines) + b"\n")
    return p


def _problem(problems, kind):
    found = [p for p in problems if p.kind == kind]
    assert len(found) == 1, (kind, problems.lines())
    return found[0]


def _cli(capsys, *argv):
    rc = main(["info", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line_error(err, *needles):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], (n, lines[0])


# ----------------------------------------------------------------------------- recoverable
def test_truncated_and_garbled_lines_are_skipped_and_counted(tmp_path, real_lines, capsys):
    lines = list(real_lines)
    lines[10] = lines[10][:17]  # cut inside the timestamp field
    lines[20] = lines[20][:-1]  # odd number of hex digits
    lines[30] = lines[30].replace(b"#", b"#Z", 1)  # non-hex payload
    lines[40] = lines[40].replace(b")", b"", 1)  # no closing parenthesis
    lines[50] = lines[50].replace(b" can0 ", b" can0  ")  # two spaces
    lines[60] = b"(1533226488.4x4433) can0 260#08FFFB0000001884"  # garbled time
    lines[70] = lines[70] + b" extra"
    lines[80] = b"(1533226488.434433) can0 1234#08"  # 4-digit id is extended; ok
    p = _log(tmp_path, lines)
    problems = Problems()
    ft = read_log(p, problems)
    bad = _problem(problems, KIND_MALFORMED)
    assert bad.count == 7
    assert bad.first == [11, 21, 31, 41, 51]  # 1-based line numbers
    assert len(ft) == N_LINES - 7
    assert 81 in ft.where and 11 not in ft.where
    rc, out, err = _cli(capsys, p, "--json", tmp_path / "info.json")
    assert rc == 0
    assert "7 x malformed line (skipped) (first at 11, 21, 31, 41, 51)" in err
    info = json.loads((tmp_path / "info.json").read_text())
    assert info["malformed_lines"] == 7 and info["malformed_where"] == [11, 21, 31, 41, 51]
    assert info["frames"] == N_LINES - 7


def test_truncated_last_line_without_newline(tmp_path, real_lines):
    p = tmp_path / "cut.log"
    p.write_bytes(b"\n".join(real_lines[:50]) + b"\n" + real_lines[50][:25])
    problems = Problems()
    ft = read_log(p, problems)
    assert len(ft) == 50
    assert _problem(problems, KIND_MALFORMED).first == [51]


def test_payload_shorter_and_longer_than_dbc(tmp_path, real_lines, comma_dbc, capsys):
    db = load_dbc(comma_dbc)
    lines = list(real_lines)
    # 0x2C1 GAS_PEDAL is 8 bytes in the DBC; 0x25 STEER_ANGLE_SENSOR 8 bytes
    short_at = [i for i, ln in enumerate(lines) if b" 2C1#" in ln][:3]
    long_at = [i for i, ln in enumerate(lines) if b" 025#" in ln][:2]
    for i in short_at:
        lines[i] = lines[i][:-4]  # 6 bytes: a truncated payload, still valid hex
    for i in long_at:
        lines[i] = lines[i] + b"AB"  # 9 bytes: a classic frame cannot hold that
    problems = Problems()
    read_log(_log(tmp_path, lines), problems)
    assert _problem(problems, KIND_MALFORMED).first == [i + 1 for i in long_at]
    # a longer payload arrives intact through CAN FD framing (12 bytes)
    lines2 = list(real_lines)
    for i in long_at:
        lines2[i] = lines2[i].replace(b"#", b"##0", 1) + b"ABCDEF01"
    for i in short_at:
        lines2[i] = lines2[i][:-4]
    ft2 = read_log(_log(tmp_path, lines2, "both.log"), Problems())
    problems = Problems()
    out = decode_frames(ft2, db, problems, names=["GAS_PEDAL", "STEER_ANGLE_SENSOR"])
    short = _problem(problems, KIND_SHORT)
    assert short.count == 3 and short.first == [i + 1 for i in short_at]
    long_ = _problem(problems, KIND_LONG)
    assert long_.count == 2 and long_.first == [i + 1 for i in long_at]
    n_gas = sum(b" 2C1#" in ln for ln in real_lines)
    assert len(out["GAS_PEDAL"]) == n_gas - 3
    assert not set(out["GAS_PEDAL"].where) & {i + 1 for i in short_at}
    # the longer frames decode their first 8 bytes exactly as the unmodified frames would
    ref = decode_frames(
        read_log(_log(tmp_path, list(real_lines), "ok.log"), Problems()),
        db,
        Problems(),
        names=["STEER_ANGLE_SENSOR"],
    )["STEER_ANGLE_SENSOR"]
    got = out["STEER_ANGLE_SENSOR"]
    assert np.array_equal(got.signals["STEER_ANGLE"], ref.signals["STEER_ANGLE"])
    rc, out, err = _cli(
        capsys, tmp_path / "both.log", "--dbc", comma_dbc, "--json", tmp_path / "i.json"
    )
    assert rc == 0
    info = json.loads((tmp_path / "i.json").read_text())["dbc"]
    every = Problems()
    decode_frames(ft2, db, every)  # all messages: real VSC1S29 frames are longer than the DBC's 4
    assert info["frames_shorter_than_dbc"] == _problem(every, KIND_SHORT).count == 3
    assert info["frames_longer_than_dbc"] == _problem(every, KIND_LONG).count > 2


def test_unknown_ids_are_counted_not_fatal(tmp_path, real_lines, comma_dbc, capsys):
    lines = list(real_lines) + [
        b"(1533226489.000000) can0 7AB#0102030405060708",
        b"(1533226489.000100) can0 1ABCDEF0#01",
    ]
    p = _log(tmp_path, lines)
    problems = Problems()
    ft = read_log(p, problems)
    decode_frames(ft, load_dbc(comma_dbc), problems)
    unk = _problem(problems, KIND_UNKNOWN_ID)
    known = {(m.frame_id, m.is_extended_frame) for m in load_dbc(comma_dbc).messages}
    assert unk.count == sum(
        (int(i), bool(e)) not in known for i, e in zip(ft.arb_id, ft.is_extended)
    )
    distinct = {(int(i), bool(e)) for i, e in zip(ft.arb_id, ft.is_extended)} - known
    assert unk.detail.startswith(f"{len(distinct)} distinct id(s)")
    rc, out, err = _cli(capsys, p, "--dbc", comma_dbc)
    assert rc == 0
    assert "(not in DBC)" in out and "0x7AB" in out


def test_timestamps_backwards_are_resorted_and_reported(tmp_path, real_lines, capsys):
    lines = list(real_lines)
    lines[100], lines[101] = lines[101], lines[100]
    lines[300], lines[350] = lines[350], lines[300]
    p = _log(tmp_path, lines)
    problems = Problems()
    ft = read_log(p, problems)
    back = _problem(problems, KIND_BACKWARDS)
    # line 102 (was 101) is earlier than 101; 302 earlier than the moved-up 301; 351 likewise
    assert back.count == 3 and back.first == [102, 302, 351]
    assert np.all(np.diff(ft.t_s) >= 0)
    ref = read_log(_log(tmp_path, list(real_lines), "ok.log"), Problems())
    assert np.array_equal(ft.t_s, ref.t_s) and len(ft) == len(ref)
    assert sorted(ft.where.tolist()) == list(range(1, N_LINES + 1))
    rc, out, err = _cli(capsys, p)
    assert rc == 0 and "timestamp earlier than the previous frame" in err


def test_clock_jump_is_reported_and_frames_kept(tmp_path, real_lines, capsys):
    lines = list(real_lines)
    for i in range(200, N_LINES):  # shift the second half 5 s later
        t = float(lines[i][1 : lines[i].index(b")")])
        lines[i] = b"(%.6f)" % (t + 5.0) + lines[i][lines[i].index(b")") + 1 :]
    p = _log(tmp_path, lines)
    problems = Problems()
    ft = read_log(p, problems, jump_s=1.0)
    jump = _problem(problems, KIND_JUMP)
    assert jump.count == 1 and jump.first == [201]
    assert len(ft) == N_LINES
    # a 5 s step is not a jump when jumps start at 10 s: nothing reported, every frame kept,
    # and the step itself is in the times as written
    quiet = Problems()
    ft10 = read_log(p, quiet, jump_s=10.0)
    assert not [q for q in quiet if q.kind == KIND_JUMP] and len(ft10) == N_LINES
    assert np.max(np.diff(ft10.t_s)) > 5.0
    rc, out, err = _cli(capsys, p, "--json", tmp_path / "j.json")
    assert rc == 0
    info = json.loads((tmp_path / "j.json").read_text())
    assert info["clock"]["jumps"] == 1 and info["clock"]["jumps_where"] == [201]
    assert info["clock"]["largest_step_s"] > 5.0


def test_duplicate_frames_are_dropped_and_counted(tmp_path, real_lines):
    lines = list(real_lines)
    lines.insert(51, lines[50])  # exact duplicate, adjacent
    p = _log(tmp_path, lines)
    problems = Problems()
    ft = read_log(p, problems)
    dup = _problem(problems, KIND_DUPLICATE)
    assert dup.count == 1 and dup.first == [52]
    assert len(ft) == len(lines) - 1
    # same time, same id, different payload: not a duplicate
    lines2 = list(real_lines)
    lines2.insert(
        51, lines2[50][:-2] + b"00" if not lines2[50].endswith(b"00") else lines2[50][:-2] + b"11"
    )
    assert not [q for q in _probs(tmp_path, lines2) if q.kind == KIND_DUPLICATE]


def _probs(tmp_path, lines):
    problems = Problems()
    read_log(_log(tmp_path, lines, "x.log"), problems)
    return list(problems)


def test_binary_garbage_in_a_text_log(tmp_path, real_lines, capsys):
    rng = np.random.default_rng(7)
    garbage = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes()
    lines = list(real_lines)
    data = b"\n".join(lines[:100]) + b"\n" + garbage + b"\n" + b"\n".join(lines[100:]) + b"\n"
    p = tmp_path / "garbage.log"
    p.write_bytes(data)
    problems = Problems()
    ft = read_log(p, problems)
    bad = _problem(problems, KIND_MALFORMED)
    n_garbage_lines = (
        garbage.count(b"\n") + 1 - sum(1 for x in garbage.split(b"\n") if not x.rstrip(b"\r"))
    )
    assert bad.count == n_garbage_lines and bad.first[0] == 101
    assert len(ft) == N_LINES
    rc, out, err = _cli(capsys, p)
    assert rc == 0


def test_libpanda_bad_lines(tmp_path, vcan_log):
    with gzip.open(vcan_log, "rb") as fh:
        lines = [fh.readline().rstrip(b"\n") for _ in range(60)]
    lines[5] = lines[5].rsplit(b",", 1)[0] + b",7"  # MessageLength disagrees with payload
    lines[6] = lines[6][:20]  # truncated
    lines[7] = lines[7].replace(b",0,", b",x,", 1)  # garbled bus
    lines[8] = lines[8] + b",surplus"  # wrong column count
    p = _log(tmp_path, lines, "drive.csv")
    problems = Problems()
    ft = read_log(p, problems)
    bad = _problem(problems, KIND_MALFORMED)
    assert bad.count == 4 and bad.first == [6, 7, 8, 9]
    assert len(ft) == 59 - 4


# ----------------------------------------------------------------------------- fatal
def test_empty_file_is_fatal(tmp_path, capsys):
    for name, data in (
        ("empty.log", b""),
        ("blank.csv", b"\n\n  \n"),
        ("empty.log.gz", gzip.compress(b"")),
    ):
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(InputError, match="empty file") as exc:
            read_log(p, Problems())
        assert str(p) in str(exc.value)
        rc, out, err = _cli(capsys, p)
        assert rc == 2
        _one_line_error(err, str(p), "empty file")


def test_nothing_usable_is_fatal_naming_the_first_line(tmp_path, capsys):
    p = tmp_path / "junk.log"
    p.write_bytes(b"(1.0) can0 hello\n(2.0) can0 123#XYZ\n")
    with pytest.raises(InputError) as exc:
        read_log(p, Problems())
    assert exc.value.line == 1 and exc.value.path == str(p)
    rc, out, err = _cli(capsys, p)
    assert rc == 2
    _one_line_error(err, f"{p}:1", "no usable CAN frame")


def test_whole_binary_file_with_log_suffix_is_fatal(tmp_path, capsys):
    rng = np.random.default_rng(11)
    p = tmp_path / "binary.log"
    p.write_bytes(rng.integers(0, 256, 20000, dtype=np.uint8).tobytes())
    rc, out, err = _cli(capsys, p)
    assert rc == 2
    _one_line_error(err, str(p))


def test_unknown_format_is_fatal(tmp_path, capsys):
    p = tmp_path / "frames.xyz"
    p.write_text("some,thing,else\n1,2,3\n")
    with pytest.raises(InputError, match="unknown log format"):
        read_log(p, Problems())
    rc, out, err = _cli(capsys, p)
    assert rc == 2
    _one_line_error(err, str(p), "unknown log format")
    p = tmp_path / "frames.csv"
    p.write_text("a,b,c\n1,2,3\n")
    rc, out, err = _cli(capsys, p)
    assert rc == 2
    _one_line_error(err, f"{p}:1", "unknown log format")


def test_missing_file_and_corrupt_gzip_are_fatal(tmp_path, comma_log, capsys):
    rc, out, err = _cli(capsys, tmp_path / "nope.log")
    assert rc == 2
    _one_line_error(err, "nope.log", "no such file")
    raw = bytearray(comma_log.read_bytes())
    raw[5000:5400] = bytes(400)  # the deflate data overwritten: corrupt, not cut
    bad = tmp_path / "corrupt.log.gz"
    bad.write_bytes(bytes(raw))
    rc, out, err = _cli(capsys, bad)
    assert rc == 2
    _one_line_error(err, str(bad))


def test_a_cut_gzip_log_is_read_up_to_the_cut(tmp_path, comma_log, capsys):
    """A gzip stream cut short is not refused whole: the frames before the cut are ingested
    and the cut is reported with its line (exit 0)."""
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(comma_log.read_bytes()[:200000])
    rc, out, err = _cli(capsys, cut)
    assert rc == 0
    assert "the gzip stream ends early" in err and str(cut) in err


def test_corrupt_binary_log_names_the_frame(tmp_path, comma_log, capsys):
    import itertools

    import can

    msgs = list(itertools.islice(can.LogReader(str(comma_log)), 500))
    p = tmp_path / "real.blf"
    w = can.BLFWriter(str(p))
    for m in msgs:
        w.on_message_received(m)
    w.stop()
    data = bytearray(p.read_bytes())
    data[200:260] = b"\xff" * 60  # smash the first object headers
    p.write_bytes(bytes(data))
    rc, out, err = _cli(capsys, p)
    assert rc == 2
    _one_line_error(err, str(p), "frame 1", "BLFReader")


def test_bad_dbc_is_fatal_naming_the_line(tmp_path, comma_log, capsys):
    dbc = tmp_path / "bad.dbc"
    dbc.write_text(
        'VERSION ""\n\nBO_ 705 GAS_PEDAL: 8 XXX\n'
        ' SG_ GAS : 7|8@0+ (0.5,0) [0|1] "" XXX\n'
        "this is not dbc\n"
    )
    with pytest.raises(InputError) as exc:
        load_dbc(dbc)
    assert exc.value.line == 5
    rc, out, err = _cli(capsys, comma_log, "--dbc", dbc)
    assert rc == 2
    _one_line_error(err, f"{dbc}:5")
    rc, out, err = _cli(capsys, comma_log, "--dbc", tmp_path / "missing.dbc")
    assert rc == 2
    _one_line_error(err, "missing.dbc")


def test_unknown_message_name_is_fatal(tmp_path, comma_log, comma_dbc):
    ft = read_log(comma_log, Problems())
    with pytest.raises(InputError) as exc:
        decode_frames(
            ft, load_dbc(comma_dbc), Problems(), names=["NOT_A_MESSAGE"], dbc_path=str(comma_dbc)
        )
    assert "NOT_A_MESSAGE" in str(exc.value) and str(comma_dbc) in str(exc.value)


def test_huge_newline_free_garbage_keeps_line_numbers(tmp_path, real_lines):
    from hmpc.models.logs.textblocks import MAX_LINE_BYTES

    blob = bytes(
        np.random.default_rng(3).integers(0, 256, 3 * MAX_LINE_BYTES // 2, dtype=np.uint8)
    ).replace(b"\n", b"x")
    p = tmp_path / "blob.log"
    p.write_bytes(
        b"\n".join(real_lines[:10]) + b"\n" + blob + b"\n" + b"\n".join(real_lines[10:20]) + b"\n"
    )
    problems = Problems()
    ft = read_log(p, problems, chunk_bytes=256 * 1024)
    assert len(ft) == 20
    assert list(ft.where[10:]) == list(range(12, 22))  # lines after the blob keep their numbers
    assert _problem(problems, KIND_MALFORMED).first[0] == 11
