"""The uncertainty budget term by term, the operating-point check, and U on an ill-conditioned eq. 20 fit.

Fast and exact on purpose: these tests pin the equations (sign of the fixture mass in eq. 15/21, the A3 and A5
sensitivities feeding U, every budget term, the loop scatter check), their boundaries and messages, so that a
single changed operator (``make mutation``) fails one of them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import envelope as E
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline import mass as mass_eq
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import selection as S
from rgse_daemon.pipeline import uncertainty as unc

G, DR = 9.81, 1.025
RAW = pp.Preprocessing(crop_sigma=None, filter="none", window=1, order="backward", location="mean", settle_s=0.0)


def linear_cal(k3: float = 1.1, k5: float = 0.85) -> C.Calibration:
    return C.Calibration("axis-linear", C.GainK(("lin",), np.array([k3])), C.GainK(("lin",), np.array([k5])),
                         np.zeros((2, 2)), (0.0, 3000.0), (0.0, 800.0), G, DR)


def test_eq14_and_eq15_subtract_the_fixture_mass():
    assert mass_eq.dut_mass_uncorrected_kg(2100.0, 300.0, 100.0, 50.0, G, DR, 10.0) == pytest.approx(
        (2000.0 - 250.0) / (G * DR) - 10.0)
    assert mass_eq.dut_mass_kg(2000.0, 400.0, G, DR, 10.288) == pytest.approx(1600.0 / (G * DR) - 10.288)
    cal = linear_cal()
    assert float(cal.mass_kg(1000.0, 200.0, 5.0)) == pytest.approx((1100.0 - 170.0) / (G * DR) - 5.0)


def loops_of(t3: float, t5: float, n_loops: int = 4, n: int = 400, sigma3: float = 0.0, sigma5: float = 0.0,
             seed: int = 0) -> list[inline.LoopSamples]:
    rng = np.random.default_rng(seed)
    return [(t3 + rng.normal(0, sigma3, n) if sigma3 else np.full(n, t3),
             t5 + rng.normal(0, sigma5, n) if sigma5 else np.full(n, t5), 0.012, f"l{k}") for k in range(n_loops)]


def test_in_line_mass_is_gross_minus_fixture_after_bias():
    cal = linear_cal()
    r = inline.in_line_mass(loops_of(1100.0, 250.0), inline.MassCalibration(cal, 100.0, 50.0), RAW,
                            fixture_mass_kg=10.288)
    gross = (1.1 * 1000.0 - 0.85 * 200.0) / (G * DR)
    assert r.gross_mass_kg == pytest.approx(gross)
    assert r.mass_kg == pytest.approx(gross - 10.288)
    assert (r.torque_a3_nm, r.torque_a5_nm) == (pytest.approx(1000.0), pytest.approx(200.0))


def test_sensitivities_feed_the_loop_term_per_axis():
    cal = linear_cal(1.1, 0.85)
    s3, s5 = inline.slope_kg_per_nm(cal, 1000.0, 200.0)
    assert s3 == pytest.approx(1.1 / (G * DR)) and s5 == pytest.approx(-0.85 / (G * DR))
    # noise on A3 only, then on A5 only: the loop term scales with that axis' sensitivity
    only3 = inline.in_line_mass(loops_of(1000.0, 200.0, sigma3=20.0, seed=1), inline.MassCalibration(cal, 0.0, 0.0),
                                RAW)
    only5 = inline.in_line_mass(loops_of(1000.0, 200.0, sigma5=20.0, seed=1), inline.MassCalibration(cal, 0.0, 0.0),
                                RAW)
    ratio = only3.uncertainty.u_loops_kg / only5.uncertainty.u_loops_kg
    assert ratio == pytest.approx(1.1 / 0.85, rel=0.02)
    # the within-loop (batch means) error of one axis, times its sensitivity, over √loops
    se = [unc.batch_means_se(a3) for a3, _, _, _ in loops_of(1000.0, 200.0, sigma3=20.0, seed=1)]
    within = abs(s3) * np.sqrt(np.sum(np.square(se))) / 4
    assert only3.uncertainty.u_loops_kg >= within * (1 - 1e-9)


def test_budget_is_the_quadrature_sum_of_every_term():
    u = unc.MassUncertainty(0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    assert u.u_kg == pytest.approx(np.sqrt(0.01 + 0.04 + 0.09 + 0.16 + 0.25 + 0.36))
    assert u.expanded_kg == pytest.approx(2 * u.u_kg)
    assert u.components() == {"loops": 0.1, "calibration": 0.2, "model": 0.3, "reference": 0.4, "g": 0.5,
                              "reproducibility": 0.6}
    for term in ("u_loops_kg", "u_calibration_kg", "u_model_kg", "u_reference_kg", "u_g_kg",
                 "u_reproducibility_kg"):
        kw = dict.fromkeys(("u_loops_kg", "u_calibration_kg", "u_model_kg"), 0.0) | {term: 3.0}
        assert unc.MassUncertainty(**kw).u_kg == pytest.approx(3.0), term
    # an old calibration file's budget has no reproducibility term
    assert "reproducibility" not in unc.MassUncertainty(0.1, 0.2, 0.3).components()


def test_reproducibility_propagates_through_eq21_with_the_axes_correlation():
    denom = G * DR
    assert unc.Reproducibility(3.0, 4.0, 0.0).u_kg(G, DR) == pytest.approx(5.0 / denom)
    assert unc.Reproducibility(3.0, 4.0, 1.0).u_kg(G, DR) == pytest.approx(1.0 / denom)  # common mode cancels
    assert unc.Reproducibility(3.0, 4.0, -1.0).u_kg(G, DR) == pytest.approx(7.0 / denom)
    r = np.array([[1.0, 2.0], [-1.0, -2.0], [3.0, 0.0]])
    rep = unc.Reproducibility.from_residuals(r)
    assert rep.rms_a3_nm == pytest.approx(np.sqrt(11 / 3)) and rep.rms_a5_nm == pytest.approx(np.sqrt(8 / 3))
    assert rep.corr == pytest.approx((4 / 3) / np.sqrt(11 / 3 * 8 / 3))
    # the mass residual of the same configurations, (r3 − r5)/(g·Δr), with the Student factor of 3 configurations
    assert rep.n == 3 and rep.small_sample_factor == pytest.approx(4.302653 / 1.959964, rel=1e-5)
    assert rep.u_kg(G, DR) == pytest.approx(np.sqrt(np.mean((r[:, 0] - r[:, 1]) ** 2)) / denom * 4.302653 / 1.959964,
                                            rel=1e-5)
    assert unc.Reproducibility(3.0, 4.0, 0.0, 1000).small_sample_factor == 1.0
    with pytest.raises(DataError):
        unc.Reproducibility.from_residuals(np.array([[1.0, 1.0]]))


def test_new_budget_terms_reach_the_result():
    cal = linear_cal()
    boot = np.array([[1.1, 0.85], [1.101, 0.85], [1.099, 0.851], [1.1, 0.849]])
    ref = np.array([[1.1, 0.85], [1.1001, 0.85]])
    cu = unc.CalibrationUncertainty(unc.Reproducibility(10.0, 10.0, 0.5), boot, ref)
    alt = linear_cal(1.102, 0.85)
    mc = inline.MassCalibration(cal, 0.0, 0.0, alternatives=[alt], uncertainty=cu)
    r = inline.in_line_mass(loops_of(1000.0, 200.0, sigma3=5.0, sigma5=5.0), mc, RAW)
    m3, m5 = r.torque_a3_nm, r.torque_a5_nm
    masses = [(p[0] * m3 - p[1] * m5) / (G * DR) for p in boot]
    c = r.uncertainty.components()
    assert c["calibration"] == pytest.approx(np.std(masses, ddof=1))
    assert c["reference"] == pytest.approx(abs(0.0001 * m3) / (G * DR) / np.sqrt(2))
    assert c["reproducibility"] == pytest.approx(10.0 / (G * DR))
    assert c["model"] == pytest.approx(0.002 * m3 / (G * DR))
    assert c["g"] == 0.0 and c["loops"] > 0
    assert r.uncertainty.u_kg == pytest.approx(np.sqrt(sum(v**2 for v in c.values())))
    assert r.method == "axis-linear" and r.operating_point == "inside"


def test_loops_disagree_flags_scatter_beyond_the_loops_own_errors():
    assert unc.loops_disagree(np.array([10.0, 10.5, 9.5]), np.array([0.05, 0.05, 0.05]))
    assert not unc.loops_disagree(np.array([10.0, 10.05, 9.95]), np.array([0.05, 0.05, 0.05]))
    # the boundary: χ² = Σ((m − m̄)/se)²/(n − 1) = 4.5/se² against factor² = 1
    m = np.array([0.0, 3.0])
    assert not unc.loops_disagree(m, np.full(2, np.sqrt(4.5) * 1.001), factor=1.0)
    assert unc.loops_disagree(m, np.full(2, np.sqrt(4.5) * 0.999), factor=1.0)
    assert unc.loops_disagree(np.array([0.0, 1.0]), np.array([0.1, 0.1]), factor=3.0)
    assert not unc.loops_disagree(np.array([0.0, 1.0]), np.array([1.0, 1.0]), factor=3.0)
    assert not unc.loops_disagree(np.array([5.0]), np.array([0.1]))
    cal = linear_cal()
    drifted = [(np.full(400, 1000.0 + 30.0 * k), np.full(400, 200.0), 0.012, f"l{k}") for k in range(3)]
    noisy = [(a3 + np.random.default_rng(k).normal(0, 1.0, 400), a5, dt, n) for k, (a3, a5, dt, n) in
             enumerate(drifted)]
    r = inline.in_line_mass(noisy, inline.MassCalibration(cal, 0.0, 0.0), RAW)
    assert any("loops disagree" in w for w in r.warnings)


def test_envelope_check():
    env = E.Envelope((0.0, 3000.0), (0.0, 800.0), (0.2, 0.6))
    assert E.check(env, 1500.0, 450.0).status == "inside"
    assert E.check(env, -1500.0, -450.0).status == "inside"  # signs do not matter
    out = E.check(env, 3600.0, 900.0)  # A3 20 % of the span beyond, A5 12.5 %
    assert out.status == "outside" and out.excess == pytest.approx(0.2) and "A3 torque" in out.detail
    assert E.check(env, 3600.0, 900.0, limit=0.15).status == "refused"
    assert E.check(env, 3000.0 * 1.6, 800.0 * 1.1).status == "refused"
    ratio = E.check(env, 1000.0, 750.0)  # ratio 0.75: 37.5 % of the ratio span outside
    assert ratio.status == "outside" and "ratio" in ratio.detail and ratio.excess == pytest.approx(0.375)
    assert E.check(env, 3000.0 * 1.04, 700.0).status == "inside"  # within the tolerance
    with pytest.raises(DataError):
        E.check(env, 1.0, 1.0, limit=float("nan"))
    assert E.Envelope.from_dict(env.to_dict()) == env
    with pytest.raises(DataError):
        E.Envelope.from_dict({"torque_a3_nm": [1, 0], "torque_a5_nm": [0, 1], "ratio_a5_a3": [0, 1]})
    with_points = E.Envelope.from_torques(np.array([0.0, 100.0, -2000.0]), np.array([0.0, 30.0, -400.0]))
    assert with_points.points_nm == ((0.0, 0.0), (100.0, 30.0), (-2000.0, -400.0))
    built = dataclasses.replace(with_points, points_nm=None)  # the box alone (files written before points_nm)
    assert built == E.Envelope((0.0, 2000.0), (0.0, 400.0), (0.2, 0.3))  # both signs: magnitudes only
    assert E.check(built, 1500.0, 300.0).status == E.check(built, -1500.0, -300.0).status == "inside"
    # with the points: 1500/300 Nm lies in the box but 35 % of the range from the nearest point (2000/400 Nm)
    far = E.check(with_points, -1500.0, -300.0)
    assert far.status == "outside" and "from the nearest calibrated configuration" in far.detail
    assert E.check(with_points, 1900.0, 390.0).status == "inside"  # magnitudes: near the (−2000, −400) point
    signed = E.Envelope.from_torques(np.array([0.0, -100.0, -2000.0]), np.array([0.0, -30.0, -400.0]))
    assert signed.sign == (-1.0, -1.0) and E.Envelope.from_dict(signed.to_dict()) == signed
    signed = dataclasses.replace(signed, points_nm=None)
    assert E.check(signed, -1500.0, -300.0).status == "inside"
    flipped = E.check(signed, 1500.0, 300.0)  # a sign-flipped channel lies below the zero-load point
    assert flipped.status == "refused" and "A3 torque -1500 is 75 % of the span outside 0..2000" in flipped.detail
    with pytest.raises(DataError, match="sign must be two of"):
        E.Envelope.from_dict({**signed.to_dict(), "sign": [1, 0]})


def test_outside_widens_u_by_the_models_spread_and_far_outside_is_refused():
    cal = linear_cal()
    alts = [linear_cal(1.11, 0.85), linear_cal(1.1, 0.84)]
    cu = unc.CalibrationUncertainty(unc.Reproducibility(5.0, 5.0, 0.0), np.array([[1.1, 0.85], [1.1, 0.85]]),
                                    np.zeros((0, 2)))
    env = E.Envelope((0.0, 2500.0), (0.0, 700.0), (0.15, 0.3))
    kw = {"alternatives": alts, "uncertainty": cu, "alternative_uncertainty": [None, None], "envelope": env}
    inside = inline.in_line_mass(loops_of(2000.0, 400.0), inline.MassCalibration(cal, 0.0, 0.0, **kw), RAW)
    outside = inline.in_line_mass(loops_of(2800.0, 560.0), inline.MassCalibration(cal, 0.0, 0.0, **kw), RAW)
    assert inside.operating_point == "inside" and not inside.warnings
    assert outside.operating_point == "outside"
    assert any("outside the calibrated envelope" in w for w in outside.warnings)
    dev = np.array([float(a.mass_kg(2800.0, 560.0)) for a in alts]) - outside.gross_mass_kg
    assert outside.uncertainty.u_model_kg == pytest.approx(np.max(np.abs(dev)))
    assert inside.uncertainty.u_model_kg == pytest.approx(unc.model_form_kg(
        inside.gross_mass_kg, np.array([float(a.mass_kg(2000.0, 400.0)) for a in alts])))
    with pytest.raises(E.OperatingPointError, match="far outside"):
        inline.in_line_mass(loops_of(4000.0, 800.0), inline.MassCalibration(cal, 0.0, 0.0, **kw), RAW)
    assert inline.in_line_mass(loops_of(4000.0, 800.0), inline.MassCalibration(cal, 0.0, 0.0, **kw), RAW,
                               envelope_limit=2.0).operating_point == "outside"


@pytest.fixture
def table1(paper_dir):
    return load_points_csv(paper_dir / "table1_calibration.csv")


def test_ill_conditioned_eq20_keeps_u_finite(table1):
    """Table 1 with its ±1 kg scatter: eq. 20's four parameters are ill-determined; their covariance pushed
    through the exponentials explodes, the bootstrap of the fitted curve at the operating point does not."""
    rng = np.random.default_rng(7)
    scattered = C.CalibrationPoints(table1.kind, table1.mass_kg, table1.torque_a3_nm,
                                    table1.torque_a5_nm + rng.normal(0, 15.0, len(table1)) * (table1.mass_kg > 0),
                                    table1.expected_a3_nm, table1.expected_a5_nm, table1.mass_cov_kg2)
    cal = C.fit(scattered, "paper", G, DR)
    ev = S.evaluate(scattered, "paper", G, DR)
    cu = unc.calibration_uncertainty(scattered, "paper", G, DR, ev.heldout_residual_nm)
    m3, m5 = 1500.0, 420.0  # a 110 kg DuT in the mass-stack pose
    u_cal = cu.curve_spread_kg(cal, m3, m5)
    old = unc.calibration_mc_kg(cal, m3, m5)
    assert np.isfinite(u_cal) and 0.0 < u_cal < 3.0
    assert not np.isfinite(old) or old > 10 * u_cal  # the parameter-space propagation is useless here
    u_rep = cu.reproducibility.u_kg(G, DR)
    assert not unc.unusable(u_cal, u_rep)
    # the budget's term is the excess over the spread at the interior configurations (in the reproducibility)
    at_points = cu.at_interior(lambda a3, a5: cu.curve_spread_kg(cal, a3, a5))
    assert len(cu.interior_torque_nm) == int(unc.interior(scattered).sum()) and at_points > 0
    assert cu.u_calibration_kg(cal, m3, m5) == pytest.approx(np.sqrt(max(u_cal**2 - at_points**2, 0.0)))
    # far beyond the points the same bootstrap says the curve is not known: unusable there
    assert unc.unusable(cu.curve_spread_kg(cal, 9000.0, 8000.0), u_rep)
    assert cu.u_calibration_kg(cal, 9000.0, 8000.0) > 10 * at_points
    assert unc.unusable(float("inf"), 1.0) and unc.unusable(3.01, 1.0) and not unc.unusable(2.99, 1.0)


def test_unusable_model_hands_over_to_an_admissible_alternative():
    cal = linear_cal()
    wide = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 1.0, 0.0),
                                      np.array([[1.0, 0.85], [1.2, 0.85]]), np.zeros((0, 2)))
    alt = linear_cal(1.101, 0.85)
    tight = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 1.0, 0.0),
                                       np.array([[1.101, 0.85], [1.1011, 0.85]]), np.zeros((0, 2)))
    mc = inline.MassCalibration(cal, 0.0, 0.0, alternatives=[alt], uncertainty=wide, alternative_uncertainty=[tight])
    r = inline.in_line_mass(loops_of(1000.0, 200.0), mc, RAW)
    assert r.method == alt.method or r.gross_mass_kg == pytest.approx(float(alt.mass_kg(1000.0, 200.0)))
    assert any("unusable" in w for w in r.warnings)
    assert r.uncertainty.u_model_kg == pytest.approx(abs(float(cal.mass_kg(1000.0, 200.0)) - r.gross_mass_kg))
    # no usable alternative: the model is kept with its wide U and a warning
    r = inline.in_line_mass(loops_of(1000.0, 200.0), inline.MassCalibration(cal, 0.0, 0.0, uncertainty=wide), RAW)
    assert r.gross_mass_kg == pytest.approx(float(cal.mass_kg(1000.0, 200.0)))
    assert any("no calibration model has a usable" in w for w in r.warnings)


def test_bootstrap_and_reference_refits(table1):
    boot = unc.bootstrap_params(table1, "axis-linear", G, DR, n=30, seed=3)
    assert boot.shape == (30, 2) and np.all(np.isfinite(boot))
    cal = C.fit(table1, "axis-linear", G, DR)
    # the refits scatter around the fit, by about the parameters' standard errors
    se = np.sqrt(np.diag(cal.covariance))
    assert np.all(np.abs(boot.mean(axis=0) - cal.params) < se)
    assert np.all((boot.std(axis=0) > 0.3 * se) & (boot.std(axis=0) < 3 * se))
    ref = unc.reference_params(table1, "axis-linear", G, DR, n=20)
    assert ref.shape == (20, 2) and np.all(ref.std(axis=0) > 0)
    exact = C.CalibrationPoints(table1.kind, table1.mass_kg, table1.torque_a3_nm, table1.torque_a5_nm,
                                table1.expected_a3_nm, table1.expected_a5_nm, None)
    assert unc.reference_params(exact, "axis-linear", G, DR).shape == (0, 2)
    assert unc.refit_spread_kg(cal, ref[:1], 1000.0, 200.0) == 0.0
    mask = unc.interior(table1)
    assert not mask[0] and not mask[-1] and mask[1:-3].all()


def test_mass_equations_default_to_the_gross_mass():
    """Without a fixture mass both equations give the gross mass (m_f = 0 by default)."""
    assert mass_eq.dut_mass_uncorrected_kg(2100.0, 300.0, 100.0, 50.0, G, DR) == pytest.approx(1750.0 / (G * DR))
    assert mass_eq.dut_mass_kg(2000.0, 400.0, G, DR) == pytest.approx(1600.0 / (G * DR))
    assert linear_cal().mass_kg(1000.0, 200.0) == pytest.approx(930.0 / (G * DR))


def test_calibration_uncertainty_round_trips_and_rejects_malformed_records():
    rep = unc.Reproducibility(12.5, 20.25, -0.25, 9)
    cu = unc.CalibrationUncertainty(rep, np.array([[1.0, 2.0], [1.5, 2.5], [0.5, 1.5]]), np.array([[3.0, 4.0]]))
    d = cu.to_dict()
    assert d["reproducibility"] == {"rms_a3_nm": 12.5, "rms_a5_nm": 20.25, "corr": -0.25, "n": 9}
    assert d["bootstrap_params"] == [[1.0, 2.0], [1.5, 2.5], [0.5, 1.5]] and d["reference_params"] == [[3.0, 4.0]]
    assert "3 refits" in d["scheme"] and "1 refits" in d["scheme"]
    back = unc.CalibrationUncertainty.from_dict(d, 2)
    assert back.reproducibility == rep
    np.testing.assert_array_equal(back.fit_params, cu.fit_params)
    np.testing.assert_array_equal(back.reference_params, cu.reference_params)
    assert unc.Reproducibility(1.0, 2.0, 0.5).to_dict() == {"rms_a3_nm": 1.0, "rms_a5_nm": 2.0, "corr": 0.5}
    old = dict(d, reproducibility={"rms_a3_nm": 1.0, "rms_a5_nm": 2.0, "corr": 0.5})
    assert unc.CalibrationUncertainty.from_dict(old, 2).reproducibility.n is None
    no_ref = {k: v for k, v in d.items() if k != "reference_params"}
    assert unc.CalibrationUncertainty.from_dict(no_ref, 2).reference_params.shape == (0, 2)
    bad = [
        {k: v for k, v in d.items() if k != "reproducibility"},
        {k: v for k, v in d.items() if k != "bootstrap_params"},
        dict(d, reproducibility={"rms_a3_nm": 1.0, "rms_a5_nm": 2.0}),
        dict(d, reproducibility={"rms_a3_nm": "x", "rms_a5_nm": 2.0, "corr": 0.0}),
        dict(d, reproducibility={"rms_a3_nm": float("nan"), "rms_a5_nm": 2.0, "corr": 0.0}),
        dict(d, reproducibility={"rms_a3_nm": 1.0, "rms_a5_nm": float("inf"), "corr": 0.0}),
        dict(d, reproducibility={"rms_a3_nm": 1.0, "rms_a5_nm": 2.0, "corr": float("nan")}),
        dict(d, bootstrap_params=[[1.0, 2.0]]),
        dict(d, bootstrap_params=[[1.0, float("nan")], [1.0, 2.0]]),
        dict(d, bootstrap_params=[[1.0, 2.0, 3.0]]),
        dict(d, reference_params=[[float("inf"), 1.0]]),
        None,
    ]
    for record in bad:
        with pytest.raises(DataError, match=r"fit\.uncertainty"):
            unc.CalibrationUncertainty.from_dict(record, 2)
    # exactly two refits are enough
    assert len(unc.CalibrationUncertainty.from_dict(dict(d, bootstrap_params=d["bootstrap_params"][:2]),
                                                    2).fit_params) == 2


ENV = E.Envelope((0.0, 3000.0), (0.0, 800.0), (0.2, 0.6))


def test_envelope_messages_and_boundaries():
    assert E.check(ENV, 3600.0, 720.0).detail == "A3 torque 3600 is 20 % of the span outside 0..3000 (limit 50 %)"
    assert E.check(ENV, 2000.0, 1000.0).detail == "A5 torque 1000 is 25 % of the span outside 0..800 (limit 50 %)"
    assert E.check(ENV, 1000.0, 100.0).detail.startswith("A5/A3 torque ratio 0.1 is 25 % of the span outside 0.2..0.6")
    # exactly at the tolerance: inside; exactly at the limit: outside, not refused
    assert E.check(ENV, 3150.0, 700.0).status == "inside"
    assert E.check(ENV, 4500.0, 700.0).status == "outside"
    assert E.check(ENV, 4500.0001, 700.0).status == "refused"
    assert E.check(ENV, 1500.0, 450.0, limit=E.INSIDE_TOLERANCE).status == "inside"
    with pytest.raises(DataError, match="envelope limit"):
        E.check(ENV, 1.0, 1.0, limit=0.049)
    with pytest.raises(DataError, match="envelope limit"):
        E.check(ENV, 1.0, 1.0, limit=float("inf"))
    # a small A3 torque is still a ratio; none at all is infinitely far off
    tiny = E.Envelope((0.0, 1.0), (0.0, 1.0), (0.2, 0.6))
    assert E.check(tiny, 0.5, 0.2).status == "inside"
    assert E.check(tiny, 0.0, 0.2).status == "refused"
    # the smallest span: a tenth of the upper end
    narrow = E.Envelope((0.0, 3000.0), (0.0, 800.0), (0.25, 0.25))
    assert E.check(narrow, 2000.0, 550.0).excess == pytest.approx(0.025 / 0.025)


def test_envelope_construction_errors():
    with pytest.raises(DataError, match="no loaded point"):
        E.Envelope.from_torques(np.zeros(3), np.zeros(3))
    assert E.Envelope.from_torques(np.array([0.0, 0.5]), np.array([0.0, 0.1])).ratio_a5_a3 == (0.2, 0.2)
    assert E.Envelope.from_dict({"torque_a3_nm": [0, 1], "torque_a5_nm": [1, 1], "ratio_a5_a3": [0.2, 0.2]})
    for bad in ({"torque_a3_nm": [0, 1, 2], "torque_a5_nm": [0, 1], "ratio_a5_a3": [0, 1]},
                {"torque_a3_nm": [0, float("nan")], "torque_a5_nm": [0, 1], "ratio_a5_a3": [0, 1]}):
        with pytest.raises(DataError, match=r"finite \[low, high\]"):
            E.Envelope.from_dict(bad)
    with pytest.raises(DataError, match="malformed"):
        E.Envelope.from_dict({"torque_a3_nm": [0, 1]})


def test_reproducibility_edges():
    two = unc.Reproducibility.from_residuals(np.array([[0.5, 0.5], [-0.5, -0.5]]))
    assert two.n == 2 and two.corr == pytest.approx(1.0) and two.rms_a3_nm == pytest.approx(0.5)
    flat = unc.Reproducibility.from_residuals(np.array([[0.0, 1.0], [0.0, -1.0], [np.nan, 3.0]]))
    assert flat.corr == 0.0 and flat.n == 2 and flat.rms_a5_nm == pytest.approx(1.0)
    with pytest.raises(C.CalibrationError, match="at least two configurations"):
        unc.Reproducibility.from_residuals(np.array([[1.0, 1.0], [np.inf, 0.0]]))


def test_batch_means_exact():
    x = np.arange(20.0)
    means = x.reshape(10, 2).mean(axis=1)
    assert unc.batch_means_se(x) == pytest.approx(means.std(ddof=1) / np.sqrt(10))
    assert unc.batch_means_se(np.arange(21.0)) == pytest.approx(means.std(ddof=1) / np.sqrt(10))
    assert np.isfinite(unc.batch_means_se(np.arange(4.0)))
    assert np.isnan(unc.batch_means_se(np.arange(3.0)))
    assert unc.batch_means_se(np.arange(4.0), n_batches=2) == pytest.approx(np.std([0.5, 2.5], ddof=1) / np.sqrt(2))


def test_loop_spread_edges():
    assert unc.loop_spread_kg(np.array([1.0, 3.0])) == pytest.approx(np.std([1.0, 3.0], ddof=1) / np.sqrt(2))
    assert np.isnan(unc.loop_spread_kg(np.array([1.0])))
    assert unc.loop_spread_kg(np.array([1.0, 1.0]), np.array([0.3, np.nan])) == 0.0
    assert unc.loop_spread_kg(np.array([2.0, 2.0, 2.0, 2.0]), 0.4) == pytest.approx(0.1)


def test_unusable_and_slope_boundaries():
    assert not unc.unusable(3.0, 1.0) and unc.unusable(2.0, 0.5) and unc.unusable(1e-8, 0.0)
    quad = C.Calibration("q", C.PolyK(np.array([1e-5, 0.0, 1.0])), C.PolyK(np.array([1.0])), np.zeros((4, 4)),
                         (0.0, 3000.0), (0.0, 800.0), G, DR)
    exact = (3e-5 * 1000.0**2 + 1.0) / (G * DR)  # d(K·M)/dM of (1e-5·M² + 1)·M at 1000 Nm
    for h in (0.5, 2.0):
        s3, s5 = inline.slope_kg_per_nm(quad, 1000.0, 200.0, h_nm=h)
        assert s3 == pytest.approx(exact, rel=1e-5) and s5 == pytest.approx(-1.0 / (G * DR))


def test_in_line_mass_counts_defaults_and_messages():
    cal = linear_cal()
    r = inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=3, n=150), inline.MassCalibration(cal, 100.0, 50.0), RAW)
    assert r.mass_kg == r.gross_mass_kg and (r.samples_used, r.samples_total) == (450, 450)
    np.testing.assert_allclose(r.loop_mass_kg, np.full(3, r.gross_mass_kg))
    assert r.warnings == [] and r.method == "axis-linear"
    short = inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=2, n=99), inline.MassCalibration(cal, 0.0, 0.0), RAW)
    assert short.warnings == ["loop l0: only 99 valid samples", "loop l1: only 99 valid samples"]
    assert not inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=2, n=100), inline.MassCalibration(cal, 0.0, 0.0),
                                   RAW).warnings
    # the pre-processing is the one given: a spike stays in with RAW and is cropped by the paper's method
    spiked = [(np.r_[np.full(399, 1000.0), 5000.0], np.full(400, 200.0), 0.012, "l0")] * 2
    raw = inline.in_line_mass(spiked, inline.MassCalibration(cal, 0.0, 0.0), RAW)
    assert raw.torque_a3_nm == pytest.approx(1010.0)
    assert inline.in_line_mass(spiked, inline.MassCalibration(cal, 0.0, 0.0),
                               pp.PAPER).torque_a3_nm == pytest.approx(1000.0)
    # without an envelope (an older file) the fitted range warns
    big = inline.in_line_mass(loops_of(5000.0, 250.0), inline.MassCalibration(cal, 0.0, 0.0), RAW)
    assert any("outside the calibrated range" in w for w in big.warnings)
    drift = [(np.full(400, 1000.0 + 40.0 * k) + np.random.default_rng(k).normal(0, 1, 400), np.full(400, 200.0),
              0.012, f"l{k}") for k in range(3)]
    assert inline.in_line_mass(drift, inline.MassCalibration(cal, 0.0, 0.0), RAW).warnings == [
        "loops disagree beyond their own spread (drift or a disturbed loop)"]


def test_former_budget_and_g():
    cov = np.diag([1e-6, 4e-6])
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])), cov,
                        (0.0, 3000.0), (0.0, 800.0), G, DR, covariance_reference=np.diag([1e-8, 1e-8]))
    loops = loops_of(1000.0, 200.0, sigma3=3.0, sigma5=3.0)
    r = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0), RAW)
    m3, m5 = r.torque_a3_nm, r.torque_a5_nm
    c = r.uncertainty.components()
    assert set(c) == {"loops", "calibration", "model", "reference", "g"}
    assert c["calibration"] == pytest.approx(unc.calibration_mc_kg(cal, m3, m5))
    assert c["reference"] == pytest.approx(unc.reference_mc_kg(cal, m3, m5))
    assert c["model"] == 0.0 and c["g"] == 0.0
    assert c["loops"] == pytest.approx(unc.loop_spread_kg(r.loop_mass_kg, np.hypot(
        1.1 / (G * DR) * np.array([unc.batch_means_se(a) for a, _, _, _ in loops]),
        0.85 / (G * DR) * np.array([unc.batch_means_se(b) for _, b, _, _ in loops]))))
    rel = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0, model_rms_rel=0.01), RAW)
    assert rel.uncertainty.u_model_kg == pytest.approx(0.01 * rel.gross_mass_kg)
    other_site = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0), RAW, g_measurement_m_s2=9.8134,
                                     g_u_measurement_m_s2=0.0069)
    assert other_site.uncertainty.u_g_kg == pytest.approx(other_site.gross_mass_kg * 0.0069 / 9.8134)
    assert inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0), RAW,
                               g_measurement_m_s2=9.8134).uncertainty.u_g_kg == 0.0
    both = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0, g_u_m_s2=0.001), RAW,
                               g_measurement_m_s2=9.8134)
    assert both.uncertainty.u_g_kg == pytest.approx(both.gross_mass_kg * 0.001 / G)


def synthetic_points(r3: np.ndarray, r5: np.ndarray) -> C.CalibrationPoints:
    """A zero point and loaded points whose expected torques miss an exact linear drive by the residuals given."""
    mass = np.r_[0.0, 20.93 * np.arange(1, len(r3) + 1)]
    l5 = np.r_[0.265, 0.275 + 0.0075 * np.arange(1, len(r3) + 1)]
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    t3, t5 = e3 / 1.1, e5 / 0.85
    e3[1:] += r3
    e5[1:] += r5
    return C.CalibrationPoints(np.array(["zero"] + ["mass"] * len(r3)), (e3 - e5) / (G * DR), t3, t5, e3, e5)


def test_bootstrap_is_reproducible_and_its_spread_is_the_residuals():
    rng = np.random.default_rng(11)
    r3, r5 = rng.normal(0, 20.0, 10), rng.normal(0, 2.0, 10)  # A3 scatters ten times more than A5
    pts = synthetic_points(r3, r5)
    boot = unc.bootstrap_params(pts, "axis-linear", G, DR, n=400)
    np.testing.assert_array_equal(boot, unc.bootstrap_params(pts, "axis-linear", G, DR, n=400, seed=0))
    assert not np.array_equal(boot, unc.bootstrap_params(pts, "axis-linear", G, DR, n=400, seed=1))
    cal = C.fit(pts, "axis-linear", G, DR)
    for axis, t in ((0, pts.torque_a3_nm[1:]), (1, pts.torque_a5_nm[1:])):
        resid = (unc.residual_pairs_nm(cal, pts)[1:, axis])
        resid = resid - resid.mean()
        inflate = np.sqrt(10 / (10 - 1))
        # a linear LS slope moves by Σ M·r / Σ M²: its spread over resampled residuals
        want = inflate * np.sqrt(np.mean(resid**2)) * np.sqrt(np.sum(t**2)) / np.sum(t**2)
        assert boot[:, axis].std() == pytest.approx(want, rel=0.12), axis
    # a joint model sees the resampled masses of eq. 21: the A3 residuals dominate its spread too
    joint = unc.bootstrap_params(pts, "gain-linear", G, DR, n=60)
    assert joint.shape == (60, 2) and np.all(joint.std(axis=0) > 0)
    assert np.all(np.abs(joint.mean(axis=0) - C.fit(pts, "gain-linear", G, DR).params) < 3 * joint.std(axis=0))


def test_refit_spread_and_parameter_mc():
    cal = linear_cal()
    params = np.array([[1.1, 0.85], [1.2, 0.85], [1.0, 0.85]])
    assert unc.refit_spread_kg(cal, params, 1000.0, 200.0) == pytest.approx(100.0 / (G * DR))
    diverging = C.Calibration("paper", C.PolyK(np.array([1.0])), C.DoubleExpK(np.array([1.0, 1.0, 0.0, 0.0])),
                              np.zeros((5, 5)), (0.0, 1.0), (0.0, 1.0), G, DR)
    assert unc.refit_spread_kg(diverging, np.array([[1.0, 1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 5.0, 0.0, 0.0]]),
                               10.0, 1000.0) == float("inf")
    assert unc.covariance_mc_kg(cal, np.zeros((2, 2)), 1000.0, 200.0) == 0.0
    assert unc.covariance_mc_kg(cal, np.zeros((0, 0)), 1000.0, 200.0) == 0.0
    cov = np.diag([1e-4, 0.0])
    assert unc.covariance_mc_kg(cal, cov, 1000.0, 200.0) == pytest.approx(0.01 * 1000.0 / (G * DR), rel=0.05)
    assert unc.covariance_mc_kg(cal, cov, 1000.0, 200.0) == unc.covariance_mc_kg(cal, cov, 1000.0, 200.0, seed=0)
    assert unc.calibration_mc_kg(cal, 1000.0, 200.0) == 0.0


def test_loops_disagree_more_edges():
    assert not unc.loops_disagree(np.array([1.0, 5.0]), np.array([0.0, 0.0]))  # no within-loop errors known
    assert unc.loops_disagree(np.array([0.0, 10.0]), np.array([1.0, 1.0]))
    assert not unc.loops_disagree(np.array([0.0, 3.0]), np.array([1.0, np.nan]))
    m = np.array([0.0, 3.0, 6.0])  # Σ((m − m̄)/se)² = 18/se², over n − 1 = 2
    assert not unc.loops_disagree(m, np.full(3, 1.5 * 1.001), factor=2.0)
    assert unc.loops_disagree(m, np.full(3, 1.5 * 0.999), factor=2.0)


def test_the_widening_outside_the_envelope_is_what_held_out_configurations_erred_at_their_distance():
    """Issue 33: U outside the envelope grows with the distance to the calibrated configurations as the calibration's
    own held-out residuals grew with theirs: r² = s² + (c·d)² recovers c; no growth gives 0; too few gives NaN."""
    d = np.array([0.06, 0.06, 0.06, 0.06, 0.15, 0.2, 0.3])
    interior = np.array([True, True, True, True, True, False, False])
    s, c = 0.3, 4.0
    r = np.sqrt(s**2 + (c * d) ** 2) * np.where(np.arange(d.size) % 2, 1.0, -1.0)
    # the interior's mean square holds a little of the growth too: c is recovered to within that
    assert unc.extrapolation_kg_per_distance(r, d, interior) == pytest.approx(c, rel=0.1)
    assert unc.extrapolation_kg_per_distance(np.full(d.size, s), d, interior) == 0.0
    assert np.isnan(unc.extrapolation_kg_per_distance(r[:2], d[:2], interior[:2]))
    # from a calibration: its held-out residuals (Nm) in kg by eq. 21, its points' distances; mismatched: None
    env = E.Envelope.from_torques(np.array([0.0, -500.0, -1000.0, -1500.0, -3000.0]),
                                  np.array([0.0, -150.0, -300.0, -450.0, -2000.0]))
    np.testing.assert_allclose(env.neighbour_distances()[:2], [np.hypot(500 / 3000, 150 / 2000)] * 2)
    resid = np.array([[0.0, 0.0], [3.0, -2.0], [-2.0, 3.0], [4.0, -1.0], [60.0, -40.0]])
    slope = inline.extrapolation_slope_kg(env, resid, 9.81, 0.5)
    assert slope is not None and slope > 0
    assert inline.extrapolation_slope_kg(env, resid[:3], 9.81, 0.5) is None
    assert inline.extrapolation_slope_kg(None, resid, 9.81, 0.5) is None
