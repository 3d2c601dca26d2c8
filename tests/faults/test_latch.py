"""Finding 1 of issue #12, the end of the line: a stop the daemon cannot confirm latches an alarm that stays set —
across a restart — until an operator clears it (``rgse safety clear``), and while it is set no run is admitted."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon import cli
from rgse_daemon.errors import RgseError
from rgse_daemon.link.frames import MsgType
from rgse_daemon.safety.latch import SafetyLatched
from rgse_daemon.store import Store
from simulators.krc4.process import SimProcess
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.faults import ours_active, swept, until_truth

ACCESS = 2


async def test_an_unconfirmed_stop_latches_until_the_operator_clears_it(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path, capsys: Any) -> None:
    data = tmp_path / "data"
    cfg = daemon_config(data, controller_port=sim_proc.port, share_dir=sim_proc.share_dir)
    cfg_file = tmp_path / "rgse.toml"
    cfg_file.write_text(f'[paths]\ndata_dir = "{data}"\n', encoding="utf-8")
    await seed_calibration(cfg, calibration_doc)
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        task = await rd.daemon.start_measurement()
        await until_truth(sim_proc, lambda v: ours_active(v, "RGSE_WARMUP"), "the warm-up moving")
        assert rd.daemon.engine is not None and rd.daemon.engine.monitor is not None
        rd.daemon.engine.monitor.make_safe_deadline_s = 2.0  # the test's patience, not the product's
        await sim_proc.fault("refuse_types", {int(MsgType.PROGRAM_CONTROL): ACCESS})  # every stop refused
        await sim_proc.update("$MODE_OP", "#T2")  # the interlock trips (mode); the controller does not stop
        with pytest.raises(RgseError):
            await asyncio.wait_for(asyncio.shield(task), 60)
        latch = rd.daemon.latch.current()
        assert latch is not None and "stop not confirmed" in latch.reason and "mode" in latch.reason
        with pytest.raises(SafetyLatched, match="safety latch set"):
            await rd.daemon.start_measurement()
        # the robot: a person stops it at the smartPAD; the controller is fine again
        await sim_proc.fault("refuse_types", {})
        await sim_proc.update("$MODE_OP", "#T1")
    # a restart does not clear it
    async with running_daemon(cfg) as rd:
        await swept(rd.daemon)
        with pytest.raises(SafetyLatched):
            await rd.daemon.start_measurement()
        assert await asyncio.to_thread(cli.main, ["safety", "status", "--config", str(cfg_file)]) == 1
        assert "SET" in capsys.readouterr().out
        assert await asyncio.to_thread(cli.main, ["safety", "clear", "--config", str(cfg_file),
                                                  "--message", "robot checked at standstill"]) == 0
        rd.daemon.latch.check()  # cleared: runs are admitted again, without a restart
        assert await asyncio.to_thread(cli.main, ["safety", "status", "--config", str(cfg_file)]) == 0
    assert "robot checked at standstill" in (data / "safety-latch.log").read_text(encoding="utf-8")
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        latched = [e for e in await store.events(limit=100_000) if e.kind == "safety_latch"]
    assert latched and latched[0].level.value == "critical"
