"""Schema migrations: numbered, in order, recorded, idempotent, each in one transaction, safe when concurrent."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from rgse_daemon.store import Repository, StoreError
from rgse_daemon.store.backend import Backend, open_backend
from rgse_daemon.store.migrations import MIGRATIONS, Migration, current_version, migrate


def _now() -> str:
    return "2024-05-01T12:00:00.000000Z"


def _backend(store_url: str | None, data_dir: Path) -> Backend:
    return open_backend(store_url, data_dir, timeout_s=10.0)


def _tables(db: Backend) -> set[str]:
    if db.dialect.name == "sqlite":
        rows = db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
    else:
        rows = db.execute(
            "SELECT table_name AS name FROM information_schema.tables WHERE table_schema = current_schema()"
        )
    return {r["name"] for r in rows}


N = len(MIGRATIONS)  # the project's own migrations; the tests' extra ones come after them
EXTRA = Migration(N + 1, "operator notes", ("CREATE TABLE notes (id {id_pk}, text TEXT NOT NULL)",))
BROKEN = Migration(
    N + 2, "half broken", ("CREATE TABLE half (x INTEGER)", "ALTER TABLE no_such_table ADD COLUMN y INTEGER")
)


def test_migrations_apply_in_order_once_and_are_recorded(store_url: str | None, data_dir: Path) -> None:
    db = _backend(store_url, data_dir)
    try:
        assert migrate(db, _now, (*MIGRATIONS, EXTRA)) == list(range(1, N + 2))
        assert migrate(db, _now, (*MIGRATIONS, EXTRA)) == []  # idempotent
        assert current_version(db) == N + 1
        rows = db.execute("SELECT version, name, applied_utc FROM schema_version ORDER BY version")
        names = [(r["version"], r["name"]) for r in rows]
        assert names[0] == (1, "initial schema") and names[-1] == (N + 1, "operator notes")
        assert {"runs", "loops", "trace_files", "calibrations", "results", "events", "outbox", "notes"} <= _tables(db)
        db.execute("INSERT INTO notes (text) VALUES (?)", ("autoincrement works",))
        assert db.execute("SELECT id FROM notes")[0]["id"] == 1
    finally:
        db.close()


def test_a_failing_migration_is_rolled_back_whole(store_url: str | None, data_dir: Path) -> None:
    db = _backend(store_url, data_dir)
    try:
        with pytest.raises(StoreError, match="no_such_table"):
            migrate(db, _now, (*MIGRATIONS, EXTRA, BROKEN))
        assert current_version(db) == N + 1  # 1..N+1 stay applied; N+2 left no trace
        assert "half" not in _tables(db)
    finally:
        db.close()


def test_badly_numbered_migrations_are_refused(data_dir: Path) -> None:
    db = _backend(None, data_dir)
    try:
        with pytest.raises(StoreError, match=rf"numbered 1\.\.n without gaps, got \[1, .*{N + 2}\]"):
            migrate(db, _now, (*MIGRATIONS, BROKEN))
        with pytest.raises(StoreError, match="without gaps"):
            migrate(db, _now, ())
    finally:
        db.close()


def test_a_database_from_a_newer_daemon_is_refused(store_url: str | None, data_dir: Path) -> None:
    db = _backend(store_url, data_dir)
    try:
        migrate(db, _now, (*MIGRATIONS, EXTRA))
    finally:
        db.close()
    with pytest.raises(StoreError, match=f"schema version {N + 1} is newer than this program knows \\({N}\\)"):
        Repository.open(store_url, data_dir)


def test_concurrent_first_opens_migrate_exactly_once(store_url: str | None, data_dir: Path) -> None:
    outcomes: list[object] = []
    barrier = threading.Barrier(3)

    def open_once() -> None:
        barrier.wait(timeout=10)
        try:
            with Repository.open(store_url, data_dir) as repo:
                outcomes.append(repo.schema_version())
        except Exception as exc:  # collected and asserted below
            outcomes.append(exc)

    threads = [threading.Thread(target=open_once) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert outcomes == [N, N, N]
    with Repository.open(store_url, data_dir) as repo:
        assert repo.schema_version() == N
