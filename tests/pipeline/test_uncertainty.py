"""Uncertainty components: batch means under autocorrelation, loop spread, reference masses, g, model form."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import uncertainty as unc


def test_batch_means_sees_autocorrelation_the_naive_error_misses():
    rng = np.random.default_rng(0)
    n, reps, phi = 2000, 200, 0.95
    e = rng.normal(size=(reps, n))
    x = np.empty_like(e)  # AR(1) rows, vectorised over repetitions
    x[:, 0] = e[:, 0]
    for k in range(1, n):
        x[:, k] = phi * x[:, k - 1] + e[:, k]
    true_se = x.mean(axis=1).std()
    naive = np.mean(x.std(axis=1) / np.sqrt(n))
    bm = np.mean([unc.batch_means_se(row) for row in x])
    assert naive < 0.4 * true_se
    assert 0.6 * true_se < bm < 1.3 * true_se


def test_loop_spread_takes_the_larger_of_between_and_within():
    assert unc.loop_spread_kg(np.array([10.0, 10.0, 10.0]), np.array([0.3, 0.3, 0.3])) == pytest.approx(
        np.sqrt(3 * 0.09) / 3)
    assert unc.loop_spread_kg(np.array([9.0, 10.0, 11.0]), np.array([0.01] * 3)) == pytest.approx(1 / np.sqrt(3))
    assert unc.loop_spread_kg(np.array([5.0]), np.array([0.2])) == pytest.approx(0.2)


def test_nested_reference_covariance():
    var = np.array([0.0, 1.0, 2.0, 11.0]) * 1e-4
    cov = C.reference_mass_covariance(var)
    np.testing.assert_allclose(cov[1:, 1:], np.array([[1, 1, 1], [1, 2, 2], [1, 2, 11]]) * 1e-4)
    assert not np.any(cov[0])
    np.testing.assert_allclose(C.reference_mass_covariance(var, nested=False), np.diag(var))


def test_reference_mass_propagation_matches_linear_algebra(paper_dir):
    """gain-linear on exact torques: the masses' error maps into the gains exactly as a linear regression."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    assert pts.mass_cov_kg2 is not None and pts.mass_cov_kg2[-1, -1] == pytest.approx(11 * 1e-4)
    cov = C.reference_mass_param_covariance(pts, "gain-linear", 9.81, 1.025)
    # Monte Carlo over the reference masses, refitting each time
    rng = np.random.default_rng(1)
    draws = rng.multivariate_normal(pts.mass_kg, pts.mass_cov_kg2, size=300, method="eigh")
    params = np.array([C.fit(pts.with_masses(m), "gain-linear", 9.81, 1.025).params for m in draws])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), params.std(axis=0), rtol=0.15)
    # the 0.01 kg per body is a ~0.005 % gain error: small, but not zero
    rel = np.sqrt(np.diag(cov)) / np.abs(C.fit(pts, "gain-linear", 9.81, 1.025).params)
    assert np.all((rel > 1e-5) & (rel < 5e-4))


def test_g_cancels_at_the_same_site_only():
    assert unc.g_kg(100.0, 9.81, 0.0035, 9.81, 0.0035) == 0.0
    assert unc.g_kg(100.0, 9.81, 0.0, 9.8134, 0.0069) == pytest.approx(100 * 0.0069 / 9.8134)


def test_g_cancels_in_the_mass():
    """Expected torques with a wrong g: the calibrated mass does not move (the reason for the g component)."""
    rng = np.random.default_rng(2)
    mass = np.r_[0.0, 20.93 * np.arange(1, 11)]
    l3 = 1.29 + 0.0075 * np.arange(11)
    g_true = 9.8134
    t3 = g_true * mass * l3 / 1.1 + rng.normal(0, 0.5, 11)
    t5 = g_true * mass * (l3 - 1.025) / 0.85 + rng.normal(0, 0.5, 11)
    masses = []
    for g in (9.81, 9.8134):
        pts = C.CalibrationPoints(np.array(["mass"] * 11), mass, t3, t5, g * mass * l3, g * mass * (l3 - 1.025))
        masses.append([C.fit(pts, m, g, 1.025).mass_kg(2000.0, 400.0) for m in ("ratio-linear", "gain-linear")])
    np.testing.assert_allclose(masses[0], masses[1], rtol=1e-9)


def test_model_component():
    assert unc.model_kg(100.0, 0.003, np.array([])) == pytest.approx(0.3)
    assert unc.model_kg(100.0, 0.0, np.array([100.4, 99.7])) == pytest.approx(np.sqrt((0.16 + 0.09) / 2))
    u = unc.MassUncertainty(0.1, 0.2, 0.3, 0.4, 0.0)
    assert u.expanded_kg == pytest.approx(2 * np.sqrt(0.01 + 0.04 + 0.09 + 0.16))
    assert set(u.components()) == {"loops", "calibration", "model", "reference", "g"}


def test_a_refit_with_its_own_sat_scale_is_expressed_in_the_calibrations_basis(paper_dir):
    """A refit of a model with a ``sat`` term picks its own τ; its coefficients put into the calibration's basis
    (another τ) gave another curve. ``params_of`` re-expresses the refit's curve in the calibration's basis: the mass
    it gives over the covered torques is the refit's own to 0.2 kg (the refit moved the mass by up to 10 kg, and the
    calibration's basis cannot follow the other τ exactly), where the raw coefficients were 7 kg off."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    cal = C.fit(pts, "axis-sat-sat", 9.81, 1.025)
    # the same loads read 2 % higher on A5 above 1 kNm: the refit's A5 τ moves on the grid
    bent = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm,
                               pts.torque_a5_nm * (1 + 0.02 * np.clip(pts.torque_a5_nm / 1000.0 - 1.0, 0, None)),
                               pts.expected_a3_nm, pts.expected_a5_nm)
    refit = C.fit(bent, "axis-sat-sat", 9.81, 1.025)
    assert refit.k_a5.term_scales_nm != cal.k_a5.term_scales_nm
    m3, m5 = np.linspace(300.0, 4500.0, 15), np.linspace(100.0, 3100.0, 15)
    own = refit.mass_kg(m3, m5)
    assert np.max(np.abs(own - cal.mass_kg(m3, m5))) > 8.0
    assert np.max(np.abs(cal.with_params(cal.params_of(refit)).mass_kg(m3, m5) - own)) < 0.25
    assert np.max(np.abs(cal.with_params(refit.params).mass_kg(m3, m5) - own)) > 5.0
    same = C.fit(pts.with_masses(pts.mass_kg * 1.001), "axis-quad", 9.81, 1.025)  # one basis: its params as they are
    np.testing.assert_array_equal(C.fit(pts, "axis-quad", 9.81, 1.025).params_of(same), same.params)


def test_the_bootstrap_spread_of_a_sat_model_is_its_refits_own(paper_dir):
    """The calibration component of a model with a ``sat`` term: on Table 1 its refits' spread at a DuT was 31 kg
    (axis-sat-sat at 3 kNm on A3) from the basis mix-up above; re-expressed, it is of the order of the sat-free
    models' (axis-quad 0.87 kg there)."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    spread = {}
    for method in ("axis-quad", "axis-sat-sat"):
        cal = C.fit(pts, method, 9.81, 1.025)
        spread[method] = unc.refit_spread_kg(cal, unc.bootstrap_params(pts, method, 9.81, 1.025), 3000.0, 1500.0)
    assert 0.3 < spread["axis-quad"] < 2.0
    assert spread["axis-sat-sat"] < 2.0 * spread["axis-quad"]


def test_the_record_says_in_which_basis_its_refits_are():
    """``fit.uncertainty.refit_basis``: written ``calibration`` (each refit re-expressed in the calibration's basis);
    a record without it (written before) reads as None and is written back without it; any other value is refused,
    naming the field."""
    cu = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 2.0, 0.5, 5), np.array([[1.0, 2.0], [3.0, 4.0]]),
                                    np.zeros((0, 2)))
    d = cu.to_dict()
    assert d["refit_basis"] == "calibration"
    assert unc.CalibrationUncertainty.from_dict(d, 2).refit_basis == "calibration"
    del d["refit_basis"]
    old = unc.CalibrationUncertainty.from_dict(d, 2)
    assert old.refit_basis is None and "refit_basis" not in old.to_dict()
    for bad in ("own", "", 1, ["calibration"]):
        with pytest.raises(DataError, match=r"^fit\.alternatives\[2\]\.uncertainty\.refit_basis: unknown value "):
            unc.CalibrationUncertainty.from_dict({**d, "refit_basis": bad}, 2, "fit.alternatives[2].uncertainty")


def test_only_refits_of_a_sat_model_from_a_file_without_refit_basis_are_stale(paper_dir):
    """The refits of a model with a sat term (its own or an average's) stored before refit_basis were in another τ's
    basis; those of the other models always were in the calibration's, and a record with the field is right."""
    pts = load_points_csv(paper_dir / "table1_calibration.csv")
    cu = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 1.0, 0.0), np.zeros((2, 1)), np.zeros((0, 1)))
    old = unc.CalibrationUncertainty(cu.reproducibility, cu.fit_params, cu.reference_params, refit_basis=None)
    for method, sat in (("axis-sat", True), ("axis-sat-sat", True), ("avg:axis-quad+axis-sat", True),
                        ("axis-quad", False), ("avg:axis-quad+axis-log", False), ("paper", False)):
        cal = C.fit(pts, method, 9.81, 1.025)
        assert unc.stale_refits(cal, old) is sat, method
        assert not unc.stale_refits(cal, cu) and not unc.stale_refits(cal, None)
