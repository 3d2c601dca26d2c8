"""Finding 7 of #12, end to end: a NUL and a terminal escape in an abort reason, sent over MQTT to the running
daemon (simulated KR C4, private Mosquitto, real store), reach neither the log nor the store unescaped; the reason
is kept, escaped (raw input is never dropped)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.store import RunState, Store
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import (
    Events,
    command,
    daemon_config,
    first_of,
    run_end,
    running_daemon,
    seed_calibration,
)
from tests.support.mqtt import Collector
from tests.support.polling import wait_until

REASON = "door\x00open\x1b[2J\x07 by QA"
ESCAPED = "door\\x00open\\x1b[2J\\x07 by QA"


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    async with SimulatedKrc4(tmp_path / "share", seed=7, time_scale=100.0, latency_s=0.0) as s:
        s.install_globals(globals_dat_text())
        yield s


async def test_abort_reason_with_control_characters_is_stored_and_logged_escaped(sim, private_broker, tmp_path,
                                                                                caplog, calibration_doc):
    broker = private_broker
    caplog.set_level(logging.INFO)
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=broker.port)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288))
    events = Events()
    running = asyncio.Event()
    events.hooks.append(lambda ev: running.set() if ev.kind == "state" and ev.data.get("state") == "running"
                        else None)
    async with running_daemon(cfg, on_event=events) as rd, \
            Collector("127.0.0.1", broker.port, "rgse/+/cmd/+/reply") as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        started = await command(op, "measure", {"loops": 2})
        assert started["ok"] is True, started
        await first_of(running.wait(), rd.task, "the run is running")
        aborted = await command(op, "abort", {"run_id": started["run_id"], "reason": REASON})
        assert aborted["ok"] is True, aborted
        with pytest.raises(Exception, match=r"door\\x00open"):
            await run_end(rd)
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        run: Any = await store.get_run(started["run_id"])
    assert run.state == RunState.ABORTED and run.detail == ESCAPED
    messages = [r.getMessage() for r in caplog.records]
    assert any(ESCAPED in m for m in messages), messages[-20:]
    assert not any(c in m for m in messages for c in "\x00\x1b\x07")
