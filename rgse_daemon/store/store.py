"""The store as the asyncio daemon sees it: every :class:`Repository` operation as a coroutine with a deadline.

All operations run, one at a time, on the store's own worker thread (one connection, one thread — what sqlite3
requires and what keeps transactions from interleaving). The event loop never blocks on the database. Each call
waits at most ``timeout_s``; the database-side timeouts (lock wait, statement, connect) are set to
:data:`DB_TIMEOUT_FRACTION` of it, so the database normally gives up first with a clean :class:`StoreError`.
If the deadline still passes, :class:`StoreTimeout` says the outcome is unknown — every write is keyed or
content-derived, so retrying is safe. One dropped database connection (:class:`StoreConnectionLost`: a PostgreSQL
restart, a terminated backend) is retried once on a new connection, not reported: the operation is one
transaction, rolled back by the server when the connection broke. Cancellation propagates to the caller
unchanged; an operation already running on the thread finishes (or rolls back) there.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Awaitable, Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Concatenate, ParamSpec, Self, TypeVar

from rgse_daemon.aio import within
from rgse_daemon.store.errors import StoreConnectionLost, StoreError, StoreTimeout
from rgse_daemon.store.repository import Clock, Repository, utc_now

_log = logging.getLogger(__name__)

#: Database-side timeouts as a fraction of the per-call deadline: the database should give up first.
DB_TIMEOUT_FRACTION = 0.8

P = ParamSpec("P")
R = TypeVar("R")


def _offload(method: Callable[Concatenate[Repository, P], R]) -> Callable[Concatenate[Store, P], Awaitable[R]]:
    """Turn a blocking :class:`Repository` method into a coroutine method of :class:`Store`."""

    async def call(self: Store, *args: P.args, **kwargs: P.kwargs) -> R:
        return await self._call(method.__name__, functools.partial(method, self._repo, *args, **kwargs))

    call.__name__ = method.__name__
    call.__qualname__ = f"Store.{method.__name__}"
    call.__doc__ = method.__doc__
    return call


def _close_if_opened(opening: Future[Repository]) -> None:
    if opening.done() and not opening.cancelled() and opening.exception() is None:
        opening.result().close()


class Store:
    """Async facade over one :class:`Repository`; open with ``await Store.open(...)`` or ``async with``."""

    def __init__(self, repo: Repository, executor: ThreadPoolExecutor, timeout_s: float) -> None:
        self._repo = repo
        self._executor = executor
        self._timeout_s = timeout_s
        self._closed = False

    @classmethod
    async def open(
        cls, url: str | None, data_dir: Path, *, timeout_s: float = 10.0, clock: Clock = utc_now
    ) -> Store:
        """Connect (SQLite file under ``data_dir`` when ``url`` is None, else the URL) and migrate the schema.

        Does not recover interrupted runs by itself: the daemon calls :meth:`recover_interrupted` with its robot,
        which on a shared database must not touch other robots' runs.
        """
        if not timeout_s > 0:
            raise StoreError(f"store timeout_s {timeout_s!r}: must be > 0")
        executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rgse-store")
        opening = executor.submit(
            Repository.open, url, data_dir, timeout_s=DB_TIMEOUT_FRACTION * timeout_s, clock=clock
        )
        try:
            # Opening may migrate a large database: allow a few operation deadlines.
            repo = await within(asyncio.wrap_future(opening), 3 * timeout_s)
        except BaseException as exc:
            # Runs after the open on the same thread: closes a connection that arrived too late for us.
            executor.submit(_close_if_opened, opening)
            executor.shutdown(wait=False)
            if isinstance(exc, TimeoutError):
                raise StoreTimeout(f"store open: no answer within {3 * timeout_s:g} s") from exc
            raise
        return cls(repo, executor, timeout_s)

    async def _call(self, name: str, fn: Callable[[], R]) -> R:
        if self._closed:
            raise StoreError(f"store {name}: the store is closed")
        for attempt in (1, 2):
            fut = asyncio.get_running_loop().run_in_executor(self._executor, fn)
            try:
                return await within(fut, self._timeout_s)
            except TimeoutError as exc:
                raise StoreTimeout(f"store {name}: no answer within {self._timeout_s:g} s; outcome unknown") from exc
            except StoreConnectionLost as exc:
                if attempt == 2:
                    raise
                _log.warning("store %s: %s; retrying once on a new connection", name, exc)
        raise AssertionError("unreachable")

    @property
    def description(self) -> str:
        return self._repo.description

    @property
    def dialect(self) -> str:
        """``sqlite`` or ``postgresql``."""
        return self._repo.dialect

    async def close(self) -> None:
        """Close the connection (bounded by the deadline) and release the worker thread. Idempotent."""
        if self._closed:
            return
        try:
            await self._call("close", self._repo.close)
        finally:
            self._closed = True
            self._executor.shutdown(wait=False)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    schema_version = _offload(Repository.schema_version)
    robots = _offload(Repository.robots)
    # runs
    create_run = _offload(Repository.create_run)
    get_run = _offload(Repository.get_run)
    list_runs = _offload(Repository.list_runs)
    set_run_state = _offload(Repository.set_run_state)
    recover_interrupted = _offload(Repository.recover_interrupted)
    # campaign points and loops
    add_points = _offload(Repository.add_points)
    set_point_state = _offload(Repository.set_point_state)
    points = _offload(Repository.points)
    add_loop = _offload(Repository.add_loop)
    update_loop = _offload(Repository.update_loop)
    loops = _offload(Repository.loops)
    # raw files
    add_trace_file = _offload(Repository.add_trace_file)
    trace_files = _offload(Repository.trace_files)
    # calibrations
    add_calibration = _offload(Repository.add_calibration)
    activate_calibration = _offload(Repository.activate_calibration)
    get_calibration = _offload(Repository.get_calibration)
    active_calibration = _offload(Repository.active_calibration)
    calibrations = _offload(Repository.calibrations)
    # results
    record_result = _offload(Repository.record_result)
    get_result = _offload(Repository.get_result)
    results = _offload(Repository.results)
    # events and alarms
    add_event = _offload(Repository.add_event)
    events = _offload(Repository.events)
    # MQTT outbox
    enqueue = _offload(Repository.enqueue)
    pending_outbox = _offload(Repository.pending_outbox)
    mark_published = _offload(Repository.mark_published)
    record_publish_failure = _offload(Repository.record_publish_failure)
    get_outbox = _offload(Repository.get_outbox)
