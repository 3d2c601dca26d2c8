"""±U (k = 2) covers the truth on the simulated KR 500: campaign → calibration → DuT, many seeds.

Each seed is a whole repetition: a new simulated robot (noise, spikes, thermal state), new true calibration-body
masses around the nominal ones, a Table-1-like campaign, ``--method auto`` and one DuT of random mass and CoG.
The code path is the one ``rgse calibrate --campaign`` / ``rgse mass`` run after reading the trace files; one
seed also goes through the real files and the CLI.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.analysis.calibration import (
    CampaignData,
    campaign_points,
    fit_and_describe,
    loo_rms_rel,
    plausible_alternatives,
)
from rgse_daemon.cli import main
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline import preprocess as pp
from tests.support.simcampaign import G, simulate_campaign, simulate_measurement, write_dirs

N_SEEDS = 40


def dut_of(seed: int) -> tuple[float, float]:
    """DuT mass (kg) and CoG distance from the flange (m) of a repetition: 30..190 kg, 0.1..0.5 m."""
    rng = np.random.default_rng(500 + seed)
    return float(rng.uniform(30.0, 190.0)), float(rng.uniform(0.1, 0.5))


def one_repetition(seed: int) -> tuple[float, float, dict[str, float], float]:
    """(measured − true mass, U, components, gross mass) of one seed."""
    camp, model = simulate_campaign(seed)
    data = CampaignData(camp.manifest, [[(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point]
                                        for point in camp.loops], [])
    points, bias3, bias5 = campaign_points(data, pp.PAPER)
    cal, chosen, evaluations = fit_and_describe(points, "auto", G, camp.manifest.setup.lever_difference_m)
    alts = calfile.alternatives("sim", {"fit": {"alternatives": plausible_alternatives(
        points, chosen, evaluations, G, camp.manifest.setup.lever_difference_m)}}, cal)
    dut_kg, cog_z_m = dut_of(seed)
    meas = simulate_measurement(model, dut_kg, cog_z_m)
    r = inline.in_line_mass([(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in meas.loops], cal,
                            bias3, bias5, pp.PAPER, meas.fixture_mass_kg, loo_rms_rel(points, chosen),
                            alternatives=alts)
    return r.mass_kg - dut_kg, r.uncertainty.expanded_kg, r.uncertainty.components(), r.gross_mass_kg


def test_expanded_uncertainty_covers_truth_in_95_percent_of_repetitions():
    runs = [one_repetition(seed) for seed in range(N_SEEDS)]
    err = np.array([r[0] for r in runs])
    big_u = np.array([r[1] for r in runs])
    gross = np.array([r[3] for r in runs])
    coverage = float(np.mean(np.abs(err) <= big_u))
    assert coverage >= 0.95, f"coverage {coverage:.3f}, errors {err.round(3)}, U {big_u.round(3)}"
    # and U stays informative: below 1 % of the gross mass on average, and every component is finite
    assert float(np.mean(big_u / gross)) < 0.01
    comps = [r[2] for r in runs]
    assert all(np.isfinite(list(c.values())).all() for c in comps)
    assert all(c["reference"] > 0 and c["loops"] > 0 and c["g"] == 0.0 for c in comps)


def test_one_repetition_through_trace_files_and_cli(tmp_path, capsys):
    seed = 3
    camp, model = simulate_campaign(seed)
    dut_kg, cog_z_m = dut_of(seed)
    meas = simulate_measurement(model, dut_kg, cog_z_m)
    write_dirs(camp, meas, tmp_path / "cal", tmp_path / "dut")
    assert main(["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "CAL.json"),
                 "--method", "auto", "--json"]) == 0
    capsys.readouterr()
    doc = json.loads((tmp_path / "CAL.json").read_text())
    assert np.asarray(doc["fit"]["covariance_reference_mass"]).shape == np.asarray(doc["fit"]["covariance"]).shape
    assert main(["mass", "--traces", str(tmp_path / "dut"), "--calibration", str(tmp_path / "CAL.json"),
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert abs(res["mass_kg"] - dut_kg) <= res["U_kg"]
    assert res["U_kg"] == pytest.approx(2 * res["u_kg"])
    c = res["u_components_kg"]
    assert set(c) == {"loops", "calibration", "model", "reference", "g"}
    assert res["u_kg"] == pytest.approx(np.sqrt(sum(v**2 for v in c.values())))
    # the same path in memory gives the same mass (the files carry the data exactly)
    err, _, _, _ = one_repetition(seed)
    assert res["mass_kg"] - dut_kg == pytest.approx(err, abs=1e-6)
