"""The slope of a torsional gain curve at an operating point and its uncertainty (parameters and model form), and
CAL.json files without the candidate models still reading (issue #15: the inertia is read through these slopes)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import axis_gain

#: (t₀.₉₇₅(3) / z₀.₉₇₅)² from the tables: 3.1824 / 1.95996.
STUDENT_4_POINTS = (3.1824 / 1.95996) ** 2
#: √F₀.₉₅(4, 4) from the tables (F = 6.388): a candidate's held-out RMS up to 2.527 times the chosen's is admissible.
F_BOUND_4_POINTS = math.sqrt(6.388)


def _hand_gain(candidates: tuple[axis_gain.GainCandidate, ...]) -> axis_gain.AxisGain:
    """A straight line r = 1.0·x (slope variance 1e-6 from four points) and the candidates the validation kept."""
    return axis_gain.AxisGain(5, "linear", (1.0,), ((1e-6,),), 5.0, (-500.0, -100.0), 1.0, 4, candidates)


def test_slope_uncertainty_by_hand():
    own = axis_gain.GainCandidate("linear", (1.0,), 10.0, ((1e-6,),))
    poly2 = axis_gain.GainCandidate("poly2", (0.95, 0.1), 12.0)  # no covariance kept: its deviation alone
    g = _hand_gain((own, poly2))
    u_par = math.sqrt(1e-6 * STUDENT_4_POINTS)
    # poly2's slope at −600 Nm: 0.95 + 2·0.1·0.6 = 1.07, 0.07 from the line's 1.0: rectangular, /√3
    u_par_rel, u_rel = g.slope_u_rel_parts(-600.0)
    assert u_par_rel == pytest.approx(u_par, rel=1e-4)
    assert u_rel == pytest.approx(0.07 / math.sqrt(3.0), rel=1e-6)
    assert g.slope_u_rel(-600.0) == u_rel
    # at −100 Nm: 0.95 + 0.02 = 0.97, 0.03 off
    assert g.slope_u_rel(-100.0) == pytest.approx(0.03 / math.sqrt(3.0), rel=1e-6)
    # a candidate's own parameter uncertainty adds to its deviation: slope variance of poly2 at −600 Nm is
    # J·Σ·Jᵀ·Student with J = [1, 1.2]
    cov2 = ((4e-4, 0.0), (0.0, 1e-4))
    g2 = _hand_gain((own, axis_gain.GainCandidate("poly2", (0.95, 0.1), 12.0, cov2)))
    var2 = (4e-4 + 1.2**2 * 1e-4) * STUDENT_4_POINTS
    assert g2.slope_u_rel(-600.0) == pytest.approx(math.sqrt(0.07**2 / 3.0 + var2), rel=1e-5)


def test_only_candidates_the_points_cannot_tell_apart_count():
    # sat300 (0.5, 1.0) has a slope of 0.5 + (1 − e⁻²) + 2·e⁻² = 1.6353 at 600 Nm: far off, counted only while its
    # held-out RMS is within √F₀.₉₅(4, 4) = 2.527 times the chosen model's (10 Nm)
    own = axis_gain.GainCandidate("linear", (1.0,), 10.0)
    sat_slope = 0.5 + (1.0 - math.exp(-2.0)) + 2.0 * math.exp(-2.0)
    inside = _hand_gain((own, axis_gain.GainCandidate("sat300", (0.5, 1.0), 0.99 * F_BOUND_4_POINTS * 10.0)))
    outside = _hand_gain((own, axis_gain.GainCandidate("sat300", (0.5, 1.0), 1.01 * F_BOUND_4_POINTS * 10.0)))
    assert [c.model for c in inside.admissible_candidates()] == ["linear", "sat300"]
    assert [c.model for c in outside.admissible_candidates()] == ["linear"]
    assert inside.slope_u_rel(-600.0) == pytest.approx((sat_slope - 1.0) / math.sqrt(3.0), rel=1e-6)
    assert outside.slope_u_rel(-600.0) == pytest.approx(math.sqrt(1e-6 * STUDENT_4_POINTS), rel=1e-4)


def _truth_reading(x):
    """A curved gain (none of the candidate models): G = 0.91 + 0.28·tanh(|x| / 500 Nm), like the simulator's A5
    curve from 0.91 up."""
    return x * (0.91 + 0.28 * np.tanh(np.abs(x) / 500.0))


def _truth_slope(x: float) -> float:
    h = 1e-3
    return float((_truth_reading(x + h) - _truth_reading(x - h)) / (2.0 * h))


@pytest.mark.parametrize("x_op", [-300.0, -600.0])
def test_slope_uncertainty_covers_a_curved_truth(x_op):
    # four points up to −480 Nm, each mounted once and read in two poses (A5's torque nearly the same in both, as in
    # the paper scheme: no per-point offset to fit), 11 Nm scatter per mounting; the operating point inside the
    # covered torques (−300 Nm) and beyond them (−600 Nm, extrapolated)
    loads = np.array([-120.0, -240.0, -360.0, -480.0])
    x = np.repeat(loads, 2) * np.tile([1.0, 0.98], 4)
    group = np.repeat(np.arange(4), 2)
    hits, hits_par, hits_line, n_line = 0, 0, 0, 0
    n = 200
    for seed in range(n):
        rng = np.random.default_rng(seed)
        r = _truth_reading(x) + rng.normal(0.0, 11.0, 4)[group] + rng.normal(0.0, 0.3, 8)
        gain, _ = axis_gain.select_gain(5, x, r, np.full(8, 0.3), group)
        err = float(gain.slope(np.array([x_op]))[0]) / _truth_slope(x_op) - 1.0
        u_par, u = gain.slope_u_rel_parts(x_op)
        hits += abs(err) <= 2.0 * u
        hits_par += abs(err) <= 2.0 * u_par
        if gain.model == "linear":  # the straight line the campaign's four points often choose
            n_line += 1
            hits_line += abs(err) <= 2.0 * u
    assert n_line >= 30
    assert hits / n >= 0.9, hits / n
    assert hits_line / n_line >= 0.9, hits_line / n_line
    assert hits_par / n < 0.8  # the chosen model's parameters alone do not hold it


def _torsional_doc() -> dict:
    rng = np.random.default_rng(2)  # a draw whose points cannot tell poly2 from three sat models
    loads = np.array([-120.0, -240.0, -360.0, -480.0])
    x = np.repeat(loads, 2) * np.tile([1.0, 0.98], 4)
    group = np.repeat(np.arange(4), 2)
    r = _truth_reading(x) + rng.normal(0.0, 11.0, 4)[group]
    gain, ev = axis_gain.select_gain(5, x, r, np.full(8, 0.3), group)
    pose = calfile.TorsionalPose("meas", (0.0, -90.0, 90.0, 0.0, 0.0, 0.0), (0.0,) * 6, (0.1,) * 6)
    return json.loads(json.dumps({"torsional": calfile.torsional_dict(
        calfile.Torsional("paper", {"meas": pose}, {5: gain}, {5: ev}, 4))}))


def test_old_cal_json_without_the_candidates_still_reads():
    doc = _torsional_doc()
    new = calfile.parse_torsional(doc["torsional"])
    assert new is not None
    g = new.gains[5]
    assert {c.model for c in g.candidates} == set(doc["torsional"]["axes"]["A5"]["evaluation"]["models"])
    assert all(c.covariance is not None for c in g.candidates)
    assert len(g.admissible_candidates()) >= 2  # what the model-form part needs
    assert g.slope_u_rel(-600.0) > g.slope_u_rel_parts(-600.0)[0]
    # written before the candidates' covariance was kept: their deviations count, their own spread not
    no_cov = json.loads(json.dumps(doc))
    for rec in no_cov["torsional"]["axes"]["A5"]["evaluation"]["models"].values():
        del rec["covariance"]
    g_nc = calfile.parse_torsional(no_cov["torsional"]).gains[5]
    assert all(c.covariance is None for c in g_nc.candidates)
    assert g_nc.slope_u_rel_parts(-600.0)[0] <= g_nc.slope_u_rel(-600.0) <= g.slope_u_rel(-600.0)
    # without the evaluation record (or without the models' params): the chosen model's parameters alone
    for strip in ("evaluation", "params"):
        old = json.loads(json.dumps(doc))
        if strip == "evaluation":
            del old["torsional"]["axes"]["A5"]["evaluation"]
        else:
            for rec in old["torsional"]["axes"]["A5"]["evaluation"]["models"].values():
                del rec["params"]
        g_old = calfile.parse_torsional(old["torsional"]).gains[5]
        assert g_old.candidates == ()
        assert g_old.params == g.params and g_old.torque_range_nm == g.torque_range_nm
        assert g_old.slope_u_rel(-600.0) == g_old.slope_u_rel_parts(-600.0)[0] == g.slope_u_rel_parts(-600.0)[0]
    # a malformed candidate is named
    bad = json.loads(json.dumps(doc))
    bad["torsional"]["axes"]["A5"]["evaluation"]["models"]["poly2"]["params"] = [1.0]
    with pytest.raises(DataError, match="poly2"):
        calfile.parse_torsional(bad["torsional"])


def test_axis_gain_round_trips_with_its_candidates():
    rng = np.random.default_rng(2)
    x = np.repeat(np.array([-120.0, -240.0, -360.0, -480.0]), 2) * np.tile([1.0, 0.98], 4)
    group = np.repeat(np.arange(4), 2)
    gain, _ = axis_gain.select_gain(5, x, _truth_reading(x) + rng.normal(0.0, 5.0, 8), np.full(8, 0.3), group)
    assert len(gain.candidates) >= 2
    assert axis_gain.AxisGain.from_dict(5, json.loads(json.dumps(gain.to_dict()))) == gain
