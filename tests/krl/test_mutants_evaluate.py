"""The KRL evaluator and typed values, operator by operator, at their exact limits (issue #31 item 6).

Expected values are KRL's as ``docs/krl-semantics.md`` states them (INT/REAL arithmetic, 32-bit limits, binary32
rounding, type errors), worked out by hand or with :mod:`struct` as an independent binary32 reference; never copied
from the evaluator's output. Both lanes (binary32 and binary64 intermediates) and both modes (``strict``: the
interlock, not strict: the simulator) are exercised.
"""

from __future__ import annotations

import math
import struct

import pytest

from rgse_daemon.krl import ast as k
from rgse_daemon.krl.evaluate import BUILTINS, MAX_EXPR_DEPTH, Evaluator, expr_depth
from rgse_daemon.krl.parser import parse_expression
from rgse_daemon.krl.values import (
    INT_MAX,
    INT_MIN,
    REAL_MIN_NORMAL,
    UNKNOWN,
    EvalError,
    KrlArray,
    KrlEnum,
    KrlStruct,
    Unsure,
    convert,
    default_value,
    describe,
    element,
    field_type,
    int32,
    is_int,
    is_number,
    is_real,
    member,
    merge,
    real32,
    real64,
    real_literal,
    round_to_int,
)

VARS = {"X": 7, "R": 2.5, "B": True, "U": UNKNOWN, "E": KrlEnum("A")}


def f32(x: float) -> float:
    """The nearest binary32 (the reference, independent of the code under test)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def ev(text: str, wide: bool = False, strict: bool = True) -> object:
    e = Evaluator(read=lambda n: VARS[n.name] if isinstance(n, k.Name) else UNKNOWN,
                  call=lambda c: UNKNOWN, wide=wide, strict=strict)
    return e.evaluate(parse_expression(text))


def both(text: str) -> tuple[object, object]:
    return ev(text), ev(text, wide=True)


# --- INT arithmetic ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "value"), [
    ("7 / 2", 3), ("-7 / 2", -3), ("7 / -2", -3), ("-7 / -2", 3), ("0 / 5", 0), ("6 / 3", 2), ("1 / 2", 0),
    ("-1 / 2", 0), ("7 + 2", 9), ("7 - 2", 5), ("7 * 2", 14), ("2147483646 + 1", INT_MAX),
    ("-2147483647 - 1", INT_MIN), ("-X", -7), ("+X", 7), ("B_NOT 0", -1), ("B_NOT 5", -6),
    ("12 B_AND 10", 8), ("12 B_OR 10", 14), ("12 B_EXOR 10", 6), ("X B_AND 3", 3),
    ("3 < 4", True), ("4 < 4", False), ("4 > 3", True), ("4 > 4", False), ("4 <= 4", True), ("5 <= 4", False),
    ("4 >= 4", True), ("3 >= 4", False), ("4 == 4", True), ("4 == 5", False), ("4 <> 5", True), ("4 <> 4", False),
])
def test_int_operations(text: str, value: int) -> None:
    got = both(text)
    assert got == (value, value) and all(type(g) is type(value) for g in got)


@pytest.mark.parametrize("text", ["2147483647 + 1", "-2147483647 - 2", "65536 * 32768", "-2147483648",
                                  "-(2147483647) - 1 - 1", "2147483648"])
def test_int_results_outside_32_bits_are_unsure(text: str) -> None:
    with pytest.raises(Unsure):
        ev(text)


def test_int_min_is_reached_but_not_as_a_literal() -> None:
    assert ev("-2147483647 - 1") == INT_MIN
    with pytest.raises(Unsure, match="INT literal -2147483648"):
        ev("-2147483648")
    assert ev("2147483647") == INT_MAX


def test_negating_int_min_overflows() -> None:
    VARS["M"] = INT_MIN
    try:
        with pytest.raises(Unsure):
            ev("-M")
        with pytest.raises(Unsure):
            ev("M / -1")
        assert ev("M / 1") == INT_MIN
    finally:
        del VARS["M"]


@pytest.mark.parametrize("text", ["1 / 0", "1.0 / 0", "1 / 0.0", "X / (X - 7)"])
def test_division_by_zero_stops_the_program(text: str) -> None:
    for wide in (False, True):
        with pytest.raises(EvalError, match="division by zero") as info:
            ev(text, wide=wide)
        assert not isinstance(info.value, Unsure)


# --- REAL arithmetic --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "value"), [
    ("7 / 2.0", 3.5), ("7.0 / 2", 3.5), ("1 + 0.5", 1.5), ("0.5 - 1", -0.5), ("R * 2", 5.0), ("-R", -2.5),
    ("+R", 2.5), ("R < 2.5", False), ("R <= 2.5", True), ("R > 2.5", False), ("R >= 2.5", True), ("R == 2.5", True),
    ("R <> 2.5", False), ("2 < R", True), ("3 > R", True), ("2.5 == 5 / 2.0", True),
])
def test_real_operations(text: str, value: object) -> None:
    got = both(text)
    assert got == (value, value) and all(type(g) is type(value) for g in got)


def test_real_is_rounded_to_binary32_after_each_operation_in_the_narrow_lane() -> None:
    # 0.1 + 0.2: binary32 rounds each literal and the sum; the wide lane keeps binary64 until stored
    assert ev("0.1 + 0.2") == f32(f32(0.1) + f32(0.2))
    assert ev("0.1 + 0.2", wide=True) == 0.1 + 0.2
    assert ev("1.0 / 3") == f32(1.0 / 3.0)
    assert ev("1.0 / 3", wide=True) == 1.0 / 3.0
    assert ev("16777216.0 + 1") == 16777216.0  # 2^24 + 1 is no binary32
    assert ev("16777216.0 + 1", wide=True) == 16777217.0
    assert ev("16777216 + 1") == 16777217  # INTs are exact
    assert ev("3 * 0.1") == f32(3 * f32(0.1)) and ev("3 * 0.1", wide=True) == 3 * 0.1
    assert ev("1.0 - 0.9") == f32(f32(1.0) - f32(0.9))


@pytest.mark.parametrize("text", ["3.0E38 * 10", "1.0E-30 * 1.0E-30", "1.0E-38 / 1000", "-3.0E38 - 3.0E38"])
def test_real_outside_the_normal_range_is_unsure(text: str) -> None:
    with pytest.raises(Unsure):
        ev(text)


def test_wide_lane_only_refuses_what_binary64_cannot_hold() -> None:
    assert ev("3.0E38 * 10", wide=True) == pytest.approx(3.0e39)
    with pytest.raises(Unsure):
        ev("1.0E308 * 10.0", wide=True)


# --- types ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "value"), [
    ("TRUE AND FALSE", False), ("TRUE AND TRUE", True), ("FALSE OR TRUE", True), ("FALSE OR FALSE", False),
    ("TRUE EXOR TRUE", False), ("TRUE EXOR FALSE", True), ("FALSE EXOR FALSE", False), ("NOT TRUE", False),
    ("NOT FALSE", True), ("B AND TRUE", True), ("TRUE == TRUE", True), ("TRUE == FALSE", False),
    ("TRUE <> FALSE", True), ("FALSE <> FALSE", False), ("E == #A", True), ("E == #B", False), ("E <> #B", True),
    ("E <> #A", False), ("1 == 1.0", True), ("1 <> 1.0", False),
])
def test_bool_and_enum_operations(text: str, value: bool) -> None:
    assert both(text) == (value, value)
    assert all(isinstance(g, bool) for g in both(text))


@pytest.mark.parametrize(("text", "message"), [
    ("1 AND TRUE", "AND needs BOOLs"), ("TRUE AND 1", "AND needs BOOLs"), ("TRUE OR 0", "OR needs BOOLs"),
    ("1 EXOR TRUE", "EXOR needs BOOLs"), ("1 AND 1", "AND needs BOOLs"), ("NOT 1", "NOT needs a BOOL"),
    ("NOT 1.0", "NOT needs a BOOL"), ("B_NOT TRUE", "B_NOT needs an INT"), ("B_NOT 1.0", "B_NOT needs an INT"),
    ("TRUE B_AND 1", "B_AND needs INTs"), ("1 B_OR 1.0", "B_OR needs INTs"), ("1.0 B_EXOR 1", "B_EXOR needs INTs"),
    ("TRUE == 1", "cannot compare"), ("1 == TRUE", "cannot compare"), ("#A <> 1", "cannot compare"),
    ("TRUE == #A", "cannot compare"), ("\"a\" == \"a\"", "cannot compare"), ("TRUE < FALSE", "< needs numbers"),
    ("TRUE + 1", "\\+ needs numbers"), ("1 - TRUE", "- needs numbers"), ("#A * 2", "\\* needs numbers"),
    ("-TRUE", "- needs a number"), ("-#A", "- needs a number"), ("1.0 < TRUE", "< needs numbers"),
])
def test_type_mismatches_stop_the_program(text: str, message: str) -> None:
    for wide in (False, True):
        with pytest.raises(EvalError, match=message) as info:
            ev(text, wide=wide)
        assert not isinstance(info.value, Unsure)


@pytest.mark.parametrize("text", ["U + 1", "1 + U", "NOT U", "-U", "U AND TRUE", "U == 1", "ABS(U)", "SQRT(U)",
                                  "ATAN2(U, 1)", "{A1 U}"])
def test_unknown_operands_give_unknown(text: str) -> None:
    assert ev(text) is UNKNOWN


def test_unknown_wins_over_a_type_error() -> None:
    # the value is not known before the run: whether it is a type error is decided where it is used
    assert ev("U AND 1") is UNKNOWN and ev("TRUE == U") is UNKNOWN


def test_literals_and_aggregates() -> None:
    assert ev('"abc"') == "abc" and ev("#XY") == KrlEnum("XY") and ev("TRUE") is True
    agg = ev("{A1 1, A2 2.5}")
    assert agg == KrlStruct(None, (("A1", 1), ("A2", 2.5)))
    typed = ev("{E6AXIS: A1 1}")
    assert isinstance(typed, KrlStruct) and typed.type_name == "E6AXIS"
    assert ev("X") == 7 and ev("R") == 2.5


def test_real_literal_lanes() -> None:
    assert ev("0.1") == f32(0.1) and ev("0.1", wide=True) == 0.1


# --- built-ins --------------------------------------------------------------------------------------------------------
def test_builtins_are_exactly_krls() -> None:
    assert BUILTINS == {"ABS": 1, "SQRT": 1, "SIN": 1, "COS": 1, "TAN": 1, "ACOS": 1, "ATAN2": 2}


@pytest.mark.parametrize(("text", "value"), [
    ("ABS(-2.5)", 2.5), ("ABS(2.5)", 2.5), ("SQRT(16)", 4.0), ("SQRT(2.25)", 1.5), ("SQRT(0)", 0.0),
    ("SIN(0)", 0.0), ("TAN(0)", 0.0), ("COS(0)", 1.0), ("ACOS(1)", 0.0), ("ATAN2(0, 1)", 0.0), ("ATAN2(0, 0.5)", 0.0),
    ("SIN(0.0)", 0.0), ("COS(0.0)", 1.0),
])
def test_builtins_where_the_result_is_exact(text: str, value: float) -> None:
    for strict in (True, False):
        got = ev(text, strict=strict), ev(text, wide=True, strict=strict)
        assert got == (value, value) and all(type(g) is float for g in got)


def test_sqrt_is_correctly_rounded_in_each_lane() -> None:
    assert ev("SQRT(2)") == f32(math.sqrt(2.0))
    assert ev("SQRT(2)", wide=True) == math.sqrt(2.0)


@pytest.mark.parametrize("text", ["SIN(30)", "COS(60)", "TAN(45)", "ACOS(0.5)", "ACOS(0)", "ATAN2(1, 1)",
                                  "ATAN2(0, -1)", "ATAN2(0, 0)", "SIN(1)", "COS(1)", "ABS(-3)", "ABS(3)"])
def test_builtins_not_documented_to_the_bit_are_unsure_for_the_interlock(text: str) -> None:
    with pytest.raises(Unsure):
        ev(text)


@pytest.mark.parametrize(("text", "value"), [
    ("SIN(30)", math.sin(math.radians(30))), ("COS(60)", math.cos(math.radians(60))),
    ("TAN(45)", math.tan(math.radians(45))), ("ACOS(0.5)", math.degrees(math.acos(0.5))),
    ("ACOS(-1)", 180.0), ("ATAN2(1, 1)", 45.0), ("ATAN2(-1, -1)", -135.0), ("ATAN2(0, -1)", 180.0),
    ("SIN(90)", 1.0), ("COS(180)", -1.0),
])
def test_the_simulator_computes_them_in_degrees(text: str, value: float) -> None:
    assert ev(text, strict=False) == f32(value)
    assert ev(text, wide=True, strict=False) == value


def test_abs_of_an_int_in_the_simulator_stays_an_int() -> None:
    assert ev("ABS(-3)", strict=False) == 3 and type(ev("ABS(-3)", strict=False)) is int
    with pytest.raises(Unsure):
        ev("ABS(-2147483647 - 1)", strict=False)


@pytest.mark.parametrize(("text", "message"), [
    ("SQRT(-1)", "SQRT of a negative"), ("SQRT(-0.5)", "SQRT of a negative"), ("ABS(1, 2)", "ABS takes 1"),
    ("ATAN2(1)", "ATAN2 takes 2"), ("SIN()", "SIN takes 1"), ("ABS(TRUE)", "ABS needs numbers"),
    ("SQRT(#A)", "SQRT needs numbers"), ("ATAN2(1, TRUE)", "ATAN2 needs numbers"),
])
def test_builtin_errors(text: str, message: str) -> None:
    for strict in (True, False):
        with pytest.raises(EvalError, match=message) as info:
            ev(text, strict=strict)
        assert not isinstance(info.value, Unsure)


def test_acos_outside_its_domain_stops_the_simulated_program() -> None:
    for arg in ("1.5", "-1.0001"):
        with pytest.raises(EvalError, match=r"outside -1\.\.1"):
            ev(f"ACOS({arg})", strict=False)
    assert ev("ACOS(1)", strict=False) == 0.0


def test_user_functions_go_to_the_caller() -> None:
    calls: list[str] = []
    e = Evaluator(read=lambda n: UNKNOWN, call=lambda c: calls.append(c.name) or 42)
    assert e.evaluate(parse_expression("MYFN(1) + 1")) == 43 and calls == ["MYFN"]
    e.evaluate(parse_expression("ASIN(1)"))
    assert calls == ["MYFN", "ASIN"]


# --- depth ------------------------------------------------------------------------------------------------------------
def chain(n: int) -> k.Expr:
    expr: k.Expr = k.IntLit(1)
    for _ in range(n - 1):
        expr = k.Unary("-", expr)
    return expr


def test_expression_depth_limit_is_inclusive() -> None:
    assert expr_depth(chain(MAX_EXPR_DEPTH)) == MAX_EXPR_DEPTH
    e = Evaluator(read=lambda n: UNKNOWN, call=lambda c: UNKNOWN)
    assert e.evaluate(chain(MAX_EXPR_DEPTH)) == (1 if MAX_EXPR_DEPTH % 2 else -1)
    with pytest.raises(Unsure, match=f"deeper than {MAX_EXPR_DEPTH}"):
        e.evaluate(chain(MAX_EXPR_DEPTH + 1))
    assert MAX_EXPR_DEPTH == 200


@pytest.mark.parametrize(("text", "depth"), [
    ("1", 1), ("1 + 2", 2), ("-(1 + 2)", 3), ("A[1 + 2]", 3), ("A.B", 2), ("F(1, 2 * 3)", 3), ("{A1 1 + 2}", 3),
    ("A[1, (2 + 3) * 4]", 4), ("A.B.C", 3), ("F()", 1),
])
def test_expression_depth(text: str, depth: int) -> None:
    assert expr_depth(parse_expression(text)) == depth


# --- values: numbers --------------------------------------------------------------------------------------------------
def test_number_kinds() -> None:
    assert is_int(1) and not is_int(True) and not is_int(1.0)
    assert is_real(1.0) and not is_real(1)
    assert is_number(1) and is_number(1.0) and not is_number(False) and not is_number("1")


def test_int32_limits_are_inclusive() -> None:
    assert int32(INT_MAX) == INT_MAX and int32(INT_MIN) == INT_MIN
    assert INT_MAX == 2147483647 and INT_MIN == -2147483648
    for n in (INT_MAX + 1, INT_MIN - 1):
        with pytest.raises(Unsure, match="INT overflow"):
            int32(n)


def test_real32_limits() -> None:
    biggest = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
    assert real32(biggest) == biggest and real32(-biggest) == -biggest
    with pytest.raises(Unsure, match="REAL overflow"):
        real32(biggest * 2)
    with pytest.raises(Unsure):
        real32(math.inf)
    with pytest.raises(Unsure):
        real32(math.nan)
    assert REAL_MIN_NORMAL == 2.0 ** -126
    assert real32(REAL_MIN_NORMAL) == REAL_MIN_NORMAL and real32(-REAL_MIN_NORMAL) == -REAL_MIN_NORMAL
    for tiny in (REAL_MIN_NORMAL / 2, -REAL_MIN_NORMAL / 2, 1e-50):
        with pytest.raises(Unsure, match="underflow"):
            real32(tiny)
    assert real32(0.0) == 0.0 and math.copysign(1.0, real32(-0.0)) == 1.0
    assert real32(0.1) == f32(0.1)


def test_real64_refuses_only_non_finite() -> None:
    assert real64(1e300) == 1e300 and real64(1e-320) == 1e-320
    for bad in (math.inf, -math.inf, math.nan):
        with pytest.raises(Unsure):
            real64(bad)


def test_real_literal_ties() -> None:
    assert real_literal(16777217.0, "16777217.0") == 16777216.0  # an exact decimal tie: to even either way
    assert real_literal(0.5, "0.5") == 0.5
    assert real_literal(0.1, "0.1") == f32(0.1)
    # 16777217.000000001 reads as binary64 16777217.0, a tie, but the decimal is above it: direct reading gives
    # 16777218, through binary64 16777216 -- not documented which
    with pytest.raises(Unsure, match="depends on how it is read"):
        real_literal(16777217.000000001, "16777217.000000001")
    with pytest.raises(Unsure):
        real_literal(16777217.0, None)  # no text: cannot tell
    # the tie between binary32 neighbours below zero and at the top of a binade
    assert real_literal(-16777217.0, "-16777217.0") == -16777216.0
    with pytest.raises(Unsure):
        real_literal(-16777217.000000001, "-16777217.000000001")
    assert real_literal(16777219.0, "16777219.0") == 16777220.0  # tie to even, upwards


def test_round_to_int() -> None:
    assert [round_to_int(x) for x in (0.4, 0.6, -0.4, -0.6, 1.49, 1.51, -1.51, 2.0, -2.0)] == [0, 1, 0, -1, 1, 2,
                                                                                              -2, 2, -2]
    for tie in (0.5, 1.5, -0.5, -2.5):
        with pytest.raises(Unsure, match="halfway"):
            round_to_int(tie)
    assert [round_to_int(x, strict=False) for x in (0.5, 1.5, -0.5, -2.5, 2.5)] == [1, 2, -1, -3, 3]
    with pytest.raises(Unsure):
        round_to_int(math.inf)
    with pytest.raises(Unsure):
        round_to_int(math.nan)
    with pytest.raises(Unsure, match="INT overflow"):
        round_to_int(2147483647.6)
    assert round_to_int(2147483647.4) == INT_MAX
    assert type(round_to_int(3.2)) is int


# --- values: assignment -----------------------------------------------------------------------------------------------
def test_convert_scalars() -> None:
    assert convert("INT", 7) == 7 and convert("INT", 2.6) == 3 and convert("INT", -2.6) == -3
    assert convert("REAL", 7) == 7.0 and type(convert("REAL", 7)) is float
    assert convert("REAL", 16777217) == 16777216.0
    assert convert("REAL", 0.1) == f32(0.1)
    assert convert("BOOL", True) is True and convert("CHAR", "x") == "x"
    assert convert("INT", UNKNOWN) is UNKNOWN and convert("E6AXIS", UNKNOWN) is UNKNOWN
    with pytest.raises(Unsure):
        convert("INT", 2.5)
    assert convert("INT", 2.5, strict=False) == 3
    with pytest.raises(Unsure):
        convert("INT", INT_MAX + 1)
    assert convert(None, 0.1) == f32(0.1) and convert("LOAD", 1) == 1
    assert convert(None, KrlStruct(None, (("X", 0.1),))) == KrlStruct(None, (("X", f32(0.1)),))


@pytest.mark.parametrize(("type_name", "value"), [
    ("INT", True), ("INT", "a"), ("REAL", True), ("REAL", KrlEnum("A")), ("BOOL", 1), ("BOOL", 0.0), ("CHAR", 1),
    ("E6AXIS", 1.0), ("AXIS", True), ("INT", KrlStruct(None, ())), ("BOOL", "TRUE"),
])
def test_convert_type_mismatches_stop_the_program(type_name: str, value: object) -> None:
    with pytest.raises(EvalError, match=f"cannot assign .* to an? {type_name}$") as info:
        convert(type_name, value)  # type: ignore[arg-type]
    assert not isinstance(info.value, Unsure)


def test_structures_take_only_the_named_fields() -> None:
    old = KrlStruct("E6AXIS", (("A1", 1.0), ("A2", 2.0)))
    new = convert("E6AXIS", KrlStruct(None, (("A3", 3), ("A1", 10))), old)
    assert new == KrlStruct("E6AXIS", (("A1", 10.0), ("A2", 2.0), ("A3", 3.0)))  # declaration order, REALs
    assert all(type(v) is float for _, v in new.fields)
    assert convert("E6AXIS", KrlStruct(None, (("A3", 3),))) == KrlStruct("E6AXIS", (("A3", 3.0),))
    # a non-structure old value counts as nothing assigned
    assert convert("AXIS", KrlStruct(None, (("A6", 1),)), 5) == KrlStruct("AXIS", (("A6", 1.0),))
    pos = convert("POS", KrlStruct(None, (("S", 2.4), ("X", 1))))
    assert pos == KrlStruct("POS", (("X", 1.0), ("S", 2)))  # S is an INT field: rounded
    assert type(dict(pos.fields)["S"]) is int
    assert field_type("S") == "INT" and field_type("T") == "INT" and field_type("A1") == "REAL"


def test_merge_errors() -> None:
    with pytest.raises(EvalError, match="cannot assign a POS aggregate to a E6AXIS"):
        merge("E6AXIS", None, KrlStruct("POS", (("X", 1.0),)))
    with pytest.raises(EvalError, match="AXIS has no field E1"):
        merge("AXIS", None, KrlStruct(None, (("E1", 1.0),)))
    assert merge("AXIS", None, KrlStruct("AXIS", (("A1", 1),))) == KrlStruct("AXIS", (("A1", 1.0),))


def test_merge_into_an_unknown_structure_type() -> None:
    old = KrlStruct("TOOLT", (("X", 1), ("Y", 2)))
    got = merge("TOOLT", old, KrlStruct(None, (("Z", 3), ("X", 9))))
    assert got == KrlStruct("TOOLT", (("X", 9), ("Y", 2), ("Z", 3)))  # old order, then new; no conversion
    assert merge(None, None, KrlStruct("FOO", (("Q", 1),))) == KrlStruct("FOO", (("Q", 1),))
    assert merge(None, KrlStruct(None, ()), KrlStruct("FOO", (("Q", 1),))).type_name == "FOO"


def test_default_values() -> None:
    assert default_value("INT") == 0 and type(default_value("INT")) is int
    assert default_value("REAL") == 0.0 and type(default_value("REAL")) is float
    assert default_value("BOOL") is False and default_value("CHAR") == ""
    assert default_value("CHAR", (10,)) == ""
    assert default_value("E6AXIS") == KrlStruct("E6AXIS", ())
    assert default_value("INT", (3,)) == KrlArray("INT", (3,))
    assert default_value("LOAD") is UNKNOWN


# --- values: access ---------------------------------------------------------------------------------------------------
def test_member_access() -> None:
    p = KrlStruct("E6AXIS", (("A1", 1.0),))
    assert member(p, "A1") == 1.0 and member(UNKNOWN, "A1") is UNKNOWN
    with pytest.raises(Unsure, match="A2 is read before"):
        member(p, "A2")
    with pytest.raises(EvalError, match="has no field X") as info:
        member(p, "X")
    assert not isinstance(info.value, Unsure)
    with pytest.raises(EvalError, match="has no field A1"):
        member(3, "A1")
    with pytest.raises(EvalError, match="has no field Q") as info:
        member(KrlStruct("TOOLT", ()), "Q")
    assert not isinstance(info.value, Unsure)


def test_element_access() -> None:
    assert element("abc", ()) == "abc" and element("abc", (1,)) == "a" and element("abc", (3,)) == "c"
    for bad in ((0,), (4,), (1, 1)):
        with pytest.raises(EvalError, match="string index"):
            element("abc", bad)
    a = KrlArray("INT", (2, 3), {(1, 1): 5, (2, 3): 6})
    assert element(a, (1, 1)) == 5 and element(a, (2, 3)) == 6 and element(UNKNOWN, (1,)) is UNKNOWN
    with pytest.raises(Unsure, match="read before"):
        element(a, (1, 2))
    for bad in ((0, 1), (3, 1), (1, 4), (1, 0), (1,), (1, 1, 1)):
        with pytest.raises(EvalError, match="outside the array") as info:
            element(a, bad)
        assert not isinstance(info.value, Unsure)
    s = KrlArray("E6AXIS", (2,))
    assert element(s, (2,)) == KrlStruct("E6AXIS", ())
    with pytest.raises(EvalError, match="cannot index"):
        element(5, (1,))


def test_describe() -> None:
    assert describe(True) == "BOOL TRUE" and describe(False) == "BOOL FALSE"
    assert describe(3) == "INT 3" and describe(2.5) == "REAL 2.5" and describe("ab") == 'CHAR[] "ab"'
    assert describe(KrlEnum("X")) == "ENUM #X"
    assert describe(KrlStruct("POS", ())) == "a POS" and describe(KrlStruct(None, ())) == "a structure"
    assert describe(KrlArray("INT", (2,))) == "an array of INT" and describe(UNKNOWN) == "an unknown value"
    assert describe(10**30).startswith("INT 1000000000…") and "(31 digits)" in describe(10**30)
    assert describe(10**23) == "INT " + str(10**23)


# --- where an error is: the check reports it at the expression's place --------------------------------------------
@pytest.mark.parametrize(("text", "column", "unsure", "strict"), [
    ("1 + NOT 1", 5, False, True), ("1 + B_NOT TRUE", 5, False, True), ("1 + -TRUE", 5, False, True),
    ("1 + (2 AND 3)", 8, False, True), ("1 + (1 B_AND TRUE)", 8, False, True), ("1 + (TRUE == 1)", 11, False, True),
    ("1 + (TRUE < 1)", 11, False, True), ("1 + (1 / 0)", 8, False, True), ("1 + (1.0 / 0)", 10, False, True),
    ("1 + ABS(1, 2)", 5, False, True), ("1 + ABS(TRUE)", 5, False, True), ("1 + ABS(-3)", 5, True, True),
    ("1 + SQRT(-1)", 5, False, True), ("1 + SIN(30)", 5, True, True), ("1 + ACOS(2)", 5, False, False),
    ("1 + 2147483647 * 2", 16, True, True), ("1 + 3.0E38 * 10", 12, True, True), ("1 + (7 / 0)", 8, False, True),
    ("1 + -2147483648", 5, True, True), ("1 + 1.0E39", 5, True, True), ("1 + SIN(2.0E-38)", 5, True, False),
    ("1 + ABS(-2147483647 - 1 - 1)", 25, True, False), ("1 + -(-2147483647 - 1)", 5, True, True),
])
def test_errors_carry_the_place_of_the_failing_expression(text: str, column: int, unsure: bool, strict: bool) -> None:
    with pytest.raises(EvalError) as info:
        ev(text, strict=strict)
    assert info.value.pos == k.Pos(1, column)
    assert isinstance(info.value, Unsure) is unsure


@pytest.mark.parametrize("call", [
    lambda p: int32(2**31, p), lambda p: real32(1e39, p), lambda p: real32(math.nan, p), lambda p: real32(1e-40, p),
    lambda p: real64(math.inf, p), lambda p: real_literal(16777217.0, None, p), lambda p: round_to_int(0.5, p),
    lambda p: round_to_int(math.inf, p), lambda p: round_to_int(3e9, p), lambda p: convert("INT", True, pos=p),
    lambda p: convert("INT", 2.5, pos=p), lambda p: convert("INT", 2**31, pos=p), lambda p: convert("REAL", "x", pos=p),
    lambda p: convert("REAL", 1e39, pos=p), lambda p: convert("BOOL", 1, pos=p), lambda p: convert("CHAR", 1, pos=p),
    lambda p: convert("AXIS", 1, pos=p), lambda p: convert("AXIS", KrlStruct(None, (("A1", 0.5e-40),)), pos=p),
    lambda p: convert("POS", KrlStruct(None, (("S", 0.5),)), pos=p), lambda p: convert(None, 1e39, pos=p),
    lambda p: convert(None, KrlStruct(None, (("X", 1e39),)), pos=p),
    lambda p: merge("AXIS", None, KrlStruct("POS", ()), p),
    lambda p: merge("AXIS", None, KrlStruct(None, (("Q", 1),)), p),
    lambda p: member(KrlStruct("AXIS", ()), "A1", p), lambda p: member(KrlStruct("AXIS", ()), "Q", p),
    lambda p: member(1, "A1", p), lambda p: element("ab", (3,), p), lambda p: element(KrlArray("INT", (2,)), (1,), p),
    lambda p: element(KrlArray("INT", (2,)), (3,), p), lambda p: element(1, (1,), p),
])
def test_value_errors_carry_their_place(call: object) -> None:
    where = k.Pos(7, 9)
    with pytest.raises(EvalError) as info:
        call(where)  # type: ignore[operator]
    assert info.value.pos == where
    assert info.value.reason == str(info.value)


# --- what the operator reads ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "strict", "message"), [
    ("NOT 1", True, "NOT needs a BOOL, not INT 1"),
    ("B_NOT TRUE", True, "B_NOT needs an INT, not BOOL TRUE"),
    ("-#A", True, "- needs a number, not ENUM #A"),
    ("1 AND TRUE", True, "AND needs BOOLs, not INT 1 and BOOL TRUE"),
    ("1 B_OR 2.5", True, "B_OR needs INTs, not INT 1 and REAL 2.5"),
    ("TRUE == 1", True, "cannot compare BOOL TRUE with INT 1"),
    ("TRUE < 1", True, "< needs numbers, not BOOL TRUE and INT 1"),
    ("1 / 0", True, "division by zero"),
    ("ABS(1, 2)", True, "ABS takes 1 argument(s), got 2"),
    ("ATAN2(TRUE, 1)", True, "ATAN2 needs numbers, not BOOL TRUE, INT 1"),
    ("ABS(-3)", True, "ABS of an INT: whether the result is an INT or a REAL is not documented"),
    ("SQRT(-4)", True, "SQRT of a negative number (-4.0)"),
    ("COS(1)", True, "COS: the controller's result is not documented to the last bit"),
    ("ACOS(2)", False, "ACOS of 2.0: outside -1..1"),
    ("2147483647 + 1", True, "INT overflow (2147483648 is outside -2147483648..2147483647)"),
    ("-2147483648", True, "INT literal -2147483648"),
])
def test_error_messages(text: str, strict: bool, message: str) -> None:
    with pytest.raises(EvalError) as info:
        ev(text, strict=strict)
    assert info.value.reason == message


def test_abs_of_int_min_overflows_at_the_call() -> None:
    with pytest.raises(Unsure) as info:
        ev("1 + ABS(-2147483647 - 1)", strict=False)
    assert info.value.pos == k.Pos(1, 5)


def test_value_error_messages() -> None:
    cases = [
        (lambda: member(KrlStruct("AXIS", ()), "A2"), "field A2 is read before it was assigned"),
        (lambda: member(KrlStruct("AXIS", ()), "Q"), "a AXIS has no field Q"),
        (lambda: element(KrlArray("INT", (2,)), (1,)), "array element [1] is read before it was assigned"),
        (lambda: element(KrlArray("INT", (2,)), (3,)), "index [3] outside the array's size [2]"),
        (lambda: element("ab", (3,)), "string index [3] out of range"),
        (lambda: element(True, (1,)), "cannot index BOOL TRUE"),
        (lambda: round_to_int(0.5), "REAL 0.5 is halfway between two INTs: how the controller rounds it is not "
                                    "documented"),
        (lambda: round_to_int(math.inf), "REAL inf cannot become an INT"),
        (lambda: real32(1e39), "REAL overflow (1e+39 is beyond ±3.4E+38)"),
        (lambda: real32(1e-40), "REAL underflow (1e-40 is below the normal REAL range 1.1E-38)"),
        (lambda: real32(math.nan), "REAL value nan is not a finite number"),
        (lambda: real64(math.inf), "REAL overflow (inf)"),
        (lambda: real_literal(16777217.0, None), "REAL literal 16777217.0: its binary32 value depends on how it is "
                                                 "read"),
        (lambda: convert("BOOL", 1), "cannot assign INT 1 to a BOOL"),
        (lambda: merge("AXIS", None, KrlStruct("POS", ())), "cannot assign a POS aggregate to a AXIS"),
        (lambda: merge("AXIS", None, KrlStruct(None, (("Q", 1), ("R", 2)))), "AXIS has no field Q, R"),
        (lambda: int32(-(2**31) - 1), "INT overflow (-2147483649 is outside -2147483648..2147483647)"),
    ]
    for call, message in cases:
        with pytest.raises(EvalError) as info:
            call()
        assert info.value.reason == message
    assert repr(UNKNOWN) == "UNKNOWN"


def test_long_numbers_are_shortened_in_messages() -> None:
    assert describe(123456789012345678901234) == "INT 123456789012345678901234"  # 24 digits: in full
    assert describe(1234567890123456789012345) == "INT 1234567890…2345 (25 digits)"
    assert describe(-123456789012345678901234) == "INT -123456789…1234 (25 digits)"


def test_merge_converts_only_known_structures_and_keeps_the_mode() -> None:
    got = merge("TOOLT", None, KrlStruct(None, (("X", 9), ("ON", True))))
    assert [(n, type(v)) for n, v in got.fields] == [("X", int), ("ON", bool)]  # no REAL conversion for unknown types
    # the simulator's mode reaches the fields: S ← 2.5 is a tie, refused by the interlock, rounded away by the simulator
    assert convert("POS", KrlStruct(None, (("S", 2.5),)), strict=False) == KrlStruct("POS", (("S", 3),))
    with pytest.raises(Unsure):
        convert("POS", KrlStruct(None, (("S", 2.5),)))


def test_a_literal_tie_with_the_lower_neighbour() -> None:
    # 16777218.999999999 reads as binary64 16777219.0, halfway between the binary32 values 16777218 and 16777220
    # (ties to even: 16777220); read directly, the decimal is below the tie: 16777218. Not documented which: refused.
    assert float("16777218.999999999") == 16777219.0
    with pytest.raises(Unsure, match="depends on how it is read"):
        real_literal(16777219.0, "16777218.999999999")
    with pytest.raises(Unsure, match="depends on how it is read"):
        real_literal(-16777219.0, "-16777218.999999999")
    assert real_literal(16777219.0, "16777219.0") == 16777220.0
    with pytest.raises(Unsure):
        ev("16777218.999999999")


def test_or_is_not_exor() -> None:
    # TRUE OR TRUE is where OR and EXOR differ
    assert both("TRUE OR TRUE") == (True, True)
    assert both("TRUE EXOR TRUE") == (False, False)
    assert both("TRUE OR FALSE") == (True, True)


def test_an_operator_the_evaluator_does_not_know_is_an_error_at_its_place() -> None:
    e = Evaluator(read=lambda n: UNKNOWN, call=lambda c: UNKNOWN)
    where = k.Pos(4, 2)
    for a, b in ((1.0, 2.0), (1, 2)):
        with pytest.raises(EvalError) as info:
            e.binary("MOD", a, b, where)
        assert info.value.reason == "unknown operator MOD" and info.value.pos == where


def test_an_expression_of_no_known_kind_is_an_error_at_its_place() -> None:
    e = Evaluator(read=lambda n: UNKNOWN, call=lambda c: UNKNOWN)
    with pytest.raises(EvalError, match="cannot evaluate Halt") as info:
        e.value(k.Halt(k.Pos(4, 7)))  # type: ignore[arg-type]
    assert info.value.pos == k.Pos(4, 7)
