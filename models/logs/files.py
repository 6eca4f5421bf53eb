"""Opening a file that may be gzip-compressed: the one place hmpc decides and decompresses.

A file is gzip when it starts with the gzip magic bytes (not by its name). :func:`open_binary`
returns a binary reader: the file itself, or a :class:`GzipReader` that decompresses it. A
gzip stream that ends early (a log copied while it was being written, a download cut short)
is read up to where it ends: ``truncated`` says so and ``text_bytes`` how far it got, so a
reader can keep the frames before the cut and report where the log ends. Corrupt compressed
data (not merely cut short) still raises ``zlib.error``.
"""

from __future__ import annotations

import io
import zlib
from pathlib import Path

GZIP_MAGIC = b"\x1f\x8b"
#: compressed bytes read from the file per step (a bounded amount of memory per call)
_RAW_CHUNK = 1 << 20


def is_gzip(path: str | Path) -> bool:
    """True when the file starts with the gzip magic bytes."""
    with open(path, "rb") as fh:
        return fh.read(2) == GZIP_MAGIC


class GzipReader(io.RawIOBase):
    """A readable binary stream of a gzip file's decompressed bytes (concatenated members
    too), tolerant of a stream that ends early.

    Attributes:
        truncated: the file ended inside a gzip member (set once the end is reached).
        text_bytes: decompressed bytes delivered so far.
    """

    def __init__(self, path: str | Path):
        super().__init__()
        self._raw = open(path, "rb")
        self._d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        self._pending = b""
        self._done = False
        self.truncated = False
        self.text_bytes = 0

    def readable(self) -> bool:
        return True

    def _fill(self) -> None:
        """Decompress until some bytes are pending or the file is used up."""
        while not self._pending and not self._done:
            if self._d.eof:
                rest = self._d.unused_data
                if not rest.strip(b"\x00"):
                    rest += self._raw.read(_RAW_CHUNK)
                    if not rest.strip(b"\x00"):
                        self._done = True  # the last member ended cleanly
                        return
                self._d = zlib.decompressobj(16 + zlib.MAX_WBITS)  # the next member
                self._pending = self._d.decompress(rest, _RAW_CHUNK)
                continue
            tail = self._d.unconsumed_tail
            raw = tail if tail else self._raw.read(_RAW_CHUNK)
            if not raw:
                self._pending = self._d.flush()
                self._done = True
                self.truncated = True  # the file ended inside a member
                return
            self._pending = self._d.decompress(raw, _RAW_CHUNK)

    def readinto(self, buffer) -> int:
        view = memoryview(buffer).cast("B")
        n = 0
        while n < len(view):
            self._fill()
            if not self._pending:
                break
            k = min(len(view) - n, len(self._pending))
            view[n : n + k] = self._pending[:k]
            self._pending = self._pending[k:]
            n += k
        self.text_bytes += n
        return n

    def close(self) -> None:
        if not self.closed:
            self._raw.close()
        super().close()


def open_binary(path: str | Path, gz: bool | None = None):
    """The file opened for reading bytes: a :class:`GzipReader` when it is gzip (``gz``
    None: decided by its magic bytes), else the plain file."""
    if gz is None:
        gz = is_gzip(path)
    return GzipReader(path) if gz else open(path, "rb")


def open_text(
    path: str | Path, *, encoding: str = "utf-8", errors: str = "strict", newline: str | None = None
):
    """The file opened for reading text, decompressed when it is gzip."""
    return io.TextIOWrapper(
        io.BufferedReader(open_binary(path)), encoding=encoding, errors=errors, newline=newline
    )


def read_bytes(path: str | Path) -> bytes:
    """The whole file's bytes, decompressed when it is gzip.

    Raises:
        EOFError: a gzip stream that ends early (a whole-file reader cannot say what is
            missing; the streaming readers use :func:`open_binary` and report the cut).
    """
    with open_binary(path) as fh:
        data = fh.read()
        if isinstance(fh, GzipReader) and fh.truncated:
            raise EOFError("compressed file ended before the end-of-stream marker was reached")
    return data
