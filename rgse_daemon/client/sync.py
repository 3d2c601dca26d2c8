"""The client for notebooks and plain scripts: :class:`RgseClient` on an event loop of its own, in a thread.

A notebook already runs an event loop, so the blocking calls cannot ``asyncio.run`` there; the client's loop lives
in a daemon thread and each call waits for its coroutine (its own deadline inside, plus a margin). A prompt handler
given to :meth:`SyncRun.wait` is an ordinary function, called in that loop's thread.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self, TypeVar

from rgse_daemon.client.client import DEFAULT_ABORT_REASON, RgseClient, Run
from rgse_daemon.client.types import (
    CampaignPoint,
    DaemonState,
    FixtureFrame,
    Identity,
    ProgressEvent,
    Prompt,
    Result,
)
from rgse_daemon.config import Config
from rgse_daemon.io.operator import DEFAULT_TIMEOUT_S

T = TypeVar("T")

#: Added to a call's own deadline before the calling thread gives up on it (the coroutine raises first).
MARGIN_S = 5.0


class SyncClient:
    """``with SyncClient.from_config(path) as rgse: rgse.measure(loops=3).wait(600)``."""

    def __init__(self, make: Callable[[], RgseClient], timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self._make = make  # called on the client's loop: an MQTT client belongs to the loop it was made on
        self.timeout_s = timeout_s
        self._client: RgseClient | None = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="rgse-client", daemon=True)

    @classmethod
    def from_config(cls, path: Path, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> SyncClient:
        return cls(lambda: RgseClient.from_config(path, timeout_s=timeout_s), timeout_s)

    @classmethod
    def of(cls, cfg: Config, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> SyncClient:
        return cls(lambda: RgseClient.of(cfg, timeout_s=timeout_s), timeout_s)

    def call(self, coro: Coroutine[Any, Any, T], timeout_s: float | None = None) -> T:
        """Run ``coro`` on the client's loop and wait for it."""
        future = asyncio.run_coroutine_threadsafe(coro, self._loop)
        return future.result((timeout_s or self.timeout_s) + MARGIN_S)

    @property
    def client(self) -> RgseClient:
        if self._client is None:
            raise RuntimeError("SyncClient: use it as `with SyncClient...(...) as rgse:`")
        return self._client

    def __enter__(self) -> Self:
        self._thread.start()

        async def enter() -> RgseClient:
            return await self._make().__aenter__()

        try:
            self._client = self.call(enter())
        except BaseException:
            self._stop()
            raise
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.call(self.client.__aexit__(exc_type, exc, tb))
        finally:
            self._stop()

    def _stop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(MARGIN_S)
        if not self._thread.is_alive():
            self._loop.close()

    def state(self) -> DaemonState:
        return self.call(self.client.state())

    def ready(self, timeout_s: float | None = None) -> DaemonState:
        return self.call(self.client.ready(timeout_s), timeout_s)

    def measure(self, *, loops: int | None = None, fixture_mass_kg: float | None = None,
                dry_run: bool = False, identity: Identity | None = None) -> SyncRun:
        return SyncRun(self, self.call(self.client.measure(loops=loops, fixture_mass_kg=fixture_mass_kg,
                                                           dry_run=dry_run, identity=identity)))

    def properties(self, *, loops: int | None = None, loops_per_pose: int | None = None, scheme: str | None = None,
                   fixture_mass_kg: float | None = None, fixture: FixtureFrame | None = None,
                   inertia: bool | None = None, dry_run: bool = False, identity: Identity | None = None,
                   mass_method: str | None = None) -> SyncRun:
        return SyncRun(self, self.call(self.client.properties(
            loops=loops, loops_per_pose=loops_per_pose, scheme=scheme, fixture_mass_kg=fixture_mass_kg,
            fixture=fixture, inertia=inertia, dry_run=dry_run, identity=identity, mass_method=mass_method)))

    def calibrate(self, points: Sequence[CampaignPoint] | None = None, *, method: str | None = None) -> SyncRun:
        return SyncRun(self, self.call(self.client.calibrate(points, method=method)))

    def confirm(self, run_id: str, point: int | None = None, message: str | None = None) -> None:
        self.call(self.client.confirm(run_id, point, message))

    def abort(self, run_id: str | None = None, reason: str = DEFAULT_ABORT_REASON) -> None:
        self.call(self.client.abort(run_id, reason))

    def result(self, run_id: str, timeout_s: float | None = None) -> Result:
        return self.call(self.client.result(run_id, timeout_s=timeout_s), timeout_s)

    def report(self, run_id: str | None = None, *, calibration_id: str | None = None,
               out_dir: Path | None = None) -> Path:
        return self.call(self.client.report(run_id, calibration_id=calibration_id, out_dir=out_dir), 120.0)


class SyncRun:
    """The blocking face of :class:`~rgse_daemon.client.client.Run`."""

    def __init__(self, owner: SyncClient, run: Run) -> None:
        self._owner = owner
        self.run = run
        self.run_id = run.run_id
        self.kind = run.kind

    def next_event(self, timeout_s: float) -> ProgressEvent:
        return self._owner.call(self.run.next_event(timeout_s), timeout_s)

    def next_prompt(self, timeout_s: float) -> Prompt:
        return self._owner.call(self.run.next_prompt(timeout_s), timeout_s)

    def confirm(self, prompt: Prompt | None = None, message: str | None = None) -> None:
        self._owner.call(self.run.confirm(prompt, message))

    def abort(self, reason: str = DEFAULT_ABORT_REASON) -> None:
        self._owner.call(self.run.abort(reason))

    def wait(self, timeout_s: float, on_prompt: Callable[[Prompt], str | None] | None = None) -> Result:
        return self._owner.call(self.run.wait(timeout_s, on_prompt), timeout_s)
