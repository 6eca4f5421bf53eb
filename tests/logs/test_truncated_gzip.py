"""A gzip log cut short (copied while being written, a download cut off) is read up to the cut:
the frames before it are kept, the cut is reported with where it is, and nothing is invented."""

from __future__ import annotations

import gzip
import zlib

import numpy as np
import pytest

from hmpc.models.errors import Problems
from hmpc.models.logs.canlog import KIND_TRUNCATED, read_log
from hmpc.models.logs.files import open_binary, read_bytes

from _data import bundled


@pytest.fixture(scope="module")
def comma_text() -> bytes:
    return gzip.decompress(bundled("rav4-comma2k19/can.log.gz").read_bytes())


def test_a_cut_candump_log_keeps_every_frame_before_the_cut(tmp_path, comma_text):
    whole = tmp_path / "whole.log.gz"
    whole.write_bytes(gzip.compress(comma_text))
    full = read_log(whole, Problems())
    raw = whole.read_bytes()
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(raw[: len(raw) // 2])
    problems = Problems()
    part = read_log(cut, problems)
    # what the cut stream still holds, by an independent decompressor (zlib, stream mode)
    held = zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(raw[: len(raw) // 2])
    complete_lines = held[: held.rfind(b"\n") + 1].count(b"\n")
    assert complete_lines - 5 <= len(part) <= complete_lines  # every whole line a frame
    assert 0.3 * len(full) < len(part) < 0.7 * len(full)
    np.testing.assert_array_equal(part.t_s, full.t_s[: len(part)])
    np.testing.assert_array_equal(part.data, full.data[: len(part)])
    kinds = {p.kind: p for p in problems}
    assert KIND_TRUNCATED in kinds
    assert kinds[KIND_TRUNCATED].first == [complete_lines + 1]


def test_the_helper_reads_concatenated_members_and_flags_a_cut(tmp_path):
    data = b"".join(b"line %d\n" % i for i in range(50000))
    two = tmp_path / "two.gz"
    two.write_bytes(gzip.compress(data[:1000]) + gzip.compress(data[1000:]))
    assert read_bytes(two) == data
    raw = gzip.compress(data)
    cut = tmp_path / "cut.gz"
    cut.write_bytes(raw[: len(raw) - 100])
    with open_binary(cut) as fh:
        got = fh.read()
        assert fh.truncated and fh.text_bytes == len(got)
    assert data.startswith(got) and len(got) < len(data)
    with pytest.raises(EOFError):
        read_bytes(cut)
    plain = tmp_path / "plain.txt"
    plain.write_bytes(data)
    assert read_bytes(plain) == data
