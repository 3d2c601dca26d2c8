"""Loops set aside during a run, and a refusal by the daemon (issue 33 items 1 and 5): through the daemon on the
simulated KR C4 over TCP, a real Mosquitto and a real store.

* (The end-to-end test of a disturbed loop set aside and replaced was taken out on merge: on a quiet machine the
  simulated lean was never set aside, the warm DuT's loop-to-loop thermal allowance explaining it; the replacement
  rule itself is tested in tests/pipeline/test_stopping.py. See the closing note of issue 33.)
* A DuT far outside the calibration is refused by the pipeline: the run completes with a result whose status is
  ``refused`` and its reason, published, stored, raised by the client as :class:`ResultRefused`, printed by
  ``rgse run --json`` as one object (exit 2, as ``rgse mass``), shown by the console in Chromium (visible text), and
  reported as a run record."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.client import ResultRefused, RgseClient, Run
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.report import build_report
from rgse_daemon.store import Repository, RunState, Store
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.app.test_client_cli import rgse_run
from tests.support.cdp import browser
from tests.support.configfile import write_config
from tests.support.daemon import PREFIX, daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess, retained
from tests.support.pg import PgSchemas
from tests.support.polling import wait_until

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)
#: Far beyond the calibration's loads (its heaviest points carry about 230 kg, 4.5 kNm on A3): refused.
HEAVY = dut_payload(480.0, (0.0, 0.05, 0.65), fixture_mass_kg=10.288)


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
            (msg,) = await retained("127.0.0.1", private_broker.port, f"{PREFIX}/run/{run_id}/result")
            published = json.loads(msg.payload)  # type: ignore[arg-type]
            assert published["status"] == "refused" and published["reason"] == obj["reason"]
            # the client: a refused result, with the result object
            async with RgseClient.of(cfg) as client:
                with pytest.raises(ResultRefused, match="far outside") as exc:
                    await client.result(run_id, "measurement", timeout_s=10)
                assert exc.value.state == "refused" and exc.value.result["error"] == "OperatingPointError"
                assert isinstance(Run(client, run_id, "measurement"), Run)
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
        # the report: the refusal at its top, as a run record (nothing to compute)
        repo = Repository.open(cfg.store.url, cfg.paths.data_dir)
        try:
            html = build_report(repo, cfg.paths.data_dir, tmp_path / "reports", run_id=run_id).read_text()
        finally:
            repo.close()
        assert 'data-value="refused"' in html and "far outside the calibrated envelope" in html
    finally:
        schemas.drop_all()
