"""``examples/scripted_campaign.py`` against the daemon on the simulated KR C4 and a private Mosquitto: the lab's
own load sequence confirmed load by load, and a retry after the first attempt fails on an interlock trip (somebody
turns the mode selector to AUT mid-campaign)."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from rgse_daemon.client import CalibrationResult, Prompt, RgseClient, RunFailed
from rgse_daemon.store import RunState, Store
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config, running_daemon
from tests.support.mqtt import MosquittoProcess
from tests.support.polling import wait_until

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "scripted_campaign.py"


def example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("scripted_campaign", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


async def test_scripted_campaign_retries_after_an_interlock_trip(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    ex = example()
    points = ex.load_sequence([2, 5, 10], [1.011])
    assert [(p.kind, p.mass_kg) for p in points] == [("zero", 0.0), ("mass", 41.86), ("mass", 104.65),
                                                     ("mass", 209.3), ("torque", 228.5)]
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1)
    mounted: list[tuple[str, int]] = []
    retries: list[tuple[int, str]] = []

    async def mount(prompt: Prompt) -> str:
        sim.mount(campaign_point_payload(dataclasses.asdict(prompt)))
        mounted.append((prompt.run_id, prompt.point_index))
        if not retries and prompt.point_index == 2:
            sim.set_mode("AUT")  # somebody turns the key while the operator confirms: the interlock must trip
        return f"point {prompt.point_index} mounted"

    async def on_retry(attempt: int, error: Exception) -> None:
        retries.append((attempt, str(error)))
        sim.set_mode("T1")  # the key back to T1
        sim.acknowledge()

    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        result = await ex.campaign(rgse, points, mount, attempts=3, run_timeout_s=120, on_retry=on_retry)
    assert isinstance(result, CalibrationResult) and result.points == 5
    assert len(retries) == 1 and retries[0][0] == 2, retries
    assert retries[0][1].startswith(f"run {mounted[0][0]} failed: ") and "AUT" in retries[0][1], retries
    first, second = dict.fromkeys(run for run, _ in mounted)
    assert [i for run, i in mounted if run == first] == [0, 1, 2]
    assert [i for run, i in mounted if run == second] == [0, 1, 2, 3, 4] and second == result.run_id
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        assert (await store.get_run(first)).state == RunState.FAILED
        assert (await store.get_run(second)).state == RunState.COMPLETED
        active = await store.active_calibration(cfg.robot.name)
    assert active is not None and active.id == result.calibration_id


async def test_scripted_campaign_aborts_its_run_at_end_of_input(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue #34: at end of input the example died with an EOFError traceback and left the daemon's run waiting for
    a confirm. Now the prompt's end of input aborts the run (not retried), as ``rgse run`` does."""
    ex = example()

    def no_more_input(prompt: str = "") -> str:
        raise EOFError

    monkeypatch.setattr("builtins.input", no_more_input)
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1)
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        with pytest.raises(RunFailed, match="end of input") as failed:
            await ex.campaign(rgse, ex.load_sequence([2], [1.011]), ex.ask_on_terminal, attempts=3,
                              run_timeout_s=60)
        await wait_until(lambda: not rd.daemon.run_active, "the daemon's run ended")
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        assert (await store.get_run(failed.value.run_id)).state == RunState.ABORTED
        assert len(await store.list_runs(robot=cfg.robot.name)) == 1  # an operator's end: not retried
