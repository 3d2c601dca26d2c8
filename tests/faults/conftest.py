"""Fixtures of the fault suite: the daemon tests' fixtures (simulated KR C4, private broker, calibration) and the
simulated KR C4 in its own OS process, which a test can SIGSTOP like a stalled controller."""

from __future__ import annotations

import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

_HERE = Path(__file__).resolve().parent
for p in (str(_HERE.parents[1]), str(_HERE.parent / "app"), str(_HERE)):
    if p not in sys.path:
        sys.path.insert(0, p)

from rgse_daemon.krl.render import globals_dat_text  # noqa: E402
from simulators.krc4.process import SimProcess  # noqa: E402
from tests.app.conftest import calibration_doc, private_broker, sim  # noqa: E402, F401  (fixtures)
from tests.store.conftest import pg_schemas, pg_url  # noqa: E402, F401  (fixtures)


@pytest.fixture
async def sim_proc(tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[SimProcess]:
    """The simulated KR C4 in a child process at ``time_scale`` (default 5: programs last seconds, long enough to
    kill or stall something in the middle of a move)."""
    import asyncio

    scale = getattr(request, "param", 5.0)
    proc = SimProcess(tmp_path / "share", seed=11, time_scale=scale, latency_s=0.0, globals_dat=globals_dat_text())
    await asyncio.to_thread(proc.start)
    try:
        yield proc
    finally:
        await asyncio.to_thread(proc.stop)
