"""Engine semantics on the simulated KR C4: finaliser on error/cancel/abort, cleanup errors never mask the cause,
pause/resume at checkpoints, dry run, and a refused program that never reaches the controller."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace

import pytest

from rgse_daemon.errors import DataError, InterlockError
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import PlanAborted, RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.measurement import measurement_plan
from rgse_daemon.procedures.programs import axes_of, program, run_checked
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.monitor import Monitor
from rgse_daemon.store import RunKind, Store
from tests.support.plans import long_motion, moving, robot_still, trace_stopped
from tests.support.polling import wait_until

from .conftest import STALE_PERIODS, make_engine


def _fails_while_moving(s: RunSettings, sim) -> m.Plan:
    """Start the long motion's trace and program, then fail in the middle of it (a pipeline error, say)."""
    plan = long_motion(s)
    msg = next(plan)
    reply = None
    while not isinstance(msg, m.WaitProgram):
        reply = yield msg
        msg = plan.send(reply)
    # the program moves the robot (the trace may already have ended on a loaded machine: the finaliser's trace stop
    # is then a no-op, and the test's "trace stopped" holds either way)
    deadline = time.monotonic() + 30.0
    while not (sim.store.read("$PRO_STATE1") == "#P_ACTIVE" and sim.store.read("$ROB_STOPPED") == "FALSE"):
        if time.monotonic() > deadline:
            raise AssertionError("the long motion never started moving")
        yield m.Sleep(0.01)

    def broken() -> None:
        raise DataError("trace.r64: truncated (the cause)")

    yield m.Process("pipeline", broken)


async def test_finaliser_runs_on_error(sim, engine: RunEngine, settings):
    with pytest.raises(DataError, match="the cause"):
        await engine.run(_fails_while_moving(settings, sim))
    await wait_until(lambda: robot_still(sim), "program stopped", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)
    assert engine.state == "failed"


async def test_cleanup_error_does_not_mask_the_cause(sim, krc, cfg, settings):
    # a monitor without watchers: this test is about the finaliser, not the interlock
    # (and a short stop deadline: the plan-end check cannot read $TRACE.STATE either, and says so after 2 s)
    monitor = Monitor(krc, watchers=(), make_safe_deadline_s=2.0)
    engine = RunEngine(krc, checker=make_engine(krc, cfg).checker, monitor=monitor, share_dir=cfg.controller.share_dir)

    def plan() -> m.Plan:
        yield from _fails_while_moving(settings, sim)

    gen = plan()

    def breaking() -> m.Plan:
        # the link drops every request naming $TRACE.STATE from now on: the finaliser's trace step fails
        try:
            result = yield from gen
        except DataError:
            sim.server.faults.drop_on_variable = "$TRACE.STATE"
            raise
        return result

    with pytest.raises(DataError, match="the cause"):
        await engine.run(breaking())
    sim.server.faults.drop_on_variable = None
    await wait_until(lambda: robot_still(sim), "program stopped by the finaliser's next step", timeout_s=10)


async def test_finaliser_runs_on_cancel(sim, engine: RunEngine, settings):
    task = asyncio.create_task(engine.run(long_motion(settings)))
    await wait_until(lambda: moving(sim), what="moving")
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    await wait_until(lambda: robot_still(sim), "program stopped", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)


async def test_abort_stops_and_raises(sim, engine: RunEngine, settings):
    task = asyncio.create_task(engine.run(long_motion(settings)))
    await wait_until(lambda: moving(sim), what="moving")
    engine.abort("operator pressed abort")
    with pytest.raises(PlanAborted, match="operator"):
        await asyncio.wait_for(task, 30)
    await wait_until(lambda: robot_still(sim), "program stopped", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)
    assert engine.state == "aborted"


async def test_pause_and_resume_at_checkpoints(sim, engine: RunEngine):
    order: list[str] = []

    def plan() -> m.Plan:
        for i in range(3):
            yield m.Checkpoint(f"c{i}")
            order.append(f"step {i}")
        return "finished"

    def on_event(ev: Event) -> None:
        if ev.kind == "state":
            order.append(ev.data["state"])
            if ev.data["state"] == "paused":
                asyncio.get_running_loop().call_later(0.05, engine.resume)

    engine.subscribe(on_event)
    engine.pause()
    assert await engine.run(plan()) == "finished"
    assert order == ["running", "paused", "running", "step 0", "step 1", "step 2", "done"]


async def test_dry_run_sends_nothing(sim, krc, cfg, store: Store, settings):
    engine = make_engine(krc, cfg, dry_run=True)
    axes_before = sim.store.read("$AXIS_ACT")
    pushed: list[str] = []
    documents: list[d.Document] = []
    engine.subscribe(lambda ev: pushed.append(ev.message) if ev.kind == "step" else None)
    engine.subscribe_documents(documents.append)
    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    opening = d.OpenRun(RunKind.MEASUREMENT, settings.robot, {"settings": settings.to_json()})
    result = await engine.execute(opening, lambda run: measurement_plan(run, settings, {}), recorder)
    assert result is None and documents == [] and engine.run_id is None
    assert "warm-up move, run 1 (1 cycles)" in pushed and "loop 2/2" in pushed
    assert not (sim.share_dir / "R1" / "PROGRAM").exists() or not any((sim.share_dir / "R1" / "PROGRAM").iterdir())
    assert not (sim.share_dir / "TRACE").exists() or not any((sim.share_dir / "TRACE").iterdir())
    assert sim.store.read("$AXIS_ACT") == axes_before and sim.moves == 0
    assert await store.list_runs() == []


def _bad_speed(s: RunSettings) -> m.Plan:
    """A template parameter injected past the renderer's safe choice: full axis speed."""
    snap = yield m.ReadState()
    prog = program("rgse_brake_release", s, axes_of(snap, s.meas_pose_deg), vel_axis_pct=100.0)
    yield from run_checked(prog, s)


def _lever_too_short(s: RunSettings) -> m.Plan:
    """A bad config: the renderer believes the payload reaches 0.05 m, the interlock knows it reaches 1.5 m."""
    snap = yield m.ReadState()
    yield from run_checked(program("rgse_warmup", replace(s, payload_lever_max_m=0.05), axes_of(snap, s.meas_pose_deg)),
                           s)


@pytest.mark.parametrize("plan", [_bad_speed, _lever_too_short])
@pytest.mark.parametrize("dry_run", [False, True])
async def test_refused_program_never_reaches_the_controller(sim, krc, cfg, settings, plan, dry_run):
    engine = make_engine(krc, cfg, dry_run=dry_run)
    alarms: list[Event] = []
    engine.subscribe(lambda ev: alarms.append(ev) if ev.kind == "alarm" else None)
    with pytest.raises(InterlockError, match="SPEED"):
        await engine.run(plan(settings))
    assert [a.data["watcher"] for a in alarms] == ["static_check"]
    programs = sim.share_dir / "R1" / "PROGRAM"
    assert not programs.exists() or not any(programs.iterdir())
    assert sim.moves == 0 and sim.store.read("$PRO_STATE1") == "#P_FREE"


async def test_trace_files_deleted_over_the_link_without_a_share(sim, krc, cfg, store: Store, settings, tmp_path):
    """Without a mounted share the engine deletes the controller's copies with #23, after archiving them."""
    engine = RunEngine(krc, checker=make_engine(krc, cfg).checker, monitor=Monitor(krc, stale_periods=STALE_PERIODS),
                       share_dir=None)

    def plan() -> m.Plan:
        from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, trace_config_xml

        yield m.PutFile(TRACE_DIR + TRACE_CONFIG_NAME, trace_config_xml(settings).encode())
        yield m.TraceStart("keep_me", TRACE_CONFIG_NAME)
        yield m.TraceWait(30)
        pulled = yield m.Pull("keep_me", tmp_path / "run")
        return pulled

    pulled = await engine.run(plan())
    assert pulled.deleted is False  # the plan deletes once the store indexed the files (procedures/loop.py)
    assert await pulled.delete_copies() == (True, "deleted over the link")
    assert not [p for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith("keep_me_")]
    assert len(pulled.files) >= 4 and all(f.path.is_file() for f in pulled.files)


async def test_abort_during_the_finaliser_still_aborts_the_run(sim, engine: RunEngine):
    """The finaliser logs a failed step and goes on (so a cleanup error cannot hide the cause); an abort delivered
    into it must still end the run aborted, not done."""

    def plan() -> m.Plan:
        yield m.Checkpoint("the plan's only step")
        engine.abort("operator pressed abort as the plan ended")  # arrives in the finaliser's first step
        return "finished"

    with pytest.raises(PlanAborted, match="as the plan ended"):
        await asyncio.wait_for(engine.run(plan()), 30)
    assert engine.state == "aborted"


def _mounts_then_pushes(s: RunSettings, mass_kg: float) -> m.Plan:
    """A calibration point's shape: the operator mounted a load (declared), then the move to the measurement pose."""
    snap = yield m.ReadState()
    yield m.Mounted(mass_kg, (0.0, 0.0, 0.6))
    yield m.Push(program("rgse_meas_pose", s, axes_of(snap, s.meas_pose_deg)))


@pytest.mark.parametrize("dry_run", [False, True])
async def test_a_push_after_mounted_checks_the_load_diagram_with_that_load(sim, krc, cfg, settings, dry_run):
    """Issue #31: the push check uses the load the plan mounted. 450 kg at 0.6 m out is 3929 Nm at A5 in the
    measurement pose (above 3330 Nm): refused before a byte is sent; 100 kg at the same place is allowed."""
    engine = make_engine(krc, cfg, dry_run=dry_run)
    with pytest.raises(InterlockError, match="A5_TORQUE"):
        await engine.run(_mounts_then_pushes(settings, 450.0))
    programs = sim.share_dir / "R1" / "PROGRAM"
    assert not programs.exists() or not any(programs.iterdir())
    # the next plan starts without the last plan's load: the checker's configured payload (0 kg here) again
    await engine.run(_pushes(settings))
    await engine.run(_mounts_then_pushes(settings, 100.0))


def _pushes(s: RunSettings) -> m.Plan:
    snap = yield m.ReadState()
    yield m.Push(program("rgse_meas_pose", s, axes_of(snap, s.meas_pose_deg)))


def test_a_calibration_point_declares_its_load() -> None:
    from rgse_daemon.kinematics import D6_M
    from rgse_daemon.procedures.calibration import mass_point, torque_point, torsional_point

    kg, cog = mass_point(10).payload()
    assert kg == pytest.approx(209.3) and cog[:2] == (0.0, 0.0) and cog[2] == pytest.approx(0.35 - D6_M)
    kg, cog = torque_point(0.8).payload()
    assert kg > 200.0 and cog[2] > 0.4
    assert torsional_point(4, (0.1, 0.0, 0.4)).payload() == (pytest.approx(83.72), (0.1, 0.0, 0.4))
