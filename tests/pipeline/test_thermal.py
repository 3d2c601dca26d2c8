"""The thermal drift of the torque estimate (§2.4.5): β from the campaign's loops, the DuT's loops corrected to the
campaign's temperature, the correction's uncertainty in U; and the budget's excess terms (what the reproducibility
already holds is not counted twice)."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import thermal as T
from rgse_daemon.pipeline import uncertainty as unc

G, DR = 9.81, 1.025
RAW = pp.Preprocessing(crop_sigma=None, filter="none", window=1, order="backward", location="mean", settle_s=0.0)
BETA = {"A3": 0.0008, "A5": 0.0017}
AMBIENT_K = 293.15


def reading(static_nm: float, beta: float, temp_k: np.ndarray) -> np.ndarray:
    return static_nm * (1.0 + beta * (np.asarray(temp_k) - AMBIENT_K))


def campaign(seed: int = 0, noise_nm: float = 0.3) -> tuple[dict, dict]:
    """14 points of 3 loops warming by ~1.5 K each, statics from -1300 (the arm) to +3000 Nm."""
    rng = np.random.default_rng(seed)
    readings, temps = {"A3": [], "A5": []}, {"A3": [], "A5": []}
    for static3, static5 in zip(np.linspace(-1320.0, 3000.0, 14), np.linspace(-316.0, 2500.0, 14), strict=True):
        t = AMBIENT_K + np.array([3.6, 5.3, 6.3]) + rng.normal(0, 0.1, 3)
        for ax, st in (("A3", static3), ("A5", static5)):
            readings[ax].append(reading(st, BETA[ax], t) + rng.normal(0, noise_nm, 3))
            temps[ax].append(t)
    return readings, temps


def test_drift_coefficient_from_the_loops_within_points():
    drift = T.fit(*campaign())
    for ax in ("A3", "A5"):
        assert drift.coeff_per_k[ax] == pytest.approx(BETA[ax], abs=3 * drift.u_coeff_per_k[ax])
        assert 0 < drift.u_coeff_per_k[ax] < 0.1 * BETA[ax]
        assert drift.reference_k[ax] == pytest.approx(AMBIENT_K + 5.07, abs=0.1)
        assert drift.span_k[ax] == pytest.approx(2.7, abs=0.5)
    assert drift.n_loops == 42
    # a constant per-point offset (a mounting, 7 Nm) hardly enters: only the within-point deviations carry β
    readings, temps = campaign()
    offsets = np.random.default_rng(5).normal(0.0, 7.0, 14)
    shifted = {ax: [r + d for r, d in zip(readings[ax], offsets, strict=True)] for ax in readings}
    again = T.fit(shifted, temps)
    assert again.coeff_per_k["A3"] == pytest.approx(drift.coeff_per_k["A3"], rel=0.02)
    # noise-free: exact to first order
    exact = T.fit(*campaign(noise_nm=0.0))
    assert exact.coeff_per_k["A5"] == pytest.approx(BETA["A5"], rel=0.01)


def test_drift_needs_loops_that_warm_within_points():
    with pytest.raises(DataError, match="do not vary"):
        T.fit_axis([np.array([1.0, 1.1]), np.array([2.0, 2.2])], [np.full(2, 300.0), np.full(2, 300.0)])
    with pytest.raises(DataError, match="two loops"):
        T.fit_axis([np.array([1.0])], [np.array([300.0])])


def test_round_trip_and_malformed():
    drift = T.fit(*campaign())
    assert T.ThermalDrift.from_dict(drift.to_dict()) == drift
    bad = drift.to_dict()
    bad["u_coeff_per_k"]["A5"] = -1.0
    with pytest.raises(DataError, match="u_coeff_per_k"):
        T.ThermalDrift.from_dict(bad)
    with pytest.raises(DataError, match=r"fit\.thermal: malformed"):
        T.ThermalDrift.from_dict({"coeff_per_k": {"A3": 0.0}})


def test_correction_and_its_uncertainty():
    drift = T.ThermalDrift({"A3": 0.001, "A5": 0.002}, {"A3": 1e-4, "A5": 2e-4}, {"A3": 300.0, "A5": 301.0}, 42,
                           {"A3": 3.0, "A5": 3.0})
    assert drift.correct_nm("A3", 1000.0, 310.0) == pytest.approx(1000.0 * (1 - 0.001 * 10.0))
    assert drift.correct_nm("A5", -500.0, 296.0) == pytest.approx(-500.0 * (1 + 0.002 * 5.0))
    assert drift.correct_nm("A3", 1000.0, 300.0) == 1000.0
    assert drift.u_correction_nm("A3", np.array([1000.0, 1000.0]), np.array([310.0, 320.0])) == pytest.approx(
        1000.0 * 15.0 * 1e-4)
    assert drift.u_correction_nm("A5", np.array([-500.0]), np.array([291.0])) == pytest.approx(500.0 * 10.0 * 2e-4)


def test_a_warm_dut_is_corrected_to_the_campaign_temperature():
    # the axes read downwards like the arm's own torque (the bias): K < 0 absorbs the sign
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([-1.1])), C.GainK(("lin",), np.array([-0.85])),
                        np.zeros((2, 2)), (0.0, 3000.0), (0.0, 800.0), G, DR)
    drift = T.fit(*campaign())
    bias3, bias5 = -1320.0, -316.0
    ref3, ref5 = drift.reference_k["A3"], drift.reference_k["A5"]
    true3, true5 = -1500.0, -400.0  # the DuT's normalised torques at the campaign's temperature
    temps = [(ref3 + d, ref5 + d) for d in (7.0, 5.5, 4.5)]  # warmer, within 3 × the campaign's 2.7 K span

    def at(static, beta, temp, ref):  # the reading the warm drive gives, relative to the campaign's temperature
        return static * (1 + beta * (temp - AMBIENT_K)) / (1 + beta * (ref - AMBIENT_K))

    loops = [(np.full(50, at(true3 + bias3, BETA["A3"], t3, ref3)),
              np.full(50, at(true5 + bias5, BETA["A5"], t5, ref5)), 0.012, f"l{k}") for k, (t3, t5) in enumerate(temps)]
    want = float(cal.mass_kg(true3, true5))
    plain = inline.in_line_mass(loops, inline.MassCalibration(cal, bias3, bias5), RAW)
    fixed = inline.in_line_mass(loops, inline.MassCalibration(cal, bias3, bias5, thermal=drift), RAW,
                                loop_temps_k=temps)
    assert abs(plain.mass_kg - want) > 0.5  # uncorrected: most of a kilogram off
    assert abs(fixed.mass_kg - want) < 0.1 * abs(plain.mass_kg - want)
    c = fixed.uncertainty.components()
    assert "thermal" not in plain.uncertainty.components()
    s3, s5 = inline.slope_kg_per_nm(cal, fixed.torque_a3_nm, fixed.torque_a5_nm)
    raw3 = np.array([lp[0][0] for lp in loops])
    raw5 = np.array([lp[1][0] for lp in loops])
    u3 = drift.u_correction_nm("A3", raw3, np.array(temps)[:, 0])
    u5 = drift.u_correction_nm("A5", raw5, np.array(temps)[:, 1])
    assert c["thermal"] == pytest.approx(np.hypot(s3 * u3, s5 * u5)) and c["thermal"] > 0
    assert abs(fixed.mass_kg - want) < 2 * c["thermal"] + 0.05
    assert fixed.thermal_applied == {"A3": True, "A5": True}
    # far beyond the span β was fitted on (issue 33): not extrapolated; U carries the campaign's own bound on the drift,
    # |β| + 2 u(β) per axis (not the prior: the span resolves β); a warning says so. The campaign resolves both βs'
    # signs, and here the two drifts pull the mass opposite ways (K < 0 on both axes, eq. 21's difference): each
    # drift lies between 0 and its bound on its own side, so their sum is bounded by the larger, not by the sum
    far = [(ref3 + d, ref5 + d) for d in (35.0, 22.0, 15.0)]
    hot = [(np.full(50, at(true3 + bias3, BETA["A3"], t3, ref3)), np.full(50, at(true5 + bias5, BETA["A5"], t5, ref5)),
            0.012, f"l{k}") for k, (t3, t5) in enumerate(far)]
    out = inline.in_line_mass(hot, inline.MassCalibration(cal, bias3, bias5, thermal=drift), RAW, loop_temps_k=far)
    assert out.thermal_applied == {"A3": False, "A5": False}
    assert any("thermal drift of A5 not corrected" in w and "beyond 3 × the" in w and "|β| + 2 u(β)" in w
               for w in out.warnings), out.warnings
    assert abs(out.mass_kg - want) < out.uncertainty.expanded_kg
    s3, s5 = inline.slope_kg_per_nm(cal, out.torque_a3_nm, out.torque_a5_nm)
    hot3, hot5 = np.array([lp[0][0] for lp in hot]), np.array([lp[1][0] for lp in hot])
    lever3 = abs(np.mean(hot3 * (np.array(far)[:, 0] - ref3)))
    lever5 = abs(np.mean(hot5 * (np.array(far)[:, 1] - ref5)))
    bound3 = abs(drift.coeff_per_k["A3"]) + 2 * drift.u_coeff_per_k["A3"]
    bound5 = abs(drift.coeff_per_k["A5"]) + 2 * drift.u_coeff_per_k["A5"]
    assert bound3 < T.DRIFT_PRIOR_PER_K and bound5 < T.DRIFT_PRIOR_PER_K
    drift3 = s3 * drift.coeff_per_k["A3"] * np.mean(hot3 * (np.array(far)[:, 0] - ref3))  # kg, the data's signs
    drift5 = s5 * drift.coeff_per_k["A5"] * np.mean(hot5 * (np.array(far)[:, 1] - ref5))
    assert np.sign(drift3) == -np.sign(drift5)
    assert out.uncertainty.components()["thermal"] == pytest.approx(
        max(abs(s3) * lever3 * bound3, abs(s5) * lever5 * bound5) / np.sqrt(3.0))
    assert abs(drift3 + drift5) < 2 * out.uncertainty.components()["thermal"]
    # the same drifts with A5's β of the other sign pull the mass the same way: the bounds add
    beta5 = {"A3": BETA["A3"], "A5": -BETA["A5"]}
    same_way = T.ThermalDrift({"A3": drift.coeff_per_k["A3"], "A5": -drift.coeff_per_k["A5"]}, drift.u_coeff_per_k,
                              drift.reference_k, drift.n_loops, drift.span_k)
    hot_b = [(np.full(50, at(true3 + bias3, beta5["A3"], t3, ref3)),
              np.full(50, at(true5 + bias5, beta5["A5"], t5, ref5)), 0.012, f"l{k}") for k, (t3, t5) in enumerate(far)]
    both = inline.in_line_mass(hot_b, inline.MassCalibration(cal, bias3, bias5, thermal=same_way), RAW,
                               loop_temps_k=far)
    s3b, s5b = inline.slope_kg_per_nm(cal, both.torque_a3_nm, both.torque_a5_nm)
    hot5b = np.array([lp[1][0] for lp in hot_b])
    lever3b = abs(np.mean(np.array([lp[0][0] for lp in hot_b]) * (np.array(far)[:, 0] - ref3)))
    lever5b = abs(np.mean(hot5b * (np.array(far)[:, 1] - ref5)))
    assert both.uncertainty.components()["thermal"] == pytest.approx(
        (abs(s3b) * lever3b * bound3 + abs(s5b) * lever5b * bound5) / np.sqrt(3.0))
    assert abs(both.mass_kg - want) > abs(out.mass_kg - want)  # the drifts add up here ...
    assert abs(both.mass_kg - want) < both.uncertainty.expanded_kg  # ... and U holds them
    # a smaller prior is the outer bound: then it is what U carries
    tight = inline.in_line_mass(hot, inline.MassCalibration(cal, bias3, bias5, thermal=drift), RAW, loop_temps_k=far,
                                drift_prior_per_k=0.0005)
    assert tight.uncertainty.components()["thermal"] == pytest.approx(
        max(abs(s3) * lever3 * 0.0005, abs(s5) * lever5 * 0.0005) / np.sqrt(3.0))
    assert any("thermal drift of A5 not corrected" in w and "the prior 0.05 %/K" in w for w in tight.warnings)
    assert tight.mass_kg == out.mass_kg  # the bound changes U, never the mass
    # loops without a temperature: no correction, no thermal term, and the operator is told (issue 33 review)
    none = inline.in_line_mass(loops, inline.MassCalibration(cal, bias3, bias5, thermal=drift), RAW,
                               loop_temps_k=[(None, None)] * 3)
    assert none.mass_kg == pytest.approx(plain.mass_kg) and "thermal" not in none.uncertainty.components()
    names = ", ".join(lp[3] for lp in loops)
    assert any(w.startswith(f"thermal drift neither corrected nor bounded: loop(s) {names} recorded no A3/A5 motor "
                            "temperature") for w in none.warnings), none.warnings
    one = inline.in_line_mass(loops, inline.MassCalibration(cal, bias3, bias5, thermal=drift), RAW,
                              loop_temps_k=[temps[0], (float("nan"), temps[1][1]), temps[2]])
    assert any(f"loop(s) {loops[1][3]} recorded no" in w for w in one.warnings), one.warnings
    assert not any("neither corrected nor bounded" in w for w in plain.warnings)


def test_excess_counts_only_what_the_reproducibility_does_not_hold():
    assert unc.excess_kg(0.5, 0.3) == pytest.approx(0.4)
    assert unc.excess_kg(0.3, 0.5) == 0.0
    assert unc.excess_kg(float("inf"), 0.5) == float("inf")
    cu = unc.CalibrationUncertainty(unc.Reproducibility(10.0, 10.0, 0.0), np.array([[1.10, 0.85], [1.12, 0.85]]),
                                    np.zeros((0, 2)), np.array([[1000.0, 200.0], [2000.0, 400.0]]))
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])),
                        np.zeros((2, 2)), (0.0, 3000.0), (0.0, 800.0), G, DR)
    at_dut = cu.curve_spread_kg(cal, 3000.0, 600.0)
    inner = np.sqrt(np.mean([cu.curve_spread_kg(cal, 1000.0, 200.0) ** 2, cu.curve_spread_kg(cal, 2000.0, 400.0) ** 2]))
    assert at_dut == pytest.approx(0.02 * 3000.0 / np.sqrt(2) / (G * DR))
    assert cu.u_calibration_kg(cal, 3000.0, 600.0) == pytest.approx(np.sqrt(at_dut**2 - inner**2))
    assert cu.u_calibration_kg(cal, 500.0, 100.0) == 0.0
    # the model term likewise: an alternative that differs by a constant gain offset differs more at larger torques
    alt = C.Calibration("axis-quad", C.GainK(("lin",), np.array([1.101])), C.GainK(("lin",), np.array([0.85])),
                        np.zeros((2, 2)), (0.0, 3000.0), (0.0, 800.0), G, DR)
    loops = [(np.full(10, 3000.0), np.full(10, 600.0), 0.012, "l0"), (np.full(10, 3000.0), np.full(10, 600.0), 0.012,
                                                                         "l1")]
    r = inline.in_line_mass(loops, inline.MassCalibration(cal, 0.0, 0.0, alternatives=[alt], uncertainty=cu,
                                                          alternative_uncertainty=[None]), RAW)
    full = 0.001 * 3000.0 / (G * DR)
    at_points = np.sqrt(np.mean([(0.001 * 1000.0 / (G * DR)) ** 2, (0.001 * 2000.0 / (G * DR)) ** 2]))
    assert r.uncertainty.u_model_kg == pytest.approx(np.sqrt(full**2 - at_points**2))


def test_what_is_applied_and_what_u_carries_follows_what_the_campaign_resolves():
    """Issue 33: β is applied only on a span ≥ 1 K, 3 u(β) from 0, the DuT within 3 × the span; where not, U carries
    |β| + 2 u(β) (at most the prior) if the span resolved β, significant or not, else the prior."""
    def drift(beta, u, span):
        return T.ThermalDrift({"A3": beta, "A5": beta}, {"A3": u, "A5": u}, {"A3": 300.0, "A5": 300.0}, 42,
                              {"A3": span, "A5": span})
    assert drift(0.002, 1e-4, 3.0).not_applicable("A5", 8.9) is None
    assert "beyond 3 × the 3 K span" in drift(0.002, 1e-4, 3.0).not_applicable("A5", 9.1)
    assert "spanned 0.2 K, less than 1 K" in drift(0.002, 1e-4, 0.2).not_applicable("A5", 0.1)
    assert "it is 1.6 standard uncertainties from 0, less than 3" in drift(-0.0008, 0.0005, 3.0).not_applicable(
        "A5", 1.0)
    assert drift(1e-5, 1e-4, 3.0).drift_bound_per_k("A5", 0.003) == pytest.approx(2.1e-4)
    assert drift(1e-5, 1e-4, 0.2).drift_bound_per_k("A5", 0.003) == 0.003  # the span resolves nothing: the prior
    # resolved and significant, not applied beyond 3 × the span: the campaign's bound, not the prior ...
    assert drift(0.002, 1e-4, 3.0).not_applicable("A5", 16.4) is not None
    assert drift(0.002, 1e-4, 3.0).drift_bound_per_k("A5", 0.003) == pytest.approx(2.2e-3)
    assert drift(-0.002, 1e-4, 1.0).drift_bound_per_k("A3", 0.003) == pytest.approx(2.2e-3)  # |β|; the span's edge
    # ... with the prior as the outer bound
    assert drift(0.0029, 1e-4, 3.0).drift_bound_per_k("A5", 0.003) == 0.003
    assert drift(0.002, 1e-4, 3.0).drift_bound_per_k("A5", 0.001) == 0.001
    # too small a span: the prior, however significant β came out
    assert drift(0.002, 1e-5, 0.99).drift_bound_per_k("A5", 0.003) == 0.003
    assert drift(0.002, 1e-5, 0.99).drift_bound_per_k("A5", 0.004) == 0.004
    assert "not resolved (its loops spanned 0.2 K" in drift(0.002, 1e-4, 0.2).describe("A5")
    assert "U carries a drift of up to 0.3 %/K (the prior)" in drift(0.002, 1e-4, 0.2).describe("A5")
    assert "resolved: applied to a DuT within 9 K" in drift(0.002, 1e-4, 3.0).describe("A5")
    assert "U carries a drift of up to 0.22 %/K (|β| + 2 u(β))" in drift(0.002, 1e-4, 3.0).describe("A5")


def test_the_axes_bounds_add_as_intervals_and_beta_s_own_uncertainties_in_quadrature():
    """Uncorrected, both axes drift with one mechanism over the same warming: where the campaign does not resolve
    their signs, their bounds may add in eq. 21, so they add linearly; where it resolves them, each drift lies between
    0 and its bound on its own side, and the sum's bound is the larger end of the summed intervals. Where β is
    applied its two regressions' errors are independent (quadrature)."""
    assert T.combine_axes([(3.0, False), (-4.0, False)]) == pytest.approx(7.0)
    assert T.combine_axes([(3.0, True), (-4.0, True)]) == pytest.approx(5.0)
    assert T.combine_axes([(3.0, True), (4.0, False)]) == pytest.approx(5.0)
    assert T.combine_axes([(0.0, True), (0.0, False)]) == 0.0
    per_loop = T.combine_axes([(np.array([1.0, -2.0]), False), (np.array([2.0, 2.0]), False)])
    assert per_loop == pytest.approx([3.0, 4.0])
    assert T.combine_axes([(3.0, False), (-4.0, False)], [1, -1]) == pytest.approx(4.0)  # opposite ways: the larger
    assert T.combine_axes([(3.0, False), (-4.0, False)], [-1, -1]) == pytest.approx(7.0)  # the same way: the sum
    assert T.combine_axes([(3.0, False), (4.0, False)], [0, -1]) == pytest.approx(7.0)  # one sign open: [-7, 3]
    assert T.combine_axes([(3.0, False), (4.0, False)], [1, 0]) == pytest.approx(7.0)  # [-4, 7]
    assert T.combine_axes([(3.0, False), (4.0, False)], [0, 0]) == pytest.approx(7.0)
    assert T.combine_axes([(3.0, True), (4.0, False)], [1, -1]) == pytest.approx(5.0)  # an applied term's sign: none
    assert T.combine_axes([(3.0, True), (6.0, False), (4.0, False)], [0, 1, -1]) == pytest.approx(np.hypot(3.0, 6.0))
    assert T.combine_axes([(np.array([1.0, 3.0]), False), (np.array([2.0, 2.0]), False)], [1, -1]) == pytest.approx(
        [2.0, 3.0])
    with pytest.raises(ValueError, match="1 directions for 2 terms"):
        T.combine_axes([(3.0, False), (4.0, False)], [1])
