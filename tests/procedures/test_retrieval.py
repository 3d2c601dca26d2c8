"""Trace retrieval without a mounted share: the controller copies are deleted over the link (#23), only after the
local copies are durable, and a refused delete leaves the files, an event and a successful run."""

from __future__ import annotations

import asyncio
import hashlib
import os
from pathlib import Path

import pytest

from rgse_daemon.controller import Controller
from rgse_daemon.manifest import MODULE_A3, MODULE_A5
from rgse_daemon.procedures.calibration import run_calibration, table1_points
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.retrieval import STAGING_DIRNAME, pull_trace
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.monitor import Monitor
from rgse_daemon.store import LoopState, RunState, Store, archive_root, verify_file
from rgse_daemon.store.archive import ArchiveConflict, ArchiveError
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4

from .conftest import STALE_PERIODS, make_engine

DELETE = 23
ACCESS = 2


def _trace_files(sim: SimulatedKrc4, trace: str) -> dict[str, bytes]:
    """Put a complete set of trace files on the simulated controller (content is opaque to the pull)."""
    folder = sim.share_dir / "TRACE"
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"{trace}_{mod}{ext}" for mod in (MODULE_A3, MODULE_A5) for ext in (".dat", ".r64", ".trc")]
    files = {n: os.urandom(3000 + 17 * i) for i, n in enumerate([*names, f"{trace}_PROG.TXT"])}
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return files


def _on_controller(sim: SimulatedKrc4, trace: str) -> list[str]:
    return sorted(p.name for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith(f"{trace}_"))


async def test_pull_without_share_deletes_over_the_link(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    files = _trace_files(sim, "t1")
    other = _trace_files(sim, "t10")  # a name starting like it: not part of the trace
    deletes = sim.server.counters.by_type[DELETE]
    pulled = await pull_trace(krc, "t1", tmp_path / "run")
    # the pull itself deletes nothing: the caller indexes the files in the store first
    assert pulled.deleted is False and _on_controller(sim, "t1") == sorted(files)
    assert sim.server.counters.by_type[DELETE] == deletes
    assert await pulled.delete_copies() == (True, "deleted over the link")
    assert sim.server.counters.by_type[DELETE] - deletes == len(files)
    assert _on_controller(sim, "t1") == []
    assert _on_controller(sim, "t10") == sorted(other)
    assert sorted(f.path.name for f in pulled.files) == sorted(files)
    for f in pulled.files:  # the local copies are intact: same bytes as the controller had
        assert f.path.read_bytes() == files[f.path.name]
        assert f.sha256 == hashlib.sha256(files[f.path.name]).hexdigest()
        verify_file(f.path, f.sha256, f.size)


async def test_nothing_is_deleted_when_the_local_copy_is_not_archived(
    sim: SimulatedKrc4, krc: Controller, tmp_path: Path
) -> None:
    files = _trace_files(sim, "t2")
    dest = tmp_path / "run"
    dest.mkdir()
    (dest / f"t2_{MODULE_A5}.r64").write_bytes(b"an earlier, different file")  # archiving must not overwrite it
    deletes = sim.server.counters.by_type[DELETE]
    with pytest.raises(ArchiveConflict):
        await pull_trace(krc, "t2", dest)
    assert sim.server.counters.by_type[DELETE] == deletes
    assert _on_controller(sim, "t2") == sorted(files)


async def test_a_copy_that_cannot_be_staged_is_an_archive_error_and_nothing_is_deleted(
    sim: SimulatedKrc4, krc: Controller, tmp_path: Path
) -> None:
    """A disk that cannot take the staged copy (here: the staging directory cannot be made) fails the pull with an
    ArchiveError naming the file (a StoreError, so a run ends as failed with the cause), never a bare OSError."""
    files = _trace_files(sim, "t5")
    dest = tmp_path / "run"
    dest.mkdir()
    (dest / STAGING_DIRNAME).write_bytes(b"")  # a file where the staging directory must go
    deletes = sim.server.counters.by_type[DELETE]
    with pytest.raises(ArchiveError, match=r"\.incoming/t5_.*cannot stage the controller's copy"):
        await pull_trace(krc, "t5", dest)
    assert sim.server.counters.by_type[DELETE] == deletes
    assert _on_controller(sim, "t5") == sorted(files)


async def test_refused_delete_leaves_the_files_and_says_so(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    files = _trace_files(sim, "t3")
    sim.server.faults.refuse_types = {DELETE: ACCESS}
    pulled = await pull_trace(krc, "t3", tmp_path / "run", delete=True)
    assert pulled.deleted is False
    assert pulled.delete_note.startswith(f"left on the controller ({len(files)} of {len(files)} files)")
    assert "(code 2)" in pulled.delete_note
    assert _on_controller(sim, "t3") == sorted(files)
    assert all(f.path.read_bytes() == files[f.path.name] for f in pulled.files)


async def test_one_read_only_file_is_left_the_others_deleted(
    sim: SimulatedKrc4, krc: Controller, tmp_path: Path
) -> None:
    files = _trace_files(sim, "t4")
    locked = f"t4_{MODULE_A3}.trc"
    (sim.share_dir / "TRACE" / locked).chmod(0o444)  # #23 without 'always' refuses a read-only file
    pulled = await pull_trace(krc, "t4", tmp_path / "run", delete=True)
    assert pulled.deleted is False
    assert pulled.delete_note.startswith(f"left on the controller (1 of {len(files)} files)")
    assert locked in pulled.delete_note
    assert _on_controller(sim, "t4") == [locked]
    assert len(pulled.files) == len(files)


def _operator(sim: SimulatedKrc4, engine: RunEngine):
    """On each confirm prompt mount the point's load on the simulated flange, then confirm."""

    def on_event(ev: Event) -> None:
        if ev.kind != "confirm":
            return
        d = ev.data
        sim.mount(campaign_point_payload(d))
        asyncio.get_running_loop().call_soon(engine.confirm, f"mounted point {d['point_index']}")

    return on_event


@pytest.mark.parametrize("refuse", [False, True])
async def test_campaign_without_share(sim, krc, cfg, store: Store, tmp_path: Path, refuse: bool) -> None:
    """A whole run with ``share_dir = None``: the copies go over #23; a refused delete is an event, not a failure."""
    engine = RunEngine(krc, checker=make_engine(krc, cfg).checker, monitor=Monitor(krc, stale_periods=STALE_PERIODS),
                       share_dir=None)
    engine.subscribe(_operator(sim, engine))
    if refuse:
        sim.server.faults.refuse_types = {DELETE: ACCESS}
    settings = RunSettings.from_config(cfg, loops=1, trace_samples=400, warmup_cycles=1, payload_lever_max_m=1.0)
    points = table1_points(n_bodies=(0, 1, 3, 5), torque_levers_a5_m=(0.761, 1.261))  # the fewest that fit
    summary = await run_calibration(engine, store, cfg, points=points, settings=settings)
    assert summary is not None
    run = await store.get_run(summary["run_id"])
    assert run.state == RunState.COMPLETED
    assert all(lp.state == LoopState.ARCHIVED for lp in await store.loops(run.id))
    files = await store.trace_files(run.id)
    assert len(files) >= 4 * len(points)
    for f in files:
        verify_file(archive_root(cfg.paths.data_dir) / f.path, f.sha256, f.size_bytes)
    left_events = [e for e in await store.events(run_id=run.id) if e.kind == "trace_left_on_controller"]
    traces = [p.name for p in (sim.share_dir / "TRACE").iterdir() if p.suffix.lower() != ".xml"]
    if refuse:
        assert len(left_events) == len(points) and all("code 2" in e.message for e in left_events)
        assert len(traces) == len(files)
    else:
        assert left_events == [] and traces == []
