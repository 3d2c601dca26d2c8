"""Common test fixtures: the paper's tables shipped in ``data/paper/``, a guard that fails tests leaking asyncio
tasks, and the order in which ``make test``'s workers get the tests (the whole stories first: support/schedule.py)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from tests.support.mqtt import MosquittoProcess
from tests.support.schedule import DEFAULT_EXPECTED_S, stories_first

pytest_plugins = ["pytester"]

REPO = Path(__file__).resolve().parent.parent
PAPER = REPO / "data" / "paper"


@pytest.hookimpl(trylast=True)  # after -k/-m have deselected: the shares are cut from what runs
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under pytest-xdist (``make test``): the tests marked ``slow`` start first, spread over the workers."""
    workers = int(getattr(config, "workerinput", {}).get("workercount", 1))
    items[:] = stories_first(items, workers, _expected_s)


def _expected_s(item: pytest.Item) -> float | None:
    """A ``slow`` test's wall time on a quiet 2-core machine under ``make test`` (s), where the scheduler puts it
    (not a check of it); None for the other tests."""
    marker = item.get_closest_marker("slow")
    return None if marker is None else float(marker.kwargs.get("expected_s", DEFAULT_EXPECTED_S))


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
