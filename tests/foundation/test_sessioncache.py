"""tests/support/sessioncache.py: a session fixture's document computed once per run, the same for every asker."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path
from typing import Any

import pytest

from tests.support.sessioncache import once_per_run, run_dir


def test_the_document_is_made_once_and_every_asker_gets_it_as_read_back(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    name = f"doc-{uuid.uuid4().hex[:8]}"
    made: list[Path] = []

    def make(directory: Path) -> dict[str, Any]:
        made.append(directory)
        return {"x": 0.1, "rows": [1, 2], "n": None}

    first = once_per_run(tmp_path_factory, name, make)
    second = once_per_run(tmp_path_factory, name, make)
    assert first == second == {"x": 0.1, "rows": [1, 2], "n": None}
    assert first is not second  # each its own copy: one asker's change cannot reach another's
    assert len(made) == 1 and made[0].is_dir()
    assert (run_dir(tmp_path_factory) / f"{name}.json").is_file()


def test_an_asker_waits_for_the_one_making_it(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Two askers at once (two workers): the second waits on the lock and reads the first one's document."""
    name = f"doc-{uuid.uuid4().hex[:8]}"
    started, release = threading.Event(), threading.Event()
    calls: list[str] = []

    def slow_make(directory: Path) -> dict[str, Any]:
        calls.append("slow")
        started.set()
        assert release.wait(10)
        return {"by": "slow"}

    results: list[dict[str, Any]] = []
    first = threading.Thread(target=lambda: results.append(once_per_run(tmp_path_factory, name, slow_make)))
    first.start()
    assert started.wait(10)
    second = threading.Thread(target=lambda: results.append(
        once_per_run(tmp_path_factory, name, lambda d: calls.append("other") or {"by": "other"})))
    second.start()
    second.join(0.5)
    assert second.is_alive()  # held by the lock while the first makes the document
    release.set()
    first.join(10)
    second.join(10)
    assert calls == ["slow"] and results == [{"by": "slow"}, {"by": "slow"}]
