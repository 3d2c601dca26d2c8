"""Inertia of a flange-mounted payload from its wrist torques during motion (issue #15).

The payload is a rigid body on the flange with the ten inertial parameters of the Newton–Euler equations, in the
flange frame (KUKA's $FLANGE, m, kg)::

    π = [m, m·cx, m·cy, m·cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]      (I about the flange origin, kg·m²)

and the torque it asks of the drive of axis i (holding-torque sign of :mod:`rgse_daemon.kinematics`) is linear in π::

    f = m·a_O + α × m·c + ω × (ω × m·c)              (force at the flange origin, a_O includes −g: eq. N–E)
    n = I_O·α + ω × (I_O·ω) + m·c × a_O               (moment about the flange origin)
    τ_i = e_i · n + h_i · f = Y_i(q, q̇, q̈) · π          (e_i = axis direction, h_i = e_i × (p_O − o_i), flange frame)

(:func:`payload_regressor`; the static part equals ``kinematics.gravity_regressor``.)

Identification (:func:`identify`): mass and CoG come from the static measurement and stay fixed; what is estimated
is the six parameters of I_O. The robot's own wrist dynamics (link inertias, rotor inertias, friction of the empty
wrist, torque ripple with position) are not modelled: they are removed by a *tare* run, the same excitation program
run with the fixture only, and the identification works on the difference DuT − tare, stroke by stroke, aligned on
the commanded motion (:func:`difference`). What the DuT adds to friction (Coulomb friction grows with load) and the
new mounting's torque offset stay in the difference: per wrist axis a Coulomb step ``Δfc·sign(q̇)``, a viscous term
``Δfv·q̇`` and an offset ``Δb`` are estimated with the inertia in one weighted least-squares fit. The constant-speed
stretches of the strokes carry the friction and offsets (there q̈ = 0), the acceleration stretches the inertia; they
are fitted together because at constant speed the gyroscopic term ω × (I·ω) still depends on the products of
inertia. Samples near standstill are left out (Stribeck friction and the static friction hysteresis are not
modelled; the sign of q̇ is not defined there), and so are samples near the corners of the profile, where q̈ steps:
a step sampled at the trace rate has no unique smoothed value, and torque and q̈ disagree there by ~3 % of the
inertial torque (found on noise-free synthetic data).

Velocities and accelerations come from the positions (``Istposition``) by Gaussian derivative filters
(``scipy.ndimage.gaussian_filter1d``, σ = ``SMOOTH_SIGMA_S``, then central differences), and the torques are
smoothed by the *same* Gaussian. Not Savitzky–Golay: its derivative kernels are not the derivatives of its smoothing
kernel, so at the corners of a trapezoidal profile (where q̈ steps) the smoothed torque and the q̈ from the
positions disagree (with the corners kept, it biased the moments by up to 10 % on noise-free synthetic data). A
Gaussian commutes with differentiation (G * D²q = D²(G * q)), so torque and regressor see exactly the same time
response; σ = 20 ms is short against the ramps (≥ ``excitation.MIN_RAMP_S``) and spans 5 samples at 4 ms.

Uncertainty: the samples within a stroke are strongly correlated (the same drift, the same friction state, the
smoothing), so a per-sample residual variance would be far too optimistic. The covariance of every parameter is a
*stroke bootstrap*: strokes are resampled with replacement within strata (the strokes of one axis in one direction)
and the fit repeated (``N_BOOTSTRAP`` times), which keeps whatever correlation there is inside a stroke. The
principal moments and axes are computed in every replicate, so their U (k = 2) needs no linearisation of the eigen-
decomposition. The torque scale no resampling can see enters axis by axis: each wrist axis' reading is taken
through its own gain curve, whose slope is uncertain on its own (``TorqueCalibration.u_slope_rel_axes``, and the
thermal drift of that axis' reading against the calibration's temperature). A slope error of one axis is not a common
scale of the tensor: the products of inertia are read from how the torques of different axes compare, and for the
wing box of the demo 2 % on A4 or A5 alone moves its I_yz (DuT frame, 0.39 kg·m²) by ~1.5 kg·m². So every bootstrap
replicate adds the fit's linear response to a drawn slope error of each axis (``_axis_scale_sensitivity``). A common
relative scale (``u_gain_rel``: one drive gain for all axes) is added in quadrature to every element.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from rgse_daemon import kinematics as kin

#: The axes whose torques identify the payload: the wrist (A1–A3 carry the arm's large, unmodelled dynamics).
WRIST_AXES: tuple[int, ...] = (4, 5, 6)
#: Names of the six inertia parameters of I (upper triangle, row-wise).
INERTIA_NAMES: tuple[str, ...] = ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
#: Standard deviation (s) of the Gaussian that smooths positions (for q̇, q̈) and torques alike.
SMOOTH_SIGMA_S = 0.02
#: Samples near a corner of the profile (jerk above this fraction of peak |q̈|/σ) are left out.
CORNER_JERK_FRACTION = 0.02
#: Samples with a moving axis slower than this (deg/s) are left out: Stribeck region, sign of q̇ undefined.
MIN_SPEED_DEG_S = 1.0
#: Parameters shared by the wrist axes (I: 6, correction to m·c: 3) and nuisance parameters per axis.
N_SHARED = 9
N_AXIS = 5
#: Motor temperatures within this of their mean (K) over both runs carry no thermal drift to fit: the column
#: ((T − T_ref)·τ) would be rounding noise times the torque and absorb the inertia (seen on a simulator run whose
#: Motortemperatur stayed at one value).
MIN_THERMAL_SPREAD_K = 0.05
#: Bootstrap replicates over strokes.
N_BOOTSTRAP = 400
COVERAGE_K = 2.0
_GRAVITY_DIR = np.array([0.0, 0.0, 1.0])  # τ holds against g: the N–E "acceleration" of the base is +g·ẑ


# --- kinematics, batched ----------------------------------------------------------------------------------------------
def _frames(q_deg: np.ndarray) -> np.ndarray:
    """Base → frame i transforms for N poses, shape (N, 6, 4, 4) (same MDH chain as ``kinematics.joint_frames``;
    batched here because the identification needs it for thousands of samples)."""
    theta = kin.robot_arrays().axis_sign * np.deg2rad(q_deg) + kin.robot_arrays().theta_offset_rad  # (N, 6)
    n = len(theta)
    out = np.empty((n, 6, 4, 4))
    t = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        alpha, a, d = kin.robot_arrays().mdh[i]
        ca, sa = math.cos(alpha), math.sin(alpha)
        ct, st = np.cos(theta[:, i]), np.sin(theta[:, i])
        m = np.zeros((n, 4, 4))
        m[:, 0, 0], m[:, 0, 1], m[:, 0, 3] = ct, -st, a
        m[:, 1, 0], m[:, 1, 1], m[:, 1, 2], m[:, 1, 3] = st * ca, ct * ca, -sa, -sa * d
        m[:, 2, 0], m[:, 2, 1], m[:, 2, 2], m[:, 2, 3] = st * sa, ct * sa, ca, ca * d
        m[:, 3, 3] = 1.0
        t = t @ m
        out[:, i] = t
    return out


def _inertia_map(v: np.ndarray) -> np.ndarray:
    """L(v), shape (N, 3, 6), with I·v = L(v)·[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    zero = np.zeros_like(x)
    return np.stack(
        [
            np.stack([x, y, z, zero, zero, zero], axis=-1),
            np.stack([zero, x, zero, y, z, zero], axis=-1),
            np.stack([zero, zero, x, zero, y, z], axis=-1),
        ],
        axis=1,
    )


def payload_regressor(
    q_deg: np.ndarray, qd_deg_s: np.ndarray, qdd_deg_s2: np.ndarray, g_m_s2: float = kin.G_PAPER_M_S2
) -> np.ndarray:
    """Y, shape (N, 6, 10): drive torques (Nm, A1..A6) of a flange-mounted rigid body are ``Y @ π``.

    ``q_deg``, ``qd_deg_s``, ``qdd_deg_s2``: (N, 6) axis angles, speeds and accelerations (deg, deg/s, deg/s²).
    π as in the module docstring (kg, kg·m, kg·m² about the flange origin, flange frame).
    """
    q = np.atleast_2d(np.asarray(q_deg, float))
    qd = np.deg2rad(np.atleast_2d(np.asarray(qd_deg_s, float)))
    qdd = np.deg2rad(np.atleast_2d(np.asarray(qdd_deg_s2, float)))
    fr = _frames(q)
    n = len(q)
    origins = fr[:, :, :3, 3]  # (N, 6, 3)
    dirs = fr[:, :, :3, 2] * kin.robot_arrays().axis_sign[None, :, None]  # KUKA-positive directions
    # forward recursion (base frame): angular velocity/acceleration of link k, linear acceleration of its origin
    w = np.zeros((n, 3))
    dw = np.zeros((n, 3))
    acc = g_m_s2 * np.broadcast_to(_GRAVITY_DIR, (n, 3)).copy()  # base "accelerates" upwards at g
    o_prev = np.zeros((n, 3))
    for k in range(6):
        r = origins[:, k] - o_prev
        acc = acc + np.cross(dw, r) + np.cross(w, np.cross(w, r))
        dw = dw + dirs[:, k] * qdd[:, k : k + 1] + np.cross(w, dirs[:, k] * qd[:, k : k + 1])
        w = w + dirs[:, k] * qd[:, k : k + 1]
        o_prev = origins[:, k]
    rot = fr[:, 5, :3, :3]  # flange → base
    rt = np.transpose(rot, (0, 2, 1))
    wf = np.einsum("nij,nj->ni", rt, w)
    dwf = np.einsum("nij,nj->ni", rt, dw)
    af = np.einsum("nij,nj->ni", rt, acc)  # flange origin = frame 6 origin
    p_o = fr[:, 5, :3, 3]
    e = np.einsum("nij,nkj->nki", rt, dirs)  # (N, 6, 3) axis directions in flange frame
    h = np.einsum("nij,nkj->nki", rt, np.cross(dirs, p_o[:, None, :] - origins))
    y = np.empty((n, 6, 10))
    y[:, :, 0] = np.einsum("nki,ni->nk", h, af)
    # m·c columns: e·(mc × a) + h·(α × mc) + h·(ω × (ω × mc))
    wh = np.einsum("nki,ni->nk", h, wf)
    ww = np.einsum("ni,ni->n", wf, wf)
    y[:, :, 1:4] = (
        np.cross(af[:, None, :], e)
        + np.cross(h, dwf[:, None, :])
        + wh[:, :, None] * wf[:, None, :]
        - ww[:, None, None] * h
    )
    # I columns: e·(I α) + e·(ω × I ω) = eᵀ L(α) π_I + (e × ω)ᵀ L(ω) π_I
    la, lw = _inertia_map(dwf), _inertia_map(wf)
    y[:, :, 4:] = np.einsum("nki,nij->nkj", e, la) + np.einsum("nki,nij->nkj", np.cross(e, wf[:, None, :]), lw)
    return y


def payload_torques_nm(
    q_deg: np.ndarray,
    qd_deg_s: np.ndarray,
    qdd_deg_s2: np.ndarray,
    pi: Sequence[float],
    g_m_s2: float = kin.G_PAPER_M_S2,
) -> np.ndarray:
    """Drive torques (N, 6) of a flange-mounted body with parameters π (see :func:`payload_regressor`)."""
    return payload_regressor(q_deg, qd_deg_s, qdd_deg_s2, g_m_s2) @ np.asarray(pi, float)


# --- inertia helpers ------------------------------------------------------------------------------------------------
def tensor(p6: Sequence[float]) -> np.ndarray:
    """3×3 symmetric tensor from [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]."""
    xx, xy, xz, yy, yz, zz = (float(v) for v in p6)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def six(t: np.ndarray) -> np.ndarray:
    """[Ixx, Ixy, Ixz, Iyy, Iyz, Izz] of a 3×3 tensor."""
    return np.array([t[0, 0], t[0, 1], t[0, 2], t[1, 1], t[1, 2], t[2, 2]])


def steiner_kgm2(mass_kg: float, c_m: Sequence[float]) -> np.ndarray:
    """m·(|c|²·E − c·cᵀ): what the parallel-axis theorem adds moving I from the CoG to a point at −c from it."""
    c = np.asarray(c_m, float)
    return mass_kg * (float(c @ c) * np.eye(3) - np.outer(c, c))


def body_params(mass_kg: float, cog_flange_m: Sequence[float], inertia_cog_flange_kgm2: np.ndarray) -> np.ndarray:
    """π (10,) of a body from its mass, CoG (flange frame) and inertia about its CoG (flange axes)."""
    c = np.asarray(cog_flange_m, float)
    i_o = np.asarray(inertia_cog_flange_kgm2, float) + steiner_kgm2(mass_kg, c)
    return np.concatenate([[mass_kg], mass_kg * c, six(i_o)])


def dut_rotation(abc_deg: Sequence[float]) -> np.ndarray:
    """DuT → flange rotation from KUKA A, B, C (deg): R = Rz(A)·Ry(B)·Rx(C)."""
    return Rotation.from_euler("ZYX", list(abc_deg), degrees=True).as_matrix()


def principal(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and axes (columns, right-handed, each with a non-negative largest component)."""
    vals, vecs = np.linalg.eigh(0.5 * (t + t.T))
    for j in range(3):
        big = int(np.argmax(np.abs(vecs[:, j])))
        if vecs[big, j] < 0:
            vecs[:, j] = -vecs[:, j]
    if np.linalg.det(vecs) < 0:
        vecs[:, 2] = -vecs[:, 2]
    return vals, vecs


# --- the drive's torque scale -----------------------------------------------------------------------------------
class GainCurve(Protocol):
    """A calibrated reading of one axis: reading r (Nm) for payload torque x (Nm) and its slope dr/dx; odd in x.
    ``rgse_daemon.pipeline.axis_gain.AxisGain`` (CAL.json's torsional section) is one."""

    def reading_nm(self, x_nm: np.ndarray) -> np.ndarray: ...

    def slope(self, x_nm: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class TorqueCalibration:
    """How the drive's torque reading depends on the payload torque: per wrist axis a gain curve (axes without one
    read the torque 1:1), and what is mounted in the tare run (``fixture_pi``: mass, m·c in the flange frame; the
    gain acts on the payload torque of MPA, fixture and DuT together, so the tare's sets the operating point).
    ``u_slope_rel_axes``: per wrist axis the relative standard uncertainty of its curve's slope (the calibration's
    own; independent between axes, propagated axis by axis). ``u_gain_rel``: a relative standard uncertainty common
    to all axes (it scales every inertia alike)."""

    gains: dict[int, GainCurve]
    fixture_pi: tuple[float, float, float, float]
    u_gain_rel: float = 0.0
    u_slope_rel_axes: dict[int, float] = field(default_factory=dict)
    slope_u_rel_at: dict[int, Callable[[float], float]] = field(default_factory=dict)
    """Per wrist axis the relative standard uncertainty of its curve's slope as a function of the payload torque
    (Nm): :func:`identify` takes it at the run's operating point (the payload torque of MPA, fixture and DuT over
    that axis' rows) and it replaces the axis' ``u_slope_rel_axes``."""
    covered_nm: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Per wrist axis the payload torques (min, max, Nm) the calibration covered: an operating point outside them
    reads through an extrapolated slope, which the result's warnings say."""
    calibration_temp_k: tuple[float, ...] | None = None
    """Motor temperatures A1..A6 (K) at which the gain curves were calibrated: with them the scale the fitted thermal
    drift implies between the runs' mean temperature and the calibration's enters U (not corrected)."""
    temp_ref_k: tuple[float, ...] | None = None
    """Motor temperatures A1..A6 (K) the thermal column refers to; None: the runs' mean (the default, and the
    better choice: referred to the calibration's temperature the column is nearly proportional to the DuT's own
    torque at T1 and takes part of the inertia with it; bench/inertia.py: the wing box's middle moment −0.4 % →
    −6.4 % at T1). The reading's scale at the runs' mean temperature against the calibration's stays a bias."""


# --- measured motion ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Stroke:
    """One motion of a run as traced: sample times (s), actual axis angles (N, 6) deg, Istmoment (N, 6) Nm (NaN
    where an axis is not traced), and the commanded angles (N, 6) deg used to align DuT and tare runs."""

    t_s: np.ndarray
    q_deg: np.ndarray
    torque_nm: np.ndarray
    q_cmd_deg: np.ndarray
    tare_torque_nm: np.ndarray | None = None
    """A differenced stroke: the tare's torque that was subtracted (N, 6)."""
    temp_k: np.ndarray | None = None
    """``Motortemperatur`` (N, 6, K), None when not traced."""
    tare_temp_k: np.ndarray | None = None
    """A differenced stroke: the tare's motor temperatures (N, 6, K)."""

    def __post_init__(self) -> None:
        n = len(self.t_s)
        for name in ("q_deg", "torque_nm", "q_cmd_deg", "tare_torque_nm", "temp_k", "tare_temp_k"):
            a = getattr(self, name)
            if a is None:
                continue
            if a.shape != (n, 6):
                raise ValueError(f"stroke: {name} must have shape ({n}, 6), got {a.shape}")


def smooth(values: np.ndarray, period_s: float, deriv: int = 0) -> np.ndarray:
    """Gaussian smoothing along axis 0 (σ = ``SMOOTH_SIGMA_S``), then ``deriv`` central differences (per s).

    The differences act on the smoothed signal (scipy's sampled derivative-of-Gaussian kernels do not sum to zero
    exactly, which leaks the angle itself into q̈); both steps are linear and shift-invariant, so they commute."""
    sigma = SMOOTH_SIGMA_S / period_s
    if len(values) < 8 * sigma:
        raise ValueError(f"a stroke of {len(values)} samples is shorter than the filter (σ = {sigma:.1f} samples)")
    out = gaussian_filter1d(np.asarray(values, float), sigma, axis=0, mode="nearest")
    for _ in range(deriv):
        out = np.gradient(out, period_s, axis=0)
    return out


def split_strokes(q_cmd_deg: np.ndarray, rest_step_deg: float = 1e-6) -> list[slice]:
    """Slices of the samples of each motion: from the last rest sample before the commanded angles leave a pose to
    the first sample where they have arrived (rest: no commanded angle changes by more than ``rest_step_deg``
    between samples)."""
    step = np.abs(np.diff(q_cmd_deg, axis=0)).max(axis=1)
    moving = step > rest_step_deg
    out: list[slice] = []
    i, n = 0, len(moving)
    while i < n:
        if not moving[i]:
            i += 1
            continue
        j = i
        while j < n and moving[j]:
            j += 1
        out.append(slice(i, j + 1))
        i = j
    return out


def _start_time(t_s: np.ndarray, q_cmd_deg: np.ndarray, threshold_deg: float = 0.05) -> float:
    """When the commanded angles have left the start by ``threshold_deg`` (linear interpolation): the same moment
    of the same planned profile in any run, to a fraction of a sample."""
    dist = np.abs(q_cmd_deg - q_cmd_deg[0]).max(axis=1)
    k = int(np.argmax(dist > threshold_deg))
    if k == 0:
        raise ValueError("stroke does not move")
    d0, d1 = dist[k - 1], dist[k]
    return float(t_s[k - 1] + (threshold_deg - d0) / (d1 - d0) * (t_s[k] - t_s[k - 1]))


def difference(dut: Stroke, tare: Stroke) -> Stroke:
    """The DuT stroke with the tare stroke's torque subtracted, the tare resampled on the DuT's time axis after
    aligning both on the commanded motion. Raises ValueError when the strokes are not the same motion."""
    if not np.allclose(dut.q_cmd_deg[0], tare.q_cmd_deg[0], atol=0.05) or not np.allclose(
        dut.q_cmd_deg[-1], tare.q_cmd_deg[-1], atol=0.05
    ):
        raise ValueError("DuT and tare strokes do not start and end at the same commanded angles")
    shift = _start_time(tare.t_s, tare.q_cmd_deg) - _start_time(dut.t_s, dut.q_cmd_deg)
    t = dut.t_s + shift
    inside = (t >= tare.t_s[0]) & (t <= tare.t_s[-1])
    tau = np.full_like(dut.torque_nm, np.nan)
    temp = None if tare.temp_k is None else np.full_like(dut.torque_nm, np.nan)
    for ax in range(6):
        tau[inside, ax] = np.interp(t[inside], tare.t_s, tare.torque_nm[:, ax])
        if temp is not None and tare.temp_k is not None:
            temp[inside, ax] = np.interp(t[inside], tare.t_s, tare.temp_k[:, ax])
    keep = inside
    return Stroke(dut.t_s[keep], dut.q_deg[keep], dut.torque_nm[keep] - tau[keep], dut.q_cmd_deg[keep], tau[keep],
                  None if dut.temp_k is None else dut.temp_k[keep], None if temp is None else temp[keep])


# --- identification -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StrokeData:
    """Rows of one stroke for the fit: per wrist axis the regressor of I and of a correction to m·c (n, 9), the
    per-axis nuisance columns (Coulomb, viscous, offset, load-dependent Coulomb, thermal drift: n, 5) and the
    measured torque minus the known mass/CoG part; ``axis`` (n,) 4..6; ``reading_nm`` (n,) the measured (smoothed,
    tare-differenced) torque itself, which a slope error of the axis' gain curve scales; ``payload_nm`` (n,) the
    payload torque (MPA, fixture and DuT; with a guess of the inertia) at which the axis' gain curve is taken for
    the row: its operating point (the DuT's own without a calibration)."""

    y_inertia: np.ndarray
    y_nuisance: np.ndarray
    torque_nm: np.ndarray
    axis: np.ndarray
    reading_nm: np.ndarray
    payload_nm: np.ndarray


def stroke_rows(
    stroke: Stroke,
    period_s: float,
    mass_kg: float,
    cog_flange_m: Sequence[float],
    g_m_s2: float,
    resting_axes: bool = False,
    calibration: TorqueCalibration | None = None,
    inertia_guess: np.ndarray | None = None,
    temp_ref_k: np.ndarray | None = None,
) -> StrokeData | None:
    """Fit rows of a (differenced) stroke: filtered derivatives, the payload's known gravity/mass part subtracted;
    None when no sample moves fast enough or several axes move (a repositioning move). Rows of a wrist axis come
    from its own motion; ``resting_axes`` adds the reaction torques of the wrist axes that stand still (their
    static friction is not modelled). ``calibration``: see :func:`identify`; ``inertia_guess`` (6,) refines the
    operating point of its gain curves."""
    travel = np.ptp(stroke.q_cmd_deg, axis=0)
    if np.count_nonzero(travel > 1e-6) != 1:
        return None  # repositioning moves of several axes: long and unlike the swings (the bootstrap's clusters)
    q = smooth(stroke.q_deg, period_s)
    qd = smooth(stroke.q_deg, period_s, 1)
    qdd = smooth(stroke.q_deg, period_s, 2)
    tau = smooth(np.nan_to_num(stroke.torque_nm), period_s)
    # the reading's thermal drift (1 + β·ΔT) does not cancel between runs at different motor temperatures: a column
    # ((T − T_ref)·τ)_DuT − ((T − T_ref)·τ)_tare per axis, β estimated (None: not traced). T_ref: where the gain
    # curves hold (else the runs' mean temperature, and the inertia refers to the reading's scale there)
    thermal = None
    if stroke.tare_torque_nm is not None and stroke.temp_k is not None and stroke.tare_temp_k is not None:
        ref = np.asarray(temp_ref_k if temp_ref_k is not None else np.zeros(6), float)
        full = stroke.torque_nm + stroke.tare_torque_nm
        thermal = smooth(np.nan_to_num((stroke.temp_k - ref) * full - (stroke.tare_temp_k - ref)
                                       * stroke.tare_torque_nm), period_s)
    y = payload_regressor(q, qd, qdd, g_m_s2)
    pi_dut = np.concatenate([[mass_kg], mass_kg * np.asarray(cog_flange_m, float)])
    if calibration is None:
        x_fix = np.zeros(y.shape[:2])
        x0 = y[:, :, :4] @ pi_dut
    else:
        x_fix = y[:, :, :4] @ np.asarray(calibration.fixture_pi, float)[:4]
        x0 = x_fix + y[:, :, :4] @ pi_dut
    if inertia_guess is not None:
        x0 = x0 + y[:, :, 4:] @ inertia_guess
    moving = np.abs(qd[:, 3:6]).max(axis=1) > MIN_SPEED_DEG_S
    # corners of the profile (q̈ steps): a sampled step has no unique smoothed value, so torque and q̈ disagree there
    # (from the commanded angles: three derivatives of the measured ones would be noise)
    qdd_cmd = smooth(stroke.q_cmd_deg, period_s, 2)
    jerk = np.abs(np.gradient(qdd_cmd, period_s, axis=0))
    peak = np.abs(qdd_cmd).max(axis=0)
    moving &= ~np.any(jerk > CORNER_JERK_FRACTION * peak / SMOOTH_SIGMA_S, axis=1)
    rows_i, rows_n, axes, taus, readings, payload = [], [], [], [], [], []
    for ax in WRIST_AXES:
        if not np.all(np.isfinite(stroke.torque_nm[:, ax - 1])):
            continue
        j = ax - 1
        ok = moving & (np.abs(qd[:, j]) > MIN_SPEED_DEG_S)
        if resting_axes:
            ok |= moving & (np.abs(stroke.q_cmd_deg[:, j] - stroke.q_cmd_deg[0, j]) < 1e-9)
        if not ok.any():
            continue
        if calibration is None or ax not in calibration.gains:
            slope = np.ones(int(ok.sum()))
            known = y[ok, j, :4] @ pi_dut
        else:
            gain = calibration.gains[ax]
            slope = gain.slope(x0[ok, j])
            known = gain.reading_nm(x0[ok, j]) - gain.reading_nm(x_fix[ok, j])
            if inertia_guess is not None:
                known = known - slope * (y[ok, j, 4:] @ inertia_guess)
        sign = np.sign(qd[ok, j])
        rows_i.append(slope[:, None] * np.hstack([y[ok, j, 4:], y[ok, j, 1:4]]))
        load = np.abs(x0[ok, j]) - np.abs(x_fix[ok, j])
        scale = np.zeros(int(ok.sum())) if thermal is None else thermal[ok, j] / 1000.0
        rows_n.append(np.stack([sign, np.deg2rad(qd[ok, j]), np.ones(int(ok.sum())), sign * load / 1000.0, scale],
                               axis=1))
        axes.append(np.full(int(ok.sum()), ax))
        taus.append(tau[ok, j] - known)
        readings.append(tau[ok, j])
        payload.append(x0[ok, j])
    if not rows_i:
        return None
    return StrokeData(np.vstack(rows_i), np.vstack(rows_n), np.concatenate(taus), np.concatenate(axes),
                      np.concatenate(readings), np.concatenate(payload))


def _design(data: Sequence[StrokeData]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack strokes: [I columns | per-axis nuisance columns], torque, axis of each row."""
    yi = np.vstack([d.y_inertia for d in data])
    yn = np.vstack([d.y_nuisance for d in data])
    ax = np.concatenate([d.axis for d in data])
    tau = np.concatenate([d.torque_nm for d in data])
    blocks = [yn * (ax == a)[:, None] for a in WRIST_AXES]
    return np.hstack([yi, *blocks]), tau, ax


def _wls(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    sw = np.sqrt(w)
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    sol, *_ = np.linalg.lstsq(a * sw[:, None] / scale, b * sw, rcond=None)
    return sol / scale


@dataclass(frozen=True)
class InertiaResult:
    """The identified inertia, all kg·m², U with k = 2."""

    inertia_flange_kgm2: np.ndarray
    """About the flange origin, flange axes (3×3)."""
    inertia_cog_dut_kgm2: np.ndarray
    """About the CoG, DuT axes (3×3): the mass-properties sheet's tensor."""
    U_inertia_cog_dut_kgm2: np.ndarray
    principal_moments_kgm2: np.ndarray
    U_principal_moments_kgm2: np.ndarray
    principal_axes_dut: np.ndarray
    """Columns: the principal axes in the DuT frame, in the order of the moments."""
    U_principal_axes_deg: np.ndarray
    friction: dict[str, dict[str, float]]
    """Per wrist axis: what the DuT adds to Coulomb friction (Nm), viscous friction (Nm·s/rad), offset (Nm)."""
    residual_rms_nm: dict[str, float]
    n_strokes: int
    n_samples: int
    condition_number: float
    covariance_inertia_flange: np.ndarray = field(repr=False)
    warnings: tuple[str, ...] = ()
    torque_scale: dict[str, dict[str, float]] = field(default_factory=dict)
    """Per wrist axis (``"A4"``..): the payload torque its gain curve worked at (``operating_point_nm``: mean, with
    ``min_nm``/``max_nm`` over its rows) and the relative standard uncertainty of its torque scale that U holds
    (``u_scale_rel``: the gain slope's there, with the model form, and the thermal scale); empty without a
    calibration."""

    def to_json(self) -> dict:
        return {
            "inertia_cog_dut_kgm2": self.inertia_cog_dut_kgm2.tolist(),
            "U_inertia_cog_dut_kgm2": self.U_inertia_cog_dut_kgm2.tolist(),
            "inertia_flange_kgm2": self.inertia_flange_kgm2.tolist(),
            "principal_moments_kgm2": self.principal_moments_kgm2.tolist(),
            "U_principal_moments_kgm2": self.U_principal_moments_kgm2.tolist(),
            "principal_axes_dut": self.principal_axes_dut.T.tolist(),
            "U_principal_axes_deg": self.U_principal_axes_deg.tolist(),
            "friction": self.friction,
            "residual_rms_nm": self.residual_rms_nm,
            "n_strokes": self.n_strokes,
            "n_samples": self.n_samples,
            "condition_number": self.condition_number,
            "coverage_k": COVERAGE_K,
            "warnings": list(self.warnings),
            "torque_scale": self.torque_scale,
        }


def _axis_scale_sensitivity(a: np.ndarray, reading_nm: np.ndarray, ax: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, n_params): the weighted fit's change per unit relative slope error of each wrist axis' gain curve.

    With the slope of axis j off by δ the reading is (1 + δ) times what the calibration says, so the torques the
    fit should have had are reading/(1 + δ) − known ≈ b − δ·reading on that axis' rows; the fit is linear in b."""
    return np.array([_wls(a, -reading_nm * (ax == x), w) for x in WRIST_AXES])


def operating_points_nm(data: Sequence[StrokeData]) -> dict[int, tuple[float, float, float]]:
    """Per wrist axis the payload torque its gain curve works at during the excitation: (mean, min, max) over the
    axis' rows (Nm; MPA, fixture and DuT, the torque :func:`stroke_rows` takes the gain's slope at)."""
    ax = np.concatenate([d.axis for d in data])
    x = np.concatenate([d.payload_nm for d in data])
    return {a: (float(np.mean(x[ax == a])), float(np.min(x[ax == a])), float(np.max(x[ax == a])))
            for a in WRIST_AXES if np.any(ax == a)}


def _slope_u_at_operating_point(calibration: TorqueCalibration, data: Sequence[StrokeData],
                                warnings: list[str]) -> np.ndarray:
    """Per wrist axis the relative standard uncertainty of its gain's slope at the run's operating point (the mean
    payload torque of its rows; ``u_slope_rel_axes`` where the calibration gives no function of the torque), and a
    warning for every axis whose operating point lies outside the torques the calibration covered."""
    ops = operating_points_nm(data)
    out = np.zeros(len(WRIST_AXES))
    for k, x in enumerate(WRIST_AXES):
        f = calibration.slope_u_rel_at.get(x)
        out[k] = f(ops[x][0]) if f is not None and x in ops else calibration.u_slope_rel_axes.get(x, 0.0)
        covered = calibration.covered_nm.get(x)
        if covered is not None and x in ops and not covered[0] <= ops[x][0] <= covered[1]:
            mean, lo, hi = ops[x]
            warnings.append(f"A{x}: the payload torque during the excitation ({mean:.0f} Nm; {lo:.0f} to {hi:.0f} "
                            f"Nm) lies outside the torques the torsional calibration covered ({covered[0]:.0f} to "
                            f"{covered[1]:.0f} Nm): its gain curve's slope is extrapolated there")
    return out


def _to_dut(i_o_six: np.ndarray, mass_kg: float, cog: np.ndarray, r_fd: np.ndarray) -> np.ndarray:
    i_c = tensor(i_o_six) - steiner_kgm2(mass_kg, cog)
    return r_fd.T @ i_c @ r_fd


def _axes_angles_deg(axes: np.ndarray, ref: np.ndarray) -> np.ndarray:
    cos = np.clip(np.abs(np.einsum("ij,ij->j", axes, ref)), 0.0, 1.0)
    return np.rad2deg(np.arccos(cos))


class NotPhysical(ValueError):
    """The identified tensor is no rigid body's beyond its uncertainty: the input is wrong, not the DuT."""


def check_physical(moments_kgm2: np.ndarray, u_moments_kgm2: np.ndarray, triangle: bool = True) -> str | None:
    """Refuse principal moments (ascending, U with k = 2) that no rigid body has, beyond their U: a moment below
    zero, or (``triangle``) I1 + I2 < I3, the triangle inequality of a positive definite inertia tensor. Such a
    result comes from wrong input (the DuT's and the tare's traces swapped: their difference changes sign; a wrong CoG
    or mass: the parallel-axis shift to the CoG is wrong), never from the DuT; within U it is left to U.

    Returns the triangle's problem when ``triangle`` is False (a warning for the caller): a flat DuT sits near
    I1 + I2 = I3, and without a torque calibration each axis' scale error is not in U."""
    m = np.asarray(moments_kgm2, float)
    u = np.asarray(u_moments_kgm2, float)
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(u))):
        raise NotPhysical(f"inertia: principal moments {m.tolist()} ± {u.tolist()} kg·m² are not finite")
    problems = [f"I{k + 1} = {m[k]:.3f} ± {u[k]:.3f} kg·m² is negative" for k in range(3) if m[k] < -u[k]]
    tri = None
    if m[0] + m[1] - m[2] < -float(np.sum(u)):
        tri = f"I1 + I2 = {m[0] + m[1]:.3f} kg·m² < I3 = {m[2]:.3f} kg·m² beyond U (no rigid body: I1 + I2 >= I3)"
        if triangle:
            problems.append(tri)
    if problems:
        raise NotPhysical("inertia: the identified tensor is not a rigid body's: " + "; ".join(problems)
                          + " (likely wrong input: the DuT and tare traces swapped, or a wrong CoG or mass)")
    return tri


def identify(
    strokes: Sequence[Stroke],
    period_s: float,
    mass_kg: float,
    cog_flange_m: Sequence[float],
    *,
    dut_abc_deg: Sequence[float] = (0.0, 0.0, 0.0),
    g_m_s2: float = kin.G_PAPER_M_S2,
    u_gain_rel: float = 0.0,
    n_bootstrap: int = N_BOOTSTRAP,
    seed: int = 0,
    resting_axes: bool = False,
    calibration: TorqueCalibration | None = None,
    u_cog_flange_m: Sequence[float] = (0.0, 0.0, 0.0),
) -> InertiaResult:
    """Inertia of the payload from (tare-differenced) strokes, mass and CoG fixed; see the module docstring.

    ``cog_flange_m``: the DuT's CoG in the flange frame; ``dut_abc_deg``: the DuT frame's orientation on the flange
    (KUKA A, B, C). ``u_gain_rel``: relative standard uncertainty of the torque scale. ``u_cog_flange_m``: standard
    uncertainty of the CoG (static measurement): the parallel-axis shift to the CoG carries it (drawn in every
    bootstrap replicate). The fit's correction to m·c only serves the gravity terms: in the tare-differenced torques
    it mixes the DuT's CoG error with the tare's and the mountings', so it does not move the CoG.

    Raises
    ------
    ValueError
        Fewer than 4 usable strokes, or the strokes do not determine all six inertia parameters;
        :class:`NotPhysical` if the tensor is no rigid body's beyond its U (:func:`check_physical`).
    """
    cog = np.asarray(cog_flange_m, float)
    u_cog = np.asarray(u_cog_flange_m, float)

    def rows(guess: np.ndarray | None) -> list[StrokeData]:
        return [d for s in strokes
                if (d := stroke_rows(s, period_s, mass_kg, cog, g_m_s2, resting_axes, calibration, guess,
                                     temp_ref)) is not None]

    temps = [t for s in strokes for t in (s.temp_k, s.tare_temp_k) if t is not None]
    temp_ref = np.nanmean(np.vstack(temps), axis=0) if temps else None
    if temp_ref is not None:
        wrist = [x - 1 for x in WRIST_AXES]
        spread = max(float(np.nanmax(np.abs(t[:, wrist] - temp_ref[wrist]))) for t in temps)
        if not spread >= MIN_THERMAL_SPREAD_K:  # one temperature throughout: no drift to fit (the column would be
            strokes = [replace(s, temp_k=None, tare_temp_k=None) for s in strokes]  # rounding noise times τ)
            temps, temp_ref = [], None
    if temps and calibration is not None and calibration.temp_ref_k is not None:
        temp_ref = np.asarray(calibration.temp_ref_k, float)

    data = rows(None)
    if len(data) < 4:
        raise ValueError(f"inertia: {len(data)} usable strokes, at least 4 needed")
    a, b, ax = _design(data)
    if calibration is not None and calibration.gains:  # the gains' operating point with the inertia: once more
        data = rows(_wls(a, b, np.ones_like(b))[:6])
        a, b, ax = _design(data)
    scaled = a / np.where(np.linalg.norm(a, axis=0) == 0, 1.0, np.linalg.norm(a, axis=0))
    sv = np.linalg.svd(scaled[:, :6], compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    if not cond < 1e6:
        raise ValueError(f"inertia: the strokes do not determine all six inertia parameters (condition {cond:.3g})")
    # per-axis weights from an unweighted first pass (the axes differ in noise and in unmodelled effects)
    sol = _wls(a, b, np.ones_like(b))
    res = b - a @ sol
    sigma = {x: float(np.sqrt(np.mean(res[ax == x] ** 2))) for x in WRIST_AXES if np.any(ax == x)}
    w = np.array([1.0 / max(sigma[x], 1e-6) ** 2 for x in ax])
    sol = _wls(a, b, w)
    res = b - a @ sol
    r_fd = dut_rotation(dut_abc_deg)
    t_dut = _to_dut(sol[:6], mass_kg, cog, r_fd)
    moments, axes = principal(t_dut)
    # per wrist axis: relative standard uncertainty of its torque scale (the gain curve's slope; the thermal drift
    # between the runs' temperature and the calibration's), and the fit's response to it
    u_axis = np.zeros(len(WRIST_AXES))
    warnings = []
    if calibration is not None:
        u_axis += _slope_u_at_operating_point(calibration, data, warnings)
        if calibration.calibration_temp_k is not None and temp_ref is not None:
            # the reading's scale at the runs' mean motor temperature against the calibration's: β̂_j·(T̄_j − T_cal,j),
            # not corrected, as a rectangular bound (β̂ is the fit's own, see TorqueCalibration.temp_ref_k)
            t_cal = calibration.calibration_temp_k
            drift = np.array([abs(sol[N_SHARED + N_AXIS * k + 4] / 1000.0 * (temp_ref[x - 1] - t_cal[x - 1]))
                              for k, x in enumerate(WRIST_AXES)])
            u_axis = np.hypot(u_axis, drift / math.sqrt(3.0))
    torque_scale = {}
    if calibration is not None:
        for x, (mean, lo, hi) in operating_points_nm(data).items():
            torque_scale[f"A{x}"] = {"operating_point_nm": mean, "min_nm": lo, "max_nm": hi,
                                     "u_scale_rel": float(u_axis[WRIST_AXES.index(x)])}
    reading = np.concatenate([d.reading_nm for d in data])
    sens = _axis_scale_sensitivity(a, reading, ax, w) if np.any(u_axis > 0) else None
    # stroke bootstrap on per-stroke normal equations (a refit is a sum of small matrices)
    rng = np.random.default_rng(seed)
    n = len(data)
    sizes = np.array([len(d.torque_nm) for d in data])
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    scale = np.linalg.norm(a, axis=0)
    unused = scale == 0  # e.g. the tare-torque column of strokes that were not differenced
    scale[unused] = 1.0
    a_s = a / scale
    ata = np.array([(a_s[i:j] * w[i:j, None]).T @ a_s[i:j] for i, j in itertools.pairwise(bounds)])
    atb = np.array([(a_s[i:j] * w[i:j, None]).T @ b[i:j] for i, j in itertools.pairwise(bounds)])
    # strata: strokes of one axis in one direction (a resample without any stroke of a direction could not tell
    # Coulomb friction from the offset)
    key = [(int(d.axis[0]), float(np.sign(np.sum(d.y_nuisance[:, 0])))) for d in data]
    strata = [np.array([i for i, k in enumerate(key) if k == u]) for u in sorted(set(key))]
    boot_i, boot_t, boot_m, boot_ang = [], [], [], []
    for _ in range(n_bootstrap):
        counts = np.zeros(n)
        for st in strata:
            np.add.at(counts, st[rng.integers(0, len(st), len(st))], 1.0)
        normal = np.tensordot(counts, ata, 1) + np.diag(unused.astype(float))
        if np.linalg.cond(normal) > 1e12:
            continue
        s_b = np.linalg.solve(normal, np.tensordot(counts, atb, 1)) / scale
        t_b_cog = cog + rng.normal(0.0, 1.0, 3) * u_cog
        if sens is not None:  # each axis' own slope error, drawn
            s_b = s_b + (rng.normal(0.0, 1.0, len(WRIST_AXES)) * u_axis) @ sens
        t_b = _to_dut(s_b[:6], mass_kg, t_b_cog, r_fd)
        m_b, ax_b = principal(t_b)
        boot_i.append(s_b[:6])
        boot_t.append(t_b)
        boot_m.append(m_b)
        boot_ang.append(_axes_angles_deg(ax_b, axes))
    if len(boot_m) < 0.9 * n_bootstrap:
        raise ValueError(f"inertia: {n_bootstrap - len(boot_m)} of {n_bootstrap} resamples of the strokes do not "
                         "determine the parameters: too few strokes")
    sizes_s = np.array([len(st) for st in strata], float)
    if np.any(sizes_s < 2):
        raise ValueError("inertia: every wrist axis needs at least two strokes in each direction")
    # the bootstrap's variance is biased low by (n_s − 1)/n_s in each stratum
    finite = math.sqrt(float(np.mean(sizes_s / (sizes_s - 1.0))))
    cov_i = np.cov(np.array(boot_i).T) * finite**2
    u_t = np.std(np.array(boot_t), axis=0, ddof=1) * finite
    u_m = np.std(np.array(boot_m), axis=0, ddof=1) * finite
    u_ang = np.sqrt(np.mean(np.array(boot_ang) ** 2, axis=0)) * finite
    if calibration is not None:
        u_gain_rel = math.hypot(u_gain_rel, calibration.u_gain_rel)
    u_t = np.sqrt(u_t**2 + (u_gain_rel * np.abs(t_dut)) ** 2)
    u_m = np.sqrt(u_m**2 + (u_gain_rel * moments) ** 2)
    friction = {}
    for k, x in enumerate(WRIST_AXES):
        fc, fv, off, mu, kappa = sol[N_SHARED + N_AXIS * k : N_SHARED + N_AXIS * (k + 1)]
        friction[f"A{x}"] = {"coulomb_nm": float(fc), "viscous_nm_s_rad": float(fv), "offset_nm": float(off),
                             "coulomb_per_knm": float(mu), "thermal_per_k": float(kappa) / 1000.0}
    # without a calibration the readings are taken 1:1: each axis' scale error is not in U, so a flat DuT
    # (I1 + I2 near I3) may cross the triangle; that is a warning then, a negative moment is refused always
    tri = check_physical(moments, COVERAGE_K * u_m, triangle=calibration is not None)
    if tri is not None:
        warnings.append(f"{tri}: without a torque calibration each axis' scale error is not in U")
    gaps = np.diff(moments) / moments[1:]
    if np.any(gaps < 0.05):
        warnings.append("two principal moments lie within 5 % of each other: their axes are poorly defined")
    return InertiaResult(
        inertia_flange_kgm2=tensor(sol[:6]),
        inertia_cog_dut_kgm2=t_dut,
        U_inertia_cog_dut_kgm2=COVERAGE_K * u_t,
        principal_moments_kgm2=moments,
        U_principal_moments_kgm2=COVERAGE_K * u_m,
        principal_axes_dut=axes,
        U_principal_axes_deg=COVERAGE_K * u_ang,
        friction=friction,
        residual_rms_nm={f"A{x}": float(np.sqrt(np.mean(res[ax == x] ** 2))) for x in WRIST_AXES if np.any(ax == x)},
        n_strokes=n,
        n_samples=len(b),
        condition_number=cond,
        covariance_inertia_flange=cov_i,
        warnings=tuple(warnings),
        torque_scale=torque_scale,
    )
