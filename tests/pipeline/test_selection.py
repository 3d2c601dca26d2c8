"""Model selection by held-out configurations: per-axis identifiable models preferred, a joint model only where
its A3/A5 split is borne out; Table 1 out of sample."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as C

G, DR = 9.81, 1.025


def drive_a3(expected_nm):
    return expected_nm / (1.09 + 2e-5 * expected_nm)  # reads 8-13 % low, a slowly varying gain


def drive_a5(expected_nm):
    return expected_nm / 0.87


def mass_stack_campaign(seed: int = 4) -> C.CalibrationPoints:
    """Zero point and 1..10 stacked bodies: M_A3 and M_A5 rise together (one lever ratio), a few Nm of scatter."""
    rng = np.random.default_rng(seed)
    n = np.arange(11)
    mass = 20.93 * n
    l5 = 0.265 + 0.0075 * n
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    t3 = drive_a3(e3) + rng.normal(0, 3, 11)
    t5 = drive_a5(e5) + rng.normal(0, 3, 11)
    t3[0] = t5[0] = 0.0
    return C.CalibrationPoints(np.array(["zero"] + ["mass"] * 10), mass, t3, t5, e3, e5)


def test_selection_prefers_per_axis_model_where_the_joint_split_is_wrong():
    pts = mass_stack_campaign()
    evs = C.evaluate_all(pts, G, DR)
    by = {e.method: e for e in evs}
    # held out by configuration the joint gain fits look best on the mass ...
    assert by["gain-linear"].loo_mean_abs_err_pct < min(e.loo_mean_abs_err_pct for e in evs if not e.joint)
    # ... but their corrected torques per axis miss the expected torques by hundreds of Nm: inadmissible
    for e in evs:
        assert e.admissible == (not e.joint), e.method
        if e.joint:
            assert "A3 held-out" in e.note and e.axis_rms_nm.min() > 50.0
    chosen = C.select_auto(evs)
    assert not chosen.joint
    # a DuT at another lever (A5 lever 1.0 m, the torque points' pose) shows who was right
    m = 150.0
    t3, t5 = drive_a3(G * m * (1.0 + DR)), drive_a5(G * m * 1.0)
    err_chosen = float(C.fit(pts, chosen.method, G, DR).mass_kg(t3, t5)) - m
    err_joint = float(C.fit(pts, "gain-linear", G, DR).mass_kg(t3, t5)) - m
    assert abs(err_chosen) < 3.0 < 30.0 < abs(err_joint)


def test_joint_model_admitted_where_its_split_holds():
    """Torque points at other lever ratios make the split identifiable: an exact joint model passes the check."""
    mass = np.r_[0.0, 20.93 * np.arange(1, 11), 228.51, 228.51, 228.51]
    l5 = np.r_[0.265 + 0.0075 * np.arange(11), 0.775, 1.025, 1.275]
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    rng = np.random.default_rng(1)
    pts = C.CalibrationPoints(np.array(["zero"] + ["mass"] * 10 + ["torque"] * 3), mass,
                              e3 / 1.1 + rng.normal(0, 0.5, 14) * (mass > 0),
                              e5 / 0.85 + rng.normal(0, 0.5, 14) * (mass > 0), e3, e5)
    by = {e.method: e for e in C.evaluate_all(pts, G, DR)}
    assert by["gain-linear"].admissible, by["gain-linear"].note
    assert np.all(by["gain-linear"].axis_rms_nm < 5.0)
    assert np.isfinite(by["gain-linear"].lever_mean_abs_err_pct)


def test_selection_rules():
    def ev(method, loo, lever=float("nan"), admissible=True, n=2):
        return C.Evaluation(method, np.zeros(1), np.zeros(1), 0.0, loo, 0.0, n, lever_mean_abs_err_pct=lever,
                            admissible=admissible)

    # an inadmissible joint model never wins, however good it looks
    assert C.select_auto([ev("gain-linear", 0.1, admissible=False), ev("axis-quad", 0.5)]).method == "axis-quad"
    # an admissible joint model must beat the best per-axis one by more than the margin
    margin = C.PREFER_AXIS_MARGIN_PCT
    assert C.select_auto([ev("gain-linear", 0.5 - margin / 2), ev("axis-quad", 0.5)]).method == "axis-quad"
    assert C.select_auto([ev("gain-linear", 0.5 - 2 * margin), ev("axis-quad", 0.5)]).method == "gain-linear"
    # the lever-group error counts in the score
    picked = C.select_auto([ev("axis-quad", 0.50, lever=10.0), ev("axis-log", 0.55, lever=1.0)])
    assert picked.method == "axis-log"
    score = C.selection_score([ev("axis-quad", 0.5, lever=2.0), ev("axis-log", 0.4)])
    assert score["axis-quad"] == pytest.approx(0.5 + C.LEVER_WEIGHT * 2.0)
    assert score["axis-log"] == pytest.approx(0.4 + C.LEVER_WEIGHT * 2.0)  # unvalidated: the worst lever figure
    # near-ties go to fewer parameters
    assert C.select_auto([ev("axis-quad", 0.500, n=4), ev("axis-linear", 0.505, n=2)]).method == "axis-linear"


def test_held_out_residuals_are_per_axis_corrected_minus_expected(paper_dir):
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    ev = C.evaluate(pts, "axis-linear", G, DR)
    i = 5
    keep = np.arange(len(pts)) != i
    cal = C.fit(pts.subset(keep), "axis-linear", G, DR)
    want = [float(cal.k_a3.corrected_torque_nm(pts.torque_a3_nm[i])) - pts.expected_a3_nm[i],
            float(cal.k_a5.corrected_torque_nm(pts.torque_a5_nm[i])) - pts.expected_a5_nm[i]]
    np.testing.assert_allclose(ev.heldout_residual_nm[i], want, rtol=1e-12)
    assert ev.loo_mass_kg[i] == pytest.approx(float(cal.mass_kg(pts.torque_a3_nm[i], pts.torque_a5_nm[i])))
    # the lever group: the three torque rows predicted by the fit on the mass points
    lever_cal = C.fit(pts.subset(np.asarray(pts.kind) != "torque"), "axis-linear", G, DR)
    np.testing.assert_allclose(ev.lever_mass_kg[-3:], lever_cal.mass_kg(pts.torque_a3_nm[-3:],
                                                                         pts.torque_a5_nm[-3:]))
    assert np.all(np.isnan(ev.lever_mass_kg[:-3]))


@pytest.mark.slow
def test_table1_nested_out_of_sample_of_auto(paper_dir):
    """Table 1, the selection repeated in every fold. The joint gain models reached 0.709 % by moving the correction
    between the axes (their held-out per-axis torques miss by 36-127 Nm); the admissible per-axis models' honest
    figure is about 0.82 %, and the paper's method is above 1 %."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    evs = C.evaluate_all(pts, G, DR)
    assert not any(e.admissible for e in evs if e.joint)
    nested = C.mean_abs_pct(pts.mass_kg, C.nested_loo_auto_mass_kg(pts, G, DR))
    paper = next(e for e in evs if e.method == "paper")
    assert nested < 0.85
    assert nested < paper.loo_mean_abs_err_pct - 0.2
