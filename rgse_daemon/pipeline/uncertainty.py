"""Measurement uncertainty of the in-line mass (GUM style): loop spread, calibration parameters, k = 2.

* Loop spread: the standard error of the mean of the per-loop masses; with one loop, batch means of that loop
  (the samples are autocorrelated, so the naive σ/√n would be far too small).
* Calibration: the parameter covariance of the fitted K functions propagated by Monte Carlo (K is non-linear).
* Model: the calibration's leave-one-out RMS relative error, the honest size of its residual lack of fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgse_daemon.pipeline.calibration import Calibration

COVERAGE_K = 2.0


@dataclass(frozen=True)
class MassUncertainty:
    u_loops_kg: float
    u_calibration_kg: float
    u_model_kg: float

    @property
    def u_kg(self) -> float:
        return float(np.sqrt(self.u_loops_kg**2 + self.u_calibration_kg**2 + self.u_model_kg**2))

    @property
    def expanded_kg(self) -> float:
        """U = k·u with k = 2."""
        return COVERAGE_K * self.u_kg


def batch_means_se(x: np.ndarray, n_batches: int = 10) -> float:
    """Standard error of the mean of an autocorrelated series from the spread of ``n_batches`` batch means."""
    x = np.asarray(x, float)
    n_batches = min(n_batches, x.size // 2)
    if n_batches < 2:
        return float("nan")
    usable = x[: x.size - x.size % n_batches].reshape(n_batches, -1).mean(axis=1)
    return float(usable.std(ddof=1) / np.sqrt(n_batches))


def loop_spread_kg(loop_mass_kg: np.ndarray, single_loop_se_kg: float = float("nan")) -> float:
    """Standard uncertainty of the mean over loops (eq. 16 outer average)."""
    m = np.asarray(loop_mass_kg, float)
    if m.size >= 2:
        return float(m.std(ddof=1) / np.sqrt(m.size))
    return float(single_loop_se_kg)


def calibration_mc_kg(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float, n_draws: int = 4000,
                      seed: int = 0) -> float:
    """Standard deviation of the mass over draws of the calibration parameters from their covariance."""
    cov = np.asarray(cal.covariance, float)
    if cov.size == 0 or not np.any(cov):
        return 0.0
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(cal.params, cov, size=n_draws, check_valid="ignore", method="eigh")
    masses = np.array([float(cal.with_params(p).mass_kg(torque_a3_nm, torque_a5_nm)) for p in draws])
    return float(np.std(masses, ddof=1))


def loops_disagree(loop_mass_kg: np.ndarray, loop_se_kg: np.ndarray, factor: float = 3.0) -> bool:
    """True if the loop masses scatter more than ``factor`` times what their own within-loop errors explain."""
    m = np.asarray(loop_mass_kg, float)
    se = np.asarray(loop_se_kg, float)
    if m.size < 2 or not np.all(np.isfinite(se)) or np.all(se == 0):
        return False
    chi2 = float(np.sum(((m - m.mean()) / np.maximum(se, 1e-12)) ** 2) / (m.size - 1))
    return chi2 > factor**2
