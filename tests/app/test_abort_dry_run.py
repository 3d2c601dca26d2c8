"""Issue 31 6b: ``abort`` refers to the run in progress, a dry run included.

The daemon (in-process, on the simulated KR C4 over its socket and a private Mosquitto) has finished one real
measurement; then a dry run starts over MQTT (on a slow link, so that it lasts) and the operator sends ``abort``.
The reply must name the dry run (it has no run id) and not the finished run, and the dry run must end aborted."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.procedures.engine import PlanAborted
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import PREFIX, Events, command, daemon_config, run_end, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess

#: Added to every controller reply while the dry run goes: it reads the controller's state and programs, so it lasts
#: seconds; long enough for an abort to find it running.
SLOW_LINK_S = 0.15
DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)


async def test_abort_during_a_dry_run_names_the_dry_run_and_stops_it(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1)
    await seed_calibration(cfg, calibration_doc)
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd, \
            Collector("127.0.0.1", private_broker.port, f"{PREFIX}/cmd/+/reply") as op:
        d = rd.daemon
        sim.mount(DUT)
        await d.start_measurement()
        await run_end(rd)
        finished = d.engine.run_id if d.engine is not None else None
        assert finished is not None
        seen = len(events.events)
        sim.server.faults.extra_latency_s = SLOW_LINK_S
        reply = await command(op, "measure", {"dry_run": True})
        assert reply["ok"] is True and reply["dry_run"] is True and reply["run_id"] is None
        await events.wait_for(lambda ev: ev in events.events[seen:] and ev.kind == "step", "the dry run's first step")
        aborted = await command(op, "abort", {"reason": "operator stops the dry run"})
        assert aborted["ok"] is True, aborted
        assert aborted["aborting"] is None and aborted["dry_run"] is True, aborted  # not the finished run
        with pytest.raises(PlanAborted, match="operator stops the dry run"):
            await run_end(rd)
        sim.server.faults.extra_latency_s = 0.0
        assert d.engine is not None and d.engine.run_id == finished  # the real engine untouched
        states = [ev.data["state"] for ev in events.events[seen:] if ev.kind == "state"]
        assert states[-1] == "aborted", states
