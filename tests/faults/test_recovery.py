"""Finding 4 of issue #12: crash recovery finishes the job.

The daemon (its own process) is SIGKILLed during a measurement; a new daemon starts on the same store and
controller. Judged by the controller's TRACE folder (the simulator's share), the archive on disk, the store and the
broker:

* killed while loop 1 records: the new daemon stops the trace, pulls and indexes what it wrote, deletes the
  controller copies only after that, marks the loop, records ``run_recovered``, and an MQTT client waiting on the
  run's result topic gets a final ``interrupted`` result;
* killed in the middle of loop 1's pull (files archived but not indexed): the new daemon indexes every file with the
  hash of the controller's original, the loop becomes ``archived``, the controller copies go.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import time
import uuid
from pathlib import Path
from typing import Any

import aiomqtt

from rgse_daemon.store import LoopState, RunKind, RunState, Store, archive_root
from simulators.krc4.process import SimProcess
from tests.support.daemon import PREFIX, daemon_config, running_daemon, seed_calibration
from tests.support.faults import DaemonProcess, ours_active, stopped, swept, truth, until_truth
from tests.support.mqtt import MosquittoProcess


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _on_controller(sim: SimProcess, trace: str) -> dict[str, str]:
    return {p.name: _sha(p) for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith(f"{trace}_")}


async def _the_run(cfg: Any) -> tuple[Any, list[Any], dict[str, Any], list[Any]]:
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        (run,) = await store.list_runs(kind=RunKind.MEASUREMENT)
        loops = await store.loops(run.id)
        files = {f.path: f for f in await store.trace_files(run.id)}
        events = await store.events(run_id=run.id, limit=100_000)
    return run, loops, files, events


async def _retained(port: int, topic: str, timeout_s: float = 30.0) -> dict[str, Any]:
    async with aiomqtt.Client("127.0.0.1", port, identifier=f"t-{uuid.uuid4().hex[:8]}", timeout=10) as client:
        await client.subscribe(topic, qos=1)
        async with asyncio.timeout(timeout_s):
            async for msg in client.messages:
                return json.loads(msg.payload)  # type: ignore[arg-type]
    raise AssertionError(f"nothing on {topic}")


async def test_killed_while_recording_the_trace_is_pulled_indexed_and_the_result_says_interrupted(
        sim_proc: SimProcess, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim_proc.port, share_dir=sim_proc.share_dir,
                        broker_port=private_broker.port)
    await seed_calibration(cfg, calibration_doc)
    child = DaemonProcess(cfg, "measurement")
    await child.start()
    try:
        await until_truth(sim_proc, lambda v: v["$TRACE.STATE"] == "#TRIGGERED", "loop 1 recording")
    finally:
        await child.kill()
    run, loops, files, _ = await _the_run(cfg)
    assert run.state == RunState.RUNNING and loops[0].state == LoopState.RECORDING and not files
    trace = loops[0].trace_name
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        assert stopped(await truth(sim_proc))
        run, loops, files, events = await _the_run(cfg)
        result = await _retained(private_broker.port, f"{PREFIX}/run/{run.id}/result")
    assert run.state == RunState.INTERRUPTED
    assert loops[0].state == LoopState.INTERRUPTED  # its trace was cut short: kept and indexed, never used
    assert all(lp.state in (LoopState.INTERRUPTED, LoopState.ARCHIVED) for lp in loops)
    loop_files = [f for f in files.values() if f.loop_index == loops[0].index]
    assert len(loop_files) >= 4, files  # the stopped trace's files: pulled, archived, indexed
    root = archive_root(cfg.paths.data_dir)
    assert all(_sha(root / f.path) == f.sha256 for f in loop_files)
    assert _on_controller(sim_proc, trace) == {}  # deleted there only after the store indexed them
    (rec,) = [e for e in events if e.kind == "run_recovered"]
    assert rec.data is not None and rec.data["indexed"] == len(loop_files)
    assert result["run_id"] == run.id and result["state"] == "interrupted"


async def test_killed_during_a_pull_the_archived_files_are_indexed_and_the_loop_archived(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim_proc.port, share_dir=sim_proc.share_dir)
    await seed_calibration(cfg, calibration_doc)
    child = DaemonProcess(cfg, "measurement")
    await child.start()
    runs = cfg.paths.data_dir / "archive" / "runs"
    try:
        await until_truth(sim_proc, lambda v: v["$TRACE.STATE"] == "#TRIGGERED", "loop 1 recording")
        # loop 1's files are pulled while loop 2 settles and records, once loop 2's move has ended (PullStart): the
        # link is slowed only then, and only as far as the deadlines allow. The simulated controller answers one
        # request at a time, all clients (the pull, the interlock's snapshots, the trace poll and the controller-side
        # watchdog's heartbeat): at 0.25 s a request a snapshot or a beat waits > 1 s, which rightly stops the run
        # (interlock "link", watchdog) before any file is pulled.
        await until_truth(sim_proc, lambda v: ours_active(v, "RGSE_BRAKE_RELEASE"), "loop 2 moving")
        await until_truth(sim_proc, lambda v: v["$PRO_STATE1"] != "#P_ACTIVE", "loop 2's move ended", period_s=0.005)
        await sim_proc.fault("extra_latency_s", 0.1)  # a slow link: the pull takes seconds
        deadline = time.monotonic() + 90
        while not [p for p in runs.glob("*/dut_*") if not p.name.startswith(".")]:
            assert time.monotonic() < deadline, "no file of loop 1 archived"
            await asyncio.sleep(0.01)
    finally:
        await child.kill()
    await sim_proc.fault("extra_latency_s", 0.0)
    run, loops, files, _ = await _the_run(cfg)
    trace = loops[0].trace_name
    originals = _on_controller(sim_proc, trace)
    archived = [p for p in (runs / run.id).glob(f"{trace}_*")]
    assert loops[0].state == LoopState.RECORDED and archived and len(files) < len(originals)
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        run, loops, files, events = await _the_run(cfg)
    assert loops[0].state == LoopState.ARCHIVED
    indexed = {Path(f.path).name: f.sha256 for f in files.values() if f.loop_index == loops[0].index}
    assert indexed == originals  # every file, each with the hash of the controller's original
    assert _on_controller(sim_proc, trace) == {}
    assert [e for e in events if e.kind == "run_recovered"]
