"""Issue 33's thermal rule for the multi-pose mass (:func:`multipose.visit_drift`): the campaign's A3 β corrects the
visits to the torsional campaign's temperature only where the data resolve it (within 3 × the campaign's span, or
where the run's own visits show the same β over a span that reaches the reference), else U carries the bound and the
operator is warned."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon.pipeline import multipose as mp
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K, ThermalDrift

REF_K = 310.0
BETA = 0.0008  # 0.08 %/K, the simulated KR C4's A3
SIGMA_NM = 0.5  # one visit's repeatability (K_A3's in-point scatter)
R_NM = {"meas": -3000.0, "A3-80": -1200.0}  # each pose's A3 reading at REF_K


def campaign(beta: float = BETA, u: float = 0.00003, span_k: float = 1.9) -> ThermalDrift:
    return ThermalDrift({"A3": beta, "A5": 0.0017}, {"A3": u, "A5": 0.00005}, {"A3": 300.0, "A5": 300.0}, 40,
                        {"A3": span_k, "A5": span_k})


def visits(temps_k: dict[str, list[float]], beta: float = BETA, noise_nm: float = 0.3, seed: int = 0
           ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each pose's readings at ``temps_k``, drifting by ``beta`` from REF_K, with white noise."""
    rng = np.random.default_rng(seed)
    out = {}
    for pose, ts in temps_k.items():
        t = np.array(ts, float)
        out[pose] = (R_NM[pose] * (1.0 + beta * (t - REF_K)) + rng.normal(0.0, noise_nm, t.size), t)
    return out


WARMING = {"meas": [313.6, 333.0], "A3-80": [320.0, 326.0]}  # A B B A over a 19.4 K warming, 13.1 K from REF_K
STEADY = {"meas": [317.4, 317.5], "A3-80": [317.4, 317.5]}  # 7.4 K from REF_K, no warming within the run


def test_within_three_spans_of_the_reference_the_campaigns_beta_is_applied():
    """The campaign's reference is 300 K: the torsional campaign (310 K) and the visits (317.45 K) lie within 3 × a
    6 K span of it."""
    d = mp.visit_drift(campaign(span_k=6.0), REF_K, visits(STEADY), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert d.applied and d.beta_per_k == BETA and d.warnings == ()
    v = d.visits("meas", *visits(STEADY)["meas"])
    assert v.torque_a3_nm == pytest.approx([R_NM["meas"]] * 2, abs=1.5)  # brought back to REF_K


def test_both_ends_of_the_correction_must_lie_where_beta_was_fitted():
    """A 3 K span: the visits lie 7.45 K from the torsional campaign (within 9 K of it), but the torsional campaign lies
    10 K from the campaign β was fitted about, and the visits 17.45 K: β is not known to hold there, a steady run
    cannot confirm it, so the visits are bounded, and the note says which end lies too far."""
    d = mp.visit_drift(campaign(span_k=3.0), REF_K, visits(STEADY), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and d.u_beta_per_k > 0 and d.warnings
    assert "the visits' mean is +17.4 K from it and the torsional campaign is +10.0 K from it, beyond 3 × the 3 K " \
           "span β was fitted on about the campaign's 300.0 K" in d.note, d.note


def test_a_visit_without_a_motor_temperature_refuses_the_multi_pose_mass():
    got = visits(WARMING)
    r, t = got["A3-80"]
    got["A3-80"] = (r, np.array([t[0], np.nan]))
    with pytest.raises(mp.DataError, match=r"a visit of pose\(s\) A3-80 has no A3 motor temperature: the thermal "
                                           r"drift from the torsional campaign's 310.0 K can be neither corrected"):
        mp.visit_drift(campaign(), REF_K, got, DRIFT_PRIOR_PER_K, SIGMA_NM)


def test_the_runs_own_visits_confirm_the_campaigns_beta_beyond_three_spans():
    d = mp.visit_drift(campaign(), REF_K, visits(WARMING), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert d.applied and d.beta_per_k == BETA and d.u_beta_per_k == 0.00003
    assert "the run's visits show β = +0.079" in d.note and "over 19 K, the same within 3 standard" in d.note
    for pose, (r, t) in visits(WARMING).items():
        assert d.visits(pose, r, t).torque_a3_nm == pytest.approx([R_NM[pose]] * 2, abs=1.5)


def test_a_run_whose_drift_is_not_the_campaigns_is_not_corrected_and_u_carries_the_bound():
    d = mp.visit_drift(campaign(), REF_K, visits(WARMING, beta=0.0), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and d.beta_per_k == 0.0
    assert d.u_beta_per_k == pytest.approx((BETA + 2 * 0.00003) / math.sqrt(3.0))
    assert "not the campaign's" in d.note
    (w,) = d.warnings
    assert w.startswith("thermal drift of A3 not corrected in the multi-pose mass") and "+13.1 K offset" in w
    r, t = visits(WARMING, beta=0.0)["meas"]
    v = d.visits("meas", r, t)
    assert np.array_equal(v.torque_a3_nm, r)  # as read
    assert v.thermal_lever_nm_k == pytest.approx(r * (t - REF_K))


def test_a_steady_run_beyond_three_spans_cannot_confirm_beta_and_is_bounded():
    d = mp.visit_drift(campaign(), REF_K, visits(STEADY), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and "beyond 3 × the 1.9 K span" in d.note
    assert d.warnings and d.u_beta_per_k > 0


def test_a_campaign_span_below_one_kelvin_bounds_by_the_prior():
    d = mp.visit_drift(campaign(span_k=0.2), REF_K, visits(WARMING), 0.002, SIGMA_NM)
    assert not d.applied and "spanned 0.2 K" in d.note
    assert d.u_beta_per_k == pytest.approx(0.002 / math.sqrt(3.0))


def test_without_a_reference_temperature_the_operator_is_told():
    d = mp.visit_drift(campaign(), None, visits(WARMING), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and d.u_beta_per_k == 0.0
    assert d.warnings == ("thermal drift of A3 neither corrected nor bounded in the multi-pose mass: the torsional "
                          "campaign recorded no A3 motor temperature",)
    none = mp.visit_drift(None, REF_K, visits(WARMING), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not none.applied and none.warnings == () and none.u_beta_per_k == 0.0


def test_run_drift_needs_two_visits_of_a_pose_and_a_known_repeatability():
    assert mp.run_drift([(np.array([1.0]), np.array([300.0]))], SIGMA_NM) is None
    assert mp.run_drift([(np.array([1.0, 2.0]), np.array([300.0, 300.0]))], SIGMA_NM) is None
    assert mp.run_drift(list(visits(WARMING).values()), 0.0) is None
    got = mp.run_drift(list(visits(WARMING, noise_nm=SIGMA_NM).values()), SIGMA_NM)
    assert got is not None and got.span_k == pytest.approx(19.4)
    # β over the visits' own mean temperature: β / (1 + β·ΔT), 1 % below β at 13 K (first order, as the campaign's)
    assert got.beta_per_k == pytest.approx(BETA / (1 + BETA * 13.2), abs=3 * got.u_beta_per_k)


def test_a_run_too_noisy_to_resolve_a_drift_of_its_own_does_not_confirm_the_campaigns_beta():
    # no drift at all in the visits (a magnet lagging the winding sensor), 7.2 K from REF_K over a 2.5 K span; one
    # visit scattering 3 Nm leaves u(β) of the run at 0.055 %/K: 0 agrees with the campaign's 0.08 %/K within 3 u,
    # so agreement alone cannot tell the campaign's β from no drift (applied, it would move the mass by 0.6 %)
    still = {"meas": [316.0, 318.5], "A3-80": [316.5, 318.0]}
    d = mp.visit_drift(campaign(), REF_K, visits(still, beta=0.0, noise_nm=0.0), DRIFT_PRIOR_PER_K, 3.0)
    assert not d.applied and d.beta_per_k == 0.0
    assert "not resolved" in d.note and d.warnings
    assert d.u_beta_per_k == pytest.approx((BETA + 2 * 0.00003) / math.sqrt(3.0))


def test_without_a_visit_repeatability_the_operator_is_told_the_run_was_not_checked():
    # an older CAL.json has no u_fit_nm (read as 0): the warming run that would confirm β cannot, and the warning
    # says why, so the operator knows a refit would let the run's own drift decide
    d = mp.visit_drift(campaign(), REF_K, visits(WARMING), DRIFT_PRIOR_PER_K, 0.0)
    assert not d.applied and d.u_beta_per_k == pytest.approx((BETA + 2 * 0.00003) / math.sqrt(3.0))
    (w,) = d.warnings
    assert "the run's own drift not checked" in d.note and "u_fit_nm" in w


def test_a_run_that_shows_the_campaigns_beta_over_too_short_a_span_to_reach_the_reference_is_bounded():
    # the run resolves the campaign's β over 2 K, but the visits lie 7.4 K from REF_K, beyond 3 × 2 K: not corrected
    short = {"meas": [316.4, 318.4], "A3-80": [316.9, 318.1]}
    d = mp.visit_drift(campaign(), REF_K, visits(short, noise_nm=0.0), DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and "a span that does not reach the reference +7.4 K away" in d.note
    assert "not the campaign's" not in d.note and "not resolved" not in d.note
    assert d.u_beta_per_k == pytest.approx((BETA + 2 * 0.00003) / math.sqrt(3.0)) and d.warnings


def test_a_run_scattering_more_than_the_calibration_says_gets_its_own_scatter_in_u():
    """Visits scattering 5 Nm (the calibration says 0.5): u(β) of the run comes from the run's residual, not from the
    calibration's smaller σ, so the run does not resolve the campaign's β on evidence it does not have."""
    noisy = visits(WARMING, noise_nm=5.0, seed=3)
    quiet = mp.run_drift(list(visits(WARMING, noise_nm=0.0).values()), SIGMA_NM)
    got = mp.run_drift(list(noisy.values()), SIGMA_NM)
    assert quiet is not None and got is not None
    assert quiet.u_beta_per_k == pytest.approx(SIGMA_NM / math.sqrt(sum(
        float(np.sum((R_NM[p] * (1 + BETA * (np.mean(t) - REF_K)) * (np.array(t) - np.mean(t))) ** 2))
        for p, t in WARMING.items())), rel=0.02)
    assert got.u_beta_per_k > 2.0 * quiet.u_beta_per_k  # 1.5 Nm of residual on one degree of freedom here


def test_the_prediction_before_the_run_carries_the_thermal_term_the_run_will():
    """auto's prediction (:func:`mp.predicted_drift`, :func:`mp.predict_multipose_U_kg` with the visits' expected
    offset): U's thermal term as the run gives it for visits at that temperature, by the same rule."""
    from dataclasses import replace

    from tests.pipeline.test_multipose import _synthetic

    visits3, cal = _synthetic(107.3, 0.0)  # three visits per pose scattering as the calibration's
    # a campaign span of 0.2 K: β unresolved, the prior bounds the drift over the visits' 5 K offset
    d = mp.predicted_drift(campaign(span_k=0.2), REF_K, REF_K + 5.0, DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not d.applied and d.u_beta_per_k == pytest.approx(DRIFT_PRIOR_PER_K / math.sqrt(3.0))
    assert d.note == "not corrected: its loops spanned 0.2 K, less than 1 K", d.note
    bounded = replace(cal, u_beta_per_k=d.u_beta_per_k)
    run = mp.multipose_mass([mp.PoseVisits(v.pose, v.torque_a3_nm, v.torque_a3_nm * 5.0) for v in visits3], bounded)
    assert run.uncertainty.components()["thermal"] > run.uncertainty.components()["visits"]  # it matters here
    predicted = mp.predict_multipose_U_kg(bounded, 107.3, 3, offset_k=5.0)
    assert predicted == pytest.approx(run.uncertainty.expanded_kg, rel=0.02)
    assert predicted > 1.5 * mp.predict_multipose_U_kg(cal, 107.3, 3)  # the prediction without the term
    # within 3 × a 6 K span of the campaign's 300 K at both ends: β applied, its own u
    applied = mp.predicted_drift(campaign(span_k=6.0), REF_K, REF_K + 5.0, DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert applied.applied and applied.u_beta_per_k == 0.00003
    # beyond 3 spans, resolved: the campaign alone does not apply β (the run's own visits may; not foreseen here)
    far = mp.predicted_drift(campaign(span_k=1.9), REF_K, REF_K + 5.0, DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert not far.applied and far.note.startswith("not corrected: the visits' mean is +15.0 K from it"), far.note
    # no β, no reference temperature, no temperature before the run: no term, and the note says which
    assert mp.predicted_drift(None, REF_K, REF_K + 5.0, DRIFT_PRIOR_PER_K, SIGMA_NM).u_beta_per_k == 0.0
    assert mp.predicted_drift(campaign(), None, REF_K + 5.0, DRIFT_PRIOR_PER_K, SIGMA_NM).u_beta_per_k == 0.0
    blind = mp.predicted_drift(campaign(), REF_K, None, DRIFT_PRIOR_PER_K, SIGMA_NM)
    assert blind.u_beta_per_k == 0.0 and blind.note == "not predicted: no A3 motor temperature before the run"
