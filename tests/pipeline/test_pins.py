"""Pins of the mass pipeline's equations found by ``make mutation``: each test fixes a behaviour that a single
changed operator used to leave unnoticed. The expected values are worked out by hand from the paper's equations
(eq. 14-21) or by independent arithmetic in the test, never taken from the code's output."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import brentq, least_squares

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline import mass as mass_eq
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import selection as S
from rgse_daemon.pipeline import thermal as T
from rgse_daemon.pipeline import uncertainty as unc

G, DR = 9.81, 1.025


# ------------------------------------------------------------------------------------------------------------
# mass.py: eq. 14 and eq. 15/21
# ------------------------------------------------------------------------------------------------------------
def test_eq14_and_eq21_work_in_float_on_integer_torques():
    """Integer torques and biases (a logger's int16 counts) are subtracted in float: 30000 − (−10000) = 40000 Nm,
    not the int16 wrap-around −25536."""
    by_hand = 40000.0 / (G * DR)
    a3 = mass_eq.dut_mass_uncorrected_kg(np.array([30000], np.int16), 0.0, np.int16(-10000), 0.0, G, DR)
    a5 = mass_eq.dut_mass_uncorrected_kg(0.0, np.array([-30000], np.int16), 0.0, np.int16(10000), G, DR)
    assert float(a3[0]) == pytest.approx(by_hand)
    assert float(a5[0]) == pytest.approx(by_hand)
    eq21 = mass_eq.dut_mass_kg(np.array([30000], np.int16), np.array([-10000], np.int16), G, DR)
    assert float(eq21[0]) == pytest.approx(by_hand)


# ------------------------------------------------------------------------------------------------------------
# thermal.py: β by regression through the origin, its u, the span
# ------------------------------------------------------------------------------------------------------------
def test_thermal_fit_axis_by_hand():
    """A single-loop point is skipped (not the end of the data); β = Σxy/Σx², u(β) = √(Σres²/(N − P − 1)/Σx²) with
    N = 5 loops, P = 2 points; the span is the widest within-point temperature range (here the two-loop point's)."""
    readings = [np.array([7.0]), np.array([100.0, 102.0]), np.array([200.0, 199.0, 204.0])]
    temps = [np.array([299.0]), np.array([300.0, 305.0]), np.array([300.0, 302.0, 304.0])]
    # x = M̄_i·(T_ij − T̄_i), y = M_ij − M̄_i, worked out per point
    x = np.array([101.0 * -2.5, 101.0 * 2.5, 201.0 * -2.0, 0.0, 201.0 * 2.0])
    y = np.array([-1.0, 1.0, -1.0, -2.0, 3.0])
    beta = (x @ y) / (x @ x)
    res = y - beta * x
    u = np.sqrt((res @ res) / 2.0 / (x @ x))
    got = T.fit_axis(readings, temps)
    assert got == (pytest.approx(beta, rel=1e-12), pytest.approx(u, rel=1e-12), pytest.approx(5.0, rel=1e-12))


def test_thermal_fit_axis_with_one_degree_of_freedom_and_small_torques():
    """N − P − 1 = 1 is enough, and Σx² below 1 (small torques) is a valid regression, not a degenerate one."""
    readings = [np.array([0.010, 0.012]), np.array([0.020, 0.019])]
    temps = [np.array([300.0, 302.0]), np.array([300.0, 301.0])]
    x = np.array([-0.011, 0.011, -0.00975, 0.00975])
    y = np.array([-0.001, 0.001, 0.0005, -0.0005])
    beta, u, span = T.fit_axis(readings, temps)
    assert beta == pytest.approx((x @ y) / (x @ x), rel=1e-9)
    res = y - beta * x
    assert u == pytest.approx(np.sqrt((res @ res) / 1.0 / (x @ x)), rel=1e-9)
    assert span == pytest.approx(2.0)


def test_thermal_fit_axis_messages_and_mismatched_points():
    with pytest.raises(DataError, match=r"^thermal drift: no calibration point has two loops$"):
        T.fit_axis([np.array([1.0])], [np.array([300.0])])
    with pytest.raises(DataError, match=r"^thermal drift: the loops' motor temperatures do not vary within the "
                                        r"points$"):
        T.fit_axis([np.array([1.0, 1.1]), np.array([2.0, 2.2])], [np.full(2, 300.0), np.full(2, 300.0)])
    with pytest.raises(ValueError, match="zip"):  # readings of three points, temperatures of two
        T.fit_axis([np.array([1.0, 1.1]), np.array([2.0, 2.2]), np.array([3.0, 3.3])],
                   [np.array([300.0, 301.0]), np.array([300.0, 302.0])])


def test_thermal_drift_with_an_exact_coefficient_is_accepted():
    """u(β) = 0 (a noise-free campaign) is valid; only a negative u is refused."""
    d = {"coeff_per_k": {"A3": 0.001, "A5": 0.002}, "u_coeff_per_k": {"A3": 0.0, "A5": 0.0},
         "reference_k": {"A3": 300.0, "A5": 301.0}, "n_loops": 6, "span_k": {"A3": 2.0, "A5": 2.0}}
    drift = T.ThermalDrift.from_dict(d)
    assert drift.u_coeff_per_k == {"A3": 0.0, "A5": 0.0}
    assert drift.u_correction_nm("A3", np.array([1000.0]), np.array([310.0])) == 0.0


# ------------------------------------------------------------------------------------------------------------
# uncertainty.py: reproducibility, the calibration file's record, reference refits, interior points
# ------------------------------------------------------------------------------------------------------------
def stack_points(scatter_nm: float = 0.0, seed: int = 0, n: int = 8) -> C.CalibrationPoints:
    """A zero point and ``n`` loads on an exact linear drive (A3 reads 1/1.1, A5 1/0.85 of the expected torque),
    with optional scatter on the expected torques; levers vary so that the A3/A5 ratio does too."""
    rng = np.random.default_rng(seed)
    mass = np.r_[0.0, 25.0 * np.arange(1, n + 1)]
    l5 = np.r_[0.3, 0.25 + 0.02 * np.arange(1, n + 1)]
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    e3[1:] += rng.normal(0.0, scatter_nm, n)
    e5[1:] += rng.normal(0.0, scatter_nm, n)
    return C.CalibrationPoints(np.array(["zero"] + ["mass"] * n), mass, e3 / 1.1, e5 / 0.85, e3, e5)


def test_reproducibility_by_hand_and_its_edges():
    r = np.array([[3.0, 1.0], [-1.0, 2.0], [2.0, -2.0], [0.0, 1.0]])
    rep = unc.Reproducibility.from_residuals(r)
    s3, s5 = np.sqrt(14.0 / 4), np.sqrt(10.0 / 4)  # RMS per axis: Σr² = 14 and 10 over 4 configurations
    assert (rep.rms_a3_nm, rep.rms_a5_nm, rep.n) == (pytest.approx(s3), pytest.approx(s5), 4)
    assert rep.corr == pytest.approx((3.0 - 2.0 - 4.0 + 0.0) / 4 / (s3 * s5))
    # integer residual records are squared in float (int16: 300² would wrap)
    wide = unc.Reproducibility.from_residuals(np.array([[300, 0], [-300, 400]], np.int16))
    assert (wide.rms_a3_nm, wide.rms_a5_nm) == (pytest.approx(300.0), pytest.approx(np.sqrt(80000.0)))
    # one axis without scatter: no correlation (not 0/0)
    flat = unc.Reproducibility.from_residuals(np.array([[1.0, 0.0], [-2.0, 0.0]]))
    assert flat.corr == 0.0 and flat.rms_a5_nm == 0.0
    # perfectly (anti)correlated axes: |ρ| never exceeds 1 by rounding, and the propagated u is exact
    a = np.array([-39.09138659531002, 26.388016173117336, 95.16162849420985])
    same = unc.Reproducibility.from_residuals(np.stack([a, a], axis=1))
    opposite = unc.Reproducibility.from_residuals(np.stack([a, -a], axis=1))
    assert same.corr == 1.0 and opposite.corr == -1.0
    assert opposite.u_kg(G, DR) == pytest.approx(2.0 * opposite.rms_a3_nm / (G * DR) * opposite.small_sample_factor)
    with pytest.raises(C.CalibrationError,
                       match=r"^reproducibility needs held-out residuals of at least two configurations$"):
        unc.Reproducibility.from_residuals(np.array([[1.0, 2.0], [np.nan, 0.0]]))


def test_reproducibility_of_a_small_scatter():
    """u = √(s3² + s5² − 2ρ·s3·s5)/(g·Δr): for s3 = s5 = 0.1 Nm, ρ = 0, many configurations, √0.02/(g·Δr)."""
    assert unc.Reproducibility(0.1, 0.1, 0.0).u_kg(G, DR) == pytest.approx(np.sqrt(0.02) / (G * DR))
    assert unc.Reproducibility(0.1, 0.1, 1.0).u_kg(G, DR) == 0.0


def test_calibration_uncertainty_record_keeps_the_interior_torques_and_floats():
    cu = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 2.0, 0.5, 5), np.array([[1, 2], [3, 4]]),
                                    np.array([[5, 6]]), np.array([[1000, 200], [1500, 300]]))
    d = cu.to_dict()
    text = json.dumps(d)
    assert '"bootstrap_params": [[1.0, 2.0], [3.0, 4.0]]' in text
    assert '"reference_params": [[5.0, 6.0]]' in text
    assert '"interior_torque_nm": [[1000.0, 200.0], [1500.0, 300.0]]' in text
    back = unc.CalibrationUncertainty.from_dict(json.loads(text), 2)
    np.testing.assert_array_equal(back.interior_torque_nm, [[1000.0, 200.0], [1500.0, 300.0]])
    record = {"reproducibility": {"rms_a3_nm": 1, "rms_a5_nm": 2, "corr": 0}, "bootstrap_params": [[1, 2], [3, 4]],
              "reference_params": [[5, 6]], "interior_torque_nm": [[1000, 200]]}
    loaded = unc.CalibrationUncertainty.from_dict(record, 2)
    for arr in (loaded.fit_params, loaded.reference_params, loaded.interior_torque_nm):
        assert arr.dtype == np.float64
    assert loaded.interior_torque_nm.shape == (1, 2)
    # the RMS over the interior configurations: √((1² + 2²)/2)
    assert cu.at_interior(lambda a3, a5: a3 / 500.0 - 1.0) == pytest.approx(np.sqrt(2.5))


def test_excess_of_an_infinite_spread_is_infinite():
    assert unc.excess_kg(float("inf"), 1.0) == float("inf")
    assert unc.excess_kg(float("nan"), 1.0) == float("inf")


def test_reference_refits_of_a_joint_model_and_their_centre():
    pts = stack_points(scatter_nm=2.0, seed=4)
    var = np.r_[0.0, np.full(8, 0.01**2)]
    pts = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm, pts.torque_a5_nm, pts.expected_a3_nm,
                              pts.expected_a5_nm, C.reference_mass_covariance(var))
    ref = unc.reference_params(pts, "gain-linear", G, DR, n=12)  # a joint model needs g and Δr to refit
    np.testing.assert_array_equal(ref, unc.reference_params(pts, "gain-linear", G, DR, n=12))
    base = C.fit(pts, "gain-linear", G, DR).params
    assert ref.shape == (12, 2) and np.all(np.abs(ref.mean(axis=0) - base) < 1e-3 * np.abs(base))
    sur = unc.reference_params(pts, "sur-linear", G, DR, n=12)  # the zero point stays unloaded in every draw
    assert np.all(np.abs(sur.mean(axis=0) - C.fit(pts, "sur-linear", G, DR).params) < 1e-3)
    zero_cov = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm, pts.torque_a5_nm, pts.expected_a3_nm,
                                   pts.expected_a5_nm, np.zeros((9, 9)))
    assert unc.reference_params(zero_cov, "gain-linear", G, DR).shape == (0, 2)
    cu = unc.calibration_uncertainty(pts, "gain-linear", G, DR, np.ones((9, 2)))
    assert cu.reference_params.shape == (unc.REFERENCE_N, 2)


def test_reference_refits_refuse_nothing_on_a_slightly_indefinite_covariance():
    """A covariance a hair from positive semi-definite (rounding in a file) is drawn from without a warning."""
    pts = stack_points()
    cov = C.reference_mass_covariance(np.r_[0.0, np.full(8, 1e-4)])
    cov[1, 2] = cov[2, 1] = 1.0001e-4  # |cov_12| > √(var_1·var_2)
    pts = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm, pts.torque_a5_nm, pts.expected_a3_nm,
                              pts.expected_a5_nm, cov)
    assert unc.reference_params(pts, "axis-linear", G, DR, n=5).shape == (5, 2)


def test_interior_points_by_hand():
    """Interior: loaded and strictly below the others' largest |M| on both axes (a tie for the largest is not)."""
    kind = np.array(["zero", "mass", "mass", "mass", "mass", "mass"])
    mass = np.array([0.0, 0.5, 10.0, 20.0, 30.0, 30.0])
    a3 = np.array([0.0, 10.0, 200.0, 900.0, 900.0, 100.0])
    a5 = np.array([0.0, 5.0, 50.0, 100.0, 80.0, 400.0])
    pts = C.CalibrationPoints(kind, mass, a3, a5, a5 + 1000.0 * (mass > 0), a5)  # (expected: any valid load)
    # 0.5 kg is a load; 900 Nm twice: neither is below the other's; the last is the largest on A5 only
    np.testing.assert_array_equal(unc.interior(pts), [False, True, True, False, False, False])


def test_model_spread_without_alternatives_is_zero():
    assert unc.model_spread_kg(5.0, np.array([])) == 0.0
    assert unc.model_spread_kg(5.0, np.array([4.0, 7.5])) == 2.5


# ------------------------------------------------------------------------------------------------------------
# preprocess.py: parameter checks, the moving average in double precision, the row median
# ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("kwargs", "message"), [
    ({"filter": "box"}, "pre-processing: unknown filter 'box' (one of none, moving_average, gaussian, median)"),
    ({"order": "sideways"}, "pre-processing: unknown order 'sideways' (one of backward, forward)"),
    ({"location": "mode"}, "pre-processing: unknown location 'mode'"),
    ({"window": 0}, "pre-processing: window must be a whole number of samples 1..100000, got 0"),
    ({"window": 2.5}, "pre-processing: window must be a whole number of samples 1..100000, got 2.5"),
    ({"window": 100_001}, "pre-processing: window must be a whole number of samples 1..100000, got 100001"),
    ({"crop_sigma": 0.0}, "pre-processing: crop_sigma must be a finite number > 0, got 0.0"),
    ({"crop_sigma": float("nan")}, "pre-processing: crop_sigma must be a finite number > 0, got nan"),
    ({"settle_s": -0.5}, "pre-processing: settle_s must be a number 0..3600 s, got -0.5"),
    ({"settle_s": float("inf")}, "pre-processing: settle_s must be a number 0..3600 s, got inf"),
])
def test_preprocessing_parameters_are_refused_by_name(kwargs, message):
    with pytest.raises(pp.PreprocessError) as err:
        pp.Preprocessing(**kwargs)
    assert str(err.value) == message


def test_preprocessing_round_trips_and_names_bad_keys():
    cfg = pp.Preprocessing(crop_sigma=2.5, filter="gaussian", window=75, order="forward", location="huber",
                           settle_s=0.3)
    assert cfg.to_dict() == {"crop_sigma": 2.5, "filter": "gaussian", "window": 75, "order": "forward",
                             "location": "huber", "settle_s": 0.3}
    assert pp.Preprocessing.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: bad parameters \{'sigma': 1\}: .*'sigma'"):
        pp.Preprocessing.from_dict({"sigma": 1})


def test_moving_average_of_float32_torques_is_summed_in_double():
    """A float32 trace (a logger's single precision) is averaged in double: its cumulative sum over 3000 samples
    of ~1500 Nm would lose the 0.01 Nm steps in single precision."""
    x = (1500.0 + 0.01 * (np.arange(3000) % 7)).astype(np.float32)
    want = np.array([x.astype(float)[max(i - 1, 0):i + 2].mean() for i in range(x.size)])  # window 3, by slices
    np.testing.assert_allclose(pp.moving_average(x, 3)[0], want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pp.moving_average(x, np.array([3.0]))[0], want, rtol=0, atol=1e-9)


def test_row_median_by_hand():
    x = np.array([[3.0, 1.0, 2.0, np.nan], [4.0, 1.0, 3.0, 2.0], [7.0, np.nan, np.nan, np.nan],
                  [np.nan, np.nan, np.nan, np.nan], [9.0, 1.0, 5.0, 3.0]])
    n_valid = np.isfinite(x).sum(axis=1)
    got = pp._row_median(x, n_valid)
    np.testing.assert_array_equal(got[[0, 1, 2, 4]], [2.0, 2.5, 7.0, 4.0])  # odd, even, one value, even
    assert np.isnan(got[3])


def test_bootstrap_refits_replayed_by_hand():
    """The residual-pair bootstrap replayed step by step: loaded points only (0.5 kg is a load), in-sample residual
    pairs centred and inflated by √(n/(n − p/2)), drawn with the generator's own integers, added to the fitted
    corrected torques; the masses of eq. 21 (floored at 1e-6 kg) for a joint model."""
    mass = np.array([0.0, 0.5, 20.0, 45.0, 70.0, 90.0])
    l5 = np.array([0.3, 0.25, 0.28, 0.31, 0.26, 0.33])
    e3, e5 = G * mass * (l5 + DR), G * mass * l5
    e3[1:] += np.array([3.0, -2.0, 5.0, -4.0, 1.0])
    e5[1:] += np.array([-1.0, 2.0, 0.5, 1.5, -2.5])
    t3, t5 = e3 / 1.1, e5 / 0.85
    pts = C.CalibrationPoints(np.array(["zero"] + ["mass"] * 5), mass, t3, t5, e3, e5)
    boot = unc.bootstrap_params(pts, "axis-linear", G, DR, n=7, seed=5)
    slope3, slope5 = (t3 @ e3) / (t3 @ t3), (t5 @ e5) / (t5 @ t5)  # least squares through the origin per axis
    fit3, fit5 = slope3 * t3[1:], slope5 * t5[1:]
    res = np.stack([e3[1:] - fit3, e5[1:] - fit5], axis=1)
    res = (res - res.mean(axis=0)) * np.sqrt(5 / (5 - 2 / 2))
    rng = np.random.default_rng(5)
    want = []
    for _ in range(7):
        d = res[rng.integers(0, 5, 5)]
        s3, s5 = fit3 + d[:, 0], fit5 + d[:, 1]
        want.append([(t3[1:] @ s3) / (t3[1:] @ t3[1:]), (t5[1:] @ s5) / (t5[1:] @ t5[1:])])
    np.testing.assert_allclose(boot, want, rtol=1e-12)
    # a joint model refits to the masses (e3 − e5)/(g·Δr) of the drawn torques; the 0.5 kg load floors at 1e-6 kg
    joint = unc.bootstrap_params(pts, "gain-linear", G, DR, n=3, seed=2)
    cal = C.fit(pts, "gain-linear", G, DR)
    fitted = np.stack([cal.k_a3.corrected_torque_nm(t3[1:]), cal.k_a5.corrected_torque_nm(t5[1:])], axis=1)
    res = np.stack([e3[1:], e5[1:]], axis=1) - fitted
    res = (res - res.mean(axis=0)) * np.sqrt(5 / (5 - 2 / 2))
    rng = np.random.default_rng(2)
    for row in joint:
        d = res[rng.integers(0, 5, 5)]
        star = fitted + d
        m = np.r_[0.0, np.maximum((star[:, 0] - star[:, 1]) / (G * DR), 1e-6)]
        refit = C.fit(C.CalibrationPoints(pts.kind, m, t3, t5, np.r_[0.0, star[:, 0]], np.r_[0.0, star[:, 1]]),
                      "gain-linear", G, DR)
        np.testing.assert_allclose(row, refit.params, rtol=1e-10)


def test_refit_spread_of_a_curve_that_turns_nan_is_infinite_without_warnings():
    """exp(b2·M) − exp(b4·M) overflows to ∞ − ∞ = NaN at a large torque: the spread is ∞, silently (the test run
    turns warnings into errors)."""
    cal = C.Calibration("paper", C.PolyK(np.array([1.0])), C.DoubleExpK(np.array([1.0, 1.0, -1.0, 1.0])),
                        np.zeros((5, 5)), (0.0, 1.0), (0.0, 1.0), G, DR)
    params = np.array([[1.0, 1.0, 1.0, -1.0, 1.0], [1.0, 1.0, 0.0, 0.0, 0.0]])
    assert unc.refit_spread_kg(cal, params, 10.0, 1000.0) == np.inf


def test_reference_streams_are_their_own():
    """The reference-mass draws use their own seed (1), not the bootstrap's or the fit covariance's (0); without a
    reference covariance the component is zero."""
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])),
                        np.diag([1e-4, 1e-4]), (0.0, 3000.0), (0.0, 800.0), G, DR, {}, np.diag([4e-5, 1e-5]))
    assert unc.reference_mc_kg(cal, 1000.0, 200.0, n_draws=200) == unc.covariance_mc_kg(
        cal, np.diag([4e-5, 1e-5]), 1000.0, 200.0, 200, seed=1)
    assert unc.reference_mc_kg(cal, 1000.0, 200.0, n_draws=200) != unc.covariance_mc_kg(
        cal, np.diag([4e-5, 1e-5]), 1000.0, 200.0, 200, seed=0)
    cal.covariance_reference = None
    assert unc.reference_mc_kg(cal, 1000.0, 200.0) == 0.0
    pts = stack_points(scatter_nm=1.0)
    pts = C.CalibrationPoints(pts.kind, pts.mass_kg, pts.torque_a3_nm, pts.torque_a5_nm, pts.expected_a3_nm,
                              pts.expected_a5_nm, C.reference_mass_covariance(np.r_[0.0, np.full(8, 1e-4)]))
    np.testing.assert_array_equal(unc.reference_params(pts, "axis-linear", G, DR, n=4),
                                  unc.reference_params(pts, "axis-linear", G, DR, n=4, seed=1))


def test_loops_disagree_at_the_default_factor_of_three():
    """χ² = Σ((m − m̄)/se)²/(n − 1) for m = 0, 3, 6: 18/se²/2 = 9/se²; the default threshold is 3² = 9, strict."""
    m = np.array([0.0, 3.0, 6.0])
    assert not unc.loops_disagree(m, np.ones(3))  # χ² = 9 exactly: not beyond
    assert unc.loops_disagree(m, np.full(3, 0.9))  # χ² = 11.1


# ------------------------------------------------------------------------------------------------------------
# inline.py: per-axis pre-processing and temperatures, every term in both budgets
# ------------------------------------------------------------------------------------------------------------
RAW = pp.Preprocessing(crop_sigma=None, filter="none", window=1, order="backward", location="mean", settle_s=0.0)


def linear_cal(k3: float = 1.1, k5: float = 0.85) -> C.Calibration:
    return C.Calibration("axis-linear", C.GainK(("lin",), np.array([k3])), C.GainK(("lin",), np.array([k5])),
                         np.zeros((2, 2)), (0.0, 3000.0), (0.0, 800.0), G, DR)


def test_in_line_mass_preprocesses_a5_with_the_given_settings():
    """A5 with a spike, no cropping asked for: its torque is the plain mean of every sample (the paper's 1σ crop
    would remove the spike)."""
    a5 = np.full(200, 200.0)
    a5[100] = 2200.0
    loops = [(np.full(200, 1000.0), a5, 0.012, "l0")]
    r = inline.in_line_mass(loops, inline.MassCalibration(linear_cal(), 0.0, 0.0), RAW)
    assert r.torque_a5_nm == pytest.approx(200.0 + 2000.0 / 200)


def test_in_line_mass_corrects_each_axis_at_its_own_temperature_in_both_budgets():
    drift = T.ThermalDrift({"A3": 0.001, "A5": 0.002}, {"A3": 1e-4, "A5": 2e-4}, {"A3": 300.0, "A5": 300.0}, 30,
                           {"A3": 5.0, "A5": 5.0})
    loops = [(np.full(50, 1000.0), np.full(50, 200.0), 0.012, f"l{k}") for k in range(2)]
    temps = [(310.0, 300.0), (320.0, 300.0)]  # A3 warm, A5 at the campaign's temperature
    cal = linear_cal()
    cu = unc.CalibrationUncertainty(unc.Reproducibility(1.0, 1.0, 0.0), np.array([[1.1, 0.85], [1.1, 0.85]]),
                                    np.zeros((0, 2)))
    s3 = 1.1 / (G * DR)
    for kw in ({}, {"uncertainty": cu}):
        r = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0, thermal=drift, g_u_m_s2=0.01, **kw), RAW,
                                loop_temps_k=temps, g_measurement_m_s2=9.8134)
        m3 = 1000.0 * (1 - 0.001 * 15.0)  # mean of the corrections at +10 K and +20 K
        assert (r.torque_a3_nm, r.torque_a5_nm) == (pytest.approx(m3), pytest.approx(200.0))
        c = r.uncertainty.components()
        assert c["thermal"] == pytest.approx(s3 * 1000.0 * 15.0 * 1e-4)  # A5 at T_ref: no A5 part
        assert c["g"] == pytest.approx(abs(r.gross_mass_kg) * 0.01 / G)


def test_crop_works_row_by_row():
    """Each row (a filter window of the study) is cropped about its own mean and σ."""
    x = np.array([[0.0, 1.0, 2.0, 3.0, 40.0], [100.0, 101.0, 102.0, 103.0, 104.0]])
    got = pp.crop_outliers(x, 1.0)
    # row 0: mean 9.2, σ 15.4: only 40 is beyond; row 1: mean 102, σ √2: 100 and 104 are beyond
    np.testing.assert_array_equal(np.isfinite(got), [[True, True, True, True, False], [False, True, True, True, False]])
    # a tiny σ keeps at least the sample nearest the mean of each row
    np.testing.assert_array_equal(np.isfinite(pp.crop_outliers(np.array([[0.0, 1.0, 5.0], [7.0, 9.0, 20.0]]), 1e-9)),
                                  [[False, True, False], [False, True, False]])


def test_smooth_edges_and_windows():
    x = np.array([1.0, 2.0, 3.0, 4.0, 50.0])
    # median of 5, ends continued by their nearest sample: the first reads (1, 1, 1, 2, 3), the last (3, 4, 50, 50, 50)
    assert pp.smooth(x, "median", 5)[0, -1] == 50.0 and pp.smooth(x, "median", 5)[0, 0] == 1.0
    # windows are whole samples: 2.5 is a window of 2
    np.testing.assert_array_equal(pp.smooth(x, "gaussian", 2.5), pp.smooth(x, "gaussian", 2))
    assert pp.smooth(np.array([1, 2, 3]), "none", 1).dtype == np.float64
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: unknown filter 'box'$"):
        pp.smooth(x, "box", 3)


def test_loop_messages_spread_and_kept_samples():
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: a loop must be 1-D, got shape \(2, 2\)$"):
        pp.process_loop(np.ones((2, 2)), 0.01, RAW)
    # a missing sample (NaN) is left out, the rest is used (issue 33)
    gap = pp.process_loop(np.array([1.0, np.nan, 2.0, 3.0]), 0.01, RAW)
    assert gap.torque_nm == 2.0 and gap.n_used == 3 and gap.n_total == 4
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: a point needs at least one loop$"):
        pp.double_average_nm(np.array([]))
    r = pp.process_loop(np.array([1.0, 2.0, 3.0, 4.0]), 0.01, RAW)
    assert (r.torque_nm, r.spread_nm, r.n_used, r.n_total) == (2.5, pytest.approx(np.sqrt(1.25)), 4, 4)
    # kept samples: the settle cut counts in samples of the period (0.1 s at 10 ms: 10), then the 1σ crop
    x = np.r_[np.full(10, 99.0), [10.0, 11.0, 12.0, 30.0, 11.0, 10.0, 12.0, 11.0]]
    for order in ("backward", "forward"):
        cfg = pp.Preprocessing(crop_sigma=1.0, filter="none", window=1, order=order, settle_s=0.1)
        np.testing.assert_array_equal(pp.kept_samples(x, 0.01, cfg), [10.0, 11.0, 12.0, 11.0, 10.0, 12.0, 11.0])
    assert pp.normalise(np.array([30000], np.int16), np.int16(-10000))[0] == 40000.0


def test_trimmed_mean_by_hand():
    """10 % cut from each tail of the valid samples (floor of 0.1·n), per row, NaN ignored."""
    a = np.array([10.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 100.0, 9.0, 11.0])  # n = 12: cut 1 each side
    b = np.array([np.nan, 4.0, 1.0, 2.0, 3.0, 50.0, 5.0, 6.0, 7.0, 8.0, 9.0, np.nan])  # n = 10: cut 1 each side
    got = pp.location_rows(np.stack([a, b]), "trimmed")
    want = [(2 + 3 + 4 + 5 + 6 + 7 + 8 + 9 + 10 + 11) / 10, (2 + 3 + 4 + 5 + 6 + 7 + 8 + 9) / 8]
    np.testing.assert_allclose(got, want, rtol=1e-15)


def huber_by_definition(row: np.ndarray) -> float:
    """The root of Σ ψ_c(x − μ) = 0, ψ clipped at c = 1.345·s, s = 1.4826·MAD (the standard deviation if MAD = 0)."""
    v = row[np.isfinite(row)]
    med = np.median(v)
    s = 1.4826 * np.median(np.abs(v - med)) or np.std(v)
    c = 1.345 * s
    return brentq(lambda mu: np.sum(np.clip(v - mu, -c, c)), v.min(), v.max(), xtol=1e-13)


def test_huber_location_is_the_root_of_its_estimating_equation():
    rows = np.array([[0.10, 0.12, 0.11, 0.13, 0.35, 0.09, 0.11, np.nan, 0.60],  # MAD-scale < 1, skewed, a NaN
                     [5.0, 5.0, 5.0, 5.0, 5.0, 6.0, 20.0, 5.0, 9.0]])  # MAD = 0: the standard deviation is the scale
    got = pp.location_rows(rows, "huber")
    np.testing.assert_allclose(got, [huber_by_definition(r) for r in rows], rtol=0, atol=1e-8)
    assert got[0] != pytest.approx(np.nanmedian(rows[0]), abs=1e-4) and got[1] != pytest.approx(5.0, abs=1e-3)


def test_loop_checks_name_the_problem():
    x = np.arange(10.0)
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: sample period must be > 0, got 0\.0$"):
        pp.process_loop(x, 0.0, RAW)
    cfg = pp.Preprocessing(crop_sigma=None, filter="none", window=1, settle_s=0.08)
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: only 2 samples left after the 0\.08 s settle "
                                                 r"cut$"):
        pp.process_loop(x, 0.01, cfg)
    with pytest.raises(pp.PreprocessError, match=r"^pre-processing: unknown location 'mode'$"):
        pp.location_rows(x, "mode")
    # a tight crop may leave a single sample: that is a loop, not an error
    tight = pp.Preprocessing(crop_sigma=0.5, filter="none", window=1)
    r = pp.process_loop(np.array([0.0, 10.0, 20.0]), 0.01, tight)
    assert (r.torque_nm, r.n_used) == (10.0, 1)


def test_parameter_monte_carlo_is_the_sample_deviation_of_seeded_draws():
    """Eq. 21 with constant gains is linear in them: m = (k3·M3 − k5·M5)/(g·Δr) for each draw; the component is the
    sample standard deviation (n − 1) over the draws of the generator seeded 0 (fit) or 1 (reference masses)."""
    cov = np.array([[1e-4, 2e-5], [2e-5, 4e-5]])
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])),
                        cov, (0.0, 3000.0), (0.0, 800.0), G, DR)
    for seed in (0, 3):
        draws = np.random.default_rng(seed).multivariate_normal([1.1, 0.85], cov, size=4, method="eigh")
        masses = (draws[:, 0] * 1000.0 - draws[:, 1] * 200.0) / (G * DR)
        assert unc.covariance_mc_kg(cal, cov, 1000.0, 200.0, n_draws=4, seed=seed) == pytest.approx(
            np.std(masses, ddof=1), rel=1e-12)
    assert unc.calibration_mc_kg(cal, 1000.0, 200.0, n_draws=4) == unc.covariance_mc_kg(
        cal, cov, 1000.0, 200.0, n_draws=4, seed=0)
    # a covariance a hair from positive semi-definite is drawn from silently (warnings are errors here)
    near = np.array([[1e-4, 1.00001e-4], [1.00001e-4, 1e-4]])
    assert unc.covariance_mc_kg(cal, near, 1000.0, 200.0, n_draws=10) > 0


# ------------------------------------------------------------------------------------------------------------
# calibration.py and selection.py: the gain curve's K, the model records, leave-one-out, the nested figure of auto
# ------------------------------------------------------------------------------------------------------------
def test_gain_curve_k_by_hand():
    """K = G(M)/M of G = 1.1·M + 0.02·M·|M|/1000; at M = 0 the linear coefficient (the limit), NaN without one."""
    k = C.GainK(("lin", "quad"), np.array([1.1, 0.02]))
    np.testing.assert_allclose(k.k(np.array([0.0, 1000.0, -500.0])), [1.1, 1.12, 1.11], rtol=1e-14)
    assert k.k(np.array([250.0]))[0] == pytest.approx((275.0 + 1.25) / 250.0, rel=1e-14)
    only_sqrt = C.GainK(("sqrt",), np.array([2.0]))
    got = only_sqrt.k(np.array([0.0, 4.0]))
    assert np.isnan(got[0]) and got[1] == pytest.approx(2.0 * np.sqrt(4000.0) / 4.0)
    assert C.GainK(("quad", "lin"), np.array([0.5, 0.9])).k(np.array([0.0]))[0] == 0.9  # wherever "lin" sits


def test_saturating_gain_term_by_hand():
    """sat: sign(M)·τ·(1 − exp(−|M|/τ)), odd, slope 1 at 0 (so K(0) adds its coefficient, as log's), flat beyond τ;
    each term at its own scale when ``scales_nm`` is given."""
    k = C.GainK(("lin", "sat", "quad"), np.array([0.9, 0.2, 0.01]), 1000.0, (1000.0, 300.0, 1000.0))
    m = np.array([-600.0, 150.0, 2500.0])
    want = 0.9 * m + 0.2 * np.sign(m) * 300.0 * (1 - np.exp(-np.abs(m) / 300.0)) + 0.01 * m * np.abs(m) / 1000.0
    np.testing.assert_allclose(k.corrected_torque_nm(m), want, rtol=1e-14)
    assert k.k(np.array([0.0]))[0] == pytest.approx(1.1)
    assert C.GainK(("lin", "log"), np.array([1.0, 0.05])).k(np.array([0.0]))[0] == pytest.approx(1.05)
    assert k.term_scales_nm == (1000.0, 300.0, 1000.0) and C.GainK(("lin",), np.ones(1)).term_scales_nm == (1000.0,)


def test_saturating_gain_fit_finds_its_scale_and_is_refused_below_it():
    """An exact drive with a saturating gain at τ = 300 Nm on the grid: the fit picks that τ and reproduces every
    expected torque; the grid stops at 0.8 of the largest covered torque, so a calibration up to 60 Nm has none."""
    tau = min((1000.0 * m for m in C.SAT_SCALE_MULTIPLES), key=lambda t: abs(t - 300.0))
    true = C.GainK(("lin", "sat", "quad"), np.array([0.85, 0.25, 0.01]), 1000.0, (1000.0, tau, 1000.0))
    torque = np.r_[0.0, np.linspace(60.0, 3200.0, 13)]
    expected = true.corrected_torque_nm(torque)
    k, cov, r2 = C.fit_axis_gain(torque, expected, ("lin", "sat", "quad"))
    assert k.term_scales_nm == (1000.0, tau, 1000.0) and r2 == pytest.approx(1.0)
    np.testing.assert_allclose(k.coef, true.coef, rtol=1e-8)
    assert cov.shape == (3, 3)
    with pytest.raises(C.CalibrationError, match=r"too small for a saturating term"):
        C.fit_axis_gain(np.array([0.0, 10.0, 20.0, 40.0, 50.0, 60.0]), np.zeros(6), ("lin", "sat", "quad"))
    with pytest.raises(C.CalibrationError, match=r"needs at least 5 points, got 4"):
        C.fit_axis_gain(torque[:4], expected[:4], ("lin", "sat", "quad"))


def test_average_of_curves_with_their_own_scales_is_their_mean():
    """Curves with sat terms at different scales average over the union of (term, scale) pairs: the mean corrected
    torque of the members, whose record keeps the scales and reads back; lin terms merge whatever the scale."""
    a = C.GainK(("lin", "sat", "quad"), np.array([0.9, 0.2, 0.01]), 1000.0, (1000.0, 300.0, 1000.0))
    b = C.GainK(("lin", "sat"), np.array([1.0, -0.1]), 1000.0, (1000.0, 800.0))
    c = C.GainK(("lin", "quad"), np.array([1.1, 0.02]))
    mean = C._mean_gain([a, b, c])
    assert mean.terms == ("lin", "quad", "sat", "sat") and mean.term_scales_nm == (1000.0, 1000.0, 300.0, 800.0)
    m = np.linspace(-3000.0, 3000.0, 13)
    np.testing.assert_allclose(mean.corrected_torque_nm(m), (a.corrected_torque_nm(m) + b.corrected_torque_nm(m)
                                                            + c.corrected_torque_nm(m)) / 3, rtol=1e-12)
    back = C.AxisK.from_dict(json.loads(json.dumps(mean.to_dict())))
    assert back.to_dict() == mean.to_dict() and back.to_dict()["scales_nm"] == [1000.0, 1000.0, 300.0, 800.0]
    assert "scales_nm" not in C._mean_gain([c, c]).to_dict()  # one scale: the record as before
    for bad in ([1000.0], [1000.0, -5.0]):
        with pytest.raises(DataError, match=r"malformed axis model .*scales positive"):
            C.AxisK.from_dict({"kind": "gain", "terms": ["lin", "sat"], "coef": [1.0, 0.1], "scale_nm": 1000.0,
                               "scales_nm": bad})
    pts = stack_points(scatter_nm=2.0, seed=5, n=12)
    avg = C.fit(pts, "avg:axis-quad+axis-sat", G, DR)
    members = [C.fit(pts, m, G, DR) for m in ("axis-quad", "axis-sat")]
    np.testing.assert_allclose(avg.points_mass_kg(pts), np.mean([f.points_mass_kg(pts) for f in members], axis=0),
                               rtol=1e-10)


def test_axis_model_records_round_trip_and_name_their_faults():
    models = [C.PolyK(np.array([1e-8, -2e-5, 1.1])), C.DoubleExpK(np.array([0.5, -1e-3, 0.6, 1e-5])),
              C.GainK(("lin", "log"), np.array([1.05, 0.02]), 800.0)]
    assert [m.to_dict() for m in models] == [
        {"kind": "poly", "coef": [1e-8, -2e-5, 1.1]}, {"kind": "double_exp", "b": [0.5, -1e-3, 0.6, 1e-5]},
        {"kind": "gain", "terms": ["lin", "log"], "coef": [1.05, 0.02], "scale_nm": 800.0}]
    for m in models:
        back = C.AxisK.from_dict(json.loads(json.dumps(m.to_dict())))
        assert type(back) is type(m) and np.array_equal(back.params, m.params)
        assert back.to_dict() == m.to_dict()
    assert C.AxisK.from_dict(models[2].to_dict()).scale_nm == 800.0
    cal = C.Calibration("x", models[0], models[1], np.zeros((7, 7)), (0.0, 1.0), (0.0, 1.0), G, DR)
    assert cal.models_dict() == {"A3": models[0].to_dict(), "A5": models[1].to_dict()}
    with pytest.raises(DataError, match=r"^calibration model: unknown axis model kind 'spline'$"):
        C.AxisK.from_dict({"kind": "spline"})
    with pytest.raises(DataError, match=r"^calibration model: malformed axis model \{'kind': 'poly'\}: 'coef'$"):
        C.AxisK.from_dict({"kind": "poly"})
    with pytest.raises(DataError, match=r"^calibration model: malformed axis model \{'coef': \[1\]\}: 'kind'$"):
        C.AxisK.from_dict({"coef": [1]})
    with pytest.raises(DataError, match=r"^calibration model: malformed axis model .*'b': 'x'.*could not convert"):
        C.AxisK.from_dict({"kind": "double_exp", "b": "x"})
    with pytest.raises(DataError, match=r"^calibration model: malformed axis model .*'terms': 1"):
        C.AxisK.from_dict({"kind": "gain", "terms": 1, "coef": [1.0], "scale_nm": 1000.0})


def test_leave_one_out_by_hand():
    """Each configuration predicted by the constant gains fitted (least squares through the origin) on the others."""
    pts = stack_points(scatter_nm=3.0, seed=9, n=6)
    t3, t5, e3, e5 = pts.torque_a3_nm, pts.torque_a5_nm, pts.expected_a3_nm, pts.expected_a5_nm
    want = []
    for i in range(len(pts)):
        o = np.arange(len(pts)) != i
        k3, k5 = (t3[o] @ e3[o]) / (t3[o] @ t3[o]), (t5[o] @ e5[o]) / (t5[o] @ t5[o])
        # eq. 21 with the point's own lever difference, which its expected torques encode: (e3 − e5)/(g·m)
        dr = (e3[i] - e5[i]) / (G * pts.mass_kg[i]) if pts.mass_kg[i] > 0 else DR
        want.append((k3 * t3[i] - k5 * t5[i]) / (G * dr))
    np.testing.assert_allclose(S.leave_one_out_mass_kg(pts, "axis-linear", G, DR), want, rtol=1e-12, atol=1e-12)


def test_nested_out_of_sample_of_auto_on_an_exact_drive():
    """Constant drive gains, no scatter: whatever each fold selects recovers every held-out mass; progress per fold."""
    pts = stack_points(n=6)
    calls = []
    got = S.nested_loo_auto_mass_kg(pts, G, DR, progress=lambda done, total: calls.append((done, total)))
    np.testing.assert_allclose(got, pts.mass_kg, rtol=1e-9, atol=1e-9)
    assert calls == [(i, 7) for i in range(1, 8)]


def test_average_of_gain_models_by_hand():
    """avg:a+b: per axis the mean gain curve over the union of terms, the members' covariances mapped onto it and
    divided by n², the torque range of the loaded points (a 0.5 kg load is one), no R²."""
    base = stack_points(scatter_nm=2.0, seed=3, n=6)
    mass = base.mass_kg.copy()
    mass[1] = 0.5
    pts = C.CalibrationPoints(base.kind, mass, base.torque_a3_nm, base.torque_a5_nm, base.expected_a3_nm,
                              base.expected_a5_nm)
    lin, quad = C.fit(pts, "axis-linear", G, DR), C.fit(pts, "axis-quad", G, DR)
    avg = C.fit(pts, "avg:axis-linear+axis-quad", G, DR)
    assert avg.method == "avg:axis-linear+axis-quad" and avg.r2 == {}
    assert avg.k_a3.terms == ("lin", "quad") and avg.k_a5.terms == ("lin", "quad")
    np.testing.assert_allclose(avg.k_a3.coef, [(lin.k_a3.coef[0] + quad.k_a3.coef[0]) / 2, quad.k_a3.coef[1] / 2])
    want = np.zeros((4, 4))
    want[np.ix_([0, 2], [0, 2])] += lin.covariance / 4
    want += quad.covariance / 4
    np.testing.assert_allclose(avg.covariance, want, rtol=1e-12)
    assert avg.torque_range_a3_nm == (abs(pts.torque_a3_nm[1]), abs(pts.torque_a3_nm[-1]))
    assert avg.torque_range_a5_nm == (min(abs(pts.torque_a5_nm[1:])), max(abs(pts.torque_a5_nm[1:])))
    assert avg.g_m_s2 == G and avg.lever_difference_m == DR
    with pytest.raises(C.CalibrationError, match=r"^average 'avg:axis-linear': needs at least two of axis-linear, "
                                                 r"axis-quad, "):
        C.fit(pts, "avg:axis-linear", G, DR)
    with pytest.raises(C.CalibrationError, match=r"^only gain curves can be averaged, got poly$"):
        C._mean_gain([C.PolyK(np.array([1.0, 0.0]))])
    with pytest.raises(ValueError):  # terms and coefficients must pair up
        C._mean_gain([C.GainK(("lin", "quad"), np.array([1.0]))])


def test_known_methods():
    assert C.known_method("paper") and C.known_method("avg:axis-linear+sur-quad")
    assert not C.known_method("avg:axis-linear") and not C.known_method("spline")
    assert not C.known_method("avg:axis-linear+gain-linear")  # a joint model cannot be averaged


def test_reference_mass_parameter_covariance_without_a_covariance_is_zero():
    pts = stack_points(n=6)
    np.testing.assert_array_equal(C.reference_mass_param_covariance(pts, "axis-quad", G, DR), np.zeros((4, 4)))


def test_with_masses_scales_the_expected_torques_of_the_loads_only():
    pts = C.CalibrationPoints(np.array(["zero", "mass", "mass"]), np.array([0.0, 0.5, 20.0]),
                              np.array([0.0, 5.0, 200.0]), np.array([0.0, 1.0, 40.0]), np.array([3.0, 5.5, 220.0]),
                              np.array([-2.0, 1.2, 44.0]),
                              np.eye(3) * 1e-4)
    new = pts.with_masses(np.array([0.0, 1.0, 15.0]))  # scales 2 and 0.75; the zero point keeps its torques
    np.testing.assert_allclose(new.expected_a3_nm, [3.0, 11.0, 165.0])
    np.testing.assert_allclose(new.expected_a5_nm, [-2.0, 2.4, 33.0])
    np.testing.assert_array_equal(new.mass_cov_kg2, pts.mass_cov_kg2)


def test_out_of_range_limits_and_message():
    """Range 100..1100 Nm, 5 % of the 1000 Nm span beyond either end: 50 and 1150 Nm are still inside."""
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])),
                        np.zeros((2, 2)), (100.0, 1100.0), (10.0, 410.0), G, DR)
    assert cal.out_of_range(50.0, 390.0) == [] and cal.out_of_range(-1150.0, 430.0) == []
    assert cal.out_of_range(60.0, 30.0) == []
    assert cal.out_of_range(49.0, 200.0) == ["torque A3 |49.0| Nm is outside the calibrated range 100.0..1100.0 Nm"]
    assert cal.out_of_range(1000.0, -430.5) == ["torque A5 |-430.5| Nm is outside the calibrated range 10.0..410.0 Nm"]
    assert len(cal.out_of_range(1150.1, 0.0)) == 1


def test_evaluate_all_progress_and_refusal():
    pts = stack_points(scatter_nm=1.0, n=6)
    calls = []
    evs = S.evaluate_all(pts, G, DR, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(i, len(C.MODELS)) for i in range(1, len(C.MODELS) + 1)] and len(evs) > 0
    one = C.CalibrationPoints(np.array(["zero", "mass"]), np.array([0.0, 10.0]), np.array([0.0, 100.0]),
                              np.array([0.0, 20.0]), np.array([0.0, 110.0]), np.array([0.0, 22.0]))
    with pytest.raises(C.CalibrationError, match=r"^no calibration model can be fitted to these points \(too few "
                                                 r"loaded points\)$"):
        S.evaluate_all(one, G, DR)


def ev(method: str, loo_pct: float, n_params: int = 2, admissible: bool = True, lever_pct: float = np.nan,
       loo: tuple[float, ...] = (0.0, 10.0), lever: tuple[float, ...] = (np.nan, np.nan)) -> S.Evaluation:
    return S.Evaluation(method, np.array(loo) + 0.1, np.array(loo), 0.0, loo_pct, 0.0, n_params,
                        np.zeros((len(loo), 2)), np.array(lever), lever_pct, admissible)


def test_selection_rules_by_hand():
    # without any lever-group figure the score is the configuration error alone
    assert S.selection_score([ev("axis-linear", 0.7), ev("sur-quad", 0.6)]) == {"axis-linear": 0.7, "sur-quad": 0.6}
    assert S.selection_score([ev("axis-linear", 0.7), ev("sur-quad", 0.6, lever_pct=2.0)]) == {
        "axis-linear": pytest.approx(0.72), "sur-quad": pytest.approx(0.62)}
    # nothing admissible: the best of all
    assert S.select_auto([ev("axis-linear", 0.7, admissible=False), ev("axis-quad", 0.5, 4, False)]).method == \
        "axis-quad"
    # no per-axis model: the joint one
    assert S.select_auto([ev("gain-linear", 0.9)]).method == "gain-linear"
    # a joint model exactly the margin better does not replace the per-axis model
    axis = 0.5
    joint = axis - S.PREFER_AXIS_MARGIN_PCT
    assert S.select_auto([ev("axis-linear", axis), ev("gain-linear", joint)]).method == "axis-linear"
    assert S.select_auto([ev("axis-linear", axis), ev("gain-linear", joint - 1e-9)]).method == "gain-linear"
    # within 0.01 % the fewer parameters win (0.01 exactly included), beyond it the score
    assert S.select_auto([ev("axis-quad", 0.5, 4), ev("axis-linear", 0.5 + 0.01, 2)]).method == "axis-linear"
    assert S.select_auto([ev("axis-quad", 0.5, 4), ev("axis-linear", 0.52, 2)]).method == "axis-quad"


def test_average_of_members_by_hand():
    pts = C.CalibrationPoints(np.array(["zero", "mass"]), np.array([0.0, 10.0]), np.zeros(2), np.zeros(2),
                              np.array([0.0, 130.0]), np.array([0.0, 30.0]))
    a = ev("axis-linear", 0.4, loo=(0.2, 10.4), lever=(np.nan, 9.0))
    b = ev("sur-quad", 0.6, 4, loo=(-0.2, 9.8), lever=(np.nan, 10.0))  # exactly 1.5 × the best: a member
    c = ev("axis-quad", 0.61, 4, loo=(5.0, 5.0))
    avg = S.average_of(pts, [a, b, c, ev("gain-linear", 0.1)])  # the joint model is never averaged
    assert avg.method == "avg:axis-linear+sur-quad"
    np.testing.assert_allclose(avg.loo_mass_kg, [0.0, 10.1])
    np.testing.assert_allclose(avg.in_sample_mass_kg, [0.1, 10.2])
    np.testing.assert_allclose(avg.lever_mass_kg, [np.nan, 9.5])
    assert avg.lever_mean_abs_err_pct == pytest.approx(5.0) and avg.loo_mean_abs_err_pct == pytest.approx(0.5)
    assert avg.n_params == 4  # the union of the terms per axis: lin and quad on A3, lin and quad on A5
    assert S.average_of(pts, [a]) is None
    assert S.average_of(pts, [a, ev("axis-quad", 0.61, 4)]) is None
    # a per-axis model that is no gain curve sets the bar too: clearly better than every gain curve, no average
    assert S.average_of(pts, [ev("paper", 0.39), a, b]) is None
    assert S.average_of(pts, [ev("paper", 0.4), a, b]).method == "avg:axis-linear+sur-quad"
    # ... but an inadmissible or a joint one does not
    assert S.average_of(pts, [ev("paper", 0.1, admissible=False), a, b]).method == "avg:axis-linear+sur-quad"
    assert S.average_of(pts, [ev("gain-quad", 0.1), a, b]).method == "avg:axis-linear+sur-quad"


def test_axis_gain_fit_by_hand():
    """Per axis, least squares of the expected torque on the basis functions; cov = s²·(AᵀA)⁻¹ with n − p degrees of
    freedom; at least p + 1 points; the torque range over the loads (0.5 kg is one); R² per axis."""
    t = np.array([0.0, 100.0, 300.0, 500.0])
    e = np.array([0.0, 112.0, 327.0, 556.0])
    k, cov, r2 = C.fit_axis_gain(t, e, ("lin",))
    c = (t @ e) / (t @ t)
    res = e - c * t
    assert k.coef[0] == pytest.approx(c, rel=1e-12)
    assert cov[0, 0] == pytest.approx((res @ res) / (4 - 1) / (t @ t), rel=1e-10)
    assert r2 == pytest.approx(1 - (res @ res) / np.sum((e - e.mean()) ** 2), rel=1e-12)
    with pytest.raises(C.CalibrationError, match=r"^gain curve lin\+quad needs at least 3 points, got 2$"):
        C.fit_axis_gain(t[:2], e[:2], ("lin", "quad"))
    assert C.fit_axis_gain(t[:3], e[:3], ("lin", "quad"))[0].coef.shape == (2,)
    pts = C.CalibrationPoints(np.array(["zero", "mass", "mass", "mass"]), np.array([0.0, 0.5, 20.0, 30.0]), t,
                              -t / 2, e, -e / 2)
    cal = C.fit(pts, "axis-linear", G, DR)
    assert cal.method == "axis-linear" and set(cal.r2) == {"A3", "A5"}
    assert cal.torque_range_a3_nm == (100.0, 500.0) and cal.torque_range_a5_nm == (50.0, 250.0)


def test_huber_lstsq_is_the_huber_m_estimate():
    """The IRLS result minimises the Huber loss with the threshold 1.345 × (1.4826 × the median |residual| of the
    least-squares start): scipy's own Huber loss with that scale finds the same line."""
    rng = np.random.default_rng(2)
    x = np.linspace(1.0, 10.0, 15)
    a = np.stack([x, np.ones_like(x)], axis=1)
    y = 2.0 * x + 1.0 + rng.normal(0.0, 0.3, 15)
    y[[3, 11]] += [6.0, -4.0]
    start, *_ = np.linalg.lstsq(a, y, rcond=None)
    scale = 1.4826 * np.median(np.abs(a @ start - y))
    ref = least_squares(lambda c: a @ c - y, start, loss="huber", f_scale=1.345 * scale, xtol=1e-15, ftol=1e-15,
                        gtol=1e-15).x
    np.testing.assert_allclose(C.huber_lstsq(a, y), ref, rtol=1e-7)
    exact = 2.0 * x + 1.0  # a perfect fit: no scale, the least-squares answer
    np.testing.assert_allclose(C.huber_lstsq(a, exact), [2.0, 1.0], rtol=1e-12)


def test_batch_means_default_is_ten_batches():
    x = np.random.default_rng(8).normal(0.0, 1.0, 34)
    means = x[:30].reshape(10, 3).mean(axis=1)  # 34 samples: ten batches of three, the last four left over
    assert unc.batch_means_se(x) == pytest.approx(means.std(ddof=1) / np.sqrt(10), rel=1e-12)


def test_calibration_uncertainty_record_needs_two_finite_refits():
    record = {"reproducibility": {"rms_a3_nm": 1.0, "rms_a5_nm": 2.0, "corr": 0.0}, "bootstrap_params": [[1.0, 2.0]]}
    with pytest.raises(DataError, match=r"^fit\.uncertainty: needs finite reproducibility and at least two bootstrap "
                                        r"parameter sets$"):
        unc.CalibrationUncertainty.from_dict(record, 2)


def ev_rms(method: str, rms3: float, rms5: float) -> S.Evaluation:
    """An evaluation whose held-out per-axis residuals have exactly this RMS (±r on two configurations)."""
    return S.Evaluation(method, np.zeros(2), np.zeros(2), 0.0, 0.5, 0.0, 2, np.array([[rms3, rms5], [-rms3, -rms5]]))


def test_admissibility_by_hand():
    """A joint model is admissible unless an axis' held-out RMS exceeds 1.5 × the best per-axis model's (floored at
    1 Nm); with no per-axis model every joint one is inadmissible."""
    out = S.admissibility([ev_rms("axis-linear", 4.0, 0.5), ev_rms("sur-quad", 6.0, 2.0),
                           ev_rms("gain-linear", 6.0, 1.5), ev_rms("gain-quad", 6.5, 1.6)], floor_nm=1.0)
    by = {e.method: e for e in out}
    assert by["axis-linear"].admissible and by["sur-quad"].admissible  # per-axis models are never judged
    assert by["gain-linear"].admissible and by["gain-linear"].note == ""  # exactly at 1.5 × 4.0 and 1.5 × max(0.5, 1)
    assert not by["gain-quad"].admissible
    assert by["gain-quad"].note == "A3 held-out 6.5 Nm vs per-axis 4.0 Nm; A5 held-out 1.6 Nm vs per-axis 0.5 Nm"
    alone = S.admissibility([ev_rms("gain-linear", 1.0, 1.0), ev_rms("gain-quad", 1.0, 1.0)], floor_nm=1.0)
    refused = (False, "no per-axis model to check the A3/A5 split against")
    assert [(e.admissible, e.note) for e in alone] == [refused, refused]
