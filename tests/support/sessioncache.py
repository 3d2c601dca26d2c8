"""A session fixture's document computed once per test run, not once per xdist worker and conftest.

``make test`` runs two workers; each has its own session, so a session-scoped fixture runs once in each worker that
needs it, and two conftests that fit the same calibration (tests/app, tests/faults) each fit it again. A
calibration of the simulated robot costs 16-18 s of CPU; :func:`once_per_run` computes a JSON document once per
run, in whichever worker asks first, and hands every later asker (any worker, any conftest) the same document from
a file in the run's own temporary directory (``/tmp/pytest-of-USER/pytest-N``, never another run's). A worker that
asks while another computes it waits on a file lock instead of computing it beside it."""

from __future__ import annotations

import fcntl
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

#: The longest a worker waits for another to finish a document (s): the fits take ~20 s on a quiet machine.
LOCK_WAIT_S = 900.0


def run_dir(factory: pytest.TempPathFactory) -> Path:
    """The directory all workers of this run share: the parent of a worker's base temp under xdist (its
    ``popen-gwN`` lies in the run's ``pytest-N``), the base temp itself in a run without workers."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def once_per_run(factory: pytest.TempPathFactory, name: str, make: Callable[[Path], dict[str, Any]]) -> dict[str, Any]:
    """``make(directory)``'s document (JSON-able), computed once per run under ``name``: every caller gets the
    document as read back from the run's file, so all get the same one."""
    root = run_dir(factory)
    path = root / f"{name}.json"
    with (root / f"{name}.lock").open("w") as lock:
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    pytest.fail(f"{name}: another worker held {root / name}.lock for more than {LOCK_WAIT_S:.0f} s")
                time.sleep(0.2)
        try:
            if not path.is_file():
                doc = make(factory.mktemp(name))
                tmp = path.with_suffix(".part")
                tmp.write_text(json.dumps(doc), encoding="utf-8")
                tmp.replace(path)
            return json.loads(path.read_text(encoding="utf-8"))
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
