"""Kinematics and static gravity torques of a KUKA six-axis arm (pure numpy), by default the active robot.

The robot's figures live in :mod:`rgse_daemon.robots`; every function takes ``robot=`` (default: the active one,
:func:`rgse_daemon.robots.active`). The docstring's figures below are those of the KR 500 R2830.

Used by the interlock (worst-case Cartesian speed of any point of the chain during a PTP motion), by the simulated
KR C4 (pose, gravity torques) and by the CoG estimator (gravity regressor).

Convention
----------
Modified (Craig) Denavit-Hartenberg, lengths in metres (docs/controller.md §1: d1 = 1045, a1 = 500, a2 = 1300, a3 = 55,
d4 = 1025, d6 = 290 mm). Frame ``i`` is attached to the link moved by axis Ai; the transform from frame ``i-1`` is
``Rx(alpha[i-1]) · Tx(a[i-1]) · Rz(theta_i) · Tz(d_i)`` with ``theta_i = sign_i · A_i + offset_i``:

====  ==============  ===========  ========  ==========================
axis  alpha[i-1] deg  a[i-1] m     d_i m     theta_i
====  ==============  ===========  ========  ==========================
A1    0               0            1.045     −A1
A2    −90             0.500        0         +A2
A3    0               1.300        0         +A3 + 90°
A4    +90             0.055        1.025     −A4
A5    −90             0            0         +A5
A6    +90             0            0.290     −A6
====  ==============  ===========  ========  ==========================

The signs reproduce KUKA's axis directions (A1, A4 and A6 turn about −z of their DH frame, as in the ROS-Industrial
URDFs of this family: A1 positive turns the arm clockwise seen from above, A2 negative lifts the upper arm, A3
positive lowers the forearm, A5 positive tilts the flange down). The base frame is KUKA's $ROBROOT: origin on the A1
axis at the foot of the robot, z up, x forward at A1 = 0. Frame 6 *is* KUKA's $FLANGE: z out of the flange, x down in
the home pose. Checks (tests/physics): home A1..A6 = (0, −90, 90, 0, 0, 0) puts the flange at (1815, 0, 2290) mm with
KUKA angles A = 0, B = 90°, C = 0; the candle (0, −90, 0, 0, 0, 0) at (555, 0, 3660) mm; fully stretched the wrist
centre is at the published reach 2826 mm from A1.

Torque sign: ``gravity_torques_nm`` returns the *holding* torque a drive must apply, about the KUKA-positive axis
direction. A load in front of the robot in the measurement pose therefore gives negative A3 and A5 torques, as the
controller reports them (``$TORQUE_AXIS_ACT[3] = -1320.46``, docs/controller.md §4).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import robots
from rgse_daemon.robots import RobotModel

# --- the default robot's figures as module names (aliases: the figures live in rgse_daemon/robots/) ---------------
# Kept for the modules that still import them; they are the *default* robot's (KR 500 R2830), not the active one's.
# Code that must work for any robot passes ``robot=`` or uses robot_arrays(); these go once nothing imports them.
_DEFAULT = robots.get(robots.DEFAULT_KEY)
D1_M = _DEFAULT.dh[0].d_m
A1_M = _DEFAULT.dh[1].a_m
A2_M = _DEFAULT.dh[2].a_m
A3_M = _DEFAULT.dh[3].a_m
D4_M = _DEFAULT.dh[3].d_m
D6_M = _DEFAULT.dh[5].d_m


@dataclass(frozen=True, eq=False)
class RobotArrays:
    """A robot's figures as the numpy arrays the arithmetic below uses."""

    mdh: np.ndarray
    """Modified DH rows: (alpha_{i-1} rad, a_{i-1} m, d_i m)."""
    axis_sign: np.ndarray
    """theta_i = axis_sign[i] * A_i + theta_offset_rad[i]"""
    theta_offset_rad: np.ndarray
    joint_limits_deg: np.ndarray
    """Software axis ranges (deg), shape (6, 2)."""
    max_axis_speed_deg_s: tuple[float, ...]
    home_deg: np.ndarray
    candle_deg: np.ndarray
    d6_m: float
    """Flange distance from the wrist centre (m)."""


def robot_arrays(robot: RobotModel | None = None) -> RobotArrays:
    """The arrays of ``robot`` (default: the active robot, :func:`rgse_daemon.robots.active`)."""
    return _arrays_of(robots.active() if robot is None else robot)


_ARRAYS: dict[int, tuple[RobotModel, RobotArrays]] = {}


def _arrays_of(r: RobotModel) -> RobotArrays:
    # keyed by identity (hashing a model's nested tuples on every call of the inner loops would cost more)
    hit = _ARRAYS.get(id(r))
    if hit is not None and hit[0] is r:
        return hit[1]
    arrays = _build_arrays(r)
    _ARRAYS[id(r)] = (r, arrays)
    return arrays


def _build_arrays(r: RobotModel) -> RobotArrays:
    return RobotArrays(
        mdh=np.array([[np.deg2rad(row.alpha_deg), row.a_m, row.d_m] for row in r.dh]),
        axis_sign=np.array(r.axis_sign, dtype=float),
        theta_offset_rad=np.deg2rad(np.array(r.theta_offset_deg, dtype=float)),
        joint_limits_deg=np.array(r.axis_range_deg, dtype=float),
        max_axis_speed_deg_s=tuple(float(v) for v in r.max_axis_speed_deg_s),
        home_deg=np.array(r.home_deg, dtype=float),
        candle_deg=np.array(r.candle_deg, dtype=float),
        d6_m=r.dh[5].d_m,
    )


def _arr(robot: RobotModel | None) -> RobotArrays:
    return _arrays_of(robots.active() if robot is None else robot)


_DEFAULT_ARRAYS = robot_arrays(_DEFAULT)
MDH = _DEFAULT_ARRAYS.mdh
AXIS_SIGN = _DEFAULT_ARRAYS.axis_sign
THETA_OFFSET_RAD = _DEFAULT_ARRAYS.theta_offset_rad
JOINT_LIMITS_DEG = _DEFAULT_ARRAYS.joint_limits_deg
MAX_AXIS_SPEED_DEG_S: tuple[float, ...] = _DEFAULT_ARRAYS.max_axis_speed_deg_s
HOME_DEG = _DEFAULT_ARRAYS.home_deg
CANDLE_DEG = _DEFAULT_ARRAYS.candle_deg

#: The paper's g (eq. 4, 14, 17, 18); local g in Bremen is 9.8134 m/s² (docs/controller.md §7). A site's figure,
#: not a robot's.
G_PAPER_M_S2 = 9.81

_Z = np.array([0.0, 0.0, 1.0])


def _as_q(q_deg: Sequence[float] | np.ndarray) -> np.ndarray:
    q = np.asarray(q_deg, dtype=float)
    if q.shape != (6,):
        raise ValueError(f"expected 6 axis angles A1..A6 in deg, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("axis angles must be finite")
    return q


def joint_frames(q_deg: Sequence[float] | np.ndarray, robot: RobotModel | None = None) -> np.ndarray:
    """Homogeneous transforms base → frame i for i = 1..6, shape (6, 4, 4), translations in m.

    Frame i's origin lies on axis Ai (frames 4 and 5 at the wrist centre, frame 6 at the flange) and its z axis is
    ``AXIS_SIGN[i]`` times the KUKA-positive direction of Ai.
    """
    return joint_frames_path(_as_q(q_deg)[None, :], robot)[0]


def joint_frames_path(
    q_path_deg: Sequence[Sequence[float]] | np.ndarray, robot: RobotModel | None = None
) -> np.ndarray:
    """:func:`joint_frames` of every sample of a path at once: (N, 6) axis angles in deg → (N, 6, 4, 4).

    The same products as one sample at a time, in one numpy pass over the samples: the interlock samples every PTP
    motion a quarter degree apart, and one pose at a time cost it 65 µs a sample in Python (``joint_frames`` is this
    with N = 1, so both give the same numbers)."""
    q = np.asarray(q_path_deg, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6:
        raise ValueError(f"expected (N, 6) axis angles A1..A6 in deg, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("axis angles must be finite")
    arr = _arr(robot)
    theta = arr.axis_sign * np.deg2rad(q) + arr.theta_offset_rad  # (N, 6)
    alpha, a, d = arr.mdh[:, 0], arr.mdh[:, 1], arr.mdh[:, 2]
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    # the link transforms Rx(alpha) · Tx(a) · Rz(theta) · Tz(d) (modified DH), (N, 6, 4, 4)
    link = np.zeros((*q.shape, 4, 4))
    link[..., 0, 0], link[..., 0, 1], link[..., 0, 3] = ct, -st, a
    link[..., 1, 0], link[..., 1, 1], link[..., 1, 2], link[..., 1, 3] = st * ca, ct * ca, -sa, -sa * d
    link[..., 2, 0], link[..., 2, 1], link[..., 2, 2], link[..., 2, 3] = st * sa, ct * sa, ca, ca * d
    link[..., 3, 3] = 1.0
    frames = np.empty_like(link)
    frames[:, 0] = link[:, 0]
    for i in range(1, 6):
        frames[:, i] = frames[:, i - 1] @ link[:, i]
    return frames


def flange_frame(q_deg: Sequence[float] | np.ndarray, robot: RobotModel | None = None) -> np.ndarray:
    """Base → $FLANGE transform (4×4, m)."""
    return joint_frames(q_deg, robot)[5]


def axis_lines(
    q_deg: Sequence[float] | np.ndarray, robot: RobotModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Points on and KUKA-positive unit directions of the six axes in the base frame: (origins_m (6,3), dirs (6,3))."""
    frames = joint_frames(q_deg, robot)
    return frames[:, :3, 3].copy(), frames[:, :3, 2] * _arr(robot).axis_sign[:, None]


def flange_point_m(
    q_deg: Sequence[float] | np.ndarray,
    point_flange_m: Sequence[float] = (0.0, 0.0, 0.0),
    robot: RobotModel | None = None,
) -> np.ndarray:
    """Base-frame position (m) of a point given in the flange frame (m)."""
    f = flange_frame(q_deg, robot)
    return f[:3, :3] @ np.asarray(point_flange_m, dtype=float) + f[:3, 3]


def kuka_abc_deg(rotation: np.ndarray) -> np.ndarray:
    """KUKA orientation angles (A, B, C) in deg of a rotation matrix: R = Rz(A) · Ry(B) · Rx(C)."""
    r = np.asarray(rotation, dtype=float)
    b = np.arctan2(-r[2, 0], np.hypot(r[0, 0], r[1, 0]))
    if np.isclose(np.cos(b), 0.0, atol=1e-9):  # gimbal lock: put everything into A
        a = np.arctan2(-r[0, 1], r[1, 1])
        c = 0.0
    else:
        a = np.arctan2(r[1, 0], r[0, 0])
        c = np.arctan2(r[2, 1], r[2, 2])
    return np.rad2deg(np.array([a, b, c]))


def flange_pose_xyzabc(q_deg: Sequence[float] | np.ndarray, robot: RobotModel | None = None) -> np.ndarray:
    """$POS_ACT-style flange pose: X, Y, Z in mm and A, B, C in deg (no tool, $ROBROOT base)."""
    f = flange_frame(q_deg, robot)
    return np.concatenate([f[:3, 3] * 1000.0, kuka_abc_deg(f[:3, :3])])


def within_limits(
    q_deg: Sequence[float] | np.ndarray, limits_deg: np.ndarray | None = None, robot: RobotModel | None = None
) -> bool:
    """True if every axis angle lies inside its software range (``limits_deg`` default: the robot's)."""
    q = _as_q(q_deg)
    if limits_deg is None:
        limits_deg = _arr(robot).joint_limits_deg
    return bool(np.all(q >= limits_deg[:, 0]) and np.all(q <= limits_deg[:, 1]))


def measurement_pose(
    a2_deg: float | None = None, a1_deg: float = 0.0, robot: RobotModel | None = None
) -> np.ndarray:
    """The paper's mass measurement pose (Fig. 19/21), A1..A6 in deg.

    Forearm horizontal (A3 = −A2), A4 = 0 so that the A5 axis is parallel to A3, flange horizontal (A5 = 0) so that a
    stack of plates grows horizontally. The A3 → A5 vector is then (d4, 0, −a3): the horizontal lever of *any* flange
    load to A3 exceeds its lever to A5 by exactly d4 (1.025 m on the KR 500), hence M_A3 − M_A5 = g·m·d4 (eq. 3–4)
    whatever the CoG. ``a2_deg`` default: the robot's ``measurement_a2_deg``.
    """
    r = robots.active() if robot is None else robot
    if a2_deg is None:
        a2_deg = r.measurement_a2_deg
    q = np.array([a1_deg, a2_deg, -a2_deg, 0.0, 0.0, 0.0])
    if not within_limits(q, robot=r):
        raise ValueError(f"measurement pose {q.tolist()} is outside the axis ranges")
    return q


# --- speeds ----------------------------------------------------------------------------------------------------------
def point_jacobian(
    q_deg: Sequence[float] | np.ndarray,
    point_flange_m: Sequence[float] = (0.0, 0.0, 0.0),
    robot: RobotModel | None = None,
) -> np.ndarray:
    """Linear velocity Jacobian (3×6) of a point rigidly attached to the flange: v [m/s] = J · q̇ [rad/s].

    Column i is u_i × (p − o_i) with u_i the KUKA-positive axis direction and o_i a point on axis Ai.
    """
    frames = joint_frames(q_deg, robot)
    origins, dirs = frames[:, :3, 3], frames[:, :3, 2] * _arr(robot).axis_sign[:, None]
    p = frames[5, :3, :3] @ np.asarray(point_flange_m, dtype=float) + frames[5, :3, 3]
    return np.cross(dirs, p - origins).T


def point_velocity_mm_s(
    q_deg: Sequence[float] | np.ndarray,
    qdot_deg_s: Sequence[float] | np.ndarray,
    point_flange_m: Sequence[float] = (0.0, 0.0, 0.0),
    robot: RobotModel | None = None,
) -> np.ndarray:
    """Cartesian velocity (mm/s, base frame) of a flange-fixed point for joint speeds ``qdot_deg_s`` (deg/s)."""
    qdot = np.deg2rad(np.asarray(qdot_deg_s, dtype=float))
    return point_jacobian(q_deg, point_flange_m, robot) @ qdot * 1000.0


@dataclass(frozen=True)
class PathSpeed:
    """Worst-case Cartesian speeds of a joint motion (mm/s).

    ``sampled_max_mm_s``: largest speed of any tracked point found on the sampled path with the given joint speeds.
    ``bound_mm_s``: a conservative upper bound over the whole path (triangle inequality Σ|ω_i|·r_i plus a
    Lipschitz margin for the path between samples); ``bound_mm_s >= sampled_max_mm_s`` always.
    ``per_point_max_mm_s``: sampled maximum per tracked point: elbow, wrist centre, flange, then the given points.
    """

    sampled_max_mm_s: float
    bound_mm_s: float
    per_point_max_mm_s: tuple[float, ...]
    n_samples: int


def path_speeds(
    q_path_deg: np.ndarray,
    qdot_path_deg_s: np.ndarray,
    points_flange_m: Iterable[Sequence[float]] = (),
    robot: RobotModel | None = None,
) -> PathSpeed:
    """Worst-case Cartesian speed along a sampled joint path.

    Parameters
    ----------
    q_path_deg : (N, 6) axis angles in deg, densely sampled (consecutive samples a fraction of a degree apart).
    qdot_path_deg_s : (N, 6) or (6,) joint speeds in deg/s at those samples (a (6,) vector applies to every sample).
    points_flange_m : flange-fixed points (m, flange frame) to track besides elbow, wrist centre and flange, e.g.
        the corners of a payload's bounding box. The interlock refuses a program whose bound exceeds 200 mm/s.
    """
    q_path = np.atleast_2d(np.asarray(q_path_deg, dtype=float))
    if q_path.ndim != 2 or q_path.shape[1] != 6 or len(q_path) < 1:
        raise ValueError("q_path_deg must have shape (N, 6)")
    qdot = np.asarray(qdot_path_deg_s, dtype=float)
    qdot = np.broadcast_to(qdot, q_path.shape)
    pts_f = np.array([np.asarray(p, dtype=float) for p in points_flange_m]).reshape(-1, 3)
    w = np.deg2rad(qdot)  # (N, 6) rad/s
    frames = joint_frames_path(q_path, robot)  # (N, 6, 4, 4)
    origins = frames[:, :, :3, 3]  # (N, 6, 3)
    dirs = frames[:, :, :3, 2] * _arr(robot).axis_sign[None, :, None]
    # the tracked points (elbow, wrist centre, flange, then the flange-fixed ones) and the last axis moving each
    pts = np.concatenate([frames[:, [2, 4, 5], :3][..., 3],
                          np.einsum("nij,pj->npi", frames[:, 5, :3, :3], pts_f) + frames[:, None, 5, :3, 3]], axis=1)
    last = np.array([2, 3, 6] + [6] * len(pts_f))
    rel = pts[:, :, None, :] - origins[:, None, :, :]  # (N, P, 6, 3)
    moving = np.arange(6)[None, :] < last[:, None]  # (P, 6): axis i moves point p only if i is proximal to it
    vel = np.einsum("npi,npij->npj", w[:, None, :] * moving[None], np.cross(dirs[:, None, :, :], rel))
    speeds_arr = np.linalg.norm(vel, axis=2)  # (N, P) m/s
    # distance of each point from each axis line (lever r_i)
    along = np.einsum("npij,nij->npi", rel, dirs)
    r = np.sqrt(np.maximum(np.einsum("npij,npij->npi", rel, rel) - along**2, 0.0)) * moving[None]
    bound_pts = np.einsum("ni,npi->np", np.abs(w), r)  # (N, P) m/s, Σ|ω_i| r_i ≥ |v|
    r_max = float(r.max(initial=0.0))
    # Between samples k and k+1 every point moves at most ||Δq||₁·r_max and the axis lines move no more, so each
    # lever r_i can grow by at most 2·||Δq||₁·r_max (Δq in rad); the margin covers the unsampled stretch.
    if len(q_path) > 1:
        step_rad = np.abs(np.diff(np.deg2rad(q_path), axis=0)).sum(axis=1).max()
    else:
        step_rad = 0.0
    margin = 2.0 * step_rad * r_max * np.abs(w).sum(axis=1).max()
    bound = float(bound_pts.max() + margin) * 1000.0
    per_point = tuple(float(v) * 1000.0 for v in speeds_arr.max(axis=0))
    return PathSpeed(float(speeds_arr.max()) * 1000.0, bound, per_point, len(q_path))


def ptp_joint_speeds_deg_s(
    q_start_deg: Sequence[float], q_end_deg: Sequence[float], axis_speed_max_deg_s: Sequence[float] | float
) -> np.ndarray:
    """Peak joint speeds (deg/s) of a synchronised PTP motion: every axis arrives together, the slowest-limited axis
    runs at its maximum. ``axis_speed_max_deg_s`` is one value or one per axis (deg/s, after override)."""
    dq = _as_q(q_end_deg) - _as_q(q_start_deg)
    vmax = np.broadcast_to(np.asarray(axis_speed_max_deg_s, dtype=float), (6,))
    moving = np.abs(dq) > 1e-12
    if not moving.any():
        return np.zeros(6)
    scale = np.min(vmax[moving] / np.abs(dq[moving]))
    return dq * scale


#: Fraction of a speed limit that a rendered motion aims for under :func:`max_point_speed_mm_s`'s bound (the KRL
#: renderer's axis speed, the inertia excitation's swings): headroom for rounding and sampling; the interlock checks
#: the limit itself.
SPEED_HEADROOM = 0.95


def max_point_speed_mm_s(
    q_start_deg: Sequence[float],
    q_end_deg: Sequence[float],
    axis_speed_max_deg_s: Sequence[float] | float,
    points_flange_m: Iterable[Sequence[float]] = (),
    max_step_deg: float = 0.25,
    synchronous: bool = True,
    robot: RobotModel | None = None,
) -> PathSpeed:
    """Worst-case Cartesian speed (mm/s) of the chain during a PTP motion from ``q_start_deg`` to ``q_end_deg``.

    ``synchronous=True`` (KUKA PTP): joint speeds are ``ptp_joint_speeds_deg_s``. ``False``: every axis may run at its
    own maximum at the same time (the most pessimistic reading of an asynchronous motion). The path is the straight
    line in joint space, sampled every ``max_step_deg`` on the axis that moves most; see :class:`PathSpeed`.
    """
    q0, q1 = _as_q(q_start_deg), _as_q(q_end_deg)
    if synchronous:
        qdot = ptp_joint_speeds_deg_s(q0, q1, axis_speed_max_deg_s)
    else:
        qdot = np.broadcast_to(np.asarray(axis_speed_max_deg_s, dtype=float), (6,)) * np.sign(q1 - q0)
    n = max(2, int(np.ceil(np.abs(q1 - q0).max() / max_step_deg)) + 1)
    path = q0[None, :] + np.linspace(0.0, 1.0, n)[:, None] * (q1 - q0)[None, :]
    return path_speeds(path, qdot, points_flange_m, robot)


# --- statics ---------------------------------------------------------------------------------------------------------
def gravity_regressor(
    q_deg: Sequence[float] | np.ndarray, g_m_s2: float = G_PAPER_M_S2, robot: RobotModel | None = None
) -> np.ndarray:
    """Static holding torque regressor Y (6×4): τ [Nm] = Y · [m, m·cx, m·cy, m·cz] for a flange-mounted rigid body.

    m in kg, (cx, cy, cz) its CoG in the flange frame in m. Row i: τ_i = u_i · ((p − o_i) × m·g·ẑ) with p the CoG,
    split into the flange-origin part (∝ m) and the CoG-offset part (∝ m·c). Linear in the parameters, so several
    static poses give mass and CoG by least squares (docs/controller.md §7).
    """
    origins, dirs = axis_lines(q_deg, robot)
    f = flange_frame(q_deg, robot)
    rot, o6 = f[:3, :3], f[:3, 3]
    y = np.empty((6, 4))
    y[:, 0] = np.einsum("ij,ij->i", dirs, np.cross(o6[None, :] - origins, _Z[None, :]))
    # u · ((R c) × ẑ) = c · Rᵀ (ẑ × u)
    y[:, 1:] = np.cross(_Z[None, :], dirs) @ rot
    return y * g_m_s2


def gravity_torques_nm(
    q_deg: Sequence[float] | np.ndarray,
    bodies: Iterable[tuple[float, Sequence[float]]],
    g_m_s2: float = G_PAPER_M_S2,
    robot: RobotModel | None = None,
) -> np.ndarray:
    """Static holding torques (Nm, A1..A6) of flange-mounted bodies given as (mass_kg, cog_flange_m)."""
    theta = np.zeros(4)
    for mass_kg, cog in bodies:
        c = np.asarray(cog, dtype=float)
        theta += mass_kg * np.array([1.0, *c])
    return gravity_regressor(q_deg, g_m_s2, robot) @ theta


def link_gravity_torques_nm(
    q_deg: Sequence[float] | np.ndarray,
    links: Iterable[tuple[int, float, Sequence[float]]],
    g_m_s2: float = G_PAPER_M_S2,
    robot: RobotModel | None = None,
) -> np.ndarray:
    """Static holding torques (Nm, A1..A6) of masses fixed to the robot's own links.

    ``links``: (link index 1..6, mass_kg, CoG in that link's DH frame in m). A mass on link j loads axes A1..Aj only.
    """
    frames = joint_frames(q_deg, robot)
    origins, dirs = frames[:, :3, 3], frames[:, :3, 2] * _arr(robot).axis_sign[:, None]
    tau = np.zeros(6)
    for link, mass_kg, cog in links:
        if not 1 <= link <= 6:
            raise ValueError(f"link index must be 1..6, got {link}")
        fr = frames[link - 1]
        p = fr[:3, :3] @ np.asarray(cog, dtype=float) + fr[:3, 3]
        moment = np.einsum("ij,ij->i", dirs[:link], np.cross(p[None, :] - origins[:link], _Z[None, :]))
        tau[:link] += moment * mass_kg * g_m_s2
    return tau


def horizontal_lever_m(
    q_deg: Sequence[float] | np.ndarray, axis: int, cog_flange_m: Sequence[float], robot: RobotModel | None = None
) -> float:
    """Lever (m) of a flange-fixed point about axis ``axis`` (1..6): −τ/(m·g), positive for a load in front.

    In :func:`measurement_pose` this is the paper's x_CoG to A3 or A5 (eq. 17–18).
    """
    if not 1 <= axis <= 6:
        raise ValueError("axis must be 1..6")
    return float(-gravity_torques_nm(q_deg, [(1.0, cog_flange_m)], 1.0, robot)[axis - 1])
