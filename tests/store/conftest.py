"""Fixtures of the store tests: a real SQLite file per test and a real PostgreSQL schema per test.

PostgreSQL comes from ``RGSE_TEST_PG_URL`` (default ``postgresql://postgres@127.0.0.1:5432/test``); each test gets
its own uniquely named schema, created here and dropped afterwards, and a store URL whose search_path selects it.
A missing server fails the test (``make test`` runs scripts/ensure-services.sh first); it never skips.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from rgse_daemon.store import Repository, Store
from tests.support.pg import PG_URL, PgSchemas, url_with_schema

__all__ = ["PG_URL", "PgSchemas", "url_with_schema"]  # the store tests import them from here

ROBOT = "KR500R2830-1234"


@pytest.fixture
def pg_schemas() -> Iterator[PgSchemas]:
    schemas = PgSchemas()
    yield schemas
    schemas.drop_all()


@pytest.fixture
def pg_url(pg_schemas: PgSchemas) -> str:
    return pg_schemas.new_url()


@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    return tmp_path / "data"


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest) -> str | None:
    """``None`` (the default SQLite file under the data directory) or a PostgreSQL URL with a fresh schema."""
    if request.param == "sqlite":
        return None
    return request.getfixturevalue("pg_url")


@pytest.fixture
def repo(store_url: str | None, data_dir: Path) -> Iterator[Repository]:
    with Repository.open(store_url, data_dir, timeout_s=10.0) as r:
        yield r


@pytest.fixture
async def store(store_url: str | None, data_dir: Path) -> AsyncIterator[Store]:
    s = await Store.open(store_url, data_dir, timeout_s=10.0)
    try:
        yield s
    finally:
        await s.close()


def calibration_doc(cal_id: str, robot: str = ROBOT, method: str = "paper") -> dict:
    """A small CAL.json-shaped document (interfaces §3)."""
    return {
        "schema": 1,
        "calibration_id": cal_id,
        "created_utc": "2024-05-01T12:00:00Z",
        "robot": robot,
        "method": method,
        "preprocessing": {"trim_s": 2.0},
        "bias_nm": {"A3": -12.5, "A5": 3.25},
        "models": {"A3": {"a": 1.01}, "A5": {"a": 0.99}},
        "lever_difference_m": 1.025,
        "g": 9.81,
        "fit": {"in_sample_mean_abs_err_pct": 0.4, "loo_mean_abs_err_pct": 0.6, "covariance": [[1e-4]]},
        "source_sha256": {},
    }
