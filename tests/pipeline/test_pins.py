"""Pins of the mass pipeline's equations found by ``make mutation``: each test fixes a behaviour that a single
changed operator used to leave unnoticed. The expected values are worked out by hand from the paper's equations
(eq. 14-21) or by independent arithmetic in the test, never taken from the code's output."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import mass as mass_eq
from rgse_daemon.pipeline import thermal as T

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
