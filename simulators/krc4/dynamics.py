"""Rigid-body dynamics, friction and the moving torque estimate of the simulated KR 500 R2830 (issue #15).

Contract (the identification of issue #15 relies on it; kept stable)
--------------------------------------------------------------------
* **A DuT with inertia** is a :class:`simulators.krc4.physics.AsymmetricDut`: ``mass_kg``, ``cog_dut_m`` (its CoG in
  its own frame, m), ``dut_origin_flange_m`` and ``dut_abc_deg`` (its frame in the flange frame, KUKA A, B, C
  = Rz·Ry·Rx, deg) and ``inertia_about_cog_kgm2``: its inertia tensor about the CoG **in the DuT frame** (three
  moments along the DuT axes or a full symmetric 3×3, kg·m²). ``dut.rotation`` is the DuT → flange rotation R
  (v_flange = R · v_dut; the tensor in the flange frame is R · I · Rᵀ = ``dut.inertia_flange_kgm2``).
  ``dut.payload()`` mounts it with MPA and fixture (both with their box inertias). Ready-made DuTs:
  ``physics.refex_wing_box()`` (107.3 kg, ≈1.6 × 0.6 × 0.3 m, full tensor with products of inertia) and
  ``physics.compact_cube()`` (60 kg, 0.5 m cube).
* **The simulator's truth**: :func:`true_principal_moments_kgm2` (three floats, ascending, kg·m², about the CoG),
  :func:`true_inertia_dut_kgm2` (the 3×3 tensor about the CoG in the DuT frame) and :func:`true_principal_axes_dut`
  (unit axes as columns, same order). Nothing of this is visible to the daemon.
* **KUKA Trace during a KRL motion**: a trace running while a program moves the robot records, for every
  ``NextGenDrive#k`` module in its configuration and at the configured rate (1, 4 or 12 ms): ``Sollposition`` (the
  planned profile, deg), ``Istposition`` (deg: the arm, which follows the command ``SERVO_LAG_S`` = 4 ms late,
  ±0.0005° jitter), ``Positionsschleppfehler`` (Soll − Ist, deg), ``Geschwindigkeitsdifferenz`` (set − actual
  speed, deg/s), ``Motortemperatur`` (K), ``Istmoment`` (Nm: inverse dynamics of the arm's actual motion +
  friction through the error model below) and ``Iststrom`` (A). There is no speed channel: q̇ and q̈ come from the
  positions. The profile is the one the
  program asked for: synchronised trapezoids from ``$VEL_AXIS``/``$ACC_AXIS``/``$OV_PRO``, slowed in T1 so that the
  flange stays ≤ 250 mm/s (``simulators.krc4.motion``). ``$TORQUE_AXIS_ACT[i]`` read during a motion is the
  noise-free dynamic reading (rigid body + friction through gain, residual and mounting offset).

Rigid body
----------
Recursive Newton–Euler on ``rgse_daemon.kinematics``' modified-DH chain (Craig's form: frame i on link i, gravity
as an upward acceleration of the base). Link masses and CoGs are the scenario's ``arm.links`` (the static arm model
of ``physics.py``), so with q̇ = q̈ = 0 the result equals ``kinematics.link_gravity_torques_nm`` plus the payload's
``gravity_regressor`` torques exactly. Hand-written (≈40 lines of numpy) rather than Pinocchio or the Robotics
Toolbox: neither is in the project's environment, both would need the chain rebuilt as a URDF with KUKA's axis signs,
and the analytic tests (tests/physics/test_dynamics.py) check this one directly. Torques are holding/drive torques
about the KUKA-positive axis direction (the sign of ``kinematics``), q in deg, q̇ in deg/s, q̈ in deg/s².

Assumptions (not KUKA data; plausible for the robot's size, said so here):

* Link inertias about their CoGs (the scenario's ``link_inertia_kgm2``, kg·m², in each link's DH frame): boxes and
  tubes of the links' masses and sizes (KR 500: upper arm 1.3 m long, wrist tube ≈1 m, hand and flange compact),
  plus the rotating column of link 1 (900 kg on the A1 axis; it carries no gravity torque, so the static model is
  unchanged). ``scenarios/kr10r1440.toml`` scales them to the KR 10.
* Rotor and first-stage inertia of each motor ``motor_inertia_kgm2`` (kg·m², motor side), reflected to the axis as
  J_m · N² with the scenario's gear ratio N: A1–A3 motors of the 6–10 kW class (4–6·10⁻³ kg·m²), A4–A6 of the
  1–2 kW class (4–6·10⁻⁴ kg·m²). The rotors' gyroscopic coupling is neglected.

Friction (per axis, axis side, Nm; :class:`AxisFriction`)
--------------------------------------------------------
::

    F(q̇) = s(q̇) · ( [Fc · (1 + α·sign q̇) + μ_L · |τ_rb| + (Fs − Fc) · exp(−(q̇/v_s)²)] · k_c(T)
                    + r · sin(N·q + φ) )
           + Fv · q̇ · k_v(T)                                          (q̇ in rad/s for the viscous term)

with s(q̇) = tanh(q̇ / 0.01 deg/s) (a smoothed sign: the drive supplies friction in the direction of motion),
direction asymmetry α (±4..8 %), load dependence μ_L = 2 % of the rigid-body torque τ_rb the gear transmits,
Stribeck: Fs = 1.3 Fc below v_s = 1 deg/s, viscous Fv, temperature k_c(T) = max(0.5, 1 − 0.5 %/K · (T − T_amb))
and k_v(T) = max(0.3, 1 − 1.5 %/K · (T − T_amb)) (gear oil thins as it warms; the motor winding temperature stands in
for the oil's), ripple r = 0.1 Fc once per motor revolution (N = gear ratio, phase φ fixed per axis).

Sizes: the static model's hysteresis h_i (the friction that stays locked in after an approach, ``hysteresis_nm``)
is the part of the sliding friction the position controller cannot relax at standstill; we take it as
κ = 10 % of Fc, so Fc = 10·h_i (A1 50, A2 100, A3 60, A4 10, A5 40, A6 10 Nm with the default scenario), and the
viscous part equals Fc at the axis' maximum speed (Fv = Fc / ω_max). Wrist friction of 10–40 Nm is 0.5–2 % of the
≈2 kNm a wrist carries at rated load (500 kg at 0.4 m): a plausible size, not a measured one; real gears of this
class may well have more, which only makes the identification harder. At rest the friction term is the static model's
−sign(last approach)·h_i, so a trace that does not move reads exactly as ``RobotModel.sample_trace``.

The torque estimate during motion
---------------------------------
Per sample k (the static error model of ``physics.py`` with the rigid-body torque in place of the static one)::

    rb        = τ_arm(q, q̇, q̈) + M0 + G(|τ_pay(q, q̇, q̈)|) · τ_pay(q, q̇, q̈)      # "static" in TraceTruth.terms
    Istmoment = rb + δ + β (T − T_amb) · rb + ε · rb · exp(−t_rel/τ_rel)
                + F(q̇, T, q) (moving) − sign(last approach) · h (at rest)        # "friction" / "hysteresis"
                + settling after each stop + N(0, σ) + spikes

τ_arm includes the reflected rotor inertias; τ_pay is the payload's share (the RNEA is linear in the inertial
parameters, so it is the full torque minus the bare arm's). t_rel is the time since the last motion ended (0 while
moving).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from simulators.krc4.motion import MotionSamples
from simulators.krc4.physics import AsymmetricDut, Payload, RobotModel, TraceTruth
from simulators.krc4.scenario import Scenario, default_scenario

_Z = np.array([0.0, 0.0, 1.0])

#: The link inertias, the column and the motor inertias are the scenario's arm (``[arm]``: ``link_inertia_kgm2``,
#: ``column_mass_kg``, ``column_cog_m``, ``motor_inertia_kgm2``; default the KR 500's).

#: Friction relative to the static model's hysteresis: Fc = hysteresis_nm / KAPPA_LOCKED.
KAPPA_LOCKED = 0.10
STRIBECK_RATIO = 1.3
STRIBECK_SPEED_DEG_S = 1.0
LOAD_FRICTION_PER_NM = 0.02
COULOMB_TEMP_PER_K = 0.005
VISCOUS_TEMP_PER_K = 0.015
RIPPLE_FRACTION = 0.10
#: Direction asymmetry α per axis (Fc · (1 + α) moving positive, Fc · (1 − α) negative) and ripple phases (rad).
ASYMMETRY: tuple[float, ...] = (0.05, -0.04, 0.06, 0.08, -0.05, 0.07)
RIPPLE_PHASE_RAD: tuple[float, ...] = (0.3, 1.9, 4.1, 2.6, 5.2, 0.8)
#: Speed (deg/s) of the smoothed sign and of the blend into the at-rest hysteresis.
SIGN_SPEED_DEG_S = 0.01
#: Servo lag (s): the arm follows the commanded motion this much later; Istposition and the torques are those of
#: the arm, Sollposition the command (following error ≈ q̇ · lag, Geschwindigkeitsdifferenz ≈ q̈ · lag).
SERVO_LAG_S = 0.004


@dataclass(frozen=True)
class AxisFriction:
    """Friction of one axis (axis side): Coulomb ``coulomb_nm``, viscous ``viscous_nm_s_rad``, Stribeck peak
    ``stribeck_nm`` below ``stribeck_speed_deg_s``, direction asymmetry ``asymmetry``, load share
    ``load_per_nm``, temperature coefficients (per K above ambient), ripple amplitude and its cycles per axis
    radian (the gear ratio: once per motor revolution) and phase."""

    coulomb_nm: float
    viscous_nm_s_rad: float
    stribeck_nm: float
    stribeck_speed_deg_s: float = STRIBECK_SPEED_DEG_S
    asymmetry: float = 0.0
    load_per_nm: float = LOAD_FRICTION_PER_NM
    coulomb_temp_per_k: float = COULOMB_TEMP_PER_K
    viscous_temp_per_k: float = VISCOUS_TEMP_PER_K
    ripple_nm: float = 0.0
    ripple_cycles_per_rad: float = 0.0
    ripple_phase_rad: float = 0.0


def default_friction(scenario: Scenario, scale: float = 1.0) -> tuple[AxisFriction, ...]:
    """Per-axis friction sized from the scenario's hysteresis and gear ratios (module docstring); ``scale``
    multiplies every level (Coulomb, Stribeck, viscous, ripple) for what-if studies (a rougher gear)."""
    if not (np.isfinite(scale) and scale >= 0.0):
        raise ValueError(f"friction scale must be finite and ≥ 0, got {scale}")
    out = []
    for i in range(6):
        ax = scenario.axis(i + 1)
        fc = scale * ax.hysteresis_nm / KAPPA_LOCKED
        w_max = np.deg2rad(robots.active().max_axis_speed_deg_s[i])
        out.append(
            AxisFriction(
                coulomb_nm=fc,
                viscous_nm_s_rad=fc / w_max,
                stribeck_nm=STRIBECK_RATIO * fc,
                asymmetry=ASYMMETRY[i],
                ripple_nm=RIPPLE_FRACTION * fc,
                ripple_cycles_per_rad=ax.gear_ratio,
                ripple_phase_rad=RIPPLE_PHASE_RAD[i],
            )
        )
    return tuple(out)


@dataclass(frozen=True)
class _Link:
    mass_kg: float
    cog_m: np.ndarray  # in the link's DH frame
    inertia_kgm2: np.ndarray  # about the CoG, in the link's DH frame


def _combine(bodies: Sequence[tuple[float, np.ndarray, np.ndarray]]) -> _Link:
    """One rigid body from several (mass, CoG, inertia about that CoG), all in one frame (parallel axes)."""
    m = sum(b[0] for b in bodies)
    if m <= 0.0:
        return _Link(0.0, np.zeros(3), sum((b[2] for b in bodies), np.zeros((3, 3))))
    c = sum(b[0] * np.asarray(b[1]) for b in bodies) / m
    inertia = np.zeros((3, 3))
    for mass, cog, ic in bodies:
        d = np.asarray(cog) - c
        inertia += ic + mass * (d @ d * np.eye(3) - np.outer(d, d))
    return _Link(m, c, inertia)


def _rows(x: np.ndarray) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 6:
        raise ValueError(f"expected axis values of shape (6,) or (n, 6), got {np.shape(x)}")
    if not np.all(np.isfinite(a)):
        raise ValueError("axis values must be finite")
    return a


class RobotDynamics:
    """Inverse dynamics of the scenario's arm (default the KR 500 R2830) with a payload (module docstring).

    ``friction_scale`` multiplies the friction levels (1: the documented sizes). A simulator with other friction:
    ``sim.dynamics = RobotDynamics(sim.model.scenario, friction_scale=3.0, robot=sim.model.robot)``."""

    def __init__(self, scenario: Scenario | None = None, g_m_s2: float | None = None, *,
                 friction_scale: float = 1.0, robot: robots.RobotModel | None = None) -> None:
        sc = scenario if scenario is not None else default_scenario()
        self.scenario = sc
        self.robot = robot
        """The arm whose DH rows the dynamics use (the simulator passes its arm as built, ``RobotModel.robot`` of
        physics.py); None: the active robot's catalogue."""
        self.g_m_s2 = sc.g_m_s2 if g_m_s2 is None else float(g_m_s2)
        per_link: dict[int, list[tuple[float, np.ndarray, np.ndarray]]] = {j: [] for j in range(1, 7)}
        per_link[1].append((sc.arm.column_mass_kg, np.array(sc.arm.column_cog_m), np.zeros((3, 3))))
        for link, mass, cog in sc.arm.links:
            per_link[link].append((float(mass), np.asarray(cog, dtype=float), np.zeros((3, 3))))
        self.links: list[_Link] = []
        for j in range(1, 7):
            combined = _combine(per_link[j])
            self.links.append(_Link(combined.mass_kg, combined.cog_m, combined.inertia_kgm2
                                    + np.diag(sc.arm.link_inertia_kgm2[j])))
        ratios = np.array([sc.axis(i).gear_ratio for i in range(1, 7)])
        self.armature_kgm2 = np.asarray(sc.arm.motor_inertia_kgm2) * ratios**2
        """Reflected rotor inertia per axis (kg·m², axis side)."""
        self.friction = default_friction(sc, friction_scale)

    # --- rigid body ------------------------------------------------------------------------------------------------
    def torques_nm(
        self,
        q_deg: Sequence[float] | np.ndarray,
        qd_deg_s: Sequence[float] | np.ndarray,
        qdd_deg_s2: Sequence[float] | np.ndarray,
        payload: Payload | None = None,
        *,
        shift_z_m: float = 0.0,
        gravity: bool = True,
        armature: bool = True,
    ) -> np.ndarray:
        """Drive torques (Nm, KUKA axis directions) of arm (with reflected rotors) and ``payload``.

        Accepts one state (6,) or n states (n, 6); returns the same shape. ``shift_z_m`` moves the payload along
        the flange axis (a mounting's CoG shift). ``gravity=False``: inertial and centrifugal/Coriolis part only.
        """
        single = np.ndim(q_deg) == 1
        q, qd, qdd = _rows(q_deg), _rows(qd_deg_s), _rows(qdd_deg_s2)
        if not (q.shape == qd.shape == qdd.shape):
            raise ValueError("q, q̇ and q̈ must have the same shape")
        links = list(self.links)
        if payload is not None and payload.bodies:
            pay = _payload_link(payload, shift_z_m)
            l6 = links[5]
            links[5] = _combine([(l6.mass_kg, l6.cog_m, l6.inertia_kgm2), (pay.mass_kg, pay.cog_m, pay.inertia_kgm2)])
        tau = _rnea(q, qd, qdd, links, self.g_m_s2 if gravity else 0.0, self.robot)
        if armature:
            tau = tau + self.armature_kgm2[None, :] * np.deg2rad(qdd)
        return tau[0] if single else tau

    def payload_torques_nm(self, q_deg: np.ndarray, qd_deg_s: np.ndarray, qdd_deg_s2: np.ndarray,
                           payload: Payload, *, shift_z_m: float = 0.0) -> np.ndarray:
        """The payload's share of the drive torques (Nm): with payload minus without (the RNEA is linear in it)."""
        full = self.torques_nm(q_deg, qd_deg_s, qdd_deg_s2, payload, shift_z_m=shift_z_m, armature=False)
        bare = self.torques_nm(q_deg, qd_deg_s, qdd_deg_s2, None, armature=False)
        return full - bare

    def mass_matrix_kgm2(self, q_deg: Sequence[float], payload: Payload | None = None) -> np.ndarray:
        """Joint-space inertia matrix M(q) (6×6, kg·m², KUKA axis directions, per rad/s²)."""
        q = np.repeat(np.asarray(q_deg, dtype=float)[None, :], 6, axis=0)
        unit = np.rad2deg(np.eye(6))  # 1 rad/s² on one axis at a time
        return self.torques_nm(q, np.zeros((6, 6)), unit, payload, gravity=False).T

    # --- friction --------------------------------------------------------------------------------------------------
    def friction_nm(
        self,
        q_deg: np.ndarray,
        qd_deg_s: np.ndarray,
        motor_temp_k: np.ndarray,
        ambient_k: float,
        load_nm: np.ndarray,
    ) -> np.ndarray:
        """Friction torque (Nm, drive sign: the drive supplies it, same sign as the speed) per axis and sample.

        All arguments (n, 6) except ``ambient_k``; ``load_nm`` is the rigid-body torque the gear transmits."""
        q, qd = _rows(q_deg), _rows(qd_deg_s)
        temp = np.broadcast_to(np.asarray(motor_temp_k, dtype=float), q.shape)
        load = np.abs(np.broadcast_to(np.asarray(load_nm, dtype=float), q.shape))
        out = np.empty_like(q)
        for i, f in enumerate(self.friction):
            v = qd[:, i]
            dt_k = temp[:, i] - ambient_k
            k_c = np.maximum(0.5, 1.0 - f.coulomb_temp_per_k * dt_k)
            k_v = np.maximum(0.3, 1.0 - f.viscous_temp_per_k * dt_k)
            sgn = np.tanh(v / SIGN_SPEED_DEG_S)
            fc = f.coulomb_nm * (1.0 + f.asymmetry * np.sign(v)) + f.load_per_nm * load[:, i]
            stribeck = (f.stribeck_nm - f.coulomb_nm) * np.exp(-((v / f.stribeck_speed_deg_s) ** 2))
            ripple = f.ripple_nm * np.sin(f.ripple_cycles_per_rad * np.deg2rad(q[:, i]) + f.ripple_phase_rad)
            out[:, i] = sgn * ((fc + stribeck) * k_c + ripple) + f.viscous_nm_s_rad * np.deg2rad(v) * k_v
        return out


def _payload_link(payload: Payload, shift_z_m: float) -> _Link:
    m = payload.mass_kg
    c = payload.cog_flange_m + np.array([0.0, 0.0, shift_z_m])
    i_o = payload.inertia_flange_kgm2(shift_z_m)
    return _Link(m, c, i_o - m * (c @ c * np.eye(3) - np.outer(c, c)))


def _rnea(q_deg: np.ndarray, qd_deg_s: np.ndarray, qdd_deg_s2: np.ndarray, links: list[_Link],
          g_m_s2: float, robot: robots.RobotModel | None = None) -> np.ndarray:
    """Recursive Newton–Euler (Craig, modified DH), batched over n states; torques (n, 6) in KUKA directions."""
    n = len(q_deg)
    arrays = kin.robot_arrays(robot)
    sign = arrays.axis_sign
    theta = sign * np.deg2rad(q_deg) + arrays.theta_offset_rad
    th_d = sign * np.deg2rad(qd_deg_s)
    th_dd = sign * np.deg2rad(qdd_deg_s2)
    rots, offsets = [], []
    for i in range(6):
        alpha, a, d = arrays.mdh[i]
        ca, sa = np.cos(alpha), np.sin(alpha)
        ct, st = np.cos(theta[:, i]), np.sin(theta[:, i])
        r = np.zeros((n, 3, 3))  # rotation of frame i in frame i−1
        r[:, 0, 0], r[:, 0, 1] = ct, -st
        r[:, 1, 0], r[:, 1, 1], r[:, 1, 2] = st * ca, ct * ca, -sa
        r[:, 2, 0], r[:, 2, 1], r[:, 2, 2] = st * sa, ct * sa, ca
        rots.append(r)
        offsets.append(np.array([a, -sa * d, ca * d]))
    w = np.zeros((n, 3))
    wd = np.zeros((n, 3))
    vd = np.tile(np.array([0.0, 0.0, g_m_s2]), (n, 1))  # gravity as an upward base acceleration
    forces, moments = [], []
    for i in range(6):
        rt = np.transpose(rots[i], (0, 2, 1))
        p = offsets[i]
        vd = np.einsum("nij,nj->ni", rt, np.cross(wd, p) + np.cross(w, np.cross(w, p)) + vd)
        w_prev = np.einsum("nij,nj->ni", rt, w)
        wd = np.einsum("nij,nj->ni", rt, wd) + np.cross(w_prev, _Z * th_d[:, i : i + 1]) + _Z * th_dd[:, i : i + 1]
        w = w_prev + _Z * th_d[:, i : i + 1]
        link = links[i]
        c = link.cog_m
        vc = np.cross(wd, c) + np.cross(w, np.cross(w, c)) + vd
        forces.append(link.mass_kg * vc)
        iw = w @ link.inertia_kgm2.T
        moments.append(wd @ link.inertia_kgm2.T + np.cross(w, iw))
    tau = np.empty((n, 6))
    f = np.zeros((n, 3))
    m = np.zeros((n, 3))
    for i in range(5, -1, -1):
        if i < 5:
            r_next = rots[i + 1]
            f_next = np.einsum("nij,nj->ni", r_next, f)
            m = moments[i] + np.einsum("nij,nj->ni", r_next, m) + np.cross(links[i].cog_m, forces[i]) + np.cross(
                offsets[i + 1], f_next
            )
            f = forces[i] + f_next
        else:
            f = forces[i]
            m = moments[i] + np.cross(links[i].cog_m, forces[i])
        tau[:, i] = m[:, 2]
    return tau * sign[None, :]


# --- the simulator's truth about a DuT (contract) --------------------------------------------------------------------
def true_inertia_dut_kgm2(dut: AsymmetricDut) -> np.ndarray:
    """The DuT's inertia tensor about its CoG in the DuT frame (3×3, kg·m²): the truth."""
    return dut.inertia_dut_kgm2


def true_principal_moments_kgm2(dut: AsymmetricDut) -> np.ndarray:
    """The DuT's principal moments about its CoG (kg·m², three floats, ascending): the truth."""
    return dut.principal_moments_kgm2


def true_principal_axes_dut(dut: AsymmetricDut) -> np.ndarray:
    """The DuT's principal axes in the DuT frame (unit columns, in the order of the moments)."""
    return dut.principal_axes_dut


# --- the torque estimate during motion ------------------------------------------------------------------------------
@dataclass(frozen=True)
class MotionTruth(TraceTruth):
    """Ground truth of a trace taken while the robot moved (a :class:`TraceTruth` whose torques are (6, n)).

    ``q_deg`` is the first sample's pose; the path is in ``q_path_deg``/``qd_path_deg_s``/``qdd_path_deg_s2``
    ((n, 6)); ``true_torque_nm``, ``payload_torque_nm`` and ``arm_torque_nm`` are the rigid-body drive torques per
    axis and sample (6, n) without friction; ``terms`` adds ``friction`` (the sliding friction while moving) to the
    static terms (``hysteresis`` is the at-rest part)."""

    t_s: np.ndarray
    q_path_deg: np.ndarray
    qd_path_deg_s: np.ndarray
    qdd_path_deg_s2: np.ndarray


def _rest_weight(qd_deg_s: np.ndarray) -> np.ndarray:
    """1 at standstill, 0 once the axis slides (blends the at-rest hysteresis into the sliding friction)."""
    return np.exp(-((np.asarray(qd_deg_s) / SIGN_SPEED_DEG_S) ** 2))


def dynamic_reading_nm(model: RobotModel, dynamics: RobotDynamics, q_deg: np.ndarray, qd_deg_s: np.ndarray,
                       qdd_deg_s2: np.ndarray, payload: Payload) -> np.ndarray:
    """Noise-free reading (Nm, (6,)) while moving: τ_arm + M0 + G(|τ_pay|)·τ_pay + δ + friction at the current motor
    temperatures and hysteresis at rest; equals ``RobotModel.static_reading_nm`` plus hysteresis at standstill."""
    q, qd, qdd = (np.asarray(x, dtype=float)[None, :] for x in (q_deg, qd_deg_s, qdd_deg_s2))
    shift = model.mount_cog_shift_m
    tau_arm = dynamics.torques_nm(q, qd, qdd, None)[0]
    tau_pay = dynamics.payload_torques_nm(q, qd, qdd, payload, shift_z_m=shift)[0]
    friction = dynamics.friction_nm(q, qd, model.state.motor_temp_k[None, :], model.ambient_k, tau_arm + tau_pay)[0]
    hyst = np.array([model.scenario.axis(i).hysteresis_nm for i in range(1, 7)])
    at_rest = -model.state.last_approach_sign * hyst * _rest_weight(qd[0])
    return tau_arm + model.residual_nm + model.gains(tau_pay) * tau_pay + model.mount_offset_nm + friction + at_rest


def sample_motion_trace(
    model: RobotModel,
    dynamics: RobotDynamics,
    payload: Payload,
    motion: MotionSamples,
    period_s: float,
    *,
    t_since_release_s: float,
    motor_temp_k: Sequence[float],
    last_approach_sign: Sequence[float],
    actual: MotionSamples | None = None,
) -> dict[int, dict[str, np.ndarray]]:
    """All drive channels of a trace whose samples (every ``period_s``) follow ``motion``; see the module docstring.

    ``motion`` is the commanded motion (``Sollposition``); ``actual`` the motion the arm really makes, i.e. the
    commanded one ``SERVO_LAG_S`` later (the simulator samples its motion history at t − lag): the torques and
    ``Istposition`` follow it. ``None``: no lag (the arm follows the command exactly; ``Istposition`` then lags by
    q̇ · lag to first order). The keyword arguments are the physics state at the first sample (as in
    ``RobotModel.sample_trace``); the model's state is not advanced (the motions do that). The truth goes to
    ``model.last_truth`` (a :class:`MotionTruth`, its path the actual one). Returns ``{axis 1..6: {channel:
    ndarray}}`` like ``RobotModel.sample_trace``.
    """
    command = motion
    if actual is not None:
        if actual.q_deg.shape != motion.q_deg.shape:
            raise ValueError("the commanded and the actual motion must have the same samples")
        motion = actual
    q, qd, qdd = motion.q_deg, motion.qd_deg_s, motion.qdd_deg_s2
    n = len(q)
    if n < 1 or not period_s > 0:
        raise ValueError("a motion trace needs at least one sample and period_s > 0")
    t_k = np.arange(n) * period_s
    shift = model.mount_cog_shift_m
    tau_arm = dynamics.torques_nm(q, qd, qdd, None).T  # (6, n), reflected rotors included
    tau_pay = dynamics.payload_torques_nm(q, qd, qdd, payload, shift_z_m=shift).T
    gain = model.gains(tau_pay)
    static = tau_arm + model.residual_nm[:, None] + gain * tau_pay
    temp0 = np.asarray(motor_temp_k, dtype=float)
    temps = model._temps_after(temp0, t_k, True)  # (6, n): the drives hold or move, brakes released
    approach = np.where(motion.approach != 0.0, motion.approach, np.sign(np.asarray(last_approach_sign))).T
    t_rel = np.where(motion.moving, 0.0, np.where(np.isfinite(motion.t_since_stop_s), motion.t_since_stop_s,
                                                   t_since_release_s + t_k))
    still = ~motion.moving
    sc = model.scenario
    axes = [sc.axis(i) for i in range(1, 7)]
    beta = np.array([a.thermal_coeff_per_k for a in axes])[:, None]
    eps = np.array([a.release_transient_frac for a in axes])[:, None]
    hyst = np.array([a.hysteresis_nm for a in axes])[:, None]
    settle_a = np.array([a.settle_amplitude_nm for a in axes])[:, None]
    sigma = np.array([a.noise_nm for a in axes])[:, None]
    friction = dynamics.friction_nm(q, qd, temps.T, model.ambient_k, (tau_arm + tau_pay).T).T
    terms = {
        "static": static,
        "mount": np.repeat(model.mount_offset_nm[:, None], n, axis=1),
        "thermal": static * beta * (temps - model.ambient_k),
        "release": static * eps * np.exp(-t_rel / sc.release.time_constant_s)[None, :],
        "friction": friction,
        "hysteresis": -approach * hyst * _rest_weight(qd.T),
        "settle": approach * settle_a * (still * np.exp(-t_rel / sc.settle.time_constant_s)
                                         * np.cos(2 * np.pi * sc.settle.frequency_hz * t_rel))[None, :],
        "noise": model.rng.normal(0.0, 1.0, (6, n)) * sigma,
    }
    hits = model.rng.random((6, n)) < sc.spikes.rate_per_sample
    terms["spikes"] = np.where(hits, model.rng.normal(0.0, sc.spikes.amplitude_nm, (6, n)), 0.0)
    torque = sum(terms.values())
    kt_ratio = np.array([a.torque_constant_nm_a * a.gear_ratio for a in axes])
    pos_jitter = model.rng.normal(0.0, 5e-4, (6, n))
    soll = command.q_deg.T
    ist = (q.T if actual is not None else q.T - qd.T * SERVO_LAG_S) + pos_jitter
    speed_diff = command.qd_deg_s.T - qd.T if actual is not None else qdd.T * SERVO_LAG_S
    out: dict[int, dict[str, np.ndarray]] = {}
    for i in range(6):
        out[i + 1] = {
            "Sollposition": soll[i].copy(),
            "Istposition": ist[i],
            "Positionsschleppfehler": soll[i] - ist[i],
            "Geschwindigkeitsdifferenz": speed_diff[i] + model.rng.normal(0.0, 0.02, n),
            "Motortemperatur": np.round(temps[i], 1),
            "Istmoment": torque[i],
            "Iststrom": torque[i] / kt_ratio[i],
        }
    model.last_truth = MotionTruth(
        q_deg=q[0].copy(),
        payload_mass_kg=payload.mass_kg,
        payload_cog_flange_m=payload.cog_flange_m + np.array([0.0, 0.0, shift]),
        true_torque_nm=tau_arm + tau_pay,
        payload_torque_nm=tau_pay,
        arm_torque_nm=tau_arm,
        residual_nm=model.residual_nm.copy(),
        gain=gain,
        t_since_release_s=float(t_rel[0]),
        motor_temp_k=temps,
        last_approach_sign=approach,
        period_s=period_s,
        terms=terms,
        t_s=t_k,
        q_path_deg=q.copy(),
        qd_path_deg_s=qd.copy(),
        qdd_path_deg_s2=qdd.copy(),
    )
    return out
