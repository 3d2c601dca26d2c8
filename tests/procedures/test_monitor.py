"""The runtime interlock: every trip stops the program and the trace on the simulator and fails the plan with an
InterlockTrip naming its watcher. Plus the declarative watchers on hand-made snapshots."""

from __future__ import annotations

import asyncio
from dataclasses import replace
from datetime import UTC, datetime

import pytest

from rgse_daemon.controller import LoadData, Snapshot
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.preconditions import PreconditionError, check_preconditions
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.monitor import DEFAULT_WATCHERS, Expect, InterlockTrip, Monitor, Observation, WatchContext
from simulators.krc4.sim import SimulatedKrc4
from tests.support.plans import long_motion, moving, robot_still, trace_stopped
from tests.support.polling import wait_until


@pytest.fixture
async def sim(sim: SimulatedKrc4) -> SimulatedKrc4:
    """The interlock end to end: the simulated KR C4 listens, and the daemon's link reaches it over TCP."""
    await sim.start()
    return sim


def _release_enabling_switch(sim: SimulatedKrc4) -> None:
    sim.set_enabling_switch(False)


def _mode_to_t2(sim: SimulatedKrc4) -> None:
    sim.store.update("$MODE_OP", "#T2")  # the mode selector turned; the controller itself does not stop here


def _link_drops(sim: SimulatedKrc4) -> None:
    sim.server.faults.drop_on_variable = "$MODE_OP"  # every snapshot (it reads $MODE_OP) loses its connection


def _program_stopped_behind_our_back(sim: SimulatedKrc4) -> None:
    sim.interpreter.stop(1)  # e.g. the start key let go, no stop message


@pytest.mark.parametrize(
    ("fault", "watcher"),
    [
        (_release_enabling_switch, "stop2"),
        (_mode_to_t2, "mode"),
        (_link_drops, "link"),
        (_program_stopped_behind_our_back, "program_state"),
    ],
)
async def test_trip_stops_motion_and_trace(sim, engine: RunEngine, settings, fault, watcher):
    alarms: list[Event] = []
    engine.subscribe(lambda ev: alarms.append(ev) if ev.kind == "alarm" else None)
    task = asyncio.create_task(engine.run(long_motion(settings)))
    await wait_until(lambda: moving(sim), what="warm-up moving with the trace recording")
    fault(sim)
    with pytest.raises(InterlockTrip) as info:
        await asyncio.wait_for(task, 30)
    assert info.value.watcher == watcher
    assert [a.data["watcher"] for a in alarms] == [watcher]
    await wait_until(lambda: robot_still(sim), "program stopped, robot still", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)
    assert sim.store.read("$PRO_STATE1") in ("#P_STOP", "#P_RESET", "#P_FREE")
    assert engine.state == "failed"
    assert engine.monitor is not None and engine.monitor.stats.trip_latency_s is not None
    print(f"\n{watcher}: trip handled {engine.monitor.stats.trip_latency_s * 1e3:.1f} ms after its poll began "
          f"(poll period {engine.monitor.poll_period_s * 1e3:.0f} ms, worst snapshot "
          f"{engine.monitor.stats.snapshot_s_max * 1e3:.1f} ms)")


def _snap(**kw: object) -> Snapshot:
    base = dict(taken_at_s=0.0, read_duration_s=0.001, mode_op="T1", pro_state1="P_ACTIVE", pro_name1="RGSE_WARMUP",
                axes_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0), pos_act=None, torques_nm=(0.0,) * 6,
                motor_temps_k=(300.0,) * 6, trace_state="T_END", peri_rdy=True, user_saf=True, stopmess=False,
                ov_pro_pct=100, load=LoadData(-1.0, (0, 0, 0), (0, 0, 0)), brake_sig="111111", vel_act_m_s=0.1,
                rob_stopped=False)
    return Snapshot(**{**base, **kw})  # type: ignore[arg-type]


def _first_trip(snap: Snapshot | None, ctx: WatchContext, error: str | None = None,
                inputs: SafetyInputs | None = None) -> str | None:
    mon = Monitor.__new__(Monitor)
    mon.watchers = DEFAULT_WATCHERS
    found = mon.check_once(Observation(snap, error, 0.0, 0.1, inputs), ctx)
    return None if found is None else found[0].name


def _inputs(area: bool = True, key: bool = True, estop: bool = True, valid: bool = True) -> SafetyInputs:
    return SafetyInputs(area, key, estop, valid, datetime.now(UTC), "" if valid else "module unreachable")


@pytest.mark.parametrize(
    ("inputs", "watcher"),
    [
        (None, None),  # no safety I/O module configured: T1 relies on the controller's own E-stop chain
        (_inputs(), None),
        (_inputs(area=False, key=False), None),  # T1: the operator is in the cell with the enabling switch
        (_inputs(estop=False), "estop"),
        (_inputs(area=False, key=False, estop=False, valid=False), "estop"),  # module unreachable = doubt
    ],
)
def test_estop_watcher_in_t1(inputs: SafetyInputs | None, watcher: str | None) -> None:
    assert _first_trip(_snap(), RUNNING, inputs=inputs) == watcher


@pytest.mark.parametrize(
    ("inputs", "refused"),
    [(None, None), (_inputs(area=False, key=False), None), (_inputs(estop=False), "E-stop chain not OK"),
     (_inputs(valid=False, estop=False), "E-stop state unknown")],
)
def test_t1_start_needs_estop_ok_when_the_module_is_configured(inputs, refused) -> None:
    snap = _snap(pro_state1="P_END")
    if refused is None:
        assert check_preconditions(snap, inputs) == "T1"
    else:
        with pytest.raises(PreconditionError, match=refused):
            check_preconditions(snap, inputs)


RUNNING = WatchContext(expect=Expect.RUNNING)


@pytest.mark.parametrize(
    ("snap", "ctx", "watcher"),
    [
        (_snap(), RUNNING, None),
        (_snap(vel_act_m_s=0.21), RUNNING, "speed"),
        (_snap(vel_act_m_s=None, errors={"$VEL_ACT": "not read"}), RUNNING, "speed"),  # doubt = trip
        (_snap(stopmess=None), RUNNING, "stop2"),
        (_snap(mode_op="AUT"), replace(RUNNING, allowed_modes=frozenset({"T1", "AUT"})), "aut_inputs"),
        (_snap(peri_rdy=False), RUNNING, "drives"),
        (_snap(user_saf=False), RUNNING, "safety_gate"),
        (_snap(pro_state1="P_ACTIVE"), WatchContext(expect=Expect.IDLE), "program_state"),
        (_snap(pro_state1="P_STOP"), WatchContext(expect=Expect.IDLE), None),
        (_snap(pro_state1="P_END"), RUNNING, None),
        (None, RUNNING, "link"),
    ],
)
def test_watchers(snap, ctx, watcher):
    assert _first_trip(snap, ctx, None if snap is not None else "LinkClosed: dropped") == watcher


async def test_a_failing_monitor_is_a_trip_that_stops_the_robot(sim, engine: RunEngine, settings, monkeypatch):
    """A bug in a watcher (or anything the poll did not foresee) must not end the monitor quietly while the robot
    moves: it trips as the ``monitor`` watcher, and program and trace are stopped."""
    task = asyncio.create_task(engine.run(long_motion(settings)))
    await wait_until(lambda: moving(sim), what="warm-up moving with the trace recording")
    assert engine.monitor is not None

    def broken(obs: Observation, ctx: WatchContext) -> None:
        raise RuntimeError("a watcher with a bug")

    monkeypatch.setattr(engine.monitor, "check_once", broken)
    with pytest.raises(InterlockTrip) as info:
        await asyncio.wait_for(task, 30)
    assert info.value.watcher == "monitor" and "a watcher with a bug" in info.value.detail
    await wait_until(lambda: robot_still(sim), "program stopped, robot still", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)
    assert engine.state == "failed"


async def test_a_snapshot_that_raises_the_unforeseen_is_link_doubt(sim, engine: RunEngine, settings, monkeypatch):
    """An exception from the snapshot that is not a link or protocol error counts as a failed poll: once the
    snapshots stay failed past the stale limit, the link watcher trips and the robot stops."""
    task = asyncio.create_task(engine.run(long_motion(settings)))
    await wait_until(lambda: moving(sim), what="warm-up moving with the trace recording")

    async def unforeseen() -> Snapshot:
        raise ValueError("Exceeds the limit (4300 digits) for integer string conversion")

    monkeypatch.setattr(engine.krc, "snapshot", unforeseen)
    with pytest.raises(InterlockTrip) as info:
        await asyncio.wait_for(task, 30)
    assert info.value.watcher == "link" and "ValueError" in info.value.detail
    monkeypatch.undo()  # the stop's read-backs use the real snapshot again
    await wait_until(lambda: robot_still(sim), "program stopped, robot still", timeout_s=10)
    await wait_until(lambda: trace_stopped(sim), "trace stopped", timeout_s=10)
