"""Two robots, one store, one broker: two daemons (two simulated KR C4s with different robot names) on one
PostgreSQL schema and one Mosquitto, each driven by its own client. Runs go in parallel; each robot measures with
its own calibration only; topics stay apart; no result is lost or crossed."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon import calfile
from rgse_daemon.client import CalibrationResult, MeasurementResult, Refused, RgseClient
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.store import RunKind, RunState, Store
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.client import operator_at, short_points
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess
from tests.support.pg import PgSchemas
from tests.support.polling import wait_until

ROBOT_A, ROBOT_B = "KR500R2830-A", "KR500R2830-B"
DUT_A_KG, DUT_B_KG = 95.0, 60.0
TIME_SCALE = 100.0


@pytest.fixture
def pg_url() -> Any:
    schemas = PgSchemas()
    yield schemas.new_url()
    schemas.drop_all()


@pytest.fixture
async def sims(tmp_path: Path) -> AsyncIterator[tuple[SimulatedKrc4, SimulatedKrc4]]:
    async with (SimulatedKrc4(tmp_path / "share-a", seed=7, time_scale=TIME_SCALE, latency_s=0.0) as a,
                SimulatedKrc4(tmp_path / "share-b", seed=8, time_scale=TIME_SCALE, latency_s=0.0) as b):
        for s in (a, b):
            s.install_globals(globals_dat_text())
        yield a, b


def robot_config(tmp_path: Path, robot: str, sim: SimulatedKrc4, broker: MosquittoProcess, store_url: str) -> Config:
    """One daemon's configuration: its own robot name, controller and data directory; the shared store and broker."""
    base = daemon_config(tmp_path / robot, controller_port=sim.port, share_dir=sim.share_dir,
                         broker_port=broker.port, loops=1)
    doc = base.model_dump(mode="json")
    doc["robot"]["name"] = robot
    doc["store"]["url"] = store_url
    return config_from_mapping({k: v for k, v in doc.items() if v is not None}, f"<{robot}>")


async def test_two_daemons_share_one_postgresql_and_one_broker(
        sims: tuple[SimulatedKrc4, SimulatedKrc4], private_broker: MosquittoProcess, pg_url: str,
        calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    sim_a, sim_b = sims
    cfg_a = robot_config(tmp_path, ROBOT_A, sim_a, private_broker, pg_url)
    cfg_b = robot_config(tmp_path, ROBOT_B, sim_b, private_broker, pg_url)
    # B is calibrated (a calibration fitted for B, sealed as rgse calibrate writes it), A is not
    cal_b = await seed_calibration(cfg_b, calfile.seal({**calibration_doc, "robot": ROBOT_B}))

    everything = Collector("127.0.0.1", private_broker.port, "rgse/#")
    async with (everything, running_daemon(cfg_a) as da, running_daemon(cfg_b) as db,
                RgseClient.of(cfg_a) as a, RgseClient.of(cfg_b) as b):
        await wait_until(lambda: da.daemon.mqtt.connected and db.daemon.mqtt.connected, "both on the broker")
        await asyncio.gather(a.ready(30), b.ready(30))
        # A without a calibration cannot measure; B's calibration is not used for it
        sim_a.mount(dut_payload(DUT_A_KG, (0.0, 0.05, 0.25), fixture_mass_kg=10.288))
        with pytest.raises(Refused, match=f"robot {ROBOT_A}: no active calibration"):
            await a.measure()
        # in parallel: A's campaign, B's measurement
        sim_b.mount(dut_payload(DUT_B_KG, (0.0, 0.05, 0.25), fixture_mass_kg=10.288))
        campaign = await a.calibrate(short_points(), method="auto")
        measure_b = await b.measure(loops=2)
        cal_a, first_b = await asyncio.gather(campaign.wait(180, operator_at(sim_a)), measure_b.wait(180))
        # in parallel again: both measure, each with its own calibration
        sim_a.mount(dut_payload(DUT_A_KG, (0.0, 0.05, 0.25), fixture_mass_kg=10.288))
        runs = await asyncio.gather(a.measure(loops=2), b.measure(loops=2))
        m_a, m_b = await asyncio.gather(*(r.wait(180) for r in runs))
        await everything.sync()
        seen_by_a, seen_by_b = set(a.results()), set(b.results())

    assert isinstance(cal_a, CalibrationResult) and cal_a.robot == ROBOT_A
    for result, robot, cal_id, dut_kg in [(first_b, ROBOT_B, cal_b, DUT_B_KG), (m_a, ROBOT_A, cal_a.calibration_id,
                                                                                   DUT_A_KG),
                                          (m_b, ROBOT_B, cal_b, DUT_B_KG)]:
        assert isinstance(result, MeasurementResult)
        assert (result.robot, result.calibration_id) == (robot, cal_id), result
        # the DuTs differ by 35 kg: a crossed result would be far from its robot's DuT (the accuracy itself is the
        # subject of the measurement tests; B's seeded calibration is from another thermal state, and says so)
        assert abs(result.mass_kg - dut_kg) < 10.0, result
    # topics apart: each daemon's messages under its own prefix only, each client saw only its robot's results
    runs_a = {campaign.run_id, m_a.run_id}
    runs_b = {measure_b.run_id, first_b.run_id, m_b.run_id}
    assert not runs_a & runs_b
    topics = {m.topic.value for m in everything.messages}
    for run_id in runs_a:
        assert not any(t.startswith(f"rgse/{ROBOT_B}/run/{run_id}") for t in topics)
    for run_id in runs_b:
        assert not any(t.startswith(f"rgse/{ROBOT_A}/run/{run_id}") for t in topics)
    assert seen_by_a == {campaign.run_id, m_a.run_id} and seen_by_b == {first_b.run_id, m_b.run_id}
    # the store: every run of each robot, its result, nothing crossed
    async with await Store.open(pg_url, tmp_path / "reader", timeout_s=10.0) as store:
        stored_a = await store.list_runs(robot=ROBOT_A)
        stored_b = await store.list_runs(robot=ROBOT_B)
        active_a = await store.active_calibration(ROBOT_A)
        active_b = await store.active_calibration(ROBOT_B)
    assert {r.id for r in stored_a} == runs_a and {r.id for r in stored_b} == runs_b
    assert [r.state for r in stored_a if r.kind == RunKind.MEASUREMENT and r.id == m_a.run_id] == [
        RunState.COMPLETED]
    assert active_a is not None and active_a.id == cal_a.calibration_id
    assert active_b is not None and active_b.id == cal_b
