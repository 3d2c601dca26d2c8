"""The file work off the robot's path (issue 35): the next loop's move is checked and pushed while a trace records,
the push before its start checks it again and sends no byte, and a program is sent again once any program ran; the
static check's verdict is reused only for the very same program in the very same context. End to end over TCP
against the simulated KR C4 where the controller is involved."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest

from rgse_daemon.errors import InterlockError
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures import programs
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.loop import collect, loop
from rgse_daemon.procedures.programs import axes_of, program, run_checked, static_checker
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import prepare
from rgse_daemon.store import RunKind, Store
from simulators.krc4.sim import SimulatedKrc4
from tests.procedures.conftest import make_engine


def _count_puts(krc: Any, sim: SimulatedKrc4) -> list[tuple[str, str]]:
    """Every file the engine writes to the controller, with the trace state at that moment."""
    puts: list[tuple[str, str]] = []
    put = krc.put_file

    async def counted(name: str, data: bytes, *a: Any, **kw: Any) -> Any:
        puts.append((name.rsplit("\\", 1)[-1].upper(), sim.store.read("$TRACE.STATE")))
        return await put(name, data, *a, **kw)

    krc.put_file = counted
    return puts


def _count_checks(engine: RunEngine) -> list[str]:
    checks: list[str] = []
    check = engine.checker

    def counted(prog: m.Program, snap: Any, **kw: Any) -> None:
        checks.append(prog.name)
        check(prog, snap, **kw)

    engine.checker = counted
    return checks


async def test_a_push_of_bytes_already_sent_is_checked_but_not_sent_again_until_a_program_ran(
        sim: SimulatedKrc4, engine: RunEngine, krc: Any, settings: RunSettings):
    puts, checks = _count_puts(krc, sim), _count_checks(engine)

    def plan() -> m.Plan:
        snap = yield m.ReadState()
        move = program("rgse_brake_release", settings, axes_of(snap, settings.meas_pose_deg))
        yield m.Push(move)  # ahead: the robot stands still
        yield m.Push(move)  # before its start: checked again, nothing sent
        sent_before_start = [n for n, _ in puts]
        yield from run_checked(move, settings)  # a third push (no bytes), then the move
        yield m.Push(move)  # a program ran since: sent again
        return sent_before_start

    sent_before_start = await engine.run(plan())
    assert sent_before_start == ["RGSE_BRAKE_RELEASE.SRC"] and [n for n, _ in puts] == sent_before_start * 2
    assert checks == ["rgse_brake_release"] * 4  # every push checked against the live state
    assert sim.moves >= 1


async def test_a_changed_program_is_sent_even_without_a_program_run(
        sim: SimulatedKrc4, engine: RunEngine, krc: Any, settings: RunSettings):
    puts = _count_puts(krc, sim)

    def plan() -> m.Plan:
        snap = yield m.ReadState()
        axes = axes_of(snap, settings.meas_pose_deg)
        yield m.Push(program("rgse_brake_release", settings, axes))
        yield m.Push(program("rgse_brake_release", replace(settings, brake_release_deg=settings.brake_release_deg / 2),
                             axes))

    await engine.run(plan())
    assert [n for n, _ in puts].count("RGSE_BRAKE_RELEASE.SRC") == 2


async def test_a_refused_program_is_refused_at_every_push(sim: SimulatedKrc4, engine: RunEngine, krc: Any,
                                                          settings: RunSettings):
    """A push ahead that the check refused sends nothing; the next push of it is refused again, checked anew."""
    puts, checks = _count_puts(krc, sim), _count_checks(engine)
    refused: list[str] = []

    def plan() -> m.Plan:
        snap = yield m.ReadState()
        fast = program("rgse_brake_release", settings, axes_of(snap, settings.meas_pose_deg), vel_axis_pct=100.0)
        for _ in range(2):
            try:
                yield m.Push(fast)
            except InterlockError as exc:
                refused.append(str(exc))

    await engine.run(plan())
    assert len(refused) == 2 and checks == ["rgse_brake_release"] * 2 and puts == []


def test_the_static_check_reuses_a_verdict_only_for_the_same_program_in_the_same_context(
        monkeypatch: pytest.MonkeyPatch, cfg: Any, settings: RunSettings):
    from rgse_daemon.controller import Snapshot

    calls: list[tuple[float, ...] | None] = []
    real = programs.ensure_allowed

    def counted(src: str, dat: str | None, ctx: Any, **kw: Any) -> None:
        calls.append(ctx.start_axes_deg)
        real(src, dat, ctx, **kw)

    monkeypatch.setattr(programs, "ensure_allowed", counted)
    check = static_checker(cfg.limits, cfg.measurement.payload_lever_max_m, require_watchdog=True)
    axes = tuple(settings.meas_pose_deg)

    def snap(axes_deg: tuple[float, ...], mode: str = "#T1") -> Snapshot:
        return Snapshot(0.0, 0.0, mode, "#P_END", "", axes_deg, None, (None,) * 6, (None,) * 6, "#T_END", True, True,
                        False, 100, None, None, 0.0, True)

    move = program("rgse_brake_release", settings, axes)
    check(move, snap(axes))
    check(move, snap(axes))  # the very same inputs: the verdict stands
    assert len(calls) == 1
    moved = (*axes[:4], axes[4] + 1e-6, axes[5])
    check(move, snap(moved))  # an axis moved by a micro-degree: computed again
    check(move, snap(axes), payload=(50.0, (0.0, 0.0, 0.3)))  # another load: again
    assert calls == [axes, moved, axes]
    with pytest.raises(InterlockError):
        check(move, snap(axes, "#AUT"))  # AUT without the cleared area: refused ...
    with pytest.raises(InterlockError):
        check(move, snap(axes, "#AUT"))  # ... and again, checked anew (a refusal is never remembered)
    assert len(calls) == 5


async def test_loops_push_the_next_move_while_the_trace_records(sim: SimulatedKrc4, krc: Any, cfg: Any,
                                                                store: Store, settings: RunSettings):
    """Three loops: the first move is pushed before its start, the next ones while the loop before records; their
    own pushes send nothing; each loop's files are indexed while the next trace records, before they leave the
    controller."""
    engine = make_engine(krc, cfg)
    order: list[str] = []
    puts, checks = _count_puts(krc, sim), _count_checks(engine)
    s = replace(settings, warmup_cycles=0)

    def watch(doc: d.Document) -> None:
        if isinstance(doc, d.TraceArchived):
            left = {p.name for p in (sim.share_dir / "TRACE").iterdir()}
            assert {f.path.name for f in doc.files} <= left, "a trace file left the controller before its index"
        order.append(f"{type(doc).__name__} {getattr(doc, 'index', '')}".strip())

    engine.subscribe_documents(watch)

    def plan(run: d.RunContext) -> m.Plan:
        yield from prepare(s, None)
        del puts[:], order[:]
        previous = None
        for i in range(1, 4):
            previous = yield from loop(i, f"ahead_l{i}", run, s, previous=previous, defer=i < 3)
        return (yield from collect(previous, run, s))

    put = krc.put_file

    async def logged(name: str, data: bytes, *a: Any, **kw: Any) -> Any:
        if name.upper().endswith(".SRC"):
            order.append("put")
        return await put(name, data, *a, **kw)

    krc.put_file = logged

    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    last = await engine.execute(d.OpenRun(RunKind.MEASUREMENT, s.robot, {"settings": s.to_json()}), plan, recorder)
    # loop 1's move before its start; loops 2 and 3's after the trace before them started, before its end
    assert order[:-1] == ["LoopStarted 1", "put", "LoopRecording 1", "put", "LoopRecorded 1",
                         "LoopStarted 2", "LoopRecording 2", "put", "TraceArchived 1", "LoopRecorded 2",
                         "LoopStarted 3", "LoopRecording 3", "TraceArchived 2", "LoopRecorded 3", "TraceArchived 3"]
    assert puts[1][1] != "#T_END"  # loop 2's move went to the controller before loop 1's trace had ended
    assert checks.count("rgse_brake_release") == 5  # loop 1's push, two ahead, loops 2 and 3's own pushes
    assert last.deleted and not any(p.name.startswith("ahead_l") for p in (sim.share_dir / "TRACE").iterdir())
