"""Durable file writes: a file appears whole or not at all, and survives a power loss once the call returns.

The data goes to a temporary file in the same directory, is flushed and fsynced, then renamed over the target
(atomic on POSIX within one file system), and the directory is fsynced so the rename itself is on disk. The one
helper for every file the project writes that must never be seen half written: CAL.json, manifests, reports, the
simulated controller's trace files.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def fsync_dir(directory: Path) -> None:
    """fsync a directory, so that entries created or renamed in it are on disk."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, data: bytes | str, *, mode: int | None = None) -> None:
    """Write ``data`` (str as UTF-8) to ``path`` atomically and durably.

    ``mode`` defaults to what a plain ``open`` would give (0o666 less the umask); ``mkstemp`` alone would make 0o600.
    The parent directory is created if missing. On any error the temporary file is removed and the target is as
    it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    if mode is None:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)
