"""The value that describes one robot arm: kinematics, motion limits, poses, loads and the calibration load set.

A robot is data. Every figure of an arm lives in that arm's own module beside this one (``kr500r2830.py``,
``kr10r1440.py``), each with its source; the rest of the code takes them from a :class:`RobotModel` (the configured
one: ``[robot] model``). This package is a leaf: it imports nothing of the project (pyproject.toml contract).

Conventions are those of :mod:`rgse_daemon.kinematics` (modified Craig DH, lengths in m, angles in deg, KUKA axis
directions); the kinematics module does the arithmetic, this module holds no code beyond checks of shape.
"""

from __future__ import annotations

from dataclasses import dataclass

Axes = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class DhRow:
    """One modified-DH row: transform from frame i-1 to frame i is Rx(alpha) · Tx(a) · Rz(theta) · Tz(d)."""

    alpha_deg: float
    a_m: float
    d_m: float


@dataclass(frozen=True)
class CalibrationLoads:
    """The calibration fixture and load set of the paper's campaign (§2.4.2–2.4.3, Table 1, Fig. 17/18), sized for
    one robot's load diagram.

    Mass points: the mass plate (MPA) alone (the zero point) and stacks of ``n`` calibration bodies (CB); torque
    points: the test adapter (TA) with bodies at longer levers in front of A5; torsional points: bodies on a bracket
    with their common CoG off the flange axis.
    """

    mpa_side_m: float
    """The MPA: a square plate with a central cut-out, ``mpa_side_m`` wide, ``mpa_thickness_m`` thick."""
    mpa_thickness_m: float
    mpa_cutout_diameter_m: float
    chain_origin_z_m: float
    """Flange-frame z of the MPA's back face."""
    body_mass_kg: float
    """m_CB: one calibration body (a plate of the MPA's outline)."""
    body_thickness_m: float
    body_count_max: int
    """Bodies in the set (Table 1: 10)."""
    zero_lever_a5_m: float
    """Effective lever of the empty MPA's CoG to A5 in the measurement pose (Table 1 '0 (MPA)' row)."""
    stack_lever_a5_m: float
    stack_step_m: float
    """Effective A5 lever of n stacked bodies: stack_lever_a5_m + stack_step_m · n."""
    adapter_mass_kg: float
    """m_TA: the torque calibration's test adapter."""
    adapter_torque_a5_nm: float
    """The test adapter's own A5 torque in the measurement pose at g = 9.81 m/s² (Table A1)."""
    adapter_rail_section_m: float
    adapter_rail_length_m: float
    adapter_rail_a5_m: tuple[float, float]
    """The A5 levers (m) the bodies can be placed at on the test adapter's rail (Table A1: 0.673..1.475 m)."""
    torque_levers_a5_m: tuple[float, ...]
    """Where the bodies' common CoG sits on the test adapter's rail at the torque points."""
    torque_body_count: int
    """Bodies on the test adapter at each torque point (Table 1: 10)."""
    torsional_points: tuple[tuple[int, tuple[float, float, float]], ...]
    """(bodies, their common CoG in the flange frame, m) of the torsional points (issue #14)."""
    torsional_bracket_m: tuple[float, float, float]
    """The torsional bracket's reach: (off the flange axis at most, along it from, to), m."""
    torsional_body_count_max: int
    """Bodies the torsional bracket carries at most."""
    fixture_mass_kg: float
    """m_f: the DuT fixture between MPA and DuT."""
    fixture_thickness_m: float
    fixture_side_m: float


@dataclass(frozen=True)
class DefaultCell:
    """The cell the default configuration assumes around one robot (``[cell]``'s defaults): in the robot's base frame
    ($ROBROOT: on the A1 axis at the robot's foot, z up), m. The room's walls are the site's (``config.py``); a site's
    ``[cell]`` replaces any default."""

    frame_height_m: float
    """Height of the frame (pedestal) the robot stands on: the floor is at −frame_height_m."""
    frame_half_width_m: float
    """Half the frame's footprint in x and y: the keep-out box from the floor up to the base."""
    payload_box_min_m: tuple[float, float, float]
    payload_box_max_m: tuple[float, float, float]
    """The box around DuT and fixture in the flange frame (z out of the flange); within ``payload_lever_max_m``."""


@dataclass(frozen=True)
class RobotModel:
    """One robot arm. All angles in deg, lengths in m; see the robot's module for the source of each figure."""

    key: str
    """The name ``[robot] model`` and ``rgse demo --robot`` use, e.g. ``kr500r2830``."""
    title: str
    """KUKA's name of the arm, e.g. ``KR 500 R2830``; the simulated controller's $MODEL_NAME."""
    dh: tuple[DhRow, DhRow, DhRow, DhRow, DhRow, DhRow]
    axis_sign: Axes
    """theta_i = axis_sign_i · A_i + theta_offset_i."""
    theta_offset_deg: Axes
    axis_range_deg: tuple[tuple[float, float], ...]
    """Software axis ranges A1..A6 (deg), (low, high)."""
    max_axis_speed_deg_s: Axes
    """Maximum axis speeds A1..A6 (deg/s) at 100 % override."""
    reach_m: float
    """Published reach: wrist centre fully stretched, from the A1 axis (a check of the DH rows)."""
    home_deg: Axes
    candle_deg: Axes
    measurement_a2_deg: float
    """A2 of the mass measurement pose; A3 = −A2, A4 = A5 = A6 = 0 (paper Fig. 19/21)."""
    lever_difference_m: float
    """Δr = r_A3 − r_A5 in the measurement pose (eq. 3–4); equals d4 of the DH rows (checked on load)."""
    operator_pose_deg: Axes
    """Operational (integration) pose: flange horizontal, within reach of the operator."""
    calibration_poses_deg: tuple[Axes, ...]
    """The CoG poses: the measurement pose, A5 tilted, A4 and A5 turned, A6 a quarter turn."""
    rated_payload_kg: float
    max_payload_kg: float
    """Largest load of the load diagram (the upper bound of ``limits.max_payload_kg``)."""
    max_a5_torque_nm: float
    """Largest static A5 torque of the load diagram (the upper bound of ``limits.max_a5_torque_nm``)."""
    a1_envelope_deg: float
    """The A1 software envelope's default (paper §2.2: ±45°)."""
    payload_lever_max_m: float
    """Farthest point of fixture + DuT from the flange the default configuration assumes (T1 speed bound)."""
    brake_release_deg: float
    """φ' of the brake-release move the default configuration uses (paper §2.4.4: 35° on the KR 500)."""
    calibration: CalibrationLoads
    cell: DefaultCell
    """The cell the default configuration assumes (``[cell]``'s defaults): the robot's frame, the payload's box."""
    multipose_a3_deg: tuple[float, ...] = ()
    """The lever poses of the multi-pose mass (issue #35): A3 offsets (deg) from the measurement pose, A5 turned by
    the opposite so that the flange keeps its orientation (:mod:`rgse_daemon.pipeline.multipose`); () = none."""

    def __post_init__(self) -> None:
        six = {"axis_sign": self.axis_sign, "theta_offset_deg": self.theta_offset_deg, "home_deg": self.home_deg,
               "candle_deg": self.candle_deg, "max_axis_speed_deg_s": self.max_axis_speed_deg_s,
               "axis_range_deg": self.axis_range_deg, "dh": self.dh, "operator_pose_deg": self.operator_pose_deg}
        for name, value in six.items():
            if len(value) != 6:
                raise ValueError(f"robot {self.key}: {name} needs 6 entries (A1..A6), has {len(value)}")
        for lo, hi in self.axis_range_deg:
            if not lo < hi:
                raise ValueError(f"robot {self.key}: axis range {lo}..{hi} is empty")
        if abs(self.lever_difference_m - self.dh[3].d_m) > 1e-12:
            raise ValueError(f"robot {self.key}: lever_difference_m {self.lever_difference_m} differs from d4 "
                             f"{self.dh[3].d_m} (in the measurement pose Δr is d4, eq. 3–4)")
        box_lo, box_hi = self.cell.payload_box_min_m, self.cell.payload_box_max_m
        if max(map(abs, (*box_lo, *box_hi))) > self.payload_lever_max_m + 1e-12:
            raise ValueError(f"robot {self.key}: the default payload box {box_lo}..{box_hi} reaches beyond "
                             f"payload_lever_max_m {self.payload_lever_max_m} (the T1 speed bound's cube)")
        if not 0.0 < self.a1_envelope_deg <= min(-self.axis_range_deg[0][0], self.axis_range_deg[0][1]):
            raise ValueError(f"robot {self.key}: A1 envelope ±{self.a1_envelope_deg} is outside the A1 range")
