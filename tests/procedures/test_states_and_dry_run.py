"""The engine's states change only along EngineState's transitions; a dry run executes only inert message types;
a document the recorder refuses fails the run."""

from __future__ import annotations

import asyncio
import inspect
from dataclasses import dataclass

import pytest

from rgse_daemon.errors import RgseError
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import TRANSITIONS, EngineState, EngineStateError, PlanAborted, RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.store import RunKind, RunState, StoreConflict

from .conftest import make_engine


def test_published_state_values_and_every_state_reachable():
    # the values go out over MQTT (state events, the retained state topic): renaming one breaks subscribers
    assert [s.value for s in EngineState] == ["idle", "running", "paused", "confirm", "done", "failed", "aborted"]
    reachable = {t for targets in TRANSITIONS.values() for t in targets}
    assert reachable == set(EngineState) - {EngineState.IDLE} and set(TRANSITIONS) == set(EngineState)


async def test_an_illegal_state_change_raises(krc, cfg):
    engine = make_engine(krc, cfg)
    with pytest.raises(EngineStateError, match="idle -> paused"):
        engine._set_state(EngineState.PAUSED)
    assert engine.state == EngineState.IDLE


async def test_state_changes_follow_the_transitions(sim, engine: RunEngine):
    states: list[str] = []

    def on_event(ev: Event) -> None:
        if ev.kind == "state":
            states.append(ev.data["state"])
            if ev.data["state"] == "paused":
                asyncio.get_running_loop().call_later(0.02, engine.resume)
        elif ev.kind == "confirm":
            answer = engine.confirm if ev.message == "answered" else lambda: engine.abort("operator left")
            asyncio.get_running_loop().call_later(0.02, answer)

    def plan() -> m.Plan:
        yield m.Checkpoint("c")
        note = yield m.Confirm("answered")
        assert engine.state == EngineState.RUNNING
        yield m.Confirm("aborted while waiting")
        return note

    engine.subscribe(on_event)
    engine.pause()
    with pytest.raises(PlanAborted, match="operator left"):
        await engine.run(plan())
    assert states == ["running", "paused", "running", "confirm", "running", "confirm", "running", "aborted"]
    for a, b in zip(["idle", *states], states, strict=False):
        assert EngineState(b) in TRANSITIONS[EngineState(a)], (a, b)
    assert not engine.waiting_for_confirmation


@dataclass(frozen=True)
class Mystery(m.Msg):
    """A message type nobody declared inert (and no engine handles): a new acting message, say."""


async def test_a_dry_run_skips_every_message_type_not_declared_inert(sim, krc, cfg):
    def plan() -> m.Plan:
        reply = yield Mystery()
        return reply

    assert await make_engine(krc, cfg, dry_run=True).run(plan()) is None
    with pytest.raises(RgseError, match="does not know message Mystery"):
        await make_engine(krc, cfg).run(plan())


def test_the_inert_message_types_are_reads_progress_and_pure_computation():
    """Declaring a type inert lets it run in a dry run: each one is a conscious decision, reviewed here."""
    types = {obj for mod in (m, d) for _, obj in inspect.getmembers(mod, inspect.isclass)
             if issubclass(obj, m.Msg) and obj.__module__ == mod.__name__}
    # Mounted only tells the engine's push check which load is on the flange: a dry run must check with it too
    assert {t for t in types if t.inert} == {m.ReadState, m.ReadVar, m.Checkpoint, m.Emit, m.Compute, m.ReadCampaign,
                                             m.Mounted}
    assert not any(t.inert for t in types if issubclass(t, d.Document))


async def test_a_document_the_store_refuses_fails_the_run_and_publishes_nothing(sim, engine: RunEngine, cfg, store):
    """The recorder's error reaches the plan (a lost record must fail the run); CloseRun still records why."""
    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    seen: list[d.Document] = []
    engine.subscribe_documents(seen.append)

    def plan(run: d.RunContext) -> m.Plan:
        yield d.Result({"mass_kg": 95.0}, ["ab" * 32])  # names a raw file this run never archived

    with pytest.raises(StoreConflict, match="not archived trace files of this run"):
        await engine.execute(d.OpenRun(RunKind.MEASUREMENT, cfg.robot.name, {}), plan, recorder)
    (run,) = await store.list_runs()
    assert run.state == RunState.FAILED and "StoreConflict" in (run.detail or "")
    assert await store.pending_outbox() == [] and await store.results(run.id) == []
    assert [type(doc).__name__ for doc in seen] == ["OpenRun", "CloseRun"]  # subscribers see only what was recorded
    assert engine.state == EngineState.FAILED
