"""A run request the daemon answers "no" (busy, not connected, safety latch, operating mode, no active calibration)
is not a run that failed: the requester gets the reason, the daemon publishes one ``run_refused`` message with it,
and the stack light is left as it was — red stays the colour of something that happened to the robot or a run.

Against the simulated KR C4 on a real socket, a private Mosquitto and the Modbus I/O simulator (the stack light's
coils), with the daemon in-process."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.safety.latch import SafetyLatch
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.variables import ProState
from simulators.modbus_io import ModbusIoSim
from tests.support.daemon import PREFIX, command, daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess, free_port
from tests.support.polling import wait_until

ALARM = f"{PREFIX}/alarm"


def peer(broker: MosquittoProcess) -> Collector:
    return Collector("127.0.0.1", broker.port, f"{PREFIX}/cmd/+/reply", ALARM)


def kinds(op: Collector) -> list[str]:
    return [a.get("kind") for a in op.json_on(ALARM)]


@pytest.mark.parametrize("why", ["no-calibration", "aut-area-not-cleared"])
async def test_a_run_refused_in_its_start_checks_is_published_as_refused_and_leaves_the_light_green(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, modbus_sim: ModbusIoSim,
        calibration_doc: dict[str, Any], tmp_path: Path, why: str) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, modbus_port=modbus_sim.port, loops=1)
    if why == "aut-area-not-cleared":
        await seed_calibration(cfg, calibration_doc)
        modbus_sim.set_input("aut_permitted", True)  # the key is turned, but the area is not cleared
        sim.set_mode("AUT")
        expected = "AUT needs the area cleared, the AUT key and E-stop OK"
    else:
        expected = "no active calibration"
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        d = rd.daemon
        await wait_until(lambda: d.mqtt is not None and d.mqtt.connected and d.safety_io.inputs.valid,
                         "mqtt up, safety inputs read")
        await wait_until(lambda: modbus_sim.light == "green", "stack light green (idle)")
        reply = await command(op, "measure", {"loops": 1})
        assert reply["ok"] is False and expected in reply["error"], reply  # the requester gets the reason
        await op.wait_for(lambda _: "run_refused" in kinds(op), "the run_refused message")
        await op.sync()
        (refused,) = [a for a in op.json_on(ALARM) if a["kind"] == "run_refused"]
        assert refused["run_kind"] == "measurement" and expected in refused["reason"]
        assert refused["reason"] == reply["error"] and expected in refused["message"] and refused["time"]
        assert "run_failed" not in kinds(op)  # nothing failed: no run started, nothing moved
        assert d.light.color == "green"  # the wish is unchanged (a red one would be set before the publish)
        await asyncio.sleep(0.3)  # a red write would reach the module's coils within a poll
        assert modbus_sim.light == "green" and not modbus_sim.running
        c = d.counters
        assert c.runs_refused == 1 and c.runs_started == 0 and not d.run_active
        assert await d.store.list_runs(robot=cfg.robot.name) == []
    assert sim.interpreter.state is not ProState.ACTIVE


async def test_a_request_refused_by_the_safety_latch_is_published_as_refused_not_failed(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    SafetyLatch(cfg.paths.data_dir).set("stop not confirmed (test)")
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt is not None and rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "calibrate", {})
        assert reply["ok"] is False and "safety latch set" in reply["error"], reply
        await op.wait_for(lambda _: "run_refused" in kinds(op), "the run_refused message")
        await op.sync()
        (refused,) = [a for a in op.json_on(ALARM) if a["kind"] == "run_refused"]
        assert refused["run_kind"] == "calibration" and refused["reason"] == reply["error"]
        assert "run_failed" not in kinds(op)
        assert rd.daemon.counters.runs_refused == 1


async def test_a_request_without_a_controller_link_is_published_as_refused_not_connected(
        private_broker: MosquittoProcess, tmp_path: Path) -> None:
    port = free_port()  # nothing listens here
    cfg = daemon_config(tmp_path / "data", controller_port=port, broker_port=private_broker.port)
    async with running_daemon(cfg, connected=False) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt is not None and rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "properties", {})
        assert reply["ok"] is False and reply["error"].startswith("not connected: "), reply
        await op.wait_for(lambda _: "run_refused" in kinds(op), "the run_refused message")
        await op.sync()
        (refused,) = [a for a in op.json_on(ALARM) if a["kind"] == "run_refused"]
        assert refused["run_kind"] == "properties" and refused["reason"] == reply["error"]
        assert "run_failed" not in kinds(op)
