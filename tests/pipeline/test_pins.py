"""Boundaries and messages of the operating-point check, the reproducibility, batch means and the in-line mass:
the single-operator changes a mutation run (``make mutation``) tries must each fail one of these."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import calibration as C
from rgse_daemon.pipeline import envelope as E
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from tests.pipeline.test_budget import DR, RAW, G, linear_cal, loops_of

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
    r = inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=3, n=150), cal, 100.0, 50.0, RAW)
    assert r.mass_kg == r.gross_mass_kg and (r.samples_used, r.samples_total) == (450, 450)
    np.testing.assert_allclose(r.loop_mass_kg, np.full(3, r.gross_mass_kg))
    assert r.warnings == [] and r.method == "axis-linear"
    short = inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=2, n=99), cal, 0.0, 0.0, RAW)
    assert short.warnings == ["loop l0: only 99 valid samples", "loop l1: only 99 valid samples"]
    assert not inline.in_line_mass(loops_of(1100.0, 250.0, n_loops=2, n=100), cal, 0.0, 0.0, RAW).warnings
    # the pre-processing is the one given: a spike stays in with RAW and is cropped by the paper's method
    spiked = [(np.r_[np.full(399, 1000.0), 5000.0], np.full(400, 200.0), 0.012, "l0")] * 2
    raw = inline.in_line_mass(spiked, cal, 0.0, 0.0, RAW)
    assert raw.torque_a3_nm == pytest.approx(1010.0)
    assert inline.in_line_mass(spiked, cal, 0.0, 0.0, pp.PAPER).torque_a3_nm == pytest.approx(1000.0)
    # without an envelope (an older file) the fitted range warns
    big = inline.in_line_mass(loops_of(5000.0, 250.0), cal, 0.0, 0.0, RAW)
    assert any("outside the calibrated range" in w for w in big.warnings)
    drift = [(np.full(400, 1000.0 + 40.0 * k) + np.random.default_rng(k).normal(0, 1, 400), np.full(400, 200.0),
              0.012, f"l{k}") for k in range(3)]
    assert inline.in_line_mass(drift, cal, 0.0, 0.0, RAW).warnings == [
        "loops disagree beyond their own spread (drift or a disturbed loop)"]


def test_former_budget_and_g():
    cov = np.diag([1e-6, 4e-6])
    cal = C.Calibration("axis-linear", C.GainK(("lin",), np.array([1.1])), C.GainK(("lin",), np.array([0.85])), cov,
                        (0.0, 3000.0), (0.0, 800.0), G, DR, covariance_reference=np.diag([1e-8, 1e-8]))
    loops = loops_of(1000.0, 200.0, sigma3=3.0, sigma5=3.0)
    r = inline.in_line_mass(loops, cal, 0.0, 0.0, RAW)
    m3, m5 = r.torque_a3_nm, r.torque_a5_nm
    c = r.uncertainty.components()
    assert set(c) == {"loops", "calibration", "model", "reference", "g"}
    assert c["calibration"] == pytest.approx(unc.calibration_mc_kg(cal, m3, m5))
    assert c["reference"] == pytest.approx(unc.reference_mc_kg(cal, m3, m5))
    assert c["model"] == 0.0 and c["g"] == 0.0
    assert c["loops"] == pytest.approx(unc.loop_spread_kg(r.loop_mass_kg, np.hypot(
        1.1 / (G * DR) * np.array([unc.batch_means_se(a) for a, _, _, _ in loops]),
        0.85 / (G * DR) * np.array([unc.batch_means_se(b) for _, b, _, _ in loops]))))
    rel = inline.in_line_mass(loops, cal, 0.0, 0.0, RAW, model_rms_rel=0.01)
    assert rel.uncertainty.u_model_kg == pytest.approx(0.01 * rel.gross_mass_kg)
    other_site = inline.in_line_mass(loops, cal, 0.0, 0.0, RAW, g_measurement_m_s2=9.8134,
                                     g_u_measurement_m_s2=0.0069)
    assert other_site.uncertainty.u_g_kg == pytest.approx(other_site.gross_mass_kg * 0.0069 / 9.8134)
    assert inline.in_line_mass(loops, cal, 0.0, 0.0, RAW, g_measurement_m_s2=9.8134).uncertainty.u_g_kg == 0.0
    both = inline.in_line_mass(loops, cal, 0.0, 0.0, RAW, g_u_calibration_m_s2=0.001, g_measurement_m_s2=9.8134)
    assert both.uncertainty.u_g_kg == pytest.approx(both.gross_mass_kg * 0.001 / G)
