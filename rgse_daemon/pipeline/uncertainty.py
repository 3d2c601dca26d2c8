"""Measurement uncertainty of the in-line mass (GUM style), coverage factor k = 2.

Five uncorrelated components, combined in quadrature:

* ``loops``: the standard error of the eq. 16 mean over the loops. The larger of (a) the spread of the per-loop
  masses, ``s/√n``, and (b) the within-loop standard errors from *batch means* (the samples are autocorrelated:
  drift, filter, settling; a naive σ/√N would be far too small), ``√(Σ se_i²)/n``. (b) rests on hundreds of
  samples per loop and keeps U honest with few loops, where ``s`` alone is a poor estimate (with 3 loops ``s`` has
  2 degrees of freedom and k = 2 would cover only ~82 %).
* ``calibration``: the fit's parameter covariance of K propagated by Monte Carlo (K is non-linear in its
  parameters for the paper's model).
* ``reference``: the reference masses' uncertainty (weighed calibration bodies, 0.01 kg each by default, nested
  loads correlated), propagated through the fit into the parameters (:func:`calibration.reference_mass_param_
  covariance`) and from there by Monte Carlo like the fit's covariance.
* ``model``: the calibration's leave-one-out RMS *relative* mass error times the mass (its lack of fit at
  calibration-like points), in quadrature with the *model-form* spread at the DuT's own torques: the RMS deviation
  of the other plausible models of the catalogue (leave-one-out error at most :data:`PLAUSIBLE_LOO_FACTOR` times
  the chosen model's) from the chosen one. Leave-one-out cannot see the gaps between calibration points (the
  paper's campaign has no A5 torque between ~720 and ~1780 Nm); where equally good models disagree there,
  the data do not tell which is right.
* ``g``: the mass is referred to the reference masses, so ``g`` cancels between calibration and measurement when
  both use the same value at the same site (the paper's 9.81 vs Bremen's 9.8134, 0.07 %, does not enter). Only a
  measurement whose ``g`` differs from the calibration's (another site) carries the two ``g`` uncertainties.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from rgse_daemon.pipeline.calibration import Calibration

COVERAGE_K = 2.0
MC_DRAWS = 2000
#: Models whose leave-one-out mean error is within this factor of the chosen model's count as plausible.
PLAUSIBLE_LOO_FACTOR = 2.0


@dataclass(frozen=True)
class MassUncertainty:
    u_loops_kg: float
    u_calibration_kg: float
    u_model_kg: float
    u_reference_kg: float = 0.0
    u_g_kg: float = 0.0

    @property
    def u_kg(self) -> float:
        return float(np.sqrt(self.u_loops_kg**2 + self.u_calibration_kg**2 + self.u_model_kg**2
                             + self.u_reference_kg**2 + self.u_g_kg**2))

    @property
    def expanded_kg(self) -> float:
        """U = k·u with k = 2."""
        return COVERAGE_K * self.u_kg

    def components(self) -> dict[str, float]:
        return {k.removeprefix("u_").removesuffix("_kg"): float(v) for k, v in asdict(self).items()}


def batch_means_se(x: np.ndarray, n_batches: int = 10) -> float:
    """Standard error of the mean of an autocorrelated series from the spread of ``n_batches`` batch means."""
    x = np.asarray(x, float)
    n_batches = min(n_batches, x.size // 2)
    if n_batches < 2:
        return float("nan")
    usable = x[: x.size - x.size % n_batches].reshape(n_batches, -1).mean(axis=1)
    return float(usable.std(ddof=1) / np.sqrt(n_batches))


def loop_spread_kg(loop_mass_kg: np.ndarray, loop_se_kg: np.ndarray | float = float("nan")) -> float:
    """Standard uncertainty of the mean over loops (eq. 16 outer average): the larger of the between-loop
    standard error and the pooled within-loop (batch means) standard error."""
    m = np.asarray(loop_mass_kg, float)
    se = np.atleast_1d(np.asarray(loop_se_kg, float))
    within = float(np.sqrt(np.sum(se**2)) / max(m.size, 1)) if np.all(np.isfinite(se)) else float("nan")
    between = float(m.std(ddof=1) / np.sqrt(m.size)) if m.size >= 2 else float("nan")
    candidates = [v for v in (within, between) if np.isfinite(v)]
    return max(candidates) if candidates else float("nan")


def covariance_mc_kg(cal: Calibration, cov: np.ndarray, torque_a3_nm: float, torque_a5_nm: float,
                     n_draws: int = MC_DRAWS, seed: int = 0) -> float:
    """Standard deviation of the mass over draws of the calibration parameters from ``cov``."""
    cov = np.asarray(cov, float)
    if cov.size == 0 or not np.any(cov):
        return 0.0
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(cal.params, cov, size=n_draws, check_valid="ignore", method="eigh")
    masses = np.array([float(cal.with_params(p).mass_kg(torque_a3_nm, torque_a5_nm)) for p in draws])
    return float(np.std(masses, ddof=1))


def calibration_mc_kg(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float, n_draws: int = MC_DRAWS,
                      seed: int = 0) -> float:
    """The fit's own parameter covariance (without the reference masses') propagated to the mass."""
    return covariance_mc_kg(cal, cal.covariance_fit, torque_a3_nm, torque_a5_nm, n_draws, seed)


def reference_mc_kg(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float, n_draws: int = MC_DRAWS,
                    seed: int = 1) -> float:
    """The reference masses' part of the parameter covariance propagated to the mass."""
    if cal.covariance_reference is None:
        return 0.0
    return covariance_mc_kg(cal, cal.covariance_reference, torque_a3_nm, torque_a5_nm, n_draws, seed)


def g_kg(mass_kg: float, g_calibration_m_s2: float, u_g_calibration_m_s2: float, g_measurement_m_s2: float,
         u_g_measurement_m_s2: float) -> float:
    """The ``g`` component: zero when calibration and measurement use the same ``g`` (it cancels, see the module
    docstring); otherwise the two relative ``g`` uncertainties, taken as independent, times the mass."""
    if g_calibration_m_s2 == g_measurement_m_s2:
        return 0.0
    rel = np.hypot(u_g_calibration_m_s2 / g_calibration_m_s2, u_g_measurement_m_s2 / g_measurement_m_s2)
    return float(abs(mass_kg) * rel)


def model_form_kg(mass_kg: float, alternative_mass_kg: np.ndarray) -> float:
    """RMS deviation of the plausible alternative models' masses from the chosen model's mass."""
    alt = np.asarray(alternative_mass_kg, float)
    return float(np.sqrt(np.mean((alt - mass_kg) ** 2))) if alt.size else 0.0


def model_kg(mass_kg: float, loo_rms_rel: float, alternative_mass_kg: np.ndarray) -> float:
    """The ``model`` component: leave-one-out lack of fit and model-form spread in quadrature."""
    return float(np.hypot(abs(mass_kg) * loo_rms_rel, model_form_kg(mass_kg, alternative_mass_kg)))


def loops_disagree(loop_mass_kg: np.ndarray, loop_se_kg: np.ndarray, factor: float = 3.0) -> bool:
    """True if the loop masses scatter more than ``factor`` times what their own within-loop errors explain."""
    m = np.asarray(loop_mass_kg, float)
    se = np.asarray(loop_se_kg, float)
    if m.size < 2 or not np.all(np.isfinite(se)) or np.all(se == 0):
        return False
    chi2 = float(np.sum(((m - m.mean()) / np.maximum(se, 1e-12)) ** 2) / (m.size - 1))
    return chi2 > factor**2
