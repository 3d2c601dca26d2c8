"""Centre of gravity of a flange payload from static axis torques (pure numpy/scipy), issue #14.

* :func:`cog_paper`: the paper's lever system (eq. 5–7). With the mass known (eq. 4/15), the linear moment gives
  the lever ``a`` along the arm, the torsional moment at 0° gives ``c``, and at 90° (rotated about ``a``) ``b``.
* :func:`cog_poses`: the static poses of a scheme. ``paper`` is eq. 5–7's 0°/90°. ``full`` is A6 at
  0/90/180/270°, A5 ±45°, and A4 ±90° with A5 +45°. A4 and A6 always enter a pose from below.
* The per-axis gain K(x) of the payload torque (:class:`~rgse_daemon.pipeline.axis_gain.AxisGain`) comes from the
  torsional calibration campaign (:func:`rgse_daemon.pipeline.torsion.fit_torsional`).
* :func:`estimate_cog_gls`: static holding torques are linear in θ = [m, m·c] (``kinematics.gravity_regressor``).
  So K⁻¹ of the bias-corrected readings over all poses gives the DuT's m·c by generalised least squares, with the
  mass fixed from the mass run and a reading offset per axis for the DuT's mounting. U per coordinate adds K and the
  mass. :func:`to_dut_frame` rotates the result into the DuT's frame.

Torques are the controller's holding torques (sign as in ``rgse_daemon.kinematics``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline.axis_gain import AxisGain


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


# ---------------------------------------------------------------------------------------------------------------------
# Pose schemes of a mass-properties run
# ---------------------------------------------------------------------------------------------------------------------
SCHEMES = ("paper", "full", "lever")

#: Tilts of the "full" scheme (deg), relative to the measurement pose: (name, ΔA4, ΔA5, ΔA6).
#: A6 at 0/90/180/270° puts each flange-transverse CoG coordinate under the A4/A6 torque twice with opposite signs
#: (a constant per-axis offset separates from it); A5 ±45° changes the lever of the flange-axial coordinate cz on
#: A5 (cos 45°), and A4 ±90° with A5 +45° puts cz under the torsional axis A4 (sin 45°), whose gain is near 1.
_FULL_TILTS: tuple[tuple[str, float, float, float], ...] = (
    ("meas", 0.0, 0.0, 0.0),
    ("A6+90", 0.0, 0.0, 90.0),
    ("A6+180", 0.0, 0.0, 180.0),
    ("A6+270", 0.0, 0.0, 270.0),
    ("A5+45", 0.0, 45.0, 0.0),
    ("A5-45", 0.0, -45.0, 0.0),
    ("A4+90/A5+45", 90.0, 45.0, 0.0),
    ("A4-90/A5+45", -90.0, 45.0, 0.0),
)
_PAPER_TILTS: tuple[tuple[str, float, float, float], ...] = (("meas", 0.0, 0.0, 0.0), ("A6+90", 0.0, 0.0, 90.0))


@dataclass(frozen=True)
class CogPose:
    """One static pose of a mass-properties run: its name (e.g. ``"meas"``, ``"A6+90"``) and A1..A6 in deg."""

    name: str
    q_deg: tuple[float, ...]
    q_approach_deg: tuple[float, ...] = ()
    """Where the last motion into the pose starts: A4 and A6 ``APPROACH_DEG`` below their target, so that both
    axes always arrive from the same side (friction hysteresis, see :func:`cog_poses`); () = no such rule."""


#: A4 and A6 arrive at every pose from this many degrees below it (A5's last motion is the brake-release move's
#: way back, the same in every pose).
APPROACH_DEG = 5.0


def cog_poses(measurement_pose_deg: Sequence[float], scheme: str = "full") -> list[CogPose]:
    """The static poses of a CoG scheme around the measurement pose, in the order they are measured.

    ``"paper"``: eq. 5–7's scheme, the measurement pose (A5 gives the lever a, A6 the offset c) and A6 turned by 90°
    (A6 gives b). ``"lever"``: the paper's poses and the multi-pose mass's lever poses (the robot's
    ``multipose_a3_deg``: A3 turned, A5 turned back, :mod:`rgse_daemon.pipeline.multipose`). ``"full"``: A6 at
    0/90/180/270°, A5 tilted ±45° and A4 ±90° with A5 +45° (see ``_FULL_TILTS``).
    Every pose lies within the axis ranges (DataError otherwise). A plan moves to ``q_approach_deg`` and then to
    ``q_deg`` (then the brake-release move), in the calibration campaign as in the properties run: every axis
    arrives at each pose from the same side in both, so the friction hysteresis cancels in the bias-corrected
    torque.
    """
    tilts = {"paper": _PAPER_TILTS, "full": _FULL_TILTS, "lever": _PAPER_TILTS}.get(scheme)
    if tilts is None:
        raise DataError(f"unknown CoG scheme {scheme!r}; use one of {', '.join(SCHEMES)}")
    turns = [(name, 0.0, d4, d5, d6) for name, d4, d5, d6 in tilts]
    if scheme == "lever":  # the multi-pose mass's lever poses (issue #35): A3 turned, A5 against it
        # (names as pipeline.multipose.pose_name gives them)
        turns += [(f"A3{d:+g}", d, 0.0, -d, 0.0) for d in robots.active().multipose_a3_deg if d != 0.0]
    base = np.asarray(measurement_pose_deg, dtype=float)
    if base.shape != (6,) or not np.all(np.isfinite(base)):
        raise DataError(f"measurement pose must be six finite angles A1..A6 (deg), got {measurement_pose_deg!r}")
    out = []
    for name, d3, d4, d5, d6 in turns:
        q = base + np.array([0.0, 0.0, d3, d4, d5, d6])
        if not kin.within_limits(q):
            raise DataError(f"CoG pose {name} {q.tolist()} is outside the axis ranges")
        approach = q - np.array([0.0, 0.0, 0.0, APPROACH_DEG, 0.0, APPROACH_DEG])
        if not kin.within_limits(approach):
            raise DataError(f"CoG pose {name}: its approach {approach.tolist()} is outside the axis ranges")
        out.append(CogPose(name, tuple(float(v) for v in q), tuple(float(v) for v in approach)))
    return out


# ---------------------------------------------------------------------------------------------------------------------
# The estimator: weighted least squares over poses, mass fixed, with its full uncertainty budget
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseTorques:
    """Bias-corrected readings of one pose: r = reading − bias (Nm, A1..A6, NaN where absent), their standard
    uncertainty from the trace (u_reading) and from the bias (u_bias)."""

    name: str
    q_deg: tuple[float, ...]
    r_nm: tuple[float, ...]
    u_reading_nm: tuple[float, ...]
    u_bias_nm: tuple[float, ...]


@dataclass(frozen=True)
class CogFit:
    """DuT CoG in the flange frame (m), its covariance (m²) split by source, and diagnostics."""

    cog_m: np.ndarray
    cov_m2: np.ndarray
    cov_parts_m2: dict[str, np.ndarray]
    offsets_nm: dict[str, float]
    residual_nm: np.ndarray
    chi2_red: float
    n_equations: int
    fitted_offsets: bool
    outside_range: tuple[str, ...]


def _design(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], params: dict[int, np.ndarray],
            offsets_nm: dict[int, float], g_m_s2: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows of the regressor, payload torques x = K⁻¹(r − o) with the current reading offsets o, their variance,
    the axis of each row, and dx/do = 1/K'(x)."""
    rows, xs, var, axis_of, dxdo = [], [], [], [], []
    for p in poses:
        y_full = kin.gravity_regressor(p.q_deg, g_m_s2)
        for ax, gain in gains.items():
            r = p.r_nm[ax - 1]
            if not np.isfinite(r):
                continue
            x = float(gain.payload_torque_nm(np.array([r - offsets_nm.get(ax, 0.0)]), params[ax])[0])
            slope = float(gain.slope(np.array([x]), params[ax])[0])
            rows.append(y_full[ax - 1])
            xs.append(x)
            var.append((p.u_reading_nm[ax - 1] ** 2 + p.u_bias_nm[ax - 1] ** 2 + gain.u_fit_nm**2) / slope**2)
            axis_of.append(ax)
            dxdo.append(1.0 / slope)
    return np.array(rows).reshape(-1, 4), np.array(xs), np.array(var), np.array(axis_of), np.array(dxdo)


@dataclass(frozen=True)
class _Gls:
    theta: np.ndarray
    cov_theta: np.ndarray
    design: np.ndarray
    b: np.ndarray
    cov_obs: np.ndarray
    axis_of: np.ndarray
    axes: list[int]
    x_nm: np.ndarray
    offsets_nm: dict[int, float]


def _gls(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], params: dict[int, np.ndarray],
         total_mass_kg: float, known_moment_kgm: np.ndarray, fit_offsets: bool, g_m_s2: float) -> _Gls:
    """GLS for the unknown first moment m·c (kg·m) of the DuT, and, when fitted, a reading offset o_i per axis
    (r = K(x) + o_i: the offset is in the reading, so it enters x-space as o/K'(x); solved by a few Gauss-Newton
    steps, each re-inverting K at r − o)."""
    offsets: dict[int, float] = {}
    for _ in range(4 if fit_offsets else 1):
        y_mat, x, var, axis_of, dxdo = _design(poses, gains, params, offsets, g_m_s2)
        if len(x) == 0:
            raise DataError("CoG: no usable axis torques")
        axes = sorted(set(axis_of.tolist()))
        b = x - y_mat[:, 0] * total_mass_kg - y_mat[:, 1:] @ known_moment_kgm
        design = y_mat[:, 1:]
        cov_obs = np.diag(var)
        if fit_offsets:
            design = np.hstack([design, (axis_of[:, None] == np.array(axes)[None, :]) * dxdo[:, None]])
        else:
            # a mounting's offset is the same in every pose: correlated within an axis
            for ax in axes:
                sel = axis_of == ax
                u = gains[ax].u_point_nm * dxdo[sel]
                cov_obs[np.ix_(sel, sel)] += np.outer(u, u)
        if design.shape[0] < 3 or not _well_posed(design[:, :3]):
            rank = np.linalg.matrix_rank(design[:, :3]) if design.shape[0] else 0
            raise DataError(f"CoG: the poses do not determine all three CoG coordinates (rank {rank} of 3 from "
                            f"{design.shape[0]} axis torques); use a scheme that turns A6 and tilts A4/A5")
        if fit_offsets and (design.shape[0] < design.shape[1] or not _well_posed(
                np.hstack([design[:, :3], (axis_of[:, None] == np.array(axes)[None, :]).astype(float)]))):
            raise DataError("CoG: these poses cannot tell a per-axis reading offset from the CoG")
        w = np.linalg.inv(cov_obs)
        cov_theta = np.linalg.inv(design.T @ w @ design)
        theta = cov_theta @ design.T @ w @ b
        if fit_offsets:
            step = dict(zip(axes, theta[3:], strict=True))
            offsets = {ax: offsets.get(ax, 0.0) + float(step[ax]) for ax in axes}
            if max(abs(v) for v in step.values()) < 1e-9:
                break
    if fit_offsets:  # the last step's offsets are increments: report the totals, b and theta at convergence
        theta = np.concatenate([theta[:3], [offsets[ax] for ax in axes]])
    return _Gls(theta, cov_theta, design, b, cov_obs, axis_of, axes, x, offsets)


#: Smallest ratio of the smallest to the largest singular value of a (column-normalised) design that counts as
#: determined: below it the poses leave a combination of the unknowns to the noise (e.g. A6 turns alone and the
#: flange-axis coordinate against the A3/A5 offsets).
WELL_POSED_RATIO = 1e-3


def _well_posed(design: np.ndarray) -> bool:
    norms = np.linalg.norm(design, axis=0)
    if design.shape[0] < design.shape[1] or np.any(norms == 0):
        return False
    sv = np.linalg.svd(design / norms, compute_uv=False)
    return bool(sv[-1] / sv[0] > WELL_POSED_RATIO)


def estimate_cog_gls(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], *, dut_mass_kg: float,
                     u_dut_mass_kg: float, fixture_mass_kg: float, fixture_cog_m: Sequence[float],
                     fit_offsets: bool | None = None, g_m_s2: float = kin.G_PAPER_M_S2) -> CogFit:
    """CoG of a DuT (flange frame, m) from bias-corrected readings in several poses, with the mass fixed.

    Model per pose p and axis i (eq. 5–7 generalised to any pose, docs/controller.md §7):
    r_pi = K_i(Y_pi · [m_DuT + m_fix, m_fix·c_fix + m_DuT·c]) (+ o_i, a reading offset of this mounting).
    Generalised least squares for m_DuT·c with the observation covariance (trace noise, bias, and, when the offsets
    are not fitted, the calibration's per-mounting scatter, fully correlated over the poses of an axis). The
    covariance of c adds, by first-order propagation (numerical Jacobians): the K parameters of every axis and the
    mass. When the fit leaves more scatter than the inputs explain (reduced χ² > 1) the noise part is scaled by it.
    ``fit_offsets``: None fits them when the poses determine them with at least two equations to spare.
    """
    if not dut_mass_kg > 0:
        raise DataError(f"CoG: DuT mass must be > 0 kg, got {dut_mass_kg}")
    if not gains:
        raise DataError("CoG: no axis has a torque calibration")
    params = {ax: np.asarray(g.params, dtype=float) for ax, g in gains.items()}
    known = fixture_mass_kg * np.asarray(fixture_cog_m, dtype=float)
    total = dut_mass_kg + fixture_mass_kg
    if fit_offsets is None:
        n_rows = sum(int(np.isfinite(p.r_nm[ax - 1])) for p in poses for ax in gains)
        n_axes = len({ax for p in poses for ax in gains if np.isfinite(p.r_nm[ax - 1])})
        fit_offsets = n_rows >= 3 + n_axes + 2
        if fit_offsets:
            try:
                _gls(poses, gains, params, total, known, True, g_m_s2)
            except DataError:
                fit_offsets = False
    sol = _gls(poses, gains, params, total, known, fit_offsets, g_m_s2)
    resid = sol.b - sol.design[:, :3] @ sol.theta[:3]  # b already has the fitted offsets removed (x = K⁻¹(r − o))
    dof = len(sol.b) - sol.design.shape[1]
    w = np.linalg.inv(sol.cov_obs)
    chi2_red = float(resid @ w @ resid / dof) if dof > 0 else float("nan")
    scale = max(chi2_red, 1.0) if dof > 0 else 1.0
    cog = sol.theta[:3] / dut_mass_kg
    cov_noise = sol.cov_theta[:3, :3] * scale / dut_mass_kg**2

    def cog_with(p: dict[int, np.ndarray], m: float) -> np.ndarray:
        return _gls(poses, gains, p, m + fixture_mass_kg, known, fit_offsets, g_m_s2).theta[:3] / m

    # calibration (K) term: along the eigenvectors of each axis' parameter covariance
    cov_k = np.zeros((3, 3))
    for ax, g in gains.items():
        vals, vecs = np.linalg.eigh(np.asarray(g.covariance, dtype=float) * g.student_factor())
        for val, vec in zip(vals, vecs.T, strict=True):
            if val <= 0:
                continue
            step = np.sqrt(val) * vec
            col = (cog_with({**params, ax: params[ax] + step}, dut_mass_kg)
                   - cog_with({**params, ax: params[ax] - step}, dut_mass_kg)) / 2.0
            cov_k += np.outer(col, col)
    cov_m = np.zeros((3, 3))
    if u_dut_mass_kg > 0:
        col = (cog_with(params, dut_mass_kg + u_dut_mass_kg) - cog_with(params, dut_mass_kg - u_dut_mass_kg)) / 2.0
        cov_m = np.outer(col, col)
    outside = []
    for ax in sol.axes:
        lo, hi = gains[ax].torque_range_nm
        xs = sol.x_nm[sol.axis_of == ax]
        margin = 0.1 * (hi - lo)
        if np.any(xs < lo - margin) or np.any(xs > hi + margin):
            outside.append(f"A{ax}")
    offsets = {f"A{ax}": v for ax, v in sol.offsets_nm.items()}
    parts = {"noise": cov_noise, "calibration": cov_k, "mass": cov_m}
    return CogFit(cog, cov_noise + cov_k + cov_m, parts, offsets, resid, chi2_red, len(sol.b), fit_offsets,
                  tuple(outside))


def kuka_rotation(abc_deg: Sequence[float]) -> np.ndarray:
    """R = Rz(A)·Ry(B)·Rx(C) of KUKA angles (deg), intrinsic Z-Y-X: the columns are the frame's axes in the parent
    frame (``kinematics.kuka_abc_deg`` is its inverse)."""
    return Rotation.from_euler("ZYX", np.asarray(abc_deg, dtype=float), degrees=True).as_matrix()


def to_dut_frame(cog_flange_m: np.ndarray, cov_flange_m2: np.ndarray, origin_flange_m: Sequence[float],
                 abc_deg: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """CoG and its covariance in the DuT frame: c_DuT = Rᵀ (c − o), Σ_DuT = Rᵀ Σ R."""
    rot = kuka_rotation(abc_deg)
    c = rot.T @ (np.asarray(cog_flange_m, dtype=float) - np.asarray(origin_flange_m, dtype=float))
    return c, rot.T @ cov_flange_m2 @ rot
