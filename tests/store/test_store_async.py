"""The asyncio facade: the same operations with a deadline, typed errors, cancellation passing through."""

from __future__ import annotations

import asyncio
import sqlite3
import uuid
from pathlib import Path

import psycopg
import pytest

from rgse_daemon.store import OutboxMessage, RunState, Store, StoreError, StoreTimeout, archive_file, archive_root
from rgse_daemon.store.backend import SQLITE_FILENAME
from rgse_daemon.store.migrations import MIGRATIONS

from .conftest import PG_URL, ROBOT, PgSchemas, calibration_doc


async def test_a_measurement_through_the_async_store(store: Store, tmp_path: Path, data_dir: Path) -> None:
    assert await store.recover_interrupted(ROBOT) == []
    cal = await store.add_calibration(calibration_doc("cal-1"))
    assert cal.active and (await store.active_calibration(ROBOT)) == cal

    run = await store.create_run("measurement", ROBOT, {"fixture_mass_kg": 10.288})
    await store.set_run_state(run.id, "running")
    await store.add_loop(run.id, 0, "dut_l01")
    src = tmp_path / "share" / "dut_l01_NextGenDrive#3.r64"
    src.parent.mkdir()
    src.write_bytes(b"\x11" * 800)
    archived = archive_file(src, archive_root(data_dir) / run.directory, expected_size=800)
    await store.add_trace_file(run.id, f"{run.directory}/{src.name}", archived.sha256, archived.size, loop_index=0)
    await store.update_loop(run.id, 0, state="archived")
    topic = f"rgse/{ROBOT}/run/{run.id}/result"
    result = await store.record_result(
        run.id, {"mass_kg": 107.65, "calibration_id": cal.id}, [archived.sha256], publish=OutboxMessage(topic)
    )
    await store.set_run_state(run.id, "completed")

    (msg,) = await store.pending_outbox()
    assert msg.topic == topic and msg.retained
    await store.mark_published(msg.id)
    assert await store.pending_outbox() == []
    assert (await store.get_result(result.id)).trace_sha256 == (archived.sha256,)
    assert (await store.get_run(run.id)).state == RunState.COMPLETED
    assert store.dialect in ("sqlite", "postgresql") and await store.schema_version() == len(MIGRATIONS)


async def test_close_is_idempotent_and_a_closed_store_refuses_calls(store_url: str | None, data_dir: Path) -> None:
    async with await Store.open(store_url, data_dir) as store:
        await store.create_run("measurement", ROBOT, {})
    await store.close()
    with pytest.raises(StoreError, match="store list_runs: the store is closed"):
        await store.list_runs()


async def test_bad_urls_and_unreachable_servers_are_store_errors() -> None:
    with pytest.raises(StoreError, match="unsupported"):
        await Store.open("mysql://db/x", Path("unused"))
    with pytest.raises(StoreError, match="cannot connect"):
        await Store.open("postgresql://postgres@127.0.0.1:1/test", Path("unused"), timeout_s=3.0)
    with pytest.raises(StoreError, match="timeout_s"):
        await Store.open(None, Path("unused"), timeout_s=0)


class _Locker:
    """Another client holding the lock every write of this robot needs, as a stuck daemon would."""

    def __init__(self, store_url: str | None, data_dir: Path) -> None:
        if store_url is None:
            self._sqlite = sqlite3.connect(data_dir / SQLITE_FILENAME, isolation_level=None)
            self._sqlite.execute("BEGIN IMMEDIATE")
            self._pg = None
        else:
            self._sqlite = None
            self._pg = psycopg.connect(store_url, autocommit=True)
            self._pg.execute("BEGIN")
            self._pg.execute("SELECT name FROM robots WHERE name = %s FOR UPDATE", (ROBOT,))

    def release(self) -> None:
        conn = self._sqlite or self._pg
        assert conn is not None
        conn.execute("ROLLBACK")
        conn.close()


async def test_a_locked_database_gives_typed_errors_not_a_hang(store_url: str | None, data_dir: Path) -> None:
    store = await Store.open(store_url, data_dir, timeout_s=2.0)
    try:
        await store.create_run("measurement", ROBOT, {}, run_id="before")
        locker = _Locker(store_url, data_dir)
        try:
            # Two writes waiting for the same lock: the first is stopped by the database's own lock timeout,
            # the second, queued behind it on the store's thread, by the call deadline.
            first = asyncio.create_task(store.create_run("measurement", ROBOT, {}, run_id="a"))
            second = asyncio.create_task(store.create_run("measurement", ROBOT, {}, run_id="b"))
            results = await asyncio.gather(first, second, return_exceptions=True)
        finally:
            locker.release()
        assert isinstance(results[0], StoreError), results[0]
        assert isinstance(results[1], StoreTimeout), results[1]
        assert "outcome unknown" in str(results[1])
        # Once the lock is gone the store works again; the retried write is idempotent.
        run = await store.create_run("measurement", ROBOT, {}, run_id="b")
        assert run.id == "b"
    finally:
        await store.close()


async def test_cancellation_reaches_the_caller(store_url: str | None, data_dir: Path) -> None:
    store = await Store.open(store_url, data_dir, timeout_s=1.0)
    try:
        await store.create_run("measurement", ROBOT, {}, run_id="before")
        locker = _Locker(store_url, data_dir)
        try:
            task = asyncio.create_task(store.create_run("measurement", ROBOT, {}, run_id="c"))
            await asyncio.sleep(0.05)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        finally:
            locker.release()
        assert (await store.get_run("before")).id == "before"
    finally:
        await store.close()


async def test_postgres_reconnects_after_the_server_dropped_it(pg_schemas: PgSchemas, data_dir: Path) -> None:
    app = f"rgse_test_{uuid.uuid4().hex[:12]}"
    url = f"{pg_schemas.new_url()}&application_name={app}"
    async with await Store.open(url, data_dir, timeout_s=5.0) as store:
        await store.create_run("measurement", ROBOT, {}, run_id="r1")
        with psycopg.connect(PG_URL, autocommit=True) as admin:
            killed = admin.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE application_name = %s", (app,)
            ).fetchall()
        assert killed == [(True,)]
        # the call that finds the connection dead retries once on a new one (same schema via the URL): no error
        assert (await store.get_run("r1")).id == "r1"
