"""The interlock for every robot of ``rgse_daemon/robots/``: its axis ranges, speeds, load diagram and A1 envelope
are the ones the static check enforces (issue 32: "the interlock test suite runs for both robots").

Each case is written relative to the robot's own figures, so a third robot file is covered without editing this
module; the cross cases show that one robot's limits do not leak into the other's check.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.config import LimitsConfig, config_from_mapping
from rgse_daemon.errors import ConfigError
from rgse_daemon.krl.render import TemplateDefaults, cube_corners, default_params, render
from rgse_daemon.robots import RobotModel
from rgse_daemon.safety.static import CheckContext, check_program

SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 1\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))


@pytest.fixture(params=sorted(robots.ROBOTS))
def robot(request: pytest.FixtureRequest) -> Iterator[RobotModel]:
    """Each robot in turn, active as a configured daemon makes it (and the default restored afterwards)."""
    r = robots.get(request.param)
    previous = robots.activate(r)
    try:
        yield r
    finally:
        robots.activate(previous)


def limits_of(r: RobotModel) -> LimitsConfig:
    return config_from_mapping({"robot": {"model": r.key}}).limits


def ctx_of(r: RobotModel, **kw: object) -> CheckContext:
    base: dict[str, object] = {"limits": limits_of(r), "start_axes_deg": tuple(r.home_deg),
                               "payload_mass_kg": 0.5 * r.rated_payload_kg,
                               "payload_cog_flange_m": (0.0, 0.0, 0.5 * r.dh[5].d_m)}
    base.update(kw)
    return CheckContext(**base)  # type: ignore[arg-type]


def program(body: str) -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF prop( )\n{SLOW}\n{body}\nEND\n"


def axes(q: tuple[float, ...] | np.ndarray) -> str:
    return "{E6AXIS: " + ", ".join(f"A{i} {v:g}" for i, v in enumerate(q, 1)) + "}"


def rules(r: RobotModel, body: str, **kw: object) -> set[str]:
    return {v.rule for v in check_program(program(body), None, ctx_of(r, **kw), "prop.src")}


def test_the_robot_s_own_poses_are_allowed_at_a_slow_speed(robot: RobotModel) -> None:
    for q in (robot.home_deg, kin.measurement_pose(), robot.operator_pose_deg, *robot.calibration_poses_deg):
        assert rules(robot, f"  PTP {axes(q)}") == set(), q


@pytest.mark.parametrize("axis", range(1, 7))
@pytest.mark.parametrize("side", [0, 1])
def test_a_target_past_an_axis_range_is_refused(robot: RobotModel, axis: int, side: int) -> None:
    lo, hi = robot.axis_range_deg[axis - 1]
    q = list(robot.home_deg)
    q[axis - 1] = hi + 1.0 if side else lo - 1.0
    found = rules(robot, f"  PTP {axes(tuple(q))}")
    assert "JOINT_LIMIT" in found
    # and just inside the range that axis is no joint-limit violation
    q[axis - 1] = hi - 1.0 if side else lo + 1.0
    assert "JOINT_LIMIT" not in rules(robot, f"  PTP {axes(tuple(q))}")


def test_a1_outside_the_envelope_is_refused(robot: RobotModel) -> None:
    q = list(robot.home_deg)
    q[0] = robot.a1_envelope_deg + 1.0
    assert "A1_ENVELOPE" in rules(robot, f"  PTP {axes(tuple(q))}")
    q[0] = robot.a1_envelope_deg - 1.0
    assert rules(robot, f"  PTP {axes(tuple(q))}") == set()


def test_a_payload_above_the_load_diagram_is_refused(robot: RobotModel) -> None:
    body = f"  PTP {axes(robot.home_deg)}"
    assert "PAYLOAD" in rules(robot, body, payload_mass_kg=1.01 * robot.max_payload_kg,
                              payload_cog_flange_m=(0.0, 0.0, 0.0))
    assert "PAYLOAD" not in rules(robot, body, payload_mass_kg=robot.max_payload_kg,
                                  payload_cog_flange_m=(0.0, 0.0, 0.0))


def test_a_limit_configured_above_the_robot_is_still_refused_by_its_load_diagram(robot: RobotModel) -> None:
    # a LimitsConfig written for the heaviest arm (no [robot] model): the check caps it at this robot's diagram
    heavy = LimitsConfig(max_payload_kg=max(r.max_payload_kg for r in robots.ROBOTS.values()),
                         max_a5_torque_nm=max(r.max_a5_torque_nm for r in robots.ROBOTS.values()))
    body = f"  PTP {axes(robot.home_deg)}"
    assert "PAYLOAD" in rules(robot, body, limits=heavy, payload_mass_kg=1.01 * robot.max_payload_kg,
                              payload_cog_flange_m=(0.0, 0.0, 0.0))
    lever_m = 1.2 * robot.max_a5_torque_nm / (kin.G_PAPER_M_S2 * robot.max_payload_kg)
    assert "A5_TORQUE" in rules(robot, f"  PTP {axes(kin.measurement_pose())}", limits=heavy,
                                start_axes_deg=tuple(kin.measurement_pose()), payload_mass_kg=robot.max_payload_kg,
                                payload_cog_flange_m=(0.0, 0.0, lever_m))


def test_the_a5_torque_of_the_load_diagram_is_enforced(robot: RobotModel) -> None:
    meas = tuple(kin.measurement_pose())
    mass = robot.max_payload_kg
    # the CoG in front of the flange so that the A5 torque in the measurement pose is 20 % over the diagram's
    lever_m = 1.2 * robot.max_a5_torque_nm / (kin.G_PAPER_M_S2 * mass) - robot.dh[5].d_m
    assert "A5_TORQUE" in rules(robot, f"  PTP {axes(meas)}", start_axes_deg=meas, payload_mass_kg=mass,
                                payload_cog_flange_m=(0.0, 0.0, lever_m))
    lever_ok_m = 0.8 * robot.max_a5_torque_nm / (kin.G_PAPER_M_S2 * mass) - robot.dh[5].d_m
    assert "A5_TORQUE" not in rules(robot, f"  PTP {axes(meas)}", start_axes_deg=meas, payload_mass_kg=mass,
                                    payload_cog_flange_m=(0.0, 0.0, max(lever_ok_m, 0.0)))


def test_full_axis_speed_is_too_fast_for_t1_and_the_renderer_s_speed_is_not(robot: RobotModel) -> None:
    meas = tuple(kin.measurement_pose())
    target = (meas[0], meas[1], meas[2] + 30.0, meas[3], meas[4] + 30.0, meas[5])
    fast = "\n".join(f"  $VEL_AXIS[{i}] = 100" for i in range(1, 7)) + f"\n  PTP {axes(target)}"
    assert "SPEED" in rules(robot, fast, start_axes_deg=meas)
    # the rendered brake-release move (the robot's speeds, its measurement pose) passes the same check
    d = TemplateDefaults(payload_points_flange_m=cube_corners(robot.payload_lever_max_m))
    rendered = render("rgse_brake_release", default_params("rgse_brake_release", d))
    ctx = ctx_of(robot, start_axes_deg=meas, payload_points_flange_m=tuple(cube_corners(robot.payload_lever_max_m)))
    assert check_program(rendered.src_text, rendered.dat_text, ctx, rendered.name + ".src") == []


def test_the_two_robots_refuse_each_other_s_poses() -> None:
    kr500, kr10 = robots.get("kr500r2830"), robots.get("kr10r1440")
    # A3 at 150 deg: inside the KR 10's range (−137..163), outside the KR 500's (−100..144); A2 at +30 the other way
    # round is outside the KR 500's (−130..20) and inside the KR 10's (−185..65)
    for q in ((0.0, -90.0, 150.0, 0.0, 0.0, 0.0), (0.0, 30.0, 0.0, 0.0, 0.0, 0.0)):
        found_500 = {v.rule for v in check_program(program(f"  PTP {axes(q)}"), None,
                                                   ctx_of(kr500, robot=kr500), "prop.src")}
        found_10 = {v.rule for v in check_program(program(f"  PTP {axes(q)}"), None,
                                                  ctx_of(kr10, robot=kr10), "prop.src")}
        assert "JOINT_LIMIT" in found_500
        assert "JOINT_LIMIT" not in found_10
    # 20 kg is nothing to the KR 500 and twice the KR 10's rated payload
    body = f"  PTP {axes(kr10.home_deg)}"
    assert "PAYLOAD" in {v.rule for v in check_program(program(body), None,
                                                       ctx_of(kr10, robot=kr10, payload_mass_kg=20.0), "prop.src")}
    assert "PAYLOAD" not in {v.rule for v in check_program(program(body), None,
                                                           ctx_of(kr500, robot=kr500, payload_mass_kg=20.0),
                                                           "prop.src")}


def test_the_config_refuses_limits_above_the_robot() -> None:
    with pytest.raises(ConfigError, match=r"limits.max_payload_kg = 20 exceeds the KR 10 R1440-2's load diagram"):
        config_from_mapping({"robot": {"model": "kr10r1440"}, "limits": {"max_payload_kg": 20.0}})
    with pytest.raises(ConfigError, match=r"limits.max_a5_torque_nm = 3330 exceeds"):
        config_from_mapping({"robot": {"model": "kr10r1440"}, "limits": {"max_a5_torque_nm": 3330.0}})
    with pytest.raises(ConfigError, match=r"robot.model: unknown robot model 'kr6'"):
        config_from_mapping({"robot": {"model": "kr6"}})
    kr10 = config_from_mapping({"robot": {"model": "kr10r1440"}})
    assert (kr10.limits.max_payload_kg, kr10.limits.max_a5_torque_nm) == (10.0, 19.6)
