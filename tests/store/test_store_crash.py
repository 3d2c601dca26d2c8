"""Crash semantics for real: a process that is recording a run is killed with SIGKILL, then the store is reopened."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rgse_daemon.store import LoopState, RunState, StoreConflict, archive_root, verify_file
from rgse_daemon.store.repository import Repository

from .conftest import ROBOT

# The child does what the daemon does during a measurement, then dies between two steps: loop 0 is archived and
# indexed, loop 1 is recording, and an event is written inside a transaction that never commits.
CHILD = textwrap.dedent(
    """
    import json, sys, time
    from pathlib import Path
    from rgse_daemon.store import Repository, archive_file, archive_root, relative_path

    url, data_dir, src = json.loads(sys.argv[1])
    url, data_dir, src = url, Path(data_dir), Path(src)
    repo = Repository.open(url, data_dir)
    run = repo.create_run("measurement", "{robot}", {{"loops": 2}}, run_id="crash-run")
    repo.set_run_state(run.id, "running")
    repo.add_loop(run.id, 0, "dut_l01")
    repo.update_loop(run.id, 0, state="recording")
    root = archive_root(data_dir)
    archived = archive_file(src, root / run.directory, expected_size=src.stat().st_size)
    repo.add_trace_file(run.id, relative_path(archived.path, root), archived.sha256, archived.size, loop_index=0)
    repo.update_loop(run.id, 0, state="archived")
    repo.add_loop(run.id, 1, "dut_l02")
    repo.update_loop(run.id, 1, state="recording")
    db = repo._db  # a write that is in flight when the power goes
    db.execute(db.dialect.begin)
    db.execute("INSERT INTO events (time_utc, level, kind, message) VALUES (?, 'info', 'uncommitted', 'lost')",
               ("2024-05-01T12:00:00.000000Z",))
    print("READY", archived.sha256, flush=True)
    time.sleep(120)
    """
).format(robot=ROBOT)


def _run_child_until_ready(tmp_path: Path, store_url: str | None, data_dir: Path, src: Path) -> tuple[int, str]:
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    proc = subprocess.Popen(
        [sys.executable, str(script), json.dumps([store_url, str(data_dir), str(src)])],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 60)
        line = proc.stdout.readline() if ready else ""  # type: ignore[union-attr]
        if not line.startswith("READY"):
            proc.kill()
            _, err = proc.communicate(timeout=30)
            pytest.fail(f"child did not get ready: {line!r}\n{err}")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        proc.stdout.close()  # type: ignore[union-attr]
        proc.stderr.close()  # type: ignore[union-attr]
    assert proc.returncode == -signal.SIGKILL
    return proc.pid, line.split()[1]


def test_a_run_killed_mid_measurement_is_recovered_and_reprocessable(
    tmp_path: Path, store_url: str | None, data_dir: Path
) -> None:
    src = tmp_path / "share" / "dut_l01_NextGenDrive#3.r64"
    src.parent.mkdir()
    src.write_bytes(os.urandom(64_000))

    _, sha = _run_child_until_ready(tmp_path, store_url, data_dir, src)

    with Repository.open(store_url, data_dir) as repo:
        (recovered,) = repo.recover_interrupted(robot=ROBOT)
        assert (recovered.id, recovered.state) == ("crash-run", RunState.INTERRUPTED)
        assert [(lp.index, lp.state) for lp in repo.loops("crash-run")] == [
            (0, LoopState.ARCHIVED),
            (1, LoopState.INTERRUPTED),
        ]
        assert [e.kind for e in repo.events()] == ["run_interrupted"]  # the uncommitted write is gone

        # The raw file is kept, intact, where the index says.
        (tf,) = repo.trace_files("crash-run")
        assert tf.sha256 == sha
        verify_file(archive_root(data_dir) / tf.path, tf.sha256, tf.size_bytes)
        assert (archive_root(data_dir) / tf.path).read_bytes() == src.read_bytes()

        # Re-processing from the raw files yields a result that names them; nothing else can be a result input.
        with pytest.raises(StoreConflict):
            repo.record_result("crash-run", {"mass_kg": 1.0}, ["0" * 64])
        result = repo.record_result("crash-run", {"mass_kg": 107.65, "loops": 1}, [tf.sha256])
        assert result.trace_sha256 == (sha,)
        assert repo.set_run_state("crash-run", "completed").state == RunState.COMPLETED
