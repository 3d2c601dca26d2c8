"""Per-test PostgreSQL schemas on the real server: ``RGSE_TEST_PG_URL`` (default
``postgresql://postgres@127.0.0.1:5432/test``); each :meth:`PgSchemas.new_url` is a store URL whose search_path
selects a fresh, uniquely named schema, dropped by :meth:`PgSchemas.drop_all`. A missing server fails the test
(``make test`` runs scripts/ensure-services.sh first); it never skips."""

from __future__ import annotations

import os
import uuid

import psycopg
import pytest

PG_URL = os.environ.get("RGSE_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/test")


def url_with_schema(url: str, schema: str) -> str:
    """The same server and database, with the libpq search_path option selecting ``schema``."""
    return f"{url}{'&' if '?' in url else '?'}options=-csearch_path%3D{schema}"


def _admin() -> psycopg.Connection:
    try:
        return psycopg.connect(PG_URL, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(f"PostgreSQL at {PG_URL} is required (make test runs scripts/ensure-services.sh): {exc}")


class PgSchemas:
    """Creates uniquely named schemas and drops them all at teardown."""

    def __init__(self) -> None:
        self.names: list[str] = []

    def new_url(self) -> str:
        name = f"rgse_test_{uuid.uuid4().hex[:16]}"
        with _admin() as conn:
            conn.execute(f'CREATE SCHEMA "{name}"')
        self.names.append(name)
        return url_with_schema(PG_URL, name)

    def drop_all(self) -> None:
        if not self.names:
            return
        with _admin() as conn:
            for name in self.names:
                conn.execute(f'DROP SCHEMA IF EXISTS "{name}" CASCADE')
        self.names.clear()
