"""A properties run through the daemon on the simulated KR C4 over TCP (issue #35):

* its mass loops are the CoG pose ``meas``'s loops too: recorded in that pose exactly as the pose's own loops would
  be (A4/A6 arriving from below, the A3..A6 trace), archived once, listed by the manifest in ``[measurement]`` and
  in the pose (``shares_measurement_loops``), the pose topped up only to ``loops_per_pose``; ``rgse cog`` on the run
  directory gives the stored CoG;
* a mass the pipeline refuses (a DuT far outside the calibration) ends the run ``completed`` with a result whose
  status is ``refused`` and whose reason says why and that the CoG needs the mass: stored, retained on MQTT, raised
  by the client as :class:`ResultRefused`, printed by ``rgse run properties --json`` as one object (exit 2)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.cli import main
from rgse_daemon.procedures import documents as d
from rgse_daemon.store import RunState, Store, archive_root
from simulators.krc4 import physics as ph
from simulators.krc4.sim import SimulatedKrc4
from tests.app.test_client_cli import rgse_run
from tests.app.test_properties_run import _config, peer
from tests.app.test_replacement_loops import HEAVY
from tests.support.configfile import write_config
from tests.support.daemon import Events, command, run_end, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess
from tests.support.polling import wait_until
from tests.support.refusal import refused_over_mqtt_and_client

WING_BOX = ph.refex_wing_box()
FIXTURE = {"cog_flange_m": list(ph.fixture_cog_flange_m()),
           "dut_origin_flange_m": list(WING_BOX.dut_origin_flange_m), "dut_abc_deg": list(WING_BOX.dut_abc_deg)}


@pytest.mark.timeout(400)
async def test_the_mass_loops_are_the_measurement_pose_loops_of_the_cog(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, cog_calibration_doc: dict[str, Any], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data", loops_per_pose=2)
    cfg = cfg.model_copy(update={"measurement": cfg.measurement.model_copy(update={"loops": 1})})
    await seed_calibration(cfg, cog_calibration_doc)
    sim.mount(WING_BOX.payload())
    events = Events()
    approach: dict[int, list[float]] = {}  # A1..A6's last approach direction as each loop starts recording

    def on_document(doc: d.Document) -> None:
        if isinstance(doc, d.LoopRecording):
            approach[doc.index] = [float(v) for v in sim.model.state.last_approach_sign]

    async with running_daemon(cfg, on_event=events) as rd, peer(private_broker) as op:
        rd.daemon.engine.subscribe_documents(on_document)
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "properties", {"fixture": FIXTURE})
        assert reply["ok"] is True
        run_id = reply["run_id"]
        result = await run_end(rd, timeout_s=300.0)
    (mass_trace,) = result["mass_traces"]
    tag = mass_trace.split("_")[1]
    meas, tilted = result["cog_poses"]
    # the mass loop is the pose's first loop; the pose is topped up to loops_per_pose, the other pose has its own
    assert meas["name"] == "meas" and meas["traces"] == [mass_trace, f"cog_{tag}_p01_l01"], meas
    assert tilted["name"] == "A6+90" and tilted["traces"] == [f"cog_{tag}_p02_l01", f"cog_{tag}_p02_l02"], tilted
    assert result["cog"]["n_poses"] == 2 and result["status"] in ("ok", "warning")
    assert abs(result["mass_kg"] - WING_BOX.mass_kg) <= result["U_kg"]
    assert [e.data["pose"] for e in events.events if e.step == "pose"] == ["meas", "A6+90"]
    (topup,) = [e for e in events.events if e.step == "pose" and e.data["pose"] == "meas"]
    assert "1 loop(s) beyond the mass loops" in topup.message
    # recorded as the pose's own loops are: A4 and A6 arrived from below (+), as in every CoG pose and the torsional
    # campaign, and the A3..A6 drives traced
    assert approach[1][3] == 1.0 and approach[1][5] == 1.0, approach[1]
    assert approach[2] == approach[1]  # the top-up loop, without a move in between
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        loops = await store.loops(run_id)
        files = await store.trace_files(run_id)
        run_dir = archive_root(cfg.paths.data_dir) / (await store.get_run(run_id)).directory
    assert [lp.trace_name for lp in loops] == [mass_trace, *meas["traces"][1:], *tilted["traces"]]  # once each
    modules = {f.path.rsplit("_", 1)[-1] for f in files if f.loop_index == 1}
    assert {f"NextGenDrive#{a}.r64" for a in (3, 4, 5, 6)} <= modules, modules
    # the run directory lists the mass loop twice, the second time as shared; `rgse cog` reproduces the stored CoG
    man = tomllib.loads((run_dir / "manifest.toml").read_text())
    assert man["measurement"]["traces"] == [mass_trace]
    assert [p.get("shares_measurement_loops", False) for p in man["properties"]["pose"]] == [True, False]
    code = main(["cog", "--traces", str(run_dir), "--calibration", str(run_dir / "CAL.json"), "--json"])
    cog = json.loads(capsys.readouterr().out)
    assert code in (0, 4) and cog["cog_flange_m"] == result["cog_m"] and cog["U_cog_flange_m"] == result["U_cog_m"]
    # robot time: the pose's loops beyond the mass loop are the CoG's (3 loops, not 4)
    per = {p["trace"]: p["robot_s"] for p in result["timing"]["per_loop"]}
    assert result["timing"]["cog_robot_time_s"] == pytest.approx(sum(per[t] for t in per if t != mass_trace))


@pytest.mark.timeout(400)
async def test_a_refused_mass_ends_the_properties_run_with_a_refused_result(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, cog_calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data", fixture={"cog_flange_m": list(ph.fixture_cog_flange_m())})
    cfg = cfg.model_copy(update={"measurement": cfg.measurement.model_copy(update={"loops": 1})})
    config = write_config(cfg, tmp_path / "rgse.toml")
    await seed_calibration(cfg, cog_calibration_doc)
    sim.mount(HEAVY)  # 480 kg: far beyond the calibration's loads
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        ran = await rgse_run("properties", "--config", config, "--json", close_stdin=True)
        # rgse run: one JSON object, the refused result with its reason; exit 2 as rgse mass refuses
        assert ran.rc == 2, (ran.rc, ran.err[-2000:])
        assert ran.out.count("\n") == 1, ran.out
        obj = json.loads(ran.out)
        run_id = obj["run_id"]
        assert obj["status"] == "refused" and obj["state"] == "completed" and obj["error"] == "OperatingPointError"
        assert "far outside the calibrated envelope" in obj["reason"], obj["reason"]
        assert obj["reason"].endswith("; the CoG is not computed: it needs the DuT's mass"), obj["reason"]
        assert "mass_kg" not in obj and "cog_m" not in obj and obj["run_kind"] == "properties"
        assert "result refused: measurement refused" in ran.err
        await refused_over_mqtt_and_client(cfg, private_broker.port, run_id, "properties", obj["reason"],
                                           "the CoG is not computed")
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        (stored,) = await store.results(run_id)
        rec = await store.get_run(run_id)
        loops = await store.loops(run_id)
    assert stored.status == "refused" and rec.state == RunState.COMPLETED, (rec.state, rec.detail)
    # every loop archived and listed in the run directory: the mass loop (shared by the pose meas) and A6+90's
    man = tomllib.loads((archive_root(cfg.paths.data_dir) / rec.directory / "manifest.toml").read_text())
    traces = [lp.trace_name for lp in loops]
    assert man["measurement"]["traces"] == traces[:1]
    assert [p["traces"] for p in man["properties"]["pose"]] == [traces[:1], traces[1:]]
