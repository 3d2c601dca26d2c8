"""The world rules of the static check at their exact limits (issue #31 item 6: survivors of mutmut on
``safety/static.py`` after the workspace, payload, motion-time and watchdog rules were merged).

Each limit is met exactly and then missed by the smallest step, and each verdict is asserted with its rule, line and
reason: the motion-time bound of a trapezoid worked out by hand, the bound of a program and of a long FOR exactly
met, the worst credible payload exactly at the load diagram's margin, the floor and a keep-out box exactly touched
with the sampling margin, the watchdog routine's allowed statements one by one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon.config import BoxConfig, CellConfig, Config, LimitsConfig, config_from_mapping
from rgse_daemon.kinematics import G_PAPER_M_S2, joint_frames
from rgse_daemon.krl.abstract import State
from rgse_daemon.safety.static import CheckContext, Violation, _Checker, check_program, mounted_payload

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
CTX = CheckContext(start_axes_deg=MEAS)
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))
#: Line of the first statement after the slow settings (3 header lines, optional decls, 12 settings).
FIRST = 16
#: KR 500 R2830: axis speeds (deg/s) and d6 (m), the numbers the hand calculations below use.
SPEEDS = (80.0, 75.0, 70.0, 90.0, 80.0, 122.0)
D6_M = 0.29


def program(body: str, decls: str = "", slow: str = SLOW) -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF world( )\n{decls}{slow}\n{body}\nEND\n"


def found(src: str, ctx: CheckContext = CTX) -> list[Violation]:
    return check_program(src, None, ctx, "world.src")


def state(vel: float = 2.0, acc: float = 20.0, ov: float = 100.0, vel_min: tuple[float, ...] | None = None,
          acc_min: tuple[float, ...] | None = None) -> State:
    return State(frozenset({MEAS}), (vel,) * 6, ov, (), vel_axis_min_pct=vel_min or (vel,) * 6,
                 acc_axis_min_pct=acc_min or (acc,) * 6, override_min_pct=ov)


def pose(**axes: float) -> tuple[float, ...]:
    q = list(MEAS)
    for name, v in axes.items():
        q[int(name[1]) - 1] = v
    return tuple(q)


# --- the motion-time bound by hand ------------------------------------------------------------------------------------
def test_the_motion_time_of_a_trapezoid_and_of_a_triangle_by_hand() -> None:
    """A3 at 2 % of 70 deg/s = 1.4 deg/s, accelerating at 20 % of 70/2 deg/s² = 7 deg/s²: the ramp covers
    v²/a = 0.28 deg. 10 deg take 10/1.4 + 1.4/7 = 7.342857 s (trapezoid), 0.1 deg 2·√(0.1/7) = 0.239046 s
    (triangle); both formulas meet at 0.28 deg (0.4 s)."""
    checker = _Checker(CTX)
    st = state()
    assert SPEEDS == CTX.robot.max_axis_speed_deg_s and CTX.limits.axis_ramp_max_s == 2.0
    assert checker.motion_time_s(MEAS, pose(a3=100.0), st) == pytest.approx(10 / 1.4 + 0.2, rel=1e-12)
    assert checker.motion_time_s(MEAS, pose(a3=80.0), st) == pytest.approx(10 / 1.4 + 0.2, rel=1e-12)
    assert checker.motion_time_s(MEAS, pose(a3=90.1), st) == pytest.approx(2 * math.sqrt(0.1 / 7), rel=1e-12)
    assert checker.motion_time_s(MEAS, pose(a3=90.28), st) == pytest.approx(0.4, rel=1e-9)
    assert checker.motion_time_s(MEAS, MEAS, st) == 0.0
    # the synchronised PTP ends with its slowest axis: A1 (80 deg/s) and A3 (70 deg/s) both 10 deg, A3 is slower;
    # an axis that stays put (A2 here, before A3) is skipped, not the end of the sum
    a1_s = 10 / 1.6 + 1.6 / 8
    assert checker.motion_time_s(MEAS, pose(a1=10.0), st) == pytest.approx(a1_s, rel=1e-12)
    assert checker.motion_time_s(MEAS, pose(a1=10.0, a3=100.0), st) == pytest.approx(10 / 1.4 + 0.2, rel=1e-12)
    assert checker.motion_time_s(MEAS, pose(a6=10.0), st) == pytest.approx(10 / 2.44 + 2.44 / 12.2, rel=1e-12)


def test_the_motion_time_at_a_lower_override_and_at_the_floors() -> None:
    checker = _Checker(CTX)
    # $OV_PRO 50: the speed halves, the acceleration quarters (v 0.7 deg/s, a 1.75 deg/s², ramp 0.28 deg)
    assert checker.motion_time_s(MEAS, pose(a3=100.0), state(ov=50.0)) == pytest.approx(10 / 0.7 + 0.4, rel=1e-12)
    # an override below 1 % counts as 1 % (the smallest a program may set)
    one = checker.motion_time_s(MEAS, pose(a3=100.0), state(ov=1.0))
    assert checker.motion_time_s(MEAS, pose(a3=100.0), state(ov=0.5)) == one
    assert one == pytest.approx(10 / 0.014 + 0.014 / 0.0007, rel=1e-12)
    # a speed or acceleration the program never set is taken at the renderer's floor, 0.01 % as a REAL holds it
    floor = float(np.float32(0.01))
    v, a = 70 * floor / 100, 35 * 20 / 100
    assert checker.motion_time_s(MEAS, pose(a3=100.0), state(vel_min=(0.0,) * 6)) == pytest.approx(
        10 / v + v / a, rel=1e-12)
    a = 35 * floor / 100
    assert checker.motion_time_s(MEAS, pose(a3=100.0), state(acc_min=(0.0,) * 6)) == pytest.approx(
        10 / 1.4 + 1.4 / a if 10 >= 1.4**2 / a else 2 * math.sqrt(10 / a), rel=1e-12)
    # per axis: only A3's own settings count for A3
    mixed = state(vel_min=(100.0, 100.0, 2.0, 100.0, 100.0, 100.0), acc_min=(100.0, 100.0, 20.0, 100.0, 100.0, 100.0))
    assert checker.motion_time_s(MEAS, pose(a3=100.0), mixed) == pytest.approx(10 / 1.4 + 0.2, rel=1e-12)


def test_the_ramp_time_is_the_configured_one() -> None:
    slow_ramp = _Checker(CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(axis_ramp_max_s=4.0)))
    # a = 70/4 · 20 % = 3.5 deg/s²
    assert slow_ramp.motion_time_s(MEAS, pose(a3=100.0), state()) == pytest.approx(10 / 1.4 + 1.4 / 3.5, rel=1e-12)


# --- the motion-time bound exactly met --------------------------------------------------------------------------------
def _limits(max_motion_s: float) -> CheckContext:
    return CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(max_motion_s=max_motion_s))


def test_a_program_exactly_at_the_motion_time_bound_is_allowed_just_above_it_refused() -> None:
    src = program("  PTP {A3 100}\n  PTP {A3 90}")
    bound_s = 2 * (10 / 1.4 + 0.2)
    assert found(src, _limits(bound_s)) == []
    v = found(src, _limits(math.nextafter(bound_s, 0.0)))
    assert [(x.line, x.column, x.rule) for x in v] == [(3, 1, "MOTION_TIME")]
    assert v[0].message == (f"the program's motion takes up to {bound_s:.4g} s, above limits.max_motion_s = "
                            f"{math.nextafter(bound_s, 0.0):g} s")
    # the longest branch counts, and a RETURN's path too
    branch = program("  IF RGSE_ARG == 1 THEN\n    PTP {A3 100}\n    RETURN\n  ENDIF\n  PTP {A3 91}")
    assert found(branch, _limits(10 / 1.4 + 0.2)) == []
    assert [x.rule for x in found(branch, _limits(10 / 1.4 + 0.19))] == ["MOTION_TIME"]


def test_a_long_for_exactly_at_the_bound_is_allowed_just_above_it_refused() -> None:
    """2000 passes (a fixpoint, not unrolled) of two 0.0625 deg moves (exact in a REAL) of 2·√(0.0625/7) s each."""
    src = program("  FOR i = 1 TO 2000\n    PTP {A3 90.0625}\n    PTP {A3 90}\n  ENDFOR", "  DECL INT i\n")
    checker = _Checker(CTX)
    per_pass_s = 2 * checker.motion_time_s(MEAS, pose(a3=90.0625), state())
    assert per_pass_s == pytest.approx(4 * math.sqrt(0.0625 / 7), rel=1e-12)
    bound_s = per_pass_s * 2000
    assert found(src, _limits(bound_s)) == []
    below = math.nextafter(bound_s, 0.0)
    v = found(src, _limits(below))
    assert [(x.line, x.rule) for x in v] == [(3, "MOTION_TIME"), (FIRST + 1, "MOTION_TIME")]
    assert v[1].message == (f"2000 passes of up to {per_pass_s:.3g} s of motion each: up to {bound_s:.3g} s, above "
                            f"limits.max_motion_s = {below:g} s")


def test_a_loop_without_motion_adds_no_time() -> None:
    """A long FOR of nothing but writes, then a motion exactly at the bound: the loop adds 0 s."""
    src = program("  FOR i = 1 TO 2000\n    RGSE_LOOP = i\n  ENDFOR\n  PTP {A3 100}", "  DECL INT i\n")
    assert found(src, _limits(10 / 1.4 + 0.2)) == []
    unbounded = program("  LOOP\n    RGSE_LOOP = 1\n  ENDLOOP\n  PTP {A3 100}")
    assert found(unbounded, _limits(10 / 1.4 + 0.2)) == []


def test_a_short_pass_inside_an_endless_loop_is_still_unbounded() -> None:
    """A pass of 0.38 s (less than a second) in a LOOP without EXIT: no bound, whatever its length."""
    src = program("  LOOP\n    PTP {A3 90.0625}\n    PTP {A3 90}\n  ENDLOOP")
    v = found(src)
    assert [(x.line, x.rule) for x in v] == [(FIRST, "UNBOUNDED")]
    assert v[0].message == ("motions inside a LOOP without a reachable EXIT (and not paced by a host command each "
                            "pass): its motion time has no bound")


def test_a_loop_with_an_exit_that_is_not_paced_is_unbounded_with_its_reason() -> None:
    body = ("  LOOP\n    IF RGSE_CMD == 99 THEN\n      EXIT\n    ENDIF\n    PTP {A3 100}\n    PTP {A3 90}\n"
            "  ENDLOOP")
    v = found(program(body))
    assert [(x.line, x.rule) for x in v] == [(FIRST, "UNBOUNDED")]
    assert v[0].message == ("motions inside a loop whose number of passes cannot be proven (and not paced by a host "
                            "command each pass): its motion time has no bound")
    w = found(program("  WHILE RGSE_CMD <> 99\n    PTP {A3 100}\n    PTP {A3 90}\n  ENDWHILE"))
    assert [(x.line, x.rule) for x in w] == [(FIRST, "UNBOUNDED")]
    assert w[0].message == v[0].message


def test_a_host_paced_pass_exactly_at_the_bound() -> None:
    """The resident program's command loop: bounded per command, the pass's motion time against the maximum."""
    body = ("  LOOP\n    WAIT FOR RGSE_CMD <> 0\n    IF RGSE_CMD == 99 THEN\n      EXIT\n    ENDIF\n"
            "    PTP {A3 100}\n    PTP {A3 90}\n    RGSE_CMD = 0\n  ENDLOOP")
    pass_s = 2 * (10 / 1.4 + 0.2)
    assert found(program(body), _limits(pass_s)) == []
    v = found(program(body), _limits(math.nextafter(pass_s, 0.0)))
    assert [(x.line, x.rule) for x in v] == [(3, "MOTION_TIME")]
    # two motions before the loop add to its pass
    before = program("  PTP {A3 100}\n  PTP {A3 90}\n" + body)
    assert found(before, _limits(2 * pass_s)) == []
    assert [x.rule for x in found(before, _limits(math.nextafter(2 * pass_s, 0.0)))] == ["MOTION_TIME"]


# --- the worst credible payload ---------------------------------------------------------------------------------------
def test_the_worst_credible_payload_by_hand() -> None:
    """Nothing configured: the heaviest payload (611 kg), its CoG on the flange axis so far out that the A5 torque
    in the measurement pose is 90 % of the load diagram: 611·9.81·(z + 0.29) = 0.9·3330 Nm."""
    cfg = Config()
    mass_kg, cog = mounted_payload(cfg)
    assert mass_kg == 611.0
    assert cog[:2] == (0.0, 0.0)
    assert cog[2] == pytest.approx(0.9 * 3330.0 / (611.0 * G_PAPER_M_S2) - D6_M, rel=1e-12)
    assert mass_kg * G_PAPER_M_S2 * (cog[2] + D6_M) == pytest.approx(0.9 * 3330.0, rel=1e-12)
    # a given DuT mass without a CoG: the lever for that mass
    mass_kg, cog = mounted_payload(cfg, 300.0)
    assert mass_kg == 300.0
    assert cog == (0.0, 0.0, pytest.approx(0.9 * 3330.0 / (300.0 * G_PAPER_M_S2) - D6_M, rel=1e-12))
    # a tight torque limit: the lever would lie inside the wrist, the CoG sits on the flange (never behind it)
    tight = config_from_mapping({"limits": {"max_a5_torque_nm": 100.0}})
    assert mounted_payload(tight) == (611.0, (0.0, 0.0, 0.0))
    # a light DuT: far out
    assert mounted_payload(cfg, 0.5)[1][2] == pytest.approx(0.9 * 3330.0 / (0.5 * G_PAPER_M_S2) - D6_M, rel=1e-12)


def test_the_worst_credible_payload_with_a_fixture() -> None:
    fixture = {"measurement": {"fixture_mass_kg": 100.0}, "properties": {"fixture": {"cog_flange_m": [0.0, 0.0, 0.1]}}}
    # the DuT the limits still allow: 511 kg, and the lever of the whole 611 kg
    mass_kg, cog = mounted_payload(config_from_mapping(fixture))
    assert mass_kg == 611.0
    assert cog == (0.0, 0.0, pytest.approx(0.9 * 3330.0 / (611.0 * G_PAPER_M_S2) - D6_M, rel=1e-12))
    # a fixture as heavy as the limit leaves no DuT: the fixture alone
    full = config_from_mapping({"measurement": {"fixture_mass_kg": 611.0}})
    assert mounted_payload(full)[0] == 611.0


def test_the_configured_payload_is_the_mass_weighted_cog() -> None:
    cfg = config_from_mapping({"measurement": {"fixture_mass_kg": 100.0},
                               "properties": {"fixture": {"cog_flange_m": [0.3, 0.1, 0.1]}},
                               "cell": {"dut_mass_kg": 300.0, "dut_cog_flange_m": [0.1, -0.2, 0.3]}})
    mass_kg, cog = mounted_payload(cfg)
    assert mass_kg == 400.0
    assert cog == pytest.approx((0.15, -0.125, 0.25), rel=1e-12, abs=1e-15)
    # a fixture without a configured CoG sits on the flange
    no_cog = config_from_mapping({"measurement": {"fixture_mass_kg": 100.0},
                                  "cell": {"dut_mass_kg": 100.0, "dut_cog_flange_m": [0.1, -0.2, 0.3]}})
    assert mounted_payload(no_cog) == (200.0, pytest.approx((0.05, -0.1, 0.15), rel=1e-12))
    # given values win over the configured ones, a given 0 kg too
    assert mounted_payload(cfg, 0.0, (0.0, 0.0, 0.9)) == (100.0, pytest.approx((0.3, 0.1, 0.1), rel=1e-12))
    assert mounted_payload(cfg, 100.0) == (200.0, pytest.approx((0.2, -0.05, 0.2), rel=1e-12))
    # nothing on the flange at all: no payload, at the flange
    empty = config_from_mapping({"cell": {"dut_mass_kg": 0.0}})
    assert mounted_payload(empty) == (0.0, (0.0, 0.0, 0.0))
    assert mounted_payload(Config(), 0.0) == (0.0, (0.0, 0.0, 0.0))


def test_the_worst_credible_payload_passes_the_push_check_in_the_measurement_pose() -> None:
    """What ``rgse krl check`` assumes without --payload: within the load diagram where it measures (A5 0), by the
    10 % margin; the same mass 12 % farther out is refused there."""
    mass_kg, cog = mounted_payload(Config())
    src = program("  PTP {A5 1}\n  PTP {A5 0}")
    assert found(src, CheckContext(start_axes_deg=MEAS, payload_mass_kg=mass_kg, payload_cog_flange_m=cog)) == []
    far = (0.0, 0.0, (cog[2] + D6_M) * 1.12 - D6_M)
    v = found(src, CheckContext(start_axes_deg=MEAS, payload_mass_kg=mass_kg, payload_cog_flange_m=far))
    assert {(x.line, x.rule) for x in v} == {(FIRST, "A5_TORQUE"), (FIRST + 1, "A5_TORQUE")}


# --- the workspace exactly touched ------------------------------------------------------------------------------------
def _point_cell(floor_z_m: float = -5.0, keep_out: tuple[BoxConfig, ...] = ()) -> CellConfig:
    """A roomy cell whose payload box is a 2 mm cube at the flange: the flange decides."""
    return CellConfig(floor_z_m=floor_z_m, walls=BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=(20.0, 20.0, 20.0)),
                      keep_out=keep_out,
                      payload_box_flange_m=BoxConfig(min_m=(-0.001, -0.001, 0.0), max_m=(0.001, 0.001, 0.002)))


def test_holding_a_pose_exactly_above_the_floor() -> None:
    """A motion to where the robot is has no sampling margin: the lowest tested point exactly on the floor is
    refused (at or below: a touch is a collision), a micrometre above it allowed. At A2 0, A3 90 the flange lies
    0.27 m below the base."""
    low = (0.0, 0.0, 90.0, 0.0, 0.0, 0.0)
    frames = joint_frames(low)
    o6 = frames[5, :3, 3]
    rot = frames[5, :3, :3]
    corners = np.array([(x, y, z) for x in (-0.001, 0.001) for y in (-0.001, 0.001) for z in (0.0, 0.002)])
    lowest = float(min((corners @ rot.T + o6)[:, 2].min(), o6[2], frames[4, 2, 3], frames[2, 2, 3]))
    assert -0.3 < lowest < -0.25
    at = CheckContext(start_axes_deg=low, cell=_point_cell(floor_z_m=lowest))
    v = found(program("  PTP {A3 90}"), at)
    assert [(x.line, x.rule) for x in v] == [(FIRST, "WORKSPACE")]
    assert v[0].message == (f"the payload box reaches z = {lowest * 1000:.0f} mm at A1..A6 = (0.0, 0.0, 90.0, 0.0, "
                            f"0.0, 0.0) deg, at or below the floor at z = {lowest * 1000:.0f} mm (cell.floor_z_m; "
                            "margin 0 mm between path samples)")
    assert found(program("  PTP {A3 90}"),
                 CheckContext(start_axes_deg=low, cell=_point_cell(floor_z_m=lowest - 1e-6))) == []


def test_a_wall_below_the_floor_names_the_cell() -> None:
    """Walls whose bottom is above the floor: the higher of the two counts, and the message says it is the cell's."""
    frames = joint_frames(MEAS)
    low_z = float(frames[5, 2, 3])
    cell = CellConfig(floor_z_m=-5.0, walls=BoxConfig(min_m=(-20.0, -20.0, low_z + 0.001), max_m=(20.0, 20.0, 20.0)),
                      keep_out=(), payload_box_flange_m=BoxConfig(min_m=(-0.001, -0.001, 0.0),
                                                                   max_m=(0.001, 0.001, 0.002)))
    v = found(program("  PTP {A3 90}"), CheckContext(start_axes_deg=MEAS, cell=cell))
    assert [(x.line, x.rule) for x in v] == [(FIRST, "WORKSPACE")]
    assert f"at or below the cell at z = {(low_z + 0.001) * 1000:.0f} mm" in v[0].message


def test_a_keep_out_box_exactly_touched_is_entered_only_inside() -> None:
    """A keep-out box whose face lies exactly at the flange's x: the flange on its face enters it (a touch counts),
    a micrometre off it does not. The payload box lies behind the flange, away from the keep-out box."""
    o6 = joint_frames(MEAS)[5, :3, 3]
    x = float(o6[0])

    def ctx(lo_x: float) -> CheckContext:
        box = BoxConfig(min_m=(lo_x, float(o6[1]) - 0.5, float(o6[2]) - 0.5),
                        max_m=(lo_x + 1.0, float(o6[1]) + 0.5, float(o6[2]) + 0.5))
        cell = _point_cell(keep_out=(box,))
        return CheckContext(start_axes_deg=MEAS, cell=replace_box(cell, (-0.001, -0.001, -0.002),
                                                                  (0.001, 0.001, 0.0)))

    assert found(program("  PTP {A3 90}"), ctx(x + 1e-6)) == []
    v = found(program("  PTP {A3 90}"), ctx(x))
    assert [(y.line, y.rule) for y in v] == [(FIRST, "WORKSPACE")]
    assert v[0].message.startswith("the flange enters keep-out box 1 (")
    assert "(cell.keep_out; margin 0 mm between path samples)" in v[0].message


def replace_box(cell: CellConfig, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> CellConfig:
    return cell.model_copy(update={"payload_box_flange_m": BoxConfig(min_m=lo, max_m=hi)})


def test_the_keep_out_message_names_the_box_in_millimetres() -> None:
    o6 = joint_frames(MEAS)[5, :3, 3]
    box = BoxConfig(min_m=(float(o6[0]) - 0.25, -0.0125, 1.0), max_m=(float(o6[0]) + 0.5, 0.0125, 3.5))
    v = found(program("  PTP {A3 90}"), CheckContext(start_axes_deg=MEAS, cell=_point_cell(keep_out=(box,))))
    assert [x.rule for x in v] == ["WORKSPACE"]
    lo = ", ".join(f"{c * 1000:.0f}" for c in box.min_m)
    hi = ", ".join(f"{c * 1000:.0f}" for c in box.max_m)
    assert f"enters keep-out box 1 (({lo}) .. ({hi}) mm) at A1..A6 = " in v[0].message


def test_a_wall_exactly_touched_is_left() -> None:
    """The flange (and the payload box's face on it) exactly on a wall's plane: refused, a touch counts; a
    micrometre inside: allowed."""
    x = float(joint_frames(MEAS)[5, 0, 3])

    def ctx(wall_x: float) -> CheckContext:
        cell = replace_box(_point_cell(), (-0.001, -0.001, -0.002), (0.001, 0.001, 0.0))
        return CheckContext(start_axes_deg=MEAS, cell=cell.model_copy(update={
            "walls": BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=(wall_x, 20.0, 20.0))}))

    v = found(program("  PTP {A3 90}"), ctx(x))
    assert [(y.line, y.rule) for y in v] == [(FIRST, "WORKSPACE")]
    assert v[0].message == (f"the payload box leaves the cell at (x = {x * 1000:.0f} mm) at A1..A6 = (0.0, -90.0, "
                            "90.0, 0.0, 0.0, 0.0) deg (cell.walls; margin 0 mm between path samples)")
    assert found(program("  PTP {A3 90}"), ctx(x + 1e-6)) == []


def _sampled_path(start: tuple[float, ...], target: tuple[float, ...], cell: CellConfig) -> tuple[float, float]:
    """The lowest tested point over the path's samples and the margin that covers the path between them, from the
    sampling argument of ``_Checker.workspace_violation``: samples at most 0.5 deg (L1) apart, both ends included;
    margin = step/2 · r_max · (1 + 2·step), r_max the largest distance of a tested point from an axis origin."""
    q0, q1 = np.array(start), np.array(target)
    l1 = float(np.abs(q1 - q0).sum())
    n = math.ceil(l1 / 0.5) + 1
    step = math.radians(l1 / (n - 1))
    b = cell.payload_box_flange_m
    corners = np.array([(x, y, z) for x in (b.min_m[0], b.max_m[0]) for y in (b.min_m[1], b.max_m[1])
                        for z in (b.min_m[2], b.max_m[2])])
    lowest, r_max = math.inf, 0.0
    for s in np.linspace(0.0, 1.0, n):
        frames = joint_frames(q0 + s * (q1 - q0))
        pts = np.vstack([corners @ frames[5, :3, :3].T + frames[5, :3, 3], frames[5, :3, 3], frames[4, :3, 3],
                         frames[2, :3, 3]])
        lowest = min(lowest, float(pts[:, 2].min()))
        r_max = max(r_max, max(float(np.linalg.norm(p - o)) for p in pts for o in frames[:, :3, 3]))
    return lowest, step / 2.0 * r_max * (1.0 + 2.0 * step)


def test_the_floor_exactly_touched_with_the_sampling_margin() -> None:
    """A2 0, A3 90 → 92.25 (5 samples 0.5625° apart): the lowest sampled point less the margin exactly on the floor
    is refused, a micrometre above the floor allowed."""
    low = (0.0, 0.0, 90.0, 0.0, 0.0, 0.0)
    target = (0.0, 0.0, 92.25, 0.0, 0.0, 0.0)
    lowest, margin = _sampled_path(low, target, _point_cell())
    assert 0.005 < margin < 0.05 and -0.35 < lowest < -0.2

    def ctx(floor_z_m: float) -> CheckContext:
        return CheckContext(start_axes_deg=low, cell=_point_cell(floor_z_m=floor_z_m))

    v = found(program("  PTP {A3 92.25}"), ctx(lowest - margin))
    assert [(x.line, x.rule) for x in v] == [(FIRST, "WORKSPACE")]
    assert v[0].message.endswith(f"at or below the floor at z = {(lowest - margin) * 1000:.0f} mm (cell.floor_z_m; "
                                 f"margin {margin * 1000:.0f} mm between path samples)")
    assert found(program("  PTP {A3 92.25}"), ctx(lowest - margin - 1e-6)) == []


# --- the watchdog's routine -------------------------------------------------------------------------------------------
def _watchdog(routine_body: str) -> str:
    from tests.safety_static.test_watchdog_rule import ARM

    return (f"DEF prop( )\n{SLOW}\n{ARM}  PTP {{A3 95}}\nEND\n\nDEF WD( )\n  BRAKE\n{routine_body}"
            "  WHILE $TIMER_FLAG[16] OR $TIMER_STOP[16]\n    HALT\n  ENDWHILE\nEND\n")


#: Line of the first statement of the routine body after BRAKE (``_watchdog``).
ROUTINE_FIRST = 22
WD_REQUIRED = CheckContext(start_axes_deg=MEAS, require_watchdog=True)
ONLY_STOP = ("in an interrupt routine: it may only stop the robot (BRAKE, HALT, assignments to RGSE_ globals, "
             "IF/WHILE of those)")


@pytest.mark.parametrize("body", [
    "",
    "  RGSE_WD_TRIP = TRUE\n",
    "  rgse_wd_trip = RGSE_N + 1\n",
    "  IF RGSE_N == 1 THEN\n    RGSE_WD_TRIP = TRUE\n  ELSE\n    HALT\n  ENDIF\n",
    "  WHILE RGSE_N > 0\n    RGSE_N = RGSE_N - 1\n  ENDWHILE\n",
    "  IF RGSE_N == 1 THEN\n    WHILE RGSE_N > 0\n      BRAKE\n    ENDWHILE\n  ENDIF\n",
])
def test_a_watchdog_routine_that_only_stops_is_allowed(body: str) -> None:
    assert check_program(_watchdog(body), None, WD_REQUIRED, "prop.src") == []


@pytest.mark.parametrize(("body", "line", "what"), [
    ("  OTHER = 1\n", ROUTINE_FIRST, "Assign"),  # not a handshake global
    ("  $OV_PRO = 50\n", ROUTINE_FIRST, "Assign"),  # on the allow-list, but a system variable
    ("  RGSE_WD_TRIP = SQRT(4)\n", ROUTINE_FIRST, "Assign"),  # a call
    ("  RGSE_WD.X = 1\n", ROUTINE_FIRST, "Assign"),  # not a plain name
    ("  IF SQRT(RGSE_N) == 1 THEN\n    HALT\n  ENDIF\n", ROUTINE_FIRST, "If"),
    ("  IF RGSE_N == 1 THEN\n    HALT\n  ELSE\n    PTP {A3 100}\n  ENDIF\n", ROUTINE_FIRST + 3, "Motion"),
    ("  IF RGSE_N == 1 THEN\n    WAIT SEC 1\n  ENDIF\n", ROUTINE_FIRST + 1, "WaitSec"),
    ("  WHILE SQRT(RGSE_N) > 1\n    HALT\n  ENDWHILE\n", ROUTINE_FIRST, "While"),
    ("  WHILE RGSE_N > 0\n    PTP {A3 100}\n  ENDWHILE\n", ROUTINE_FIRST + 1, "Motion"),
])
def test_a_watchdog_routine_statement_that_does_more_than_stop_is_named(body: str, line: int, what: str) -> None:
    v = check_program(_watchdog(body), None, WD_REQUIRED, "prop.src")
    watchdog = [x for x in v if x.rule == "WATCHDOG"]
    assert [(x.line, x.column, x.message) for x in watchdog] == [(line, watchdog[0].column, f"{what} {ONLY_STOP}")]
    # the routine is not allowed as the watchdog's, so it is an extra routine too
    assert {x.rule for x in v} == {"WATCHDOG", "STATEMENT"}


# --- what the refusal says --------------------------------------------------------------------------------------------
def test_the_refusal_lists_every_violation_with_its_file() -> None:
    from rgse_daemon.safety.static import ProgramRefused, ensure_allowed

    src = program("  PTP {A1 46}\n  OTHER = 1")
    with pytest.raises(ProgramRefused) as info:
        ensure_allowed(src, None, CTX, "world.src")
    assert str(info.value) == (
        "world.src: refused by the interlock (2 violation(s)):\n"
        "world.src:16:3: A1_ENVELOPE: A1 target 46 deg outside the ±45 deg envelope\n"
        "world.src:17:3: WRITE: write to OTHER: not a variable of this program and not on the allow-list")
    assert info.value.file == "world.src" and [v.rule for v in info.value.violations] == ["A1_ENVELOPE", "WRITE"]
    with pytest.raises(ProgramRefused, match=r"^<program>: refused by the interlock \(1 violation\(s\)\):\n"
                                             r"<program>:16:3: A1_ENVELOPE: "):
        ensure_allowed(program("  PTP {A1 46}"), None, CTX)
    assert ensure_allowed(program("  PTP {A1 45}"), None, CTX, "world.src") is None
    # a program that does not parse is named in the error
    from rgse_daemon.errors import KrlSyntaxError

    with pytest.raises(KrlSyntaxError, match=r"world\.src"):
        ensure_allowed(program("  PTP {A1 45"), None, CTX, "world.src")
    # the data list is checked too
    with pytest.raises(ProgramRefused, match=r"world\.src:2:3: STATEMENT: INTERRUPT is not allowed"):
        ensure_allowed(program(""), "DEFDAT world\n  INTERRUPT ON 3\nENDDAT\n", CTX, "world.src")


def test_a_data_list_syntax_error_names_the_data_list_of_a_long_name() -> None:
    from rgse_daemon.errors import KrlSyntaxError

    with pytest.raises(KrlSyntaxError, match=r"measure_point\.dat"):
        check_program(program(""), "DEFDAT measure_point\n  DECL INT = \nENDDAT\n", CTX, "measure_point.src")


def test_a_motion_from_an_unknown_start_says_why() -> None:
    v = check_program(program("  PTP {A3 95}"), None, CheckContext(), "world.src")
    assert [(x.line, x.column, x.rule) for x in v] == [(FIRST, 3, "START_UNKNOWN")]
    assert v[0].message == ("PTP from an unknown start pose: its path and speed cannot be verified (read the robot's "
                            "axes before the push)")


def test_an_indexed_trace_member_is_named_by_its_variable() -> None:
    v = found(program('  $TRACE.NAME[1][] = "x"'))
    assert [(x.line, x.rule, x.message) for x in v] == [
        (FIRST, "SYSVAR", "write to system variable $TRACE is not allowed")]


# --- the time bound through branches and loops (krl/abstract.py) ------------------------------------------------------
T10_S = 10 / 1.4 + 0.2  # A3 10 deg at 2 % and 20 %: the trapezoid above


@pytest.mark.parametrize(("setting", "bound_s"), [
    ("$VEL_AXIS[3] = 3", T10_S),  # the slowest speed either branch leaves
    ("$ACC_AXIS[3] = 100", T10_S),  # ... and acceleration
    ("$OV_PRO = 50", 10 / 0.7 + 0.4),  # the lowest override either branch leaves
])
def test_after_a_branch_the_time_bound_takes_the_slowest_settings(setting: str, bound_s: float) -> None:
    src = program(f"  IF RGSE_ARG == 1 THEN\n    {setting}\n  ENDIF\n  PTP {{A3 100}}")
    assert found(src, _limits(bound_s)) == []
    assert [x.rule for x in found(src, _limits(math.nextafter(bound_s, 0.0)))] == ["MOTION_TIME"]


def test_after_a_branch_the_time_bound_takes_the_longer_branch() -> None:
    src = program("  IF RGSE_ARG == 1 THEN\n    PTP {A3 100}\n  ELSE\n    PTP {A3 95}\n  ENDIF\n  PTP {A3 90}")
    bound_s = 2 * T10_S
    assert found(src, _limits(bound_s)) == []
    assert [x.rule for x in found(src, _limits(math.nextafter(bound_s, 0.0)))] == ["MOTION_TIME"]


PACED = ("  LOOP\n    WAIT FOR RGSE_CMD <> 0\n    IF RGSE_CMD == 99 THEN\n      EXIT\n    ENDIF\n"
         "    PTP {A3 100}\n    PTP {A3 90}\n    RGSE_CMD = 0\n  ENDLOOP")


@pytest.mark.parametrize(("change", "paced"), [
    (("", ""), True),
    (("    RGSE_CMD = 0\n", "    RGSE_CMD = 0\n    PTP {A3 95}\n"), False),  # ends with a motion, not the reset
    (("    RGSE_CMD = 0\n", "    RGSE_ARR[1] = 0\n"), False),  # the reset is no plain variable
    (("    RGSE_CMD = 0\n", "    RGSE_OTHER = 0\n"), False),  # resets a variable the wait does not read
    (("    RGSE_CMD = 0\n", "    RGSE_CMD = 1 / 0\n"), False),  # the reset's value is a runtime error
    (("    RGSE_CMD = 0\n", "    RGSE_CMD = RGSE_ZERO\n"), False),  # the reset's value is not known
    (("WAIT FOR RGSE_CMD <> 0", "WAIT FOR (RGSE_CMD <> 0) OR RGSE_GO"), False),  # the wait may pass anyway
    (("WAIT FOR RGSE_CMD <> 0", "WAIT FOR RGSE_CMD <> 0.0"), True),  # INT 0 against a REAL 0: still FALSE
    (("    PTP {A3 90}\n", "    PTP {A3 90}\n    WAIT FOR RGSE_DONE\n"), True),  # a second wait after the motions
    (("    WAIT FOR RGSE_CMD <> 0\n", "    WAIT SEC 1\n"), False),  # no WAIT FOR
])
def test_a_loop_is_paced_by_the_host_only_through_its_wait_and_reset(change: tuple[str, str], paced: bool) -> None:
    src = program(PACED.replace(*change) if change[0] else PACED)
    assert src != program(PACED) or change[0] == ""
    v = found(src)
    assert [(x.line, x.rule) for x in v if x.rule != "RUNTIME"] == ([] if paced else [(FIRST, "UNBOUNDED")]), v
    assert {x.rule for x in v} <= {"UNBOUNDED", "RUNTIME"}  # (RUNTIME: the division by zero itself)


def test_a_while_paced_by_the_host_is_bounded_but_a_for_is_counted() -> None:
    body = "    WAIT FOR RGSE_CMD <> 0\n    PTP {A3 100}\n    PTP {A3 90}\n    RGSE_CMD = 0\n"
    assert found(program(f"  WHILE RGSE_RUN\n{body}  ENDWHILE")) == []
    # a FOR with too many passes is judged by their count, paced or not
    many = program(f"  FOR i = 1 TO 2000\n{body}  ENDFOR", "  DECL INT i\n")
    assert [(x.line, x.rule) for x in found(many)] == [(3, "MOTION_TIME"), (FIRST + 1, "MOTION_TIME")]


def test_the_wrist_centre_is_held_to_the_cell() -> None:
    """At A2 -30, A3 60, A5 -120 the wrist centre hangs 0.29 m below the flange (the flange points up): the cell's
    bottom between them refuses the wrist, nothing else."""
    up = (0.0, -30.0, 60.0, 0.0, -120.0, 0.0)
    frames = joint_frames(up)
    wrist_z, flange_z = float(frames[4, 2, 3]), float(frames[5, 2, 3])
    assert flange_z - wrist_z == pytest.approx(D6_M) and float(frames[2, 2, 3]) > flange_z
    bottom = (wrist_z + flange_z) / 2
    cell = _point_cell().model_copy(update={"walls": BoxConfig(min_m=(-20.0, -20.0, bottom),
                                                               max_m=(20.0, 20.0, 20.0))})
    v = found(program("  PTP {A3 60}"), CheckContext(start_axes_deg=up, cell=cell))
    assert [(x.line, x.rule) for x in v] == [(FIRST, "WORKSPACE")]
    assert v[0].message.startswith(f"the wrist centre reaches z = {wrist_z * 1000:.0f} mm at A1..A6 = (0.0, -30.0, "
                                   "60.0, 0.0, -120.0, 0.0) deg, at or below the cell at z = ")


def test_the_workspace_is_the_checked_robots() -> None:
    """The KR 10 held at A2 -90, A3 90: its flange 1.06 m up, under a 1.5 m ceiling; the KR 500's would be 2.29 m
    up, through it."""
    from rgse_daemon import robots

    kr10 = robots.get("kr10r1440")
    assert float(joint_frames(MEAS, robot=kr10)[5, 2, 3]) < 1.2 < 1.5 < float(joint_frames(MEAS)[5, 2, 3])
    cell = _point_cell().model_copy(update={"walls": BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=(20.0, 20.0, 1.5))})
    assert found(program("  PTP {A3 90}"), CheckContext(start_axes_deg=MEAS, cell=cell, robot=kr10)) == []
    assert [x.rule for x in found(program("  PTP {A3 90}"), CheckContext(start_axes_deg=MEAS, cell=cell))] == [
        "WORKSPACE"]


def _held_points(q: tuple[float, ...], cell: CellConfig) -> np.ndarray:
    """The points the workspace rule tests in pose ``q``: the payload box's corners, the flange, the wrist centre and
    the elbow (world frame, m)."""
    frames = joint_frames(q)
    b = cell.payload_box_flange_m
    corners = np.array([(x, y, z) for x in (b.min_m[0], b.max_m[0]) for y in (b.min_m[1], b.max_m[1])
                        for z in (b.min_m[2], b.max_m[2])])
    return np.vstack([corners @ frames[5, :3, :3].T + frames[5, :3, 3], frames[5, :3, 3], frames[4, :3, 3],
                      frames[2, :3, 3]])


@pytest.mark.parametrize("axis", [0, 1])
def test_a_wall_exactly_touched_on_its_low_side(axis: int) -> None:
    """Held at A1 30 (every point off the x and y axes), the wall at the smallest x (or y) of the tested points is
    touched: refused; a micrometre farther out: allowed."""
    q = (30.0, -90.0, 90.0, 0.0, 0.0, 0.0)
    base = _point_cell()
    low = float(_held_points(q, base)[:, axis].min())

    def ctx(wall: float) -> CheckContext:
        lo = [-20.0, -20.0, -5.0]
        lo[axis] = wall
        return CheckContext(start_axes_deg=q, cell=base.model_copy(update={
            "walls": BoxConfig(min_m=tuple(lo), max_m=(20.0, 20.0, 20.0))}))

    v = found(program("  PTP {A1 30}"), ctx(low))
    assert [(x.line, x.rule) for x in v] == [(FIRST, "WORKSPACE")]
    assert f"leaves the cell at ({'xy'[axis]} = {low * 1000:.0f} mm) at A1..A6 = (30.0, " in v[0].message
    assert found(program("  PTP {A1 30}"), ctx(low - 1e-6)) == []


def test_a_for_with_step_zero_is_refused_with_its_reason() -> None:
    v = found(program("  FOR i = 1 TO 5 STEP 0\n    RGSE_LOOP = i\n  ENDFOR", "  DECL INT i\n"))
    assert [(x.line, x.rule, x.message) for x in v] == [(FIRST + 1, "LOOP", "FOR with STEP 0 never ends")]


def test_a_parameter_steers_both_branches_and_an_untracked_declaration_is_evaluated() -> None:
    """The main routine's parameter T is declared (own) but its value is the caller's: both branches of IF T == 1
    are followed, the fast one is refused. A CHAR (not tracked) initialised from an own INT is read for errors."""
    src = ("&ACCESS RVP\n&REL 1\nDEF world(T :IN)\n  DECL INT T\n  DECL INT n = 3\n  DECL CHAR c = n\n" + SLOW
           + "\n  IF T == 1 THEN\n    $VEL_AXIS[3] = 100\n  ENDIF\n  PTP {A3 100}\nEND\n")
    v = found(src)
    assert [(x.line, x.rule) for x in v] == [(22, "SPEED")]
    assert found(src.replace("DECL CHAR c = n", "DECL CHAR c = 1 / 0")) == [
        Violation(6, 19, "RUNTIME", "the controller stops here: division by zero"), *v]


@pytest.mark.parametrize(("body", "what"), [("I = TRUE", "BOOL TRUE to an INT"), ("B = 1", "INT 1 to a BOOL"),
                                            ("I = #X", "ENUM #X to an INT")])
def test_a_type_mismatch_is_a_runtime_error_at_its_statement(body: str, what: str) -> None:
    """The conversion's error has no place of its own: the statement's is reported."""
    v = found(program(f"  {body}", "  DECL INT I\n  DECL BOOL B\n"))
    assert [(x.line, x.column, x.rule, x.message) for x in v] == [
        (FIRST + 2, 3, "RUNTIME", f"the controller stops here: cannot assign {what}")]


@pytest.mark.parametrize("write", ["X.A1 = 5\n  PTP X", "XS[1] = {A1 5}\n  PTP XS[1]"])
def test_a_partial_write_keeps_the_other_fields_of_a_target(write: str) -> None:
    """A member write or a partial aggregate into an array element changes only that field: A3 150 (beyond the
    KR 500's 144) stays in the target and is refused."""
    decls = "  DECL E6AXIS X\n  DECL E6AXIS XS[2]\n"
    first = "{A1 0, A2 -90, A3 150, A4 0, A5 0, A6 0, E1 0, E2 0, E3 0, E4 0, E5 0, E6 0}"
    src = program(f"  X = {first}\n  XS[1] = {first}\n  {write}", decls)
    v = found(src)
    assert [(x.line, x.rule) for x in v] == [(FIRST + 5, "JOINT_LIMIT")]
    assert v[0].message == "A3 target 150 deg outside the axis range -100..144 deg"


# --- the last survivors of the seed-31 sample (session 17) ------------------------------------------------------------
def test_a_vel_axis_of_an_unknown_index_counts_as_100_percent_on_every_axis() -> None:
    """``$VEL_AXIS[7] = 2`` is refused (no such axis) and, as any axis may have been meant, every axis counts at 100 %
    from there: A6 turned by 10 deg at 100 % moves a payload point 0.1 m off the flange axis at 246.7 mm/s, at 101 %
    at 249.1 mm/s. With the T1 speed between the two, the A6 motion after the write is allowed at 100 % (101 %
    would refuse it)."""
    from rgse_daemon.kinematics import max_point_speed_mm_s

    target = pose(A6=10.0)
    point = (0.1, 0.0, 0.0)

    def bound_mm_s(pct: float) -> float:
        return max_point_speed_mm_s(MEAS, target, tuple(pct / 100.0 * s for s in SPEEDS), [point, (0.0, 0.0, 0.0)],
                                    robot=CTX.robot).bound_mm_s

    at_100, at_101 = bound_mm_s(100.0), bound_mm_s(101.0)
    assert 246.0 < at_100 < 247.0 < 249.0 < at_101 < 249.5
    limit_mm_s = (at_100 + at_101) / 2.0
    ctx = CheckContext(start_axes_deg=MEAS, payload_points_flange_m=(point,),
                       limits=LimitsConfig(t1_speed_mm_s=limit_mm_s))
    v = found(program("  $VEL_AXIS[7] = 2\n  PTP {A6 10}"), ctx)
    assert [(x.line, x.column, x.rule) for x in v] == [(FIRST, 3, "VELOCITY")]
    assert v[0].message == "$VEL_AXIS must be set per axis with a constant index 1..6"
    # the same limit refuses the motion at 100 % a hair faster (the T1 speed just below the 100 % bound)
    slower = CheckContext(start_axes_deg=MEAS, payload_points_flange_m=(point,),
                          limits=LimitsConfig(t1_speed_mm_s=at_100 - 0.5))
    assert [x.rule for x in found(program("  $VEL_AXIS[7] = 2\n  PTP {A6 10}"), slower)] == ["VELOCITY", "SPEED"]


def test_a_payload_under_1_kg_has_its_a5_torque() -> None:
    """0.5 kg with its CoG 0.5 m out on the flange axis, held with the flange axis level (A5 = 0): its A5 torque is
    m·g·(d6 + 0.5 m) = 0.5 · 9.81 · 0.79 = 3.87 Nm, above a 3 Nm limit."""
    ctx = CheckContext(start_axes_deg=MEAS, payload_mass_kg=0.5, payload_cog_flange_m=(0.0, 0.0, 0.5),
                       limits=LimitsConfig(max_a5_torque_nm=3.0))
    torque_nm = 0.5 * G_PAPER_M_S2 * (D6_M + 0.5)
    assert f"{torque_nm:.2f}" == "3.87"
    v = found(program("  PTP {A1 0}"), ctx)
    assert [(x.line, x.column, x.rule, x.message) for x in v] == [
        (FIRST, 3, "A5_TORQUE", f"static A5 torque of the payload reaches {torque_nm:.1f} Nm on this motion, above "
                                "the load diagram's 3 Nm")]
    assert found(program("  PTP {A1 0}"), CheckContext(start_axes_deg=MEAS, payload_mass_kg=0.5,
                                                       payload_cog_flange_m=(0.0, 0.0, 0.5),
                                                       limits=LimitsConfig(max_a5_torque_nm=3.9))) == []


def test_the_a5_torque_is_the_checked_robots() -> None:
    """2 kg 0.1 m out on the flange axis of a KR 10 (d6 0.1 m), held at A5 = 60 deg: the CoG is 0.2 m from the wrist
    centre (the bound, 3.92 Nm, is above a 3 Nm limit, so the pose is worked out) and its A5 torque is
    m·g·0.2 m·cos 60° = 1.96 Nm, allowed. The KR 500's longer d6 (0.29 m) would give 3.83 Nm at the same axes."""
    from rgse_daemon import robots
    from rgse_daemon.kinematics import gravity_torques_nm

    kr10 = robots.get("kr10r1440")
    held = pose(A5=60.0)
    body = [(2.0, (0.0, 0.0, 0.1))]
    assert abs(float(gravity_torques_nm(held, body, robot=kr10)[4])) == pytest.approx(2.0 * G_PAPER_M_S2 * 0.1)
    assert abs(float(gravity_torques_nm(held, body, robot=robots.get("kr500r2830"))[4])) == pytest.approx(
        2.0 * G_PAPER_M_S2 * 0.39 / 2.0)
    assert 2.0 * G_PAPER_M_S2 * 0.2 > 3.0
    ctx = CheckContext(start_axes_deg=held, payload_mass_kg=2.0, payload_cog_flange_m=(0.0, 0.0, 0.1),
                       limits=LimitsConfig(max_a5_torque_nm=3.0), robot=kr10)
    assert found(program("  PTP {A5 60}"), ctx) == []
    v = found(program("  PTP {A5 60}"), CheckContext(start_axes_deg=held, payload_mass_kg=2.0,
                                                     payload_cog_flange_m=(0.0, 0.0, 0.1),
                                                     limits=LimitsConfig(max_a5_torque_nm=1.9), robot=kr10))
    assert [(x.rule, x.message) for x in v] == [
        ("A5_TORQUE", "static A5 torque of the payload reaches 2.0 Nm on this motion, above the load diagram's 1.9 Nm")]
