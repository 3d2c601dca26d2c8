"""One measurement loop, shared by the measurement run and the calibration campaign.

A *loop* (paper §2.4.4, Fig. 23/24) is: brake-release move (A3 and A5 rotate by φ' and back) → settle → trace of
``trace_samples`` at ``trace_period_s`` → pull the trace files, verify and archive them → record the loop. A series
of loops takes the file work off the robot's path (``previous``/``defer`` of :func:`loop`, :func:`collect` for the
last one): loop N's pull, its archive, index and delete, and the check and push of loop N+2's move run while loop
N+1's trace records (the robot stands still, no program runs: the file-window rule), so that between two recordings
only the move and its handshakes remain. Its timing is split into **robot time** (program start → ``#P_END`` as the
controller reports it, the settling wait and trace start → ``#T_END``) and **daemon overhead** (pulling, archiving,
recording, work that outlasts the trace), both in the loop event. What the loop records it yields as run documents
(:mod:`~rgse_daemon.procedures.documents`).
"""

from __future__ import annotations

import time
from collections.abc import Generator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import WAIT_POLL_S
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, render_program, run_checked
from rgse_daemon.procedures.settings import RunSettings


@dataclass
class LoopTiming:
    """Robot time (motion, settling, recording: what the controller takes) and daemon overhead (pull, archive,
    store), both in s. ``pull_s`` is the time the plan waited for the pull; ``pull_total_s`` the pull's own time
    (list, read, verify, archive), which the next loop's settling and recording hide when it overlapped them."""

    motion_s: float = 0.0
    settle_s: float = 0.0
    record_s: float = 0.0
    pull_s: float = 0.0
    store_s: float = 0.0
    pull_total_s: float = 0.0
    predict_s: float = 0.0
    """The stop rule's interim budget after this loop (on the robot's path)."""
    render_s: float = 0.0
    """Rendering the next loop's move beyond the settling it overlaps (on the robot's path)."""
    overrun_s: float = 0.0
    """The work done while the trace recorded (the previous loop's pull, archive, index and delete; the next move's
    check and push) past the trace's end (on the robot's path; its recording then counts as its nominal length)."""

    @property
    def robot_s(self) -> float:
        return self.motion_s + self.settle_s + self.record_s

    @property
    def overhead_s(self) -> float:
        return self.pull_s + self.store_s + self.predict_s + self.render_s + self.overrun_s

    def to_json(self) -> dict[str, float]:
        return {"robot_s": self.robot_s, "overhead_s": self.overhead_s, "motion_s": self.motion_s,
                "settle_s": self.settle_s, "record_s": self.record_s, "pull_s": self.pull_s, "store_s": self.store_s,
                "pull_total_s": self.pull_total_s, "predict_s": self.predict_s, "render_s": self.render_s,
                "overrun_s": self.overrun_s}


@dataclass
class LoopOutcome:
    trace: str
    timing: LoopTiming
    sha256s: tuple[str, ...] = ()
    deleted: bool = False
    delete_note: str = ""
    index: int = 0
    pending: bool = False
    """Recorded, its files not yet pulled: :func:`collect` (or the next loop's ``previous``) pulls them."""
    next_program: Any = None
    """The next loop's brake-release move, rendered while this loop settled, from the axes ``next_axes_deg``."""
    next_axes_deg: tuple[float, ...] | None = None


#: How often the engine polls $TRACE.STATE (s): a TraceWait that returned within two polls found the trace ended.
TRACE_POLL_S = WAIT_POLL_S

#: A move rendered ahead is used only if the axes at the next loop's start are within this of the ones it was
#: rendered from (deg; the monitor's "has moved" tolerance); else it is rendered again. The push checks it against
#: the live snapshot either way.
RENDER_AHEAD_TOLERANCE_DEG = 0.01


def loop(index: int, trace: str, run: d.RunContext, s: RunSettings, *, point_index: int | None = None,
         trace_config: str = TRACE_CONFIG_NAME, previous: LoopOutcome | None = None,
         defer: bool = False) -> Generator[m.Msg, Any, LoopOutcome]:
    """One measurement loop (see the module docstring): loop ``index`` of the run, its trace named ``trace``,
    recorded with the trace configuration ``trace_config``. The brake-release move turns A3 and A5 about
    ``s.meas_pose_deg`` (a CoG pose of the mass-properties run passes its own pose there).

    ``previous``: a loop of the same series whose files are still on the controller (``pending``): its pull starts
    once this loop's trace has started, runs while it records, and is archived, indexed and only then deleted on the
    controller before the trace is awaited. ``defer``: leave this loop's own files for the next loop (or
    :func:`collect`); its outcome is then ``pending``, and the next loop's move, rendered while this loop settles, is
    checked and pushed while it records (the next loop's push then finds it on the controller: the engine checks it
    again and sends no byte)."""
    timing = LoopTiming()
    snap = yield m.ReadState()
    brake = _ahead(previous, snap)
    if brake is None:
        brake = yield from render_program("rgse_brake_release", s, snap)
    yield d.LoopStarted(index, trace, _now(), point_index)
    timing.motion_s = (yield from run_checked(brake, s)) or 0.0
    t0 = time.monotonic()
    still = (yield m.ReadState()) if defer else None  # where the robot stands for the next loop's move
    next_program = None
    if still is not None:  # render the next loop's move while this one settles (CPU; the robot stands still)
        next_program = yield from render_program("rgse_brake_release", s, still)
    busy_s = time.monotonic() - t0
    yield m.Sleep(max(0.0, s.settle_s - busy_s))
    timing.render_s = max(0.0, busy_s - s.settle_s)
    timing.settle_s = time.monotonic() - t0 - timing.render_s
    yield d.LoopRecording(index, robot_end_utc=_now(), record_start_utc=_now())
    t0 = time.monotonic()
    yield m.TraceStart(trace, trace_config)
    # while the trace records (the robot stands still, no program runs): file work, one operation at a time, after
    # the trace's start (a file read blocks the controller's other requests, the trace's start included)
    if previous is not None and previous.pending:
        yield m.PullStart(previous.trace, run.run_dir)
    if next_program is not None:
        yield m.Push(next_program)  # checked against the live state; after the pull (the engine waits for it)
    if previous is not None and previous.pending:
        yield from collect(previous, run, s, started=True)  # archived, indexed, only then deleted
        previous.timing.pull_s = previous.timing.store_s = 0.0  # hidden by this recording; past it: overrun_s
    waited_s = (yield m.TraceWait(s.trace_timeout_s)) or 0.0
    elapsed_s = time.monotonic() - t0
    if waited_s > 2 * TRACE_POLL_S or elapsed_s <= s.trace_wall_s:  # the trace ended after the work: its own time
        timing.record_s = elapsed_s
    else:  # the work outlasted the trace: the recording counts as its nominal length, the rest is overhead
        timing.record_s = s.trace_wall_s
        timing.overrun_s = elapsed_s - s.trace_wall_s
    yield d.LoopRecorded(index, _now())
    outcome = LoopOutcome(trace, timing, index=index, pending=True, next_program=next_program,
                          next_axes_deg=None if still is None else still.axes_deg)
    if not defer:
        yield from collect(outcome, run, s)
    return outcome


def collect(outcome: LoopOutcome, run: d.RunContext, s: RunSettings, *,
            started: bool = False) -> Generator[m.Msg, Any, LoopOutcome]:
    """Pull a ``pending`` loop's files (``started``: join the background pull :class:`~messages.PullStart` began),
    archive them, index them in the store and only then delete the controller's copies."""
    if not outcome.pending:
        return outcome
    timing = outcome.timing
    if started:
        joined = yield m.PullJoin(outcome.trace)
        pulled, timing.pull_s, _ = joined if joined is not None else (None, 0.0, 0.0)
        if pulled is not None:
            timing.pull_total_s = pulled.duration_s  # the pull's own time, as it overlapped the next loop
    else:
        pulled = yield m.Pull(outcome.trace, run.run_dir, s.trace_timeout_s)
        if pulled is not None:
            timing.pull_s = timing.pull_total_s = pulled.duration_s
    outcome.pending = False
    if pulled is None:  # dry run
        return outcome
    index, trace = outcome.index, outcome.trace
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


def _ahead(previous: LoopOutcome | None, snap: Any) -> Any:
    """The move the previous loop rendered ahead, if the robot still stands where it was rendered from."""
    if previous is None or previous.next_program is None or previous.next_axes_deg is None:
        return None
    axes = getattr(snap, "axes_deg", None)
    if axes is None or len(axes) != len(previous.next_axes_deg):
        return None
    if max(abs(a - b) for a, b in zip(axes, previous.next_axes_deg, strict=True)) > RENDER_AHEAD_TOLERANCE_DEG:
        return None
    return previous.next_program


def _now() -> datetime:
    return datetime.now(UTC)
