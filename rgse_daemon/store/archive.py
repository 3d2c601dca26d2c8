"""The raw-file archive: trace files copied from the controller into a run's directory, durably and verified.

Raw data is the one thing that cannot be re-made, so a file is archived like this: copy into a temporary file in
the same directory while hashing, ``fsync`` it, compare size and SHA-256 with what the caller expects and read the
copy back, then publish it under its name with ``link`` (which, unlike ``rename``, never replaces an existing file)
and ``fsync`` the directory. Only after :func:`archive_file` returns may the daemon delete the controller's copy.
An existing file of the same name is never overwritten: the identical file is success (idempotent retry), a
different one is an :class:`ArchiveConflict`.

Paths recorded in the store are relative to the archive root, ``<data_dir>/archive``.
"""

from __future__ import annotations

import asyncio
import errno
import hashlib
import os
import stat
import tempfile
from pathlib import Path
from typing import NamedTuple

from rgse_daemon.aio import within
from rgse_daemon.durable import fsync_dir
from rgse_daemon.store.errors import ArchiveConflict, ArchiveError

ARCHIVE_DIRNAME = "archive"
_TMP_PREFIX = ".rgse-part-"
_CHUNK = 1 << 20
# Errors of file systems without hard links (some SMB/FAT mounts): fall back to check-then-rename.
_NO_LINK = {errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.ENOSYS}


class ArchivedFile(NamedTuple):
    path: Path
    sha256: str
    size: int


def archive_root(data_dir: Path) -> Path:
    """Where run directories live: ``<data_dir>/archive``."""
    return Path(data_dir) / ARCHIVE_DIRNAME


def relative_path(path: Path, root: Path) -> str:
    """``path`` relative to the archive ``root`` as a POSIX string, the form the store records."""
    try:
        return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError as exc:
        raise ArchiveError(f"{path}: not inside the archive {root}") from exc


def file_digest(path: Path) -> tuple[str, int]:
    """SHA-256 (hex) and size in bytes of a file's current content."""
    h = hashlib.sha256()
    size = 0
    try:
        with open(path, "rb") as f:
            while chunk := f.read(_CHUNK):
                h.update(chunk)
                size += len(chunk)
    except OSError as exc:
        raise ArchiveError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    return h.hexdigest(), size


def verify_file(path: Path, sha256: str, size: int) -> None:
    """Check an archived file against its recorded hash and size; :class:`ArchiveError` names the difference."""
    actual_sha, actual_size = file_digest(path)
    if actual_size != size:
        raise ArchiveError(f"{path}: {actual_size} bytes on disk, {size} recorded")
    if actual_sha != sha256:
        raise ArchiveError(f"{path}: sha256 {actual_sha} on disk, {sha256} recorded (file corrupted)")


def archive_file(
    src: Path | str,
    run_dir: Path | str,
    expected_size: int | None = None,
    expected_sha256: str | None = None,
) -> ArchivedFile:
    """Copy ``src`` into ``run_dir`` under its own name, durably; returns (path, sha256, size).

    ``expected_size``/``expected_sha256`` (e.g. from the controller's directory listing or a manifest) turn a short
    or corrupted copy into an :class:`ArchiveError` instead of an archived file. Nothing is left behind on failure,
    and ``src`` is never modified.
    """
    src = Path(src)
    run_dir = Path(run_dir)
    if expected_size is not None and (not isinstance(expected_size, int) or expected_size < 0):
        raise ArchiveError(f"{src}: expected_size {expected_size!r} must be an integer >= 0")
    if expected_sha256 is not None:
        if not isinstance(expected_sha256, str) or len(expected_sha256) != 64:
            raise ArchiveError(f"{src}: expected_sha256 {expected_sha256!r} is not a hex SHA-256")
        expected_sha256 = expected_sha256.lower()
    if not src.name or src.name.startswith(_TMP_PREFIX):
        raise ArchiveError(f"{src}: not an archivable file name")
    try:
        before = src.stat()
    except OSError as exc:
        raise ArchiveError(f"{src}: cannot read: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(before.st_mode):
        raise ArchiveError(f"{src}: not a regular file")

    _make_dirs(run_dir)
    dest = run_dir / src.name
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=_TMP_PREFIX, dir=run_dir)
    except OSError as exc:
        raise ArchiveError(f"{run_dir}: cannot create a file: {exc.strerror or exc}") from exc
    tmp = Path(tmp_name)
    try:
        sha, size = _copy_and_sync(src, fd, tmp)
        _check_copy(src, before, sha, size, expected_size, expected_sha256)
        back_sha, back_size = file_digest(tmp)
        if (back_sha, back_size) != (sha, size):
            raise ArchiveError(
                f"{dest}: the copy reads back as {back_size} bytes sha256 {back_sha}, not {size} bytes {sha}"
                " (corrupted copy); not archived"
            )
        if not _publish(tmp, dest):
            return _existing(dest, sha, size)
        tmp.unlink()
        _fsync_dir(run_dir)
        return ArchivedFile(dest, sha, size)
    finally:
        tmp.unlink(missing_ok=True)


async def archive_file_async(
    src: Path | str,
    run_dir: Path | str,
    expected_size: int | None = None,
    expected_sha256: str | None = None,
    *,
    timeout_s: float = 120.0,
) -> ArchivedFile:
    """:func:`archive_file` off the event loop (it copies and fsyncs), with a deadline.

    On timeout the copy may still finish in its thread; the source must be kept, and a retry is safe (the
    identical file already archived is success).
    """
    try:
        return await within(
            asyncio.to_thread(archive_file, src, run_dir, expected_size, expected_sha256), timeout_s
        )
    except TimeoutError as exc:
        raise ArchiveError(f"{src}: archiving did not finish within {timeout_s:g} s; keep the source, retry") from exc


def discard_partial_copies(run_dir: Path) -> list[Path]:
    """Remove temporary copies left in ``run_dir`` by an interrupted :func:`archive_file`; returns them.

    These are never raw data: the controller's copy is deleted only after a successful archive.
    """
    removed = []
    for p in sorted(Path(run_dir).glob(f"{_TMP_PREFIX}*")):
        p.unlink(missing_ok=True)
        removed.append(p)
    if removed:
        _fsync_dir(Path(run_dir))
    return removed


def _copy_and_sync(src: Path, fd: int, tmp: Path) -> tuple[str, int]:
    h = hashlib.sha256()
    size = 0
    try:
        with open(fd, "wb") as out, open(src, "rb") as inp:
            while chunk := inp.read(_CHUNK):
                out.write(chunk)
                h.update(chunk)
                size += len(chunk)
            out.flush()
            os.fsync(out.fileno())
    except OSError as exc:
        raise ArchiveError(f"{src}: copy to {tmp.parent} failed: {exc.strerror or exc}; not archived") from exc
    return h.hexdigest(), size


def _check_copy(
    src: Path, before: os.stat_result, sha: str, size: int, expected_size: int | None, expected_sha256: str | None
) -> None:
    try:
        after = src.stat()
    except OSError as exc:
        raise ArchiveError(f"{src}: vanished while being copied: {exc.strerror or exc}; not archived") from exc
    if size != before.st_size or (after.st_size, after.st_mtime_ns) != (before.st_size, before.st_mtime_ns):
        raise ArchiveError(
            f"{src}: changed while being copied ({before.st_size} bytes before, {size} copied, {after.st_size} after);"
            " not archived"
        )
    if expected_size is not None and size != expected_size:
        raise ArchiveError(f"{src}: {size} bytes, expected {expected_size} (short or truncated copy); not archived")
    if expected_sha256 is not None and sha != expected_sha256:
        raise ArchiveError(f"{src}: sha256 {sha}, expected {expected_sha256} (corrupted copy); not archived")


def _publish(tmp: Path, dest: Path) -> bool:
    """Give the verified temporary file its final name; False if that name is already taken."""
    try:
        os.link(tmp, dest)
        return True
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINK:
            raise ArchiveError(f"{dest}: cannot create: {exc.strerror or exc}; not archived") from exc
    # No hard links here: check, then rename (a concurrent writer of the same name could still race us).
    if dest.exists():
        return False
    try:
        os.rename(tmp, dest)
    except OSError as exc:
        raise ArchiveError(f"{dest}: cannot create: {exc.strerror or exc}; not archived") from exc
    return True


def _existing(dest: Path, sha: str, size: int) -> ArchivedFile:
    have_sha, have_size = file_digest(dest)
    if (have_sha, have_size) == (sha, size):
        return ArchivedFile(dest, sha, size)
    raise ArchiveConflict(
        f"{dest}: already archived with different content ({have_size} bytes sha256 {have_sha}; new file {size} bytes"
        f" sha256 {sha}); nothing overwritten"
    )


def _make_dirs(path: Path) -> None:
    """``mkdir -p`` that also fsyncs the parent of every directory it created, so the path survives power loss."""
    missing = []
    p = path
    while not p.exists():
        missing.append(p)
        p = p.parent
    try:
        path.mkdir(parents=True, exist_ok=True)
        for d in reversed(missing):
            _fsync_dir(d.parent)
    except OSError as exc:
        raise ArchiveError(f"{path}: cannot create the directory: {exc.strerror or exc}") from exc
    if not path.is_dir():
        raise ArchiveError(f"{path}: not a directory")


def _fsync_dir(path: Path) -> None:
    try:
        fsync_dir(path)
    except OSError as exc:
        raise ArchiveError(f"{path}: cannot sync the directory: {exc.strerror or exc}") from exc
