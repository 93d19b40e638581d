"""Writing files so that no reader ever sees half of one, with the modes a plain ``open`` gives.

Generic file I/O used by ``packlab.cases`` (case suites, reference exports) and others:
``tempfile`` creates files 0600 and directories 0700, which would leave outputs only their
writer can read, so each helper applies the user's umask itself before renaming into place.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO


def file_sha256(path: str | os.PathLike[str]) -> str:
    """The sha256 hex digest of a file's bytes, read in 1 MiB blocks (models can be large)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def current_umask() -> int:
    """The process umask, read without changing it where the system allows (Linux >= 4.7);
    elsewhere set-and-restore, the only portable way."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_atomically(path: Path, write: Callable[[IO[bytes]], object]) -> Path:
    """Write ``path`` through a temp file renamed into place, so no reader ever sees half a
    file and a failure leaves the old one. ``mkstemp`` creates 0600; the file gets the mode a
    plain ``open`` would have given it (0666 less the umask) before the rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # The ".tmp" suffix marks a leftover of a killed writer for cleaners (datagen's resume).
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fchmod(fh.fileno(), 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def create_directory_atomically(out: Path, fill: Callable[[Path], None]) -> Path:
    """Create directory ``out`` by filling a hidden sibling with ``fill(tmp)`` and renaming it
    into place: a failure leaves no half directory. ``mkdtemp`` makes 0700; the directory gets
    the mode a plain ``mkdir`` would have given it (0777 less the umask)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        os.chmod(tmp, 0o777 & ~current_umask())
        fill(tmp)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


__all__ = [
    "create_directory_atomically",
    "current_umask",
    "file_sha256",
    "write_atomically",
]
