"""Fixtures of the MQTT tests: real brokers, a real store, a recording command handler, a collecting subscriber.

* ``system_broker``: the machine's Mosquitto on 127.0.0.1:1883; each test uses its own random topic prefix and
  clears the retained messages it left under it.
* ``private_broker``: a Mosquitto of our own on a free port, with persistence in ``tmp_path`` — the only broker
  a test may stop and restart.
* ``store``: the real :class:`Store` on SQLite in ``tmp_path``; ``pg_store`` on PostgreSQL in a fresh schema
  (``RGSE_TEST_PG_URL``, default ``postgresql://postgres@127.0.0.1:5432/test``; a missing server fails).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import psycopg
import pytest

from rgse_daemon.store import Store
from tests.support.mqtt import RecordingHandler, clear_retained, port_open

PG_URL = os.environ.get("RGSE_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/test")
SYSTEM_BROKER = ("127.0.0.1", 1883)


@pytest.fixture
async def system_broker() -> tuple[str, int]:
    if not await port_open(*SYSTEM_BROKER):
        pytest.fail(f"the MQTT tests need Mosquitto on {SYSTEM_BROKER[0]}:{SYSTEM_BROKER[1]}")
    return SYSTEM_BROKER


@pytest.fixture
async def prefix(system_broker: tuple[str, int]) -> AsyncIterator[str]:
    """A topic prefix of this test alone; retained messages under it are cleared afterwards."""
    p = f"rgse-test/{uuid.uuid4().hex[:12]}"
    yield p
    await clear_retained(*system_broker, p)



@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    return tmp_path / "data"


@pytest.fixture
async def store(data_dir: Path) -> AsyncIterator[Store]:
    s = await Store.open(None, data_dir, timeout_s=10.0)
    try:
        yield s
    finally:
        await s.close()


def _admin() -> psycopg.Connection:
    try:
        return psycopg.connect(PG_URL, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(f"PostgreSQL at {PG_URL} is required (make test runs scripts/ensure-services.sh): {exc}")


@pytest.fixture
def pg_url() -> Iterator[str]:
    """The test database with a fresh schema selected by search_path; dropped afterwards."""
    schema = f"rgse_test_{uuid.uuid4().hex[:16]}"
    with _admin() as conn:
        conn.execute(f'CREATE SCHEMA "{schema}"')
    try:
        yield f"{PG_URL}{'&' if '?' in PG_URL else '?'}options=-csearch_path%3D{schema}"
    finally:
        with _admin() as conn:
            conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')


@pytest.fixture
async def pg_store(pg_url: str, data_dir: Path) -> AsyncIterator[Store]:
    s = await Store.open(pg_url, data_dir, timeout_s=10.0)
    try:
        yield s
    finally:
        await s.close()


@pytest.fixture
def handler() -> RecordingHandler:
    return RecordingHandler()
