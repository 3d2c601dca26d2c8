"""Blocking database connections (sqlite3 or psycopg 3) behind one tiny interface.

Why blocking drivers in a worker thread rather than async drivers: SQLite has no async driver that is more than a
thread around ``sqlite3`` anyway, so one thread-based path serves both databases with the same code and the same
SQL; every store operation is a short transaction, so one dedicated thread per store is plenty; and one connection
used from one thread matches SQLite's single-writer model. The asyncio side (:mod:`rgse_daemon.store.store`) puts a
deadline on every call; the database-side timeouts set here are shorter, so the database normally gives up first
and reports a clean error.

Driver errors become :class:`StoreError` here and nowhere else.
"""

from __future__ import annotations

import sqlite3
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import psycopg
from psycopg.rows import dict_row

from rgse_daemon.store.dialect import POSTGRESQL, SQLITE, Dialect
from rgse_daemon.store.errors import StoreConnectionLost, StoreError

Row = dict[str, Any]

#: File name of the default SQLite store inside the data directory.
SQLITE_FILENAME = "rgse.sqlite3"


class Backend(ABC):
    """One open connection. Not thread-safe: use it from the thread that opened it."""

    dialect: Dialect
    description: str

    def __init__(self) -> None:
        self._in_transaction = False

    # -- driver specific -----------------------------------------------------------------------------------------
    @abstractmethod
    def _execute(self, sql: str, params: Sequence[Any]) -> list[Row]:
        """Run one statement in the driver's own placeholder style."""

    @abstractmethod
    def close(self) -> None:
        """Close the connection; an open transaction is rolled back by the database."""

    # -- common --------------------------------------------------------------------------------------------------
    def execute(self, sql: str, params: Sequence[Any] = ()) -> list[Row]:
        """Run one statement written with ``?`` markers; returns its rows as dicts (empty if it returns none)."""
        if "%" in sql:
            raise StoreError(f"{self.description}: SQL must not contain '%' (portable placeholders only): {sql!r}")
        if self.dialect.placeholder != "?":
            sql = sql.replace("?", self.dialect.placeholder)
        return self._execute(sql, params)

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """A write transaction: committed when the block ends normally, rolled back on any exception."""
        if self._in_transaction:
            raise StoreError(f"{self.description}: nested transactions are not supported")
        self._execute(self.dialect.begin, ())
        self._in_transaction = True
        try:
            yield
        except BaseException:
            self._in_transaction = False
            self._rollback_quietly()
            raise
        self._in_transaction = False
        try:
            self._execute("COMMIT", ())
        except BaseException:
            self._rollback_quietly()  # never leave a half-open transaction behind a failed COMMIT
            raise

    def _rollback_quietly(self) -> None:
        try:
            self._execute("ROLLBACK", ())
        except StoreError:
            # The connection is gone (the server rolled back for us) or never opened the transaction: the original
            # error is the one worth reporting.
            pass


class SqliteBackend(Backend):
    """A SQLite file in WAL mode with foreign keys enforced and fully synchronous commits."""

    dialect = SQLITE

    def __init__(self, path: Path, busy_timeout_s: float) -> None:
        super().__init__()
        self.path = path
        self.description = f"sqlite store {path}"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None: the driver never opens transactions behind our back; we issue BEGIN/COMMIT.
            self._conn = sqlite3.connect(str(path), timeout=busy_timeout_s, isolation_level=None)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"{self.description}: cannot open: {exc}") from exc
        self._conn.row_factory = sqlite3.Row
        try:
            self._enable_wal(busy_timeout_s)
            # FULL: a commit survives power loss, which the outbox and "result after raw files" rely on.
            self._execute("PRAGMA synchronous=FULL", ())
            self._execute("PRAGMA foreign_keys=ON", ())
            if self._execute("PRAGMA foreign_keys", ())[0]["foreign_keys"] != 1:
                raise StoreError(f"{self.description}: this SQLite build cannot enforce foreign keys")
        except BaseException:
            self._conn.close()
            raise

    def _enable_wal(self, timeout_s: float) -> None:
        """Switch a new database file to WAL (persistent, so later opens find it set).

        Changing the journal mode does not wait on SQLite's busy handler: when several processes open a brand-new
        file at once, the losers get "database is locked" at once. Retry until the busy timeout instead.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                mode = self._conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
                break
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() >= deadline:
                    raise StoreError(f"{self.description}: cannot switch to WAL journal mode: {exc}") from exc
                time.sleep(0.01)
        if mode != "wal":
            raise StoreError(f"{self.description}: cannot switch to WAL journal mode (got {mode!r})")

    def _execute(self, sql: str, params: Sequence[Any]) -> list[Row]:
        try:
            cur = self._conn.execute(sql, tuple(params))
            rows = cur.fetchall()
        except sqlite3.Error as exc:
            raise StoreError(f"{self.description}: {exc}") from exc
        return [dict(r) for r in rows]

    def close(self) -> None:
        self._conn.close()


class PostgresBackend(Backend):
    """A PostgreSQL connection by URL; reconnects once, lazily, after the server dropped it.

    The schema is chosen by the URL like any libpq option, e.g. ``postgresql://host/db?options=-csearch_path%3Drgse``.
    """

    dialect = POSTGRESQL

    def __init__(self, url: str, timeout_s: float) -> None:
        super().__init__()
        self.url = url
        self.description = f"postgresql store {_redact(url)}"
        self._timeout_s = timeout_s
        self._conn: psycopg.Connection[Row] | None = None
        self._connect()

    def _connect(self) -> None:
        try:
            conn = psycopg.connect(
                self.url, autocommit=True, row_factory=dict_row, connect_timeout=max(1, round(self._timeout_s))
            )
        except psycopg.Error as exc:
            raise StoreError(f"{self.description}: cannot connect: {exc}") from exc
        try:
            ms = max(1, int(self._timeout_s * 1000))
            conn.execute(f"SET statement_timeout = {ms}")
            conn.execute(f"SET lock_timeout = {ms}")
            conn.execute("SET TIME ZONE 'UTC'")
        except psycopg.Error as exc:
            conn.close()
            raise StoreError(f"{self.description}: cannot configure the session: {exc}") from exc
        self._conn = conn

    def _execute(self, sql: str, params: Sequence[Any]) -> list[Row]:
        if self._conn is None or self._conn.closed:
            if self._in_transaction:
                raise StoreConnectionLost(f"{self.description}: connection lost inside a transaction")
            self._connect()
        assert self._conn is not None
        try:
            cur = self._conn.execute(sql, tuple(params), prepare=False)  # type: ignore[arg-type]
            return cur.fetchall() if cur.description is not None else []
        except psycopg.OperationalError as exc:
            if self._conn.closed or self._conn.broken:
                self._conn = None
                raise StoreConnectionLost(f"{self.description}: connection lost: {exc}") from exc
            raise StoreError(f"{self.description}: {exc}") from exc
        except psycopg.Error as exc:
            raise StoreError(f"{self.description}: {exc}") from exc

    def _rollback_quietly(self) -> None:
        if self._conn is not None:  # a lost connection took its transaction with it; do not reconnect to roll back
            super()._rollback_quietly()

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def _redact(url: str) -> str:
    """The URL without a password, for messages and logs."""
    if "@" not in url or "://" not in url:
        return url
    scheme, rest = url.split("://", 1)
    creds, host = rest.rsplit("@", 1)
    user = creds.split(":", 1)[0]
    return f"{scheme}://{user}@{host}" if user else f"{scheme}://{host}"


def sqlite_path(url: str | None, data_dir: Path) -> Path | None:
    """The SQLite file a store ``url`` names (as :func:`open_backend` resolves it), or None for any other URL."""
    if url is None or url in ("sqlite:", "sqlite://"):
        return Path(data_dir) / SQLITE_FILENAME
    if url.startswith("sqlite:///"):
        path = Path(url.removeprefix("sqlite:///"))
        if not path.name:
            raise StoreError(f"store URL {url!r}: no file name")
        return path if path.is_absolute() else Path(data_dir) / path
    return None


def describe_store(url: str | None, data_dir: Path) -> str:
    """The store ``url`` names, in words (a PostgreSQL password redacted), without opening it."""
    path = sqlite_path(url, data_dir)
    if path is not None:
        return f"sqlite store {path}"
    kind = "postgresql store" if (url or "").startswith(("postgresql://", "postgres://")) else "store"
    return f"{kind} {_redact(url or '')}"


def open_backend(url: str | None, data_dir: Path, timeout_s: float) -> Backend:
    """Open the store named by ``url``.

    ``None`` or ``sqlite:`` → ``<data_dir>/rgse.sqlite3``; ``sqlite:///PATH`` → that file (relative paths are
    relative to ``data_dir``, ``sqlite:////abs/path`` is absolute); ``postgresql://…`` or ``postgres://…`` → that
    server. Anything else is a :class:`StoreError` naming the URL.
    """
    path = sqlite_path(url, data_dir)
    if path is not None:
        return SqliteBackend(path, timeout_s)
    assert url is not None
    if url.startswith(("postgresql://", "postgres://")):
        return PostgresBackend(url, timeout_s)
    raise StoreError(f"store URL {_redact(url)!r}: unsupported (use sqlite:///PATH or postgresql://...)")
