"""What the daemon does on every connect to the controller, before it admits a run, and when a stop fails.

1. **Sweep** (:func:`~rgse_daemon.safety.makesafe.sweep`): a ``RGSE_*`` program a previous daemon (SIGKILL, power
   loss) or a previous link left active, stopped or reset is stopped and deselected, a running trace stopped; why is
   recorded (store event ``left_running_stopped``, log, MQTT alarm). A stop that cannot be confirmed latches
   (:mod:`rgse_daemon.safety.latch`).
2. **Interrupted runs finish their job** (:meth:`Recovery.recover_runs`), once per interruption: every loop's trace
   files still on the controller are pulled and archived, archived files the store lacks are indexed (with their
   SHA-256; a file also still on the controller must match it), the controller copies are deleted only after the
   store indexed them, loops are marked consistently (``recorded`` with a complete indexed set → ``archived``;
   ``pending`` → ``interrupted``; an interrupted loop keeps its state: its trace may have been cut short), an event
   ``run_recovered`` says what was done, and the run's MQTT topic is told: a measurement gets its final result
   ``{"state": "interrupted", ...}`` (retained, through the durable outbox); a calibration campaign, which the daemon
   continues, an alarm and a progress message.

   A run that *ended* (failed, aborted) with a loop ``recorded`` but not archived — a pull that failed on a full
   disk or a lost link — is reconciled the same way at the next connect (its state and result stay; a loop whose
   trace is neither on the controller nor complete here becomes ``failed``).

:meth:`Recovery.on_unsafe` is the interlock monitor's hook for a stop not confirmed by its deadline: latch, alarm,
event.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rgse_daemon.aio import within
from rgse_daemon.config import Config
from rgse_daemon.errors import RgseError
from rgse_daemon.io.topics import Topics
from rgse_daemon.krc import KrcController
from rgse_daemon.procedures.retrieval import REQUIRED_SUFFIXES, TRACE_DIR, archived_not_indexed, base_name, pull_trace
from rgse_daemon.safety.latch import CLEAR_HINT, SafetyLatch
from rgse_daemon.safety.makesafe import STEP_TIMEOUT_S, StopReport, sweep
from rgse_daemon.safety.monitor import InterlockTrip
from rgse_daemon.store import LoopState, RunKind, RunRecord, RunState, Store, archive_root, relative_path
from rgse_daemon.store.archive import ArchivedFile
from rgse_daemon.store.errors import ArchiveError

log = logging.getLogger(__name__)

#: Event kind that marks an interruption as recovered (its ``data.ended_utc`` names which interruption).
RECOVERED = "run_recovered"

#: How long recovery waits for a stopped trace to be written (s).
TRACE_WRITTEN_S = 30.0

Alarm = Callable[[dict[str, Any]], None]


def _ended(run: RunRecord) -> str:
    return run.ended_utc.isoformat() if run.ended_utc is not None else ""


class Recovery:
    """The daemon's connect-time sweep and run recovery, and its hook for an unconfirmed stop."""

    def __init__(self, cfg: Config, store: Store, latch: SafetyLatch, alarm: Alarm,
                 progress: Callable[[str, dict[str, Any]], None] | None = None,
                 outbox_added: Callable[[], None] | None = None) -> None:
        self.cfg = cfg
        self.store = store
        self.latch = latch
        self.alarm = alarm
        self.progress = progress
        self.outbox_added = outbox_added

    async def _event(self, level: str, kind: str, message: str, run_id: str | None = None,
                     data: dict[str, Any] | None = None) -> None:
        try:
            await self.store.add_event(level, kind, message, run_id=run_id, data=data)
        except RgseError as exc:  # the log has it; the store may be the thing that is broken
            log.error("event %s not stored: %s", kind, exc)

    # --- 1. the sweep -------------------------------------------------------------------------------------------
    async def on_connect(self, krc: KrcController) -> None:
        """Sweep, then recover interrupted runs; the daemon admits runs only after this returned."""
        report = await sweep(krc)
        if report.acted or not report.confirmed:
            message = f"found on the controller at connect: {report.describe()}"
            level = "warning" if report.confirmed else "critical"
            log.log(logging.WARNING if report.confirmed else logging.CRITICAL, "%s", message)
            await self._event(level, "left_running_stopped", message, data=_report_json(report))
            self.alarm({"kind": "left_running_stopped", "message": message, **_report_json(report)})
        if not report.confirmed:
            await self._latch(f"stop at connect not confirmed: {report.describe()}", report)
            return
        try:
            await self._trace_written(krc)
            await self.recover_runs(krc)
        except (RgseError, TimeoutError, OSError) as exc:  # the link, the store or the disk (still full) failed:
            log.error("recovery of interrupted runs incomplete: %s", exc)  # the next connect tries again

    async def _trace_written(self, krc: KrcController) -> None:
        """A trace stopped by the sweep is still being written (``#T_WRITING``): wait for its files (bounded)."""
        deadline = time.monotonic() + TRACE_WRITTEN_S
        while True:
            state = str(await within(krc.read_raw("$TRACE.STATE"), STEP_TIMEOUT_S)).strip().lstrip("#").upper()
            if state != "T_WRITING":
                return
            if time.monotonic() > deadline:
                raise RgseError(f"trace still #T_WRITING after {TRACE_WRITTEN_S:g} s; recovery waits for the next "
                                "connect")
            await asyncio.sleep(0.1)

    async def on_unsafe(self, trip: InterlockTrip, report: StopReport) -> None:
        """The interlock's stop was not confirmed by its deadline: latch."""
        await self._latch(f"interlock trip [{trip.watcher}]: stop not confirmed: {report.describe()}", report)

    async def _latch(self, reason: str, report: StopReport) -> None:
        latch = self.latch.set(reason, _report_json(report))
        message = f"SAFETY LATCH: {latch.reason}; no run is admitted; {CLEAR_HINT}"
        log.critical("%s", message)
        self.alarm({"kind": "safety_latch", "message": message, "latched_utc": latch.time_utc})
        await self._event("critical", "safety_latch", message, data=latch.to_json())

    # --- 2. interrupted runs ------------------------------------------------------------------------------------
    async def recover_runs(self, krc: KrcController) -> list[str]:
        """Recover every interrupted run of this robot not recovered since its last interruption; returns their
        ids."""
        done: list[str] = []
        for run in await self.store.list_runs(robot=self.cfg.robot.name, state=RunState.INTERRUPTED):
            events = await self.store.events(run_id=run.id, limit=100_000)
            if any(e.kind == RECOVERED and (e.data or {}).get("ended_utc") == _ended(run) for e in events):
                continue
            await self.recover_run(krc, run)
            done.append(run.id)
        # runs that ended (failed, aborted) with a loop's trace recorded but never archived: a pull that failed (the
        # disk full, the link lost mid-pull) left its files on the controller and maybe some archived, unindexed
        for state in (RunState.FAILED, RunState.ABORTED):
            for run in await self.store.list_runs(robot=self.cfg.robot.name, state=state):
                if any(lp.state == LoopState.RECORDED for lp in await self.store.loops(run.id)):
                    await self.recover_run(krc, run, ended=True)
                    done.append(run.id)
        return done

    async def recover_run(self, krc: KrcController, run: RunRecord, *, ended: bool = False) -> dict[str, Any]:
        """Pull, index and mark the loops of ``run`` (see the module docstring). ``ended``: a run that ended (failed,
        aborted) with a loop ``recorded`` but not archived; its state and result stay as they are, and a loop whose
        trace is neither on the controller nor complete in the archive becomes ``failed`` (nothing left to pull)."""
        archive = archive_root(self.cfg.paths.data_dir)
        run_dir = archive / run.directory
        share_dir = self.cfg.controller.share_dir
        listing = {base_name(e.name).upper() for e in await krc.list_dir(TRACE_DIR) if not e.is_dir}
        indexed = {(archive / f.path).resolve(): f for f in await self.store.trace_files(run.id)}
        summary: dict[str, Any] = {"ended_utc": _ended(run), "pulled": 0, "indexed": 0, "deleted": 0,
                                   "left_on_controller": [], "conflicts": [], "loops": {}}
        for lp in await self.store.loops(run.id):
            prefix = f"{lp.trace_name}_".upper()
            files: list[ArchivedFile] = []
            if any(n.startswith(prefix) for n in listing):
                try:
                    pulled = await pull_trace(krc, lp.trace_name, run_dir, share_dir=share_dir,
                                              require_complete=False)
                except ArchiveError as exc:  # a different file under the same name: keep both, say so
                    summary["conflicts"].append(f"{lp.trace_name}: {exc}")
                    pulled = None
                if pulled is not None:
                    summary["pulled"] += len(pulled.files)
                    files += pulled.files
            else:
                pulled = None
            files += archived_not_indexed(run_dir, lp.trace_name, {*indexed, *(f.path.resolve() for f in files)})
            for f in files:
                rel = relative_path(f.path, archive)
                if f.path.resolve() not in indexed:
                    rec = await self.store.add_trace_file(run.id, rel, f.sha256, f.size, loop_index=lp.index)
                    indexed[f.path.resolve()] = rec
                    summary["indexed"] += 1
            if pulled is not None:  # every file of it is indexed now: the controller copies may go
                deleted, note = await pulled.delete_copies()
                if deleted:
                    summary["deleted"] += len(pulled.names)
                else:
                    summary["left_on_controller"].append(f"{lp.trace_name}: {note}")
            names = {Path(p).name.upper() for p, rec in indexed.items() if rec.loop_index == lp.index}
            complete = all((lp.trace_name + s).upper() in names for s in REQUIRED_SUFFIXES)
            new_state = lp.state
            if lp.state == LoopState.RECORDED and complete:
                new_state = LoopState.ARCHIVED
            elif lp.state == LoopState.RECORDED and ended and pulled is None:
                new_state = LoopState.FAILED  # its trace is gone from the controller and incomplete here
            elif lp.state in (LoopState.PENDING, LoopState.RECORDING):
                new_state = LoopState.INTERRUPTED
            if new_state != lp.state:
                await self.store.update_loop(run.id, lp.index, state=new_state)
            summary["loops"][str(lp.index)] = {"trace": lp.trace_name, "state": new_state.value,
                                               "complete_set_indexed": complete}
        why = f"ended {run.state.value} with a trace not archived" if ended else "recovered after its interruption"
        message = (f"run {run.id} ({run.kind.value}) {why}: {summary['pulled']} trace files "
                   f"pulled, {summary['indexed']} indexed, {summary['deleted']} deleted on the controller")
        log.warning("%s", message)
        await self.store.add_event("warning", RECOVERED, message, run_id=run.id, data=summary)
        if not ended:
            await self._tell(run, summary)
        return summary

    async def _tell(self, run: RunRecord, summary: dict[str, Any]) -> None:
        """A final word on the run's topic: an ``interrupted`` result, or (a campaign continues) an alarm."""
        if run.kind in (RunKind.MEASUREMENT, RunKind.PROPERTIES):
            if self.cfg.mqtt.enabled:
                final = {"run_id": run.id, "robot": run.robot, "state": RunState.INTERRUPTED.value,
                         "detail": run.detail, "ended_utc": summary["ended_utc"], "recovery": summary}
                topic = Topics.of(self.cfg.mqtt, self.cfg.robot.name).result(run.id)
                await self.store.enqueue(topic, final, retained=True, qos=1)
                if self.outbox_added is not None:
                    self.outbox_added()
            self.alarm({"kind": "run_interrupted", "run_id": run.id, "run_kind": run.kind.value,
                        "message": f"{run.kind.value} run {run.id} was interrupted ({run.detail}); its final result "
                                   "says so"})
            return
        self.alarm({"kind": "run_interrupted", "run_id": run.id, "run_kind": run.kind.value,
                    "message": f"calibration campaign {run.id} was interrupted ({run.detail}); it is continued at "
                               "its first incomplete point"})
        if self.progress is not None:
            self.progress(run.id, {"state": RunState.INTERRUPTED.value, "run_id": run.id, "recovery": summary})


def _report_json(report: StopReport) -> dict[str, Any]:
    return {"confirmed": report.confirmed, "program": report.program, "first_state": report.first_state,
            "last_state": report.last_state, "trace_state": report.trace_state, "actions": list(report.actions),
            "errors": list(report.errors[-5:]), "duration_s": round(report.duration_s, 3), "rounds": report.rounds}
