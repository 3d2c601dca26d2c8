"""The web console (``[console] enabled``) in real Chromium against the daemon on the simulated KR C4: live state
(and its latency from a change at the controller to the page), a whole campaign confirmed by clicking, a reload in
the middle of the run that finds its place again, an abort by clicking, every action recorded with source
"console", and the history linked to the reports. Set ``RGSE_CONSOLE_SCREENSHOT=FILE`` to keep the screenshot
(the README's is taken this way)."""

from __future__ import annotations

import asyncio
import html
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import aiohttp

from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.store import RunState, Store
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.cdp import Page, browser
from tests.support.client import SHORT_CAMPAIGN
from tests.support.daemon import COMMAND_TOKEN, Events, daemon_config, running_daemon

POINTS = SHORT_CAMPAIGN


def console_config(tmp_path: Path, sim: SimulatedKrc4, loops: int = 1, **extra: Any) -> Config:
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        loops=loops).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    doc["mqtt"].update(extra)
    return config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<console test>")


async def text(page: Page, element_id: str) -> str:
    return str(await page.evaluate(f"document.getElementById({json.dumps(element_id)}).textContent"))


async def wait_prompt(page: Page, index: int) -> None:
    await page.wait_for(f"!document.getElementById('prompt').hidden && prompt && prompt.data.point_index === {index}",
                        f"the prompt of point {index} on the page")


async def test_a_campaign_confirmed_by_clicking_with_a_reload_mid_run(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = console_config(tmp_path, sim, loops=2)  # two loops a point: the campaign fits its thermal drift β
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd, browser() as page:
        console = rd.daemon.console
        assert console is not None and console.port
        await page.goto(console.url)
        await page.wait_for("document.getElementById('engine').textContent === 'idle'", "the idle engine")
        assert await text(page, "mode") == "T1" and (await text(page, "link")).startswith("up")
        assert await page.evaluate("document.getElementById('confirm').disabled")
        # latency: the mode selector turned at the controller, until the page shows it
        latencies = []
        for mode in ("T2", "T1", "T2", "T1", "T2", "T1"):
            t0 = time.monotonic()
            sim.set_mode(mode)
            await page.wait_for(f"document.getElementById('mode').textContent === '{mode}'", f"mode {mode} shown")
            latencies.append(time.monotonic() - t0)
        print(f"\nconsole latency, controller change to page: median {sorted(latencies)[3] * 1000:.0f} ms, "
              f"max {max(latencies) * 1000:.0f} ms (state read at {console.period_s * 1000:.0f} ms intervals)")

        await page.type_into("#token", COMMAND_TOKEN)  # the configured command token, asked for by the page
        task = await rd.daemon.start_calibration(points=POINTS, method="auto")
        for index in range(len(POINTS)):
            await wait_prompt(page, index)
            if index == 2:  # the page is reloaded mid-run: it finds the run, its events, plot and prompt again
                await page.reload()
                await wait_prompt(page, index)
                await page.type_into("#token", COMMAND_TOKEN)
                run_id = await text(page, "run-id")
                assert run_id == rd.daemon.engine.run_id
                assert "loop" in await text(page, "events")
                assert await page.evaluate("plot.length > 10")
            if index == 3:
                shot = await page.screenshot(tmp_path / "console.png")
                if target := os.environ.get("RGSE_CONSOLE_SCREENSHOT"):
                    shutil.copyfile(shot, target)
            prompt = (await events.wait_for(lambda e, i=index: e.kind == "confirm" and e.data["point_index"] == i,
                                            f"prompt {index}")).data
            sim.mount(campaign_point_payload(prompt))
            await page.type_into("#note", f"point {index} mounted (console)")
            await page.click("#confirm")
            await page.wait_for("document.getElementById('prompt').hidden", "the prompt answered")
        await page.wait_for("document.getElementById('run-state').textContent === 'done'", "the campaign done",
                            timeout_s=120)
        # the live torque plot was fed from the state all along (A3, A5 N·m)
        assert await page.evaluate("plot.length > 20 && plot.every(p => p.length === 3)")
        assert await page.evaluate("document.getElementById('run-progress').value === 5")
        async with asyncio.timeout(30):
            summary = await asyncio.shield(task)
        link = await page.wait_for(
            f"[...document.querySelectorAll('#history a')].map(a => a.href).find(h => h.includes("
            f"'{summary['calibration_id']}'))", "the calibration's report link in the history")
        async with aiohttp.ClientSession() as http, http.get(link) as resp:
            report = await resp.text()
            assert resp.status == 200 and summary["calibration_id"] in report
        # the campaign's result as the operator reads it: β per axis, its span and whether it will be applied, in the
        # console and the report (with the campaign result's status at the report's top)
        assert summary["thermal"] is not None
        shown = str(await page.evaluate("document.getElementById('result').innerText"))  # as shown
        for ax in ("A3", "A5"):
            described = summary["thermal"][ax]["description"]
            assert f"thermal drift {described}" in shown, (described, shown)
            assert html.escape(described, quote=True) in report
        assert f'data-field="status" data-value="{summary["status"]}"' in report
        assert "Campaign loops set aside" in report
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        evs = await store.events(run_id=run_id)
    actions = [e for e in evs if e.kind == "console_action"]
    assert [(a.data["source"], a.data["verb"], a.data["point"], a.data["ok"]) for a in actions] == [
        ("console", "confirm", i, True) for i in range(len(POINTS))]
    said = [e.message for e in evs if e.kind == "operator_confirmed"]
    assert len(said) == len(POINTS) and said[0].endswith("point 0 mounted (console)")


async def test_an_abort_by_clicking_and_a_token_when_one_is_configured(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = console_config(tmp_path, sim, command_tokens=["s3cret"])
    async with running_daemon(cfg) as rd, browser() as page:
        await page.goto(rd.daemon.console.url)
        await page.wait_for("document.getElementById('engine').textContent === 'idle'", "the idle engine")
        await rd.daemon.start_calibration(points=POINTS, method="auto")
        await wait_prompt(page, 0)
        run_id = rd.daemon.engine.run_id
        await page.wait_for("!document.getElementById('abort').disabled", "Abort enabled for the run")
        await page.click("#abort")  # no token typed: refused, the run goes on
        await page.wait_for("document.getElementById('said').textContent.includes('unauthorised')", "the refusal")
        assert rd.daemon.engine.state == "confirm"
        await page.type_into("#token", "s3cret")
        await page.click("#abort")
        await page.wait_for("document.getElementById('run-state').textContent === 'aborted'", "the run aborted")
        # the reason of the aborted run, on the page (it showed none)
        await page.wait_for("document.getElementById('run-reason').innerText.includes('aborted by the operator')",
                            "the abort's reason shown")
        row = str(await page.evaluate(f"[...document.querySelectorAll('#history tr')].find(r => r.innerText.includes("
                                      f"'{run_id}')).innerText"))
        assert "aborted" in row and "reason: aborted by the operator (console)" in row, row
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        assert (await store.get_run(run_id)).state == RunState.ABORTED
        actions = [e.data for e in await store.events(run_id=run_id) if e.kind == "console_action"]
    assert [(a["source"], a["verb"], a["ok"]) for a in actions] == [("console", "abort", False),
                                                                    ("console", "abort", True)]
    assert "unauthorised" in actions[0]["error"]
