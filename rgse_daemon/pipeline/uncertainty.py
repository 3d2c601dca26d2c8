"""Measurement uncertainty of the in-line mass (GUM style), coverage factor k = 2.

A calibration written by this version carries a :class:`CalibrationUncertainty` (CAL.json ``fit.uncertainty``) and
the budget is:

* ``loops``: as below.
* ``reproducibility``: what a new load configuration (a new mounting) does that the loops cannot see, estimated per
  axis from the calibration's *held-out* per-axis residuals (corrected minus expected torque, eq. 17/18, each
  configuration predicted by the fit without it: Table 1's scatter) and propagated through eq. 21 with their
  correlation: ``u = √(s_A3² + s_A5² − 2ρ·s_A3·s_A5) / (g·Δr)``.
* ``calibration``: the uncertainty of the fitted *curve* at the operating point: the spread of the DuT's mass over
  refits of the calibration to resampled points (residual-pair bootstrap: each refit is a curve through plausible
  data, so an ill-determined eq. 20 stays finite where its points are). Never parameter draws pushed through the
  exponentials. A held-out residual is a new configuration's scatter *plus* the curve's error there (the fit did
  not see the point), so the reproducibility already holds the curve's spread at calibration-like points: only the
  *excess* of the spread at the DuT over its RMS at the interior configurations enters (``√max(s_DuT² − s̄², 0)``;
  counting both covered the truth in ~100 % of the simulated repetitions).
* ``reference``: likewise, the spread over refits with the reference masses drawn from their covariance.
* ``model``: the model-form spread of the admissible alternatives at the DuT's torques, again only its excess over
  the RMS spread at the interior configurations (each alternative's lack of fit there is in the held-out residuals
  as well); outside the campaign's envelope their full spread.
* ``g``: as below.
* ``thermal``: the uncertainty of the thermal-drift correction (:mod:`rgse_daemon.pipeline.thermal`), when the
  calibration carries the campaign's drift and the loops their motor temperatures.

A calibration file without ``fit.uncertainty`` (written before) keeps the former budget of five components:

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

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline.calibration import Calibration, CalibrationError, CalibrationPoints, GainK

COVERAGE_K = 2.0
MC_DRAWS = 2000
#: Refits of the residual-pair bootstrap (calibration component) and of the reference-mass draws.
BOOTSTRAP_N = 60
REFERENCE_N = 30
#: A model's curve uncertainty at the DuT beyond this many times its reproducibility (its scatter at calibration-like
#: points) makes it unusable for that DuT.
UNUSABLE_FACTOR = 3.0
#: Models whose leave-one-out mean error is within this factor of the chosen model's count as plausible.
PLAUSIBLE_LOO_FACTOR = 2.0
#: CAL.json ``fit.uncertainty.refit_basis``: the basis the refits' parameters are stored in. ``calibration``: each
#: refit re-expressed in the calibration's own (:meth:`Calibration.params_of`). Files without it were written before;
#: their refits of a model with a ``sat`` term are coefficients of the refit's own τ (:func:`stale_refits`).
REFIT_BASIS = "calibration"


@dataclass(frozen=True)
class MassUncertainty:
    u_loops_kg: float
    u_calibration_kg: float
    u_model_kg: float
    u_reference_kg: float = 0.0
    u_g_kg: float = 0.0
    u_reproducibility_kg: float | None = None
    """None: a calibration file without held-out residuals (the former budget, no such component)."""
    u_thermal_kg: float | None = None
    """None: no thermal correction (a calibration without ``fit.thermal`` or loops without motor temperature)."""

    @property
    def u_kg(self) -> float:
        return float(np.sqrt(sum(v**2 for v in self.components().values())))

    @property
    def expanded_kg(self) -> float:
        """U = k·u with k = 2."""
        return COVERAGE_K * self.u_kg

    def components(self) -> dict[str, float]:
        return {k.removeprefix("u_").removesuffix("_kg"): float(v) for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class Reproducibility:
    """Held-out per-axis residual scatter of a calibration (Nm), the correlation of A3's with A5's, and how many
    configurations it rests on (``n``; None: unknown, taken as many)."""

    rms_a3_nm: float
    rms_a5_nm: float
    corr: float
    n: int | None = None

    @property
    def small_sample_factor(self) -> float:
        """t₀.₉₇₅(n − 1)/t₀.₉₇₅(∞): a scatter estimated from few configurations is itself uncertain (GUM G.3);
        folding the Student factor into u keeps k = 2 for the whole budget."""
        if self.n is None or self.n > 200:
            return 1.0
        return float(stats.t.ppf(0.975, max(self.n - 1, 1)) / stats.norm.ppf(0.975))

    @classmethod
    def from_residuals(cls, residual_nm: np.ndarray) -> Reproducibility:
        r = np.asarray(residual_nm, float)
        r = r[np.all(np.isfinite(r), axis=1)]
        if len(r) < 2:
            raise CalibrationError("reproducibility needs held-out residuals of at least two configurations")
        s3, s5 = np.sqrt(np.mean(r**2, axis=0))
        corr = float(np.mean(r[:, 0] * r[:, 1]) / (s3 * s5)) if s3 > 0 and s5 > 0 else 0.0
        return cls(float(s3), float(s5), float(np.clip(corr, -1.0, 1.0)), len(r))

    def u_kg(self, g_m_s2: float, lever_difference_m: float) -> float:
        """Eq. 21 propagation: ∂m/∂(K·M)_A3 = 1/(g·Δr), ∂m/∂(K·M)_A5 = −1/(g·Δr), with the axes' correlation,
        times :attr:`small_sample_factor`."""
        var = self.rms_a3_nm**2 + self.rms_a5_nm**2 - 2.0 * self.corr * self.rms_a3_nm * self.rms_a5_nm
        return float(np.sqrt(max(var, 0.0)) / abs(g_m_s2 * lever_difference_m)) * self.small_sample_factor

    def to_dict(self) -> dict[str, float]:
        return {"rms_a3_nm": self.rms_a3_nm, "rms_a5_nm": self.rms_a5_nm, "corr": self.corr,
                **({} if self.n is None else {"n": self.n})}


@dataclass(frozen=True)
class CalibrationUncertainty:
    """What a fitted model carries for its uncertainty at any operating point (CAL.json ``fit.uncertainty``)."""

    reproducibility: Reproducibility
    fit_params: np.ndarray
    """(B, p) parameter sets of the residual-pair bootstrap refits."""
    reference_params: np.ndarray
    """(R, p) parameter sets of the refits with reference masses drawn from their covariance (may be empty)."""
    interior_torque_nm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """(k, 2) normalised A3/A5 torques of the interior configurations the reproducibility rests on (empty in older
    files: then nothing is taken as already counted)."""
    refit_basis: str | None = REFIT_BASIS
    """The basis the refits' parameters are in (:data:`REFIT_BASIS`); None: a file written before it was recorded."""

    def to_dict(self) -> dict[str, Any]:
        return {"reproducibility": self.reproducibility.to_dict(),
                "scheme": f"residual-pair bootstrap ({len(self.fit_params)} refits), reference-mass draws "
                          f"({len(self.reference_params)} refits), evaluated at the operating point",
                **({} if self.refit_basis is None else {"refit_basis": self.refit_basis}),
                "bootstrap_params": np.asarray(self.fit_params, float).tolist(),
                "reference_params": np.asarray(self.reference_params, float).tolist(),
                "interior_torque_nm": np.asarray(self.interior_torque_nm, float).tolist()}

    @classmethod
    def from_dict(cls, d: Any, n_params: int, where: str = "fit.uncertainty") -> CalibrationUncertainty:
        """``where``: the record's place in CAL.json, for the messages."""
        try:
            n = d["reproducibility"].get("n")
            rep = Reproducibility(float(d["reproducibility"]["rms_a3_nm"]), float(d["reproducibility"]["rms_a5_nm"]),
                                  float(d["reproducibility"]["corr"]), None if n is None else int(n))
            boot = np.asarray(d["bootstrap_params"], float).reshape(-1, n_params)
            ref = np.asarray(d.get("reference_params") or [], float).reshape(-1, n_params)
            inner = np.asarray(d.get("interior_torque_nm") or [], float).reshape(-1, 2)
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{where}: malformed: {exc}") from exc
        if not (np.all(np.isfinite(boot)) and np.all(np.isfinite(ref)) and np.all(np.isfinite(inner)) and len(boot) >= 2
                and all(np.isfinite([rep.rms_a3_nm, rep.rms_a5_nm, rep.corr]))):
            raise DataError(f"{where}: needs finite reproducibility and at least two bootstrap parameter sets")
        basis = d.get("refit_basis")
        if basis is not None and basis != REFIT_BASIS:
            raise DataError(f"{where}.refit_basis: unknown value {basis!r} (known: {REFIT_BASIS}; absent in files "
                            f"written before it)")
        return cls(rep, boot, ref, inner, basis)

    def curve_spread_kg(self, cal: Calibration, torque_a3_nm: float, torque_a5_nm: float) -> float:
        """The whole bootstrap spread of the mass at these torques (the usability check of a model)."""
        return refit_spread_kg(cal, self.fit_params, torque_a3_nm, torque_a5_nm)

    def at_interior(self, mass_at: Callable[[float, float], float]) -> float:
        """RMS of ``mass_at(M_A3, M_A5)`` over the interior configurations (0 if the file names none)."""
        vals = np.array([mass_at(a3, a5) for a3, a5 in np.asarray(self.interior_torque_nm, float)])
        return float(np.sqrt(np.mean(vals**2))) if vals.size else 0.0

    def u_calibration_kg(self, cal: Calibration, torque_a3_nm: float, torque_a5_nm: float) -> float:
        """The curve's spread at the DuT beyond what the reproducibility holds (see the module docstring)."""
        at_dut = self.curve_spread_kg(cal, torque_a3_nm, torque_a5_nm)
        return excess_kg(at_dut, self.at_interior(lambda a3, a5: self.curve_spread_kg(cal, a3, a5)))

    def u_reference_kg(self, cal: Calibration, torque_a3_nm: float, torque_a5_nm: float) -> float:
        return refit_spread_kg(cal, self.reference_params, torque_a3_nm, torque_a5_nm)


def stale_refits(cal: Calibration, cu: CalibrationUncertainty | None) -> bool:
    """``cu`` comes from a file written before ``refit_basis`` and ``cal`` has a ``sat`` term (its own τ, or an
    average holding one): each refit picked its own τ, and its coefficients were stored as if in the calibration's
    basis, so their spread at the DuT is that of other curves (on Table 1 10 to 30 times the refits' own). The refits
    of the other models always were in the calibration's basis."""
    return cu is not None and cu.refit_basis is None and any(
        isinstance(k, GainK) and "sat" in k.terms for k in (cal.k_a3, cal.k_a5))


def excess_kg(at_dut_kg: float, at_interior_kg: float) -> float:
    """``√max(s_DuT² − s̄²_interior, 0)``: the part of a spread at the DuT that the held-out residuals of the interior
    configurations (the reproducibility) do not already hold."""
    if not np.isfinite(at_dut_kg):
        return np.inf
    return float(np.sqrt(max(at_dut_kg**2 - at_interior_kg**2, 0.0)))


def residual_pairs_nm(cal: Calibration, points: CalibrationPoints) -> np.ndarray:
    """In-sample residuals (expected − corrected torque) of the loaded points, A3 and A5 side by side (n, 2)."""
    c3 = cal.k_a3.corrected_torque_nm(points.torque_a3_nm)
    c5 = cal.k_a5.corrected_torque_nm(points.torque_a5_nm)
    return np.stack([points.expected_a3_nm - c3, points.expected_a5_nm - c5], axis=1)


def bootstrap_params(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
                     n: int = BOOTSTRAP_N, seed: int = 0) -> np.ndarray:
    """Residual-pair bootstrap: each refit sees the fitted corrected torques plus a resampled (A3, A5) residual pair
    per loaded point (pairs keep the axes' correlation; centred, inflated by √(n/(n − p/2)) for the fitted
    parameters); the calibration masses follow from eq. 21 so joint and per-axis models see the same data."""
    cal = cal_mod.fit(points, method, g_m_s2, lever_difference_m)
    loaded = np.flatnonzero(points.mass_kg > 0)
    fitted = np.stack([cal.k_a3.corrected_torque_nm(points.torque_a3_nm),
                       cal.k_a5.corrected_torque_nm(points.torque_a5_nm)], axis=1)
    resid = residual_pairs_nm(cal, points)[loaded]
    resid = resid - resid.mean(axis=0)  # centred: the refits scatter around the fit, not around its mean residual
    inflate = np.sqrt(len(loaded) / max(len(loaded) - len(cal.params) / 2, 1.0))
    rng = np.random.default_rng(seed)
    denom = g_m_s2 * points.lever_difference_m(g_m_s2, lever_difference_m)  # each point's own Δr (eq. 21)
    out = []
    for _ in range(n):
        e3, e5 = points.expected_a3_nm.copy(), points.expected_a5_nm.copy()
        draw = resid[rng.integers(0, len(loaded), len(loaded))] * inflate
        e3[loaded] = fitted[loaded, 0] + draw[:, 0]
        e5[loaded] = fitted[loaded, 1] + draw[:, 1]
        mass = points.mass_kg.copy()
        mass[loaded] = np.maximum((e3[loaded] - e5[loaded]) / denom[loaded], 1e-6)
        try:  # (a draw whose expected A5 torque reaches A3's is not a load: refused by CalibrationPoints)
            star = CalibrationPoints(points.kind, mass, points.torque_a3_nm, points.torque_a5_nm, e3, e5,
                                     points.mass_cov_kg2)
            out.append(cal.params_of(cal_mod.fit(star, method, g_m_s2, lever_difference_m)))
        except CalibrationError:
            continue  # a degenerate resample: the others still estimate the spread
    return np.asarray(out, float).reshape(-1, len(cal.params))


def reference_params(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
                     n: int = REFERENCE_N, seed: int = 1) -> np.ndarray:
    """Refits with the reference masses drawn from their covariance (empty if they are taken as exact)."""
    cal = cal_mod.fit(points, method, g_m_s2, lever_difference_m)
    n_par = len(cal.params)
    if points.mass_cov_kg2 is None or not np.any(points.mass_cov_kg2):
        return np.zeros((0, n_par))
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(points.mass_kg, points.mass_cov_kg2, size=n, check_valid="ignore", method="eigh")
    return np.array([cal.params_of(cal_mod.fit(points.with_masses(np.maximum(d, 0.0)), method, g_m_s2,
                                               lever_difference_m)) for d in draws]).reshape(-1, n_par)


def refit_spread_kg(cal: Calibration, params: np.ndarray, torque_a3_nm: float, torque_a5_nm: float) -> float:
    """Standard deviation of the mass at the operating point over refitted parameter sets (∞ if one diverges)."""
    params = np.asarray(params, float)
    if len(params) < 2:
        return 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        masses = np.array([float(cal.with_params(p).mass_kg(torque_a3_nm, torque_a5_nm)) for p in params])
    return float(np.std(masses, ddof=1)) if np.all(np.isfinite(masses)) else np.inf


def calibration_uncertainty(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
                            heldout_residual_nm: np.ndarray) -> CalibrationUncertainty:
    """Everything :class:`CalibrationUncertainty` needs, from the calibration points and the method's held-out
    per-axis residuals (:attr:`selection.Evaluation.heldout_residual_nm`). The reproducibility counts the loaded
    *interior* configurations only: holding out the heaviest point on an axis is an extrapolation, which the
    operating-point check (:mod:`rgse_daemon.pipeline.envelope`) treats, not the reproducibility."""
    inner = interior(points)
    return CalibrationUncertainty(Reproducibility.from_residuals(np.asarray(heldout_residual_nm)[inner]),
                                  bootstrap_params(points, method, g_m_s2, lever_difference_m),
                                  reference_params(points, method, g_m_s2, lever_difference_m),
                                  np.stack([points.torque_a3_nm[inner], points.torque_a5_nm[inner]], axis=1))


def interior(points: CalibrationPoints) -> np.ndarray:
    """Loaded points whose |M_A3| and |M_A5| both lie below the largest of the other points' (bool mask)."""
    a3, a5 = np.abs(points.torque_a3_nm), np.abs(points.torque_a5_nm)
    # below the others' largest ⇔ below the overall largest (the largest itself, or a tie for it, is not below)
    return (points.mass_kg > 0) & (a3 < a3.max()) & (a5 < a5.max())


def unusable(u_calibration_kg: float, u_reproducibility_kg: float) -> bool:
    """A model whose curve uncertainty at the DuT dwarfs its own scatter at calibration-like points is unusable."""
    return not np.isfinite(u_calibration_kg) or u_calibration_kg > UNUSABLE_FACTOR * max(u_reproducibility_kg, 1e-9)


def batch_means_se(x: np.ndarray, n_batches: int = 10) -> float:
    """Standard error of the mean of an autocorrelated series from the spread of ``n_batches`` batch means."""
    x = np.asarray(x, float)
    n_batches = min(n_batches, x.size // 2)
    if n_batches < 2:
        return np.nan
    usable = x[: x.size - x.size % n_batches].reshape(n_batches, -1).mean(axis=1)
    return float(usable.std(ddof=1) / np.sqrt(n_batches))


def loop_spread_kg(loop_mass_kg: np.ndarray, loop_se_kg: np.ndarray | float = np.nan) -> float:
    """Standard uncertainty of the mean over loops (eq. 16 outer average): the larger of the between-loop
    standard error and the pooled within-loop (batch means) standard error."""
    m = np.asarray(loop_mass_kg, float)
    se = np.atleast_1d(np.asarray(loop_se_kg, float))
    within = float(np.sqrt(np.sum(se**2)) / max(m.size, 1)) if np.all(np.isfinite(se)) else np.nan
    between = float(m.std(ddof=1) / np.sqrt(m.size)) if m.size >= 2 else np.nan
    candidates = [v for v in (within, between) if np.isfinite(v)]
    return max(candidates) if candidates else np.nan


def covariance_mc_kg(cal: Calibration, cov: np.ndarray, torque_a3_nm: float, torque_a5_nm: float,
                     n_draws: int = MC_DRAWS, seed: int = 0) -> float:
    """Standard deviation of the mass over draws of the calibration parameters from ``cov``."""
    if not np.any(cov):  # also an empty covariance
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


def model_spread_kg(mass_kg: float, alternative_mass_kg: np.ndarray) -> float:
    """The full spread of the alternatives around the chosen model: the largest deviation (outside the envelope)."""
    alt = np.asarray(alternative_mass_kg, float)
    return float(np.max(np.abs(alt - mass_kg))) if alt.size else 0.0


def extrapolation_kg_per_distance(heldout_residual_kg: np.ndarray, distance: np.ndarray,
                                  interior: np.ndarray) -> float:
    """How the held-out error grows with the distance to the calibrated configurations (kg per unit of
    :meth:`Envelope.nearest <rgse_daemon.pipeline.envelope.Envelope.nearest>`'s distance), from the calibration's own
    held-out residuals (each loaded configuration predicted by the fit on the others, eq. 21 in kg) at their distance
    to the nearest other configuration: r_i² ≈ s² + (c·d_i)², with s² the mean square of the interior configurations'
    residuals (the reproducibility, already in U); c² by least squares in d_i² (0 if the data show no growth).
    The widening of U for a DuT outside the envelope is c·d at its distance: out of sample, and only as large as the
    calibration's own extrapolations were wrong (NaN if fewer than three configurations give a residual)."""
    r = np.asarray(heldout_residual_kg, float)
    d = np.asarray(distance, float)
    ok = np.isfinite(r) & np.isfinite(d) & (d > 0)
    inner = ok & np.asarray(interior, bool)
    if ok.sum() < 3 or inner.sum() < 2:
        return float("nan")
    s2 = float(np.mean(r[inner] ** 2))
    c2 = float(np.sum(d[ok] ** 2 * (r[ok] ** 2 - s2)) / np.sum(d[ok] ** 4))
    return float(np.sqrt(max(c2, 0.0)))


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
