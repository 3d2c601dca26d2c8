"""Calibration function K per axis (paper §2.4.6, eq. 19/20): the models, their fits and averages.

Pure numpy/scipy. A calibration maps the bias-normalised measured torque of A3 and A5 to a corrected torque
``K(M)·M``; the mass follows from eq. 21 (see :mod:`rgse_daemon.pipeline.mass`).

Two families of models are offered:

* ``paper`` / ``ratio-*``: as in the paper, K of each axis is fitted on its own to the calibration factor
  samples ``K_i = M_expected / M_measured`` (eq. 19: 2nd-order polynomial for A3, eq. 20: double exponential
  for A5).
* ``axis-*``: one monotone drive gain curve ``G(M) = K(M)·M`` per axis, linear in its parameters, each axis
  least-squares fitted on its own to its expected torque (eq. 17/18): identifiable per axis like the paper's.
* ``gain-*``: the same gain curves, both axes fitted *jointly* so that the mass of eq. 21 matches the calibration
  masses (relative errors, the paper's error measure). They need no per-axis expected torque, but how the
  correction splits between A3 and A5 is only identifiable where the campaign's A3/A5 torque ratio varies: they
  are admitted only when their per-axis corrected torques match the expected ones on held-out configurations
  (:func:`rgse_daemon.pipeline.selection.admissibility`).

Which model ``--method auto`` uses, by held-out configurations, is :mod:`rgse_daemon.pipeline.selection`'s job.

Every torque function is odd in the torque (``K`` is evaluated at ``|M|``): the sign of ``Istmoment`` depends
on pose and axis direction and nothing here assumes positive torques.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from scipy.optimize import least_squares

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import mass as mass_eq

#: Scale of the gain basis functions as a fraction of the campaign's largest measured torque (either axis,
#: :meth:`CalibrationPoints.gain_scale_nm`). The ``log`` and ``sat`` terms bend at their scale, so a fixed scale in Nm
#: would give each robot and payload range another model family; tied to the campaign, the catalogue is the same in
#: relative terms everywhere (every torque and mass ×c gives the same relative fit). 2/9: Table 1's 4.5 kNm top gives
#: the 1 kNm the catalogue was first set up with.
GAIN_SCALE_FRACTION = 2.0 / 9.0
#: Scale (Nm) of a gain curve that names none (calibration files written before the scale followed the campaign).
GAIN_SCALE_NM = 1000.0
#: Scales τ a ``sat`` gain term is fitted at, as multiples of the gain scale (log-spaced grid, 0.05 to 3: on Table 1
#: 50 Nm to 3 kNm) ...
SAT_SCALE_MULTIPLES = tuple(float(v) for v in np.geomspace(0.05, 3.0, 25))
#: ... up to this fraction of the largest torque the calibration covers on that axis.
SAT_MAX_FRACTION = 0.8
#: Evaluations of the bounded least-squares polish of eq. 20 from the grid's best start (the grid start is close; on
#: near-exact data the valley is flat and the polish would creep on for hundreds of steps without changing K).
MAX_NFEV_DOUBLE_EXP = 40


class CalibrationError(DataError):
    """The calibration points do not allow the requested fit (too few points, degenerate data)."""


# ------------------------------------------------------------------------------------------------------------
# calibration points
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationPoints:
    """The pre-averaged, bias-normalised torques of a calibration campaign (paper Table 1).

    Attributes
    ----------
    kind : array of str
        ``"zero"``, ``"mass"`` or ``"torque"`` per point.
    mass_kg : ndarray
        Calibration load mass (CBs and TA), kg; 0 for the zero point.
    torque_a3_nm, torque_a5_nm : ndarray
        Measured, bias-normalised torque (eq. 16 double average minus M_0), Nm.
    expected_a3_nm, expected_a5_nm : ndarray
        Expected torque ``g·m·lever`` (eq. 17/18), Nm; used by the per-axis ``paper``/``ratio-*`` models only.
    mass_cov_kg2 : ndarray or None
        Covariance of the reference masses ``mass_kg`` (kg², n × n; see :func:`reference_mass_covariance`);
        None: the reference masses are taken as exact.
    """

    kind: np.ndarray
    mass_kg: np.ndarray
    torque_a3_nm: np.ndarray
    torque_a5_nm: np.ndarray
    expected_a3_nm: np.ndarray
    expected_a5_nm: np.ndarray
    mass_cov_kg2: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.mass_kg)
        for name in ("kind", "torque_a3_nm", "torque_a5_nm", "expected_a3_nm", "expected_a5_nm"):
            if len(getattr(self, name)) != n:
                raise CalibrationError(f"calibration points: column {name} has {len(getattr(self, name))} "
                                       f"values, expected {n}")
        for name in ("mass_kg", "torque_a3_nm", "torque_a5_nm", "expected_a3_nm", "expected_a5_nm"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise CalibrationError(f"calibration points: column {name} holds NaN or infinite values")
        if np.any(self.mass_kg < 0):
            raise CalibrationError("calibration points: negative mass_kg")
        flat = (self.mass_kg > 0) & ~(self.expected_a3_nm > self.expected_a5_nm)
        if flat.any():  # its lever difference Δr (eq. 21, :meth:`lever_difference_m`) would be ≤ 0
            bad = int(np.flatnonzero(flat)[0])
            raise CalibrationError(f"calibration point {bad + 1}: expected A3 torque {self.expected_a3_nm[bad]:.2f} Nm "
                                   f"is not above its expected A5 torque {self.expected_a5_nm[bad]:.2f} Nm "
                                   f"(r_A3 − r_A5 must be positive)")
        if self.mass_cov_kg2 is not None and (np.shape(self.mass_cov_kg2) != (n, n)
                                              or not np.all(np.isfinite(self.mass_cov_kg2))):
            raise CalibrationError(f"calibration points: mass covariance must be a finite {n}x{n} matrix")

    def __len__(self) -> int:
        return len(self.mass_kg)

    def subset(self, index: np.ndarray) -> CalibrationPoints:
        idx = np.arange(len(self))[index]
        cov = None if self.mass_cov_kg2 is None else np.asarray(self.mass_cov_kg2)[np.ix_(idx, idx)]
        return CalibrationPoints(*(np.asarray(getattr(self, f))[idx] for f in
                                   ("kind", "mass_kg", "torque_a3_nm", "torque_a5_nm", "expected_a3_nm",
                                    "expected_a5_nm")), cov)

    def lever_difference_m(self, g_m_s2: float, default_m: float) -> np.ndarray:
        """Each point's own lever difference r_A3 − r_A5 (eq. 21's Δr), m: what its expected torques encode,
        ``(M_A3,exp − M_A5,exp) / (g·m)`` (eq. 17/18); ``default_m`` (the measurement pose's) for the zero point.

        A point recorded in another pose than the measurement pose has another Δr (Table 1's torque rows: 1.0204 m
        against the mass rows' 1.0250 m); eq. 21 with the measurement pose's Δr would give such a point a mass
        0.45 % off even when both of its corrected torques are exact."""
        loaded = self.mass_kg > 0
        dr = np.full(len(self), float(default_m))
        dr[loaded] = (self.expected_a3_nm[loaded] - self.expected_a5_nm[loaded]) / (g_m_s2 * self.mass_kg[loaded])
        return dr  # positive: checked when the points are made

    def gain_scale_nm(self) -> float:
        """The torque scale of the gain curves fitted to these points (:data:`GAIN_SCALE_FRACTION` of the largest
        measured torque of a loaded point, either axis); :data:`GAIN_SCALE_NM` if no point is loaded."""
        loaded = self.mass_kg > 0
        top = float(np.max(np.abs(np.concatenate([self.torque_a3_nm[loaded], self.torque_a5_nm[loaded]])),
                           initial=0.0))
        return GAIN_SCALE_FRACTION * top if top > 0 else GAIN_SCALE_NM

    def with_masses(self, mass_kg: np.ndarray) -> CalibrationPoints:
        """The same points with other reference masses (expected torques scaled along)."""
        m = np.asarray(mass_kg, float)
        scale = np.divide(m, self.mass_kg, out=np.ones_like(m), where=self.mass_kg > 0)
        return CalibrationPoints(self.kind, m, self.torque_a3_nm, self.torque_a5_nm, self.expected_a3_nm * scale,
                                 self.expected_a5_nm * scale, self.mass_cov_kg2)


def reference_mass_covariance(mass_var_kg2: np.ndarray, nested: bool = True) -> np.ndarray:
    """Covariance of the calibration loads' reference masses from each load's variance.

    ``nested``: the loads contain each other (the paper's stack of calibration bodies: a load of n bodies holds
    the bodies of every lighter load, the torque rows all ten and the test adapter), so with independent body
    errors ``cov(i, j) = min(var_i, var_j)``. Otherwise the loads are independent (diagonal).
    """
    v = np.asarray(mass_var_kg2, float)
    return np.minimum.outer(v, v) if nested else np.diag(v)


def mean_abs_pct(mass_true_kg: np.ndarray, mass_calc_kg: np.ndarray) -> float:
    """Mean absolute mass error in % as the paper counts it: over all points, the zero-mass point as 0 %."""
    true = np.asarray(mass_true_kg, float)
    safe = np.where(true > 0, true, 1.0)
    pct = np.where(true > 0, np.abs(np.asarray(mass_calc_kg) - true) / safe * 100.0, 0.0)
    return float(pct.mean())


def r_squared(y: np.ndarray, y_fit: np.ndarray) -> float:
    """Coefficient of determination of a fit."""
    ss_res = float(np.sum((y - y_fit) ** 2))
    ss_tot = float(np.sum((y - np.mean(y)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else np.nan


# ------------------------------------------------------------------------------------------------------------
# K functions of one axis
# ------------------------------------------------------------------------------------------------------------
class AxisK(ABC):
    """A calibration function of one axis: ``K(M)`` and the corrected torque ``K(M)·M``."""

    kind: ClassVar[str]

    @abstractmethod
    def k(self, torque_nm: np.ndarray) -> np.ndarray:
        """The calibration factor K at the (bias-normalised) measured torque."""

    def corrected_torque_nm(self, torque_nm: np.ndarray) -> np.ndarray:
        """K(M)·M, the torque the drive really carries (numerator terms of eq. 21)."""
        m = np.asarray(torque_nm, float)
        return self.k(m) * m

    @property
    @abstractmethod
    def params(self) -> np.ndarray:
        """The parameter vector (the order of the covariance rows)."""

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (CAL.json ``models``)."""

    @staticmethod
    def from_dict(d: dict[str, Any]) -> AxisK:
        try:
            kind = d["kind"]
            if kind == PolyK.kind:
                return PolyK(np.asarray(d["coef"], float))
            if kind == DoubleExpK.kind:
                return DoubleExpK(np.asarray(d["b"], float))
            if kind == GainK.kind:
                scales = d.get("scales_nm")
                k = GainK(tuple(d["terms"]), np.asarray(d["coef"], float), float(d["scale_nm"]),
                          None if scales is None else tuple(float(v) for v in scales))
                if len(k.coef) != len(k.terms) or len(k.term_scales_nm) != len(k.terms) or not all(
                        v > 0 and np.isfinite(v) for v in k.term_scales_nm):
                    raise ValueError("terms, coef and scales_nm must match in length, scales positive")
                return k
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"calibration model: malformed axis model {d!r}: {exc}") from exc
        raise DataError(f"calibration model: unknown axis model kind {kind!r}")


@dataclass(frozen=True)
class PolyK(AxisK):
    """Eq. 19: ``K(M) = a1·M² + a2·M + a3`` (``coef = [a1, a2, a3]``, highest power first), M taken as |M|."""

    coef: np.ndarray
    kind: ClassVar[str] = "poly"

    def k(self, torque_nm: np.ndarray) -> np.ndarray:
        return np.polyval(self.coef, np.abs(np.asarray(torque_nm, float)))

    @property
    def params(self) -> np.ndarray:
        return np.asarray(self.coef, float)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "coef": [float(c) for c in self.coef]}


@dataclass(frozen=True)
class DoubleExpK(AxisK):
    """Eq. 20: ``K(M) = b1·exp(b2·M) + b3·exp(b4·M)`` (``b = [b1, b2, b3, b4]``), M taken as |M|."""

    b: np.ndarray
    kind: ClassVar[str] = "double_exp"

    def k(self, torque_nm: np.ndarray) -> np.ndarray:
        x = np.abs(np.asarray(torque_nm, float))
        b1, b2, b3, b4 = self.b
        return b1 * np.exp(b2 * x) + b3 * np.exp(b4 * x)

    @property
    def params(self) -> np.ndarray:
        return np.asarray(self.b, float)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "b": [float(v) for v in self.b]}


def _basis(term: str, torque_nm: np.ndarray, scale_nm: float) -> np.ndarray:
    """Odd basis functions of a drive gain curve G(M), each monotone increasing in M."""
    m = np.asarray(torque_nm, float)
    s = scale_nm
    if term == "lin":
        return m
    if term == "quad":
        return m * np.abs(m) / s
    if term == "sqrt":
        return np.sign(m) * np.sqrt(np.abs(m) * s)
    if term == "log":
        return np.sign(m) * s * np.log1p(np.abs(m) / s)
    if term == "sat":  # eq. 20's saturating exponential as a gain term: slope 1 at 0, none beyond a few s
        return np.sign(m) * s * -np.expm1(-np.abs(m) / s)
    raise DataError(f"calibration model: unknown gain term {term!r}")


@dataclass(frozen=True)
class GainK(AxisK):
    """A drive gain curve ``G(M) = Σ c_k·φ_k(M)`` linear in its parameters; ``K(M) = G(M)/M``.

    Every term's torque scale is ``scale_nm`` unless ``scales_nm`` gives one per term (a ``sat`` term fitted at its
    own scale, or an average of curves with different ones)."""

    terms: tuple[str, ...]
    coef: np.ndarray
    scale_nm: float = GAIN_SCALE_NM
    scales_nm: tuple[float, ...] | None = None
    kind: ClassVar[str] = "gain"

    @property
    def term_scales_nm(self) -> tuple[float, ...]:
        return self.scales_nm if self.scales_nm is not None else (self.scale_nm,) * len(self.terms)

    def design(self, torque_nm: np.ndarray) -> np.ndarray:
        """Columns φ_k(M): the Jacobian of G(M) with respect to the coefficients."""
        return np.stack([_basis(t, torque_nm, s) for t, s in zip(self.terms, self.term_scales_nm, strict=True)],
                        axis=-1)

    def corrected_torque_nm(self, torque_nm: np.ndarray) -> np.ndarray:
        return self.design(torque_nm) @ np.asarray(self.coef, float)

    def k(self, torque_nm: np.ndarray) -> np.ndarray:
        m = np.asarray(torque_nm, float)
        g = self.corrected_torque_nm(m)
        # the slope at 0: 1 per unit coefficient of lin, log and sat, 0 of quad (sqrt's is infinite: left out)
        slope0 = (float(sum(c for t, c in zip(self.terms, self.coef, strict=True) if t in ("lin", "log", "sat")))
                  if "lin" in self.terms else np.nan)
        with np.errstate(invalid="ignore"):  # G(0)/0 is replaced by the slope at 0
            return np.where(m != 0, g / m, slope0)

    @property
    def params(self) -> np.ndarray:
        return np.asarray(self.coef, float)

    def to_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind, "terms": list(self.terms), "coef": [float(c) for c in self.coef],
             "scale_nm": self.scale_nm}
        if self.scales_nm is not None:
            d["scales_nm"] = [float(v) for v in self.scales_nm]
        return d


# ------------------------------------------------------------------------------------------------------------
# a fitted calibration
# ------------------------------------------------------------------------------------------------------------
@dataclass
class Calibration:
    """A fitted calibration: K of A3 and A5, their parameter covariance and the torque range they cover.

    ``covariance`` is over ``concat(k_a3.params, k_a5.params)``: the fit's own (torque noise and lack of fit)
    plus ``covariance_reference``, the part due to the reference masses' uncertainty (zero if not propagated).
    """

    method: str
    k_a3: AxisK
    k_a5: AxisK
    covariance: np.ndarray
    torque_range_a3_nm: tuple[float, float]
    torque_range_a5_nm: tuple[float, float]
    g_m_s2: float
    lever_difference_m: float
    r2: dict[str, float] = field(default_factory=dict)
    covariance_reference: np.ndarray | None = None

    @property
    def params(self) -> np.ndarray:
        return np.concatenate([self.k_a3.params, self.k_a5.params])

    def with_params(self, params: np.ndarray) -> Calibration:
        """The same model with other parameter values (for Monte Carlo propagation)."""
        n3 = len(self.k_a3.params)
        return Calibration(self.method, _replace_params(self.k_a3, params[:n3]),
                           _replace_params(self.k_a5, params[n3:]), self.covariance, self.torque_range_a3_nm,
                           self.torque_range_a5_nm, self.g_m_s2, self.lever_difference_m, self.r2,
                           self.covariance_reference)

    def params_of(self, other: Calibration) -> np.ndarray:
        """``other``'s curves (a refit of this model to other data) as this calibration's parameters, for
        :meth:`with_params`. A refit of a model with a ``sat`` term picks its own τ on the grid (and an average's
        refit its own union of terms): its coefficients belong to its own basis, and put into this one they give
        another curve (on Table 1, a spread of the DuT's mass over the refits 10 to 30 times the refits' own).
        Where the bases differ, each axis' refitted curve G(M) is projected by least squares onto this calibration's
        basis over 0 to 1.5 times the torque it covers (the envelope's limit); the basis functions are odd, so one
        sign suffices. Same basis: ``other.params``."""
        out = []
        for mine, theirs, (_, top) in ((self.k_a3, other.k_a3, self.torque_range_a3_nm),
                                       (self.k_a5, other.k_a5, self.torque_range_a5_nm)):
            if not (isinstance(mine, GainK) and isinstance(theirs, GainK)) or (
                    mine.terms == theirs.terms and mine.term_scales_nm == theirs.term_scales_nm):
                out.append(theirs.params)
                continue
            grid = np.linspace(0.0, 1.5 * max(top, 1.0), 301)
            coef, *_ = np.linalg.lstsq(mine.design(grid), theirs.corrected_torque_nm(grid), rcond=None)
            out.append(coef)
        return np.concatenate(out)

    @property
    def covariance_fit(self) -> np.ndarray:
        """The fit's own part of the parameter covariance (without the reference masses')."""
        cov = np.asarray(self.covariance, float)
        return cov if self.covariance_reference is None else cov - self.covariance_reference

    def mass_kg(self, torque_a3_nm: np.ndarray, torque_a5_nm: np.ndarray, fixture_mass_kg: float = 0.0) -> np.ndarray:
        """Eq. 21 with this calibration's K functions."""
        return mass_eq.dut_mass_kg(self.k_a3.corrected_torque_nm(torque_a3_nm),
                                   self.k_a5.corrected_torque_nm(torque_a5_nm),
                                   self.g_m_s2, self.lever_difference_m, fixture_mass_kg)

    def points_mass_kg(self, points: CalibrationPoints, index: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Eq. 21 for calibration points, each with its own lever difference
        (:meth:`CalibrationPoints.lever_difference_m`): the mass that the point's corrected torques give in the
        geometry its expected torques were computed for."""
        idx = np.arange(len(points))[index]
        dr = points.lever_difference_m(self.g_m_s2, self.lever_difference_m)[idx]
        return mass_eq.dut_mass_kg(self.k_a3.corrected_torque_nm(points.torque_a3_nm[idx]),
                                   self.k_a5.corrected_torque_nm(points.torque_a5_nm[idx]), self.g_m_s2, dr)

    def out_of_range(self, torque_a3_nm: float, torque_a5_nm: float, margin: float = 0.05) -> list[str]:
        """Warnings for torques outside the fitted range (beyond ``margin`` of its span)."""
        out = []
        for axis, m, (lo, hi) in (("A3", torque_a3_nm, self.torque_range_a3_nm),
                                  ("A5", torque_a5_nm, self.torque_range_a5_nm)):
            span = hi - lo
            if abs(m) < lo - margin * span or abs(m) > hi + margin * span:
                out.append(f"torque {axis} |{m:.1f}| Nm is outside the calibrated range {lo:.1f}..{hi:.1f} Nm")
        return out

    def models_dict(self) -> dict[str, Any]:
        return {"A3": self.k_a3.to_dict(), "A5": self.k_a5.to_dict()}


def _replace_params(k: AxisK, p: np.ndarray) -> AxisK:
    if isinstance(k, PolyK):
        return PolyK(np.asarray(p, float))
    if isinstance(k, DoubleExpK):
        return DoubleExpK(np.asarray(p, float))
    if isinstance(k, GainK):
        return GainK(k.terms, np.asarray(p, float), k.scale_nm, k.scales_nm)
    raise TypeError(type(k))


def _torque_range(torque_nm: np.ndarray) -> tuple[float, float]:
    a = np.abs(torque_nm)
    return (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)


# ------------------------------------------------------------------------------------------------------------
# per-axis ratio fits (the paper's way)
# ------------------------------------------------------------------------------------------------------------
def _ratio_samples(points: CalibrationPoints, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Calibration factor samples K_i = M_expected / M_measured of the loaded points (paper Table 1)."""
    measured = points.torque_a3_nm if axis == "A3" else points.torque_a5_nm
    expected = points.expected_a3_nm if axis == "A3" else points.expected_a5_nm
    use = (points.mass_kg > 0) & (measured != 0)
    return np.abs(measured[use]), expected[use] / measured[use]


def fit_poly_k(x: np.ndarray, y: np.ndarray, degree: int) -> tuple[PolyK, np.ndarray, float]:
    """Least-squares polynomial K (eq. 19 for degree 2); returns K, parameter covariance and R²."""
    if len(x) < degree + 2:
        raise CalibrationError(f"polynomial K of degree {degree} needs at least {degree + 2} loaded points, "
                               f"got {len(x)}")
    a = np.vander(x, degree + 1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ coef
    s2 = float(resid @ resid) / (len(x) - degree - 1)
    cov = s2 * np.linalg.pinv(a.T @ a)
    return PolyK(coef), cov, r_squared(y, a @ coef)


def fit_double_exp_k(x: np.ndarray, y: np.ndarray, n_grid: int = 48, n_starts: int = 1
                     ) -> tuple[DoubleExpK, np.ndarray, float]:
    """Eq. 20 fitted robustly: variable projection on a grid of rates, then bounded least squares from the best starts.

    For fixed rates (b2, b4) the amplitudes (b1, b3) are linear; a vectorised grid over the rates gives
    the best ``n_starts`` distinct starting points, each polished by ``scipy.optimize.least_squares`` with bounds.
    """
    if len(x) < 6:
        raise CalibrationError(f"double-exponential K needs at least 6 loaded points, got {len(x)}")
    x_max = float(np.max(x))
    rate_lo, rate_hi = -30.0 / x_max, 3.0 / x_max
    amp_bound = 10.0
    rates = np.linspace(rate_lo, rate_hi, n_grid)
    e = np.exp(np.outer(rates, x))  # (n_grid, n)
    s11 = np.einsum("in,in->i", e, e)[:, None]
    s22 = s11.T
    s12 = e @ e.T
    r1 = (e @ y)[:, None]
    r2 = r1.T
    det = s11 * s22 - s12**2
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (s22 * r1 - s12 * r2) / det
        b3 = (s11 * r2 - s12 * r1) / det
    cost = float(y @ y) - (b1 * r1 + b3 * r2)  # residual sum of squares at the projected optimum
    valid = (np.triu(np.ones_like(det, bool), 1) & np.isfinite(cost) & (np.abs(det) > 1e-12 * s11 * s22)
             & (np.abs(b1) <= amp_bound) & (np.abs(b3) <= amp_bound))
    cost = np.where(valid, cost, np.inf)
    order = np.argsort(cost, axis=None)[:n_starts]

    def resid(p: np.ndarray) -> np.ndarray:
        return p[0] * np.exp(p[1] * x) + p[2] * np.exp(p[3] * x) - y

    def jac(p: np.ndarray) -> np.ndarray:
        e1, e2 = np.exp(p[1] * x), np.exp(p[3] * x)
        return np.stack([e1, p[0] * x * e1, e2, p[2] * x * e2], axis=1)

    lower = [-amp_bound, rate_lo * 2, -amp_bound, rate_lo * 2]
    upper = [amp_bound, rate_hi * 2, amp_bound, rate_hi * 2]
    best = None
    for flat in order:
        i, j = np.unravel_index(flat, cost.shape)
        if not np.isfinite(cost[i, j]):
            continue
        p0 = np.array([b1[i, j], rates[i], b3[i, j], rates[j]])
        r = least_squares(resid, np.clip(p0, lower, upper), jac=jac, bounds=(lower, upper), x_scale="jac",
                          max_nfev=MAX_NFEV_DOUBLE_EXP)
        if best is None or r.cost < best.cost:
            best = r
    if best is None:
        raise CalibrationError("double-exponential K: no admissible start (degenerate calibration factors)")
    j = best.jac
    dof = max(len(x) - 4, 1)
    cov = (2 * best.cost / dof) * np.linalg.pinv(j.T @ j)
    k = DoubleExpK(best.x)
    return k, cov, r_squared(y, k.k(x))


def _fit_ratio(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
               a3: Callable, a5: Callable) -> Calibration:
    x3, y3 = _ratio_samples(points, "A3")
    x5, y5 = _ratio_samples(points, "A5")
    k3, c3, r3 = a3(x3, y3)
    k5, c5, r5 = a5(x5, y5)
    cov = np.zeros((len(k3.params) + len(k5.params),) * 2)
    cov[: len(k3.params), : len(k3.params)] = c3
    cov[len(k3.params):, len(k3.params):] = c5
    return Calibration(method, k3, k5, cov, _torque_range(points.torque_a3_nm[points.mass_kg > 0]),
                       _torque_range(points.torque_a5_nm[points.mass_kg > 0]), g_m_s2, lever_difference_m,
                       {"A3": r3, "A5": r5})


# ------------------------------------------------------------------------------------------------------------
# per-axis drive-gain fits (each axis' corrected torque to its own expected torque, eq. 17/18)
# ------------------------------------------------------------------------------------------------------------
def fit_axis_gain(torque_nm: np.ndarray, expected_nm: np.ndarray, terms: tuple[str, ...],
                  scale_nm: float = GAIN_SCALE_NM) -> tuple[GainK, np.ndarray, float]:
    """Least-squares ``G(M) = Σ c_k·φ_k(M)`` of one axis to its expected torques (Nm residuals), its terms at the
    torque scale ``scale_nm`` (:meth:`CalibrationPoints.gain_scale_nm`); K, cov, R².

    A ``sat`` term's scale τ is one more parameter: the curve is fitted at every τ of :data:`SAT_SCALE_MULTIPLES`
    times ``scale_nm`` up to :data:`SAT_MAX_FRACTION` of the largest covered torque (beyond it the term is the lin
    and quad terms over again) and the τ with the least squares is kept (variable projection on a grid; the
    covariance is the coefficients' at that τ; the bootstrap of the uncertainty refits τ and re-expresses each refit
    in the calibration's basis, :meth:`Calibration.params_of`)."""
    n_par = len(terms) + ("sat" in terms)
    if len(torque_nm) < n_par + 1:
        raise CalibrationError(f"gain curve {'+'.join(terms)} needs at least {n_par + 1} points, "
                               f"got {len(torque_nm)}")
    top = float(np.max(np.abs(torque_nm)))
    taus = ([t * scale_nm for t in SAT_SCALE_MULTIPLES if t * scale_nm <= SAT_MAX_FRACTION * top]
            if "sat" in terms else [scale_nm])
    if not taus:
        raise CalibrationError(f"gain curve {'+'.join(terms)}: the covered torques (up to {top:.0f} Nm) are too "
                               f"small for a saturating term")
    best = None
    for tau in taus:
        scales = tuple(float(tau) if t == "sat" else scale_nm for t in terms) if "sat" in terms else None
        a = GainK(terms, np.zeros(len(terms)), scale_nm, scales).design(torque_nm)
        coef, *_ = np.linalg.lstsq(a, expected_nm, rcond=None)
        resid = expected_nm - a @ coef
        if best is None or float(resid @ resid) < best[0]:
            best = (float(resid @ resid), GainK(terms, coef, scale_nm, scales), a)
    sse, k, a = best
    dof = max(len(torque_nm) - n_par, 1)
    cov = sse / dof * np.linalg.pinv(a.T @ a)
    return k, cov, r_squared(expected_nm, a @ k.coef)


def _fit_axis(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
              terms_a3: tuple[str, ...], terms_a5: tuple[str, ...]) -> Calibration:
    scale_nm = points.gain_scale_nm()
    k3, c3, r3 = fit_axis_gain(points.torque_a3_nm, points.expected_a3_nm, terms_a3, scale_nm)
    k5, c5, r5 = fit_axis_gain(points.torque_a5_nm, points.expected_a5_nm, terms_a5, scale_nm)
    cov = np.zeros((len(terms_a3) + len(terms_a5),) * 2)
    cov[: len(terms_a3), : len(terms_a3)] = c3
    cov[len(terms_a3):, len(terms_a3):] = c5
    loaded = points.mass_kg > 0
    return Calibration(method, k3, k5, cov, _torque_range(points.torque_a3_nm[loaded]),
                       _torque_range(points.torque_a5_nm[loaded]), g_m_s2, lever_difference_m, {"A3": r3, "A5": r5})


#: Largest |correlation| of the two axes' residuals the ``sur-*`` fits use: at ±1 the common mode would be free and
#: the A3/A5 split unidentifiable (a joint model); below it each axis stays tied to its own expected torque.
SUR_RHO_CAP = 0.9
#: Feasible-GLS rounds of the ``sur-*`` fits (residual covariance re-estimated each round).
SUR_ROUNDS = 3
#: Huber threshold in robust standard deviations (1.345: 95 % efficiency at normal errors); the scale is the
#: normalised median absolute residual (1.4826 × median |r|).
HUBER_K = 1.345


def huber_lstsq(a: np.ndarray, y: np.ndarray, rounds: int = 30) -> np.ndarray:
    """Huber M-estimate of ``a·c ≈ y`` by iteratively reweighted least squares, threshold :data:`HUBER_K` robust
    standard deviations (scale: 1.4826 × the median |residual| of the least-squares start, held fixed).

    Hand-written rather than ``scipy.optimize.least_squares(loss="huber")``: the nested validation and the bootstrap
    make thousands of these tiny fits, and IRLS on a linear model is a few weighted normal-equation solves."""
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    scale = 1.4826 * float(np.median(np.abs(a @ coef - y)))
    if not scale > 0:
        return coef
    for _ in range(rounds):
        r = np.abs(a @ coef - y) / (HUBER_K * scale)
        w = np.where(r > 1.0, 1.0 / np.maximum(r, 1e-12), 1.0)
        aw = a * w[:, None]
        new = np.linalg.solve(aw.T @ a, aw.T @ y)
        if np.all(np.abs(new - coef) <= 1e-9 * (np.abs(coef) + 1e-12)):
            return new
        coef = new
    return coef


def _fit_axis_sur(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
                  terms_a3: tuple[str, ...], terms_a5: tuple[str, ...]) -> Calibration:
    """Per-axis gain curves (eq. 17/18: each axis' corrected torque to its own expected torque) fitted together as
    *seemingly unrelated regressions*, robustly and in relative terms.

    A new mounting moves the load's CoG (and the stack's lever) by the same length for both axes, so the torque
    error it causes is nearly the same on A3 and A5 and cancels in eq. 21 (eq. 3/4). Fitting each axis on its own
    (``axis-*``) chases this common mode; here the (A3, A5) residual pair of every point is whitened with the
    axes' residual covariance (feasible GLS, re-estimated :data:`SUR_ROUNDS` times, correlation capped at
    :data:`SUR_RHO_CAP` so each axis keeps its own expected torque), weighted by 1/m (the relative mass error, the
    paper's measure) and fitted with a Huber loss so that a single scattered point does not pull the curve
    (``scipy.optimize.least_squares``)."""
    loaded = points.mass_kg > 0
    n, p3, p5 = int(loaded.sum()), len(terms_a3), len(terms_a5)
    if n < max(p3, p5) + 2:
        raise CalibrationError(f"model {method} needs at least {max(p3, p5) + 2} loaded points, got {n}")
    scale_nm = points.gain_scale_nm()
    a3 = GainK(terms_a3, np.zeros(p3), scale_nm).design(points.torque_a3_nm[loaded])
    a5 = GainK(terms_a5, np.zeros(p5), scale_nm).design(points.torque_a5_nm[loaded])
    x = np.zeros((n, 2, p3 + p5))
    x[:, 0, :p3], x[:, 1, p3:] = a3, a5
    y = np.stack([points.expected_a3_nm[loaded], points.expected_a5_nm[loaded]], axis=1)
    w = 1.0 / points.mass_kg[loaded]
    x, y = x * w[:, None, None], y * w[:, None]
    cov_r = np.eye(2)
    for _ in range(SUR_ROUNDS):
        white = np.linalg.inv(np.linalg.cholesky(cov_r))
        xw, yw = np.einsum("ij,njp->nip", white, x).reshape(2 * n, -1), (y @ white.T).reshape(-1)
        coef = huber_lstsq(xw, yw)
        r = np.einsum("nkp,p->nk", x, coef) - y
        s = np.sqrt(np.mean(r**2, axis=0))
        if not np.all(s > 0):
            break
        rho = float(np.clip(np.mean(r[:, 0] * r[:, 1]) / (s[0] * s[1]), -SUR_RHO_CAP, SUR_RHO_CAP))
        cov_r = np.array([[s[0] ** 2, rho * s[0] * s[1]], [rho * s[0] * s[1], s[1] ** 2]])
    resid = xw @ coef - yw
    dof = max(2 * n - p3 - p5, 1)
    cov = float(resid @ resid) / dof * np.linalg.pinv(xw.T @ xw)
    k3, k5 = GainK(terms_a3, coef[:p3], scale_nm), GainK(terms_a5, coef[p3:], scale_nm)
    return Calibration(method, k3, k5, cov, _torque_range(points.torque_a3_nm[loaded]),
                       _torque_range(points.torque_a5_nm[loaded]), g_m_s2, lever_difference_m,
                       {"A3": r_squared(points.expected_a3_nm[loaded], k3.corrected_torque_nm(
                           points.torque_a3_nm[loaded])),
                        "A5": r_squared(points.expected_a5_nm[loaded], k5.corrected_torque_nm(
                            points.torque_a5_nm[loaded]))})


# ------------------------------------------------------------------------------------------------------------
# joint drive-gain fits (mass error minimised directly)
# ------------------------------------------------------------------------------------------------------------
def _fit_gain(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float,
              terms_a3: tuple[str, ...], terms_a5: tuple[str, ...], loss: str = "linear") -> Calibration:
    """Fit G_A3 and G_A5 jointly so that eq. 21 reproduces the calibration masses (relative residuals)."""
    n_par = len(terms_a3) + len(terms_a5)
    loaded = points.mass_kg > 0
    if int(loaded.sum()) < n_par + 1:
        raise CalibrationError(f"model {method} has {n_par} parameters and needs at least {n_par + 1} loaded "
                               f"points, got {int(loaded.sum())}")
    scale_nm = points.gain_scale_nm()
    g3 = GainK(terms_a3, np.zeros(len(terms_a3)), scale_nm)
    g5 = GainK(terms_a5, np.zeros(len(terms_a5)), scale_nm)
    denom = g_m_s2 * points.lever_difference_m(g_m_s2, lever_difference_m)
    # eq. 21 is linear in the gain coefficients: m = (Φ3·c3 − Φ5·c5) / (g·Δr), each point with its own Δr
    a = np.hstack([g3.design(points.torque_a3_nm), -g5.design(points.torque_a5_nm)]) / denom[:, None]
    y = points.mass_kg
    m_floor = float(points.mass_kg[loaded].min())
    w = 1.0 / np.maximum(y, m_floor)  # relative residuals: the paper's error measure
    aw, yw = a * w[:, None], y * w
    coef, *_ = np.linalg.lstsq(aw, yw, rcond=None)
    if loss != "linear":
        r = least_squares(lambda c: aw @ c - yw, coef, loss=loss, f_scale=0.005)
        coef = r.x
    resid = aw @ coef - yw
    dof = max(len(y) - n_par, 1)
    cov = float(resid @ resid) / dof * np.linalg.pinv(aw.T @ aw)
    k3 = GainK(terms_a3, coef[: len(terms_a3)], scale_nm)
    k5 = GainK(terms_a5, coef[len(terms_a3):], scale_nm)
    return Calibration(method, k3, k5, cov, _torque_range(points.torque_a3_nm[loaded]),
                       _torque_range(points.torque_a5_nm[loaded]), g_m_s2, lever_difference_m, {})


# ------------------------------------------------------------------------------------------------------------
# the catalogue of models
# ------------------------------------------------------------------------------------------------------------
FitFn = Callable[[CalibrationPoints, float, float], Calibration]


# pragma: no mutate start, as the model factories run once at import, before mutmut switches a mutant on: no test
# can kill their mutants (every fit of the tests goes through the lambdas they return)
def _ratio_model(name: str, a3: Callable, a5: Callable) -> FitFn:
    return lambda p, g, dr: _fit_ratio(p, name, g, dr, a3, a5)


#: The per-axis gain models' terms (A3, A5): their average is again a per-axis gain curve
#: (:func:`rgse_daemon.pipeline.selection.average_of`).
GAIN_TERMS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}


def _sur_model(name: str, t3: tuple[str, ...], t5: tuple[str, ...]) -> FitFn:
    GAIN_TERMS[name] = (t3, t5)
    return lambda p, g, dr: _fit_axis_sur(p, name, g, dr, t3, t5)


def _gain_model(name: str, t3: tuple[str, ...], t5: tuple[str, ...], loss: str = "linear") -> FitFn:
    return lambda p, g, dr: _fit_gain(p, name, g, dr, t3, t5, loss)


def _axis_model(name: str, t3: tuple[str, ...], t5: tuple[str, ...]) -> FitFn:
    GAIN_TERMS[name] = (t3, t5)
    return lambda p, g, dr: _fit_axis(p, name, g, dr, t3, t5)


# pragma: no mutate end
MODELS: dict[str, tuple[FitFn, str]] = {
    "paper": (_ratio_model("paper", lambda x, y: fit_poly_k(x, y, 2), fit_double_exp_k),
              "K_A3 2nd-order polynomial (eq. 19), K_A5 double exponential (eq. 20), per-axis ratio fits"),
    "ratio-linear": (_ratio_model("ratio-linear", lambda x, y: fit_poly_k(x, y, 1), lambda x, y: fit_poly_k(x, y, 1)),
                     "K linear in torque per axis, per-axis ratio fits"),
    "axis-linear": (_axis_model("axis-linear", ("lin",), ("lin",)),
                    "constant drive gain per axis, each axis fitted to its expected torque"),
    "axis-quad": (_axis_model("axis-quad", ("lin", "quad"), ("lin", "quad")),
                  "quadratic drive gain per axis (odd in torque), each axis fitted to its expected torque"),
    "axis-log": (_axis_model("axis-log", ("lin", "log"), ("lin", "sqrt")),
                 "A3 gain with a saturating log term, A5 with a square-root term, each axis fitted on its own"),
    "axis-sat": (_axis_model("axis-sat", ("lin", "quad"), ("lin", "sat", "quad")),
                 "A3 quadratic gain, A5 gain with eq. 20's saturating exponential (scale fitted) and a quadratic "
                 "term, each axis fitted on its own"),
    "axis-sat-sat": (_axis_model("axis-sat-sat", ("lin", "sat", "quad"), ("lin", "sat", "quad")),
                     "saturating exponential (scale fitted) and quadratic gain terms on both axes, each axis fitted "
                     "on its own"),
    "sur-linear": (_sur_model("sur-linear", ("lin",), ("lin",)),
                   "constant drive gain per axis, per-axis curves fitted together (axes' common mode, Huber, 1/m)"),
    "sur-quad": (_sur_model("sur-quad", ("lin", "quad"), ("lin", "quad")),
                 "quadratic drive gain per axis, per-axis curves fitted together (common mode, Huber, 1/m)"),
    "sur-log": (_sur_model("sur-log", ("lin", "log"), ("lin", "sqrt")),
                "A3 log, A5 square-root gain term, per-axis curves fitted together (common mode, Huber, 1/m)"),
    "sur-log-lin": (_sur_model("sur-log-lin", ("lin", "log"), ("lin",)),
                    "A3 log gain term, A5 constant gain, per-axis curves fitted together (common mode, Huber, 1/m)"),
    "sur-log-quad": (_sur_model("sur-log-quad", ("lin", "log"), ("lin", "quad")),
                     "A3 log, A5 quadratic gain term, per-axis curves fitted together (common mode, Huber, 1/m)"),
    "sur-log-log": (_sur_model("sur-log-log", ("lin", "log"), ("lin", "log")),
                    "log gain term on both axes, per-axis curves fitted together (common mode, Huber, 1/m)"),
    "gain-linear": (_gain_model("gain-linear", ("lin",), ("lin",)),
                    "constant drive gain per axis, fitted jointly to the masses"),
    "gain-sqrt": (_gain_model("gain-sqrt", ("lin", "sqrt"), ("lin",)),
                  "A3 gain with a square-root (friction-like) term, A5 constant, fitted to the masses"),
    "gain-log": (_gain_model("gain-log", ("lin", "log"), ("lin",)),
                 "A3 gain with a saturating log term (friction-like), A5 constant, fitted to the masses"),
    "gain-quad": (_gain_model("gain-quad", ("lin", "quad"), ("lin", "quad")),
                  "quadratic drive gain per axis (odd in torque), fitted to the masses"),
    "gain-sqrt-huber": (_gain_model("gain-sqrt-huber", ("lin", "sqrt"), ("lin", "sqrt"), "huber"),
                        "square-root gain terms on both axes, Huber-robust fit to the masses"),
}


#: Models fitted jointly to the masses: their A3/A5 split must be shown on held-out configurations.
JOINT_MODELS = frozenset(name for name in MODELS if name.startswith("gain-"))


def reference_mass_param_covariance(points: CalibrationPoints, method: str, g_m_s2: float,
                                    lever_difference_m: float, step_kg: float = 0.01) -> np.ndarray:
    """Covariance of the model parameters caused by the reference masses' uncertainty: ``J·Σ_m·Jᵀ`` with
    ``J = ∂params/∂mass_kg`` by central differences (exact for the gain models, which are linear in the masses
    up to their weights)."""
    base = fit(points, method, g_m_s2, lever_difference_m)
    n_par = len(base.params)
    if points.mass_cov_kg2 is None or not np.any(points.mass_cov_kg2):
        return np.zeros((n_par, n_par))
    jac = np.zeros((n_par, len(points)))
    for i in np.flatnonzero(np.diag(points.mass_cov_kg2) > 0):
        d = np.zeros(len(points))
        d[i] = step_kg
        # (a sat term's τ may move on its grid between the two refits: each is taken in the base fit's basis)
        hi = base.params_of(fit(points.with_masses(points.mass_kg + d), method, g_m_s2, lever_difference_m))
        lo = base.params_of(fit(points.with_masses(points.mass_kg - d), method, g_m_s2, lever_difference_m))
        jac[:, i] = (hi - lo) / (2 * step_kg)
    return jac @ points.mass_cov_kg2 @ jac.T


def fit(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float) -> Calibration:
    """Fit calibration ``method`` (a key of :data:`MODELS`, or an average ``avg:a+b+...`` of per-axis gain models)
    to the calibration points."""
    if method.startswith(AVERAGE_PREFIX):
        return _fit_average(points, method, g_m_s2, lever_difference_m)
    if method not in MODELS:
        raise CalibrationError(f"unknown calibration method {method!r}; choose auto or one of {', '.join(MODELS)}")
    return MODELS[method][0](points, g_m_s2, lever_difference_m)


def known_method(method: str) -> bool:
    """A key of :data:`MODELS` or a well-formed average of its per-axis gain models."""
    if method.startswith(AVERAGE_PREFIX):
        members = method.removeprefix(AVERAGE_PREFIX).split("+")
        return len(members) >= 2 and all(m in AVERAGEABLE for m in members)
    return method in MODELS


# ------------------------------------------------------------------------------------------------------------
# the average of the admissible per-axis gain models (what ``auto`` gives)
# ------------------------------------------------------------------------------------------------------------
#: Prefix of an averaged model's method name; the members follow, joined by ``+``.
AVERAGE_PREFIX = "avg:"
#: Models whose two axes are gain curves fitted per axis: their average is again a per-axis gain curve.
AVERAGEABLE = tuple(GAIN_TERMS)
_TERM_ORDER = ("lin", "quad", "sqrt", "log", "sat")


def _term_keys(k: GainK, lin_scale_nm: float) -> list[tuple[str, float]]:
    """(term, scale) per term: ``lin`` does not depend on the scale, so every curve's lin terms are one (keyed at
    ``lin_scale_nm``)."""
    return [(t, lin_scale_nm if t == "lin" else float(s)) for t, s in zip(k.terms, k.term_scales_nm, strict=True)]


def _mean_gain(ks: list[AxisK]) -> GainK:
    """The mean of gain curves: G(M) = Σ G_k(M)/n is linear in the union of their (term, scale) pairs."""
    for k in ks:
        if not isinstance(k, GainK):
            raise CalibrationError(f"only gain curves can be averaged, got {k.kind}")
    base = ks[0].scale_nm  # the members' common scale (fitted to the same points)
    keys = sorted({key for k in ks for key in _term_keys(k, base)},
                  key=lambda ts: (_TERM_ORDER.index(ts[0]), ts[1]))
    coef = np.zeros(len(keys))
    for k in ks:
        for key, c in zip(_term_keys(k, base), k.coef, strict=True):
            coef[keys.index(key)] += float(c) / len(ks)
    scales = tuple(s for _, s in keys)
    return GainK(tuple(t for t, _ in keys), coef, base, None if all(s == base for s in scales) else scales)


def _fit_average(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float) -> Calibration:
    """Each member fitted on the points, their gain curves averaged per axis with equal weights. Eq. 21 is linear in
    the corrected torques, so the mass of the average is the average of the members' masses, and each axis still
    answers to its own expected torque. Averaging the few best models instead of picking one keeps the choice among
    near-equal held-out errors (which 13 points cannot make reliably) from adding its own scatter.

    The covariance is the members' covariances mapped onto the union of terms with the members taken as
    independent (an approximation; the budget of a file with ``fit.uncertainty`` uses the bootstrap refits)."""
    if not known_method(method):
        raise CalibrationError(f"average {method!r}: needs at least two of {', '.join(AVERAGEABLE)}")
    fits = [fit(points, m, g_m_s2, lever_difference_m) for m in method.removeprefix(AVERAGE_PREFIX).split("+")]
    k3, k5 = _mean_gain([f.k_a3 for f in fits]), _mean_gain([f.k_a5 for f in fits])
    n3 = len(k3.terms)
    cov = np.zeros((n3 + len(k5.terms),) * 2)
    for f in fits:
        idx = ([_term_keys(k3, k3.scale_nm).index(key) for key in _term_keys(f.k_a3, k3.scale_nm)]
               + [n3 + _term_keys(k5, k5.scale_nm).index(key) for key in _term_keys(f.k_a5, k5.scale_nm)])
        cov[np.ix_(idx, idx)] += np.asarray(f.covariance, float) / len(fits) ** 2
    loaded = points.mass_kg > 0
    return Calibration(method, k3, k5, cov, _torque_range(points.torque_a3_nm[loaded]),
                       _torque_range(points.torque_a5_nm[loaded]), g_m_s2, lever_difference_m, {})
