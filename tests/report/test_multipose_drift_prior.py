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
