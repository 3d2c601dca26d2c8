"""Finding 5 of issue #12: store failures.

* one dropped PostgreSQL connection (the backend terminated with ``pg_terminate_backend``) is retried, not fatal;
* disk full (a 3 MB tmpfs holding the archive and the SQLite store, filled during a measurement's recording): the
  run fails, its end is recorded as ``failed`` once there is room again, and archive, store and controller stay
  consistent — every trace file is still on the controller or archived *and* indexed with its hash; none is deleted
  on the controller before the store indexed it.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psycopg
import pytest

from rgse_daemon.errors import RgseError
from rgse_daemon.store import RunState, Store, archive_root
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.faults import PG_URL


async def test_one_dropped_postgresql_connection_is_retried(pg_url: str, tmp_path: Path) -> None:
    app = f"rgse-fault-{uuid.uuid4().hex[:8]}"
    url = f"{pg_url}&application_name={app}"
    async with await Store.open(url, tmp_path) as store:
        run = await store.create_run("measurement", "R1", {"x": 1})
        with psycopg.connect(PG_URL, autocommit=True, connect_timeout=5) as admin:
            killed = admin.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE application_name = %s",
                                   (app,)).fetchall()
        assert killed == [(True,)]
        rec = await store.set_run_state(run.id, "running")  # on a new connection, without an error
        assert rec.state == RunState.RUNNING
        assert (await store.get_run(run.id)).state == RunState.RUNNING


@contextlib.contextmanager
def tmpfs(path: Path, size: str) -> Iterator[Path]:
    """A small tmpfs at ``path`` (needs root: a clear failure otherwise, never a skip)."""
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True,
                       text=True)
    assert r.returncode == 0, f"the disk-full test needs root to mount a tmpfs at {path}: {r.stderr.strip()}"
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)


def _fill(path: Path) -> Path:
    """Fill the disk of ``path`` up to the last byte. Unbuffered: a buffered file's close would flush what the full
    disk did not take and raise ENOSPC (how much is left over depends on the sizes of the run's files)."""
    filler = path / "filler"
    with open(filler, "wb", buffering=0) as f, contextlib.suppress(OSError):
        while True:  # a write the disk takes only in part returns less; the next one raises ENOSPC
            f.write(b"\0" * 65536)
    return filler


async def _indexed(daemon: Any) -> int:
    """How many trace files of the daemon's current run the store has indexed."""
    run_id = daemon.engine.run_id if daemon.engine else None
    if daemon.store is None or run_id is None:
        return 0
    return len(await daemon.store.trace_files(run_id))


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.mark.parametrize("full", ["archive and store", "store only"])
async def test_disk_full_during_a_measurement_keeps_archive_store_and_controller_consistent(
        sim: SimulatedKrc4, calibration_doc: dict[str, Any], tmp_path: Path, full: str) -> None:
    with tmpfs(tmp_path / "small", "3m") as small:
        if full == "archive and store":
            cfg = daemon_config(small / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=3)
        else:  # the archive has room, the store's disk is full: the pull archives, the index fails
            cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=3)
            cfg = cfg.model_copy(update={"store": cfg.store.model_copy(
                update={"url": f"sqlite:///{small / 'rgse.sqlite3'}"})})
        await seed_calibration(cfg, calibration_doc)
        async with running_daemon(cfg) as rd:
            task = await rd.daemon.start_measurement()
            # the first loop's files archived and indexed while there is room, so that what was indexed before the
            # disk filled is there to check; then the next loop's recording
            async with asyncio.timeout(120):
                while not await _indexed(rd.daemon):  # noqa: ASYNC110 - a store query, no event to await
                    await asyncio.sleep(0.05)
            while sim.store.read("$TRACE.STATE").strip().upper() not in ("#TRIGGERED", "#T_WRITING"):  # noqa: ASYNC110
                await asyncio.sleep(0.005)
            if full == "store only":  # fill the store's disk in the middle of the pull: archived, not indexed
                sim.server.faults.extra_latency_s = 0.2
                runs = cfg.paths.data_dir / "archive" / "runs"
                first_loop = await _indexed(rd.daemon)  # archived and indexed
                while len([p for p in runs.glob("*/dut_*") if not p.name.startswith(".")]) <= first_loop:  # noqa: ASYNC110
                    await asyncio.sleep(0.005)
                sim.server.faults.extra_latency_s = 0.0
            filler = _fill(small)  # the disk is full while the trace is written and pulled
            try:
                while not task.done() and not (rd.daemon.engine and rd.daemon.engine.state == "failed"):  # noqa: ASYNC110
                    await asyncio.sleep(0.05)
                await asyncio.sleep(1.0)  # the run's end is retried against the full disk meanwhile
            finally:
                filler.unlink()
            try:
                await asyncio.wait_for(asyncio.shield(task), 60)
                raise AssertionError("the run should have failed on the full disk")
            except RgseError:
                pass  # expected: the run fails on the full disk; what it left behind is checked below
        run_id = rd.daemon.engine.run_id if rd.daemon.engine else None
        assert run_id is not None
        async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
            run = await store.get_run(run_id)
            indexed = {f.path: f for f in await store.trace_files(run_id)}
            loops = await store.loops(run_id)
        root = archive_root(cfg.paths.data_dir)
        on_controller = {p.name for p in (sim.share_dir / "TRACE").iterdir()}
        archived = {p.name: p for p in (root / run.directory).glob("*") if p.is_file() and not p.name.startswith(".")}
        if full == "store only":  # the case of the finding: files archived, then the index failed
            assert archived and len(indexed) < len(archived), (sorted(archived), sorted(indexed))
        assert indexed  # the first loop's (the loop below checks something)
        for f in indexed.values():  # everything indexed is archived, intact
            assert _sha(root / f.path) == f.sha256
        for lp in loops:
            names = {n for n in on_controller | set(archived) if n.startswith(f"{lp.trace_name}_")}
            for name in names:
                rel = f"{run.directory}/{name}"
                # not deleted on the controller unless archived and indexed
                assert name in on_controller or rel in indexed, (name, lp.state)
        assert run.state == RunState.FAILED, (run.state, run.detail)  # recorded once the disk had room again
