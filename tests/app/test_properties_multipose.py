"""The multi-pose mass end to end (issue #35): an MQTT ``properties`` command with scheme ``lever`` and mass method
``auto`` → the daemon → the simulated KR C4 on a real socket (the mass loops, the paper's CoG poses and the lever
pose with the forearm raised, every motion through the interlock's static check) → a result that records both
masses, their robot time and the method auto chose before the run by prediction; and the refusal of
``multipose`` without the lever poses.

Where the operator looks (issue #33 item 5): which method gave the mass, that auto chose it, and both estimates with
their U, in the client's result, the console (real Chromium, visible text: the result and the history row), the HTML
report opened from the console's link (visible text; the stored multi-pose mass recomputed from the archived files),
the PDF certificate (its text) and ``rgse runs --json``."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from pypdf import PdfReader

from rgse_daemon.cli import main
from rgse_daemon.client import PropertiesResult, RgseClient
from rgse_daemon.config import config_from_mapping
from rgse_daemon.report.certificate import certificate_pdf, latin1, load
from rgse_daemon.store import Repository
from simulators.krc4 import physics as ph
from simulators.krc4.sim import SimulatedKrc4
from tests.app.conftest import SIM_SEED
from tests.app.test_properties_run import _config, peer
from tests.support.cdp import browser
from tests.support.cogcal import fit_sim_cog_calibration
from tests.support.configfile import write_config
from tests.support.daemon import Events, command, run_end, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess
from tests.support.polling import wait_until

WING_BOX = ph.refex_wing_box()


@pytest.fixture(scope="module")
def lever_calibration_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """CAL.json of the simulated robot with its torsional section in scheme ``lever`` (fitted offline), calibrated on
    the same arm as the test's simulated KR C4 (its arm as built is drawn from the seed): the bare readings of the
    raised pose are that arm's own gravity torque, and another arm's are off by a few Nm (0.6 kg of mass between the
    arms of seeds 5 and 7), as a calibration of another robot would be."""
    return fit_sim_cog_calibration(tmp_path_factory.mktemp("lever-calibration"), "lever", seed=SIM_SEED)


@pytest.mark.timeout(400)  # the lever calibration fitted offline (about 60 s) and the run (deadline 300 s)
async def test_properties_run_in_the_lever_poses_gives_both_masses_and_records_the_choice(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, lever_calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    data = _config(sim, private_broker, tmp_path / "data", scheme="lever", loops_per_pose=2,
                   mass_method="auto").model_dump(mode="json")
    data["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    # the daemon's own mass loops (10 at most, the stop rule: at least 3), which a run that gives the multi-pose mass
    # must not spend: its measurement pose is a lever pose like the others (loops_per_pose visits)
    data["measurement"] = {**data["measurement"], "loops": 10, "min_loops": 3, "stop_loop_share": 0.2}
    cfg = config_from_mapping({k: v for k, v in data.items() if v is not None}, "<multipose test>")
    await seed_calibration(cfg, lever_calibration_doc)
    sim.mount(WING_BOX.payload())
    events = Events()
    fixture = {"cog_flange_m": list(ph.fixture_cog_flange_m()),
               "dut_origin_flange_m": list(WING_BOX.dut_origin_flange_m), "dut_abc_deg": list(WING_BOX.dut_abc_deg)}
    async with running_daemon(cfg, on_event=events) as rd, peer(private_broker) as op, browser() as page:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        console = rd.daemon.console
        assert console is not None and console.port
        await page.goto(console.url)
        await page.wait_for("document.getElementById('engine').textContent === 'idle'", "the idle engine")
        reply = await command(op, "properties", {"fixture": fixture})
        assert reply["ok"] is True and reply["scheme"] == "lever" and reply["mass_method"] == "auto"
        result = await run_end(rd, timeout_s=300.0)
        run_id = result["run_id"]
        # auto chose before anything moved, by the U each method was predicted to give per robot minute (CAL.json
        # alone): the single pose's reproducibility (a new mounting's scatter) against MP1-MP3's predicted U
        choice = result["mass_choice"]
        said_at = [k for k, e in enumerate(events.events) if "mass_choice" in (e.data or {})]
        first_move = next(k for k, e in enumerate(events.events)  # the mass loops' step, or the first CoG pose
                          if e.step == "pose" or (e.step == "mass" and "mass_choice" not in (e.data or {})))
        assert said_at and said_at[0] < first_move
        predicted = choice["predicted"]
        score = {k: v["U_kg"] ** 2 * v["robot_min"] for k, v in predicted.items()}
        assert choice["method"] == min(score, key=score.get) == result["mass_method"] == "multipose"
        assert predicted["multipose"]["U_kg"] < 0.5 * predicted["single"]["U_kg"]
        # with U's thermal term for the A3 motor temperature after the warm-up: the campaign alone does not apply β so
        # far from the span it was fitted on; the run's own visits may confirm it (they did in this test's runs), and
        # U without them, the bound's, is said beside it
        expect = predicted["multipose"]
        assert expect["offset_k"] != 0.0 and expect["thermal"].startswith("β applied if the run's own visits "
                                                                          "confirm it"), expect
        assert expect["U_unconfirmed_kg"] > expect["U_kg"] and expect["thermal"] in choice["reason"], expect
        assert result["mass_method_requested"] == "auto"
        # its poses measured (the raised one with them); the mass loops are the pose meas's loops (#35)
        assert [e.data["pose"] for e in events.events if e.step == "pose"] == ["A6+90", "A3-80"]
        methods = result["mass_methods"]
        assert set(methods) == {"single", "multipose"}
        assert methods["multipose"]["visits"] == {"meas": 2, "A3-80": 2}
        assert methods["single"]["robot_time_s"] > 0 and methods["multipose"]["robot_time_s"] > 0
        # robot time: the loops the chosen mass and the CoG need and no more. The measurement pose gets the multi-pose
        # mass's 2 visits, not the single pose's stop rule's 3 or more: 2 + 2 (A6+90) + 2 (A3-80) loops; the single
        # pose's figure comes from those 2 visits and says so
        per_loop = result["timing"]["per_loop"]
        assert len(per_loop) == 6 and len(result["mass_traces"]) == 2, [lp["trace"] for lp in per_loop]
        assert {p["name"]: len(p["traces"]) for p in result["cog_poses"]} == {"meas": 2, "A6+90": 2, "A3-80": 2}
        assert result["timing"]["robot_time_s"] == pytest.approx(sum(lp["robot_s"] for lp in per_loop))
        assert result["stop_rule"]["max_loops"] == 2 and result["stop_reason"] == "max loops"
        assert methods["single"]["robot_time_s"] == pytest.approx(result["timing"]["mass_robot_time_s"])
        assert methods["single"]["loops"] == 2 and methods["single"]["loops_from"] == "multipose visits"
        assert methods["multipose"]["robot_time_s"] == pytest.approx(
            sum(lp["robot_s"] for lp in per_loop if lp["trace"] not in {t for p in result["cog_poses"]
                                                                       if p["name"] == "A6+90" for t in p["traces"]}))
        chosen = methods["multipose"]
        # A3's drift (issue 33): the visits lie beyond 3 x the 1.9 K span the campaign's β rests on (+6.0 K from the
        # torsional campaign's temperature in a quiet run of this test). Where the run's own visits show that β over a
        # span that reaches the reference it is applied; where they do not (under a full suite's load the scaled
        # simulator's motors warm more between requests: +29 K, a 3.1 K run span that did not reach it) the visits
        # stay uncorrected and U carries the bound, with a warning. Either way the result says how it was decided,
        # and U holds the truth (below)
        if chosen["thermal"].startswith("campaign's β applied over "):
            assert "the run's visits show β = " in chosen["thermal"], chosen["thermal"]
            expected_u = predicted["multipose"]["U_kg"]
        else:
            assert chosen["thermal"].startswith("not corrected: "), chosen["thermal"]
            assert any(w.startswith("multi-pose: ") and "not corrected" in w for w in result["warnings"]), \
                result["warnings"]
            assert chosen["u_components_kg"]["thermal"] > 0.0
            expected_u = predicted["multipose"]["U_unconfirmed_kg"]
        assert result["mass_kg"] == pytest.approx(chosen["mass_kg"])
        assert result["U_kg"] == pytest.approx(chosen["U_kg"])
        # the prediction was of the right size: the U measured is within a factor 2 of the one predicted for the way
        # the drift went
        assert 0.5 < chosen["U_kg"] / expected_u < 2.0, (chosen, predicted)
        for name, m in methods.items():
            assert abs(m["mass_kg"] - WING_BOX.mass_kg) <= m["U_kg"], (name, m)

        # what every surface must say: the method, that auto chose it, and both estimates with their U
        names = {"single": "single pose", "multipose": "multi-pose"}
        other = next(k for k in methods if k != result["mass_method"])
        said = [f"{names[result['mass_method']]}, chosen by auto",
                *(f"{names[k]} {methods[k]['mass_kg']:.3f} ± {methods[k]['U_kg']:.3f} kg"
                  for k in (result["mass_method"], other))]
        print(f"auto chose {result['mass_method']}: {methods}")
        # and how the thermal drift of the mass given was treated: the multi-pose mass's note with U's thermal term,
        # not the single pose's β per axis (the result's top-level thermal_notes/thermal_applied are the single pose's)
        thermal = (f"multi-pose mass: {chosen['thermal']}; thermal term of U: "
                   f"u = {chosen['u_components_kg']['thermal']:.3f} kg")
        single_thermal = "; ".join(f"{ax} {n}" for ax, n in sorted(result["thermal_notes"].items()))
        assert single_thermal and single_thermal not in thermal

        # the client, over the broker
        async with RgseClient.of(cfg) as client:
            typed = await client.result(run_id, "properties", timeout_s=10)
        assert isinstance(typed, PropertiesResult)
        assert typed.mass_method == result["mass_method"] and typed.mass_method_requested == "auto"
        assert {e.method: (e.mass_kg, e.U_kg) for e in typed.mass_methods} == {
            k: (pytest.approx(v["mass_kg"]), pytest.approx(v["U_kg"])) for k, v in methods.items()}

        # the console, as the operator reads it: the result and the history row
        await page.wait_for("!document.getElementById('result-mass-method').hidden", "the mass method shown")
        shown = str(await page.evaluate("document.getElementById('result').innerText"))
        for text in said:
            assert text in shown, (text, shown)
        assert f"thermal correction: {thermal}" in shown and single_thermal not in shown, (thermal, shown)
        await page.wait_for(f"[...document.querySelectorAll('#history tr')].some(r => r.innerText.includes("
                            f"'{run_id}') && r.innerText.includes('chosen by auto'))", "the mass method in the history")
        row = str(await page.evaluate(f"[...document.querySelectorAll('#history tr')].find(r => "
                                      f"r.innerText.includes('{run_id}')).innerText"))
        for text in said:
            assert text in row, (text, row)

        # the report, from the console's link: recomputed from the archived files (the multi-pose mass included)
        link = str(await page.evaluate(f"[...document.querySelectorAll('#history tr')].find(r => "
                                       f"r.innerText.includes('{run_id}')).querySelector('a').href"))
        got = await page.evaluate(f"fetch({json.dumps(link)}).then(async r => [r.status, await r.text()])", 120)
        assert got[0] == 200, got[1][:2000]
        saved = tmp_path / "report.html"
        saved.write_text(got[1], encoding="utf-8")
        await page.goto(saved.as_uri())
        report = str(await page.evaluate("document.body.innerText"))
        top = report[:report.index("Result\n")]  # above the first section
        for text in said:
            assert text in top and text in report[report.index("Result\n"):], (text, report[:3000])
        assert "consistency checks passed" in report
        assert f"thermal correction\t{thermal}" in report and single_thermal not in report, (thermal, report[:6000])

    # the certificate
    def certificate_text() -> str:
        with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
            pdf = certificate_pdf(load(repo, run_id))
        out = tmp_path / "cert.pdf"
        out.write_bytes(pdf)
        reader = PdfReader(out)
        assert len(reader.pages) == 1
        return " ".join(reader.pages[0].extract_text().split())

    cert = await asyncio.to_thread(certificate_text)
    for text in said:
        assert text.replace("±", "+/-") in cert or text in cert, (text, cert)
    assert f"Thermal correction {latin1(thermal)}" in cert, (latin1(thermal), cert)

    # rgse runs --json: the mass method beside the figure
    out = tmp_path / "runs.json"
    config = write_config(cfg, tmp_path / "rgse.toml")
    assert await asyncio.to_thread(main, ["runs", "--config", str(config), "--json", "--out", str(out)]) == 0
    (listed,) = json.loads(out.read_text())["runs"]
    for text in said:
        assert text in listed["mass_method"], (text, listed)


async def test_multipose_refused_without_the_lever_poses(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, lever_calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = _config(sim, private_broker, tmp_path / "data", scheme="paper", loops_per_pose=2)
    await seed_calibration(cfg, lever_calibration_doc)
    async with running_daemon(cfg) as rd, peer(private_broker) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        reply = await command(op, "properties", {"fixture": {"cog_flange_m": list(ph.fixture_cog_flange_m())},
                                                 "mass_method": "multipose"})
        assert reply["ok"] is False and "needs scheme 'lever'" in reply["error"]
