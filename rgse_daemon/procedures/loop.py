"""One measurement loop, shared by the measurement run and the calibration campaign.

A *loop* (paper §2.4.4, Fig. 23/24) is: brake-release move (A3 and A5 rotate by φ' and back) → settle → trace of
``trace_samples`` at ``trace_period_s`` → pull the trace files, verify and archive them → record the loop. Its
timing is split into **robot time** (program start → ``#P_END`` as the controller reports it, the settling wait and
trace start → ``#T_END``) and **daemon overhead** (pulling, archiving, recording), both in the loop event. What the
loop records it yields as run documents (:mod:`~rgse_daemon.procedures.documents`).
"""

from __future__ import annotations

import time
from collections.abc import Generator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, render_program, run_checked
from rgse_daemon.procedures.retrieval import PulledTrace
from rgse_daemon.procedures.settings import RunSettings


@dataclass
class LoopTiming:
    """Robot time (motion, settling, recording: what the controller takes) and daemon overhead (pull, archive,
    store), both in s."""

    motion_s: float = 0.0
    settle_s: float = 0.0
    record_s: float = 0.0
    pull_s: float = 0.0
    store_s: float = 0.0

    @property
    def robot_s(self) -> float:
        return self.motion_s + self.settle_s + self.record_s

    @property
    def overhead_s(self) -> float:
        return self.pull_s + self.store_s

    def to_json(self) -> dict[str, float]:
        return {"robot_s": self.robot_s, "overhead_s": self.overhead_s, "motion_s": self.motion_s,
                "settle_s": self.settle_s, "record_s": self.record_s, "pull_s": self.pull_s, "store_s": self.store_s}


@dataclass
class LoopOutcome:
    trace: str
    timing: LoopTiming
    sha256s: tuple[str, ...] = ()
    deleted: bool = False
    delete_note: str = ""


def loop(index: int, trace: str, run: d.RunContext, s: RunSettings, *, point_index: int | None = None,
         trace_config: str = TRACE_CONFIG_NAME) -> Generator[m.Msg, Any, LoopOutcome]:
    """One measurement loop (see the module docstring): loop ``index`` of the run, its trace named ``trace``,
    recorded with the trace configuration ``trace_config``. The brake-release move turns A3 and A5 about
    ``s.meas_pose_deg`` (a CoG pose of the mass-properties run passes its own pose there)."""
    timing = LoopTiming()
    snap = yield m.ReadState()
    brake = yield from render_program("rgse_brake_release", s, snap)
    yield d.LoopStarted(index, trace, _now(), point_index)
    timing.motion_s = (yield from run_checked(brake, s)) or 0.0
    t0 = time.monotonic()
    yield m.Sleep(s.settle_s)
    timing.settle_s = time.monotonic() - t0
    yield d.LoopRecording(index, robot_end_utc=_now(), record_start_utc=_now())
    t0 = time.monotonic()
    yield m.TraceStart(trace, trace_config)
    yield m.TraceWait(s.trace_timeout_s)
    timing.record_s = time.monotonic() - t0
    yield d.LoopRecorded(index, _now())
    pulled: PulledTrace | None = yield m.Pull(trace, run.run_dir, s.trace_timeout_s)
    outcome = LoopOutcome(trace, timing)
    if pulled is None:  # dry run
        return outcome
    timing.pull_s = pulled.duration_s
    t0 = time.monotonic()
    yield d.TraceArchived(index, trace, pulled.files, False)  # indexed in the store ...
    deleted, note = yield m.DeleteTraceCopies(pulled)  # ... and only then may the controller's copies go
    if not deleted:  # recorded again (indexing is idempotent), now with the note why the copies stay
        yield d.TraceArchived(index, trace, pulled.files, False, note)
    timing.store_s = time.monotonic() - t0
    outcome.sha256s = pulled.sha256s
    outcome.deleted = deleted
    outcome.delete_note = note
    return outcome


def _now() -> datetime:
    return datetime.now(UTC)
