"""KUKA KR 500 R2830 with KR C4: the paper's robot (the full-size RGSE at DLR Bremen).

Sources (docs/controller.md §1 and its source list):
- [P] the paper (Kottmeier, Wippermann, Schulz et al., Smart GSE): load diagram (Fig. 16: 611 kg, 3.33 kNm at A5),
  the measurement pose and Δr = 1.025 m (Table 1, eq. 3–4), the A1 envelope ±45° and 200 mm/s (§2.2), the
  calibration equipment (§2.4.2–2.4.3, Table 1, Table A1) and the ReFEx fixture (§2.4.7: 10.288 kg).
- [DS] KUKA's data sheet of the KR 500 R2830: rated payload 500 kg, reach 2826 mm, axis speeds (*approximate*:
  not compared with a current data sheet).
- [RKC] RobotKinematicsCatalogue (SaltworkerMLU), KR 500 R2830 entry: DH lengths d1 1045, a1 500, a2 1300, a3 55,
  d4 1025, d6 290 mm and the inverted joints A1, A4, A6; axis ranges (*approximate*). [KRD] kuka_robot_descriptions'
  kr600_r2830 joint origins agree with the lengths.
- Project choices (named as such): the operator pose, the CoG calibration poses, the torsional points, the
  default payload lever and the geometry of the plates (chosen to reproduce Table 1's effective levers).
- The default cell: the robot on the paper's 600 mm frame ([P]); the frame's 1.4 × 1.4 m footprint and the payload
  box (±1 m across, 1.5 m out of the flange: MPA + TA rail + DuT) are project choices.
"""

from __future__ import annotations

from rgse_daemon.robots.model import CalibrationLoads, DefaultCell, DhRow, RobotModel

ROBOT = RobotModel(
    key="kr500r2830",
    title="KR 500 R2830",
    # [RKC] lengths in the modified-DH convention of rgse_daemon.kinematics (its docstring's table)
    dh=(
        DhRow(alpha_deg=0.0, a_m=0.0, d_m=1.045),
        DhRow(alpha_deg=-90.0, a_m=0.500, d_m=0.0),
        DhRow(alpha_deg=0.0, a_m=1.300, d_m=0.0),
        DhRow(alpha_deg=90.0, a_m=0.055, d_m=1.025),
        DhRow(alpha_deg=-90.0, a_m=0.0, d_m=0.0),
        DhRow(alpha_deg=90.0, a_m=0.0, d_m=0.290),
    ),
    axis_sign=(-1.0, 1.0, 1.0, -1.0, 1.0, -1.0),  # [RKC]: A1, A4, A6 inverted
    theta_offset_deg=(0.0, 0.0, 90.0, 0.0, 0.0, 0.0),
    # [RKC], approximate
    axis_range_deg=((-185.0, 185.0), (-130.0, 20.0), (-100.0, 144.0), (-350.0, 350.0), (-120.0, 120.0),
                    (-350.0, 350.0)),
    max_axis_speed_deg_s=(80.0, 75.0, 70.0, 90.0, 80.0, 122.0),  # [DS], approximate
    reach_m=2.826,  # [DS]
    home_deg=(0.0, -90.0, 90.0, 0.0, 0.0, 0.0),  # KUKA's home; docs/controller.md §4's $AXIS_ACT example
    candle_deg=(0.0, -90.0, 0.0, 0.0, 0.0, 0.0),
    measurement_a2_deg=-90.0,  # [P] Fig. 19/21: upper arm vertical, forearm horizontal
    lever_difference_m=1.025,  # [P] Table 1, eq. 3–4 (= d4)
    # project choice: flange horizontal at about 1.1 m height, 2.25 m in front of A1
    operator_pose_deg=(0.0, -45.0, 100.0, 0.0, -55.0, 0.0),
    calibration_poses_deg=(
        (0.0, -90.0, 90.0, 0.0, 0.0, 0.0),
        (0.0, -90.0, 90.0, 0.0, 30.0, 0.0),
        (0.0, -90.0, 90.0, 45.0, 30.0, 0.0),
        (0.0, -90.0, 90.0, 0.0, 0.0, 90.0),
    ),
    rated_payload_kg=500.0,  # [DS]
    max_payload_kg=611.0,  # [P] Fig. 16
    max_a5_torque_nm=3330.0,  # [P] Fig. 16
    a1_envelope_deg=45.0,  # [P] §2.2
    payload_lever_max_m=1.5,  # project choice: MPA + TA rail + DuT
    brake_release_deg=35.0,  # [P] §2.4.4
    calibration=CalibrationLoads(
        mpa_side_m=0.440,  # [P] §2.4.2: 440 × 440 × 20 mm stainless plate, 120 mm cut-out
        mpa_thickness_m=0.020,
        mpa_cutout_diameter_m=0.120,
        chain_origin_z_m=-0.035,  # chosen so that the chain reproduces Table 1's effective levers
        body_mass_kg=20.93,  # [P] Table 1
        body_thickness_m=0.015,  # [P] §2.4.2
        body_count_max=10,  # [P] Table 1
        zero_lever_a5_m=0.265,  # [P] Table 1 '0 (MPA)' row
        stack_lever_a5_m=0.275,  # [P] Table 1's printed levers − 0.020 m
        stack_step_m=0.0075,
        adapter_mass_kg=19.20,  # [P] Table 1: 228.51 kg − 10 × 20.93 kg
        adapter_torque_a5_nm=217.95,  # [P] Table A1, at g = 9.81
        adapter_rail_section_m=0.120,  # assumed (the rail's inertia only)
        adapter_rail_length_m=1.000,
        adapter_rail_a5_m=(0.60, 1.50),  # [P] Table A1's 0.673..1.475 m with margin
        torque_levers_a5_m=(0.761, 1.011, 1.261),  # [P] Table 1 torque rows
        torque_body_count=10,  # [P] Table 1
        # project choice (issue #14): payload torques of A3..A6 spanning a 100–130 kg DuT in every CoG pose
        torsional_points=(
            (2, (0.10, 0.0, 0.30)), (2, (0.0, -0.10, 0.30)), (4, (-0.10, 0.05, 0.40)), (4, (0.05, 0.10, 0.40)),
            (6, (0.10, -0.05, 0.45)), (6, (-0.05, -0.10, 0.50)),
        ),
        torsional_bracket_m=(0.20, 0.10, 0.60),  # project choice: the rail of Fig. 18 turned across the MPA
        torsional_body_count_max=6,
        fixture_mass_kg=10.288,  # [P] §2.4.7, the ReFEx fixture
        fixture_thickness_m=0.040,
        fixture_side_m=0.400,  # assumed footprint (its inertia only)
    ),
    cell=DefaultCell(
        frame_height_m=0.6,  # [P] the robot's 600 mm frame
        frame_half_width_m=0.7,  # project choice: the frame's footprint
        payload_box_min_m=(-1.0, -1.0, 0.0),  # project choice: within payload_lever_max_m
        payload_box_max_m=(1.0, 1.0, 1.5),
    ),
    # project choice (issue #35): the measurement pose and the forearm raised by 80° (A3 10°, A5 +80°): the flange's
    # lever to A3 falls from 1.315 to 0.522 m while its orientation, and so every load's A5 torque, stays. Not 90°:
    # the brake-release move's +35° on A5 would pass its +120° limit (the interlock's static check refuses it)
    multipose_a3_deg=(0.0, -80.0),
)
