"""The paper reproduced on Table 1 (eq. 19/20/21, Table A3 as oracle) and the models' out-of-sample figures."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import selection as S


@pytest.fixture
def table1(paper_dir):
    return load_points_csv(paper_dir / "table1_calibration.csv")


@pytest.fixture
def table_a3(paper_dir):
    rows = [ln for ln in (paper_dir / "tableA3_paper_result.csv").read_text().splitlines()
            if ln and not ln.startswith("#")]
    names = rows[0].split(",")
    data = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    return {n: data[:, i] for i, n in enumerate(names)}


def test_k_a3_polynomial_reproduces_paper_r2(table1):
    cal = C.fit(table1, "paper", 9.81, 1.025)
    assert cal.r2["A3"] == pytest.approx(0.8922, abs=5e-5)
    assert isinstance(cal.k_a3, C.PolyK) and isinstance(cal.k_a5, C.DoubleExpK)


def test_k_evaluation_matches_table_a3(table1, table_a3):
    cal = C.fit(table1, "paper", 9.81, 1.025)
    t3 = cal.k_a3.corrected_torque_nm(table1.torque_a3_nm)
    t5 = cal.k_a5.corrected_torque_nm(table1.torque_a5_nm)
    # the paper's K came from its own (unrounded) data: A3 agrees to 0.1 %; the double exponential of A5 is
    # the least-squares optimum of the Table 1 samples, within 5 Nm (0.5 kg) of the paper's curve
    np.testing.assert_allclose(t3[1:], table_a3["m_a3_calc_nm"][1:], rtol=1e-3)
    np.testing.assert_allclose(t5[1:], table_a3["m_a5_calc_nm"][1:], atol=5.0)


def test_paper_mass_from_table_a3_torques_is_eq21(table_a3):
    from rgse_daemon.pipeline.mass import dut_mass_kg

    m = dut_mass_kg(table_a3["m_a3_calc_nm"], table_a3["m_a5_calc_nm"], 9.81, 1.025)
    np.testing.assert_allclose(m, table_a3["mass_calc_kg"], atol=1e-4)
    assert C.mean_abs_pct(table_a3["mass_kg"], m) == pytest.approx(0.6986, abs=5e-4)


def test_paper_method_in_sample_close_to_paper(table1):
    ev = S.evaluate(table1, "paper", 9.81, 1.025)
    assert ev.in_sample_mean_abs_err_pct == pytest.approx(0.6986, abs=0.05)
    # out of sample the paper's method is clearly worse: about 1 % and several kg at the high-torque points
    assert 0.9 < ev.loo_mean_abs_err_pct < 1.2
    assert ev.loo_max_abs_err_kg > 5.0


def test_double_exponential_fit_is_start_independent(table1):
    x, y = C._ratio_samples(table1, "A5")
    k_a, _, r2_a = C.fit_double_exp_k(x, y)
    k_b, _, r2_b = C.fit_double_exp_k(x[::-1], y[::-1], n_grid=61, n_starts=10)
    assert r2_a == pytest.approx(r2_b, abs=1e-6)
    np.testing.assert_allclose(k_a.k(x), k_b.k(x), atol=1e-5)
    # the global least-squares optimum is at least as good as the paper's own curve on the same samples
    paper_like = C.DoubleExpK(np.array([0.8337, 2.068e-5, 0.15255, -4.5108e-3]))
    assert r2_a >= C.r_squared(y, paper_like.k(x))


def test_auto_beats_paper_out_of_sample(table1):
    evs = S.evaluate_all(table1, 9.81, 1.025)
    by = {e.method: e for e in evs}
    chosen = S.select_auto(evs)
    assert chosen.loo_mean_abs_err_pct < by["paper"].loo_mean_abs_err_pct - 0.2
    assert chosen.loo_max_abs_err_kg < by["paper"].loo_max_abs_err_kg


def test_models_are_sign_safe(table1):
    flipped = C.CalibrationPoints(table1.kind, table1.mass_kg, -table1.torque_a3_nm, -table1.torque_a5_nm,
                                  table1.expected_a3_nm, table1.expected_a5_nm)
    for method in C.MODELS:
        a = C.fit(table1, method, 9.81, 1.025).mass_kg(table1.torque_a3_nm, table1.torque_a5_nm)
        b = C.fit(flipped, method, 9.81, 1.025).mass_kg(flipped.torque_a3_nm, flipped.torque_a5_nm)
        np.testing.assert_allclose(a, b, atol=1e-6, err_msg=method)


def test_gain_model_recovers_known_linear_drive():
    rng = np.random.default_rng(3)
    mass = np.r_[0.0, np.arange(1, 11) * 20.93, 228.5, 228.5]
    l3 = np.r_[np.full(11, 1.3), 1.8, 2.3]
    t3, t5 = 9.81 * mass * l3, 9.81 * mass * (l3 - 1.025)
    pts = C.CalibrationPoints(np.array(["mass"] * 13), mass, t3 / 1.1 + rng.normal(0, 0.01, 13),
                              t5 / 0.85 + rng.normal(0, 0.01, 13), t3, t5)
    cal = C.fit(pts, "gain-linear", 9.81, 1.025)
    np.testing.assert_allclose(cal.params, [1.1, 0.85], rtol=1e-4)
    assert cal.covariance.shape == (2, 2)


def test_too_few_points_is_typed_error(table1):
    with pytest.raises(DataError):
        C.fit(table1.subset(np.arange(3)), "paper", 9.81, 1.025)
    with pytest.raises(DataError, match="unknown calibration method"):
        C.fit(table1, "nope", 9.81, 1.025)
