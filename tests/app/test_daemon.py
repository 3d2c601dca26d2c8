"""The daemon service itself (:class:`rgse_daemon.app.Daemon`), in-process against the simulated KR C4 on a real
socket, a private Mosquitto, the Modbus I/O simulator and a real store: ordered startup and bounded ordered shutdown,
one run at a time, the controller link's loss and recovery, the MQTT commands, and the safety I/O's part in the
interlock (AUT only with "area cleared" and "key switch AUT permitted"; an input dropping mid-run trips)."""

from __future__ import annotations

import asyncio
import json
import os
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.app import STOP_TIMEOUT_S, Daemon, NotConnected, campaign_point
from rgse_daemon.errors import InterlockError
from rgse_daemon.io.commands import CalibrationPoint
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.procedures.calibration import table1_points
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.programs import program
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.monitor import InterlockTrip
from rgse_daemon.services.state import StatePublisher
from rgse_daemon.store import RunState, Store, StoreError
from rgse_daemon.systemd import Notifier
from simulators.krc4.physics import dut_payload, mass_calibration_payload, torque_calibration_payload
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.variables import ProState
from simulators.modbus_io import ModbusIoSim
from tests.support.daemon import (
    PREFIX,
    ROBOT,
    WAIT_S,
    Events,
    command,
    daemon_config,
    first_of,
    run_end,
    running_daemon,
    seed_calibration,
)
from tests.support.mqtt import Collector, MosquittoProcess, free_port, retained
from tests.support.polling import wait_until

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)


def peer(broker: MosquittoProcess) -> Collector:
    """An operator's MQTT client: command replies, alarms and progress of the daemon."""
    return Collector("127.0.0.1", broker.port, f"{PREFIX}/cmd/+/reply", f"{PREFIX}/alarm", f"{PREFIX}/run/+/progress")


def pause_at_first(events: Events, daemon_ref: list[Any], kind: str, **match: Any) -> asyncio.Event:
    """Pause the run (at its next checkpoint) on the first event of ``kind`` whose fields (or ``data`` items) equal
    ``match``; the returned event is set once the engine reports ``paused``."""
    paused = asyncio.Event()
    armed = [True]

    def hook(ev: Event) -> None:
        if armed[0] and ev.kind == kind and all(ev.data.get(k, getattr(ev, k, None)) == v
                                                        for k, v in match.items()):
            armed[0] = False
            daemon_ref[0].daemon.engine.pause()
        if ev.kind == "state" and ev.data.get("state") == "paused":
            paused.set()

    events.hooks.append(hook)
    return paused


async def stored_run(cfg: Any, run_id: str) -> Any:
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        return await store.get_run(run_id)


# --- startup and shutdown ----------------------------------------------------------------------------------------
class NotifySocket:
    """The receiving end of ``$NOTIFY_SOCKET`` as systemd has it: a bound AF_UNIX datagram socket."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.received: list[str] = []

    async def next(self, timeout_s: float = WAIT_S) -> str:
        data = await asyncio.wait_for(asyncio.get_running_loop().sock_recv(self.sock, 4096), timeout_s)
        self.received.append(data.decode())
        return self.received[-1]

    def drain(self) -> list[str]:
        while True:
            try:
                self.received.append(self.sock.recv(4096).decode())
            except BlockingIOError:
                return self.received


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[NotifySocket]:
    ns = NotifySocket(tmp_path / "notify.sock")
    try:
        yield ns
    finally:
        ns.sock.close()


async def test_startup_in_order_ready_watchdog_then_bounded_ordered_shutdown(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, modbus_sim: ModbusIoSim, notify_socket: NotifySocket,
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, modbus_port=modbus_sim.port)
    notifier = Notifier({"NOTIFY_SOCKET": str(notify_socket.path), "WATCHDOG_USEC": "200000",
                         "WATCHDOG_PID": str(os.getpid())})
    assert notifier.watchdog_interval_s == pytest.approx(0.1)
    async with running_daemon(cfg, notifier=notifier, connected=False) as rd:
        d = rd.daemon
        # READY=1 is the first thing systemd hears, and only once every component has been started
        assert await notify_socket.next() == f"READY=1\nSTATUS=serving robot {ROBOT}"
        assert d.store is not None and await d.store.active_calibration(ROBOT) is None  # the store answers
        assert d.safety_io is not None and d.safety_io.state.value != "stopped"
        assert d.mqtt is not None and d.mqtt.connection_state.value != "stopped"
        # the watchdog pings while the loop runs and the store answers
        assert [await notify_socket.next() for _ in range(2)] == ["WATCHDOG=1", "WATCHDOG=1"]
        await first_of(d.connected.wait(), rd.task, "controller connected")
        await wait_until(lambda: modbus_sim.light == "green" and not modbus_sim.running, "stack light green (idle)")
        await wait_until(lambda: d.mqtt.connected, "mqtt connected")
        assert not rd.task.done()
        took_s = await rd.shutdown()
    assert took_s < STOP_TIMEOUT_S  # bounded (it takes a fraction of a second; the bound is per component)
    sent = notify_socket.drain()
    assert sent[0].startswith("READY=1") and "STOPPING=1" in sent
    assert set(sent[1:]) <= {"WATCHDOG=1", "STOPPING=1"} and sent.count("STOPPING=1") == 1
    # in reverse order: the retained status says offline, the stack light is dark, the link is closed
    (status,) = await retained("127.0.0.1", private_broker.port, f"{PREFIX}/status")
    assert json.loads(status.payload)["state"] == "offline"  # type: ignore[arg-type]
    assert modbus_sim.light == "off" and not modbus_sim.running
    await wait_until(lambda: sim.server.client_count == 0, "the controller link closed")
    assert d.store is not None
    with pytest.raises(StoreError, match="the store is closed"):
        await d.store.active_calibration(ROBOT)


async def test_stop_during_a_run_stops_the_program_first_and_marks_the_run(
        calibration_doc: dict[str, Any], modbus_sim: ModbusIoSim, tmp_path: Path) -> None:
    # a slow clock (2 simulated s per wall s): the warm-up program is still moving when the daemon is stopped
    async with SimulatedKrc4(tmp_path / "share", seed=3, time_scale=2.0, latency_s=0.0) as slow:
        slow.install_globals(globals_dat_text())
        slow.mount(DUT)
        cfg = daemon_config(tmp_path / "data", controller_port=slow.port, share_dir=slow.share_dir,
                            modbus_port=modbus_sim.port)
        await seed_calibration(cfg, calibration_doc)
        events = Events()
        async with running_daemon(cfg, on_event=events) as rd:
            task = await rd.daemon.start_measurement()
            await events.wait_for(lambda e: e.step == "warm-up", "the warm-up step")
            await wait_until(lambda: slow.interpreter.state is ProState.ACTIVE, "the warm-up program runs",
                             timeout_s=WAIT_S)
            await wait_until(lambda: modbus_sim.light == "yellow" and modbus_sim.running, "stack light yellow")
            run_id = rd.daemon.engine.run_id if rd.daemon.engine else None
            assert run_id is not None
            took_s = await rd.shutdown()
        assert took_s < STOP_TIMEOUT_S
        assert task.cancelled()
        # the program was stopped mid-motion over the still open link: it ramps down to #P_STOP (a program left
        # alone would run on to #P_END)
        await wait_until(lambda: slow.interpreter.state is not ProState.ACTIVE, "the program ramped down",
                         timeout_s=WAIT_S)
        assert slow.interpreter.state is ProState.STOP
        assert slow.store.read("$TRACE.STATE").strip().upper() in ("#T_END", "#T_STOP")
        run = await stored_run(cfg, run_id)
        assert run.state == RunState.INTERRUPTED and run.detail == "daemon stopped during the run"
        assert events.states()[-1] in ("failed", "aborted")
        assert modbus_sim.light == "off" and not modbus_sim.running


async def test_an_interrupted_campaign_continues_after_a_restart(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=1)
    points = table1_points(n_bodies=(0, 3), torque_levers_a5_m=(1.011,))
    first, ref = Events(), []
    waiting_at_1 = asyncio.Event()

    def operator(ev: Event) -> None:  # mounts and confirms point 0; leaves point 1 waiting
        if ev.kind == "confirm" and ev.data["point_index"] == 0:
            sim.mount(mass_calibration_payload(0))
            asyncio.get_running_loop().call_soon(ref[0].daemon.engine.confirm, "mounted")
        elif ev.kind == "confirm":
            waiting_at_1.set()

    first.hooks.append(operator)
    async with running_daemon(cfg, on_event=first) as rd:
        ref.append(rd)
        await rd.daemon.start_calibration(points=points)
        await first_of(waiting_at_1.wait(), rd.task, "the campaign waits for point 1")
        run_id = rd.daemon.engine.run_id if rd.daemon.engine else None
        assert run_id is not None
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        assert (await store.get_run(run_id)).state == RunState.INTERRUPTED
        assert [p.state.value for p in await store.points(run_id)] == ["done", "pending", "pending"]

    # a new daemon on the same store continues the campaign at its first incomplete point
    second = Events()
    async with running_daemon(cfg, on_event=second) as rd2:
        prompt = await second.wait_for(lambda e: e.kind == "confirm", "the continued campaign's first prompt")
        assert prompt.run_id == run_id and prompt.data["point_index"] == 1 and prompt.data["n_cb"] == 3
        assert rd2.daemon.run_kind == "calibration" and rd2.daemon.run_active
    assert (await stored_run(cfg, run_id)).state == RunState.INTERRUPTED  # stopped again, still resumable


# --- one run at a time --------------------------------------------------------------------------------------------
async def test_second_measure_is_refused_busy_with_the_reason_in_the_reply(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)
    events, ref = Events(), []
    paused = pause_at_first(events, ref, "state", state="running")
    async with running_daemon(cfg, on_event=events) as rd, peer(private_broker) as op:
        ref.append(rd)
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        first = await command(op, "measure", {"loops": 2})
        assert first["ok"] is True and first["accepted"] == "measurement"
        run_id = first["run_id"]
        assert run_id and run_id == rd.daemon.engine.run_id
        await first_of(paused.wait(), rd.task, "the run paused")  # it stays in progress until told otherwise
        second = await command(op, "measure", {"loops": 1})
        assert second["ok"] is False
        assert second["error"] == (f"busy: a measurement run ({run_id}) is in progress; abort it first or wait")
        third = await command(op, "calibrate", {})
        assert third["ok"] is False and third["error"].startswith("busy: a measurement run")
        assert rd.daemon.counters.runs_started == 1 and rd.daemon.counters.runs_refused == 2
        # the run in progress is untouched by the refusals; abort it over MQTT
        assert rd.daemon.run_active
        wrong = await command(op, "abort", {"run_id": "not-this-run", "reason": "test"})
        assert wrong["ok"] is False and run_id in wrong["error"]
        aborted = await command(op, "abort", {"run_id": run_id, "reason": "operator test"})
        assert aborted == {"aborting": run_id, "dry_run": False, "request_id": aborted["request_id"], "ok": True}
        with pytest.raises(Exception, match="operator test"):
            await run_end(rd)
    run = await stored_run(cfg, run_id)
    assert run.state == RunState.ABORTED and run.detail == "operator test"
    assert sim.interpreter.state is not ProState.ACTIVE


async def test_measure_without_an_active_calibration_counts_as_refused_not_started(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "measure", {"loops": 1})
        assert reply["ok"] is False and "no active calibration" in reply["error"], reply
        c = rd.daemon.counters
        await wait_until(lambda: c.runs_refused == 1, "the refusal counted")
        assert c.runs_started == 0 and not rd.daemon.run_active


async def test_measure_with_the_controller_unreachable_is_refused_not_connected(
        private_broker: MosquittoProcess, tmp_path: Path) -> None:
    port = free_port()  # nothing listens here
    cfg = daemon_config(tmp_path / "data", controller_port=port, broker_port=private_broker.port)
    async with running_daemon(cfg, connected=False) as rd, peer(private_broker) as op:
        d = rd.daemon
        await wait_until(lambda: d.counters.controller_connect_failures >= 3 and d.mqtt.connected,
                         "several failed connects (with backoff)", timeout_s=WAIT_S)
        reply = await command(op, "measure", {})
        assert reply["ok"] is False
        assert reply["error"].startswith(f"not connected: controller 127.0.0.1:{port} is not connected (")
        with pytest.raises(NotConnected, match="not connected"):
            await d.start_measurement()
        assert not d.connected.is_set() and d.run_task is None
        await op.sync()
        link_alarms = [a for a in op.json_on(f"{PREFIX}/alarm") if a.get("kind") == "link"]
        assert len(link_alarms) == 1  # published once, not once per attempt
        assert f"127.0.0.1:{port} unreachable" in link_alarms[0]["message"]


async def test_link_loss_then_recovery_reconnects_with_backoff(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    await seed_calibration(cfg, calibration_doc)
    port = sim.port
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        d = rd.daemon
        assert d.counters.controller_connects == 1
        first_engine = d.engine
        await sim.server.close()  # the controller goes away: every connection dropped, nothing listens
        await wait_until(lambda: not d.connected.is_set(), "the daemon notices the lost link", timeout_s=WAIT_S)
        with pytest.raises(NotConnected):
            await d.start_measurement()
        await wait_until(lambda: d.counters.controller_connect_failures >= 3, "reconnect attempts, backing off",
                         timeout_s=WAIT_S)
        assert d.counters.link_losses == 1 and d.counters.controller_connects == 1
        sim.server.config.port = port  # the controller is back at the same address
        await sim.server.start()
        await first_of(d.connected.wait(), rd.task, "reconnected")
        assert d.counters.controller_connects == 2 and d.counters.link_losses == 1
        assert d.engine is not first_engine and d.krc is not None
        # the new link serves a run (a dry run: checks the state and the programs, moves nothing)
        reply = await command(op, "measure", {"dry_run": True})
        assert reply["ok"] is True and reply["dry_run"] is True
        assert await run_end(rd) is None
        await op.sync()
        link_alarms = [a for a in op.json_on(f"{PREFIX}/alarm") if a.get("kind") == "link"]
        assert len(link_alarms) == 1 and "link lost" in link_alarms[0]["message"]


async def test_a_standing_job_that_ends_with_an_error_is_an_alarm_at_once(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A daemon job (here the state publisher) that dies is published as an alarm while the daemon runs, not only
    logged at shutdown."""
    go = asyncio.Event()

    async def dies(self: StatePublisher) -> None:
        await go.wait()
        raise RuntimeError("a bug in the state job")

    monkeypatch.setattr(StatePublisher, "run", dies)
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt is not None and rd.daemon.mqtt.connected, "mqtt connected")
        go.set()

        def alarms() -> list[dict[str, Any]]:
            return [a for a in op.json_on(f"{PREFIX}/alarm") if a.get("kind") == "task_failed_state"]

        await wait_until(lambda: len(alarms()) == 1, "the job's alarm published", timeout_s=WAIT_S)
        assert "a bug in the state job" in alarms()[0]["message"] and not rd.task.done()


# --- commands -------------------------------------------------------------------------------------------------------
def test_controller_backoff_is_exponential_jittered_and_capped(tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path, controller_port=7000)  # reconnect 0.05 s .. 0.4 s
    d = Daemon(cfg)
    for attempt, base in enumerate((0.05, 0.1, 0.2, 0.4, 0.4, 0.4)):
        delays = [d.link.backoff_s(attempt) for _ in range(50)]
        assert all(0.5 * base <= x <= base for x in delays) and len(set(delays)) > 1, attempt


async def test_a_link_that_fails_right_after_its_connect_keeps_backing_off(sim: SimulatedKrc4, tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The connect succeeds, then the link's preparation fails (a full disk in the recovery sweep, say): the next
    attempts back off further each time instead of reconnecting at the minimum delay forever."""
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir)
    d = Daemon(cfg)
    attempts: list[int] = []
    backoff = d.link.backoff_s
    monkeypatch.setattr(d.link, "backoff_s", lambda attempt: attempts.append(attempt) or backoff(attempt))
    stop = asyncio.Event()

    async def prepare(krc: object) -> None:
        if len(attempts) >= 4:
            stop.set()
        raise OSError(28, "No space left on device")

    async def never(*_: object) -> None:
        raise AssertionError("the link never comes up here")

    await asyncio.wait_for(d.link.run(stop, never, never, prepare=prepare), WAIT_S)
    assert attempts == [0, 1, 2, 3]
    assert d.link.error == "OSError: [Errno 28] No space left on device"


def test_calibrate_command_points_map_back_to_what_the_operator_mounts() -> None:
    for p in table1_points():
        got = campaign_point(CalibrationPoint(kind=p.kind, mass_kg=p.mass_kg, lever_a3_m=p.lever_a3_m,  # type: ignore
                                              lever_a5_m=p.lever_a5_m))
        assert (got.kind, got.n_cb, got.mass_kg, got.lever_a5_m) == (p.kind, p.n_cb, p.mass_kg, p.lever_a5_m)
        assert got.cb_lever_a5_m == pytest.approx(p.cb_lever_a5_m, abs=1e-9) if p.cb_lever_a5_m else \
            got.cb_lever_a5_m is None
    with pytest.raises(Exception, match="not a whole number of calibration bodies"):
        campaign_point(CalibrationPoint(kind="mass", mass_kg=30.0, lever_a3_m=1.3, lever_a5_m=0.3))


async def test_calibrate_and_confirm_over_mqtt(sim: SimulatedKrc4, private_broker: MosquittoProcess,
                                               tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1)
    points = table1_points(n_bodies=(0, 3), torque_levers_a5_m=(1.011,))
    specs = [{"kind": p.kind, "mass_kg": p.mass_kg, "lever_a3_m": p.lever_a3_m, "lever_a5_m": p.lever_a5_m}
             for p in points]
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "calibrate", {"points": specs, "method": "auto"})
        assert reply["ok"] is True and reply["points"] == 3
        run_id = reply["run_id"]
        progress = f"{PREFIX}/run/{run_id}/progress"

        async def prompt(index: int) -> dict[str, Any]:
            def find() -> list[dict[str, Any]]:
                return [m["data"] for m in op.json_on(progress)
                        if m["kind"] == "confirm" and m["data"]["point_index"] == index]
            await op.wait_for(lambda _: bool(find()), f"the confirm prompt of point {index}")
            return find()[0]

        zero = await prompt(0)
        assert (zero["kind"], zero["n_cb"]) == ("zero", 0)
        wrong = await command(op, "confirm", {"run_id": run_id, "point": 1})
        assert wrong["ok"] is False and "waits for point 0, not point 1" in wrong["error"]
        sim.mount(mass_calibration_payload(0))
        assert (await command(op, "confirm", {"run_id": run_id, "point": 0}))["ok"] is True
        stack = await prompt(1)
        assert (stack["kind"], stack["n_cb"]) == ("mass", 3)
        sim.mount(mass_calibration_payload(3))
        assert (await command(op, "confirm", {"run_id": run_id, "point": 1,
                                              "message": "3 bodies on the MPA, bolts torqued"}))["ok"] is True
        torque = await prompt(2)
        # what the operator mounts for a torque point: 10 bodies on the test adapter, 1.011 m from A5
        assert (torque["kind"], torque["n_cb"]) == ("torque", 10)
        assert torque["cb_lever_a5_m"] == pytest.approx(1.011, abs=1e-9)
        torque_calibration_payload(torque["n_cb"], torque["cb_lever_a5_m"])  # a load the simulator can mount
        aborted = await command(op, "abort", {"run_id": run_id, "reason": "enough"})
        assert aborted["ok"] is True
        with pytest.raises(Exception, match="enough"):
            await run_end(rd)
    run = await stored_run(cfg, run_id)
    assert run.state == RunState.ABORTED
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        said = [e.message for e in await store.events(run_id=run_id) if e.kind == "operator_confirmed"]
    assert said == ["point 1/3 (empty MPA): point 0",
                    "point 2/3 (3 calibration bodies on the MPA): 3 bodies on the MPA, bolts torqued"]


# --- the safety I/O in the interlock --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("area_cleared", "aut_permitted", "modbus_up", "accepted"),
    [(True, True, True, True), (False, True, True, False), (True, False, True, False), (True, True, False, False)],
    ids=["all-present", "area-not-cleared", "key-not-turned", "modbus-link-down"],
)
async def test_aut_only_with_area_cleared_and_key_switch(
        sim: SimulatedKrc4, modbus_sim: ModbusIoSim, calibration_doc: dict[str, Any], tmp_path: Path,
        area_cleared: bool, aut_permitted: bool, modbus_up: bool, accepted: bool) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        modbus_port=modbus_sim.port, loops=1)
    await seed_calibration(cfg, calibration_doc)
    modbus_sim.set_input("estop_ok", True)
    modbus_sim.set_input("area_cleared", area_cleared)
    modbus_sim.set_input("aut_permitted", aut_permitted)
    sim.set_mode("AUT")
    sim.mount(DUT)
    async with running_daemon(cfg) as rd:
        d = rd.daemon
        await wait_until(lambda: d.safety_io.inputs.valid, "the first reading of the safety inputs")
        if not modbus_up:
            await modbus_sim.stop()
            await wait_until(lambda: not d.safety_io.inputs.valid, "the safety I/O link lost")
        # the static check of every program the daemon pushes sees the inputs
        assert d.engine is not None and d.krc is not None
        snap = await d.krc.snapshot()
        prog = program("rgse_meas_pose", RunSettings.from_config(cfg), snap.axes_deg or ())
        if accepted:
            await asyncio.to_thread(d.engine.checker, prog, snap)
        else:
            with pytest.raises(InterlockError, match="mode AUT refused"):
                await asyncio.to_thread(d.engine.checker, prog, snap)
        await d.start_measurement()
        if accepted:
            result = await run_end(rd)
            assert result is not None and result["loops"] == 1
            assert d.engine.monitor is not None and d.engine.monitor.context.allowed_modes == {"AUT"}
            await wait_until(lambda: modbus_sim.light == "green" and not modbus_sim.running, "green after the run")
        else:  # refused before anything is recorded or moved
            with pytest.raises(PreconditionError, match="AUT needs the area cleared, the AUT key and E-stop OK"):
                await run_end(rd)
            assert await d.store.list_runs(robot=ROBOT) == []
            if modbus_up:  # a refusal is a request answered "no", not a failure: the light stays green
                assert d.light.color == "green"
                await wait_until(lambda: modbus_sim.light == "green" and not modbus_sim.running, "stack light green")
    assert sim.interpreter.state is not ProState.ACTIVE


async def test_t1_campaign_refused_at_admission_while_configured_safety_inputs_are_unreadable(
        sim: SimulatedKrc4, modbus_sim: ModbusIoSim, calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    """Issue #34: with [modbus] configured and unreachable, a campaign was admitted, prompted for its first load and
    tripped only after that Confirm. Refuse before the first prompt, as the plan's own 'verify' would."""
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        modbus_port=modbus_sim.port, loops=1)
    await seed_calibration(cfg, calibration_doc)
    modbus_sim.set_all_inputs(True)
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd:
        d = rd.daemon
        await wait_until(lambda: d.safety_io.inputs.valid, "the first reading of the safety inputs")
        await modbus_sim.stop()
        await wait_until(lambda: not d.safety_io.inputs.valid, "the safety I/O link lost")
        await d.start_calibration(points=table1_points(n_bodies=(0, 3), torque_levers_a5_m=(1.011,)))
        with pytest.raises(PreconditionError, match="E-stop state unknown: safety inputs invalid"):
            await run_end(rd)
        assert events.of("confirm") == []
        assert await d.store.list_runs(robot=ROBOT) == []
    assert sim.interpreter.state is not ProState.ACTIVE


async def test_campaign_too_small_for_its_method_is_refused_before_the_first_load(
        sim: SimulatedKrc4, tmp_path: Path) -> None:
    """Issue #34: a 5-point campaign with --method paper moved the robot through every point and failed at the end
    (the model needs more loaded points). Now it is refused before the first prompt, naming the cause."""
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=1)
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd:
        d = rd.daemon
        await d.start_calibration(points=table1_points(n_bodies=(0, 2, 4, 6, 8), torque_levers_a5_m=()),
                                  method="paper")
        with pytest.raises(PreconditionError, match=r"5 mass and torque points cannot give a paper calibration: "
                                                    r".*needs at least \d+ loaded points, got 4"):
            await run_end(rd)
        assert events.of("confirm") == [] and await d.store.list_runs(robot=ROBOT) == []
    assert sim.moves == 0


@pytest.mark.parametrize("fault", ["area_cleared", "estop_ok", "modbus_link"])
async def test_safety_input_dropping_mid_run_trips_the_interlock(
        sim: SimulatedKrc4, modbus_sim: ModbusIoSim, private_broker: MosquittoProcess,
        calibration_doc: dict[str, Any], tmp_path: Path, fault: str) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        modbus_port=modbus_sim.port, broker_port=private_broker.port, loops=3)
    await seed_calibration(cfg, calibration_doc)
    modbus_sim.set_all_inputs(True)
    sim.set_mode("AUT")
    sim.mount(DUT)
    events, ref = Events(), []
    paused = pause_at_first(events, ref, "step", step="loop")
    async with running_daemon(cfg, on_event=events) as rd, peer(private_broker) as op:
        ref.append(rd)
        d = rd.daemon
        await wait_until(lambda: d.safety_io.inputs.safe and d.mqtt.connected, "safe inputs, mqtt connected")
        await d.start_measurement()
        await first_of(paused.wait(), rd.task, "the run paused at its first loop")
        run_id = d.engine.run_id if d.engine else None
        await wait_until(lambda: modbus_sim.light == "yellow" and modbus_sim.running, "stack light yellow")
        if fault == "modbus_link":
            await modbus_sim.stop()  # link loss counts as not cleared
        else:
            modbus_sim.set_input(fault, False)  # type: ignore[arg-type]
        # the run cannot end without the interlock: it is paused until the trip interrupts it
        with pytest.raises(InterlockTrip) as trip:
            await run_end(rd)
        assert trip.value.watcher == "aut_inputs"
        expected = {"area_cleared": "area cleared", "estop_ok": "E-stop", "modbus_link": "safety inputs invalid"}
        assert expected[fault] in trip.value.detail
        await op.wait_for(lambda _: any(a.get("data", {}).get("watcher") == "aut_inputs"
                                        for a in op.json_on(f"{PREFIX}/alarm")), "the interlock alarm")
        alarm = next(a for a in op.json_on(f"{PREFIX}/alarm") if a.get("data", {}).get("watcher") == "aut_inputs")
        assert alarm["kind"] == "alarm" and alarm["run_id"] == run_id and expected[fault] in alarm["message"]
        if fault != "modbus_link":
            await wait_until(lambda: modbus_sim.light == "red" and not modbus_sim.running, "stack light red")
    assert sim.interpreter.state is not ProState.ACTIVE
    assert run_id is not None
    run = await stored_run(cfg, run_id)
    assert run.state == RunState.FAILED and "aut_inputs" in (run.detail or "")
