"""The Python client (:mod:`rgse_daemon.client`) against a real daemon on the simulated KR C4 and a private
Mosquitto: a campaign from a points file confirmed prompt by prompt, a measurement with its typed result and
report, an abort, refusals with the daemon's reason, deadlines, and the blocking client from a plain thread."""

from __future__ import annotations

import asyncio
import json
import uuid
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.client import (
    CalibrationResult,
    MeasurementResult,
    Prompt,
    Refused,
    RgseClient,
    RunFailed,
    RunKind,
    SyncClient,
    WaitTimeout,
    load_points,
)
from rgse_daemon.config import config_from_mapping
from rgse_daemon.errors import DataError
from rgse_daemon.io.operator import Unreachable
from rgse_daemon.store import RunState, Store
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.client import operator_at, write_points
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess, free_port
from tests.support.polling import wait_until

DUT_MASS_KG = 95.0
DUT = dut_payload(DUT_MASS_KG, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)
POINTS_TOML = """\
[[point]]
kind = "zero"
mass_kg = 0.0
lever_a3_m = 1.3
lever_a5_m = 0.3
"""


def cfg_for(tmp_path: Path, sim: SimulatedKrc4, broker: MosquittoProcess, **measurement: Any):
    return daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                         broker_port=broker.port, **measurement)


async def test_a_campaign_from_a_points_file_confirmed_prompt_by_prompt(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path, sim, private_broker, loops=1)
    points = load_points(write_points(tmp_path / "campaign.toml"))
    seen: list[Prompt] = []
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        run = await rgse.calibrate(points, method="auto")
        assert run.run_id is not None and run.kind == "calibration"
        result = await run.wait(120, on_prompt=operator_at(sim, seen))
        assert isinstance(result, CalibrationResult)
        assert result.run_id == run.run_id and result.points == len(points) == 5
        assert result.loo_mean_abs_err_pct is not None and result.loo_mean_abs_err_pct > 0  # 5 points: a few %
        kinds = [ev.kind for ev in rgse.events_of(run.run_id)]
        # each event's time as the daemon sent it, in order
        times = [datetime.fromisoformat(str(ev.time)) for ev in rgse.events_of(run.run_id)]
        assert times == sorted(times) and all(t.utcoffset() == timedelta(0) for t in times)
        assert kinds.count("confirm") == 5 and "loop" in kinds
        assert [ev.state for ev in rgse.events_of(run.run_id) if ev.kind == "state"][-1] == "done"
        # the retained result is there for a client that connects later, too
        async with RgseClient.of(cfg) as later:
            again = await later.result(run.run_id, timeout_s=10)
        assert again == result
        report = await rgse.report(calibration_id=result.calibration_id, out_dir=tmp_path / "reports")
    assert [p.point_index for p in seen] == [0, 1, 2, 3, 4]
    assert [(p.kind, p.n_cb) for p in seen] == [("zero", 0), ("mass", 2), ("mass", 5), ("mass", 10), ("torque", 10)]
    assert report.is_file() and result.calibration_id in report.read_text()
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        said = [e.message for e in await store.events(run_id=run.run_id) if e.kind == "operator_confirmed"]
        active = await store.active_calibration(cfg.robot.name)
    assert len(said) == 5 and said[0].endswith("mounted point 0")
    assert active is not None and active.id == result.calibration_id


async def test_a_measurement_its_typed_result_and_report(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path, sim, private_broker)
    cal_id = await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        assert (await rgse.ready(10)).engine == "idle"
        run = await rgse.measure(loops=2)
        with pytest.raises(Refused, match="busy"):  # one run at a time: the daemon's own words
            await rgse.measure()
        steps = [ev.step async for ev in run.events(60) if ev.kind == "step"]
        result = await rgse.result(run.run_id or "", "measurement", timeout_s=30)
        report = await rgse.report(run.run_id, out_dir=tmp_path / "reports")
    assert "loop" in steps or "measurement-pose" in steps, steps
    assert isinstance(result, MeasurementResult) and result.calibration_id == cal_id and result.loops == 2
    assert result.U_kg is not None and abs(result.mass_kg - DUT_MASS_KG) < 3 * result.U_kg
    assert report.is_file() and run.run_id in report.read_text()


async def test_abort_a_waiting_campaign_and_refusals_carry_the_daemons_reason(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path, sim, private_broker, loops=1)
    points = load_points(write_points(tmp_path / "campaign.toml"))
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        run = await rgse.calibrate(points)
        prompt = await run.next_prompt(60)
        assert (prompt.point_index, prompt.kind) == (0, "zero")
        with pytest.raises(Refused, match="waits for point 0, not point 3"):
            await rgse.confirm(run.run_id or "", point=3)
        with pytest.raises(WaitTimeout, match="a prompt of run"):  # nothing new comes while nobody confirms
            await run.next_prompt(0.5)
        await run.abort("the crane is needed elsewhere")
        with pytest.raises(RunFailed, match="aborted") as failed:
            await run.wait(60)
        assert failed.value.state == "aborted" and "crane" in failed.value.reason
        with pytest.raises(Refused):
            await rgse.confirm(run.run_id or "")
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        assert (await store.get_run(run.run_id or "")).state == RunState.ABORTED


async def test_the_blocking_client_from_a_plain_thread(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path, sim, private_broker)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)

    def script() -> MeasurementResult:  # what a notebook cell does
        with SyncClient.of(cfg) as rgse:
            assert rgse.ready(10).connected
            result = rgse.measure(loops=1).wait(60)
            assert isinstance(result, MeasurementResult)
            return result

    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        result = await asyncio.to_thread(script)
    assert result.loops == 1 and result.U_kg is not None and abs(result.mass_kg - DUT_MASS_KG) < 3 * result.U_kg


async def test_no_broker_is_unreachable_within_the_deadline(tmp_path: Path) -> None:
    cfg = config_from_mapping({"robot": {"name": "KR-X"}, "paths": {"data_dir": str(tmp_path)},
                               "mqtt": {"enabled": True, "host": "127.0.0.1", "port": free_port(),
                                        "command_tokens": ["t"]}}, "<test>")
    with pytest.raises(Unreachable, match="cannot connect"):
        async with RgseClient.of(cfg, timeout_s=2):
            pass  # entering is what fails: no broker on that port


async def test_a_message_nested_too_deeply_does_not_end_the_clients_reading(tmp_path: Path) -> None:
    """Whoever may publish under the prefix can send anything; the client reads on (a RecursionError from json
    ended its reader without a word, and every wait then ran to its deadline)."""
    prefix = f"rgse-test/{uuid.uuid4().hex[:12]}"
    cfg = config_from_mapping({"robot": {"name": "KR-X"}, "paths": {"data_dir": str(tmp_path)},
                               "mqtt": {"enabled": True, "host": "127.0.0.1", "port": 1883, "prefix": prefix,
                                        "command_tokens": ["t"]}}, "<test>")
    async with RgseClient.of(cfg, timeout_s=5) as rgse, Collector("127.0.0.1", 1883, f"{prefix}/nothing") as peer:
        await peer.publish(f"{prefix}/state", b"[" * 60000)
        await peer.publish(f"{prefix}/state", json.dumps({"engine": "idle", "connected": True}))
        state = await rgse.state(5)
    assert state.engine == "idle" and state.connected


def test_a_points_file_names_the_bad_point(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text(POINTS_TOML)
    assert [p.kind for p in load_points(good)] == ["zero"]
    for text, fragment in [
        (POINTS_TOML.replace('"zero"', '"heavy"'), "#1: kind"),
        (POINTS_TOML + "mass = 3\n", "#1: unknown key(s) mass"),
        (POINTS_TOML.replace("lever_a5_m = 0.3", 'lever_a5_m = "x"'), "#1: lever_a5_m"),
        ("", "no [[point]] tables"),
        ("[[point]\n", "cannot read the points file"),
    ]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(DataError, match=r"bad\.toml") as err:
            load_points(bad)
        assert fragment in str(err.value), (fragment, str(err.value))


async def test_a_lost_broker_ends_the_wait_at_once_not_at_its_deadline(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path, sim, private_broker, loops=1)
    points = load_points(write_points(tmp_path / "campaign.toml"))
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as rgse:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        run = await rgse.calibrate(points)
        await run.next_prompt(60)
        await private_broker.stop()
        t0 = asyncio.get_running_loop().time()
        with pytest.raises(Unreachable, match="connection lost"):
            await run.next_prompt(300)
        assert asyncio.get_running_loop().time() - t0 < 60  # a hang guard: the deadline was 300 s
        with pytest.raises(Unreachable, match="connection lost"):
            await rgse.confirm(run.run_id or "")
        rd.daemon.engine.abort("test over")


async def test_a_measurement_that_the_daemon_accepted_as_a_properties_run_is_one_in_the_client() -> None:
    """``[properties] when = "every_measurement"``: ``measure`` starts a properties run (test_properties_run.py,
    over the broker); the handle takes the kind the reply names, so its result is read with the CoG."""
    client = RgseClient.of(config_from_mapping({"mqtt": {"enabled": True, "command_auth": "open_lab_bench"}}))
    for kind in (RunKind.PROPERTIES, RunKind.MEASUREMENT):
        async def reply(verb: str, fields: dict[str, Any], accepted: str = kind.value) -> dict[str, Any]:
            assert verb == "measure"
            return {"ok": True, "accepted": accepted, "run_id": "r-1"}  # the reply as the daemon sends it
        client._command = reply  # type: ignore[method-assign]  # no broker needed for what the reply says
        assert (await client.measure()).kind == kind
