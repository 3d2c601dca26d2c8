"""Numbered schema migrations, applied in order when a store is opened.

Each migration runs in its own transaction together with the row that records it in ``schema_version``, so a
migration is either fully applied and recorded or not at all; re-opening applies only what is missing. A database
written by a newer daemon (a version this code does not know) is refused rather than guessed at.

``{id_pk}`` in a statement is replaced by the dialect's auto-increment primary key; all else is portable SQL, except
where a migration gives SQLite its own statements (SQLite cannot change a constraint in place: it rebuilds the
table). Migrations are append-only: never edit a released one, add the next number.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from rgse_daemon.store.backend import Backend
from rgse_daemon.store.dialect import SQLITE
from rgse_daemon.store.errors import StoreError


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    statements: tuple[str, ...]
    """Portable SQL; PostgreSQL's alone where :attr:`sqlite` is given."""
    sqlite: tuple[str, ...] | None = None
    """SQLite's own statements, a table rebuild. They run with foreign keys off (else dropping the old table would
    empty its children) and the transaction commits only if ``PRAGMA foreign_key_check`` then finds nothing: the
    procedure of SQLite's ALTER TABLE documentation (§7)."""


_V1 = (
    """CREATE TABLE robots (
        name TEXT PRIMARY KEY,
        created_utc TEXT NOT NULL
    )""",
    """CREATE TABLE runs (
        id TEXT PRIMARY KEY,
        kind TEXT NOT NULL CHECK (kind IN ('measurement', 'calibration')),
        robot TEXT NOT NULL REFERENCES robots(name),
        state TEXT NOT NULL
            CHECK (state IN ('queued', 'running', 'completed', 'failed', 'interrupted', 'aborted')),
        created_utc TEXT NOT NULL,
        started_utc TEXT,
        ended_utc TEXT,
        config TEXT NOT NULL,
        directory TEXT NOT NULL UNIQUE,
        detail TEXT
    )""",
    "CREATE INDEX runs_robot_state ON runs(robot, state)",
    """CREATE TABLE campaign_points (
        run_id TEXT NOT NULL REFERENCES runs(id),
        idx INTEGER NOT NULL CHECK (idx >= 0),
        spec TEXT NOT NULL,
        state TEXT NOT NULL CHECK (state IN ('pending', 'measuring', 'done', 'failed')),
        updated_utc TEXT NOT NULL,
        PRIMARY KEY (run_id, idx)
    )""",
    """CREATE TABLE loops (
        run_id TEXT NOT NULL REFERENCES runs(id),
        idx INTEGER NOT NULL CHECK (idx >= 0),
        point_idx INTEGER,
        trace_name TEXT NOT NULL,
        state TEXT NOT NULL
            CHECK (state IN ('pending', 'recording', 'recorded', 'archived', 'failed', 'interrupted')),
        robot_start_utc TEXT,
        robot_end_utc TEXT,
        record_start_utc TEXT,
        record_end_utc TEXT,
        updated_utc TEXT NOT NULL,
        PRIMARY KEY (run_id, idx),
        UNIQUE (run_id, trace_name),
        FOREIGN KEY (run_id, point_idx) REFERENCES campaign_points(run_id, idx)
    )""",
    """CREATE TABLE trace_files (
        id {id_pk},
        run_id TEXT NOT NULL REFERENCES runs(id),
        loop_idx INTEGER,
        path TEXT NOT NULL UNIQUE,
        sha256 TEXT NOT NULL CHECK (length(sha256) = 64),
        size_bytes BIGINT NOT NULL CHECK (size_bytes >= 0),
        archived_utc TEXT NOT NULL,
        FOREIGN KEY (run_id, loop_idx) REFERENCES loops(run_id, idx)
    )""",
    "CREATE INDEX trace_files_run ON trace_files(run_id)",
    """CREATE TABLE calibrations (
        id TEXT PRIMARY KEY,
        robot TEXT NOT NULL REFERENCES robots(name),
        created_utc TEXT NOT NULL,
        method TEXT NOT NULL,
        document TEXT NOT NULL,
        active INTEGER NOT NULL DEFAULT 0 CHECK (active IN (0, 1)),
        added_utc TEXT NOT NULL,
        activated_utc TEXT,
        run_id TEXT REFERENCES runs(id)
    )""",
    # The database itself guarantees "at most one active calibration per robot".
    "CREATE UNIQUE INDEX calibrations_one_active ON calibrations(robot) WHERE active = 1",
    """CREATE TABLE results (
        id TEXT PRIMARY KEY,
        run_id TEXT NOT NULL REFERENCES runs(id),
        calibration_id TEXT,
        result TEXT NOT NULL,
        created_utc TEXT NOT NULL
    )""",
    "CREATE INDEX results_run ON results(run_id)",
    """CREATE TABLE result_inputs (
        result_id TEXT NOT NULL REFERENCES results(id),
        trace_file_id BIGINT NOT NULL REFERENCES trace_files(id),
        PRIMARY KEY (result_id, trace_file_id)
    )""",
    """CREATE TABLE events (
        id {id_pk},
        time_utc TEXT NOT NULL,
        level TEXT NOT NULL CHECK (level IN ('debug', 'info', 'warning', 'error', 'critical')),
        kind TEXT NOT NULL,
        message TEXT NOT NULL,
        run_id TEXT REFERENCES runs(id),
        data TEXT
    )""",
    "CREATE INDEX events_run ON events(run_id)",
    """CREATE TABLE outbox (
        id {id_pk},
        topic TEXT NOT NULL,
        payload TEXT NOT NULL,
        retained INTEGER NOT NULL CHECK (retained IN (0, 1)),
        qos INTEGER NOT NULL CHECK (qos IN (0, 1, 2)),
        created_utc TEXT NOT NULL,
        published_utc TEXT,
        attempts INTEGER NOT NULL DEFAULT 0,
        last_error TEXT
    )""",
    "CREATE INDEX outbox_pending ON outbox(published_utc, id)",
)

# A result's status (rgse_daemon.verdict): ok, warning or refused, so that a query finds the results with warnings
# without parsing every document. Results stored before have NULL here; the repository derives theirs from the
# document when it reads them.
_V2 = (
    "ALTER TABLE results ADD COLUMN status TEXT CHECK (status IS NULL OR status IN ('ok', 'warning', 'refused'))",
    "CREATE INDEX results_status ON results(status)",
)

# A properties run is a kind of its own (rgse_daemon.runkind). Before, it was stored as 'measurement' with
# 'properties' in its configuration: those rows become 'properties' here.
_V3_KINDS = "('measurement', 'calibration', 'properties')"
_V3_POSTGRESQL = (
    "ALTER TABLE runs DROP CONSTRAINT runs_kind_check",
    f"ALTER TABLE runs ADD CONSTRAINT runs_kind_check CHECK (kind IN {_V3_KINDS})",
    "UPDATE runs SET kind = 'properties' WHERE kind = 'measurement' AND (config::jsonb -> 'properties') IS NOT NULL",
)
_V3_RUNS_COLUMNS = "id, kind, robot, state, created_utc, started_utc, ended_utc, config, directory, detail"
_V3_SQLITE = (
    f"""CREATE TABLE runs_v3 (
        id TEXT PRIMARY KEY,
        kind TEXT NOT NULL CHECK (kind IN {_V3_KINDS}),
        robot TEXT NOT NULL REFERENCES robots(name),
        state TEXT NOT NULL
            CHECK (state IN ('queued', 'running', 'completed', 'failed', 'interrupted', 'aborted')),
        created_utc TEXT NOT NULL,
        started_utc TEXT,
        ended_utc TEXT,
        config TEXT NOT NULL,
        directory TEXT NOT NULL UNIQUE,
        detail TEXT
    )""",
    f"""INSERT INTO runs_v3 ({_V3_RUNS_COLUMNS})
        SELECT id, CASE WHEN kind = 'measurement' AND json_type(config, '$.properties') IS NOT NULL
                        THEN 'properties' ELSE kind END,
               robot, state, created_utc, started_utc, ended_utc, config, directory, detail
        FROM runs""",
    "DROP TABLE runs",
    "ALTER TABLE runs_v3 RENAME TO runs",
    "CREATE INDEX runs_robot_state ON runs(robot, state)",
)

MIGRATIONS: tuple[Migration, ...] = (
    Migration(1, "initial schema", _V1),
    Migration(2, "result status", _V2),
    Migration(3, "properties run kind", _V3_POSTGRESQL, sqlite=_V3_SQLITE),
)

_VERSION_TABLE = """CREATE TABLE IF NOT EXISTS schema_version (
    version INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    applied_utc TEXT NOT NULL
)"""


def current_version(backend: Backend) -> int:
    """The highest applied migration (0 for an empty database)."""
    backend.execute(_VERSION_TABLE)
    row = backend.execute("SELECT MAX(version) AS v FROM schema_version")[0]
    return int(row["v"] or 0)


def migrate(backend: Backend, now_utc: Callable[[], str], migrations: Sequence[Migration] = MIGRATIONS) -> list[int]:
    """Apply every migration newer than the database, in order; returns the versions applied (often none)."""
    versions = [m.version for m in migrations]
    if not versions or versions != list(range(1, len(versions) + 1)):
        raise StoreError(f"migrations must be numbered 1..n without gaps, got {versions}")
    latest = len(migrations)
    applied: list[int] = []
    for migration in migrations:
        rebuild = migration.sqlite if backend.dialect.name == SQLITE.name else None
        if rebuild is not None:
            backend.execute("PRAGMA foreign_keys=OFF")  # a no-op inside a transaction: before it
        try:
            if _apply(backend, migration, latest, now_utc, migration.statements if rebuild is None else rebuild,
                      check_foreign_keys=rebuild is not None):
                applied.append(migration.version)
        finally:
            if rebuild is not None:
                backend.execute("PRAGMA foreign_keys=ON")
    return applied


def _apply(backend: Backend, migration: Migration, latest: int, now_utc: Callable[[], str],
           statements: Sequence[str], *, check_foreign_keys: bool) -> bool:
    """Apply one migration in its own transaction unless the database has it; whether it was applied."""
    with backend.transaction():
        if backend.dialect.migration_lock:
            backend.execute(backend.dialect.migration_lock)
        # Read under the lock: another process may have migrated while we waited.
        have = current_version(backend)
        if have > latest:
            raise StoreError(
                f"{backend.description}: schema version {have} is newer than this program knows ({latest}); "
                "upgrade the daemon"
            )
        if have >= migration.version:
            return False
        for statement in statements:
            backend.execute(statement.replace("{id_pk}", backend.dialect.id_pk))
        if check_foreign_keys:
            broken = backend.execute("PRAGMA foreign_key_check")
            if broken:
                raise StoreError(f"{backend.description}: migration {migration.version} ({migration.name}) would "
                                 f"break {len(broken)} foreign key(s), first {broken[0]}; nothing changed")
        backend.execute(
            "INSERT INTO schema_version (version, name, applied_utc) VALUES (?, ?, ?)",
            (migration.version, migration.name, now_utc()),
        )
    return True
