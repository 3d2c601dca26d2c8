"""``[robot] model`` selects the arm everywhere: the config's limits, the process's active robot, the command
schemas' mass bound, the renderer's defaults, the simulated controller (its name, home pose, software limits)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.config import load_config
from rgse_daemon.io.commands import CommandRefused, parse_command
from rgse_daemon.krl.render import TemplateDefaults, default_params
from rgse_daemon.link.krlvalue import parse_value
from rgse_daemon.robots import RobotModel
from simulators.krc4.motion import MotionError, check_limits
from simulators.krc4.sim import SimulatedKrc4


@pytest.fixture(autouse=True)
def restore_active_robot() -> Iterator[None]:
    previous = robots.active()
    try:
        yield
    finally:
        robots.activate(previous)


@pytest.fixture(params=sorted(robots.ROBOTS))
def robot(request: pytest.FixtureRequest) -> RobotModel:
    return robots.get(request.param)


def test_load_config_makes_the_configured_robot_active(tmp_path: Path, robot: RobotModel) -> None:
    path = tmp_path / "rgse.toml"
    path.write_text(f'[robot]\nmodel = "{robot.key.upper()}"\n', encoding="utf-8")
    cfg = load_config(path)
    assert cfg.robot.model == robot.key and cfg.robot_model is robot
    assert robots.active() is robot
    assert cfg.limits.max_payload_kg == robot.max_payload_kg
    assert cfg.limits.max_a5_torque_nm == robot.max_a5_torque_nm
    assert cfg.measurement.payload_lever_max_m == robot.payload_lever_max_m
    # the kinematics and the renderer follow it: the measurement pose, the operator pose
    assert tuple(kin.measurement_pose()) == (0.0, robot.measurement_a2_deg, -robot.measurement_a2_deg, 0.0, 0.0, 0.0)
    d = TemplateDefaults()
    assert d.oper_pose == robot.operator_pose_deg and d.cal_poses == robot.calibration_poses_deg
    assert default_params("rgse_oper_pose", d).oper_pose == robot.operator_pose_deg  # type: ignore[attr-defined]


def test_a_command_s_mass_is_bounded_by_the_active_robot_s_load_diagram(robot: RobotModel) -> None:
    robots.activate(robot)
    ok = parse_command("measure", b'{"request_id": "r1", "fixture_mass_kg": %g}' % robot.max_payload_kg)
    assert ok.fixture_mass_kg == robot.max_payload_kg  # type: ignore[attr-defined]
    with pytest.raises(CommandRefused, match=r"exceeds the .* load diagram"):
        parse_command("measure", b'{"request_id": "r2", "fixture_mass_kg": %g}' % (robot.max_payload_kg + 1.0))


def test_the_kr500_s_611_kg_diagram_is_what_a_command_may_name_not_500() -> None:
    robots.activate("kr500r2830")
    cmd = parse_command("measure", b'{"request_id": "r1", "fixture_mass_kg": 600.0}')
    assert cmd.fixture_mass_kg == 600.0  # type: ignore[attr-defined]
    robots.activate("kr10r1440")
    with pytest.raises(CommandRefused):
        parse_command("measure", b'{"request_id": "r1", "fixture_mass_kg": 600.0}')


def test_the_simulated_controller_is_the_scenario_s_robot(tmp_path: Path, robot: RobotModel) -> None:
    from simulators.krc4.scenario import scenario_for

    sim = SimulatedKrc4(tmp_path, scenario=scenario_for(robot.key), latency_s=0.0)
    assert robots.active() is robot
    assert sim.store.read("$MODEL_NAME[]") == f'"#{robot.title.replace(" ", "")} C4"'
    assert sim.store.read("$ROBNAME[]") == f'"{robot.title.replace(" ", "")}"'
    home = dict(parse_value(sim.store.read("$AXIS_ACT")).fields)  # type: ignore[union-attr]
    assert tuple(home[f"A{i}"] for i in range(1, 7)) == robot.home_deg
    # its software limits are this arm's: A3 150 deg is within the KR 10's range, beyond the KR 500's
    q = (0.0, -90.0, 150.0, 0.0, 0.0, 0.0)
    if robot.axis_range_deg[2][1] >= 150.0:
        check_limits(q)
    else:
        with pytest.raises(MotionError, match="A3 target 150"):
            check_limits(q)


def test_the_simulated_dynamics_are_the_robot_s_and_reduce_to_its_statics_at_rest(robot: RobotModel) -> None:
    from simulators.krc4.dynamics import RobotDynamics
    from simulators.krc4.physics import RobotModel as SimArm
    from simulators.krc4.physics import mass_calibration_payload
    from simulators.krc4.scenario import scenario_for

    robots.activate(robot)
    scenario = scenario_for(robot.key)
    arm = SimArm(scenario)
    dyn = RobotDynamics(scenario, robot=arm.robot)  # the arm as built, as the simulator's statics
    payload = mass_calibration_payload(3)
    q = kin.measurement_pose()
    at_rest = dyn.torques_nm(q, [0.0] * 6, [0.0] * 6, payload, armature=False)
    statics = arm.arm_torques_nm(q) + kin.gravity_torques_nm(q, [(payload.mass_kg, payload.cog_flange_m)],
                                                             scenario.g_m_s2, arm.robot)
    assert at_rest == pytest.approx(statics, abs=1e-6 * max(1.0, float(abs(statics).max())))
    # accelerating A1 at 100 deg/s² takes a torque of the arm's size: the KR 10's is 50-200 times smaller
    inertial = dyn.torques_nm(q, [0.0] * 6, [100.0, 0, 0, 0, 0, 0], None, gravity=False)[0]
    expected = {"kr500r2830": (1000.0, 10000.0), "kr10r1440": (5.0, 100.0)}[robot.key]
    assert expected[0] < abs(inertial) < expected[1], inertial
