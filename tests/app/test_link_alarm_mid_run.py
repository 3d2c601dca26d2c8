"""Issue 31 6f: the ``link`` alarm (docs/interfaces.md §4.2) is raised when the controller link drops mid-run.

The daemon (in-process) runs a measurement on the simulated KR C4 over its socket and a private Mosquitto; while
a loop records, the controller goes away (its server closes every connection and stops listening, as a cable
pulled for a few seconds). The interlock trips and the run fails. The link is back before the run has
ended (the outage is over before the daemon's idle probe could see it); an operator's MQTT client must also get the
``link`` alarm, once."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.errors import LinkError
from rgse_daemon.safety.monitor import InterlockTrip
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import PREFIX, Events, daemon_config, run_end, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess
from tests.support.polling import wait_until

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)


async def test_a_link_dropped_mid_run_raises_the_link_alarm(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=5)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd, \
            Collector("127.0.0.1", private_broker.port, f"{PREFIX}/alarm") as op:
        await wait_until(lambda: rd.daemon.mqtt is not None and rd.daemon.mqtt.connected, "mqtt connected")
        await rd.daemon.start_measurement()
        await events.wait_for(lambda ev: ev.kind == "loop", "a loop recording")
        port = sim.port
        await sim.server.close()  # the link goes: every connection dropped, nothing listens
        monitor = rd.daemon.engine.monitor if rd.daemon.engine is not None else None
        assert monitor is not None
        await wait_until(lambda: monitor.trip is not None, "the interlock's trip", 30)
        assert monitor.trip is not None and monitor.trip.watcher == "link", monitor.trip
        sim.server.config.port = port  # back at the same address before the run has ended
        await sim.server.start()
        with pytest.raises((InterlockTrip, LinkError), match="link"):  # the trip, or a step's request, first
            await run_end(rd)
        await op.wait_for(lambda _: any(a.get("kind") == "link" for a in op.json_on(f"{PREFIX}/alarm")),
                          "the link alarm")
    link = [a for a in op.json_on(f"{PREFIX}/alarm") if a.get("kind") == "link"]
    assert len(link) == 1 and "link lost during a run" in link[0]["message"], link
    assert rd.daemon.counters.link_losses == 1
