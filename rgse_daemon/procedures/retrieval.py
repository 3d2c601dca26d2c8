"""Trace retrieval: from the controller's TRACE folder into the run directory, verified and durable.

Raw data is the one thing that cannot be made again, so a trace is pulled like this (:func:`pull_trace`):

1. list the TRACE folder and take every file of the trace name (``<name>_<module>.dat/.r64/.trc``,
   ``<name>_PROG.TXT``); refuse a set without the ``.dat``/``.r64`` pair of each drive module the pipeline reads;
2. read each file over the link; its size must equal the size the listing reported (when the server reports one);
3. write it to a staging file, then :func:`~rgse_daemon.store.archive.archive_file` it into ``dest_dir`` with the
   size and SHA-256 of *what was read* as expectations: a short or corrupted local copy is an error, never archived;
4. the controller copies are **not** deleted by the pull: the caller first indexes the archived files in the store,
   then calls :meth:`PulledTrace.delete_copies` (a disk-full store must never leave a file that is neither indexed
   nor on the controller). It deletes on the controller's share where it is mounted (``controller.share_dir``),
   else over the link (:meth:`Controller.delete_file`: C3 Bridge #23). A delete that fails never fails the loop:
   the files stay on the controller, and the returned note says why (recorded with the loop as
   ``trace_left_on_controller``). ``pull_trace(..., delete=True)`` deletes at once (for callers without a store).

:func:`archived_not_indexed` lists files of a trace that were archived (a complete, published file) but that the
store does not index — what a daemon killed between the archive and the index leaves; crash recovery indexes them.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import os
import re
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rgse_daemon.controller import share_path
from rgse_daemon.errors import DataError, RgseError
from rgse_daemon.krc import KrcController
from rgse_daemon.link.errors import CommandError
from rgse_daemon.manifest import MODULE_A3, MODULE_A5
from rgse_daemon.store.archive import ArchivedFile, ArchiveError, archive_file_async, file_digest
from rgse_daemon.trace.names import plain_name

_log = logging.getLogger(__name__)

#: The controller's trace folder (docs/controller.md §5.2).
TRACE_DIR = "C:\\KRC\\ROBOTER\\TRACE\\"
#: Files the pipeline needs of every trace: the A3 and A5 drive modules, header and data.
REQUIRED_SUFFIXES = tuple(f"_{mod}{ext}" for mod in (MODULE_A3, MODULE_A5) for ext in (".dat", ".r64"))
STAGING_DIRNAME = ".incoming"


@dataclass(frozen=True)
class PulledTrace:
    """One trace, archived: the files (path, sha256, size), whether the controller copies were deleted and how
    long pulling + archiving took (s, daemon overhead). ``names`` are the controller's file names."""

    trace: str
    files: tuple[ArchivedFile, ...]
    deleted: bool
    delete_note: str
    duration_s: float
    names: tuple[str, ...] = ()
    _delete: Callable[[], Awaitable[tuple[bool, str]]] | None = field(default=None, repr=False, compare=False)

    async def delete_copies(self) -> tuple[bool, str]:
        """Delete the controller copies — call only once the store has indexed :attr:`files`. Returns (deleted,
        note); never raises for a failed delete."""
        if self._delete is None:
            return self.deleted, self.delete_note
        return await self._delete()

    @property
    def sha256s(self) -> tuple[str, ...]:
        return tuple(f.sha256 for f in self.files)


def base_name(full: str) -> str:
    return re.split(r"[\\/]", full.rstrip("\\/"))[-1]


def _listed_size(info: str) -> int | None:
    """The size in the server's info text ``<itemType>;<sizeBytes>;...`` if it has one."""
    parts = info.split(";")
    if len(parts) >= 2 and parts[1].isdigit():
        return int(parts[1])
    return None


def _write_staging(path: Path, data: bytes) -> None:
    """The copy read from the controller into the archive's staging directory; a disk that cannot take it (full,
    read-only) is an :class:`ArchiveError` naming the file, as every other archive write, and no partial copy stays."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        raise ArchiveError(f"{path}: cannot stage the controller's copy: {exc.strerror or exc}") from exc


async def pull_trace(
    krc: KrcController,
    trace: str,
    dest_dir: Path,
    *,
    trace_dir: str = TRACE_DIR,
    share_dir: Path | None = None,
    delete: bool = False,
    require_complete: bool = True,
    modules: Sequence[str] = (MODULE_A3, MODULE_A5),
) -> PulledTrace:
    """Pull, verify and archive every file of ``trace``; see the module docstring. Raises DataError if the set is
    incomplete (unless not ``require_complete``: crash recovery keeps whatever a stopped trace left) or a copy does
    not match what was read (nothing is deleted then)."""
    t0 = asyncio.get_running_loop().time()
    plain_name(trace, f"{trace_dir}: trace name")
    prefix = f"{trace}_".upper()
    listing = await krc.list_dir(trace_dir)
    entries = [e for e in listing if not e.is_dir and base_name(e.name).upper().startswith(prefix)]
    names = {plain_name(base_name(e.name), f"{trace_dir}: listed file"): e for e in entries}
    required = REQUIRED_SUFFIXES if tuple(modules) == (MODULE_A3, MODULE_A5) else tuple(
        f"_{mod}{ext}" for mod in modules for ext in (".dat", ".r64"))
    missing = [trace + s for s in required if not any(n.upper() == (trace + s).upper() for n in names)]
    if missing and require_complete:
        raise DataError(f"{trace_dir}{trace}: trace incomplete on the controller, missing {', '.join(missing)}")
    staging = dest_dir / STAGING_DIRNAME
    archived: list[ArchivedFile] = []
    for base, entry in sorted(names.items()):
        data = await krc.get_file(trace_dir + base)
        listed = _listed_size(entry.info)
        if listed is not None and listed != len(data):
            raise DataError(f"{trace_dir}{base}: read {len(data)} bytes, the controller lists {listed}")
        sha = hashlib.sha256(data).hexdigest()
        tmp = staging / base
        await asyncio.to_thread(_write_staging, tmp, data)
        try:
            archived.append(await archive_file_async(tmp, dest_dir, expected_size=len(data), expected_sha256=sha))
        finally:
            tmp.unlink(missing_ok=True)
    try:
        staging.rmdir()
    except OSError:
        pass  # not empty (another pull in flight) or already gone
    if len(archived) != len(names):
        raise DataError(f"{trace}: archived {len(archived)} of {len(names)} files")
    listed_names = sorted(names)

    async def delete_copies() -> tuple[bool, str]:
        return await _delete_controller_copies(krc, trace_dir, listed_names, share_dir)

    duration_s = asyncio.get_running_loop().time() - t0
    if delete:
        deleted, note = await delete_copies()
        return PulledTrace(trace, tuple(archived), deleted, note, duration_s, tuple(listed_names))
    return PulledTrace(trace, tuple(archived), False, "not deleted yet: index first", duration_s,
                       tuple(listed_names), delete_copies)


def archived_not_indexed(run_dir: Path, trace: str, indexed: set[Path]) -> list[ArchivedFile]:
    """Archived files of ``trace`` in ``run_dir`` (published names: a partial copy has a hidden temporary name) that
    are not in ``indexed`` (absolute paths), with their SHA-256 and size as read now."""
    prefix = f"{trace}_".upper()
    found: list[ArchivedFile] = []
    if not run_dir.is_dir():
        return found
    for path in sorted(run_dir.iterdir()):
        if path.is_file() and path.name.upper().startswith(prefix) and path.resolve() not in indexed:
            sha, size = file_digest(path)
            found.append(ArchivedFile(path, sha, size))
    return found


async def _delete_controller_copies(
    krc: KrcController, trace_dir: str, names: list[str], share_dir: Path | None
) -> tuple[bool, str]:
    """Delete the controller's copies (called only once all are archived); returns (deleted, note). Never raises
    for a failed delete: a file the controller refuses to delete is named in the note, a link failure stops."""
    if share_dir is None:
        return await _delete_over_link(krc, trace_dir, names)
    try:
        paths = [share_path(share_dir, trace_dir + n) for n in names]
        await asyncio.to_thread(lambda: [p.unlink(missing_ok=True) for p in paths])
    except (OSError, RgseError) as exc:
        _log.warning("could not delete trace files on the controller share: %r", exc)
        return False, f"delete on the share failed: {exc}"
    return True, "deleted on the controller share"


async def _delete_over_link(krc: KrcController, trace_dir: str, names: list[str]) -> tuple[bool, str]:
    refused: list[str] = []
    for i, name in enumerate(names):
        try:
            await krc.delete_file(trace_dir + name)
        except CommandError as exc:  # this file refused (read-only, in use): try the others
            refused.append(str(exc))
        except RgseError as exc:  # link down, no delete on this server: the rest would fail alike
            _log.warning("could not delete trace files over the link: %r", exc)
            left = len(names) - i + len(refused)
            return False, f"left on the controller ({left} of {len(names)} files): delete over the link failed: {exc}"
    if refused:
        _log.warning("controller refused to delete trace files: %s", "; ".join(refused))
        return False, f"left on the controller ({len(refused)} of {len(names)} files): {'; '.join(refused)}"
    return True, "deleted over the link"
