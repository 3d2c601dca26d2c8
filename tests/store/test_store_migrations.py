"""Schema migrations: numbered, in order, recorded, idempotent, each in one transaction, safe when concurrent."""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import pytest

from rgse_daemon.store import Repository, RunKind, RunState, StoreError
from rgse_daemon.store.backend import Backend, open_backend
from rgse_daemon.store.migrations import MIGRATIONS, Migration, current_version, migrate

from .conftest import ROBOT


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


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def test_migration_3_stores_a_properties_run_as_one_and_keeps_the_rows_before_it(
    store_url: str | None, data_dir: Path
) -> None:
    """A database of schema 2, with a properties run stored as ``measurement`` (``properties`` in its config) and
    its loops, raw files and result: migration 3 makes it a ``properties`` run and keeps every row and every
    constraint (on SQLite the runs table is rebuilt; its children's foreign keys still hold)."""
    db = _backend(store_url, data_dir)
    try:
        migrate(db, _now, MIGRATIONS[:2])
        v2 = Repository(db)
        v2.create_run(RunKind.MEASUREMENT, ROBOT, {"settings": {"loops": 2}}, run_id="m1")
        props_config = {"settings": {"loops": 2}, "calibration_id": "cal-1", "properties": {"scheme": "full"}}
        v2.create_run(RunKind.MEASUREMENT, ROBOT, props_config, run_id="p1")
        v2.create_run(RunKind.CALIBRATION, ROBOT, {"method": "auto", "properties": "not a properties run"},
                      run_id="c1")
        v2.add_points("c1", [{"kind": "zero"}])
        v2.add_loop("c1", 0, "c1_l01", point_index=0)
        v2.set_run_state("p1", RunState.RUNNING)
        v2.add_loop("p1", 0, "p1_l01")
        v2.add_trace_file("p1", "runs/p1/p1_l01_NextGenDrive#3.r64", _sha("p1"), 1000, loop_index=0)
        stored = v2.record_result("p1", {"mass_kg": 107.6, "cog_m": [0.0, 0.0, 0.1], "warnings": []}, [_sha("p1")])
        v2.set_run_state("p1", RunState.COMPLETED)
        with pytest.raises(StoreError, match="kind"):  # schema 2 has no such kind
            v2.create_run(RunKind.PROPERTIES, ROBOT, props_config, run_id="p0")

        assert migrate(db, _now) == [3]
        repo = Repository(db)
        assert repo.schema_version() == N
        assert {r.id: r.kind for r in repo.list_runs()} == {
            "m1": RunKind.MEASUREMENT, "p1": RunKind.PROPERTIES, "c1": RunKind.CALIBRATION}
        p1 = repo.get_run("p1")
        assert (p1.config, p1.state, p1.directory) == (props_config, RunState.COMPLETED, "runs/p1")
        assert [r.id for r in repo.list_runs(kind="properties")] == ["p1"]
        assert [r.id for r in repo.list_runs(kind="measurement")] == ["m1"]
        assert repo.results("p1") == [stored]
        assert [lp.trace_name for lp in repo.loops("p1")] == ["p1_l01"] and len(repo.trace_files("p1")) == 1
        assert [pt.index for pt in repo.points("c1")] == [0]
        new = repo.create_run(RunKind.PROPERTIES, ROBOT, props_config, run_id="p2")
        assert repo.get_run(new.id).kind == RunKind.PROPERTIES
        with pytest.raises(StoreError):  # the kinds are still checked
            db.execute("UPDATE runs SET kind = 'weighing' WHERE id = 'p2'")
        with pytest.raises(StoreError):  # the children's foreign keys still hold
            db.execute("INSERT INTO loops (run_id, idx, trace_name, state, updated_utc) VALUES ('nope', 0, 'x', "
                       "'pending', '2024-05-01T12:00:00.000000Z')")
        with pytest.raises(StoreError):  # and the runs' own constraints
            repo.create_run(RunKind.MEASUREMENT, ROBOT, {}, run_id="m2", directory="runs/m1")
        assert migrate(db, _now) == []
    finally:
        db.close()
