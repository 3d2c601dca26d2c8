"""Common test fixtures: the paper's tables shipped in ``data/paper/``, and a guard that fails tests leaking asyncio
tasks."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from tests.support.mqtt import MosquittoProcess

pytest_plugins = ["pytester"]

REPO = Path(__file__).resolve().parent.parent
PAPER = REPO / "data" / "paper"


@pytest.fixture
def paper_dir() -> Path:
    if not PAPER.is_dir():
        pytest.fail(f"the paper's tables are expected at {PAPER} (they ship with the checkout)")
    return PAPER


@pytest.fixture(autouse=True)
async def _fail_on_leaked_tasks():
    """A test (with its fixtures) must not leave tasks running on the loop: they would outlive their owner."""
    before = asyncio.all_tasks()
    yield
    for _ in range(3):  # let cancelled tasks and done-callbacks settle
        await asyncio.sleep(0)
    current = asyncio.current_task()
    leaked = [t for t in asyncio.all_tasks() - before if t is not current and not t.done()]
    if leaked:
        for t in leaked:
            t.cancel()
        await asyncio.gather(*leaked, return_exceptions=True)
        pytest.fail(f"test leaked {len(leaked)} asyncio task(s): {[t.get_name() for t in leaked]}")


@pytest.fixture
async def private_broker(tmp_path: Path) -> AsyncIterator[MosquittoProcess]:
    """A Mosquitto of this test alone, with persistence: the only kind of broker a test may restart."""
    broker = MosquittoProcess(tmp_path / "mosquitto")
    await broker.start()
    try:
        yield broker
    finally:
        await broker.stop()
