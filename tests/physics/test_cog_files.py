"""The CoG end to end offline, on real KUKA trace files written by the simulator's trace writer: a campaign with
mass and torsional points → ``rgse calibrate`` (CAL.json with a torsional section) → ``rgse mass`` and
``rgse cog`` on a properties run of the asymmetric wing box."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.procedures.properties import compute_properties
from simulators.krc4 import physics as ph
from tests.support import cogcampaign as cc
from tests.support import simcampaign as sc


def _json(capsys, argv: list[str]) -> dict:
    code = main(argv)
    doc = json.loads(capsys.readouterr().out)
    assert code == (4 if doc.get("status") == "warning" else 0), (code, doc.get("warnings"))  # interfaces §1.1
    return doc


@pytest.mark.slow
def test_calibrate_mass_and_cog_from_trace_files(tmp_path, capsys):
    campaign, model = sc.simulate_campaign(3, n_loops=2)
    sc.write_dirs(campaign, sc.simulate_measurement(model, 50.0), tmp_path / "cal", tmp_path / "unused")
    torsional = cc.simulate_torsional(model, "full", seed=3)
    lines = cc.torsional_manifest_lines(tmp_path / "cal", torsional)
    with (tmp_path / "cal" / "manifest.toml").open("a", encoding="utf-8") as f:
        f.write("\n" + "\n".join(lines))
    cal_json = tmp_path / "CAL.json"
    cal = _json(capsys, ["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(cal_json), "--json"])
    assert set(cal["torsional"]) == {"A3", "A4", "A5", "A6"}
    doc = json.loads(cal_json.read_text())
    assert doc["calibration_id"] == cal["calibration_id"] and len(doc["torsional"]["poses"]) == 8
    assert set(doc["torsional"]["thermal_state_k"]) == {"A3", "A4", "A5", "A6"}  # from the traces' Motortemperatur

    # the properties run of the wing box; copies of its measurement-pose loops are the mass run's
    run = cc.simulate_properties(model, ph.refex_wing_box(), "full")
    prop = tmp_path / "prop"
    cc.write_properties_dir(prop, run, robot=sc.ROBOT, measurement_pose_traces=True)
    mass = _json(capsys, ["mass", "--traces", str(prop), "--calibration", str(cal_json), "--json"])
    assert abs(mass["mass_kg"] - 107.3) <= mass["U_kg"]
    res = _json(capsys, ["cog", "--traces", str(prop), "--calibration", str(cal_json), "--json"])
    err_mm = (np.array(res["cog_flange_m"]) - run.true_cog_flange_m) * 1000.0
    assert np.all(np.abs(err_mm[:2]) < 1.0), err_mm
    assert np.all(np.abs(err_mm) <= np.array(res["U_cog_flange_m"]) * 1000.0), (err_mm, res["U_cog_flange_m"])
    assert res["scheme"] == "full" and res["n_poses"] == 8 and res["budget"]["calibration_id"] == cal["calibration_id"]
    assert res["mass_kg"] == pytest.approx(mass["mass_kg"]) and res["U_mass_kg"] == pytest.approx(mass["U_kg"])

    assert not [w for w in res["warnings"] if "sample period" in w]
    # a calibration campaign traced at another period: the CoG says so, as the mass does (the filter window counts
    # samples), and the properties run's one result says it once
    doc_other = {**doc, "fit": {**doc["fit"], "sample_period_s": doc["fit"]["sample_period_s"] / 3}}
    other = tmp_path / "prop_other"
    shutil.copytree(prop, other)
    (other / "CAL.json").write_text(json.dumps(calfile.seal(doc_other)))
    period_ms = doc["fit"]["sample_period_s"] * 1000
    said = f"trace sample period {period_ms:g} ms differs from the calibration campaign's {period_ms / 3:g} ms"
    res_other = _json(capsys, ["cog", "--traces", str(other), "--calibration", str(other / "CAL.json"), "--json"])
    assert [w for w in res_other["warnings"] if w.startswith(said)], res_other["warnings"]
    assert res_other["cog_flange_m"] == res["cog_flange_m"]  # a warning only
    both = compute_properties(other)
    assert len([w for w in both["warnings"] if w.startswith(said)]) == 1, both["warnings"]

    # the mass run's warnings stay in the CoG's result (a calibration campaign 10 K warmer than the loops)
    doc_warm = {**doc, "thermal_state_k": {ax: t + 10.0 for ax, t in doc["thermal_state_k"].items()}}
    warm = tmp_path / "prop_warm"
    shutil.copytree(prop, warm)
    (warm / "CAL.json").write_text(json.dumps(calfile.seal(doc_warm)))
    mass_warm = _json(capsys, ["mass", "--traces", str(warm), "--calibration", str(warm / "CAL.json"), "--json"])
    said = [w for w in mass_warm["warnings"] if w.startswith("motor temperatures differ")]
    assert said and mass_warm["status"] == "warning", mass_warm["warnings"]
    res_warm = _json(capsys, ["cog", "--traces", str(warm), "--calibration", str(warm / "CAL.json"), "--json"])
    assert f"mass: {said[0]}" in res_warm["warnings"] and res_warm["status"] == "warning", res_warm["warnings"]

    # the human form, and a calibration without the torsional section refused with the reason
    assert main(["cog", "--traces", str(prop), "--calibration", str(cal_json)]) == (4 if res["warnings"] else 0)
    assert "CoG (flange)" in capsys.readouterr().out
    del doc["torsional"]
    old = tmp_path / "OLD.json"
    old.write_text(json.dumps(calfile.seal(doc)))  # a calibration fitted without torsional points
    assert main(["cog", "--traces", str(prop), "--calibration", str(old)]) == 2
    assert "no 'torsional' section" in capsys.readouterr().err
