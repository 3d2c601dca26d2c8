"""The mass equations of the paper (§2.3, eq. 14, 15 and 21) and nothing else.

All torques are the gear-output torques of axis A3 and A5 in the measurement pose, in Nm. ``lever_difference_m``
is ``r_A3 − r_A5``, the horizontal distance between the two axes: any load's CoG has levers to A3 and A5 that
differ by exactly this length, which is why the DuT's unknown CoG drops out (eq. 3/4).
"""

from __future__ import annotations

import numpy as np


def dut_mass_uncorrected_kg(torque_a3_nm, torque_a5_nm, bias_a3_nm, bias_a5_nm, g_m_s2: float,
                            lever_difference_m: float, fixture_mass_kg: float = 0.0):
    """Eq. 14: ``m_DuT = ((M_A3 − M_0,A3) − (M_A5 − M_0,A5)) / (g·(r_A3 − r_A5)) − m_f`` (no calibration)."""
    norm_a3 = np.asarray(torque_a3_nm, float) - bias_a3_nm
    norm_a5 = np.asarray(torque_a5_nm, float) - bias_a5_nm
    return (norm_a3 - norm_a5) / (g_m_s2 * lever_difference_m) - fixture_mass_kg


def dut_mass_kg(corrected_a3_nm, corrected_a5_nm, g_m_s2: float, lever_difference_m: float,
                fixture_mass_kg: float = 0.0):
    """Eq. 15/21 with the calibration applied: ``m_DuT = (K_A3·M_A3,norm − K_A5·M_A5,norm) / (g·Δr) − m_f``.

    Parameters
    ----------
    corrected_a3_nm, corrected_a5_nm
        ``K(M_norm)·M_norm`` per axis: bias-normalised torque (``M − M_0``) times its calibration factor.
        (Eq. 15 writes the bias after K; the paper evaluates it with normalised torques, eq. 21 and Table A3,
        because K was fitted on normalised torques.)
    g_m_s2
        Gravitational acceleration used for the expected torques of the calibration.
    lever_difference_m
        ``r_A3 − r_A5`` in the measurement pose.
    fixture_mass_kg
        Mass of the mounting fixture m_f; 0 gives the gross mass.
    """
    # A3 in float makes the difference float (integer counts must not wrap); A5 follows numpy's promotion
    return (np.asarray(corrected_a3_nm, float) - corrected_a5_nm) / (g_m_s2 * lever_difference_m) - fixture_mass_kg
