"""The report recomputes a properties run's multi-pose mass with the drift prior the run used: where β is not applied
its U carries ``measurement.drift_prior_per_k`` (issue 33), so a recomputation under the default prior would differ
from the stored U and refuse the report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon.analysis.calibration import fit_campaign
from rgse_daemon.analysis.multipose import compute_multipose_dir
from rgse_daemon.procedures.properties import _chosen_mass
from rgse_daemon.report.data import multipose_drift_prior_per_k
from simulators.krc4 import physics as ph
from tests.support import cogcampaign as cc
from tests.support import simcampaign as sc

PRIOR_PER_K = 0.0005  # below the default 0.003 %/K ... and below the campaign's |β| + 2 u(β): the prior bounds


def _run_dir(root: Path) -> Path:
    """A properties run in scheme ``lever`` with its CAL.json, whose A3 β rests on a 0.2 K span (not applied: U
    carries the prior)."""
    campaign, model = sc.simulate_campaign(2024, n_loops=2)
    sc.write_dirs(campaign, sc.simulate_measurement(model, 50.0, n_loops=1), root / "campaign", root / "dut")
    cc.warm_up(model)
    lines = cc.torsional_manifest_lines(root / "campaign", cc.simulate_torsional(model, "lever", seed=2024))
    with (root / "campaign" / "manifest.toml").open("a", encoding="utf-8") as f:
        f.write("\n" + "\n".join(lines))
    doc = fit_campaign(root / "campaign", "auto")[0].to_dict()
    doc["fit"]["thermal"]["span_k"]["A3"] = 0.2
    doc["calibration_id"] = calfile.content_id(doc)
    run = root / "prop"
    cc.write_properties_dir(run, cc.simulate_properties(model, ph.refex_wing_box(), "lever"), robot=sc.ROBOT,
                            scheme="lever", measurement_pose_traces=True)
    (run / "CAL.json").write_text(json.dumps(doc), encoding="utf-8")
    return run


def test_the_report_recomputes_the_multipose_U_under_the_runs_drift_prior(tmp_path):
    run = _run_dir(tmp_path)
    single = {"mass_kg": 0.0, "U_kg": 0.0, "u_components_kg": {}, "warnings": []}
    res = _chosen_mass(run, single, "multipose", {}, PRIOR_PER_K)
    assert res["mass_methods"]["multipose"]["thermal"].startswith("not corrected: its loops spanned 0.2 K")
    default = compute_multipose_dir(run, run / "CAL.json").uncertainty.expanded_kg
    assert res["U_kg"] < default - 0.01  # the prior matters to U here
    again = compute_multipose_dir(run, run / "CAL.json", drift_prior_per_k=multipose_drift_prior_per_k(res))
    assert again.uncertainty.expanded_kg == pytest.approx(res["U_kg"], rel=1e-12)
    # a result from before the prior was recorded: the default, as it was computed with then
    assert multipose_drift_prior_per_k({"mass_methods": {"multipose": {}}}) == 0.003


def test_autos_prediction_carries_the_thermal_bound_the_run_then_carries(tmp_path):
    """auto's prediction before the run (``predict_methods`` from CAL.json, the A3 motor temperature before the run
    and the drift prior): where the campaign's β is not applied (its 0.2 K span), U's thermal term bounds the drift
    over the visits' offset from the torsional campaign's temperature, as the run's U does (before: no term)."""
    from rgse_daemon import kinematics as kin
    from rgse_daemon.analysis.multipose import _readings, predict_methods
    from rgse_daemon.manifest import load_manifest, read_toml
    from rgse_daemon.pipeline import preprocess as pp

    run = _run_dir(tmp_path)
    calf = calfile.read(run / "CAL.json")
    measured = compute_multipose_dir(run, run / "CAL.json")
    u_thermal = measured.uncertainty.components()["thermal"]
    assert u_thermal > 0.0 and measured.thermal == "not corrected: its loops spanned 0.2 K, less than 1 K"
    poses = read_toml(load_manifest(run).path)["properties"]["pose"]
    temps = [t for p in poses if p["name"] in measured.visits
             for t in _readings(run, p["name"], list(p["traces"]), calf.preprocessing or pp.PAPER)[1]]
    visits_k = sum(temps) / len(temps)  # the temperature the prediction is told the visits will have

    def predicted(temp_k: float | None, prior: float = 0.003) -> dict:
        return predict_methods(calf, tuple(float(v) for v in kin.measurement_pose()), 3, 2, 69.0,
                               motor_temp_a3_k=temp_k, drift_prior_per_k=prior)["multipose"]

    blind, told = predicted(None), predicted(visits_k)
    assert blind["thermal"] == "not predicted: no A3 motor temperature before the run"
    assert told["thermal"] == measured.thermal  # the run's rule, decided before the run
    assert told["offset_k"] == pytest.approx(visits_k - calf.torsional.thermal_state_k["A3"])
    # the term the prediction adds (at the heaviest load the torsional calibration covered, 173 kg, against the wing
    # box's 107 kg) is of the run's size
    u_added = (told["U_kg"] ** 2 - blind["U_kg"] ** 2) ** 0.5 / 2.0
    assert 0.5 * u_thermal < u_added < 2.0 * u_thermal, (u_added, u_thermal)
    # under a narrower prior, a smaller bound
    assert blind["U_kg"] < predicted(visits_k, PRIOR_PER_K)["U_kg"] < told["U_kg"]
