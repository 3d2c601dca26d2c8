"""A mass-properties run from the Python client (issue #16's leftover): ``SyncClient.properties`` (the blocking face
over ``RgseClient.properties``) against the daemon on the simulated KR C4 and a private Mosquitto, with its typed
result; a refusal raises :class:`Refused` with the daemon's reason."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.client import FixtureFrame, PropertiesResult, Refused, SyncClient
from simulators.krc4 import physics as ph
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess
from tests.support.polling import wait_until

WING_BOX = ph.refex_wing_box()
#: The paper's settling after each brake-release move, 4 s simulated (the sim runs at 100x): the traces hold still,
#: as the offline campaign that fitted the calibration did.
SETTLE_S = 4.0 / 100.0


async def test_sync_client_runs_properties_and_gets_the_typed_result(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, cog_calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1, fixture_mass_kg=ph.FIXTURE_MASS_KG,
                        settle_s=SETTLE_S)
    await seed_calibration(cfg, cog_calibration_doc)
    sim.mount(WING_BOX.payload())
    fixture = FixtureFrame(ph.fixture_cog_flange_m(), WING_BOX.dut_origin_flange_m, WING_BOX.dut_abc_deg)

    def script() -> tuple[PropertiesResult, str]:  # what a notebook does, in a plain thread
        with SyncClient.of(cfg) as rgse:
            rgse.ready(30.0)
            with pytest.raises(Refused, match="scheme 'full'"):  # the calibration has the paper poses only
                rgse.properties(scheme="full", fixture=fixture)
            run = rgse.properties(scheme="paper", loops_per_pose=1, fixture=fixture)
            assert run.kind == "properties" and run.run_id
            result = run.wait(120.0)
            return result, run.run_id

    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        result, run_id = await asyncio.to_thread(script)
    assert isinstance(result, PropertiesResult) and result.run_id == run_id
    assert abs(result.mass_kg - WING_BOX.mass_kg) <= result.U_kg
    assert len(result.cog_m) == 3 and all(u > 0 for u in result.U_cog_m)
    assert result.cog_dut_m is not None and result.raw["cog"]["scheme"] == "paper"
