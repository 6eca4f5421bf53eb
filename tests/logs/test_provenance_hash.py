"""Provenance hashes of a file and of a folder input (a bag folder, a CSV topic export)."""

import hashlib

from hmpc.models.logs.ingest import sha256_file


def test_a_file_hashes_as_its_bytes(tmp_path):
    f = tmp_path / "a.csv"
    f.write_bytes(b"time,speed\n0,1\n")
    assert sha256_file(f) == hashlib.sha256(b"time,speed\n0,1\n").hexdigest()


def test_a_folder_hashes_its_files_paths_and_contents(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "b.csv").write_bytes(b"b")
    (tmp_path / "sub" / "a.csv").write_bytes(b"a")
    want = hashlib.sha256(
        f"b.csv {hashlib.sha256(b'b').hexdigest()}\n"
        f"sub/a.csv {hashlib.sha256(b'a').hexdigest()}\n".encode()
    ).hexdigest()
    first = sha256_file(tmp_path)
    assert first == want
    (tmp_path / "sub" / "a.csv").rename(tmp_path / "sub" / "c.csv")  # a rename changes it
    assert sha256_file(tmp_path) != first
