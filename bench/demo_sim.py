"""The benches' shared set-up: ``rgse demo``'s simulated KR C4 in its own process, with the controller's file work at
the daemon's default rate scaled by the simulator's time scale, its daemon configuration, and the whole daemon with
the demo's simulated operator (mounts what a prompt asks for, then confirms). Not a bench itself.

::

    async with demo_sim("rgse-bench-", scale=50.0, seed=2024) as (sim, cfg):
        async with running_daemon(sim, cfg) as daemon:
            cal = await finished(await daemon.start_calibration(points=demo.CAMPAIGN, method="auto"))
"""

from __future__ import annotations

import asyncio
import tempfile
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from rgse_daemon.app import Daemon
from rgse_daemon.commands import demo
from rgse_daemon.config import Config
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.link.connection import Connection, ServerLoad
from rgse_daemon.procedures.events import Event
from rgse_daemon.services.heartbeat import Heartbeat
from rgse_daemon.services.signals import Alarms, StackLight
from simulators.krc4.process import SimProcess

#: The daemon's default controller file rate (config.ControllerConfig.file_rate_bytes_s), B/s of real time. The
#: benches scale it with the simulator, so a pull takes the share of a loop it would take on the real robot.
FILE_RATE_BYTES_S = 40_000.0
#: Deadline of one run of a bench (s of wall time).
RUN_DEADLINE_S = 3600.0


@asynccontextmanager
async def demo_sim(prefix: str, scale: float, seed: int) -> AsyncIterator[tuple[SimProcess, Config]]:
    """The demo's simulator (``seed``, ``scale`` x real time, file work at :data:`FILE_RATE_BYTES_S` x ``scale``)
    in a temporary directory, and the demo's daemon configuration for it; stopped and removed on exit."""
    rate = FILE_RATE_BYTES_S * scale
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        root = Path(tmp)
        sim = SimProcess(root / "share", seed=seed, time_scale=scale, globals_dat=globals_dat_text(),
                         file_rate_bytes_s=rate)
        await asyncio.to_thread(sim.start)
        try:
            yield sim, demo.demo_config(sim, root / "data", None, time_scale=scale, file_rate_bytes_s=rate)
        finally:
            await asyncio.to_thread(sim.stop)


@asynccontextmanager
async def running_daemon(sim: SimProcess, cfg: Config, watch: Callable[[Event], None] | None = None,
                         operator: Callable[[SimProcess, list[Daemon], demo.View], demo.Operator] = demo.Operator,
                         ) -> AsyncIterator[Daemon]:
    """The whole daemon on ``sim``, connected, with the demo's simulated operator (or the one ``operator`` builds from
    the simulator, the daemon's slot and a view); ``watch`` sees every event too."""
    ref: list[Daemon] = []
    lab = operator(sim, ref, demo.SilentView())

    def on_event(ev: Event) -> None:
        lab(ev)
        if watch is not None:
            watch(ev)

    daemon = Daemon(cfg, on_event=on_event)
    ref.append(daemon)
    stop = asyncio.Event()
    service = asyncio.create_task(daemon.run(stop), name="rgse-bench-daemon")
    try:
        async with asyncio.timeout(30):
            await daemon.connected.wait()
        yield daemon
    finally:
        stop.set()
        async with asyncio.timeout(60):
            await service


@asynccontextmanager
async def heartbeat(cfg: Config, load: ServerLoad | None = None) -> AsyncIterator[None]:
    """The daemon's own heartbeat of the controller-side watchdog while the block runs, for a bench that drives the
    run engine without the whole daemon (the programs wait for a fresh beat before they move); ``load``: the
    controller's file work in flight (its pool's), which the daemon's heartbeat shares."""
    beat = Heartbeat(cfg.controller, Alarms(lambda _alarm: None, StackLight(None)), link_up=lambda: True,
                     connection=Connection.from_config(cfg.controller, name="heartbeat", load=load))
    stop = asyncio.Event()
    task = asyncio.create_task(beat.run(stop), name="rgse-bench-heartbeat")
    try:
        yield
    finally:
        stop.set()
        async with asyncio.timeout(15):
            await task


async def finished(task: asyncio.Task[Any], timeout_s: float = RUN_DEADLINE_S) -> Any:
    """The value of a run the daemon started (``start_measurement`` and the like), within ``timeout_s``."""
    async with asyncio.timeout(timeout_s):
        return await task
