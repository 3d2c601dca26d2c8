"""Loops set aside during a run, and a refusal by the daemon (issue 33 items 1 and 5): through the daemon on the
simulated KR C4 over TCP, a real Mosquitto and a real store.

* A loop disturbed while it records (the test's fault hook leans on the load for exactly that loop's trace: the
  simulator's reading offsets shift while it records and shift back after) is set aside with its reason; with fewer
  loops kept than the stop rule needs, the daemon measures a replacement loop and the result rests on the kept ones;
  the set-aside loop's raw files stay archived. Without a replacement budget the result rests on the loops kept.
* A DuT far outside the calibration is refused by the pipeline: the run completes with a result whose status is
  ``refused`` and its reason, published, stored, raised by the client as :class:`ResultRefused`, printed by
  ``rgse run --json`` as one object (exit 2, as ``rgse mass``), shown by the console in Chromium (visible text), and
  reported as a run record."""

from __future__ import annotations

import asyncio
import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.client import RgseClient
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.procedures import documents as d
from rgse_daemon.report import build_report
from rgse_daemon.store import LoopState, Repository, RunState, Store, archive_root, verify_file
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.app.test_client_cli import rgse_run
from tests.support.cdp import browser
from tests.support.configfile import write_config
from tests.support.daemon import daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess
from tests.support.pg import PgSchemas
from tests.support.polling import wait_until
from tests.support.refusal import refused_over_mqtt_and_client

#: The DuT the result measures: the MPA is in the calibration's zero point (Table 1's "0 (MPA)" row), the fixture is
#: subtracted (measurement.fixture_mass_kg); ``DUT.mass_kg`` counts both (as tests/app/test_client.py's DUT_MASS_KG)
DUT_KG = 95.0
DUT = dut_payload(DUT_KG, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)
#: Far beyond the calibration's loads (its heaviest points carry about 230 kg, 4.5 kNm on A3): refused.
HEAVY = dut_payload(480.0, (0.0, 0.05, 0.65), fixture_mass_kg=10.288)
#: The lean on the load during one loop (A3, A5; Nm): some tens of Nm, as the issue's knock.
LEAN_NM = (30.0, -30.0)


def lean_during(sim: SimulatedKrc4, loop_index: int):
    """The fault hook: while loop ``loop_index`` records (from its LoopRecording to its LoopRecorded document),
    someone leans on the load: the simulator's reading offsets of A3 and A5 shift by :data:`LEAN_NM`, then back."""
    offset = [0.0, 0.0, LEAN_NM[0], 0.0, LEAN_NM[1], 0.0]

    def on_document(doc: d.Document) -> None:
        if isinstance(doc, d.LoopRecording) and doc.index == loop_index:
            sim.model.knock(offset)
        elif isinstance(doc, d.LoopRecorded) and doc.index == loop_index:
            sim.model.knock([-v for v in offset])

    return on_document


async def measure_leaning_on(sim: SimulatedKrc4, cfg: Config, calibration_doc: dict[str, Any], loop_index: int):
    """A measurement through the daemon and the client with loop ``loop_index`` leaned on; (result, run).

    A lab warms the robot up until its motors are steady (measurement.warmup_until_steady), and calibrated at that
    temperature: the simulated motors start at the temperature they hold with the brakes released, the campaign's
    thermal state is the same (the short test configuration does one warm-up cycle only)."""
    model = sim.model
    model.state.motor_temp_k = model.ambient_k + np.array([a.hold_temperature_rise_k for a in model._axes])
    steady = {"A3": float(model.state.motor_temp_k[2]), "A5": float(model.state.motor_temp_k[4])}
    await seed_calibration(cfg, calfile.seal({**calibration_doc, "thermal_state_k": steady}))
    sim.mount(DUT)
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as client:
        rd.daemon.engine.subscribe_documents(lean_during(sim, loop_index))
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        run = await client.measure()
        result = await run.wait(180)
    return result, run


@pytest.mark.parametrize("replacements", [2, 0])
async def test_a_disturbed_loop_is_set_aside_named_and_replaced(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any], tmp_path: Path,
        replacements: int) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=3, stop_loop_share=0.0,
                        replacement_loops=replacements)
    result, run = await measure_leaning_on(sim, cfg, calibration_doc, 2)
    raw = result.raw
    tag = raw["loops_used"][0].rsplit("_l", 1)[0]
    # the disturbed loop is named, with why
    (aside,) = raw["loops_set_aside"]
    assert aside["loop"] == f"{tag}_l02" and "disagrees with the other loops" in aside["reason"], aside
    assert f"loop {tag}_l02 set aside: disagrees" in " ".join(result.warnings)
    if replacements:  # 2 kept of 3: one replacement loop, and the mass rests on 3 kept loops
        assert raw["loops_used"] == [f"{tag}_l01", f"{tag}_l03", f"{tag}_l04"], raw["loops_used"]
        assert raw["stop_rule"]["stop_reason"] == "max loops" and raw["stop_rule"]["loops_kept"] == 3
    else:  # no budget: the mass rests on the 2 loops kept
        assert raw["loops_used"] == [f"{tag}_l01", f"{tag}_l03"], raw["loops_used"]
    assert result.status == "warning" and result.loops == len(raw["loops_used"])
    assert abs(result.mass_kg - DUT_KG) <= result.U_kg, (result.mass_kg, result.U_kg)
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        loops = await store.loops(run.run_id)
        files = await store.trace_files(run.run_id)
        rec = await store.get_run(run.run_id)
    n = 4 if replacements else 3
    assert [lp.trace_name for lp in loops] == [f"{tag}_l{i:02d}" for i in range(1, n + 1)]
    assert all(lp.state == LoopState.ARCHIVED for lp in loops) and rec.state == RunState.COMPLETED
    # the set-aside loop's raw files stay archived as they were, with the hashes recorded
    aside_files = [f for f in files if f.loop_index == 2]
    assert aside_files
    for f in aside_files:
        verify_file(archive_root(cfg.paths.data_dir) / f.path, f.sha256, f.size_bytes)


async def test_the_loop_the_stop_rule_would_stop_on_is_judged_first(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    """The stop rule stops early (here at its fewest, 3 loops) while the last loop's files are still on the
    controller: that loop is pulled and screened before the stop, so a disturbed last loop is replaced and the mass
    rests on 3 kept loops, not on 2 under "loop term below share"."""
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=6, stop_loop_share=0.95, replacement_loops=2)
    result, _ = await measure_leaning_on(sim, cfg, calibration_doc, 3)
    raw = result.raw
    tag = raw["loops_used"][0].rsplit("_l", 1)[0]
    (aside,) = raw["loops_set_aside"]
    assert aside["loop"] == f"{tag}_l03", aside
    assert raw["loops_used"] == [f"{tag}_l01", f"{tag}_l02", f"{tag}_l04"], raw["loops_used"]
    # the rule's budget rests on the loops it kept of those archived: 3 of 4 (the leaned one set aside)
    assert raw["stop_rule"]["stop_reason"] == "loop term below share" and raw["stop_rule"]["loops_kept"] == 3 \
        and raw["stop_rule"]["loops_analysed"] == 3, raw["stop_rule"]
    assert result.loops == 3 and abs(result.mass_kg - DUT_KG) <= result.U_kg, (result.mass_kg, result.U_kg)


def refusal_config(tmp_path: Path, sim: SimulatedKrc4, broker: MosquittoProcess, store_url: str) -> Config:
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=broker.port, loops=1).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    doc["store"]["url"] = store_url
    return config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<refusal test>")


async def test_a_refusal_by_the_daemon_is_a_result_everywhere_the_operator_looks(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    schemas = PgSchemas()
    try:
        cfg = refusal_config(tmp_path, sim, private_broker, schemas.new_url())
        config = write_config(cfg, tmp_path / "rgse.toml")
        await seed_calibration(cfg, calibration_doc)
        sim.mount(HEAVY)
        async with running_daemon(cfg) as rd, browser() as page:
            console = rd.daemon.console
            assert console is not None and console.port
            await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
            await page.goto(console.url)
            await page.wait_for("document.getElementById('engine').textContent === 'idle'", "the idle engine")
            ran = await rgse_run("measure", "--config", config, "--json", close_stdin=True)
            # rgse run: one JSON object, the refused result with its reason; exit 2 as rgse mass refuses
            assert ran.rc == 2, (ran.rc, ran.err[-2000:])
            assert ran.out.count("\n") == 1, ran.out
            obj = json.loads(ran.out)
            assert obj["status"] == "refused" and obj["state"] == "completed" and obj["error"] == "OperatingPointError"
            assert "far outside the calibrated envelope" in obj["reason"] and "mass_kg" not in obj
            run_id = obj["run_id"]
            assert "result refused: measurement refused: the DuT lies far outside" in ran.err
            # the MQTT result, retained: status refused with its reason
            # and the client: a refused result, with the result object
            refused = await refused_over_mqtt_and_client(cfg, private_broker.port, run_id, "measurement",
                                                         obj["reason"], "far outside")
            assert refused.result["error"] == "OperatingPointError"
            # the console, as the operator reads it
            await page.wait_for("document.getElementById('result-status').textContent === 'refused'",
                                "the refused status shown")
            shown = str(await page.evaluate("document.getElementById('result').innerText"))
            assert "refused: measurement refused: the DuT lies far outside the calibrated envelope" in shown, shown
            await page.wait_for(f"[...document.querySelectorAll('#history tr')].some(r => r.innerText.includes("
                                f"'{run_id}') && r.innerText.includes('refused'))", "the refusal in the history")
            row = str(await page.evaluate(f"[...document.querySelectorAll('#history tr')].find(r => "
                                          f"r.innerText.includes('{run_id}')).innerText"))
            assert "completed" in row and "far outside the calibrated envelope" in row, row
        # the store: a result with status refused, the run completed (not failed)
        async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
            (stored,) = await store.results(run_id)
            rec = await store.get_run(run_id)
        assert stored.status == "refused" and "far outside" in stored.result["reason"]
        assert rec.state == RunState.COMPLETED, (rec.state, rec.detail)
        # rgse runs over the same store: the status and the reason, short in the table, whole in JSON and CSV
        table_out, json_out, csv_out = tmp_path / "runs.txt", tmp_path / "runs.json", tmp_path / "runs.csv"
        for fmt, out in (([], table_out), (["--json", "--status", "refused"], json_out), (["--csv"], csv_out)):
            assert await asyncio.to_thread(main, ["runs", "--config", str(config), *fmt, "--out", str(out)]) == 0
        (line,) = [x for x in table_out.read_text().splitlines() if x.startswith(run_id[:16])]
        assert " refused " in line and "refused: measurement refused: the DuT lies far outside" in line, line
        assert len(line) < 200 and line.endswith("…"), line  # shortened: the reason is longer than the table's 72
        (listed,) = json.loads(json_out.read_text())["runs"]
        assert listed["run_id"] == run_id and listed["status"] == "refused" and listed["state"] == "completed"
        assert listed["reason"] == stored.result["reason"] and listed["mass_kg"] is None
        (row,) = csv.DictReader(io.StringIO(csv_out.read_text()))
        assert row["status"] == "refused" and row["reason"] == stored.result["reason"]
        # the report: the refusal at its top, as a run record (nothing to compute)
        repo = Repository.open(cfg.store.url, cfg.paths.data_dir)
        try:
            html = build_report(repo, cfg.paths.data_dir, tmp_path / "reports", run_id=run_id).read_text()
        finally:
            repo.close()
        assert 'data-value="refused"' in html and "far outside the calibrated envelope" in html
    finally:
        schemas.drop_all()
