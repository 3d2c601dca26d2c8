"""The in-line mass of a DuT from its measurement loops (paper §2.4.7): pre-process every loop, eq. 16 double
average, bias normalisation with the calibration's M_0, eq. 21, and the uncertainty budget of
:mod:`rgse_daemon.pipeline.uncertainty`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.calibration import Calibration

#: Fewer valid samples per loop than this draws a warning.
MIN_SAMPLES_PER_LOOP = 100

#: One loop: (A3 torque samples Nm, A5 torque samples Nm, sample period s, name for messages).
LoopSamples = tuple[np.ndarray, np.ndarray, float, str]


@dataclass(frozen=True)
class InlineMass:
    gross_mass_kg: float
    mass_kg: float
    uncertainty: unc.MassUncertainty
    loop_mass_kg: np.ndarray
    torque_a3_nm: float
    torque_a5_nm: float
    samples_used: int
    samples_total: int
    warnings: list[str] = field(default_factory=list)


def slope_kg_per_nm(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float, h_nm: float = 1.0
                    ) -> tuple[float, float]:
    """∂m/∂M_A3 and ∂m/∂M_A5 of eq. 21 with this calibration at the working point (central differences)."""
    d3 = float(cal.mass_kg(torque_a3_nm + h_nm, torque_a5_nm) - cal.mass_kg(torque_a3_nm - h_nm, torque_a5_nm))
    d5 = float(cal.mass_kg(torque_a3_nm, torque_a5_nm + h_nm) - cal.mass_kg(torque_a3_nm, torque_a5_nm - h_nm))
    return d3 / (2 * h_nm), d5 / (2 * h_nm)


def in_line_mass(loops: Sequence[LoopSamples], cal: Calibration, bias_a3_nm: float, bias_a5_nm: float,
                 pre: pp.Preprocessing, fixture_mass_kg: float = 0.0, model_rms_rel: float = 0.0,
                 g_u_calibration_m_s2: float = 0.0, g_measurement_m_s2: float | None = None,
                 g_u_measurement_m_s2: float = 0.0, alternatives: Sequence[Calibration] = ()) -> InlineMass:
    """Mass of the DuT and its uncertainty from its loops (contracts §1 ``rgse mass``).

    ``alternatives``: the other plausible calibration models (same points), for the model-form spread.
    """
    t3, t5, se3, se5, used, total = [], [], [], [], 0, 0
    warnings: list[str] = []
    for a3, a5, period_s, name in loops:
        r3 = pp.process_loop(a3, period_s, pre)
        r5 = pp.process_loop(a5, period_s, pre)
        t3.append(r3.torque_nm)
        t5.append(r5.torque_nm)
        se3.append(unc.batch_means_se(pp.kept_samples(a3, period_s, pre)))
        se5.append(unc.batch_means_se(pp.kept_samples(a5, period_s, pre)))
        n_used = min(r3.n_used, r5.n_used)
        used += n_used
        total += r3.n_total
        if n_used < MIN_SAMPLES_PER_LOOP:
            warnings.append(f"loop {name}: only {n_used} valid samples")
    n3, n5 = pp.normalise(np.array(t3), bias_a3_nm), pp.normalise(np.array(t5), bias_a5_nm)
    loop_mass = np.asarray(cal.mass_kg(n3, n5), float)
    m3, m5 = pp.double_average_nm(n3), pp.double_average_nm(n5)  # eq. 16 over loops
    gross = float(cal.mass_kg(m3, m5))
    s3, s5 = slope_kg_per_nm(cal, m3, m5)
    loop_se = np.hypot(s3 * np.array(se3), s5 * np.array(se5))  # A3 and A5 noise independent
    warnings += cal.out_of_range(m3, m5)
    if unc.loops_disagree(loop_mass, loop_se):
        warnings.append("loops disagree beyond their own spread (drift or a disturbed loop)")
    g_meas = cal.g_m_s2 if g_measurement_m_s2 is None else g_measurement_m_s2
    u = unc.MassUncertainty(
        u_loops_kg=unc.loop_spread_kg(loop_mass, loop_se),
        u_calibration_kg=unc.calibration_mc_kg(cal, m3, m5),
        u_model_kg=unc.model_kg(gross, model_rms_rel, np.array([float(a.mass_kg(m3, m5)) for a in alternatives])),
        u_reference_kg=unc.reference_mc_kg(cal, m3, m5),
        u_g_kg=unc.g_kg(gross, cal.g_m_s2, g_u_calibration_m_s2, g_meas, g_u_measurement_m_s2),
    )
    return InlineMass(gross, gross - fixture_mass_kg, u, loop_mass, m3, m5, used, total, warnings)
