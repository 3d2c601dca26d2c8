"""The mass-properties run end to end (issue #14): an MQTT ``properties`` command → the daemon → the simulated KR C4
on a real socket (mass loops, then every CoG pose, each motion through the interlock's static check) → the
retained result with ``cog_m`` and U → the stored run → the HTML report with its CoG table. And the refusals: a bad
fixture (schema), a fixture with a mass but no CoG, a calibration without a torsional section."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rgse_daemon.commands.status import _result_line
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.errors import ConfigError
from rgse_daemon.store import Repository, RunKind, RunState
from simulators.krc4 import physics as ph
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import (
    PREFIX,
    Events,
    command,
    daemon_config,
    first_of,
    run_end,
    running_daemon,
    seed_calibration,
)
from tests.support.mqtt import Collector, MosquittoProcess, retained
from tests.support.polling import wait_until

WING_BOX = ph.refex_wing_box()
#: The paper's settling after each brake-release move, 4 s simulated (the sim runs at 100x): the traces hold still,
#: as the offline campaign that fitted the calibration did.
SETTLE_S = 4.0 / 100.0


def _config(sim: SimulatedKrc4, broker: MosquittoProcess, data_dir: Path, **properties: Any) -> Config:
    base = daemon_config(data_dir, controller_port=sim.port, share_dir=sim.share_dir, broker_port=broker.port,
                         loops=2, fixture_mass_kg=ph.FIXTURE_MASS_KG, settle_s=SETTLE_S)
    data = base.model_dump(mode="json")
    data["properties"] = {"scheme": "paper", "loops_per_pose": 1, **properties}
    return config_from_mapping(data, "<test>")


def peer(broker: MosquittoProcess) -> Collector:
    return Collector("127.0.0.1", broker.port, f"{PREFIX}/cmd/+/reply", f"{PREFIX}/alarm", f"{PREFIX}/run/+/progress",
                     f"{PREFIX}/run/+/result")


async def test_properties_command_measures_mass_and_cog_to_a_retained_result_and_report(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, cog_calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data")
    await seed_calibration(cfg, cog_calibration_doc)
    sim.mount(WING_BOX.payload())
    events = Events()
    fixture = {"cog_flange_m": list(ph.fixture_cog_flange_m()),
               "dut_origin_flange_m": list(WING_BOX.dut_origin_flange_m), "dut_abc_deg": list(WING_BOX.dut_abc_deg)}
    async with running_daemon(cfg, on_event=events) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "properties", {"fixture": fixture})
        assert reply["ok"] is True and reply["accepted"] == "properties" and reply["scheme"] == "paper"
        run_id = reply["run_id"]
        assert rd.daemon.run_kind == "properties"
        result = await run_end(rd, timeout_s=120.0)
        await first_of(op.wait_for(lambda ms: any(m.topic.value == f"{PREFIX}/run/{run_id}/result" for m in ms),
                                   "the result"),
                       rd.task, "the retained result")
    truth = sim.truth
    assert truth is not None
    # the steps in order: mass loops in the measurement pose, which are the CoG pose meas's loops too (issue #35),
    # then the scheme's other pose with its loop
    steps = [e.step for e in events.events if e.step in ("mass", "cog", "pose", "compute")]
    assert steps == ["mass", "cog", "pose", "compute"]
    assert [e.data["pose"] for e in events.events if e.step == "pose"] == ["A6+90"]
    assert result["cog_poses"][0]["name"] == "meas" and result["cog_poses"][0]["traces"] == result["mass_traces"]

    # the retained result, as a fresh subscriber gets it
    (msg,) = await retained("127.0.0.1", private_broker.port, f"{PREFIX}/run/{run_id}/result")
    doc = json.loads(msg.payload)
    assert doc == json.loads(json.dumps(result))
    assert len(doc["cog_m"]) == 3 and len(doc["U_cog_m"]) == 3 and doc["k"] == 2
    assert doc["run_kind"] == "properties" and doc["cog"]["scheme"] == "paper" and doc["cog"]["n_poses"] == 2
    assert abs(doc["mass_kg"] - WING_BOX.mass_kg) <= doc["U_kg"]
    # the CoG itself: U per coordinate, and the DuT's true CoG (as the simulator mounted it) at least on the same side
    # of the flange axis. Its accuracy against the truth is the demo test's and bench/cog.py's: there the torsional
    # calibration is measured on the same simulated robot through the daemon; here it is fitted offline
    # (tests/support/cogcal.py) on the in-process robot model, which since the simulator's dynamics (issue #15)
    # reads a few Nm differently in the CoG poses (measured: 4/4/55 mm off the truth against U 3.6/3.5/39 mm)
    true_dut_m = (truth.payload_mass_kg * np.asarray(truth.payload_cog_flange_m)
                  - ph.mpa().mass_kg * np.asarray(ph.mpa().cog_flange_m)
                  - ph.FIXTURE_MASS_KG * np.asarray(ph.fixture_cog_flange_m())) / WING_BOX.mass_kg
    assert np.all(np.asarray(doc["U_cog_m"]) > 0) and np.all(np.isfinite(doc["cog_m"]))
    assert np.all(np.sign(doc["cog_m"]) == np.sign(true_dut_m)), (doc["cog_m"], true_dut_m)
    # the DuT frame: the wing box's frame is turned 90° about the flange axis
    assert doc["cog_dut_m"][0] == pytest.approx(doc["cog_m"][1] - WING_BOX.dut_origin_flange_m[1], abs=1e-9)
    # `rgse status` shows it
    line = _result_line(doc)
    assert line.startswith(f"mass {doc['mass_kg']:.3f} kg") and f"x {1000 * doc['cog_m'][0]:.2f} ± " in line

    # stored: the run, its result, the properties run directory that `rgse cog` reads
    with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
        run = repo.get_run(run_id)
        assert run.state == RunState.COMPLETED and run.kind == RunKind.PROPERTIES
        assert run.config["properties"]["scheme"] == "paper"
        (stored,) = repo.results(run_id)
        assert stored.result["cog_m"] == doc["cog_m"]
        from rgse_daemon.report import build_report

        page = build_report(repo, cfg.paths.data_dir, tmp_path / "report", run_id=run_id)
    html = page.read_text(encoding="utf-8")
    assert "Centre of gravity" in html and "±2.5 mm" in html and "cog-figure" in html


async def test_properties_refused_without_cog_calibration_or_with_a_bad_fixture(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data")
    assert "torsional" not in calibration_doc
    await seed_calibration(cfg, calibration_doc)  # a mass-only calibration: no CoG
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        bad = await command(op, "properties", {"fixture": {"cog_flange_m": [0.0, 0.05]}})
        assert bad["ok"] is False and "fixture.cog_flange_m" in bad["error"]
        far = await command(op, "properties", {"fixture": {"cog_flange_m": [0.0, 0.0, 7.0]}})
        assert far["ok"] is False and "fixture.cog_flange_m.2" in far["error"]
        no_cog = await command(op, "properties", {})  # the config's fixture has 10.288 kg and no CoG
        assert no_cog["ok"] is False and "properties.fixture.cog_flange_m" in no_cog["error"]
        no_tors = await command(op, "properties", {"fixture": {"cog_flange_m": [0.0, 0.0, 0.04]}})
        assert no_tors["ok"] is False and "no torsional section" in no_tors["error"]
        assert not rd.daemon.run_active
        alarms = op.json_on(f"{PREFIX}/alarm")
        assert any(a.get("kind") == "refused_command" and a.get("verb") == "properties" for a in alarms)


async def test_every_measurement_is_a_properties_run_when_configured(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data", when="every_measurement",
                  fixture={"cog_flange_m": list(ph.fixture_cog_flange_m())})
    await seed_calibration(cfg, calibration_doc)  # mass only: the properties run that `measure` starts is refused
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "measure", {"loops": 1})
        assert reply["ok"] is False and "no torsional section" in reply["error"]
        assert rd.daemon.run_kind == "properties" and not rd.daemon.run_active


def test_every_measurement_needs_the_fixture_cog_in_the_config() -> None:
    with pytest.raises(ConfigError, match=r"properties\.fixture\.cog_flange_m"):
        config_from_mapping({"measurement": {"fixture_mass_kg": 10.288}, "properties": {"when": "every_measurement"}})
    with pytest.raises(ConfigError, match=r"properties\.scheme"):
        config_from_mapping({"properties": {"scheme": "eq5"}})
    with pytest.raises(ConfigError, match=r"properties\.fixture\.dut_abc_deg"):
        config_from_mapping({"properties": {"fixture": {"cog_flange_m": [0, 0, 0.05], "dut_abc_deg": [0, 0, 400]}}})
