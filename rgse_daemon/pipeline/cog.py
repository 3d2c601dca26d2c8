"""Centre of gravity of a flange payload from static axis torques (pure numpy).

Two methods:

* :func:`cog_paper` — the paper's lever system (eq. 5–7): with the mass known (eq. 4/15), the linear moment gives
  the lever ``a`` along the arm, the torsional moment at 0° gives ``c`` and at 90° (rotated about ``a``) gives ``b``.
* :func:`estimate_cog` — better: static holding torques are linear in θ = [m, m·cx, m·cy, m·cz]
  (``kinematics.gravity_regressor``), so several static poses with varied A4/A5/A6 give mass and CoG in the flange
  frame by weighted least squares, with a covariance. Give it bias-corrected torques: each observation carries the
  reading without the payload in the same pose (M0, eq. 13–14), so the arm's own torque cancels.

Torques are the controller's holding torques (sign as in ``rgse_daemon.kinematics``) and should be calibrated: an
axis whose gain is off by k % scales its equations by k %; ``axis_gain`` divides it out, and
:func:`axis_gains_from_reference` measures it with a known reference load in the same poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon.errors import DataError


@dataclass(frozen=True)
class Observation:
    """One static pose: axis angles A1..A6 (deg), mean torques A1..A6 (Nm, NaN = not measured) with the payload, and
    the same without it (bias, Nm). ``sigma_nm``: standard error of each torque mean, if known (NaN = unknown)."""

    q_deg: Sequence[float]
    torque_nm: Sequence[float]
    bias_nm: Sequence[float]
    sigma_nm: Sequence[float] | None = None


@dataclass(frozen=True)
class CogEstimate:
    """Mass (kg), CoG in the flange frame (m), their covariances and the fit's residuals."""

    mass_kg: float
    cog_m: np.ndarray
    theta: np.ndarray
    cov_theta: np.ndarray
    cov_cog_m2: np.ndarray
    u_mass_kg: float
    u_cog_m: np.ndarray
    residual_rms_nm: float
    n_equations: int

    def as_dict(self) -> dict:
        return {
            "mass_kg": self.mass_kg,
            "cog_m": self.cog_m.tolist(),
            "u_mass_kg": self.u_mass_kg,
            "u_cog_m": self.u_cog_m.tolist(),
            "residual_rms_nm": self.residual_rms_nm,
            "n_equations": self.n_equations,
        }


def cog_paper(
    mass_kg: float,
    m_linear_0_nm: float,
    m_torsion_0_nm: float,
    m_torsion_90_nm: float,
    g_m_s2: float = kin.G_PAPER_M_S2,
) -> np.ndarray:
    """CoG levers (a, b, c) in m by the paper's eq. 5–7.

    ``m_linear_0_nm``: linear moment M_2 at the reference axis (e.g. A5, bias removed), ``m_torsion_0_nm``: the
    torsional moment M_T (A4 or A6) in the same pose, ``m_torsion_90_nm``: M_T after turning the body 90° about a.
    """
    if not mass_kg > 0:
        raise DataError(f"cog_paper: mass must be > 0 kg, got {mass_kg}")
    w = mass_kg * g_m_s2
    a = m_linear_0_nm / w  # eq. 5
    c = m_torsion_0_nm / w  # eq. 6
    b = m_torsion_90_nm / w  # eq. 7
    return np.array([a, b, c])


def _stack(
    observations: Sequence[Observation], axes: Sequence[int], axis_gain: Sequence[float] | None, g_m_s2: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gains = np.ones(6) if axis_gain is None else np.asarray(axis_gain, dtype=float)
    if gains.shape != (6,) or np.any(gains <= 0) or not np.all(np.isfinite(gains)):
        raise DataError("axis_gain must be six positive finite factors (A1..A6)")
    rows, ys, sig = [], [], []
    idx = np.asarray(axes, dtype=int) - 1
    for k, ob in enumerate(observations):
        tau = np.asarray(ob.torque_nm, dtype=float)
        bias = np.asarray(ob.bias_nm, dtype=float)
        if tau.shape != (6,) or bias.shape != (6,):
            raise DataError(f"observation {k}: torque_nm and bias_nm need six entries (A1..A6)")
        s = np.full(6, np.nan) if ob.sigma_nm is None else np.asarray(ob.sigma_nm, dtype=float)
        y_full = kin.gravity_regressor(ob.q_deg, g_m_s2)
        for i in idx:
            if np.isfinite(tau[i]) and np.isfinite(bias[i]):
                rows.append(y_full[i])
                ys.append((tau[i] - bias[i]) / gains[i])
                sig.append(s[i] / gains[i])
    return np.array(rows).reshape(-1, 4), np.array(ys), np.array(sig)


def estimate_cog(
    observations: Sequence[Observation],
    axes: Sequence[int] = (2, 3, 4, 6),
    mass_kg: float | None = None,
    axis_gain: Sequence[float] | None = None,
    g_m_s2: float = kin.G_PAPER_M_S2,
) -> CogEstimate:
    """Mass and CoG (flange frame) by least squares over several static poses.

    Parameters
    ----------
    observations : poses with payload torques and biases (Nm), see :class:`Observation`.
    axes : which axes' equations to use (1..6). A1 carries no gravity torque while its axis is vertical. The default
        leaves out A5: its gain is strongly torque-dependent (Table 1: +6 % at 60 Nm, +19 % at 600 Nm), so a single
        gain factor biases cz by ~1 cm; add A5 once its torques are calibrated with a K(M) function.
    mass_kg : if given (e.g. from eq. 15), the mass is fixed and only m·c is fitted.
    axis_gain : per-axis factor measured/true (A1..A6) to divide out, e.g. from :func:`axis_gains_from_reference`.
    g_m_s2 : gravity used to build the regressor (the paper's 9.81 by default).

    Equations are weighted by 1/σ² when every observation gives ``sigma_nm``; otherwise each axis gets the variance
    of its own residuals (two passes), so a noisy axis does not drown a quiet one. The covariance of the CoG follows
    from that of θ by first-order propagation of c = θ[1:]/θ[0].
    """
    if not observations:
        raise DataError("estimate_cog: no observations")
    y_mat, y, sig = _stack(observations, axes, axis_gain, g_m_s2)
    unknowns = 3 if mass_kg is not None else 4
    if len(y) < unknowns + 1:
        raise DataError(f"estimate_cog: {len(y)} usable equations for {unknowns} unknowns")
    if mass_kg is not None:
        y = y - y_mat[:, 0] * mass_kg
        design = y_mat[:, 1:]
    else:
        design = y_mat
    if np.all(np.isfinite(sig)) and np.all(sig > 0):
        weights = 1.0 / sig**2
        theta, cov = _wls(design, y, weights, scale_by_residual=False)
    else:
        # per-axis variance from a first unweighted pass
        row_axis = _row_axes(observations, axes)
        theta0, _ = _wls(design, y, np.ones_like(y), scale_by_residual=True)
        r = y - design @ theta0
        var = np.ones_like(y)
        for a in np.unique(row_axis):
            sel = row_axis == a
            v = float(np.mean(r[sel] ** 2)) if sel.sum() > 1 else 0.0
            var[sel] = max(v, 1e-6)
        theta, cov = _wls(design, y, 1.0 / var, scale_by_residual=True)
    residual = y - design @ theta
    if mass_kg is not None:
        full = np.concatenate([[mass_kg], theta])
        cov_full = np.zeros((4, 4))
        cov_full[1:, 1:] = cov
    else:
        full, cov_full = theta, cov
    m = full[0]
    if not m > 0:
        raise DataError(f"estimate_cog: fitted mass {m:.3f} kg is not positive; check signs, biases and poses")
    cog = full[1:] / m
    jac = np.zeros((3, 4))
    jac[:, 0] = -full[1:] / m**2
    jac[:, 1:] = np.eye(3) / m
    cov_cog = jac @ cov_full @ jac.T
    return CogEstimate(
        mass_kg=float(m),
        cog_m=cog,
        theta=full,
        cov_theta=cov_full,
        cov_cog_m2=cov_cog,
        u_mass_kg=float(np.sqrt(max(cov_full[0, 0], 0.0))),
        u_cog_m=np.sqrt(np.maximum(np.diag(cov_cog), 0.0)),
        residual_rms_nm=float(np.sqrt(np.mean(residual**2))),
        n_equations=len(y),
    )


def _row_axes(observations: Sequence[Observation], axes: Sequence[int]) -> np.ndarray:
    out = []
    for ob in observations:
        tau = np.asarray(ob.torque_nm, dtype=float)
        bias = np.asarray(ob.bias_nm, dtype=float)
        out.extend(a for a in axes if np.isfinite(tau[a - 1]) and np.isfinite(bias[a - 1]))
    return np.array(out)


def _wls(
    design: np.ndarray, y: np.ndarray, weights: np.ndarray, scale_by_residual: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares; returns (θ, covariance). With ``scale_by_residual`` the covariance is scaled by the
    reduced χ² (the weights are then only relative)."""
    w = np.sqrt(weights)
    a = design * w[:, None]
    b = y * w
    theta, *_ = np.linalg.lstsq(a, b, rcond=None)
    rank = np.linalg.matrix_rank(a)
    if rank < design.shape[1]:
        raise DataError(
            f"estimate_cog: the poses do not determine all {design.shape[1]} parameters (rank {rank}); vary A4/A5/A6"
        )
    cov = np.linalg.inv(a.T @ a)
    if scale_by_residual:
        dof = max(len(y) - design.shape[1], 1)
        chi2 = float(np.sum((b - a @ theta) ** 2)) / dof
        cov = cov * chi2
    return theta, cov


def axis_gains_from_reference(
    observations: Sequence[Observation],
    mass_kg: float,
    cog_m: Sequence[float],
    g_m_s2: float = kin.G_PAPER_M_S2,
) -> np.ndarray:
    """Per-axis gain (measured/true, A1..A6) from a reference load of known mass and CoG measured in the same poses.

    The paper's advice for the torsional axes (§3: "a similar calibration on one of the torsional axes"): the gain of
    axis i is the least-squares slope of measured against predicted payload torque over all poses. Axes without a
    usable prediction (torque never above 1 Nm) get 1.
    """
    theta = mass_kg * np.array([1.0, *np.asarray(cog_m, dtype=float)])
    num = np.zeros(6)
    den = np.zeros(6)
    for ob in observations:
        pred = kin.gravity_regressor(ob.q_deg, g_m_s2) @ theta
        meas = np.asarray(ob.torque_nm, dtype=float) - np.asarray(ob.bias_nm, dtype=float)
        ok = np.isfinite(meas)
        num[ok] += pred[ok] * meas[ok]
        den[ok] += pred[ok] ** 2
    gains = np.ones(6)
    usable = den > 1.0
    gains[usable] = num[usable] / den[usable]
    return gains
