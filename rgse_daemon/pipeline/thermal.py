"""The thermal drift of the torque estimate (paper §2.4.5): estimated from the campaign's own loops, removed at
measurement time, its uncertainty a term of U.

The drive's torque estimate drifts with motor temperature, relative to the whole reading (arm, bias and load):
``M(T) = M_static·(1 + β·(T − T_amb))``. Within one calibration point the load and its mounting are fixed while the
motors warm from loop to loop, so each loop's deviation from its point's mean is ``β·M̄_i·(T_ij − T̄_i)`` plus
noise: a regression through the origin over all loops of all points gives β per axis and its standard uncertainty
(the mounting offsets, the hysteresis and the settling are the same for every loop of a point and drop out).

At measurement time each loop's reading is brought to the campaign's mean motor temperature ``T_ref`` (CAL.json
``thermal_state_k``, the temperature the calibration points hold): ``M_corr = M·(1 − β·(T − T_ref))`` (first order
in β·ΔT; the second order is below 0.01 % for 40 K at β = 0.002/K). The uncertainty of β gives the ``thermal``
component ``u(δ) = u_β·|M̄·(T − T_ref)|`` per axis, through eq. 21's sensitivities.

Where β is not applied (issue 33: :meth:`ThermalDrift.not_applicable`) the loops stay uncorrected and the ``thermal``
component is the drift a coefficient up to :meth:`ThermalDrift.drift_bound_per_k` could cause over the DuT's offset
(rectangular); :func:`combine_axes` adds the two axes' terms, with the signs the campaign resolves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rgse_daemon.errors import DataError

AXES = ("A3", "A5")
#: β is applied only where the data resolve it (issue 33): at least this many standard uncertainties from 0 ...
MIN_SIGNIFICANCE = 3.0
#: ... fitted on loops whose temperatures spanned at least this much within a point (K) ...
MIN_SPAN_K = 1.0
#: ... and with the DuT's temperature offset from the reference at most this multiple of that span.
MAX_EXTRAPOLATION = 3.0
#: Where β is not applied, U carries the drift a coefficient up to a bound could cause over the DuT's temperature
#: offset (rectangular): |β| + 2 u(β) where the campaign's span resolves β, at most this prior (1/K), which alone
#: bounds it where the span is too small. 0.3 %/K bounds the simulated KR C4's 0.08 (A3) and 0.17 %/K (A5) and the
#: thermal_coeff_per_k a drive's torque estimate plausibly has after warm-up; ``rgse mass --drift-prior`` and the
#: daemon's ``measurement.drift_prior_per_k`` set it.
DRIFT_PRIOR_PER_K = 0.003


@dataclass(frozen=True)
class ThermalDrift:
    """β per axis (1/K), its standard uncertainty, the reference temperature (K), the loops it rests on."""

    coeff_per_k: dict[str, float]
    u_coeff_per_k: dict[str, float]
    reference_k: dict[str, float]
    n_loops: int
    span_k: dict[str, float]
    """The spread of the loop temperatures about their point means the estimate saw (max − min, K)."""

    def correct_nm(self, axis: str, reading_nm: float, temp_k: float) -> float:
        """The loop's (raw, not bias-normalised) reading brought to the reference temperature."""
        return float(reading_nm) * (1.0 - self.coeff_per_k[axis] * (float(temp_k) - self.reference_k[axis]))

    def u_correction_nm(self, axis: str, reading_nm: np.ndarray, temp_k: np.ndarray) -> float:
        """Standard uncertainty of the correction of the mean over the loops (β's error is common to all loops)."""
        lever = np.mean(np.asarray(reading_nm, float) * (np.asarray(temp_k, float) - self.reference_k[axis]))
        return float(abs(lever) * self.u_coeff_per_k[axis])

    def unresolved(self, axis: str) -> str | None:
        """Why the campaign does not resolve β of ``axis`` (too small a temperature span, not significant); None if
        it does."""
        beta, u, span = self.coeff_per_k[axis], self.u_coeff_per_k[axis], self.span_k[axis]
        if span < MIN_SPAN_K:
            return f"its loops spanned {span:.2g} K, less than {MIN_SPAN_K:g} K"
        if not abs(beta) >= MIN_SIGNIFICANCE * u:
            return f"it is {abs(beta) / u if u > 0 else 0.0:.1f} standard uncertainties from 0, less than " \
                   f"{MIN_SIGNIFICANCE:g}"
        return None

    def not_applicable(self, axis: str, offset_k: float) -> str | None:
        """Why β of ``axis`` is not applied to a DuT ``offset_k`` from the reference temperature; None if it is."""
        why = self.unresolved(axis)
        if why is None and abs(offset_k) > MAX_EXTRAPOLATION * self.span_k[axis]:
            why = (f"the DuT is {offset_k:+.1f} K from the campaign's temperature, beyond {MAX_EXTRAPOLATION:g} × the "
                   f"{self.span_k[axis]:.2g} K span β was fitted on")
        return why

    def drift_bound_per_k(self, axis: str, prior_per_k: float) -> float:
        """The bound on |β| of ``axis`` that U carries where β is not applied (1/K).

        Where the campaign's span (≥ :data:`MIN_SPAN_K`) resolves β, significant or not: what it shows,
        |β| + 2 u(β), with the prior as the outer bound; where the span is too small: the prior. A β resolved but not
        applied because the DuT lies beyond :data:`MAX_EXTRAPOLATION` × the span is bounded this way too: the
        correction would extrapolate the fit (its sign and offset), the bound only its size over the offset, and
        it never exceeds the prior, which assumes no more about the drift's linearity than before."""
        beta, u = abs(self.coeff_per_k[axis]), self.u_coeff_per_k[axis]
        if self.span_k[axis] >= MIN_SPAN_K:
            return min(prior_per_k, beta + 2.0 * u)
        return prior_per_k

    def describe(self, axis: str, prior_per_k: float = DRIFT_PRIOR_PER_K) -> str:
        """β with its uncertainty and span, where it is applied, and the bound U carries where not, for
        ``rgse calibrate``."""
        why = self.unresolved(axis)
        state = "resolved: applied to a DuT within " + f"{MAX_EXTRAPOLATION * self.span_k[axis]:.2g} K of " + \
            f"{self.reference_k[axis]:.2f} K" if why is None else f"not resolved ({why}): not applied"
        bound = self.drift_bound_per_k(axis, prior_per_k)
        source = "the prior" if bound >= prior_per_k else "|β| + 2 u(β)"
        return (f"{axis} β = {100 * self.coeff_per_k[axis]:+.3f} ± {100 * self.u_coeff_per_k[axis]:.3f} %/K over a "
                f"{self.span_k[axis]:.2g} K span, {state}; where not applied, U carries a drift of up to "
                f"{100 * bound:.3g} %/K ({source})")

    def to_dict(self) -> dict[str, Any]:
        return {"coeff_per_k": dict(self.coeff_per_k), "u_coeff_per_k": dict(self.u_coeff_per_k),
                "reference_k": dict(self.reference_k), "n_loops": self.n_loops, "span_k": dict(self.span_k)}

    @classmethod
    def from_dict(cls, d: Any) -> ThermalDrift:
        try:
            vals = {key: {ax: float(d[key][ax]) for ax in AXES}
                    for key in ("coeff_per_k", "u_coeff_per_k", "reference_k", "span_k")}
            n = int(d["n_loops"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"fit.thermal: malformed {d!r}: {exc}") from exc
        if not all(np.isfinite(v) for sub in vals.values() for v in sub.values()) or any(
                v < 0 for v in vals["u_coeff_per_k"].values()):
            raise DataError(f"fit.thermal: needs finite values and u_coeff_per_k >= 0, got {d!r}")
        return cls(vals["coeff_per_k"], vals["u_coeff_per_k"], vals["reference_k"], n, vals["span_k"])


def combine_axes(terms: Sequence[tuple[Any, bool]], directions: Sequence[int] | None = None) -> Any:
    """The ``thermal`` component from the axes' terms (in kg, each ``(term, applied)``; floats or arrays alike).

    Where β is applied a term is β's own uncertainty: the two regressions rest on each axis's own noise, so their
    errors are independent and add in quadrature. Where β is not applied a term bounds the uncorrected drift, and
    the two drifts are not independent: one mechanism (the drives' torque estimate with motor temperature) over the
    same warming, so they may add in eq. 21 as well as cancel. Each axis's drift lies in an interval: ±term where
    the campaign does not resolve β's sign, and from 0 to the term on the side the data show where it does
    (``directions``: per term the sign of that axis's drift in the mass, +1 or −1; 0 or None: either sign; the drift
    keeps its sign beyond the span, as a drift that is monotone in temperature does). The bound on their sum is the
    larger end of the sum of the intervals: the linear sum where no sign is resolved (the worst case, at most √2
    above quadrature), the larger term where two resolved drifts pull the mass opposite ways. That bound adds in
    quadrature with any applied axis's term."""
    dirs = [0] * len(terms) if directions is None else list(directions)
    if len(dirs) != len(terms):
        raise ValueError(f"combine_axes: {len(dirs)} directions for {len(terms)} terms")
    low, high = np.float64(0.0), np.float64(0.0)
    for (t, applied), d in zip(terms, dirs, strict=True):
        if applied:
            continue
        low = low - (np.abs(t) if d <= 0 else 0.0)
        high = high + (np.abs(t) if d >= 0 else 0.0)
    bound = np.maximum(-low, high)
    return np.sqrt(bound**2 + sum((np.square(t) for t, applied in terms if applied), start=np.float64(0.0)))


def fit_axis(readings_nm: Sequence[np.ndarray], temps_k: Sequence[np.ndarray]) -> tuple[float, float, float]:
    """β (1/K), u(β) and the temperature span of one axis from per-point loop readings and temperatures.

    Regression through the origin of ``M_ij − M̄_i`` on ``M̄_i·(T_ij − T̄_i)``; the residual variance has
    ``N − P − 1`` degrees of freedom (N loops, P point means, β)."""
    xs, ys = [], []
    for r, t in zip(readings_nm, temps_k, strict=True):
        r, t = np.asarray(r, float), np.asarray(t, float)
        if r.size < 2:
            continue
        xs.append(r.mean() * (t - t.mean()))
        ys.append(r - r.mean())
    if not xs:
        raise DataError("thermal drift: no calibration point has two loops")
    x, y = np.concatenate(xs), np.concatenate(ys)
    sxx = float(x @ x)
    dof = x.size - len(xs) - 1
    if sxx <= 0 or dof < 1:
        raise DataError("thermal drift: the loops' motor temperatures do not vary within the points")
    beta = float(x @ y) / sxx
    res = y - beta * x
    span = float(max(np.ptp(np.asarray(t, float)) for t in temps_k if np.size(t) >= 2))  # max − min within a point
    return beta, float(np.sqrt(float(res @ res) / dof / sxx)), span


def fit(readings_nm: dict[str, Sequence[np.ndarray]], temps_k: dict[str, Sequence[np.ndarray]]) -> ThermalDrift:
    """:class:`ThermalDrift` of A3 and A5 from a campaign's per-point loop readings (raw, after pre-processing, Nm)
    and motor temperatures (K); the reference is the mean temperature over every loop."""
    coeff, u, ref, span = {}, {}, {}, {}
    for ax in AXES:
        coeff[ax], u[ax], span[ax] = fit_axis(readings_nm[ax], temps_k[ax])
        ref[ax] = float(np.mean(np.concatenate([np.asarray(t, float) for t in temps_k[ax]])))
    n = int(sum(np.size(t) for t in temps_k["A3"]))
    return ThermalDrift(coeff, u, ref, n, span)
