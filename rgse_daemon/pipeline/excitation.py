"""Excitation moves for the inertia identification (issue #15): back-and-forth rotations of A6, A5 and A4 that the
interlock allows.

The program (:func:`design`) visits ``N_BLOCKS`` wrist orientations around a base pose (A1–A3 fixed, by default the
measurement pose). In each orientation it swings A6, then A5, then A4 back and forth ``repeats`` times by
±amplitude about the orientation and returns to it. Each swing is a synchronised PTP of one axis, so its profile is a
trapezoid: an acceleration ramp, a stretch at constant speed (what the friction is identified from) and a braking
ramp (what the inertia is identified from).

What is chosen, and how:

* **Speed** of each swing: the largest ``$VEL_AXIS`` % that keeps every point of the payload's bounding box (and
  the robot's elbow, wrist and flange) under the T1 limit on the whole swing, from the interlock's own conservative
  bound (``kinematics.max_point_speed_mm_s``). The information grows with speed, so this bound is active.
* **Acceleration**: the largest ``$ACC_AXIS`` % (≤ 100) whose inertial torque, for a generous inertia (twice that
  of a solid box filling the bounding box, :func:`_upper_inertia_kgm2`), keeps the payload's peak wrist torque
  within the load diagram's A5 limit, and whose ramps last at least ``MIN_RAMP_S`` (resolvable by the filter).
* **Orientations** (A5 and A6 of each block): chosen by ``scipy.optimize.minimize`` (Powell) to maximise the
  D-optimality of the six inertia parameters — log det of their information matrix after the per-axis friction and
  offset columns are eliminated (Schur complement) — over the planned profiles, within the axis ranges.
* **Amplitude**: long enough that every swing reaches its constant speed for at least ``PLATEAU_S``.

Planning assumption: ``NOMINAL_RAMP_TIME_S`` (time to reach an axis's full speed at 100 % ``$ACC_AXIS``) is not
published by KUKA; it only sets the planned durations and the acceleration choice. The identification itself uses the
measured positions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from rgse_daemon import kinematics as kin
from rgse_daemon.pipeline import inertia as inr

#: Time (s) to reach full axis speed at 100 % $ACC_AXIS (planning assumption, see the module docstring).
NOMINAL_RAMP_TIME_S = 0.5
NOMINAL_MAX_ACCEL_DEG_S2 = tuple(v / NOMINAL_RAMP_TIME_S for v in kin.MAX_AXIS_SPEED_DEG_S)


def nominal_max_accel_deg_s2() -> tuple[float, ...]:
    """The active robot's axis accelerations at 100 % (deg/s²); ``NOMINAL_MAX_ACCEL_DEG_S2`` is the default
    robot's (an alias)."""
    return tuple(v / NOMINAL_RAMP_TIME_S for v in kin.robot_arrays().max_axis_speed_deg_s)
#: Wrist orientations per program and swings of each axis per orientation.
N_BLOCKS = 3
REPEATS = 2
#: Shortest stretch at constant speed in each swing (s).
PLATEAU_S = 0.4
#: Shortest acceleration ramp (s): a ramp not much longer than the smoothing (pipeline.inertia.SMOOTH_SIGMA_S)
#: is smeared by the filter and by the drive's own response; the information per ramp (∝ a²·t = a·v) is traded
#: for ramps the derivatives can resolve.
MIN_RAMP_S = 0.25
#: Speed of the repositioning moves between orientations, % of the T1-safe speed.
REPOSITION_FRACTION = 1.0
#: Swinging axes in the order of a block.
SWING_AXES: tuple[int, ...] = (6, 5, 4)
#: Largest swing amplitude (deg) and the margin kept to the axis ranges (deg).
MAX_AMPLITUDE_DEG = 60.0
LIMIT_MARGIN_DEG = 5.0
#: Sampling of the planned profiles for the design criterion (s).
DESIGN_STEP_S = 0.02


@dataclass(frozen=True)
class Move:
    """One PTP: target A1..A6 (deg) and the ``$VEL_AXIS``/``$ACC_AXIS`` % in force for it."""

    target_deg: tuple[float, ...]
    vel_axis_pct: tuple[float, ...]
    acc_axis_pct: tuple[float, ...]
    swing_axis: int | None
    """The axis this move swings (4..6), None for a repositioning move."""


@dataclass(frozen=True)
class Excitation:
    """A designed excitation program: start pose, moves, planned robot time (s), the design's condition number and
    log det of the inertia information (from the planned profiles, unit torque noise)."""

    start_deg: tuple[float, ...]
    moves: tuple[Move, ...]
    robot_time_s: float
    condition_number: float
    log_det: float
    limit_mm_s: float
    max_point_speed_mm_s: float
    """The largest worst-case point speed over the moves (the interlock's bound, at the rendered speeds)."""


def _round_down(pct: float) -> float:
    return max(0.01, math.floor(pct * 100.0) / 100.0)


def _plan(q0: np.ndarray, q1: np.ndarray, vel_pct: Sequence[float], acc_pct: Sequence[float],
          step_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A synchronised trapezoidal PTP q0 → q1 (planning model): q, q̇, q̈ sampled every ``step_s``, duration."""
    dq = q1 - q0
    dist = float(np.abs(dq).max())
    if dist == 0:
        return q0[None, :], np.zeros((1, 6)), np.zeros((1, 6)), 0.0
    vmax = np.array(vel_pct) / 100.0 * np.array(kin.robot_arrays().max_axis_speed_deg_s)
    amax = np.array(acc_pct) / 100.0 * np.array(nominal_max_accel_deg_s2())
    moving = np.abs(dq) > 0
    v = float(np.min(vmax[moving] / np.abs(dq[moving])))  # path parameter s in 0..1
    a = float(np.min(amax[moving] / np.abs(dq[moving])))
    t_acc = v / a
    if v * t_acc >= 1.0:  # triangle
        t_acc = math.sqrt(1.0 / a)
        v = a * t_acc
        t_flat = 0.0
    else:
        t_flat = (1.0 - v * t_acc) / v
    total = 2 * t_acc + t_flat
    t = np.arange(0.0, total + step_s / 2, step_s)
    s = np.where(t < t_acc, 0.5 * a * t**2,
                 np.where(t < t_acc + t_flat, 0.5 * a * t_acc**2 + v * (t - t_acc),
                          1.0 - 0.5 * a * np.clip(total - t, 0, None) ** 2))
    sd = np.where(t < t_acc, a * t, np.where(t < t_acc + t_flat, v, a * np.clip(total - t, 0, None)))
    sdd = np.where(t < t_acc, a, np.where(t < t_acc + t_flat, 0.0, -a))
    return q0 + s[:, None] * dq, sd[:, None] * dq, sdd[:, None] * dq, total


def _upper_inertia_kgm2(mass_kg: float, points_flange_m: np.ndarray, cog: np.ndarray) -> np.ndarray:
    """A generous inertia about the CoG for the torque check: the mass spread as a solid box over the bounding box
    of the points, doubled (an asymmetric mass distribution can exceed the uniform box's moments)."""
    ext = points_flange_m.max(axis=0) - points_flange_m.min(axis=0)
    d2 = ext**2 / 12.0
    return 2.0 * mass_kg * np.diag([d2[1] + d2[2], d2[0] + d2[2], d2[0] + d2[1]])


def safe_single_axis_pct(q0: np.ndarray, q1: np.ndarray, points: Sequence[Sequence[float]], limit_mm_s: float,
                         vel_pct_other: float = 100.0) -> float:
    """Largest $VEL_AXIS % for a PTP q0 → q1 keeping every tracked point under ``limit_mm_s`` (the interlock's
    bound scales linearly with the axis speeds)."""
    bound = kin.max_point_speed_mm_s(q0, q1, kin.robot_arrays().max_axis_speed_deg_s, points).bound_mm_s
    if bound == 0.0:
        return vel_pct_other
    return _round_down(min(100.0, 100.0 * kin.SPEED_HEADROOM * limit_mm_s / bound))


@dataclass(frozen=True)
class Payload:
    """What the design needs of the payload: mass (kg), CoG (flange frame, m), the corners of its bounding box
    (flange frame, m), and the load diagram's A5 torque limit (Nm)."""

    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    points_flange_m: tuple[tuple[float, float, float], ...]
    max_wrist_torque_nm: float = 4000.0


def _lever_m(centre: np.ndarray, ax: int, points: Sequence[Sequence[float]]) -> float:
    """Largest distance (m) of the payload points and the flange from axis ``ax`` in pose ``centre``: a rotation of
    that axis alone keeps these distances, so the fastest point moves at ω·lever on the whole swing."""
    origins, dirs = kin.axis_lines(centre)
    pts = [kin.flange_point_m(centre, p) for p in [*points, (0.0, 0.0, 0.0)]]
    rel = np.array(pts) - origins[ax - 1]
    along = rel @ dirs[ax - 1]
    return float(np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - along**2, 0.0)).max())


def _swing(centre: np.ndarray, ax: int, payload: Payload, limit_mm_s: float, acc_cap_pct: float,
           exact: bool = True) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The two ends of a swing of axis ``ax`` about ``centre``, its T1-safe $VEL_AXIS % and its $ACC_AXIS %.

    ``exact``: the speed from the interlock's bound over the swing (else from the lever alone, for the optimiser)."""
    j = ax - 1
    pts = list(payload.points_flange_m)
    limits = kin.robot_arrays().joint_limits_deg
    lo, hi = limits[j][0] + LIMIT_MARGIN_DEG, limits[j][1] - LIMIT_MARGIN_DEG
    lever = max(_lever_m(centre, ax, pts), 1e-3)
    w_deg_s = math.degrees(kin.SPEED_HEADROOM * limit_mm_s / 1000.0 / lever)
    pct = _round_down(min(100.0, 100.0 * w_deg_s / kin.robot_arrays().max_axis_speed_deg_s[j]))
    v = pct / 100.0 * kin.robot_arrays().max_axis_speed_deg_s[j]
    a_max = nominal_max_accel_deg_s2()[j]
    acc_pct = _round_down(min(acc_cap_pct, 100.0 * v / (MIN_RAMP_S * a_max)))
    a = acc_pct / 100.0 * a_max
    amp = max(2.0, min(MAX_AMPLITUDE_DEG, 0.5 * (v * v / a + v * PLATEAU_S), centre[j] - lo, hi - centre[j]))
    amp = math.ceil(amp * 100.0) / 100.0  # targets with two decimals: what the program says is what is checked
    up, down = centre.copy(), centre.copy()
    up[j] += amp
    down[j] -= amp
    if exact:
        pct = min(pct, safe_single_axis_pct(down, up, pts, limit_mm_s), safe_single_axis_pct(centre, up, pts,
                                                                                               limit_mm_s))
    return up, down, pct, acc_pct


def _block(base: np.ndarray, q5: float, q6: float, payload: Payload, limit_mm_s: float, repeats: int,
           acc_cap_pct: float, exact: bool = True) -> list[Move]:
    """Moves of one orientation: for A6, A5, A4 in turn: to +amp, ``repeats`` × (−amp, +amp), back to the centre."""
    centre = base.copy()
    centre[4], centre[5] = q5, q6
    moves = []
    for ax in SWING_AXES:
        up, down, pct, acc_pct = _swing(centre, ax, payload, limit_mm_s, acc_cap_pct, exact)
        vel = tuple(pct if i == ax - 1 else 100.0 for i in range(6))
        acc = tuple(acc_pct if i == ax - 1 else acc_cap_pct for i in range(6))
        moves.append(Move(tuple(up.tolist()), vel, acc, None))
        for _ in range(repeats):
            moves.append(Move(tuple(down.tolist()), vel, acc, ax))
            moves.append(Move(tuple(up.tolist()), vel, acc, ax))
        moves.append(Move(tuple(centre.tolist()), vel, acc, None))
    return moves


def _reposition(q0: np.ndarray, q1: np.ndarray, payload: Payload, limit_mm_s: float, acc_pct: float) -> Move:
    vmax = kin.robot_arrays().max_axis_speed_deg_s
    bound = kin.max_point_speed_mm_s(q0, q1, vmax, payload.points_flange_m).bound_mm_s
    pct = 100.0 if bound == 0 else _round_down(min(100.0, 100.0 * kin.SPEED_HEADROOM * limit_mm_s / bound))
    return Move(tuple(q1.tolist()), (pct * REPOSITION_FRACTION,) * 6, (acc_pct,) * 6, None)


def program_moves(start: np.ndarray, base: np.ndarray, orientations: Sequence[tuple[float, float]],
                  payload: Payload, limit_mm_s: float, acc_pct: float, repeats: int = REPEATS,
                  exact: bool = True) -> list[Move]:
    """Every move of the program: to each orientation, its block, and back to ``start``."""
    moves: list[Move] = []
    here = np.asarray(start, float)
    for q5, q6 in orientations:
        centre = base.copy()
        centre[4], centre[5] = q5, q6
        moves.append(_reposition(here, centre, payload, limit_mm_s, acc_pct))
        moves.extend(_block(base, q5, q6, payload, limit_mm_s, repeats, acc_pct, exact))
        here = centre
    moves.append(_reposition(here, np.asarray(start, float), payload, limit_mm_s, acc_pct))
    return moves


def planned_motion(start: Sequence[float], moves: Sequence[Move], step_s: float = DESIGN_STEP_S) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """q, q̇, q̈ (deg, deg/s, deg/s²) of the moves as planned, the swing axis of each sample (0: none), total time."""
    here = np.asarray(start, float)
    qs, qds, qdds, tags = [], [], [], []
    total = 0.0
    for m in moves:
        target = np.asarray(m.target_deg, float)
        q, qd, qdd, dur = _plan(here, target, m.vel_axis_pct, m.acc_axis_pct, step_s)
        qs.append(q)
        qds.append(qd)
        qdds.append(qdd)
        tags.append(np.full(len(q), m.swing_axis or 0))
        total += dur
        here = target
    return np.vstack(qs), np.vstack(qds), np.vstack(qdds), np.concatenate(tags), total


def information(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, tags: np.ndarray) -> np.ndarray:
    """Information matrix (6×6) of the inertia parameters from the swing samples of the wrist axes, unit noise,
    with each axis's Coulomb, viscous and offset columns eliminated (Schur complement)."""
    sel = tags > 0
    y = inr.payload_regressor(q[sel], qd[sel], qdd[sel])
    info = np.zeros((6, 6))
    for ax in inr.WRIST_AXES:
        rows = (tags[sel] == ax) & (np.abs(qd[sel, ax - 1]) > inr.MIN_SPEED_DEG_S)
        if rows.sum() < 4:
            continue
        a = y[rows, ax - 1, 4:]
        n = np.stack([np.sign(qd[sel][rows, ax - 1]), np.deg2rad(qd[sel][rows, ax - 1]), np.ones(int(rows.sum()))],
                     axis=1)
        ann = n.T @ n + 1e-9 * np.eye(3)
        info += a.T @ a - a.T @ n @ np.linalg.solve(ann, n.T @ a)
    return info


def _criterion(info: np.ndarray) -> tuple[float, float]:
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= 0:
        return -math.inf, math.inf
    return float(np.sum(np.log(ev))), float(math.sqrt(ev[-1] / ev[0]))


def acceleration_pct(base: np.ndarray, payload: Payload, limit_mm_s: float) -> float:
    """Largest $ACC_AXIS % (≤ 100) whose peak payload torque on A4–A6 stays within the load diagram's limit, for a
    generous inertia (:func:`_upper_inertia_kgm2`), over swings in the base orientation at the T1 speed."""
    cog = np.asarray(payload.cog_flange_m, float)
    pts = np.asarray(payload.points_flange_m, float).reshape(-1, 3)
    i_c = _upper_inertia_kgm2(payload.mass_kg, pts if len(pts) else cog[None, :], cog)
    pi = inr.body_params(payload.mass_kg, cog, i_c)
    for pct in (100.0, 70.0, 50.0, 35.0, 25.0, 15.0, 10.0):
        moves = _block(base, base[4], base[5], payload, limit_mm_s, 1, pct, exact=False)
        q, qd, qdd, _, _ = planned_motion(base, moves)
        peak = float(np.abs(inr.payload_torques_nm(q, qd, qdd, pi)[:, 3:6]).max())
        if peak <= payload.max_wrist_torque_nm:
            return pct
    raise ValueError(f"inertia excitation: even 10 % $ACC_AXIS exceeds the load diagram's "
                     f"{payload.max_wrist_torque_nm:g} Nm on the wrist")


def design(payload: Payload, *, base_deg: Sequence[float] | None = None, start_deg: Sequence[float] | None = None,
           limit_mm_s: float = 200.0, n_blocks: int = N_BLOCKS, repeats: int = REPEATS,
           optimise: bool = True, max_evaluations: int = 40) -> Excitation:
    """The excitation program for ``payload`` under ``limit_mm_s`` (see the module docstring).

    ``base_deg``: A1..A3 (and A4 as the swing centre) of the blocks, default the measurement pose; ``start_deg``:
    where the program starts and ends (default ``base_deg``).
    """
    base = np.asarray(kin.measurement_pose() if base_deg is None else base_deg, float)
    start = base if start_deg is None else np.asarray(start_deg, float)
    d6_m = kin.robot_arrays().d6_m
    lever_m = float(np.linalg.norm(np.asarray(payload.cog_flange_m) + np.array([0.0, 0.0, d6_m])))
    if payload.mass_kg * kin.G_PAPER_M_S2 * lever_m > payload.max_wrist_torque_nm:
        raise ValueError("inertia excitation: the payload's static wrist torque exceeds the load diagram")
    acc = acceleration_pct(base, payload, limit_mm_s)
    lim5 = np.array([-60.0, 60.0])  # A5 tilt of the blocks: leaves room for the A5 swings inside ±120°

    def orientations(x: np.ndarray) -> list[tuple[float, float]]:
        return [(float(np.clip(x[2 * k], *lim5)), float(np.clip(x[2 * k + 1], -180.0, 180.0)))
                for k in range(n_blocks)]

    def score(x: np.ndarray) -> float:
        moves = program_moves(start, base, orientations(x), payload, limit_mm_s, acc, repeats=1, exact=False)
        q, qd, qdd, tags, _ = planned_motion(start, moves, step_s=2.5 * DESIGN_STEP_S)
        logdet, _ = _criterion(information(q, qd, qdd, tags))
        return -logdet if math.isfinite(logdet) else 1e9

    # a spread start: A5 tilted both ways and level, A6 turned by thirds of a turn
    x0 = np.array([v for k in range(n_blocks) for v in (
        [lim5[1] * 0.75, lim5[0] * 0.75, 0.0][k % 3], -120.0 + 240.0 * k / max(n_blocks - 1, 1))])
    if optimise:
        bounds = [(lim5[0], lim5[1]) if i % 2 == 0 else (-180.0, 180.0) for i in range(len(x0))]
        res = minimize(score, x0, method="Powell", bounds=bounds,
                       options={"maxfev": max_evaluations, "xtol": 1.0, "ftol": 1e-3})
        x = res.x if res.fun <= score(x0) else x0
    else:
        x = x0
    orient = [(round(a, 1), round(b, 1)) for a, b in orientations(x)]
    moves = program_moves(start, base, orient, payload, limit_mm_s, acc, repeats=repeats)
    q, qd, qdd, tags, total = planned_motion(start, moves)
    logdet, cond = _criterion(information(q, qd, qdd, tags))
    here = start
    worst = 0.0
    for m in moves:
        vmax = np.array(m.vel_axis_pct) / 100.0 * np.array(kin.robot_arrays().max_axis_speed_deg_s)
        if not np.allclose(here, m.target_deg):
            worst = max(worst, kin.max_point_speed_mm_s(here, m.target_deg, vmax, payload.points_flange_m).bound_mm_s)
        here = np.asarray(m.target_deg, float)
    return Excitation(tuple(start.tolist()), tuple(moves), total, cond, logdet, limit_mm_s, worst)


def box_corners(centre_flange_m: Sequence[float], half_extent_m: Sequence[float],
                rotation_flange_box: np.ndarray | None = None) -> tuple[tuple[float, float, float], ...]:
    """The 8 corners (flange frame, m) of a box with centre, half extents along its own axes, and orientation."""
    r = np.eye(3) if rotation_flange_box is None else np.asarray(rotation_flange_box, float)
    c = np.asarray(centre_flange_m, float)
    h = np.asarray(half_extent_m, float)
    return tuple(tuple((c + r @ (h * np.array(s))).tolist())
                 for s in [(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
