"""A result's status and the DuT's identity where the operator looks (issue 33 item 5, issue 34 items 4 and 7): a
measurement of a named DuT, started from the console's form, whose result warns, through the daemon on the
simulated KR C4, a real Mosquitto and a real store (SQLite and PostgreSQL): the status and the identity in the MQTT
result, the client's result, the store's column and the run's record; and the console in real Chromium, read as the
operator reads it (visible text): a plausible time on every event line (it said "Invalid Date"), the DuT's name, the
status and the warning, where the run is, and "stale" once the daemon is gone; the report's top."""

from __future__ import annotations

import asyncio
import json
import re
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon import calfile
from rgse_daemon.client import Identity, MeasurementResult, RgseClient, Run, RunFailed
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.report import build_report
from rgse_daemon.store import Repository, Store
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.cdp import browser
from tests.support.chromium import Dom, dump_dom
from tests.support.daemon import COMMAND_TOKEN, PREFIX, daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import Collector, MosquittoProcess, retained
from tests.support.pg import PgSchemas
from tests.support.polling import wait_until

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)
WHO = Identity(dut_name="Refex wing box", serial_number="SN-0042", part_number="PN-7-100", project="GSE-7",
               operator="A. Tester", note="first fit check")


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest) -> Any:
    if request.param == "sqlite":
        yield None
        return
    schemas = PgSchemas()
    yield schemas.new_url()
    schemas.drop_all()


def config(tmp_path: Path, sim: SimulatedKrc4, broker: MosquittoProcess, store_url: str | None) -> Config:
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=broker.port, loops=1).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    if store_url is not None:
        doc["store"]["url"] = store_url
    return config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<status test>")


def plausible_time(text: str, now: datetime) -> bool:
    """``text`` begins with a local time of day (``4:31:02 PM`` or ``16:31:02``) within 10 minutes of ``now``."""
    m = re.match(r"(\d{1,2}):(\d{2}):(\d{2})(?:\s*([AP]M))?", text)
    if m is None:
        return False
    h, mi, s = int(m[1]), int(m[2]), int(m[3])
    if m[4]:
        h = h % 12 + (12 if m[4] == "PM" else 0)
    shown = now.replace(hour=h, minute=mi, second=s, microsecond=0)
    return min(abs(shown - now), abs(shown + timedelta(days=1) - now), abs(shown - timedelta(days=1) - now)) \
        <= timedelta(minutes=10)


async def test_a_named_dut_with_a_warning_everywhere_the_operator_looks(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        store_url: str | None, tmp_path: Path) -> None:
    cfg = config(tmp_path, sim, private_broker, store_url)
    # the calibration campaign ran 15 K cooler than this robot runs now: the result must warn about it
    cool = {ax: t - 15.0 for ax, t in calibration_doc["thermal_state_k"].items()}
    await seed_calibration(cfg, calfile.seal({**calibration_doc, "thermal_state_k": cool}))
    sim.mount(DUT)
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as client, browser() as page:
        console = rd.daemon.console
        assert console is not None and console.port
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        await page.goto(console.url)
        await page.wait_for("document.getElementById('engine').textContent === 'idle'", "the idle engine")

        # the operator starts the measurement from the console, naming the DuT in its form
        await page.type_into("#token", COMMAND_TOKEN)
        for field, value in (("dut-name", WHO.dut_name), ("dut-serial", WHO.serial_number),
                             ("dut-part", WHO.part_number), ("dut-project", WHO.project),
                             ("dut-operator", WHO.operator), ("dut-note", WHO.note), ("start-loops", "1")):
            await page.type_into(f"#{field}", str(value))
        await page.wait_for("!document.getElementById('start-measure').disabled", "Start enabled while idle")
        await page.click("#start-measure")
        await wait_until(lambda: rd.daemon.engine.run_id is not None, "the run started from the console")
        await page.wait_for("document.getElementById('start-measure').disabled", "Start disabled during the run")
        run = Run(client, rd.daemon.engine.run_id, "measurement")  # followed by the client, over the broker
        result = await run.wait(120)
        assert isinstance(result, MeasurementResult)
        assert result.status == "warning" and result.identity == WHO, (result.status, result.identity)
        assert any(w.startswith("motor temperatures differ") for w in result.warnings), result.warnings

        # what a fresh MQTT subscriber gets: the retained result, with its status and identity
        (msg,) = await retained("127.0.0.1", private_broker.port, f"{PREFIX}/run/{run.run_id}/result")
        published = json.loads(msg.payload)  # type: ignore[arg-type]
        assert published["status"] == "warning" and published["identity"]["dut_name"] == "Refex wing box"
        assert published["identity"]["serial_number"] == "SN-0042" and published["warnings"] == list(result.warnings)

        # the console, as the operator reads it
        await page.wait_for("document.getElementById('result-status').textContent === 'warning'", "the status shown")
        # the history row is written when the run's end reaches the console, which may come after its result
        await page.wait_for("[...document.querySelectorAll('#history tr')].some(r => r.innerText.includes("
                            "'Refex wing box') && r.innerText.includes('warning'))", "the DuT's warning in the history")
        await page.wait_for("document.getElementById('run-where').innerText.endsWith('run done')", "the run's end")
        now = datetime.now()
        body = str(await page.evaluate("document.body.innerText"))
        assert "Invalid Date" not in body
        lines = list(await page.evaluate("[...document.querySelectorAll('#events li')].map(li => li.innerText)"))
        assert lines and all(plausible_time(line, now) for line in lines), lines[:5]
        # the event line counts every warning of the result: the motor temperatures, and (the DuT runs far from the
        # temperature span the campaign's β was fitted on) the thermal drift left uncorrected, per axis
        n_warnings = len(result.warnings)
        assert n_warnings >= 1
        assert any(re.search(r" result: warning: Refex wing box: mass \d+\.\d{3} kg ± \d+\.\d{3} kg \(k = 2\); "
                             rf"{n_warnings} warnings?\b", line) for line in lines), (lines[:5], result.warnings)
        assert "Refex wing box" in str(await page.evaluate("document.getElementById('run-dut').innerText"))
        shown = str(await page.evaluate("document.getElementById('result').innerText"))
        assert "Refex wing box" in shown and "S/N SN-0042" in shown
        assert "warning: motor temperatures differ from the calibration campaign's" in shown, shown
        # per axis how the thermal drift was treated, as the result says it (thermal_notes: β with its span applied
        # over the DuT's offset, or why not and the bound U carries), and U's thermal term
        notes = result.raw["thermal_notes"]
        assert set(notes) == {"A3", "A5"} and set(result.raw["thermal_applied"]) == {"A3", "A5"}, notes
        for ax, on in result.raw["thermal_applied"].items():
            assert notes[ax].startswith("campaign's β = " if on else "not corrected ("), notes
            assert on or " U carries a drift of up to " in notes[ax], notes
        u_thermal = result.raw["u_components_kg"]["thermal"]
        corrected = "; ".join(f"{ax} {n}" for ax, n in sorted(notes.items()))
        assert f"thermal correction: {corrected}; thermal term of U: u = {u_thermal:.3f} kg" in shown, (notes, shown)
        where = str(await page.evaluate("document.getElementById('run-where').innerText"))
        assert where.endswith("run done"), where
        row = str(await page.evaluate(f"[...document.querySelectorAll('#history tr')].find(r => r.innerText.includes("
                                      f"'{run.run_id}')).innerText"))
        assert "Refex wing box" in row and "warning" in row and "motor temperatures differ" in row, row
        assert await page.evaluate("document.getElementById('stale').hidden")
        shot = await page.screenshot(tmp_path / "console-result.png")
        assert shot.stat().st_size > 0

        # the daemon stops: the page says its state is stale, not "running / link up"
        await rd.shutdown()
        await page.wait_for("!document.getElementById('stale').hidden", "the stale marking", timeout_s=30)
        stale = str(await page.evaluate("document.getElementById('stale').innerText"))
        assert stale.startswith("STALE:") and "last word" in stale, stale
        assert await page.evaluate("document.body.classList.contains('stale')")
        assert str(await page.evaluate("document.getElementById('conn').innerText")) == "daemon gone"

    # the store: the result's status column and the run's identity
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        (stored,) = await store.results(run.run_id)
        rec = await store.get_run(run.run_id)
        evs = await store.events(run_id=run.run_id)
    assert stored.status == "warning" and stored.result["identity"]["project"] == "GSE-7"
    actions = [e.data for e in evs if e.kind == "console_action"]
    assert [(a["verb"], a["ok"], a["run_id"]) for a in actions] == [("measure", True, run.run_id)]
    assert rec.config["settings"]["identity"] == {"dut_name": "Refex wing box", "serial_number": "SN-0042",
                                                  "part_number": "PN-7-100", "project": "GSE-7",
                                                  "operator": "A. Tester", "note": "first fit check"}

    # the report: the status, the warnings and the identity at its top (before the first section), in Chromium
    def write() -> Path:
        with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
            return build_report(repo, cfg.paths.data_dir, tmp_path / "reports", run_id=run.run_id)

    page_file = await asyncio.to_thread(write)
    html = await asyncio.to_thread(dump_dom, page_file)
    dom = Dom(html)
    assert dom.fields["status"] == ["warning"]
    assert dom.fields["warning"] == list(result.warnings)
    assert dom.fields["identity.dut_name"] == ["Refex wing box"] and dom.fields["identity.serial_number"] == ["SN-0042"]
    head = html[html.index("<body"):html.index("<h2>Result</h2>")]  # above the first section
    assert "Refex wing box" in head and "motor temperatures differ" in head and ">warning</span>" in head


async def test_the_client_raises_the_reason_of_a_refused_result(private_broker: MosquittoProcess,
                                                                 tmp_path: Path) -> None:
    """A result whose status is ``refused`` has no figure: the client raises RunFailed with its reason (state
    ``refused``) instead of failing on the missing mass; a result with warnings reads with its status."""
    cfg = daemon_config(tmp_path / "data", controller_port=1, broker_port=private_broker.port)
    refused = {"status": "refused", "reason": "2 of 10 loops left after setting aside 8: fewer than 3",
               "warnings": [], "run_id": "R-refused"}
    warned = {"mass_kg": 95.1, "U_kg": 0.3, "warnings": ["loops disagree"], "run_id": "R-warned"}  # no status key
    async with Collector("127.0.0.1", private_broker.port, f"{PREFIX}/run/+/result") as pub:
        for doc in (refused, warned):
            await pub._client.publish(f"{PREFIX}/run/{doc['run_id']}/result", json.dumps(doc), qos=1, retain=True)
        await pub.sync()
    async with RgseClient.of(cfg) as client:
        with pytest.raises(RunFailed, match="R-refused refused: 2 of 10 loops left") as exc:
            await client.result("R-refused", timeout_s=10)
        assert exc.value.state == "refused"
        result = await client.result("R-warned", "measurement", timeout_s=10)
        assert result.status == "warning"  # a daemon before the status field: derived by the same rule
