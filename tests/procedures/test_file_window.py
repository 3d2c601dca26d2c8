"""The interlock's file-window rule (rgse_daemon.safety.monitor): a pull blocks the real controller's status reads,
so it runs only at standstill, late snapshots are bounded by the file work's own deadline, every snapshot that
arrives is judged (pose unchanged included), and the window closes only on a fresh snapshot."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import pytest

from rgse_daemon.controller import Controller
from rgse_daemon.errors import InterlockError
from rgse_daemon.manifest import MODULE_A3, MODULE_A5
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.retrieval import PulledTrace
from rgse_daemon.safety.monitor import InterlockTrip
from rgse_daemon.services.link import ControllerLink, DaemonCounters
from rgse_daemon.services.signals import Alarms, StackLight
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.variables import e6axis
from tests.support.heartbeat import beating
from tests.support.polling import wait_until

from .conftest import controller, heartbeat, make_engine


@pytest.fixture
async def sim(sim: SimulatedKrc4) -> SimulatedKrc4:
    """The interlock end to end: the simulated KR C4 listens, and the daemon's link reaches it over TCP."""
    await sim.start()
    return sim

FILE_BYTES = 120_000  # each .r64: 1.2 s of the simulator's default 100 kB/s, longer than the staleness limit


def _big_trace(sim: SimulatedKrc4, trace: str) -> dict[str, bytes]:
    folder = sim.share_dir / "TRACE"
    names = [f"{trace}_{mod}{ext}" for mod in (MODULE_A3, MODULE_A5) for ext in (".dat", ".r64")]
    files = {n: os.urandom(FILE_BYTES if n.endswith(".r64") else 2000) for n in names}
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return files


def _pull_plan(trace: str, dest: Path) -> m.Plan:
    pulled = yield m.Pull(trace, dest, 30.0)
    return pulled


async def test_a_long_pull_completes_with_the_interlock_watching(sim, engine: RunEngine, tmp_path: Path) -> None:
    assert engine.monitor is not None
    assert FILE_BYTES / sim.server.config.file_rate_bytes_s > engine.monitor.stale_after_s
    files = _big_trace(sim, "w1")
    pulled = await asyncio.wait_for(engine.run(_pull_plan("w1", tmp_path / "run")), 60)
    assert isinstance(pulled, PulledTrace) and len(pulled.files) == len(files)
    stats = engine.monitor.stats
    assert stats.window_polls >= 1 and stats.window_late_polls >= 1  # late, bounded, and cleared at the close
    assert engine.monitor.trip is None


async def test_the_window_opens_only_at_standstill(sim, engine: RunEngine, tmp_path: Path) -> None:
    _big_trace(sim, "w2")
    sim.store.update("$ROB_STOPPED", "FALSE")
    with pytest.raises(InterlockError, match="must stand still"):
        await asyncio.wait_for(engine.run(_pull_plan("w2", tmp_path / "run")), 30)
    assert sorted(p.name for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith("w2_"))  # untouched


async def test_motion_seen_during_a_pull_trips(sim, engine: RunEngine, tmp_path: Path) -> None:
    _big_trace(sim, "w3")
    task = asyncio.create_task(engine.run(_pull_plan("w3", tmp_path / "run")))
    await asyncio.sleep(0.3)  # the pull is under way
    sim.store.update("$AXIS_ACT", e6axis((0.0, -90.0, 95.0, 0.0, 0.0, 0.0)))  # someone jogged A3 by 5 deg
    with pytest.raises(InterlockTrip) as info:
        await asyncio.wait_for(task, 30)
    assert info.value.watcher == "file_window" and "A3 moved" in info.value.detail


async def test_a_status_read_later_than_the_file_work_allows_trips(sim, cfg, tmp_path: Path) -> None:
    _big_trace(sim, "w4")
    async with controller(sim, cfg) as krc, heartbeat(sim, cfg):
        engine = make_engine(krc, cfg)
        task = asyncio.create_task(engine.run(_pull_plan("w4", tmp_path / "run")))
        await asyncio.sleep(0.3)
        sim.server.faults.extra_latency_s = 8.0  # the controller hangs far beyond any file work's deadline
        monitor = engine.monitor
        assert monitor is not None
        await wait_until(lambda: monitor.trip is not None, "the interlock trips", 40.0)
        sim.server.faults.extra_latency_s = 0.0  # the controller answers again: the stop can be confirmed
        with pytest.raises(InterlockTrip) as info:
            await asyncio.wait_for(task, 40)
        assert info.value.watcher == "link"


async def test_a_heartbeat_queued_behind_a_pull_is_late_not_lost(sim, cfg, tmp_path: Path) -> None:
    """The daemon's heartbeat shares the controller's file work in flight (``ControllerLink.heartbeat_connection``):
    a beat queued behind a pull's file read longer than the watchdog's bound gets that read's deadline added, as the
    pool's requests do, so a pull at the controller's file rate raises no "heartbeat failed" alarm and drops no
    connection. A heartbeat on a connection that does not know the pull (the daemon's before) fails at every such
    read. The controller's bound is untouched (it counts from the last beat that arrived); no program runs during a
    pull (the file window opens only then), so the watchdog guards no motion meanwhile."""
    assert FILE_BYTES / sim.server.config.file_rate_bytes_s > cfg.controller.watchdog_bound_s
    files = _big_trace(sim, "w6")
    alarms: list[dict[str, object]] = []
    link = ControllerLink(cfg.controller, DaemonCounters(), Alarms(alarms.append, StackLight(None)),
                          busy=lambda: True)
    async with (Controller.connect(cfg.controller, load=link.load) as krc,
                beating(cfg.controller, connection=link.heartbeat_connection()) as shared,
                beating(cfg.controller) as alone):
        await wait_until(lambda: shared.beats >= 3 and alone.beats >= 3, "both heartbeats beating", timeout_s=10)
        engine = make_engine(krc, cfg)
        pulled = await asyncio.wait_for(engine.run(_pull_plan("w6", tmp_path / "run")), 60)
        assert isinstance(pulled, PulledTrace) and len(pulled.files) == len(files)
        beats = shared.beats
        await wait_until(lambda: shared.beats > beats + 2, "beats after the pull", timeout_s=10)
    assert shared.failures == 0, shared.failures
    assert alone.failures >= 1  # the same pull, a heartbeat that does not know it: late, taken as lost
