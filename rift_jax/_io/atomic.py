"""Atomic writes: a file is either its old self or its new self, never half written, so an
interrupted save (or a long run stopped mid-write) loses nothing that was there."""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def write_atomic(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> Path:
    """``write(file)`` into a temporary file beside ``path``, then rename it into place.

    The temporary file is created with ``os.open``'s mode 0o666, so the file gets the mode
    the process's umask gives every new file (``tempfile.mkstemp`` would make it 0600,
    unreadable to the user's group and to web servers); a file written again gets it
    anew."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)  # Windows: bytes
    fd = os.open(tmp, flags, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
