"""The robot files: each robot's figures are consistent with themselves and with its published data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.robots import RobotModel

ALL = sorted(robots.ROBOTS)


@pytest.fixture(params=ALL)
def robot(request: pytest.FixtureRequest) -> RobotModel:
    return robots.get(request.param)


def test_reach_from_the_dh_rows_is_the_published_reach(robot: RobotModel) -> None:
    a1, a2, a3, d4 = robot.dh[1].a_m, robot.dh[2].a_m, robot.dh[3].a_m, robot.dh[3].d_m
    # fully stretched (A2 = 0: upper arm horizontal; A3 scanned near 0): the wrist centre's largest distance from A1
    reach = max(math.hypot(*kin.joint_frames([0.0, 0.0, a3_deg, 0.0, 0.0, 0.0], robot)[4, :2, 3])
                for a3_deg in np.arange(-5.0, 5.0, 0.002))
    assert reach == pytest.approx(a1 + a2 + math.hypot(d4, a3), abs=1e-6)
    assert reach == pytest.approx(robot.reach_m, abs=0.002)


def test_home_pose_puts_the_flange_in_front_pointing_down_the_x_axis(robot: RobotModel) -> None:
    d = robot.dh
    pose = kin.flange_pose_xyzabc(robot.home_deg, robot)
    assert pose[0] == pytest.approx(1000 * (d[1].a_m + d[3].d_m + d[5].d_m))
    assert pose[2] == pytest.approx(1000 * (d[0].d_m + d[2].a_m - d[3].a_m))
    assert pose[3:] == pytest.approx([0.0, 90.0, 0.0], abs=1e-9)


def test_measurement_pose_lever_difference_is_delta_r_whatever_the_cog(robot: RobotModel) -> None:
    q = kin.measurement_pose(robot=robot)
    for cog in [(0.0, 0.0, 0.2), (0.05, -0.03, 0.4), (-0.1, 0.1, 0.05)]:
        dr = kin.horizontal_lever_m(q, 3, cog, robot) - kin.horizontal_lever_m(q, 5, cog, robot)
        assert dr == pytest.approx(robot.lever_difference_m, abs=1e-12)


def test_poses_are_within_the_axis_ranges_and_the_a1_envelope(robot: RobotModel) -> None:
    for q in (robot.home_deg, robot.candle_deg, robot.operator_pose_deg, *robot.calibration_poses_deg):
        assert kin.within_limits(q, robot=robot)
        assert abs(q[0]) <= robot.a1_envelope_deg


def test_the_calibration_load_set_stays_within_the_load_diagram(robot: RobotModel) -> None:
    c = robot.calibration
    q = kin.measurement_pose(robot=robot)
    mpa = c.mpa_side_m**2 - math.pi * (c.mpa_cutout_diameter_m / 2) ** 2
    mpa_mass = mpa * c.mpa_thickness_m * 7900.0
    assert mpa_mass + c.body_count_max * c.body_mass_kg <= robot.max_payload_kg
    ta_lever = c.adapter_torque_a5_nm / (9.81 * c.adapter_mass_kg)
    for lever in c.torque_levers_a5_m:
        bodies = c.torque_body_count * c.body_mass_kg
        assert mpa_mass + c.adapter_mass_kg + bodies <= robot.max_payload_kg
        torque = 9.81 * (bodies * lever + c.adapter_mass_kg * ta_lever)
        assert torque <= robot.max_a5_torque_nm
    for n, cog in c.torsional_points:
        assert n <= c.body_count_max
        assert abs(kin.gravity_torques_nm(q, [(n * c.body_mass_kg, cog)], 9.81, robot)[4]) <= robot.max_a5_torque_nm


def test_an_unknown_model_is_refused_with_the_known_ones_named() -> None:
    with pytest.raises(ValueError, match=r"unknown robot model 'kr5'.*kr10r1440.*kr500r2830"):
        robots.get("kr5")


def test_a_robot_whose_delta_r_is_not_d4_is_refused() -> None:
    import dataclasses
    r = robots.get("kr500r2830")
    with pytest.raises(ValueError, match="differs from d4"):
        dataclasses.replace(r, lever_difference_m=1.0)


def test_the_kr500_figures_are_the_paper_s() -> None:
    r = robots.get("kr500r2830")
    assert (r.max_payload_kg, r.max_a5_torque_nm, r.lever_difference_m, r.a1_envelope_deg) == (611.0, 3330.0,
                                                                                              1.025, 45.0)


def test_a_robot_whose_payload_box_reaches_past_its_payload_lever_is_refused() -> None:
    import dataclasses
    r = robots.get("kr10r1440")
    too_long = dataclasses.replace(r.cell, payload_box_max_m=(0.5, 0.5, r.payload_lever_max_m + 0.1))
    with pytest.raises(ValueError, match="payload_lever_max_m"):
        dataclasses.replace(r, cell=too_long)


def test_the_default_cell_is_the_configured_robot_s_and_the_kr500_s_is_unchanged() -> None:
    from rgse_daemon.config import BoxConfig, CellConfig, config_from_mapping
    # the KR 500: the paper's cell exactly as before the cell moved into the robot files
    kr500 = CellConfig(floor_z_m=-0.6, walls=BoxConfig(min_m=(-4.5, -4.5, -0.6), max_m=(4.5, 4.5, 5.0)),
                       keep_out=(BoxConfig(min_m=(-0.7, -0.7, -0.6), max_m=(0.7, 0.7, 0.0)),),
                       payload_box_flange_m=BoxConfig(min_m=(-1.0, -1.0, 0.0), max_m=(1.0, 1.0, 1.5)))
    assert config_from_mapping({}).cell == kr500 == CellConfig()
    assert config_from_mapping({"robot": {"model": "kr500r2830"}}).cell == kr500
    # the KR 10 gets its own payload box (its 0.5 m lever, not the KR 500's 1.5 m) and frame
    kr10 = robots.get("kr10r1440")
    cell = config_from_mapping({"robot": {"model": "kr10r1440"}}).cell
    assert cell == CellConfig.of_robot(kr10) != kr500
    assert max(cell.payload_box_flange_m.max_m) <= kr10.payload_lever_max_m
    # a site's [cell] key replaces just that default
    cell = config_from_mapping({"robot": {"model": "kr10r1440"}, "cell": {"floor_z_m": -0.9}}).cell
    assert cell.floor_z_m == -0.9 and cell.payload_box_flange_m == CellConfig.of_robot(kr10).payload_box_flange_m


def test_a_dut_heavier_than_the_limits_is_refused_for_the_configured_robot() -> None:
    from rgse_daemon.config import config_from_mapping
    from rgse_daemon.errors import ConfigError
    with pytest.raises((ConfigError, ValueError), match=r"cell\.dut_mass_kg"):
        config_from_mapping({"robot": {"model": "kr10r1440"}, "cell": {"dut_mass_kg": 20.0}})
    light = config_from_mapping({"robot": {"model": "kr10r1440"}, "cell": {"dut_mass_kg": 5.0}})
    assert light.cell.dut_mass_kg == 5.0
    assert config_from_mapping({"cell": {"dut_mass_kg": 300.0}}).cell.dut_mass_kg == 300.0
