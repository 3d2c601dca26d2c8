"""The static check at its exact limits, each boundary from both sides (issue #31 item 6: survivors of mutmut).

Every limit of ``safety/static.py`` is inclusive as documented in its rule table ("≤ t1_speed_mm_s", "within the axis
ranges", "|A1| ≤ a1_range_deg", "payload ≤ max_payload_kg", "torque ≤ max_a5_torque_nm", "$OV_PRO 1..100",
"$VEL_AXIS [0.01, 100] %", "$VEL.CP (0, 2] m/s"): a value exactly at the limit is allowed, the next representable
step beyond is refused. The programs named in the issue (``$VEL_AXIS[1, 2] = 2``, ``B = 1 AND TRUE``,
``B = TRUE == 1``) are refused as ``docs/krl-semantics.md`` says the controller treats them.
"""

from __future__ import annotations

import math
import re
import struct

import pytest

from rgse_daemon.config import BoxConfig, CellConfig, LimitsConfig
from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.kinematics import JOINT_LIMITS_DEG, MAX_AXIS_SPEED_DEG_S, max_point_speed_mm_s
from rgse_daemon.krl import ast as k
from rgse_daemon.krl.abstract import State, TooComplex
from rgse_daemon.safety.static import MAX_MOTION_CHECKS, CheckContext, Violation, _Checker, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
CTX = CheckContext(start_axes_deg=MEAS)
#: a cell with nothing in the way (no floor or frame under the base, walls and ceiling far off): for the axis-range
#: boundaries, which the default cell's WORKSPACE rule would hide (A2 20 with A3 90 takes the payload box below the
#: floor)
ROOMY_CELL = CellConfig(floor_z_m=-5.0, walls=BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=(20.0, 20.0, 20.0)),
                        keep_out=())
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))


def program(body: str, decls: str = "", slow: str = SLOW) -> str:
    return f"&ACCESS RVP\n&REL 1\nDEF prop( )\n{decls}{slow}\n{body}\nEND\n"


def found(src: str, ctx: CheckContext = CTX) -> list[Violation]:
    return check_program(src, None, ctx, "prop.src")


def rules(src: str, ctx: CheckContext = CTX) -> set[str]:
    return {v.rule for v in found(src, ctx)}


# --- the three programs of the issue ----------------------------------------------------------------------------------
def test_a_two_index_vel_axis_is_refused_and_speeds_stay_worst_case() -> None:
    # $VEL_AXIS is a one-dimensional array: [1, 2] is no axis; had it set A1 to 2 % the motion would pass as slow
    fast = "\n".join(f"  $VEL_AXIS[{i}] = 100" for i in range(1, 7))
    src = program("  $VEL_AXIS[1, 2] = 2\n  PTP {A1 5}", slow=fast)
    assert rules(src) == {"VELOCITY", "SPEED"}
    v = next(v for v in found(src) if v.rule == "VELOCITY")
    assert (v.line, v.column) == (10, 3) and "constant index 1..6" in v.message
    # the same setting with a single index is a real per-axis speed and slows A1
    assert rules(program("  $VEL_AXIS[1] = 2\n  PTP {A1 5}", slow=fast)) == set()


@pytest.mark.parametrize("expr", ["1 AND TRUE", "TRUE AND 1", "1 OR FALSE", "FALSE EXOR 0", "NOT 1", "1.0 AND TRUE"])
def test_logic_on_numbers_is_a_runtime_error(expr: str) -> None:
    src = program(f"  B = {expr}", "  DECL BOOL B\n")
    assert [(v.rule, v.line) for v in found(src)] == [("RUNTIME", 17)]


@pytest.mark.parametrize("expr", ["TRUE == 1", "1 == TRUE", "TRUE <> 0", "#A == 1", "TRUE == #A", "1.0 == FALSE"])
def test_comparing_a_bool_or_enum_with_a_number_is_a_runtime_error(expr: str) -> None:
    src = program(f"  B = {expr}", "  DECL BOOL B\n")
    assert [(v.rule, v.line) for v in found(src)] == [("RUNTIME", 17)]


@pytest.mark.parametrize("expr", ["TRUE == TRUE", "TRUE <> FALSE", "#A == #A", "#A <> #B", "1 == 1.0", "2 <> 1"])
def test_comparisons_of_one_kind_are_allowed(expr: str) -> None:
    assert found(program(f"  B = {expr}", "  DECL BOOL B\n")) == []


def test_a_condition_from_a_wrong_comparison_does_not_steer_the_check() -> None:
    # if TRUE == 1 were read as FALSE, the fast branch would be skipped and the program allowed
    src = program("  IF TRUE == 1 THEN\n    PTP {A1 5}\n  ELSE\n    $VEL_AXIS[1] = 100\n    PTP {A1 40}\n  ENDIF")
    assert "RUNTIME" in rules(src) and "SPEED" in rules(src)


# --- axis ranges, the A1 envelope, relative moves ---------------------------------------------------------------------
AXIS_CASES = [(2, 20.0), (2, -130.0), (3, 144.0), (3, -100.0), (4, 350.0), (4, -350.0), (5, 120.0), (5, -120.0),
              (6, 350.0), (6, -350.0)]


@pytest.mark.parametrize(("axis", "limit"), AXIS_CASES)
def test_a_start_exactly_at_an_axis_limit_is_allowed_beyond_it_refused(axis: int, limit: float) -> None:
    # checked on the start pose (no motion: the speed at 2 % never matters); the limits are the robot's own
    assert tuple(JOINT_LIMITS_DEG[axis - 1]) in {(-130.0, 20.0), (-100.0, 144.0), (-350.0, 350.0), (-120.0, 120.0)}
    at = list(MEAS)
    at[axis - 1] = limit
    assert rules(program(""), CheckContext(start_axes_deg=tuple(at))) == set()
    beyond = list(at)
    beyond[axis - 1] = math.nextafter(limit, math.copysign(math.inf, limit))
    found_beyond = found(program(""), CheckContext(start_axes_deg=tuple(beyond)))
    assert [v.rule for v in found_beyond] == ["JOINT_LIMIT"]
    assert found_beyond[0].message.startswith(f"start pose: A{axis} target")


@pytest.mark.parametrize(("axis", "limit"), AXIS_CASES)
def test_a_target_exactly_at_an_axis_limit_is_allowed_beyond_it_refused(axis: int, limit: float) -> None:
    start = list(MEAS)
    start[axis - 1] = limit - math.copysign(1.0, limit)
    ctx = CheckContext(start_axes_deg=tuple(start), cell=ROOMY_CELL)
    assert rules(program(f"  PTP {{A{axis} {limit:g}}}"), ctx) == set()
    beyond = f"{limit + math.copysign(0.001, limit):.3f}"
    assert rules(program(f"  PTP {{A{axis} {beyond}}}"), ctx) == {"JOINT_LIMIT"}


def test_a1_envelope_is_inclusive_on_both_sides() -> None:
    for a1 in (45.0, -45.0):
        assert rules(program(f"  PTP {{A1 {a1:g}}}")) == set()
        assert rules(program(f"  PTP {{A1 {a1 * 1.0001:g}}}")) == {"A1_ENVELOPE"}
    narrow = CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(a1_range_deg=10.0))
    assert rules(program("  PTP {A1 -10}"), narrow) == set()
    assert rules(program("  PTP {A1 -10.001}"), narrow) == {"A1_ENVELOPE"}
    # the start pose is held to the envelope too, its message says so
    v = found(program(""), CheckContext(start_axes_deg=(45.001, -90.0, 90.0, 0.0, 0.0, 0.0)))
    assert [x.rule for x in v] == ["A1_ENVELOPE"] and v[0].message.startswith("start pose: A1 target 45.001")
    assert found(program(""), CheckContext(start_axes_deg=(-45.0, -90.0, 90.0, 0.0, 0.0, 0.0))) == []


def test_a1_beyond_the_envelope_but_within_its_axis_range_still_refused() -> None:
    # A1's axis range is ±185; only the envelope refuses 46, and nothing else may be reported
    v = found(program("  PTP {A1 46}"))
    assert [(x.rule, x.line) for x in v] == [("A1_ENVELOPE", 16)]
    assert "46 deg outside the ±45 deg envelope" in v[0].message


def test_relative_amplitude_is_inclusive() -> None:
    assert rules(program("  PTP_REL {A3 -45, A5 45, A6 -45}")) == set()
    v = found(program("  PTP_REL {A3 -45.001, A5 45, A6 45.001}"))
    assert [x.rule for x in v] == ["REL_AMPLITUDE"]
    assert "of A3, A6 by more than 45 deg" in v[0].message
    small = CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(brake_release_max_deg=5.0))
    assert rules(program("  PTP_REL {A5 -5}"), small) == set()
    assert rules(program("  PTP_REL {A5 -5.001}"), small) == {"REL_AMPLITUDE"}


# --- payload and the load diagram -------------------------------------------------------------------------------------
def test_payload_mass_is_inclusive_at_zero_and_at_the_limit() -> None:
    for kg in (0.0, 611.0):
        assert rules(program(""), CheckContext(start_axes_deg=MEAS, payload_mass_kg=kg)) == set()
    for kg in (-0.001, math.nextafter(611.0, math.inf)):
        v = found(program(""), CheckContext(start_axes_deg=MEAS, payload_mass_kg=kg))
        assert [(x.rule, x.line) for x in v] == [("PAYLOAD", 3)]
        assert "outside 0..611 kg" in v[0].message
    low = LimitsConfig(max_payload_kg=50.0)
    assert rules(program(""), CheckContext(start_axes_deg=MEAS, payload_mass_kg=50.0, limits=low)) == set()
    assert rules(program(""), CheckContext(start_axes_deg=MEAS, payload_mass_kg=50.01, limits=low)) == {"PAYLOAD"}


def lever_torque_nm(mass_kg: float, cog: tuple[float, float, float]) -> float:
    """The largest static A5 torque in any pose: m·g·|CoG from the wrist centre| (d6 = 0.290 m along flange z)."""
    return mass_kg * 9.81 * math.sqrt(cog[0] ** 2 + cog[1] ** 2 + (cog[2] + 0.290) ** 2)


def test_a5_torque_exactly_at_the_limit_is_allowed() -> None:
    cog = (0.0, 0.0, 0.21)
    torque = lever_torque_nm(100.0, cog)
    assert torque == pytest.approx(490.5, abs=1e-9)
    at = CheckContext(start_axes_deg=MEAS, payload_mass_kg=100.0, payload_cog_flange_m=cog,
                      limits=LimitsConfig(max_a5_torque_nm=torque))
    assert rules(program("  PTP {A5 30}"), at) == set()
    # just below the lever bound: the path is sampled; with the CoG on flange z the torque is m·g·lever·|sin(angle)|,
    # which reaches the full lever only where the flange axis is horizontal, as at the start pose (A5 0)
    below = CheckContext(start_axes_deg=MEAS, payload_mass_kg=100.0, payload_cog_flange_m=cog,
                         limits=LimitsConfig(max_a5_torque_nm=torque - 0.01))
    v = found(program("  PTP {A5 30}"), below)
    assert [x.rule for x in v] == ["A5_TORQUE"] and "above the load diagram's 490.49 Nm" in v[0].message


def test_a5_torque_along_the_path_with_the_flange_pointing_down() -> None:
    # Start A5 = 90 (flange z straight down at MEAS: A2 -90, A3 90), CoG 0.21 m out on z: the lever hangs under the
    # A5 axis and the static torque is m·g·0.5·sin(A5 - 90°). A motion to A5 = 60 passes torques up to 0.5 of the
    # lever bound: a limit at 0.55 of it allows the motion, at 0.45 refuses it, and the hold at A5 90 needs nothing.
    cog = (0.0, 0.0, 0.21)
    full = lever_torque_nm(300.0, cog)
    start = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)

    def ctx(fraction: float) -> CheckContext:
        return CheckContext(start_axes_deg=start, payload_mass_kg=300.0, payload_cog_flange_m=cog,
                            limits=LimitsConfig(max_a5_torque_nm=full * fraction))

    assert rules(program("  PTP {A5 90}"), ctx(0.05)) == set()
    assert rules(program("  PTP {A5 60}"), ctx(0.55)) == set()
    assert rules(program("  PTP {A5 60}"), ctx(0.45)) == {"A5_TORQUE"}
    assert rules(program("  PTP {A5 120}"), ctx(0.55)) == set()
    assert rules(program("  PTP {A5 120}"), ctx(0.45)) == {"A5_TORQUE"}


def test_no_payload_no_torque() -> None:
    tiny = CheckContext(start_axes_deg=MEAS, payload_mass_kg=0.0, payload_cog_flange_m=(0.0, 0.0, 5.0),
                        limits=LimitsConfig(max_a5_torque_nm=0.001))
    assert rules(program("  PTP {A5 30}"), tiny) == set()


# --- speed ------------------------------------------------------------------------------------------------------------
def test_a_speed_exactly_at_the_t1_limit_is_allowed() -> None:
    start, target = MEAS, (0.0, -90.0, 110.0, 0.0, 0.0, 0.0)
    vmax = tuple(round(p / 100.0 * m, 9) for p, m in zip((2.0, 2.0, 12.0, 2.0, 2.0, 2.0), MAX_AXIS_SPEED_DEG_S,
                                                            strict=True))
    speed = max_point_speed_mm_s(start, target, vmax, [(0.0, 0.0, 0.0)]).bound_mm_s
    src = program("  $VEL_AXIS[3] = 12\n  PTP {A3 110}")
    assert 150.0 < speed < 250.0
    assert rules(src, CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(t1_speed_mm_s=speed))) == set()
    below = CheckContext(start_axes_deg=MEAS, limits=LimitsConfig(t1_speed_mm_s=math.nextafter(speed, 0.0)))
    v = found(src, below)
    assert [x.rule for x in v] == ["SPEED"]
    assert f"worst-case point speed {speed:.0f} mm/s" in v[0].message and "$VEL_AXIS 2/2/12/2/2/2 %" in v[0].message
    assert "override 100 %" in v[0].message


def test_the_override_scales_the_axis_speeds() -> None:
    # at 40 % of A3's speed the path is too fast; a locked override of 5 % brings it to 2 %, which is slow enough
    src = program("  $VEL_AXIS[3] = 40\n  PTP {A3 110}")
    assert rules(src) == {"SPEED"}
    assert rules(src, CheckContext(start_axes_deg=MEAS, override_max_pct=5.0)) == set()
    # the program's own higher override wins over a locked lower one
    assert rules(program("  $OV_PRO = 100\n  $VEL_AXIS[3] = 40\n  PTP {A3 110}"),
                 CheckContext(start_axes_deg=MEAS, override_max_pct=5.0)) == {"SPEED"}


def test_a_motion_to_where_the_robot_is_has_no_speed() -> None:
    fast = "\n".join(f"  $VEL_AXIS[{i}] = 100" for i in range(1, 7))
    assert rules(program("  PTP {A3 90}", slow=fast)) == set()
    assert rules(program("  PTP {A3 91}", slow=fast)) == {"SPEED"}


# --- motion settings --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("setting", "ok"), [
    ("$VEL_AXIS[1] = 100", True), ("$VEL_AXIS[6] = 100.0", True), ("$VEL_AXIS[1] = 100.001", False),
    ("$VEL_AXIS[2] = 0.01", True), ("$VEL_AXIS[2] = 0.0099", False), ("$VEL_AXIS[7] = 2", False),
    ("$VEL_AXIS[0] = 2", False), ("$VEL_AXIS[-1] = 2", False), ("$VEL_AXIS[I] = 2", False),
    ("$VEL_AXIS[1] = TRUE", False), ("$ACC_AXIS[6] = 100", True), ("$ACC_AXIS[1] = 100.001", False),
    ("$ACC_AXIS[3] = 0.01", True), ("$ACC_AXIS[3] = 0.0099", False), ("$ACC_AXIS[7] = 20", False),
    ("$ACC_AXIS = 20", False), ("$VEL_AXIS = 2", False),
    ("$VEL.CP = 2", True), ("$VEL.CP = 2.001", False), ("$VEL.CP = 0.001", True), ("$VEL.CP = 0", False),
    ("$VEL.CP = -1", False), ("$VEL.CP = $VEL.CP", False), ("$VEL.ORI1 = 1", False), ("$VEL = 1", False),
    ("$OV_PRO = 100", True), ("$OV_PRO = 100.4", True), ("$OV_PRO = 100.6", False), ("$OV_PRO = 101", False),
    ("$OV_PRO = -1", False), ("$OV_PRO = 50", True), ("$OV_PRO = RGSE_OV", False), ("$OV_PRO[1] = 5", False),
    ("$OV_PRO = TRUE", False), ("$APO.CDIS = 5", True), ("$APO = {CDIS 5}", True), ("$APO[1] = 5", False),
])
def test_motion_settings_at_their_limits(setting: str, ok: bool) -> None:
    src = program(f"  {setting}", "  DECL INT I\n")
    got = found(src)
    assert (got == []) is ok, got
    if not ok:
        assert {v.rule for v in got} <= {"VELOCITY", "OV_PRO", "SYSVAR", "UNSURE", "RUNTIME"}
        assert all(v.line == 17 for v in got)


def test_a_refused_vel_axis_counts_as_full_speed() -> None:
    # a refused per-axis speed must not be taken as the slow value written: the next motion is checked at 100 %
    for bad in ("$VEL_AXIS[3] = 0.001", "$VEL_AXIS[3] = 101", "$VEL_AXIS[9] = 2", "$VEL_AXIS[3] = RGSE_V"):
        assert rules(program(f"  {bad}\n  PTP {{A3 100}}")) >= {"VELOCITY", "SPEED"}, bad
    # a good per-axis speed changes only its own axis
    fast_a1 = program("  $VEL_AXIS[1] = 100\n  PTP {A3 100}")
    assert rules(fast_a1) == set()


def test_a_refused_override_counts_as_full_override() -> None:
    locked = CheckContext(start_axes_deg=MEAS, override_max_pct=5.0)
    src = "  $VEL_AXIS[3] = 40\n  $OV_PRO = {}\n  PTP {{A3 110}}"
    assert rules(program(src.format(5)), locked) == set()
    assert rules(program(src.format(101)), locked) == {"OV_PRO", "SPEED"}
    assert rules(program(src.format("RGSE_OV")), locked) == {"OV_PRO", "SPEED"}
    assert rules(program(src.format("5\n  $OV_PRO[1] = 5")), locked) >= {"SYSVAR", "SPEED"}


# --- mode -------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("mode", "cleared", "key", "ok"), [
    ("T1", False, False, True), (" t1 ", False, False, True), ("#T1", False, False, True),
    ("AUT", True, True, True), ("#aut", True, True, True), ("AUT", True, False, False), ("AUT", False, True, False),
    ("AUT", False, False, False), ("T2", True, True, False), ("EX", True, True, False), ("T11", False, False, False),
])
def test_mode(mode: str, cleared: bool, key: bool, ok: bool) -> None:
    got = found(program(""), CheckContext(start_axes_deg=MEAS, mode=mode, area_cleared=cleared, key_confirmed=key))
    assert (got == []) is ok
    if not ok:
        assert [(v.line, v.column, v.rule) for v in got] == [(0, 0, "MODE")]


def test_aut_names_what_is_missing() -> None:
    (v,) = found(program(""), CheckContext(start_axes_deg=MEAS, mode="AUT"))
    assert v.message == "mode AUT refused: the hazard area is not cleared and the key switch is not confirmed"
    (v,) = found(program(""), CheckContext(start_axes_deg=MEAS, mode="AUT", area_cleared=True))
    assert v.message == "mode AUT refused: the key switch is not confirmed"
    (v,) = found(program(""), CheckContext(start_axes_deg=MEAS, mode="T2"))
    assert v.message == "mode 'T2' refused: only T1 (or AUT with cleared area and key switch)"


# --- source text ---------------------------------------------------------------------------------------------------
def test_line_length_limit_is_inclusive() -> None:
    pad = "  ; " + "x" * 246  # 250 characters
    assert len(pad) == 250
    assert found(program(pad)) == []
    assert found(program(pad).replace("\n", "\r\n")) == []  # CR LF: the CR is not counted
    v = found(program(pad + "x"))
    assert [(x.line, x.column, x.rule) for x in v] == [(16, 251, "LINE_END")]
    assert "line of 251 characters (limit 250)" in v[0].message
    # the data list is held to it too
    dat = f"DEFDAT prop\n{pad}x\nENDDAT\n"
    assert [(x.line, x.rule) for x in check_program(program(""), dat, CTX, "prop.src")] == [(2, "LINE_END")]
    assert check_program(program(""), f"DEFDAT prop\n{pad}\nENDDAT\n", CTX, "prop.src") == []


@pytest.mark.parametrize(("char", "ok"), [
    ("\t", True), (" ", True), ("~", True), ("\xa0", True), ("\xff", True), ("\x1f", False), ("\x00", False),
    ("\x7f", False), ("\x80", False), ("\x85", False), ("\x9f", False), ("\x0b", False), ("\x0c", False),
    ("\r", False), ("\u2028", False), ("\u2029", False),
])
def test_characters_in_a_comment(char: str, ok: bool) -> None:
    v = found(program(f"  ; a{char}b{char}"))
    if ok:
        assert v == []
    else:
        assert [(x.line, x.column, x.rule) for x in v] == [(16, 6, "LINE_END")]  # the first one only
        assert ("a CR without LF" if char == "\r" else repr(char)) in v[0].message


def test_line_ends_stop_the_check_before_anything_else() -> None:
    # a broken line end refuses the program before it is parsed (even if it would not parse); the mode is still told
    src = program("  PTP {A1 90}\r  DEF(")
    v = check_program(src, None, CheckContext(start_axes_deg=MEAS, mode="T2"))
    assert [x.rule for x in v] == ["MODE", "LINE_END"]


def test_forbidden_keywords_in_the_data_list_and_with_a_syntax_error() -> None:
    dat = "DEFDAT prop\n  DECL INT GOTO_X = 1\nENDDAT\n"
    assert check_program(program(""), dat, CTX, "prop.src") == []  # a name that contains a keyword is no keyword
    v = check_program(program("  GOTO lbl"), None, CTX, "prop.src")
    assert [(x.line, x.column, x.rule) for x in v] == [(16, 3, "STATEMENT")]
    assert v[0].message == "GOTO is not allowed in RGSE programs"
    v = check_program(program(""), "DEFDAT prop\n  INTERRUPT ON 3\nENDDAT\n", CTX, "prop.src")
    assert [(x.line, x.rule) for x in v] == [(2, "STATEMENT")]


def test_a_data_list_syntax_error_names_the_data_list() -> None:
    for file, dat_name in (("prop.src", "prop.dat"), ("PROP.SRC", "PROP.dat"), ("prop", "prop.dat")):
        with pytest.raises(KrlSyntaxError, match=re.escape(dat_name)):
            check_program(program(""), "DEFDAT prop\n  DECL INT = \nENDDAT\n", CTX, file)


# --- the program's parts ---------------------------------------------------------------------------------------------
def test_extra_routines_are_refused_with_their_place() -> None:
    src = program("") + "DEF helper( )\n  PTP {A1 90}\nEND\n"
    v = found(src)
    assert [(x.line, x.column, x.rule) for x in v] == [(18, 1, "STATEMENT")]
    assert v[0].message == "routine HELPER: only a module's main routine is verified"


def test_the_payload_violation_sits_at_the_main_routine() -> None:
    v = found(program(""), CheckContext(start_axes_deg=MEAS, payload_mass_kg=700.0))
    assert [(x.line, x.column, x.rule) for x in v] == [(3, 1, "PAYLOAD")]
    assert v[0].message == "payload 700 kg outside 0..611 kg (load diagram of the KR 500 R2830, paper Fig. 16)"


def test_data_list_values() -> None:
    dat = "DEFDAT prop\n  DECL E6AXIS xa = {A3 100}\n  DECL INT n = 144\n  DECL GLOBAL INT g = 100\nENDDAT\n"
    assert check_program(program("  PTP xa\n  PTP {A3 n}"), dat, CTX, "prop.src") == []
    assert {v.rule for v in check_program(program("  n = 145\n  PTP {A3 n}"), dat, CTX, "prop.src")} == {
        "JOINT_LIMIT"}
    # written by the program: the next run starts with what this one left, not the pushed value
    assert {v.rule for v in check_program(program("  PTP {A3 n}\n  n = 100"), dat, CTX, "prop.src")} == {"TARGET"}
    assert {v.rule for v in check_program(program("  PTP {A3 g}"), dat, CTX, "prop.src")} == {"TARGET"}
    link = "DEFDAT prop\n  DECL INT RGSE_N = 100\nENDDAT\n"  # the daemon may write it: never a constant
    assert {v.rule for v in check_program(program("  PTP {A3 RGSE_N}"), link, CTX, "prop.src")} == {"TARGET"}
    bad_init = "DEFDAT prop\n  DECL GLOBAL INT g = f(1)\nENDDAT\n"
    assert {v.rule for v in check_program(program(""), bad_init, CTX, "prop.src")} == {"CALL"}
    bad_link = "DEFDAT prop\n  DECL INT RGSE_X = f(1)\nENDDAT\n"
    assert {v.rule for v in check_program(program(""), bad_link, CTX, "prop.src")} == {"CALL"}
    ok_link = "DEFDAT prop\n  DECL INT RGSE_X\nENDDAT\n"
    assert check_program(program(""), ok_link, CTX, "prop.src") == []


def test_parameters_of_the_main_routine_are_own_but_unknown() -> None:
    # (A3 100: a pose the default cell allows; A3 5 would lift the payload box into the ceiling, WORKSPACE)
    src = f"&ACCESS RVP\n&REL 1\nDEF prop(T :IN)\n  DECL INT T\n{SLOW}\n  T = 100\n  PTP {{A3 T}}\nEND\n"
    assert found(src) == []  # its own variable: written without WRITE, and known after the write
    unknown = src.replace("  T = 100\n", "")
    assert {v.rule for v in found(unknown)} == {"TARGET"}  # the caller's value is not known


# --- caches and points ---------------------------------------------------------------------------------------------
def test_the_same_path_at_another_speed_is_checked_again() -> None:
    again = "  PTP {A3 100}\n  PTP {A3 90}\n  $VEL_AXIS[3] = 60\n  PTP {A3 100}"
    v = found(program(again))
    assert [(x.line, x.rule) for x in v] == [(19, "SPEED")]


def test_the_same_path_with_another_payload_pose_is_checked_for_torque() -> None:
    cog = (0.0, 0.0, 0.21)
    full = lever_torque_nm(300.0, cog)
    ctx = CheckContext(start_axes_deg=(0.0, -90.0, 90.0, 0.0, 90.0, 0.0), payload_mass_kg=300.0,
                       payload_cog_flange_m=cog, limits=LimitsConfig(max_a5_torque_nm=full * 0.55))
    # there and back: A5 90 → 60 passes 0.5 of the lever bound; 90 → 0 all of it (the second motion's path)
    v = found(program("  PTP {A5 60}\n  PTP {A5 90}\n  PTP {A5 0}"), ctx)
    assert [(x.line, x.rule) for x in v] == [(18, "A5_TORQUE")]


def test_the_cog_is_a_speed_point() -> None:
    body = program("  PTP {A3 110, A5 20}")
    assert rules(body) == set()
    far_cog = CheckContext(start_axes_deg=MEAS, payload_mass_kg=1.0, payload_cog_flange_m=(2.5, 2.5, 2.5))
    assert rules(body, far_cog) == {"SPEED"}


# --- the start pose ------------------------------------------------------------------------------------------------
def test_a_start_pose_outside_the_axis_ranges_leaves_every_path_unverified() -> None:
    ctx = CheckContext(start_axes_deg=(0.0, -90.0, 145.0, 0.0, 0.0, 0.0))
    v = found(program("  PTP {A3 100}"), ctx)
    assert [(x.line, x.rule) for x in v] == [(0, "JOINT_LIMIT"), (16, "START_UNKNOWN")]


@pytest.mark.parametrize("start", [(0.0,) * 5, (0.0,) * 7, (0.0, -90.0, math.nan, 0.0, 0.0, 0.0),
                                   (0.0, -90.0, 90.0, math.inf, 0.0, 0.0)])
def test_a_start_pose_that_is_not_six_finite_angles(start: tuple[float, ...]) -> None:
    v = found(program("  PTP {A3 100}"), CheckContext(start_axes_deg=start))
    assert [(x.line, x.rule) for x in v] == [(0, "START_UNKNOWN"), (16, "START_UNKNOWN")]
    assert v[0].message == "start pose is not six finite axis angles"


def test_a_start_pose_at_minus_zero_is_the_same_pose() -> None:
    ctx = CheckContext(start_axes_deg=(-0.0, -90.0, 90.0, -0.0, -0.0, -0.0))
    assert found(program("  PTP {A3 90}\n  PTP {A1 0}"), ctx) == []


# --- writes ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("write", "rule"), [
    ("$TRACE.MODE = #T_START", None), ("$TRACE.NAME[] = \"x\"", None), ("$TRACE.CONFIG[] = \"x\"", None),
    ("$TRACE.STATE = #T_END", "SYSVAR"), ("$TRACE.NAME[1] = \"x\"", "SYSVAR"), ("$TRACE = 1", "SYSVAR"),
    ("$TRACE.MODE.X = 1", "SYSVAR"), ("$OUT[1] = TRUE", "SYSVAR"), ("RGSE_STEP = 1", None), ("rgse_step = 1", None),
    ("OTHER = 1", "WRITE"), ("$VEL.CP.X = 1", "SYSVAR"),
])
def test_writes(write: str, rule: str | None) -> None:
    v = found(program(f"  {write}"))
    assert [x.rule for x in v] == ([] if rule is None else [rule])
    if rule == "WRITE":
        assert v[0].message == "write to OTHER: not a variable of this program and not on the allow-list"
    if rule == "SYSVAR" and write.startswith("$TRACE.STATE"):
        assert v[0].message == "write to system variable $TRACE.STATE is not allowed"


def test_a_context_allow_list_is_used() -> None:
    ctx = CheckContext(start_axes_deg=MEAS, writable_variables=frozenset({"OTHER"}), writable_prefix="MY_")
    assert rules(program("  OTHER = 1\n  my_x = 1"), ctx) == set()
    assert rules(program("  RGSE_STEP = 1"), ctx) == {"WRITE"}
    assert ctx.link_writable(" other ") and ctx.link_writable("My_Y") and not ctx.link_writable("RGSE_STEP")


def test_the_sampled_a5_torque_bound_by_hand() -> None:
    # CoG 0.21 m out on flange z, 0.5 m from the wrist centre; at A2 -90, A3 90, A4 0 the A5 axis is horizontal and the
    # flange points down at A5 90: the static A5 torque is m·g·0.5·sin(90° - A5). The check samples the path every
    # 0.25° at most (n = ceil(L1 / 0.25) + 1 points, both ends included) and adds 2·m·g·(d6 + |c|)·step for the
    # unsampled stretches between them.
    m, g = 300.0, 9.81
    start = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)
    ctx = CheckContext(start_axes_deg=start, payload_mass_kg=m, payload_cog_flange_m=(0.0, 0.0, 0.21),
                       limits=LimitsConfig(max_a5_torque_nm=100.0))  # below the lever bound: the path is sampled
    checker = _Checker(ctx)
    for a5 in (60.0, 60.1, 0.0, 89.9):
        l1 = 90.0 - a5
        n = math.ceil(l1 / 0.25) + 1
        expected = m * g * 0.5 * math.sin(math.radians(l1)) + 2.0 * m * g * 0.5 * math.radians(l1 / (n - 1))
        assert checker.max_a5_torque_nm(start, (0.0, -90.0, 90.0, 0.0, a5, 0.0)) == pytest.approx(expected, rel=1e-12)
    # holding the pose: only the torque there (none, the CoG hangs under the axis)
    assert checker.max_a5_torque_nm(start, start) == pytest.approx(0.0, abs=1e-9)
    # a lever short enough for the limit: the bound m·g·|lever| itself, no sampling
    roomy = _Checker(CheckContext(start_axes_deg=start, payload_mass_kg=m, payload_cog_flange_m=(0.0, 0.0, 0.21)))
    assert roomy.max_a5_torque_nm(start, (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)) == pytest.approx(m * g * 0.5, rel=1e-12)
    sideways = _Checker(CheckContext(start_axes_deg=start, payload_mass_kg=m, payload_cog_flange_m=(0.3, 0.4, -0.29)))
    assert sideways.max_a5_torque_nm(start, start) == pytest.approx(m * g * 0.5, rel=1e-12)


def test_setting_messages() -> None:
    def message(body: str) -> str:
        (v,) = found(program(body))
        return v.message

    not_constant = "a value that is not a constant"
    stall = " (below the smallest speed a motion is allowed: it would stall)"  # only below the floor
    assert message("  $OV_PRO = RGSE_OV") == f"$OV_PRO must be a constant in 1..100 %, not {not_constant}"
    assert message("  $OV_PRO = 101") == "$OV_PRO must be a constant in 1..100 %, not INT 101"
    assert message("  $OV_PRO = 0") == f"$OV_PRO must be a constant in 1..100 %, not INT 0{stall}"
    assert message("  $OV_PRO = 0.4") == f"$OV_PRO must be a constant in 1..100 %, not INT 0{stall}"  # stored as INT
    assert found(program("  $OV_PRO = 1\n  PTP {A3 91}")) == []  # the floor itself is allowed
    f32 = struct.unpack("<f", struct.pack("<f", 0.0099))[0]
    assert message("  $VEL_AXIS[2] = 0.0099") == (
        f"$VEL_AXIS must be set to a constant in [0.01, 100] %, not REAL {f32!r}")
    assert message("  $VEL.CP = 3") == "$VEL.CP must be a constant in (0, 2] m/s, not REAL 3.0"
    assert message("  $VEL.ORI1 = 1") == "only $VEL.CP of $VEL may be written"
    assert message("  $OV_PRO[1] = 5") == "$OV_PRO is a scalar"
    # an indexed member has no name on the allow-list: the message names the variable
    assert message('  $TRACE.NAME[1].X = 1') == "write to system variable $TRACE is not allowed"
    assert message("  $TRACE.STATE = 1") == "write to system variable $TRACE.STATE is not allowed"
    assert message("  $TRACE.NAME[2] = 1") == "write to system variable $TRACE is not allowed"


def test_a_write_to_no_variable_is_named_as_such() -> None:
    # the parser only gives targets rooted in a name; the check still names anything else if it is handed one
    checker = _Checker(CTX)
    assert not checker.writable(k.IntLit(1), k.Pos(5, 3))
    (v,) = checker.found.values()
    assert v == Violation(5, 3, "WRITE", "write to an expression that is not a variable: not a variable of this "
                                         "program and not on the allow-list")


def test_the_motion_check_budget_is_exact() -> None:
    checker = _Checker(CTX)
    checker.motion_checks = MAX_MOTION_CHECKS - 1
    checker.check_path(MEAS, MEAS, _state(), k.Pos(9, 3))  # the 20000th: still checked
    with pytest.raises(TooComplex, match="more than 20000 motion checks") as info:
        checker.check_path(MEAS, MEAS, _state(), k.Pos(9, 3))
    assert info.value.pos == k.Pos(9, 3) and MAX_MOTION_CHECKS == 20_000


def _state() -> State:
    return State(frozenset({MEAS}), (2.0,) * 6, 0.0, ())
