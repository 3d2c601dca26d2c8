"""Issue 31 6g: a disk that fills up mid-run leaves the archive and the controller reconciled.

The daemon (in-process) measures on the simulated KR C4 over its socket. While it pulls loop 2's trace, the disk
is full: the real archive code gets ENOSPC from the write of the file after two of that trace's files (the fault
is injected at the staging write, the first byte the pull puts on disk). The run fails; then the disk has room
again and the daemon restarts on the same store and controller. Its connect-time recovery must pull the controller's
copies, index every archived file (with the hash of the controller's original), mark the loop ``archived``, and
delete the controller's copies only after that: no file left in the archive unindexed, no loop left ``recorded``."""

from __future__ import annotations

import errno
import hashlib
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.procedures import retrieval
from rgse_daemon.store import LoopState, RunKind, RunState, Store, archive_root
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config, run_end, running_daemon, seed_calibration
from tests.support.faults import swept

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def on_controller(sim: SimulatedKrc4, trace: str) -> dict[str, str]:
    return {p.name: _sha(p) for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith(f"{trace}_")}


async def the_run(cfg: Any) -> tuple[Any, list[Any], dict[str, Any], list[Any]]:
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        (run,) = await store.list_runs(kind=RunKind.MEASUREMENT)
        return (run, await store.loops(run.id), {f.path: f for f in await store.trace_files(run.id)},
                await store.events(run_id=run.id, limit=10_000))


async def test_a_disk_full_mid_pull_is_reconciled_at_the_next_connect(
        sim: SimulatedKrc4, calibration_doc: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=3)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)
    real_write = retrieval._write_staging
    written: dict[str, int] = {}  # files written per trace, in the order the traces come

    def disk_fills_up(path: Path, data: bytes) -> None:
        trace = path.name.rsplit("_", 1)[0]
        written[trace] = written.get(trace, 0) + 1
        if len(written) == 2 and written[trace] > 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real_write(path, data)

    monkeypatch.setattr(retrieval, "_write_staging", disk_fills_up)
    async with running_daemon(cfg) as rd:
        await rd.daemon.start_measurement()
        with pytest.raises(OSError, match="No space left"):
            await run_end(rd)
    monkeypatch.undo()  # room on the disk again
    run, loops, files, _ = await the_run(cfg)
    trace = list(written)[1]
    (loop,) = [lp for lp in loops if lp.trace_name == trace]
    originals = on_controller(sim, trace)
    run_dir = archive_root(cfg.paths.data_dir) / run.directory
    archived = {p.name for p in run_dir.glob(f"{trace}_*")}
    # what the failure left: a failed run, the loop recorded, two files archived but not indexed, all on the controller
    assert run.state == RunState.FAILED and loop.state == LoopState.RECORDED
    assert len(archived) == 2 and not [f for f in files.values() if f.loop_index == loop.index]
    assert len(originals) >= 4 and archived < set(originals)

    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
    run, loops, files, events = await the_run(cfg)
    (loop,) = [lp for lp in loops if lp.trace_name == trace]
    assert loop.state == LoopState.ARCHIVED
    indexed = {Path(f.path).name: f.sha256 for f in files.values() if f.loop_index == loop.index}
    assert indexed == originals  # every file, each with the hash of the controller's original
    root = archive_root(cfg.paths.data_dir)
    assert all(_sha(root / f.path) == f.sha256 for f in files.values())
    assert {p.name for p in run_dir.iterdir() if p.is_file()} == {Path(f.path).name for f in files.values()}
    assert on_controller(sim, trace) == {}  # deleted there only after the store indexed them
    assert run.state == RunState.FAILED  # still the failed run it was: reconciled, not rewritten
    assert [e for e in events if e.kind == "run_recovered"]
