"""Typed errors of the store and the raw-file archive.

Callers react by kind: a :class:`StoreTimeout` means "outcome unknown, the operation may still complete" (every
write is idempotent or keyed, so retrying is safe); a :class:`StoreConflict` means the request contradicts what is
already recorded and retrying will not help; an :class:`ArchiveError` means a raw file was not archived and the
controller's copy must be kept.
"""

from __future__ import annotations

from rgse_daemon.errors import RgseError


class StoreError(RgseError):
    """The store could not do what was asked: unreachable database, bad argument, unknown record."""


class StoreTimeout(StoreError):
    """A store operation did not finish within its deadline; its outcome is unknown."""


class StoreConnectionLost(StoreError):
    """The database connection broke under an operation (server restart, backend terminated); the operation did
    not commit, or its outcome is unknown. The next operation reconnects; the async store retries once."""


class StoreConflict(StoreError):
    """The request contradicts recorded data (another document under the same id, an illegal state change)."""


class NotFound(StoreError):
    """A run, calibration or other record named by the caller does not exist."""


class ArchiveError(StoreError):
    """A raw file could not be archived durably or failed verification; the source must be kept."""


class ArchiveConflict(ArchiveError):
    """A different file with the same name is already archived; nothing was overwritten."""
