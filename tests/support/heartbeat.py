"""The daemon's heartbeat for tests that drive the run engine without a :class:`~rgse_daemon.app.Daemon` around it:
the programs the daemon pushes arm the controller-side watchdog and wait for a fresh heartbeat before they move
(docs/security.md). This is the daemon's own :class:`~rgse_daemon.services.heartbeat.Heartbeat`, beating while the
block runs."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

from rgse_daemon.config import ControllerConfig
from rgse_daemon.link.connection import Connection
from rgse_daemon.services.heartbeat import Heartbeat
from rgse_daemon.services.signals import Alarms, StackLight


@contextlib.asynccontextmanager
async def beating(cfg: ControllerConfig, *, connection: Connection | None = None) -> AsyncIterator[Heartbeat]:
    """Beat on ``connection`` (default: the heartbeat's own TCP connection to ``cfg``'s controller)."""
    alarms: list[dict[str, object]] = []
    heartbeat = Heartbeat(cfg, Alarms(alarms.append, StackLight(None)), link_up=lambda: True, connection=connection)
    stop = asyncio.Event()
    task = asyncio.create_task(heartbeat.run(stop), name="test-heartbeat")
    try:
        yield heartbeat
    finally:
        stop.set()
        await asyncio.wait({task}, timeout=10.0)
        if not task.done():
            task.cancel()
            await asyncio.wait({task}, timeout=5.0)
