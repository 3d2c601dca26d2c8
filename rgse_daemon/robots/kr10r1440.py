"""KUKA KR 10 R1440-2 (KR CYBERTECH nano) with KR C4: the paper's subscale software bench ("KR10-1440").

Sources:
- [URDF] ROS-Industrial kuka_experimental, ``kuka_kr10_support/urdf/kr10r1440_2_macro.xacro`` (commit a81249877f):
  joint origins A1 z 425 mm, A2 x 170 mm, A3 x 610 mm, A4 x 660 mm and z +20 mm, A6 x 100 mm; joint axes A1 −z, A2 +y,
  A3 +y, A4 −x, A5 +y, A6 −x (the same axis directions as the KR 500's, so the same signs); axis ranges A1 ±170,
  A2 −185…+65, A3 −137…+163, A4 ±185, A5 ±120, A6 ±350 deg; axis speeds 220, 210, 270, 381, 311, 472 deg/s (the
  URDF's limits, taken from KUKA's data; *not compared with the current data sheet*).
- [DS] KUKA's data sheet of the KR 10 R1440-2: rated payload 10 kg, maximum reach 1441 mm (the DH rows give
  0.170 + √(1.270² + 0.020²) = 1.4402 m from the A1 axis to the wrist centre). *Not checked here against a copy of
  the sheet; the figures as commonly published.*
- [P] the paper: the subscale bench on a KR10-1440; the measurement pose's geometry (Fig. 19/21) is the KR 500's
  applied to this arm, so Δr = d4 = 0.660 m.
- Project choices (no published figure; marked *assumed*): the largest A5 torque of the load diagram (rated payload
  at 100 mm in front of the flange, 10 kg × 9.81 × 0.200 m ≈ 19.6 Nm, *assumed*, KUKA's load diagram of the arm not
  consulted), the maximum payload equal to the rated one (no diagram beyond it), the operator and CoG poses, and the
  whole calibration load set: the KR 500's (paper §2.4.2–2.4.3) scaled to the 10 kg class — a 160 × 160 × 8 mm
  stainless MPA (1.54 kg), ten 160 × 160 × 4 mm bodies of 0.77 kg (10 bodies + MPA = 9.2 kg ≤ 10 kg), a 0.6 kg test
  adapter, a 0.5 kg fixture; levers follow from the plates' thicknesses on this flange (d6 = 100 mm).
  The default cell is *assumed* as well (no drawing of the bench consulted): the arm on a 0.6 m high pedestal with a
  0.5 × 0.5 m footprint (KUKA's base of this arm is about 0.32 m square), and a payload box of ±0.5 m across and
  0.5 m out of the flange (= payload_lever_max_m: MPA + adapter rail + DuT of this class).
"""

from __future__ import annotations

from rgse_daemon.robots.model import CalibrationLoads, DefaultCell, DhRow, RobotModel

_MPA_THICKNESS_M = 0.008
_BODY_THICKNESS_M = 0.004
_D6_M = 0.100
_CHAIN_ORIGIN_Z_M = 0.0

ROBOT = RobotModel(
    key="kr10r1440",
    title="KR 10 R1440-2",
    # [URDF] joint origins in the modified-DH convention of rgse_daemon.kinematics; a3 is −20 mm because A4 lies
    # 20 mm *above* the A3 axis here (the KR 500's lies 55 mm below: +55 mm)
    dh=(
        DhRow(alpha_deg=0.0, a_m=0.0, d_m=0.425),
        DhRow(alpha_deg=-90.0, a_m=0.170, d_m=0.0),
        DhRow(alpha_deg=0.0, a_m=0.610, d_m=0.0),
        DhRow(alpha_deg=90.0, a_m=-0.020, d_m=0.660),
        DhRow(alpha_deg=-90.0, a_m=0.0, d_m=0.0),
        DhRow(alpha_deg=90.0, a_m=0.0, d_m=_D6_M),
    ),
    axis_sign=(-1.0, 1.0, 1.0, -1.0, 1.0, -1.0),  # [URDF] A1, A4, A6 about the negative axis
    theta_offset_deg=(0.0, 0.0, 90.0, 0.0, 0.0, 0.0),
    axis_range_deg=((-170.0, 170.0), (-185.0, 65.0), (-137.0, 163.0), (-185.0, 185.0), (-120.0, 120.0),
                    (-350.0, 350.0)),  # [URDF]
    max_axis_speed_deg_s=(220.0, 210.0, 270.0, 381.0, 311.0, 472.0),  # [URDF]
    reach_m=1.441,  # [DS]
    home_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0),  # KUKA's home position of the family
    candle_deg=(0.0, -90.0, 0.0, 0.0, 0.0, 0.0),
    measurement_a2_deg=-90.0,  # [P] Fig. 19/21 applied to this arm
    lever_difference_m=0.660,  # = d4
    # assumed: flange horizontal about 0.55 m in front of A1 at 0.75 m height
    operator_pose_deg=(0.0, -45.0, 100.0, 0.0, -55.0, 0.0),
    calibration_poses_deg=(
        (0.0, -90.0, 90.0, 0.0, 0.0, 0.0),
        (0.0, -90.0, 90.0, 0.0, 30.0, 0.0),
        (0.0, -90.0, 90.0, 45.0, 30.0, 0.0),
        (0.0, -90.0, 90.0, 0.0, 0.0, 90.0),
    ),
    rated_payload_kg=10.0,  # [DS]
    max_payload_kg=10.0,  # assumed: the rated payload (no load diagram beyond it consulted)
    max_a5_torque_nm=19.6,  # assumed: 10 kg at 100 mm in front of the flange (see the module docstring)
    a1_envelope_deg=45.0,  # [P] §2.2, the same software envelope
    payload_lever_max_m=0.5,  # assumed: MPA + adapter rail + DuT of this class
    brake_release_deg=35.0,  # [P] §2.4.4, the same move
    calibration=CalibrationLoads(
        mpa_side_m=0.160,
        mpa_thickness_m=_MPA_THICKNESS_M,
        mpa_cutout_diameter_m=0.040,
        chain_origin_z_m=_CHAIN_ORIGIN_Z_M,
        body_mass_kg=0.77,  # 160 × 160 × 4 mm stainless with a 40 mm cut-out
        body_thickness_m=_BODY_THICKNESS_M,
        body_count_max=10,
        # the empty MPA's CoG: d6 + chain origin + half the plate
        zero_lever_a5_m=_D6_M + _CHAIN_ORIGIN_Z_M + _MPA_THICKNESS_M / 2,
        # n bodies on the MPA: their common CoG at the MPA's face + n · t / 2
        stack_lever_a5_m=_D6_M + _CHAIN_ORIGIN_Z_M + _MPA_THICKNESS_M,
        stack_step_m=_BODY_THICKNESS_M / 2,
        adapter_mass_kg=0.60,
        adapter_torque_a5_nm=0.60 * 9.81 * 0.20,  # its CoG 0.20 m in front of A5, at g = 9.81
        adapter_rail_section_m=0.030,
        adapter_rail_length_m=0.300,
        adapter_rail_a5_m=(0.12, 0.30),
        # 8 bodies (6.16 kg) on the adapter: 6.16 × 9.81 × 0.22 + 1.18 = 14.5 Nm ≤ 19.6 Nm; MPA + TA + 8 = 8.3 kg
        torque_levers_a5_m=(0.14, 0.18, 0.22),
        torque_body_count=8,
        torsional_points=(
            (2, (0.04, 0.0, 0.10)), (2, (0.0, -0.04, 0.10)), (4, (-0.04, 0.02, 0.13)), (4, (0.02, 0.04, 0.13)),
            (6, (0.04, -0.02, 0.15)), (6, (-0.02, -0.04, 0.16)),
        ),
        torsional_bracket_m=(0.06, 0.05, 0.20),
        torsional_body_count_max=6,
        fixture_mass_kg=0.50,
        fixture_thickness_m=0.010,
        fixture_side_m=0.150,
    ),
    cell=DefaultCell(
        frame_height_m=0.6,  # assumed (see the module docstring)
        frame_half_width_m=0.25,  # assumed
        payload_box_min_m=(-0.5, -0.5, 0.0),  # assumed: within payload_lever_max_m
        payload_box_max_m=(0.5, 0.5, 0.5),
    ),
)
