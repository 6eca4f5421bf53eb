"""Pre-shared keys of the tele-operation link: one line of hex in a file only its owner may
read (:func:`load_key` refuses anything else), and :func:`create_key` to make one."""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from hmpc.models.errors import InputError

#: a key shorter than the hash output weakens HMAC-SHA256 (RFC 2104 section 3)
MIN_KEY_BYTES = 32


class KeyFileError(InputError):
    """A key file is missing, readable by others, too short or not hex."""


def load_key(path: str | Path) -> bytes:
    """Read a pre-shared key: one line of hex, at least ``MIN_KEY_BYTES`` bytes.

    Raises:
        KeyFileError: the file is missing, not a regular file, readable or writable by group
            or others (``chmod 600`` it), not one line of hex, or shorter than 32 bytes.
    """
    p = str(path)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise KeyFileError(f"cannot read key file: {exc.strerror}", p) from None
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError("key file is not a regular file", p)
    if st.st_mode & 0o077:
        raise KeyFileError(
            f"key file is accessible by group or others (mode "
            f"{stat.S_IMODE(st.st_mode):04o}); run chmod 600 on it",
            p,
        )
    with open(p, "rb") as fh:
        raw = fh.read(4096)
    text = raw.decode("ascii", errors="replace")
    lines = text.splitlines()
    if len(lines) != 1:
        raise KeyFileError("key file must hold exactly one line of hex", p, line=1)
    try:
        key = bytes.fromhex(lines[0].strip())
    except ValueError:
        raise KeyFileError("key is not hex", p, line=1) from None
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(f"key has {len(key)} bytes, needs at least {MIN_KEY_BYTES}", p, line=1)
    return key


def create_key(path: str | Path, n_bytes: int = MIN_KEY_BYTES) -> Path:
    """Write a new random key (``secrets``) as hex to a new file with mode 0600.

    Refuses to overwrite an existing file (``FileExistsError``).
    """
    if n_bytes < MIN_KEY_BYTES:
        raise ValueError(f"n_bytes must be >= {MIN_KEY_BYTES}")
    p = Path(path)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(secrets.token_hex(n_bytes) + "\n")
    os.chmod(p, 0o600)  # the umask can only remove bits, but say it explicitly
    return p
