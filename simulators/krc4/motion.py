"""Joint motion of the simulated KR 500 R2830 in (simulated) time.

A PTP motion is a *synchronised* trapezoidal profile: every axis follows the straight line in joint space from start
to target, all axes start, reach constant speed, brake and arrive together (KUKA PTP). The common path parameter
``s`` (0 → 1) runs with the largest speed and acceleration that no axis exceeds:

* axis speed limit    ``$VEL_AXIS[i] % · MAX_AXIS_SPEED_DEG_S[i] · $OV_PRO %``
* axis accel. limit   ``$ACC_AXIS[i] % · MAX_AXIS_ACCEL_DEG_S2[i] · ($OV_PRO %)²`` (the override scales time, so
  acceleration goes with its square and the path stays the same)

T1 (``t1_limit_mm_s`` given): the planner lowers the path speed so that the flange never exceeds the limit
(250 mm/s by default, ISO 10218-1 reduced speed). This is what KSS does with ``$SPEED_LIMIT_TEACH_MODE`` and
spline/PTP motions in T1: the motion is *slowed*, not refused (the safety controller would stop the robot only if the
planned speed were exceeded anyway).

LIN in this simulator is joint-interpolated (no inverse kinematics): a LIN to an axis target moves like a PTP whose
flange speed is capped at ``$VEL.CP``; the path is then not exactly straight in Cartesian space. LIN/PTP to Cartesian
targets are refused by the interpreter for the same reason.

STOP 2 (enabling switch released): :meth:`JointMove.stopped_at` ramps the motion down *on its path* with the
profile's deceleration.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.errors import RgseError
from rgse_daemon.kinematics import MAX_AXIS_SPEED_DEG_S, point_velocity_mm_s

#: Time (s) an axis needs to reach its maximum speed at 100 % $ACC_AXIS and 100 % override: an assumption of the
#: simulator (KUKA publishes no accelerations); it sets the axis accelerations (:func:`max_axis_accel_deg_s2`).
RAMP_TIME_AT_100_PCT_S = 0.5
#: The default robot's (an alias); the motion uses the active robot's.
MAX_AXIS_ACCEL_DEG_S2: tuple[float, ...] = tuple(v / RAMP_TIME_AT_100_PCT_S for v in MAX_AXIS_SPEED_DEG_S)


def max_axis_accel_deg_s2() -> tuple[float, ...]:
    """The simulated robot's (the active robot's) axis accelerations at 100 % $ACC_AXIS and override (deg/s²)."""
    return tuple(v / RAMP_TIME_AT_100_PCT_S for v in robots.active().max_axis_speed_deg_s)
#: Cartesian speed the controller enforces in T1 (mm/s).
T1_LIMIT_MM_S = 250.0
#: Path sampling for the Cartesian speed limits: at most this many degrees between samples on the largest axis.
SAMPLE_STEP_DEG = 0.5

FlangeSpeed = Callable[[np.ndarray, np.ndarray], float]
"""``fn(q_deg, qdot_deg_s) -> flange speed in mm/s``."""


class MotionError(RgseError):
    """A motion the simulated controller refuses (target outside the software limits, zero speed ...)."""


def flange_speed_mm_s(q_deg: Sequence[float] | np.ndarray, qdot_deg_s: Sequence[float] | np.ndarray) -> float:
    """Cartesian speed (mm/s) of the flange centre at axis angles ``q_deg`` moving at ``qdot_deg_s`` (deg/s)."""
    return float(np.linalg.norm(point_velocity_mm_s(q_deg, qdot_deg_s)))


@dataclass(frozen=True)
class Segment:
    """Constant acceleration of the path parameter from ``t0_s``: start ``s0``, speed ``v0`` (1/s), ``a`` (1/s²)."""

    t0_s: float
    duration_s: float
    s0: float
    v0: float
    a: float

    def at(self, t_s: float) -> tuple[float, float]:
        dt = min(max(t_s - self.t0_s, 0.0), self.duration_s)
        return self.s0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt


@dataclass(frozen=True)
class Profile:
    """Path parameter ``s(t)`` as consecutive constant-acceleration segments; ``decel`` (1/s²) is its braking rate."""

    segments: tuple[Segment, ...]
    decel: float

    @property
    def duration_s(self) -> float:
        last = self.segments[-1]
        return last.t0_s + last.duration_s

    def sample(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, ds/dt, d²s/dt²)`` at the times ``t_s`` since the start (arrays; at rest before and after)."""
        t = np.asarray(t_s, dtype=float)
        first, last = self.segments[0], self.segments[-1]
        s_end, v_end = last.at(self.duration_s)
        s = np.where(t < 0.0, first.s0, s_end)
        v = np.where(t < 0.0, 0.0, v_end)
        a = np.zeros_like(t)
        for k, seg in enumerate(self.segments):
            end = seg.t0_s + seg.duration_s
            inside = (t >= seg.t0_s) & ((t < end) if k < len(self.segments) - 1 else (t <= end))
            dt = t - seg.t0_s
            s = np.where(inside, seg.s0 + seg.v0 * dt + 0.5 * seg.a * dt * dt, s)
            v = np.where(inside, seg.v0 + seg.a * dt, v)
            a = np.where(inside & (seg.duration_s > 0.0), seg.a, a)
        return s, v, a

    def at(self, t_s: float) -> tuple[float, float]:
        """``(s, ds/dt)`` at time ``t_s`` since the start (clamped to the profile's ends)."""
        for seg in self.segments:
            if t_s <= seg.t0_s + seg.duration_s:
                return seg.at(t_s)
        return self.segments[-1].at(self.duration_s)

    @staticmethod
    def trapezoid(v_max: float, a_max: float) -> Profile:
        """Rest-to-rest profile over ``s`` = 0 → 1 with peak speed ``v_max`` and acceleration ``a_max`` (per s, s²).

        Falls back to a triangle when the distance is too short to reach ``v_max``.
        """
        if not (v_max > 0.0 and a_max > 0.0 and math.isfinite(v_max) and math.isfinite(a_max)):
            raise MotionError(f"a motion needs positive speed and acceleration (got {v_max}, {a_max})")
        t_ramp = v_max / a_max
        if v_max * t_ramp >= 1.0:  # triangle: never reaches v_max
            t_ramp = math.sqrt(1.0 / a_max)
            v_peak = a_max * t_ramp
            return Profile((Segment(0.0, t_ramp, 0.0, 0.0, a_max), Segment(t_ramp, t_ramp, 0.5, v_peak, -a_max)), a_max)
        s_ramp = 0.5 * v_max * t_ramp
        t_const = (1.0 - 2.0 * s_ramp) / v_max
        return Profile(
            (
                Segment(0.0, t_ramp, 0.0, 0.0, a_max),
                Segment(t_ramp, t_const, s_ramp, v_max, 0.0),
                Segment(t_ramp + t_const, t_ramp, 1.0 - s_ramp, v_max, -a_max),
            ),
            a_max,
        )


@dataclass(frozen=True)
class MotionSettings:
    """The settings in force for a motion (KRL system variables), as percentages and m/s."""

    vel_axis_pct: tuple[float, ...] = (100.0,) * 6
    acc_axis_pct: tuple[float, ...] = (100.0,) * 6
    override_pct: float = 100.0
    vel_cp_m_s: float = 2.0


@dataclass(frozen=True)
class JointMove:
    """One planned motion: axis angles along the straight joint-space line ``q_start_deg`` → ``q_end_deg``."""

    kind: str  # "PTP" or "LIN"
    q_start_deg: tuple[float, ...]
    q_end_deg: tuple[float, ...]
    profile: Profile
    t1_clamped: bool = False
    """True when the T1 Cartesian limit made the motion slower than its axis settings would allow."""

    @property
    def duration_s(self) -> float:
        return self.profile.duration_s

    @property
    def delta_deg(self) -> np.ndarray:
        return np.asarray(self.q_end_deg) - np.asarray(self.q_start_deg)

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Axis angles (deg) and speeds (deg/s) ``t_s`` seconds after the start."""
        s, v = self.profile.at(t_s)
        delta = self.delta_deg
        return np.asarray(self.q_start_deg) + s * delta, v * delta

    def sample(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Axis angles (deg), speeds (deg/s) and accelerations (deg/s²), each (n, 6), at times ``t_s`` (n,)
        since the start."""
        s, v, a = self.profile.sample(np.atleast_1d(np.asarray(t_s, dtype=float)))
        delta = self.delta_deg
        return np.asarray(self.q_start_deg) + s[:, None] * delta, v[:, None] * delta, a[:, None] * delta

    def directions(self) -> tuple[int, ...]:
        """Sign (+1, −1, 0) of each axis' travel: which side the axes approach the target from."""
        return tuple(int(np.sign(d)) for d in self.delta_deg)

    def stopped_at(self, t_s: float) -> JointMove:
        """The same motion braking on its path from time ``t_s`` on (STOP 2): it ends where the ramp-down ends.

        The returned move starts at the position of time ``t_s`` and its ``q_end_deg`` is where the robot comes to
        rest; its path parameter is measured along the *original* line, so the stop never leaves the path.
        """
        s, v = self.profile.at(t_s)
        decel = self.profile.decel
        t_stop = v / decel if v > 0.0 else 0.0
        s_rest = min(1.0, s + 0.5 * v * t_stop)
        delta = self.delta_deg
        q_now = np.asarray(self.q_start_deg) + s * delta
        q_rest = np.asarray(self.q_start_deg) + s_rest * delta
        span = s_rest - s
        if span <= 1e-12 or t_stop <= 0.0:
            profile = Profile((Segment(0.0, 0.0, 0.0, 0.0, 0.0),), decel)
            return JointMove(self.kind, tuple(q_now), tuple(q_now), profile, self.t1_clamped)
        # re-normalise: the new path parameter runs 0 → 1 over [q_now, q_rest]
        profile = Profile((Segment(0.0, t_stop, 0.0, v / span, -decel / span),), decel / span)
        return JointMove(self.kind, tuple(q_now), tuple(q_rest), profile, self.t1_clamped)


def check_limits(q_deg: Sequence[float]) -> None:
    """Refuse a target outside the axis software limits (docs/controller.md §1), as the controller does before
    moving."""
    for i, (q, (lo, hi)) in enumerate(zip(q_deg, robots.active().axis_range_deg, strict=True), 1):
        if not lo <= q <= hi:
            raise MotionError(f"A{i} target {q:.3f} deg is outside the software limits {lo:g}..{hi:g} deg")


def axis_lines_batched(q_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``kinematics.axis_lines`` for many poses at once: origins (n, 6, 3) m and KUKA-positive directions (n, 6, 3)
    of the six axes for q (n, 6) deg; the origin of axis 6 is the flange's. The same modified-DH chain, batched
    (the T1 planner and a moving trace need hundreds to thousands of poses; one at a time that took ~75 ms per
    motion, during which the simulated robot stood still)."""
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    theta = kin.robot_arrays().axis_sign * np.deg2rad(q) + kin.robot_arrays().theta_offset_rad
    n = len(q)
    t = np.tile(np.eye(4), (n, 1, 1))
    origins, dirs = np.empty((n, 6, 3)), np.empty((n, 6, 3))
    for i in range(6):
        alpha, a, d = kin.robot_arrays().mdh[i]
        ca, sa = np.cos(alpha), np.sin(alpha)
        ct, st = np.cos(theta[:, i]), np.sin(theta[:, i])
        step = np.zeros((n, 4, 4))
        step[:, 0, 0], step[:, 0, 1], step[:, 0, 3] = ct, -st, a
        step[:, 1, 0], step[:, 1, 1], step[:, 1, 2], step[:, 1, 3] = st * ca, ct * ca, -sa, -sa * d
        step[:, 2, 0], step[:, 2, 1], step[:, 2, 2], step[:, 2, 3] = st * sa, ct * sa, ca, ca * d
        step[:, 3, 3] = 1.0
        t = t @ step
        origins[:, i], dirs[:, i] = t[:, :3, 3], t[:, :3, 2] * kin.robot_arrays().axis_sign[i]
    return origins, dirs


def flange_speeds_mm_s(q_deg: np.ndarray, qdot_deg_s: np.ndarray) -> np.ndarray:
    """:func:`flange_speed_mm_s` for many poses at once (q (n, 6) deg, one q̇ (6,) deg/s)."""
    origins, dirs = axis_lines_batched(q_deg)
    flange = origins[:, 5]
    w = np.deg2rad(np.asarray(qdot_deg_s, dtype=float))
    v = np.einsum("i,nij->nj", w, np.cross(dirs, flange[:, None, :] - origins))
    return np.linalg.norm(v, axis=1) * 1000.0


def path_speed_per_unit(q_start_deg: np.ndarray, delta_deg: np.ndarray, speed_fn: FlangeSpeed) -> float:
    """Largest flange speed (mm/s) along the joint line per unit of path-parameter speed ``ds/dt`` (1/s)."""
    n = max(2, math.ceil(float(np.abs(delta_deg).max()) / SAMPLE_STEP_DEG) + 1)
    s = np.linspace(0.0, 1.0, n)
    if speed_fn is flange_speed_mm_s:
        return float(flange_speeds_mm_s(q_start_deg + s[:, None] * delta_deg, delta_deg).max())
    return max(speed_fn(q_start_deg + sk * delta_deg, delta_deg) for sk in s)


def plan_joint_move(
    kind: str,
    q_start_deg: Sequence[float],
    q_end_deg: Sequence[float],
    settings: MotionSettings,
    *,
    t1_limit_mm_s: float | None = None,
    speed_fn: FlangeSpeed = flange_speed_mm_s,
) -> JointMove:
    """Plan a PTP (or joint-interpolated LIN) from ``q_start_deg`` to ``q_end_deg`` (deg).

    ``t1_limit_mm_s``: the Cartesian flange speed limit of T1 (``None`` outside T1). A LIN additionally keeps the
    flange at or below ``settings.vel_cp_m_s``.

    Raises
    ------
    MotionError
        Target outside the axis limits, or a speed/acceleration/override of zero.
    """
    if kind not in ("PTP", "LIN"):
        raise MotionError(f"unknown motion kind {kind}")
    q0 = np.asarray(q_start_deg, dtype=float)
    q1 = np.asarray(q_end_deg, dtype=float)
    check_limits(q1)
    delta = q1 - q0
    moving = np.abs(delta) > 1e-9
    if not moving.any():
        return JointMove(kind, tuple(q0), tuple(q1), Profile((Segment(0.0, 0.0, 0.0, 0.0, 0.0),), 1.0))
    ov = settings.override_pct / 100.0
    v_axis = np.array(settings.vel_axis_pct) / 100.0 * np.array(robots.active().max_axis_speed_deg_s) * ov
    a_axis = np.array(settings.acc_axis_pct) / 100.0 * np.array(max_axis_accel_deg_s2()) * ov * ov
    if np.any(v_axis[moving] <= 0.0) or np.any(a_axis[moving] <= 0.0):
        raise MotionError("axis speed, acceleration and override must be above 0 % for the axes that move")
    v_path = float(np.min(v_axis[moving] / np.abs(delta[moving])))
    a_path = float(np.min(a_axis[moving] / np.abs(delta[moving])))
    cart_limits = []
    if t1_limit_mm_s is not None:
        cart_limits.append(t1_limit_mm_s)
    if kind == "LIN":
        cart_limits.append(settings.vel_cp_m_s * 1000.0 * ov)
    clamped = False
    if cart_limits:
        per_unit = path_speed_per_unit(q0, delta, speed_fn)
        if per_unit > 0.0:
            v_cart = min(cart_limits) / per_unit
            if v_cart < v_path:
                clamped = t1_limit_mm_s is not None and t1_limit_mm_s / per_unit < v_path
                v_path = v_cart
    return JointMove(kind, tuple(q0), tuple(q1), Profile.trapezoid(v_path, a_path), clamped)


@dataclass(frozen=True)
class MotionSamples:
    """The robot's axes at a set of times (see :meth:`MotionHistory.sample`)."""

    q_deg: np.ndarray  # (n, 6)
    qd_deg_s: np.ndarray  # (n, 6)
    qdd_deg_s2: np.ndarray  # (n, 6)
    moving: np.ndarray  # (n,) bool: a motion is under way
    t_since_stop_s: np.ndarray  # (n,) time since the last motion came to rest; NaN if none did before
    approach: np.ndarray  # (n, 6) sign of each axis' travel in the last motion that moved it; 0 if none


class MotionHistory:
    """The motions the robot made, as planned, in the simulator's clock: the axes, speeds and accelerations at any
    time follow from them exactly (the KRL interpreter only sees them once per interpolation cycle).

    Every motion is recorded at its start with :meth:`add`; a later entry (a STOP 2 ramp, a resumed motion)
    supersedes the earlier one from its own start time. Entries older than ``keep_s`` before the newest are
    dropped.
    """

    def __init__(self, keep_s: float = 3600.0) -> None:
        self.keep_s = keep_s
        self._entries: list[tuple[float, JointMove]] = []

    def add(self, t0_s: float, move: JointMove) -> None:
        self._entries.append((float(t0_s), move))
        horizon = t0_s - self.keep_s
        while len(self._entries) > 1 and self._entries[1][0] < horizon:
            self._entries.pop(0)

    def active(self, t_s: float) -> JointMove | None:
        """The motion under way at ``t_s`` (None when at rest)."""
        for t0, move in reversed(self._entries):
            if t0 <= t_s:
                return move if t_s < t0 + move.duration_s else None
        return None

    def sample(self, t_s: np.ndarray, q_rest_deg: Sequence[float] | None = None) -> MotionSamples:
        """The axes at the times ``t_s`` (n,). ``q_rest_deg``: where the robot stands before the first entry
        (default: that entry's start)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        n = len(t)
        entries = list(self._entries)  # a trace is sampled in a worker thread while the interpreter may add moves
        if q_rest_deg is None:
            q_rest_deg = entries[0][1].q_start_deg if entries else (0.0,) * 6
        q = np.tile(np.asarray(q_rest_deg, dtype=float), (n, 1))
        qd = np.zeros((n, 6))
        qdd = np.zeros((n, 6))
        moving = np.zeros(n, dtype=bool)
        since = np.full(n, np.nan)
        approach = np.zeros((n, 6))
        starts = [t0 for t0, _ in entries] + [np.inf]
        for k, (t0, move) in enumerate(entries):
            t_end = t0 + move.duration_s
            mask = (t >= t0) & (t < starts[k + 1])
            if not mask.any():
                continue
            qk, qdk, qddk = move.sample(t[mask] - t0)
            q[mask], qd[mask], qdd[mask] = qk, qdk, qddk
            moving[mask] = t[mask] < t_end
            rest = mask & (t >= t_end)
            since[rest] = t[rest] - t_end
            dirs = np.array(move.directions(), dtype=float)
            moved = dirs != 0
            approach[np.ix_(mask, moved)] = dirs[moved]
        # an axis the current entry does not move keeps the direction of the last entry that moved it
        for i in range(6):
            col = approach[:, i]
            for k in range(1, n):
                if col[k] == 0.0:
                    col[k] = col[k - 1]
        return MotionSamples(q, qd, qdd, moving, since, approach)
