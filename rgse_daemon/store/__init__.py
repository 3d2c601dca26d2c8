"""Persistence: runs, loops, raw-file index, calibrations, results, events and the MQTT outbox.

SQLite under the data directory by default, PostgreSQL by URL for a shared (fleet) store; one interface either
way. The daemon uses :class:`Store` (async, every call with a deadline); scripts and tests may use
:class:`Repository` (the same operations, blocking). Raw trace files are copied by :mod:`.archive`.

    store = await Store.open(url, data_dir)       # url None: <data_dir>/rgse.sqlite3; or "postgresql://..."
    await store.recover_interrupted(robot)        # at start: runs a dead daemon left 'running'
    run = await store.create_run("measurement", robot, {...})
    await store.set_run_state(run.id, "running")
    f = await archive_file_async(src, archive_root(data_dir) / run.directory, expected_size=n)
    await store.add_trace_file(run.id, relative_path(f.path, archive_root(data_dir)), f.sha256, f.size)
    await store.record_result(run.id, result, [f.sha256], publish=OutboxMessage(f"rgse/{robot}/run/{run.id}/result"))
"""

from rgse_daemon.store.archive import (
    ArchivedFile,
    archive_file,
    archive_file_async,
    archive_root,
    discard_partial_copies,
    file_digest,
    relative_path,
    verify_file,
)
from rgse_daemon.store.backend import describe_store, sqlite_path
from rgse_daemon.store.errors import (
    ArchiveConflict,
    ArchiveError,
    NotFound,
    StoreConflict,
    StoreError,
    StoreTimeout,
)
from rgse_daemon.store.records import (
    CalibrationRecord,
    EventLevel,
    EventRecord,
    LoopRecord,
    LoopState,
    OutboxMessage,
    OutboxRecord,
    PointRecord,
    PointState,
    ResultRecord,
    RunKind,
    RunRecord,
    RunState,
    TraceFileRecord,
)
from rgse_daemon.store.repository import Repository
from rgse_daemon.store.store import Store

__all__ = [
    "ArchiveConflict",
    "ArchiveError",
    "ArchivedFile",
    "CalibrationRecord",
    "EventLevel",
    "EventRecord",
    "LoopRecord",
    "LoopState",
    "NotFound",
    "OutboxMessage",
    "OutboxRecord",
    "PointRecord",
    "PointState",
    "Repository",
    "ResultRecord",
    "RunKind",
    "RunRecord",
    "RunState",
    "Store",
    "StoreConflict",
    "StoreError",
    "StoreTimeout",
    "TraceFileRecord",
    "archive_file",
    "archive_file_async",
    "archive_root",
    "describe_store",
    "discard_partial_copies",
    "file_digest",
    "relative_path",
    "sqlite_path",
    "verify_file",
]
