"""The store recorder: the one place in the procedures that writes run documents to the :class:`Store`.

::

    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    result = await engine.execute(OpenRun(...), lambda run: measurement_plan(run, ...), recorder)

Each document maps to the store's records as the loop's and the campaign's states require (a crash leaves a state
that says how far a loop got); the result is stored with its outbox message to ``<prefix>/run/<run_id>/result``
(:class:`~rgse_daemon.io.topics.Topics`, the same object the MQTT bridge publishes under), so the bridge publishes
it after the store has it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rgse_daemon.errors import RgseError
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.store import (
    CalibrationRecord,
    LoopState,
    OutboxMessage,
    PointState,
    RunState,
    Store,
    archive_root,
    relative_path,
)
from rgse_daemon.store.errors import StoreConflict


class StoreRecorder:
    """Writes documents to ``store``; run directories live under ``<data_dir>/archive``."""

    def __init__(self, store: Store, data_dir: Path, topics: Topics) -> None:
        self.store = store
        self.archive = archive_root(data_dir)
        self.topics = topics

    async def active_calibration(self, robot: str) -> CalibrationRecord | None:
        """The calibration a measurement of ``robot`` uses (read before a run is opened)."""
        return await self.store.active_calibration(robot)

    async def campaign(self, run_id: str) -> d.CampaignProgress:
        return d.CampaignProgress(tuple(await self.store.points(run_id)), tuple(await self.store.loops(run_id)),
                                  tuple(await self.store.trace_files(run_id)))

    async def record(self, run_id: str | None, doc: d.Document) -> Any:
        if isinstance(doc, d.OpenRun):
            return await self._open(doc)
        if run_id is None:
            raise RgseError(f"{doc.describe()}: no run is open to record it in")
        st = self.store
        match doc:
            case d.PointStarted():
                await st.add_event("info", "operator_confirmed", doc.said, run_id=run_id,
                                   data={"point_index": doc.point_index, "note": doc.note})
                for lp in await st.loops(run_id):  # an earlier attempt at this point (daemon stopped): superseded
                    if lp.point_index == doc.point_index and lp.state != LoopState.FAILED:
                        await st.update_loop(run_id, lp.index, state=LoopState.FAILED)
                await st.set_point_state(run_id, doc.point_index, PointState.MEASURING)
            case d.LoopStarted():
                await st.add_loop(run_id, doc.index, doc.trace, point_index=doc.point_index)
                await st.update_loop(run_id, doc.index, robot_start_utc=doc.robot_start_utc)
            case d.LoopRecording():
                await st.update_loop(run_id, doc.index, state=LoopState.RECORDING, robot_end_utc=doc.robot_end_utc,
                                     record_start_utc=doc.record_start_utc)
            case d.LoopRecorded():
                await st.update_loop(run_id, doc.index, state=LoopState.RECORDED, record_end_utc=doc.record_end_utc)
            case d.TraceArchived():
                for f in doc.files:
                    await st.add_trace_file(run_id, relative_path(f.path, self.archive), f.sha256, f.size,
                                            loop_index=doc.index)
                await st.update_loop(run_id, doc.index, state=LoopState.ARCHIVED)
                if not doc.deleted and doc.delete_note:  # no note yet: the delete comes after the index
                    await st.add_event("warning", "trace_left_on_controller", f"{doc.trace}: {doc.delete_note}",
                                       run_id=run_id, data={"trace": doc.trace})
            case d.PointDone():
                await st.set_point_state(run_id, doc.point_index, PointState.DONE)
            case d.Result():
                if doc.calibration is not None:
                    await st.add_calibration(doc.calibration, run_id=run_id, activate=True)
                await st.record_result(run_id, doc.result, list(doc.trace_sha256),
                                       publish=OutboxMessage(self.topics.result(run_id)))
            case d.CloseRun():
                await st.set_run_state(run_id, doc.state, doc.detail)
            case _:
                raise RgseError(f"the store recorder does not know document {type(doc).__name__}")
        return None

    async def _open(self, doc: d.OpenRun) -> d.RunContext:
        st = self.store
        if doc.resume_run_id is None:
            run = await st.create_run(doc.kind, doc.robot, doc.config)
            if doc.points:
                await st.add_points(run.id, list(doc.points))
        else:
            run = await st.get_run(doc.resume_run_id)
            if run.kind != doc.kind or run.robot != doc.robot:
                raise StoreConflict(f"run {run.id}: not a {doc.kind.value} run of robot {doc.robot}")
            if run.state not in (RunState.INTERRUPTED, RunState.QUEUED, RunState.RUNNING):
                raise StoreConflict(f"run {run.id}: is {run.state.value}, cannot continue")
        await st.set_run_state(run.id, RunState.RUNNING)
        return d.RunContext(run.id, self.archive / run.directory, self.archive)
