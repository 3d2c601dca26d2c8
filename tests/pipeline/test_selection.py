"""Model selection by held-out configurations: per-axis identifiable models preferred, a joint model only where
its A3/A5 split is borne out; Table 1 out of sample."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import selection as S

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
    evs = S.evaluate_all(pts, G, DR)
    by = {e.method: e for e in evs}
    # held out by configuration the joint gain fits look best on the mass ...
    assert by["gain-linear"].loo_mean_abs_err_pct < min(e.loo_mean_abs_err_pct for e in evs if not e.joint)
    # ... but their corrected torques per axis miss the expected torques by hundreds of Nm: inadmissible
    for e in evs:
        assert e.admissible == (not e.joint), e.method
        if e.joint:
            assert "A3 held-out" in e.note and e.axis_rms_nm.min() > 50.0
    chosen = S.select_auto(evs)
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
    by = {e.method: e for e in S.evaluate_all(pts, G, DR)}
    assert by["gain-linear"].admissible, by["gain-linear"].note
    assert np.all(by["gain-linear"].axis_rms_nm < 5.0)
    assert np.isfinite(by["gain-linear"].lever_mean_abs_err_pct)


def test_selection_rules():
    def ev(method, loo, lever=float("nan"), admissible=True, n=2):
        return S.Evaluation(method, np.zeros(1), np.zeros(1), 0.0, loo, 0.0, n, lever_mean_abs_err_pct=lever,
                            admissible=admissible)

    # an inadmissible joint model never wins, however good it looks
    assert S.select_auto([ev("gain-linear", 0.1, admissible=False), ev("axis-quad", 0.5)]).method == "axis-quad"
    # an admissible joint model must beat the best per-axis one by more than the margin
    margin = S.PREFER_AXIS_MARGIN_PCT
    assert S.select_auto([ev("gain-linear", 0.5 - margin / 2), ev("axis-quad", 0.5)]).method == "axis-quad"
    assert S.select_auto([ev("gain-linear", 0.5 - 2 * margin), ev("axis-quad", 0.5)]).method == "gain-linear"
    # the lever-group error counts in the score
    picked = S.select_auto([ev("axis-quad", 0.50, lever=10.0), ev("axis-log", 0.55, lever=1.0)])
    assert picked.method == "axis-log"
    score = S.selection_score([ev("axis-quad", 0.5, lever=2.0), ev("axis-log", 0.4)])
    assert score["axis-quad"] == pytest.approx(0.5 + S.LEVER_WEIGHT * 2.0)
    assert score["axis-log"] == pytest.approx(0.4 + S.LEVER_WEIGHT * 2.0)  # unvalidated: the worst lever figure
    # near-ties go to fewer parameters
    assert S.select_auto([ev("axis-quad", 0.500, n=4), ev("axis-linear", 0.505, n=2)]).method == "axis-linear"


def test_held_out_residuals_are_per_axis_corrected_minus_expected(paper_dir):
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    ev = S.evaluate(pts, "axis-linear", G, DR)
    i = 5
    keep = np.arange(len(pts)) != i
    cal = C.fit(pts.subset(keep), "axis-linear", G, DR)
    want = [float(cal.k_a3.corrected_torque_nm(pts.torque_a3_nm[i])) - pts.expected_a3_nm[i],
            float(cal.k_a5.corrected_torque_nm(pts.torque_a5_nm[i])) - pts.expected_a5_nm[i]]
    np.testing.assert_allclose(ev.heldout_residual_nm[i], want, rtol=1e-12)
    dr = (pts.expected_a3_nm[i] - pts.expected_a5_nm[i]) / (G * pts.mass_kg[i])  # the point's own Δr
    assert ev.loo_mass_kg[i] == pytest.approx((want[0] + pts.expected_a3_nm[i] - want[1] - pts.expected_a5_nm[i])
                                              / (G * dr), rel=1e-12)
    # the lever group: the three torque rows predicted by the fit on the mass points
    lever_cal = C.fit(pts.subset(np.asarray(pts.kind) != "torque"), "axis-linear", G, DR)
    c3 = lever_cal.k_a3.corrected_torque_nm(pts.torque_a3_nm[-3:])
    c5 = lever_cal.k_a5.corrected_torque_nm(pts.torque_a5_nm[-3:])
    np.testing.assert_allclose(ev.lever_mass_kg[-3:], (c3 - c5) / (G * 1.0204), rtol=1e-4)
    assert np.all(np.isnan(ev.lever_mass_kg[:-3]))


def test_each_point_has_its_own_lever_difference(paper_dir):
    """Eq. 21 for a calibration point uses the Δr its expected torques encode. Table 1's torque rows were computed
    for r_A3 − r_A5 = 1.0204 m, its mass rows for 1.0250 m: with 1.025 m an exact per-axis K would put each torque
    row 0.45 % (1.03 kg) low. On an exact drive with one point in another pose every point's mass comes out exact."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    dr = pts.lever_difference_m(G, DR)
    np.testing.assert_allclose(dr[1:11], DR, atol=1e-4)
    np.testing.assert_allclose(dr[11:], 1.0204, atol=1e-4)
    assert dr[0] == DR  # the zero point: the measurement pose's
    mass = np.array([0.0, 50.0, 100.0, 150.0, 200.0, 150.0])
    l5 = np.array([0.3, 0.3, 0.31, 0.32, 0.33, 0.9])
    l3 = l5 + np.r_[DR, DR, DR, DR, DR, 0.98]  # the last point in a pose where the axes are 0.98 m apart
    e3, e5 = G * mass * l3, G * mass * l5
    exact = C.CalibrationPoints(np.array(["zero", "mass", "mass", "mass", "mass", "torque"]), mass, e3 / 1.1,
                                e5 / 0.85, e3, e5)
    cal = C.fit(exact, "axis-linear", G, DR)
    np.testing.assert_allclose(cal.points_mass_kg(exact), mass, atol=1e-9)
    assert abs(float(cal.mass_kg(exact.torque_a3_nm[-1], exact.torque_a5_nm[-1])) - 150.0) > 6.0  # with 1.025 m
    np.testing.assert_allclose(S.evaluate(exact, "axis-linear", G, DR).loo_mass_kg, mass, atol=1e-9)
    with pytest.raises(C.CalibrationError, match=r"^calibration point 2: expected A3 torque .* is not above its "
                                                 r"expected A5 torque .* \(r_A3 − r_A5 must be positive\)$"):
        C.CalibrationPoints(exact.kind, mass, e3, e5, e5, e3)  # A5's expected torque above A3's


@pytest.mark.slow
def test_table1_nested_out_of_sample_of_auto(paper_dir):
    """Table 1, the selection repeated in every fold. The joint gain models reached 0.709 % by moving the correction
    between the axes (their held-out per-axis torques miss by 36-127 Nm); the admissible per-axis models' honest
    figure was 0.82 % picking one, 0.74 % averaging the best per-axis gain models with the ``sur-*`` among them, 0.718 %
    once each point's mass is taken in its own geometry (the torque rows' Δr, 1.0204 m; the issue's 0.70 % is not
    reached), and the paper's method is above 1 %."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    evs = S.evaluate_all(pts, G, DR)
    assert not any(e.admissible for e in evs if e.joint)
    nested = C.mean_abs_pct(pts.mass_kg, S.nested_loo_auto_mass_kg(pts, G, DR))
    paper = next(e for e in evs if e.method == "paper")
    assert nested < 0.73
    assert nested < paper.loo_mean_abs_err_pct - 0.2


def scaled(pts: C.CalibrationPoints, c: float) -> C.CalibrationPoints:
    """The same campaign on a robot and payload range c times as strong: every torque and mass times c."""
    return C.CalibrationPoints(pts.kind, pts.mass_kg * c, pts.torque_a3_nm * c, pts.torque_a5_nm * c,
                               pts.expected_a3_nm * c, pts.expected_a5_nm * c)


@pytest.mark.parametrize("c", [0.01, 0.2, 5.0, 100.0])
def test_the_catalogue_is_the_same_for_every_torque_scale(paper_dir, c):
    """Table 1 with every torque and mass times c (another robot, another payload range, the same relative data):
    every model's held-out errors in %, the admissibility and auto's choice are Table 1's own. The gain curves'
    torque scale follows the campaign; at a fixed 1 kNm the ``log`` and ``sat`` terms bent elsewhere on the data
    and auto's nested figure was 0.79 % at c = 0.2 and 0.86 % at c = 5 against 0.72 %. The joint models' split check
    is floored in the same scale: a fixed 1 Nm floor admitted four joint models at c = 0.01."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    ref = {e.method: e for e in S.evaluate_all(pts, G, DR)}
    assert pts.gain_scale_nm() == pytest.approx(2 / 9 * 4505.9, abs=0.05)  # Table 1's largest torque, A3 (Nm)
    big = scaled(pts, c)
    assert big.gain_scale_nm() == pytest.approx(c * pts.gain_scale_nm())
    evs = S.evaluate_all(big, G, DR)
    assert [e.method for e in evs] == list(ref)
    for e in evs:
        np.testing.assert_allclose(e.loo_mass_kg / c, ref[e.method].loo_mass_kg, rtol=1e-6, atol=1e-6,
                                   err_msg=e.method)
        assert e.admissible == ref[e.method].admissible, e.method
    assert S.choose_auto(big, evs).method == S.choose_auto(pts, list(ref.values())).method


def common_mode_campaign(seed: int, shift_m: float = 0.008) -> tuple[C.CalibrationPoints, np.ndarray]:
    """Table-1-like loads; every mounting shifts the load's CoG by δ (σ = ``shift_m``): the same g·m·δ on A3 and A5
    (eq. 3/4), which eq. 21 cancels. Returns the points and the true constant drive gains (A3, A5)."""
    rng = np.random.default_rng(seed)
    mass = np.r_[0.0, 20.93 * np.arange(1, 11), 228.51, 228.51, 228.51]
    l5 = np.r_[0.265 + 0.0075 * np.arange(11), 0.775, 1.025, 1.275]
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    shift = G * mass * rng.normal(0.0, shift_m, 14)
    gains = np.array([1.1, 0.87])
    t3 = (e3 + shift) / gains[0] + rng.normal(0, 2, 14) * (mass > 0)
    t5 = (e5 + shift) / gains[1] + rng.normal(0, 2, 14) * (mass > 0)
    return C.CalibrationPoints(np.array(["zero"] + ["mass"] * 10 + ["torque"] * 3), mass, t3, t5, e3, e5), gains


def test_sur_fit_uses_the_axes_common_mode():
    """A mounting's CoG shift moves both axes' torques alike: fitting the axes together with their residual
    correlation finds each axis' gain better than fitting each axis alone, and the mass of a DuT at another lever."""
    err_sur, err_axis, gain_sur, gain_axis = [], [], [], []
    for seed in range(30):
        pts, gains = common_mode_campaign(seed, shift_m=0.02)
        sur, axis = C.fit(pts, "sur-linear", G, DR), C.fit(pts, "axis-linear", G, DR)
        assert not S.Evaluation("sur-linear", *(np.zeros(1),) * 2, 0.0, 0.0, 0.0, 2).joint
        gain_sur.append(np.abs(sur.params - gains))
        gain_axis.append(np.abs(axis.params - gains))
        m, l5 = 120.0, np.array([0.3, 0.6, 1.2])  # DuTs at the mass stack's, between and the torque points' levers
        t3, t5 = G * m * (l5 + DR) / gains[0], G * m * l5 / gains[1]
        err_sur.append(np.abs(sur.mass_kg(t3, t5) - m))
        err_axis.append(np.abs(axis.mass_kg(t3, t5) - m))
    assert np.mean(err_sur) < 0.75 * np.mean(err_axis), (np.mean(err_sur), np.mean(err_axis))
    assert np.all(np.mean(gain_sur, axis=0) < np.mean(gain_axis, axis=0))
    # each axis still answers to its own expected torque: the split is identified (not a joint fit)
    assert np.all(np.mean(gain_sur, axis=0) < 0.006)


def test_sur_fit_is_robust_to_one_scattered_point():
    pts, _ = common_mode_campaign(1, shift_m=0.0)
    bad = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm + 150.0 * (np.arange(14) == 6),
                              pts.torque_a5_nm, pts.expected_a3_nm, pts.expected_a5_nm)
    clean = C.fit(pts, "sur-linear", G, DR).params
    robust = C.fit(bad, "sur-linear", G, DR).params
    plain = C.fit(bad, "axis-linear", G, DR).params
    assert np.abs(robust - clean).max() < 0.5 * np.abs(plain - C.fit(pts, "axis-linear", G, DR).params).max()
    # Huber by IRLS: the gross residual gets weight < 1, the others stay least squares
    a = np.c_[np.ones(20), np.arange(20.0)]
    y = 2.0 + 0.5 * np.arange(20.0) + np.random.default_rng(0).normal(0, 0.1, 20)
    y[5] += 10.0
    # (bounded influence: the outlier still pulls a little, 10 × weight ≈ 1.345 σ_robust / 10)
    np.testing.assert_allclose(C.huber_lstsq(a, y), [2.0, 0.5], atol=0.2)
    assert abs(np.linalg.lstsq(a, y, rcond=None)[0][0] - 2.0) > 1.0


def test_auto_averages_the_best_per_axis_gain_models():
    pts, _ = common_mode_campaign(3)
    evs = S.evaluate_all(pts, G, DR)
    avg = S.choose_auto(pts, evs)
    assert avg.method.startswith(C.AVERAGE_PREFIX) and C.known_method(avg.method)
    members = avg.method.removeprefix(C.AVERAGE_PREFIX).split("+")
    score = S.selection_score(evs)
    pool = [e.method for e in evs if e.method in C.AVERAGEABLE and e.admissible]
    best = min(score[e.method] for e in evs if e.admissible and not e.joint)  # paper and ratio-linear count too
    assert members == [m for m in pool if score[m] <= S.AVERAGE_FACTOR * best] and len(members) >= 2
    # eq. 21 is linear in the corrected torques: the average's mass is the members' mean, per axis a gain curve
    cal = C.fit(pts, avg.method, G, DR)
    t3, t5 = np.array([800.0, 2500.0]), np.array([300.0, 1500.0])
    want = np.mean([C.fit(pts, m, G, DR).mass_kg(t3, t5) for m in members], axis=0)
    np.testing.assert_allclose(cal.mass_kg(t3, t5), want, rtol=1e-12)
    assert isinstance(cal.k_a3, C.GainK) and isinstance(cal.k_a5, C.GainK)
    assert cal.covariance.shape == (len(cal.params),) * 2
    # its held-out figures are the members' means too (held out with the members refitted without the point)
    by = {e.method: e for e in evs}
    np.testing.assert_allclose(avg.loo_mass_kg, np.mean([by[m].loo_mass_kg for m in members], axis=0))
    np.testing.assert_allclose(avg.heldout_residual_nm, np.mean([by[m].heldout_residual_nm for m in members], axis=0))
    assert avg.loo_mean_abs_err_pct == pytest.approx(C.mean_abs_pct(pts.mass_kg, avg.loo_mass_kg))
    # a joint model the selection admits and prefers is kept; with one candidate there is nothing to average
    assert not C.known_method("avg:axis-quad") and not C.known_method("avg:axis-quad+gain-linear")
    with pytest.raises(C.CalibrationError, match="average"):
        C.fit(pts, "avg:axis-quad+paper", G, DR)
    one = [e for e in evs if e.method in ("axis-quad", "paper")]
    assert S.choose_auto(pts, one).method in ("axis-quad", "paper")
