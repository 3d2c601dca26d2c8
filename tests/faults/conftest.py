"""Fixtures of the fault suite: the simulated KR C4 in its own OS process (a test can SIGSTOP it like a stalled
controller) or on the test's loop, a calibration of the simulated robot, and a PostgreSQL schema of the test's own."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import psycopg
import pytest

from rgse_daemon.krl.render import globals_dat_text
from simulators.krc4.process import SimProcess
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import fit_sim_calibration
from tests.support.faults import PG_URL
from tests.support.sessioncache import once_per_run


@pytest.fixture
async def sim_proc(tmp_path: Path) -> AsyncIterator[SimProcess]:
    """The simulated KR C4 in a child process at 5× real time: programs last seconds, long enough to kill or stall
    something in the middle of a move."""
    proc = SimProcess(tmp_path / "share", seed=11, time_scale=5.0, latency_s=0.0, globals_dat=globals_dat_text())
    await asyncio.to_thread(proc.start)
    try:
        yield proc
    finally:
        await asyncio.to_thread(proc.stop)


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    """The simulated KR C4 on this test's event loop (its server's faults are set directly)."""
    async with SimulatedKrc4(tmp_path / "share", seed=7, time_scale=100.0, latency_s=0.0) as s:
        s.install_globals(globals_dat_text())
        yield s


@pytest.fixture(scope="session")
def calibration_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """CAL.json of the simulated robot, fitted once per run (tests/app's is the same document)."""
    return once_per_run(tmp_path_factory, "sim-calibration", fit_sim_calibration)


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A store URL on the real PostgreSQL with a schema of this test alone (dropped afterwards)."""
    schema = f"rgse_fault_{uuid.uuid4().hex[:12]}"
    try:
        admin = psycopg.connect(PG_URL, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(f"PostgreSQL at {PG_URL} is required (make test runs scripts/ensure-services.sh): {exc}")
    with admin:
        admin.execute(f"CREATE SCHEMA {schema}")
        try:
            yield f"{PG_URL}{'&' if '?' in PG_URL else '?'}options=-csearch_path%3D{schema}"
        finally:
            admin.execute(f"DROP SCHEMA {schema} CASCADE")
