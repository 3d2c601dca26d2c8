"""Finding 1 of issue #12: a stop that reaches the robot after any fault.

Every case is judged by the simulated controller's own program and trace state (``SimProcess.peek``), never by
what the daemon believes. "Stopped" (:func:`faults_helpers.stopped`): no program active, none of ours left selected
in ``#P_STOP``/``#P_RESET`` (where a start key would resume half a move), no trace recording.

* daemon crash (SIGKILL of the daemon's process) in each phase of a measurement and of a campaign, then a restart:
  the new daemon's sweep stops and deselects what the dead one left, before it admits a run, and records why;
* controller stall (SIGSTOP of the simulator's process for several seconds during a move, then SIGCONT);
* link faults during a move: every request dropped, answered with garbage, or delayed past the deadlines, for a
  while — the stop is retried until a read-back confirms it.
"""

from __future__ import annotations

import asyncio
import os
import signal
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.errors import RgseError
from rgse_daemon.store import Store
from simulators.krc4.process import SimProcess
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.faults import DaemonProcess, halted, ours_active, stopped, swept, truth, until_truth

#: How long a stall or a link fault lasts (s): longer than the interlock's staleness (1 s) and one stop attempt.
FAULT_S = 5.0


def _config(tmp_path: Path, sim: SimProcess, **kw: Any):
    return daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, **kw)


async def _events(cfg, kind: str) -> list[Any]:
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        return [e for e in await store.events(limit=100_000) if e.kind == kind]


PHASES = [
    ("measurement", "RGSE_WARMUP"),
    ("measurement", "RGSE_BRAKE_RELEASE"),
    ("measurement", "recording"),
    ("calibration", "confirm"),
    ("calibration", "RGSE_WARMUP"),
    ("calibration", "RGSE_BRAKE_RELEASE"),
    ("calibration", "recording"),
]


@pytest.mark.parametrize(("kind", "phase"), PHASES, ids=[f"{k}-{p}" for k, p in PHASES])
async def test_daemon_killed_in_each_phase_then_restarted_leaves_the_robot_stopped(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path, kind: str, phase: str) -> None:
    cfg = _config(tmp_path, sim_proc)
    await seed_calibration(cfg, calibration_doc)
    child = DaemonProcess(cfg, kind, confirm=phase != "confirm")
    await child.start()
    try:
        if phase == "confirm":
            await child.until(lambda x: x.get("kind") == "confirm", "the campaign asks the operator")
            left_moving = False
        elif phase == "recording":
            await until_truth(sim_proc, lambda v: v["$TRACE.STATE"] in ("#T_WAIT", "#TRIGGERED"), "a trace recording")
            left_moving = True
        else:
            await until_truth(sim_proc, lambda v: ours_active(v, phase), f"{phase} moving")
            left_moving = True
    finally:
        await child.kill()
    before = await truth(sim_proc)
    if left_moving:  # the dead daemon left something running: the restart must stop it
        assert not stopped(before), before
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        # connected means: the sweep ran; nothing of ours moves or records any more
        after = await truth(sim_proc)
        assert stopped(after), after
        assert rd.daemon.latch.current() is None
    if left_moving:
        (ev,) = await _events(cfg, "left_running_stopped")
        assert ev.level.value == "warning" and ev.data is not None and ev.data["confirmed"] is True
        assert ev.data["program"] or ev.data["trace_state"]


async def test_controller_stall_during_a_move_stops_the_program_once_it_is_back(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    cfg = _config(tmp_path, sim_proc)
    await seed_calibration(cfg, calibration_doc)
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        task = await rd.daemon.start_measurement()
        await until_truth(sim_proc, lambda v: ours_active(v, "RGSE_WARMUP"), "the warm-up moving")
        assert sim_proc.pid is not None
        os.kill(sim_proc.pid, signal.SIGSTOP)
        try:
            await asyncio.sleep(FAULT_S)
        finally:
            os.kill(sim_proc.pid, signal.SIGCONT)
        v = await until_truth(sim_proc, stopped, "the program stopped after the controller came back", 60)
        assert v["$PRO_STATE1"] == "#P_FREE", v  # stopped and deselected by us: it did not run on to #P_END
        with pytest.raises(RgseError):
            await asyncio.wait_for(asyncio.shield(task), 60)
        assert rd.daemon.engine is not None
        report = rd.daemon.engine.monitor.stats.stop_report if rd.daemon.engine.monitor else None
        # the engine may be a new one after a reconnect; then the reconnect's sweep did it
        assert report is None or report.confirmed
        assert rd.daemon.latch.current() is None


LINK_FAULTS = {
    # every request closes its connection without a reply
    "dropped link": ("drop_after_requests", 0),
    # every request is answered with bytes that are no frame
    "garbage": ("garbage_next", True),
}


@pytest.mark.parametrize("fault", [*LINK_FAULTS, "delayed reply"])
async def test_link_fault_during_a_move_the_stop_is_retried_until_confirmed(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path, fault: str) -> None:
    cfg = _config(tmp_path, sim_proc)
    await seed_calibration(cfg, calibration_doc)
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        task = await rd.daemon.start_measurement()
        await until_truth(sim_proc, lambda v: ours_active(v, "RGSE_WARMUP"), "the warm-up moving")
        if fault == "delayed reply":
            await sim_proc.fault("extra_latency_s", 3.0)  # every reply later than every deadline of the stop
            await asyncio.sleep(FAULT_S)
            await sim_proc.fault("extra_latency_s", 0.0)
        else:
            name, value = LINK_FAULTS[fault]
            end = asyncio.get_running_loop().time() + FAULT_S
            while asyncio.get_running_loop().time() < end:  # re-armed at once: the fault lasts FAULT_S
                await sim_proc.fault(name, value)
                await asyncio.sleep(0.01)
            await sim_proc.fault(name, None if name == "drop_after_requests" else False)
        # motion and recording stopped (whether the interlock tripped first and deselected the program, or the plan
        # failed on the fault first and its finaliser, confirmed at the end of the plan, left it #P_STOP)
        v = await until_truth(sim_proc, halted, f"the program stopped after the {fault}", 60)
        assert v["$PRO_STATE1"] in ("#P_FREE", "#P_STOP", "#P_RESET", "#P_END"), v
        with pytest.raises(RgseError):
            await asyncio.wait_for(asyncio.shield(task), 60)
        assert rd.daemon.latch.current() is None
