"""The accuracy bench's ``true form`` row: its basis holds the simulated drive's corrected torque exactly, so what
that row shows is the campaign's scatter alone, not a form error of its own."""

from __future__ import annotations

import numpy as np
import pytest

from bench import accuracy as bench
from rgse_daemon.pipeline.calibration import CalibrationPoints
from simulators.krc4.physics import gain_curve
from simulators.krc4.scenario import AxisErrors, default_scenario


def normalised_reading_nm(axis: AxisErrors, torque_nm: np.ndarray, mpa_nm: float) -> np.ndarray:
    """What a calibration point reads once the zero point (the MPA alone) is subtracted: F(x + x0) − F(x0)."""

    def reading(x: np.ndarray) -> np.ndarray:
        return np.array([gain_curve(axis.gain0, axis.gain_sat, axis.tau_sat_nm, axis.gain_slope_per_knm,
                                    axis.gain_quad_per_knm2, v) * v for v in np.atleast_1d(x)])

    return reading(torque_nm + mpa_nm) - reading(np.array([mpa_nm]))


@pytest.mark.parametrize("axis", [
    default_scenario().axis(3),
    default_scenario().axis(5),
    AxisErrors(gain0=1.1, gain_sat=-0.2, tau_sat_nm=1500.0, gain_slope_per_knm=0.02, gain_quad_per_knm2=-0.004),
])
def test_true_basis_spans_the_simulated_reading(axis: AxisErrors):
    true_nm = np.linspace(0.0, 4500.0, 40)
    reading = normalised_reading_nm(axis, true_nm, mpa_nm=140.0)
    a = bench._true_basis(true_nm, axis)
    coef, *_ = np.linalg.lstsq(a, reading, rcond=None)
    assert np.max(np.abs(a @ coef - reading)) < 1e-6 * np.max(np.abs(reading))
    # without its last column the basis misses the curve by far more (the check above can fail)
    c, *_ = np.linalg.lstsq(a[:, :-1], reading, rcond=None)
    assert np.max(np.abs(a[:, :-1] @ c - reading)) > 0.05


def test_true_form_recovers_an_exact_campaign():
    """On noise-free points the true-form row gives the DuT's mass to rounding: it adds no error of its own."""
    sc = default_scenario()
    mass = np.r_[0.0, 20.93 * np.arange(1, 11), 228.51, 228.51, 228.51]
    l5 = np.r_[0.265 + 0.0075 * np.arange(11), 0.775, 1.025, 1.275]
    e3, e5 = bench.G * mass * (l5 + 1.025), bench.G * mass * l5
    m3 = normalised_reading_nm(sc.axis(3), e3, 150.0)
    m5 = normalised_reading_nm(sc.axis(5), e5, 40.0)
    pts = CalibrationPoints(np.array(["zero"] + ["mass"] * 10 + ["torque"] * 3), mass, m3, m5, e3, e5)
    dut_kg, l5_dut = 140.0, 0.7
    d3 = normalised_reading_nm(sc.axis(3), np.array([bench.G * dut_kg * (l5_dut + 1.025)]), 150.0)[0]
    d5 = normalised_reading_nm(sc.axis(5), np.array([bench.G * dut_kg * l5_dut]), 40.0)[0]
    assert bench.true_form_mass_kg(pts, sc, d3, d5, 1.025, 0.0) == pytest.approx(dut_kg, abs=1e-6)


def test_true_basis_has_only_the_terms_the_curve_needs():
    x = np.array([100.0, 2000.0])
    assert bench._true_basis(x, AxisErrors(gain0=0.92)).shape == (2, 1)  # a constant gain: a straight line
    assert bench._true_basis(x, AxisErrors(gain_slope_per_knm=0.01)).shape == (2, 2)
    assert bench._true_basis(x, default_scenario().axis(3)).shape == (2, 3)  # slope and bend
    assert bench._true_basis(x, default_scenario().axis(5)).shape == (2, 4)  # slope and saturation
