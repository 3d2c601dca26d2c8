"""Physics of the simulated KR 500 R2830: the payload chain, static gravity torques, and the controller's torque
estimate (``Istmoment``) with the error sources the paper reports.

API (small on purpose; the KUKA Trace engine and the KRL interpreter use only this)::

    model = RobotModel(scenario=None, seed=0)          # None: scenarios/default.toml
    payload = mass_calibration_payload(n_cb=3)          # MPA + 3 calibration bodies; or dut_payload(...), ...
    model.true_torques_nm(q_deg, payload)               # (6,) gravity holding torques, Nm, A1..A6
    model.move(q_from_deg, q_to_deg, duration_s)        # a motion: heats the motors, sets the approach directions,
                                                        # restarts the settling/release clock at its end
    model.brake_release_move(q_deg)                     # the paper's ±35° A3/A5 brake-release move (§2.4.4)
    model.hold(duration_s); model.apply_brakes(duration_s)   # standing with brakes open / closed (cooling)
    model.new_mounting()                                # a load (re-)mounted: a new per-mounting offset δ
    trace = model.sample_trace(q_deg, payload, n_samples=1000, period_s=0.012)
    trace[3]["Istmoment"]                               # ndarray, Nm; axes 1..6, channels in CHANNELS
    model.last_truth                                    # TraceTruth: true mass/CoG/torques and every error term

``sample_trace`` uses and advances the model's state (motor temperatures, time since the last motion, approach
directions); the keyword overrides ``t_since_release_s``, ``motor_temp_k`` and ``last_approach_sign`` replace the
state for that trace only (the state still advances by the trace's duration). Deterministic for a given seed and
call sequence (one ``np.random.Generator``).

Torque estimate of axis i at sample k (all Nm, holding-torque sign of ``rgse_daemon.kinematics``)::

    static    = τ_arm(q) + M0_i + G_i(|τ_pay|) · τ_pay           # M0: residual (eq. 17–18), G: Table 1 gain
              + δ_i                                              # offset of this mounting (new_mounting())
    Istmoment = static · (1 + β_i (T_k − T_amb))                  # slow drift with motor temperature
              + ε_i · static · exp(−t_k/τ_rel)                    # transient after each brake release
              − sign(last approach) · h_i                         # friction hysteresis
              + A_i exp(−t_k/τ_s) cos(2π f t_k)                   # settling after the brake-release move
              + N(0, σ_i) + sparse spikes

``Iststrom`` = Istmoment / (k_t · gear ratio) (A; the controller derives the torque from the current with its
nominal constants), ``Motortemperatur`` = winding temperature T_k (K, first order: heats towards
T_amb + rise while the brakes are open, cools towards T_amb while they are applied; ≈2 K per 12 s trace from cold).
Position channels: ``Sollposition`` / ``Istposition`` (deg, axis side), ``Positionsschleppfehler`` (deg),
``Geschwindigkeitsdifferenz`` (deg/s).

Payload chain geometry, derived from Table 1 (see ``paper_levers_m``): the printed levers grow 7.5 mm per body and
the expected torques equal g·m·(printed lever − 0.020 m). So the *effective* lever of n bodies to A5 is
0.275 + 0.0075·n m (to A3: + d4 = 1.025 m), the MPA's CoG sits at 0.265 m: a 20 mm MPA whose front face is at
0.275 m from the A5 axis, carrying 15 mm plates (440 × 440 mm, 20.93 kg: steel with the Ø120 mm cut-out) stacked
horizontally, each adding half its thickness to the stack's CoG lever. With d6 = 290 mm the MPA's back face would be
at 0.290 m, not 0.255 m: the paper's levers are 35 mm shorter than the data-sheet flange distance implies. We keep
the paper's levers (they define Table 1's expected torques and the campaign manifests): the simulated chain starts at
flange z = ``CHAIN_ORIGIN_Z_M`` = −0.035 m. A modelling choice, not a physical claim.

The arm as built (``[kinematics]`` of the scenario): a real arm is not its catalogue. Each simulated robot (each seed,
its own random stream) draws its DH lengths, twists and zero offsets about the catalogue's once (:func:`as_built_robot`;
default KR 500: σ 0.5 mm per length, 0.01° per twist, 0.02° per zero offset) and keeps them. Every torque (the
static ``arm_torques_nm`` / ``payload_torques_nm`` and the dynamics, ``RobotDynamics(robot=model.robot)``) uses the arm
as built; the axis angles the controller reports and plans with, and everything the daemon computes, use the
catalogue. So a lever the daemon takes from the DH rows is off by what this arm's lengths and mastering are off, as on
a real KR C4 without KUKA's absolute-accuracy option. ``model.robot`` is the arm as built,
``model.kinematics_deviation`` the draws.

Test adapter (torque-based calibration, Fig. 18): 19.20 kg (Table 1: 228.51 kg − 10 × 20.93 kg) with its CoG
placed so that its A5 torque in the measurement pose is Table A1's 217.95 Nm (lever 1.157 m). Its A3 torque is then
217.95 + g·19.20·d4 = 411.0 Nm, not Table A1's 646.79 Nm: that value would need a 42.65 kg adapter and contradicts
Table 1's total mass under eq. 3, so we follow Table 1. With the bodies at A5 levers 0.761 / 1.011 / 1.261 m the
three torque rows reproduce Table 1's expected A5 torques exactly and A3 within 0.25 %.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.robots import CalibrationLoads, DhRow
from rgse_daemon.robots import RobotModel as ArmKinematics
from rgse_daemon.trace.channels import DRIVE_CHANNEL_UNITS
from simulators.krc4.scenario import AXIS_KEYS, Kinematics, Scenario, default_scenario

#: The drive channels a trace holds, with their units: the daemon's table (one list for both sides of the link).
CHANNEL_UNITS = DRIVE_CHANNEL_UNITS
CHANNELS = tuple(CHANNEL_UNITS)

# --- payload chain (paper §2.2, §2.4.2–2.4.3, Table 1, Table A1) -------------------------------------------------
# The load set's figures are the robot's (rgse_daemon/robots/: ``calibration``); the functions below take the active
# robot's. These module names are the default robot's (KR 500), kept as aliases.
STAINLESS_DENSITY_KG_M3 = 7900.0
_KR500 = robots.get(robots.DEFAULT_KEY).calibration
CHAIN_ORIGIN_Z_M = _KR500.chain_origin_z_m
"""Flange-frame z of the MPA's back face, chosen so that the chain reproduces the paper's effective levers."""
MPA_THICKNESS_M = _KR500.mpa_thickness_m
MPA_SIDE_M = _KR500.mpa_side_m
MPA_CUTOUT_DIAMETER_M = _KR500.mpa_cutout_diameter_m
CB_MASS_KG = _KR500.body_mass_kg
CB_THICKNESS_M = _KR500.body_thickness_m
N_CB_MAX = _KR500.body_count_max
TA_MASS_KG = _KR500.adapter_mass_kg
TA_TORQUE_A5_NM = _KR500.adapter_torque_a5_nm
FIXTURE_MASS_KG = _KR500.fixture_mass_kg
FIXTURE_THICKNESS_M = _KR500.fixture_thickness_m
FIXTURE_SIDE_M = _KR500.fixture_side_m
TA_RAIL_SECTION_M = _KR500.adapter_rail_section_m
TA_RAIL_LENGTH_M = _KR500.adapter_rail_length_m


def _loads() -> CalibrationLoads:
    return robots.active().calibration


def mpa_mass_kg(loads: CalibrationLoads | None = None) -> float:
    """The MPA's mass: a stainless plate with a central cut-out."""
    c = _loads() if loads is None else loads
    return (c.mpa_side_m**2 - np.pi * (c.mpa_cutout_diameter_m / 2) ** 2) * c.mpa_thickness_m * STAINLESS_DENSITY_KG_M3


MPA_MASS_KG = mpa_mass_kg(_KR500)


def fixture_mass_kg() -> float:
    """m_f of the active robot's fixture."""
    return _loads().fixture_mass_kg


InertiaLike = Sequence[float] | Sequence[Sequence[float]] | np.ndarray
"""Three principal moments (a diagonal tensor) or a full symmetric 3×3 tensor, kg·m²."""


def inertia_tensor_kgm2(value: InertiaLike, what: str = "inertia") -> np.ndarray:
    """A 3×3 inertia tensor (kg·m²) from three diagonal moments or a full tensor; ValueError naming ``what`` if it is
    not a physical one (finite, symmetric, principal moments ≥ 0 and obeying the triangle inequality)."""
    t = np.asarray(value, dtype=float)
    if t.shape == (3,):
        t = np.diag(t)
    if t.shape != (3, 3) or not np.all(np.isfinite(t)):
        raise ValueError(f"{what}: expected three moments or a 3×3 tensor of finite kg·m², got shape {t.shape}")
    scale = max(float(np.abs(t).max()), 1e-12)
    if not np.allclose(t, t.T, atol=1e-9 * scale):
        raise ValueError(f"{what}: the inertia tensor is not symmetric")
    p = np.linalg.eigvalsh(t)
    tol = 1e-9 * scale
    if p[0] < -tol or p[2] > p[0] + p[1] + tol:
        raise ValueError(f"{what}: principal moments {p.round(6).tolist()} kg·m² are not a rigid body's "
                         "(each must be ≥ 0 and none larger than the sum of the other two)")
    return t


def box_inertia_kgm2(mass_kg: float, x_m: float, y_m: float, z_m: float) -> tuple[float, float, float]:
    """Principal moments (kg·m²) about the CoG of a homogeneous box with edges x, y, z (m) along its axes."""
    return (mass_kg * (y_m**2 + z_m**2) / 12.0, mass_kg * (x_m**2 + z_m**2) / 12.0,
            mass_kg * (x_m**2 + y_m**2) / 12.0)


def plate_with_hole_inertia_kgm2(mass_kg: float, side_m: float, thickness_m: float,
                                 hole_diameter_m: float) -> tuple[float, float, float]:
    """Principal moments (kg·m²) about the CoG of a square plate (side × side × thickness, z its normal) with a
    centred round cut-out, homogeneous, of total mass ``mass_kg``: the full plate minus the disc."""
    r = hole_diameter_m / 2.0
    a_plate, a_hole = side_m**2, np.pi * r**2
    m_full = mass_kg * a_plate / (a_plate - a_hole)
    m_hole = m_full - mass_kg
    ixx = m_full * (side_m**2 + thickness_m**2) / 12.0 - m_hole * (3 * r**2 + thickness_m**2) / 12.0
    izz = m_full * 2 * side_m**2 / 12.0 - m_hole * r**2 / 2.0
    return (float(ixx), float(ixx), float(izz))


@dataclass(frozen=True)
class RigidBody:
    """A rigid body fixed to the flange: mass (kg), CoG in the flange frame (m) and its inertia tensor about the
    CoG in the flange frame (kg·m²; three principal moments along the flange axes, or a full 3×3 tensor; kept as
    a 3×3 tuple). The static torques do not depend on the inertia; the dynamics (``dynamics.py``) do."""

    name: str
    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    inertia_cog_kgm2: InertiaLike = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass_kg) and self.mass_kg >= 0.0):
            raise ValueError(f"{self.name}: mass must be finite and ≥ 0, got {self.mass_kg}")
        if len(self.cog_flange_m) != 3 or not np.all(np.isfinite(self.cog_flange_m)):
            raise ValueError(f"{self.name}: CoG must be three finite coordinates (m)")
        t = inertia_tensor_kgm2(self.inertia_cog_kgm2, f"{self.name}: inertia about the CoG")
        object.__setattr__(self, "inertia_cog_kgm2", tuple(tuple(float(v) for v in row) for row in t))

    @property
    def inertia_tensor_kgm2(self) -> np.ndarray:
        """The inertia tensor about the body's CoG in the flange frame (3×3, kg·m²)."""
        return np.array(self.inertia_cog_kgm2, dtype=float)


@dataclass(frozen=True)
class Payload:
    """Everything on the flange, as a list of rigid bodies."""

    bodies: tuple[RigidBody, ...] = ()

    @property
    def mass_kg(self) -> float:
        return float(sum(b.mass_kg for b in self.bodies))

    @property
    def theta(self) -> np.ndarray:
        """Gravity parameters [m, m·cx, m·cy, m·cz] (kg, kg·m) for ``kinematics.gravity_regressor``."""
        t = np.zeros(4)
        for b in self.bodies:
            t += b.mass_kg * np.array([1.0, *b.cog_flange_m])
        return t

    @property
    def cog_flange_m(self) -> np.ndarray:
        t = self.theta
        return t[1:] / t[0] if t[0] > 0 else np.zeros(3)

    def inertia_flange_kgm2(self, shift_z_m: float = 0.0) -> np.ndarray:
        """Inertia tensor (3×3, kg·m²) of all bodies about the flange origin in the flange frame (parallel-axis
        theorem: I_o = Σ I_c + m (|c|² 1 − c cᵀ)); ``shift_z_m`` moves every body along the flange axis (a
        mounting's CoG shift)."""
        total = np.zeros((3, 3))
        for b in self.bodies:
            c = np.asarray(b.cog_flange_m, dtype=float) + np.array([0.0, 0.0, shift_z_m])
            total += b.inertia_tensor_kgm2 + b.mass_kg * (c @ c * np.eye(3) - np.outer(c, c))
        return total

    @property
    def inertia_cog_kgm2(self) -> np.ndarray:
        """Inertia tensor (3×3, kg·m²) of the whole payload about its common CoG, in the flange frame."""
        c = self.cog_flange_m
        return self.inertia_flange_kgm2() - self.mass_kg * (c @ c * np.eye(3) - np.outer(c, c))

    def __add__(self, other: Payload) -> Payload:
        return Payload(self.bodies + other.bodies)


def mpa() -> RigidBody:
    """The multi-payload adapter (§2.2; KR 500: 440 × 440 × 20 mm stainless plate with a Ø120 mm cut-out)."""
    c = _loads()
    m = mpa_mass_kg(c)
    return RigidBody("MPA", m, (0.0, 0.0, c.chain_origin_z_m + c.mpa_thickness_m / 2),
                     plate_with_hole_inertia_kgm2(m, c.mpa_side_m, c.mpa_thickness_m, c.mpa_cutout_diameter_m))


def cb_inertia_kgm2() -> tuple[float, float, float]:
    """A calibration body's principal moments about its CoG (kg·m², z its normal): a plate of the MPA's outline
    (KR 500: 440 × 440 × 15 mm with the Ø120 mm cut-out, 20.93 kg)."""
    c = _loads()
    return plate_with_hole_inertia_kgm2(c.body_mass_kg, c.mpa_side_m, c.body_thickness_m, c.mpa_cutout_diameter_m)


def mpa_front_z_m() -> float:
    c = _loads()
    return c.chain_origin_z_m + c.mpa_thickness_m


def calibration_stack(n_cb: int, base_z_m: float | None = None) -> tuple[RigidBody, ...]:
    """``n_cb`` calibration bodies (KR 500: 20.93 kg, 15 mm) stacked outward from ``base_z_m`` (default: the MPA's
    face)."""
    c = _loads()
    if not 0 <= n_cb <= c.body_count_max:
        raise ValueError(f"n_cb must be 0..{c.body_count_max}, got {n_cb}")
    z0 = mpa_front_z_m() if base_z_m is None else base_z_m
    return tuple(
        RigidBody(f"CB{k}", c.body_mass_kg, (0.0, 0.0, z0 + c.body_thickness_m * (k - 0.5)), cb_inertia_kgm2())
        for k in range(1, n_cb + 1)
    )


def mass_calibration_payload(n_cb: int) -> Payload:
    """Mass-based calibration (Fig. 17): MPA plus ``n_cb`` stacked bodies."""
    return Payload((mpa(), *calibration_stack(n_cb)))


def paper_levers_m(n_cb: int) -> tuple[float, float]:
    """Effective levers (m) of the calibration load to A3 and A5 in the measurement pose, as Table 1's expected
    torques use them: printed lever − 0.020 m. n = 0 is the MPA alone (Table 1's "0 (MPA)" row)."""
    c = _loads()
    lever_a5 = c.zero_lever_a5_m if n_cb == 0 else c.stack_lever_a5_m + c.stack_step_m * n_cb
    return lever_a5 + robots.active().lever_difference_m, lever_a5


def test_adapter(g_m_s2: float = kin.G_PAPER_M_S2) -> RigidBody:
    """The guide-rail test adapter (Fig. 18) on the MPA; its A5 torque in the measurement pose is Table A1's."""
    c = _loads()
    lever_a5 = c.adapter_torque_a5_nm / (kin.G_PAPER_M_S2 * c.adapter_mass_kg)
    # a guide rail along the flange axis (KR 500: a 120 × 120 mm box of 1.0 m; its inertia is an assumption)
    return RigidBody("TA", c.adapter_mass_kg, (0.0, 0.0, lever_a5 - robots.active().dh[5].d_m),
                     box_inertia_kgm2(c.adapter_mass_kg, c.adapter_rail_section_m, c.adapter_rail_section_m,
                                      c.adapter_rail_length_m))


def torque_calibration_payload(n_cb: int, cb_lever_a5_m: float) -> Payload:
    """Torque-based calibration (§2.4.3): MPA, test adapter, ``n_cb`` bodies whose common CoG is ``cb_lever_a5_m``
    from the A5 axis in the measurement pose (Table A1: 0.673..1.475 m)."""
    c = _loads()
    lo, hi = c.adapter_rail_a5_m
    if not lo <= cb_lever_a5_m <= hi:
        raise ValueError(f"cb_lever_a5_m {cb_lever_a5_m} m is outside the guide rail ({lo:g}..{hi:g} m)")
    z = cb_lever_a5_m - robots.active().dh[5].d_m
    bodies = tuple(RigidBody(f"CB{k}", c.body_mass_kg, (0.0, 0.0, z), cb_inertia_kgm2()) for k in range(1, n_cb + 1))
    return Payload((mpa(), test_adapter(), *bodies))


def campaign_point_payload(point: Mapping[str, Any]) -> Payload:
    """What the operator mounts for a campaign point, from the daemon's confirm prompt (``kind``, ``n_cb`` and, for a
    torque point, ``cb_lever_a5_m``; :class:`rgse_daemon.procedures.calibration.CampaignPoint`)."""
    if point["kind"] == "torque":
        return torque_calibration_payload(int(point["n_cb"]), float(point["cb_lever_a5_m"]))
    if point["kind"] == "torsional":
        x, y, z = (float(v) for v in point["cb_cog_flange_m"])
        return torsional_point_payload(int(point["n_cb"]), x, y, z)
    return mass_calibration_payload(int(point["n_cb"]))


def dut_payload(
    dut_mass_kg: float,
    dut_cog_m: Sequence[float],
    dut_inertia_kgm2: InertiaLike = (0.0, 0.0, 0.0),
    fixture_mass_kg: float | None = None,
    with_mpa: bool = True,
) -> Payload:
    """A device under test on its fixture on the MPA (Fig. 14, 29).

    ``dut_cog_m`` is the DuT's CoG in the flange frame (m); ``dut_inertia_kgm2`` its inertia about that CoG in the
    flange frame (three moments along the flange axes or a 3×3 tensor, kg·m²). The fixture is a 400 × 400 × 40 mm
    block centred on the MPA's face (KR 500: 400 × 400 × 40 mm); ``fixture_mass_kg`` default the robot's m_f.
    """
    c = _loads()
    fixture_mass_kg = c.fixture_mass_kg if fixture_mass_kg is None else fixture_mass_kg
    bodies: list[RigidBody] = [mpa()] if with_mpa else []
    if fixture_mass_kg > 0:
        base = mpa_front_z_m() if with_mpa else 0.0
        bodies.append(RigidBody("fixture", fixture_mass_kg, (0.0, 0.0, base + c.fixture_thickness_m / 2),
                                box_inertia_kgm2(fixture_mass_kg, c.fixture_side_m, c.fixture_side_m,
                                                 c.fixture_thickness_m)))
    bodies.append(RigidBody("DuT", dut_mass_kg, tuple(float(c) for c in dut_cog_m), dut_inertia_kgm2))
    return Payload(tuple(bodies))


# --- asymmetric DuTs and the torsional calibration (issue #14) -----------------------------------------------------
def fixture_cog_flange_m(with_mpa: bool = True) -> tuple[float, float, float]:
    """CoG of the fixture block of :func:`dut_payload` in the flange frame (m)."""
    base = mpa_front_z_m() if with_mpa else 0.0
    return (0.0, 0.0, base + _loads().fixture_thickness_m / 2)


def fixture_front_z_m(with_mpa: bool = True) -> float:
    """Flange-frame z of the fixture's front face, where a DuT's interface sits (m)."""
    return (mpa_front_z_m() if with_mpa else 0.0) + _loads().fixture_thickness_m


@dataclass(frozen=True)
class AsymmetricDut:
    """A DuT whose CoG is off the flange axis, with its own frame: origin (m) and KUKA A, B, C (Z-Y-X, deg) in
    the flange frame, its CoG in that frame (m), its inertia tensor about the CoG in that frame
    (``inertia_about_cog_kgm2``: three moments along the DuT axes or a full symmetric 3×3, kg·m²). ``cog_flange_m``
    is the truth the CoG measurement is checked against (before the per-mounting shift the robot model adds);
    ``principal_moments_kgm2`` (ascending) and ``inertia_dut_kgm2`` the truth of an inertia identification. The
    DuT → flange rotation is ``rotation``: v_flange = R · v_dut, I_flange = R · I_dut · Rᵀ. Its envelope, for the
    T1 speed limit at every point of the payload, is a box of ``box_size_dut_m`` (edges along the DuT axes, m)
    centred at ``box_centre_dut_m`` (default: the CoG); ``box_corners_flange_m()`` gives its eight corners."""

    name: str
    mass_kg: float
    cog_dut_m: tuple[float, float, float]
    dut_origin_flange_m: tuple[float, float, float]
    dut_abc_deg: tuple[float, float, float]
    inertia_about_cog_kgm2: InertiaLike = (0.0, 0.0, 0.0)
    box_size_dut_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    box_centre_dut_m: tuple[float, float, float] | None = None

    def box_corners_flange_m(self) -> np.ndarray:
        """The eight corners of the DuT's envelope box in the flange frame (8×3, m)."""
        centre = np.asarray(self.cog_dut_m if self.box_centre_dut_m is None else self.box_centre_dut_m, dtype=float)
        half = np.asarray(self.box_size_dut_m, dtype=float) / 2.0
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        corners_dut = centre + signs * half
        return corners_dut @ self.rotation.T + np.asarray(self.dut_origin_flange_m)

    def __post_init__(self) -> None:
        t = inertia_tensor_kgm2(self.inertia_about_cog_kgm2, f"{self.name}: inertia about the CoG")
        object.__setattr__(self, "inertia_about_cog_kgm2", tuple(tuple(float(v) for v in row) for row in t))

    @property
    def inertia_dut_kgm2(self) -> np.ndarray:
        """The inertia tensor about the CoG in the DuT frame (3×3, kg·m²)."""
        return np.array(self.inertia_about_cog_kgm2, dtype=float)

    @property
    def inertia_flange_kgm2(self) -> np.ndarray:
        """The inertia tensor about the CoG in the flange frame (3×3, kg·m²): R · I_dut · Rᵀ."""
        r = self.rotation
        return r @ self.inertia_dut_kgm2 @ r.T

    @property
    def principal_moments_kgm2(self) -> np.ndarray:
        """The true principal moments about the CoG (kg·m², ascending)."""
        return np.linalg.eigvalsh(self.inertia_dut_kgm2)

    @property
    def principal_axes_dut(self) -> np.ndarray:
        """Unit principal axes in the DuT frame as columns, in the order of ``principal_moments_kgm2``."""
        return np.linalg.eigh(self.inertia_dut_kgm2)[1]

    @property
    def rotation(self) -> np.ndarray:
        # intrinsic Z-Y-X = Rz(A)·Ry(B)·Rx(C), KUKA's convention (scipy, not the daemon's own helper)
        return _zyx_matrix(self.dut_abc_deg)

    @property
    def cog_flange_m(self) -> np.ndarray:
        return self.rotation @ np.asarray(self.cog_dut_m) + np.asarray(self.dut_origin_flange_m)

    def payload(self, fixture_mass_kg: float | None = None, with_mpa: bool = True) -> Payload:
        """MPA, fixture and this DuT, as mounted for a mass and a properties run."""
        return dut_payload(self.mass_kg, self.cog_flange_m, self.inertia_flange_kgm2, fixture_mass_kg, with_mpa)


def _zyx_matrix(abc_deg: Sequence[float]) -> np.ndarray:
    """Rz(A)·Ry(B)·Rx(C) by scipy's ``Rotation``, imported here: scipy.spatial costs a simulator process (``rgse
    sim``, each test's :class:`~simulators.krc4.process.SimProcess`) about a second of start-up on a loaded machine,
    and only a DuT turned on its fixture needs it."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", abc_deg, degrees=True).as_matrix()


def _rotated_tensor(principal_kgm2: Sequence[float], abc_deg: Sequence[float]) -> np.ndarray:
    """R · diag(principal) · Rᵀ with R = Rz(A)·Ry(B)·Rx(C): a tensor whose principal axes are turned by A, B, C."""
    r = _zyx_matrix(abc_deg)
    return r @ np.diag(np.asarray(principal_kgm2, dtype=float)) @ r.T


#: The wing box's principal moments about its CoG (kg·m²) and how its principal axes are turned against the DuT
#: axes (KUKA A, B, C in deg: the spar's sweep and the skins' twist). A 1.6 × 0.6 × 0.3 m box (x × y × z) of
#: 107.3 kg homogeneous would have (4.02, 23.70, 26.11); the mass of a wing box sits in its skins and spars, away
#: from the centre, so each moment is ~25 % larger. Invented numbers of the right size, not ReFEx data.
WING_BOX_PRINCIPAL_KGM2 = (5.1, 29.4, 32.6)
WING_BOX_AXES_ABC_DEG = (8.0, 2.5, -4.0)


def refex_wing_box() -> AsymmetricDut:
    """A ReFEx-like wing box (paper §2.4.7: the DuT on the 10.288 kg fixture): 107.3 kg, its frame at the centre of
    the fixture's front face turned 90° about the flange axis (its x along the flange's y), its CoG 310 mm out from
    the interface and 28/41 mm off the flange axis; 1.6 m along its x, 0.6 m along y, 0.3 m deep (on a 0.16 m
    bracket), with a full inertia tensor (products of inertia from the principal axes turned by
    ``WING_BOX_AXES_ABC_DEG``). Invented numbers of the right size, not ReFEx data."""
    return AsymmetricDut("ReFEx wing box", 107.3, (-0.028, 0.041, 0.310), (0.0, 0.0, fixture_front_z_m()),
                         (90.0, 0.0, 0.0), _rotated_tensor(WING_BOX_PRINCIPAL_KGM2, WING_BOX_AXES_ABC_DEG),
                         (1.6, 0.6, 0.3))


#: The subscale DuT's principal moments about its CoG (kg·m²) and the turn of its principal axes (KUKA A, B, C, deg):
#: a 0.30 × 0.12 × 0.10 m box of 4.6 kg homogeneous would have (0.0094, 0.0383, 0.0400); +25 % as for the wing box.
SUBSCALE_BOX_PRINCIPAL_KGM2 = (0.0117, 0.048, 0.050)
SUBSCALE_BOX_AXES_ABC_DEG = (6.0, -3.0, 4.0)


def subscale_box() -> AsymmetricDut:
    """A DuT for the KR 10's subscale bench: a 4.6 kg instrument box on the fixture (MPA 1.54 + fixture 0.5 + 4.6 =
    6.6 kg of the arm's 10 kg), its frame at the centre of the fixture's front face turned 90° about the flange axis,
    its CoG 80 mm out from the interface and 10/14 mm off the flange axis; 0.30 × 0.12 × 0.10 m. Invented numbers of
    the right size."""
    return AsymmetricDut("subscale instrument box", 4.6, (-0.010, 0.014, 0.080), (0.0, 0.0, fixture_front_z_m()),
                         (90.0, 0.0, 0.0), _rotated_tensor(SUBSCALE_BOX_PRINCIPAL_KGM2, SUBSCALE_BOX_AXES_ABC_DEG),
                         (0.30, 0.12, 0.10))


def compact_cube() -> AsymmetricDut:
    """A compact DuT: a 0.5 m cube of 60 kg (a homogeneous one would have 2.5 kg·m² about every axis), its
    equipment not evenly spread: principal moments 2.2 / 2.5 / 2.9 kg·m², axes turned (12°, −5°, 7°) against the
    cube's, its CoG 12/−8 mm off its centre. Its frame sits at the fixture's front face turned 20° about the flange
    axis. Invented numbers of the right size."""
    return AsymmetricDut("compact cube", 60.0, (0.012, -0.008, 0.25), (0.0, 0.0, fixture_front_z_m()),
                         (20.0, 0.0, 0.0), _rotated_tensor((2.2, 2.5, 2.9), (12.0, -5.0, 7.0)), (0.5, 0.5, 0.5),
                         (0.0, 0.0, 0.25))


#: The torsional calibration (interfaces §2): up to six calibration bodies on a bracket on the MPA whose CoG sits at
#: a known point up to 0.20 m off the flange axis and 0.10..0.60 m along it (the guide rail of Fig. 18 turned
#: across the MPA).
TORSIONAL_BRACKET_Z_M = 0.30
"""Default flange z (m) of the bodies' CoG on the torsional bracket (it slides 0.10..0.60 m)."""
TORSIONAL_N_CB_MAX = 6


def torsional_point_payload(n_cb: int, offset_x_m: float, offset_y_m: float,
                            z_m: float = TORSIONAL_BRACKET_Z_M) -> Payload:
    """A torsional calibration point: MPA plus ``n_cb`` bodies whose common CoG is at (x, y, z) in the flange frame
    (m); n_cb = 0 is the MPA alone (the bias of every pose)."""
    c = _loads()
    if not 0 <= n_cb <= c.torsional_body_count_max:
        raise ValueError(f"n_cb {n_cb} must be 0..{c.torsional_body_count_max} on the torsional bracket")
    off_max, z_lo, z_hi = c.torsional_bracket_m
    if n_cb and (max(abs(offset_x_m), abs(offset_y_m)) > off_max or not z_lo <= z_m <= z_hi):
        raise ValueError(f"the torsional bracket reaches {off_max:g} m off the flange axis and {z_lo:g}..{z_hi:g} m "
                         "along it")
    bodies = tuple(RigidBody(f"CB{k}", c.body_mass_kg, (offset_x_m, offset_y_m, z_m), cb_inertia_kgm2())
                   for k in range(1, n_cb + 1))
    return Payload((mpa(), *bodies))


# --- the robot --------------------------------------------------------------------------------------------------
@dataclass
class RobotState:
    """What the torque estimate remembers: motor temperatures (K), time since the last motion ended (s), the sign of
    each axis' last approach, and whether the brakes are open."""

    motor_temp_k: np.ndarray
    t_since_release_s: float = 1e6
    last_approach_sign: np.ndarray = field(default_factory=lambda: np.ones(6))
    brakes_released: bool = False


@dataclass(frozen=True)
class TraceTruth:
    """Ground truth of one simulated trace, for tests: nothing here is visible to the daemon.

    ``terms`` holds every additive error term per axis and sample (Nm, shape (6, n)): ``static`` (true torque
    through the gain, plus residual), ``mount`` (this mounting's offset), ``thermal``, ``release``, ``hysteresis``,
    ``settle``, ``noise``, ``spikes``;
    their sum is Istmoment.
    """

    q_deg: np.ndarray
    payload_mass_kg: float
    payload_cog_flange_m: np.ndarray
    true_torque_nm: np.ndarray
    payload_torque_nm: np.ndarray
    arm_torque_nm: np.ndarray
    residual_nm: np.ndarray
    gain: np.ndarray
    t_since_release_s: float
    motor_temp_k: np.ndarray
    last_approach_sign: np.ndarray
    period_s: float
    terms: dict[str, np.ndarray]


def gain_curve(
    gain0: float, gain_sat: float, tau_sat_nm: float, slope_per_knm: float, quad_per_knm2: float, x_nm: np.ndarray
) -> np.ndarray:
    """Table 1 gain of the torque estimate for payload torque x = |τ| (Nm):
    G(x) = gain0 + gain_sat·(1 − exp(−x/tau_sat)) + slope·x/1000 + quad·(x/1000)²."""
    x = np.abs(np.asarray(x_nm, dtype=float))
    xk = x / 1000.0
    return gain0 + gain_sat * (1.0 - np.exp(-x / tau_sat_nm)) + slope_per_knm * xk + quad_per_knm2 * xk**2


@dataclass(frozen=True)
class KinematicsDeviation:
    """What one arm as built differs from its catalogue by: per DH row (A1..A6) Δa_{i-1}, Δd_i (m), Δalpha_{i-1} and
    the zero offset Δθ_i (deg)."""

    da_m: np.ndarray
    dd_m: np.ndarray
    dalpha_deg: np.ndarray
    dtheta_deg: np.ndarray


def as_built_robot(catalogue: ArmKinematics, spread: Kinematics,
                   rng: np.random.Generator) -> tuple[ArmKinematics, KinematicsDeviation]:
    """One arm as built: the catalogue's DH lengths, twists and zero offsets each moved by a normal draw of the
    scenario's σ (``[kinematics]``), but for A1's twist (the A1 axis stays plumb). The draws come in a fixed order, so
    one seed gives one arm whatever the σ."""
    z = rng.normal(0.0, 1.0, (4, 6))
    z[2, 0] = 0.0  # A1's axis stays plumb: its tilt is the installation's (the floor), not the arm's build
    dev = KinematicsDeviation(z[0] * spread.length_sigma_m, z[1] * spread.length_sigma_m,
                              z[2] * spread.twist_sigma_deg, z[3] * spread.zero_offset_sigma_deg)
    dh = tuple(DhRow(alpha_deg=row.alpha_deg + float(dev.dalpha_deg[i]), a_m=row.a_m + float(dev.da_m[i]),
                     d_m=row.d_m + float(dev.dd_m[i])) for i, row in enumerate(catalogue.dh))
    offsets = tuple(float(o + dt) for o, dt in zip(catalogue.theta_offset_deg, dev.dtheta_deg, strict=True))
    built = replace(catalogue, dh=dh, theta_offset_deg=offsets, lever_difference_m=dh[3].d_m)
    return built, dev


class RobotModel:
    """The simulated KR 500 R2830's statics and torque estimate; see the module docstring."""

    def __init__(self, scenario: Scenario | None = None, seed: int | None = 0) -> None:
        self.scenario = scenario if scenario is not None else default_scenario()
        self.rng = np.random.default_rng(seed)
        self.g_m_s2 = self.scenario.g_m_s2
        self._axes = [self.scenario.axis(i) for i in range(1, 7)]
        self._links = [(link, mass, cog) for link, mass, cog in self.scenario.arm.links]
        # the arm as built: its own stream, so the noise of every trace stays what it was for a seed
        self.robot, self.kinematics_deviation = as_built_robot(
            robots.get(self.scenario.robot), self.scenario.kinematics,
            np.random.default_rng(None if seed is None else [seed, 0x6B696E]))
        self.residual_nm = np.zeros(6)
        pinned = self.scenario.arm.bias_measurement_pose_nm
        if pinned:
            arm = self.arm_torques_nm(kin.measurement_pose())
            for i, key in enumerate(AXIS_KEYS):
                if key in pinned:
                    self.residual_nm[i] = pinned[key] - arm[i]
        self.ambient_k = self.scenario.thermal.ambient_k
        self.state = RobotState(motor_temp_k=np.full(6, self.ambient_k))
        self.last_truth: TraceTruth | None = None
        # mountings draw from their own stream: the noise of every trace stays the same whatever is mounted; the
        # robot as built has none (the first mounting draws)
        self._mount_rng = np.random.default_rng(None if seed is None else [seed, 0x6D6F756E74])
        self.mount_offset_nm = np.zeros(6)
        self.mount_cog_shift_m = 0.0

    def new_mounting(self) -> None:
        """A load was (re-)mounted: draw this mounting's reading offset δ_i ~ N(0, mount_offset_nm_i) and the shift
        of the load's CoG along the flange axis (``mounting.cog_shift_m``), both fixed until the next mounting."""
        sigma = np.array([a.mount_offset_nm for a in self._axes])
        self.mount_offset_nm = self._mount_rng.normal(0.0, 1.0, 6) * sigma
        self.mount_cog_shift_m = float(self._mount_rng.normal(0.0, self.scenario.mounting.cog_shift_m))

    def knock(self, offset_nm: Sequence[float]) -> None:
        """The mounted load is knocked or its fixture settles: the reading offsets of this mounting shift by
        ``offset_nm`` (per axis A1..A6, Nm) from now until the next mounting (a load that no longer sits as it did)."""
        self.mount_offset_nm = self.mount_offset_nm + np.asarray(offset_nm, dtype=float)

    # --- statics -------------------------------------------------------------------------------------------------
    def arm_torques_nm(self, q_deg: Sequence[float]) -> np.ndarray:
        """Gravity holding torques of the robot's own links (Nm), on the arm as built."""
        return kin.link_gravity_torques_nm(q_deg, self._links, self.g_m_s2, self.robot)

    def payload_torques_nm(self, q_deg: Sequence[float], payload: Payload) -> np.ndarray:
        """Gravity holding torques of the payload as mounted now (its CoG shifted by this mounting's shift, Nm), on the
        arm as built."""
        theta = payload.theta + np.array([0.0, 0.0, 0.0, payload.mass_kg * self.mount_cog_shift_m])
        return kin.gravity_regressor(q_deg, self.g_m_s2, self.robot) @ theta

    def true_torques_nm(self, q_deg: Sequence[float], payload: Payload) -> np.ndarray:
        """Static gravity holding torques of arm plus payload at every axis (Nm, A1..A6)."""
        return self.arm_torques_nm(q_deg) + self.payload_torques_nm(q_deg, payload)

    def gains(self, payload_torque_nm: np.ndarray) -> np.ndarray:
        """Per-axis gain G_i(|τ_payload,i|) of the torque estimate (Table 1 measured/expected)."""
        return np.array(
            [
                gain_curve(
                    a.gain0, a.gain_sat, a.tau_sat_nm, a.gain_slope_per_knm, a.gain_quad_per_knm2, payload_torque_nm[i]
                )
                for i, a in enumerate(self._axes)
            ]
        )

    def static_reading_nm(self, q_deg: Sequence[float], payload: Payload) -> np.ndarray:
        """Noise-free, cold, settled reading (Nm) of the load as mounted now: τ_arm + M0 + G(|τ_pay|)·τ_pay + δ."""
        tau_p = self.payload_torques_nm(q_deg, payload)
        return self.arm_torques_nm(q_deg) + self.residual_nm + self.gains(tau_p) * tau_p + self.mount_offset_nm

    # --- state ---------------------------------------------------------------------------------------------------
    def _temps_after(self, t0_k: np.ndarray, dt_s: np.ndarray | float, released: bool) -> np.ndarray:
        th = self.scenario.thermal
        dt = np.asarray(dt_s, dtype=float)
        if released:
            eq = self.ambient_k + np.array([a.hold_temperature_rise_k for a in self._axes])
            tau = th.heat_time_constant_s
        else:
            eq = np.full(6, self.ambient_k)
            tau = th.cool_time_constant_s
        decay = np.exp(-dt / tau)
        return eq[..., None] + (t0_k[..., None] - eq[..., None]) * decay if dt.ndim else eq + (t0_k - eq) * decay

    def move(self, q_from_deg: Sequence[float], q_to_deg: Sequence[float], duration_s: float) -> None:
        """A motion with brakes released: motors heat for ``duration_s``, every moved axis remembers the direction
        it arrived from, and the settling/release clock restarts at the end."""
        if duration_s < 0:
            raise ValueError("duration_s must be ≥ 0")
        dq = np.asarray(q_to_deg, dtype=float) - np.asarray(q_from_deg, dtype=float)
        moved = np.abs(dq) > 1e-9
        self.state.last_approach_sign = np.where(moved, np.sign(dq), self.state.last_approach_sign)
        self.state.motor_temp_k = self._temps_after(self.state.motor_temp_k, duration_s, True)
        self.state.brakes_released = True
        self.state.t_since_release_s = 0.0

    def brake_release_move(
        self, q_deg: Sequence[float], swing_deg: float = 35.0, speed_deg_s: float = 5.0, axes: Iterable[int] = (3, 5)
    ) -> None:
        """The paper's brake-release move (§2.4.4): A3 and A5 turn by the same angle (35°) away and back."""
        q = np.asarray(q_deg, dtype=float)
        away = q.copy()
        for ax in axes:
            away[ax - 1] += swing_deg
        leg_s = abs(swing_deg) / speed_deg_s
        self.move(q, away, leg_s)
        self.move(away, q, leg_s)

    def hold(self, duration_s: float) -> None:
        """Stand still with brakes released (drives holding the load)."""
        self.state.motor_temp_k = self._temps_after(self.state.motor_temp_k, duration_s, True)
        self.state.brakes_released = True
        self.state.t_since_release_s += duration_s

    def apply_brakes(self, duration_s: float = 0.0) -> None:
        """Apply the brakes and stand for ``duration_s``: no current, the motors cool."""
        self.state.brakes_released = False
        self.state.motor_temp_k = self._temps_after(self.state.motor_temp_k, duration_s, False)
        self.state.t_since_release_s += duration_s

    # --- the trace -----------------------------------------------------------------------------------------------
    def sample_trace(
        self,
        q_deg: Sequence[float],
        payload: Payload,
        n_samples: int,
        period_s: float,
        *,
        t_since_release_s: float | None = None,
        motor_temp_k: Sequence[float] | None = None,
        last_approach_sign: Sequence[float] | None = None,
    ) -> dict[int, dict[str, np.ndarray]]:
        """Record ``n_samples`` samples every ``period_s`` s of all drive channels while holding still at ``q_deg``.

        Returns ``{axis 1..6: {channel: ndarray}}`` (units in ``CHANNEL_UNITS``); the truth is in ``last_truth``.
        """
        if n_samples < 1 or not (period_s > 0):
            raise ValueError("n_samples must be ≥ 1 and period_s > 0")
        q = np.asarray(q_deg, dtype=float)
        st = self.state
        t0 = st.t_since_release_s if t_since_release_s is None else float(t_since_release_s)
        temp0 = st.motor_temp_k.copy() if motor_temp_k is None else np.asarray(motor_temp_k, dtype=float)
        approach = st.last_approach_sign.copy() if last_approach_sign is None else np.sign(last_approach_sign)
        t = t0 + np.arange(n_samples) * period_s  # time since the end of the last motion
        temps = self._temps_after(temp0, np.arange(n_samples) * period_s, True)  # (6, n)

        tau_arm = self.arm_torques_nm(q)
        tau_pay = self.payload_torques_nm(q, payload)
        gain = self.gains(tau_pay)
        static = tau_arm + self.residual_nm + gain * tau_pay
        ax = self._axes
        mount = self.mount_offset_nm
        beta = np.array([a.thermal_coeff_per_k for a in ax])
        eps = np.array([a.release_transient_frac for a in ax])
        hyst = np.array([a.hysteresis_nm for a in ax])
        settle_a = np.array([a.settle_amplitude_nm for a in ax])
        sigma = np.array([a.noise_nm for a in ax])
        sc = self.scenario
        terms = {
            "static": np.repeat(static[:, None], n_samples, axis=1),
            "mount": np.repeat(mount[:, None], n_samples, axis=1),
            "thermal": static[:, None] * beta[:, None] * (temps - self.ambient_k),
            "release": static[:, None] * eps[:, None] * np.exp(-t / sc.release.time_constant_s)[None, :],
            "hysteresis": np.repeat((-approach * hyst)[:, None], n_samples, axis=1),
            "settle": (approach * settle_a)[:, None]
            * (np.exp(-t / sc.settle.time_constant_s) * np.cos(2 * np.pi * sc.settle.frequency_hz * t))[None, :],
            "noise": self.rng.normal(0.0, 1.0, (6, n_samples)) * sigma[:, None],
        }
        hits = self.rng.random((6, n_samples)) < sc.spikes.rate_per_sample
        terms["spikes"] = np.where(hits, self.rng.normal(0.0, sc.spikes.amplitude_nm, (6, n_samples)), 0.0)
        torque = sum(terms.values())

        kt_ratio = np.array([a.torque_constant_nm_a * a.gear_ratio for a in ax])
        pos_jitter = self.rng.normal(0.0, 5e-4, (6, n_samples))
        out: dict[int, dict[str, np.ndarray]] = {}
        for i in range(6):
            out[i + 1] = {
                "Sollposition": np.full(n_samples, q[i]),
                "Istposition": q[i] + pos_jitter[i],
                "Positionsschleppfehler": -pos_jitter[i],
                "Geschwindigkeitsdifferenz": self.rng.normal(0.0, 0.02, n_samples),
                "Motortemperatur": np.round(temps[i], 1),
                "Istmoment": torque[i],
                "Iststrom": torque[i] / kt_ratio[i],
            }
        self.last_truth = TraceTruth(
            q_deg=q.copy(),
            payload_mass_kg=payload.mass_kg,
            payload_cog_flange_m=payload.cog_flange_m + np.array([0.0, 0.0, self.mount_cog_shift_m]),
            true_torque_nm=tau_arm + tau_pay,
            payload_torque_nm=tau_pay,
            arm_torque_nm=tau_arm,
            residual_nm=self.residual_nm.copy(),
            gain=gain,
            t_since_release_s=t0,
            motor_temp_k=temps,
            last_approach_sign=approach,
            period_s=period_s,
            terms=terms,
        )
        # advance the state by the trace's duration (holding, brakes released)
        duration = n_samples * period_s
        st.motor_temp_k = self._temps_after(temp0, duration, True)
        st.t_since_release_s = t0 + duration
        st.brakes_released = True
        st.last_approach_sign = approach
        return out
