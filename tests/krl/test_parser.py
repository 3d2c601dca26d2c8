"""Parser tests: the daemon's own program shapes, error positions, and the walker the interlock relies on."""

from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.krl import format_module, parse, parse_dat, parse_expression, parse_src, walk
from rgse_daemon.krl.ast import (
    Aggregate,
    Assign,
    Binary,
    BoolLit,
    Call,
    CallStmt,
    DataList,
    Decl,
    EnumLit,
    Exit,
    For,
    Halt,
    If,
    Index,
    IntLit,
    Loop,
    Member,
    Module,
    Motion,
    Name,
    Pos,
    RealLit,
    Repeat,
    Return,
    StrLit,
    Unary,
    WaitFor,
    WaitSec,
    While,
)
from rgse_daemon.krl.formatter import format_expr
from rgse_daemon.krl.walk import motions, root_name, waits, written_targets

PROGRAMS = Path(__file__).parent / "programs"


def load(name: str) -> Module | DataList:
    path = PROGRAMS / name
    return parse(path.read_text(), str(path))


@pytest.mark.parametrize("name", sorted(p.name for p in PROGRAMS.iterdir()))
def test_sample_programs_parse_and_round_trip(name: str) -> None:
    tree = load(name)
    again = parse(format_module(tree), "formatted")
    assert again == tree
    assert format_module(again) == format_module(tree)


def test_warmup_program_structure() -> None:
    module = load("rgse_warmup.src")
    assert isinstance(module, Module)
    assert module.headers == ("&ACCESS RVP", "&REL 3", "&PARAM EDITMASK = *")
    main = module.main
    assert main.name == "RGSE_WARMUP" and main.params == ()
    decls = [s for s in main.body if isinstance(s, Decl)]
    assert [(d.type_name, d.names[0].name) for d in decls] == [("INT", "LOOP_I"), ("REAL", "DWELL_S")]
    assert main.body[2] == CallStmt("BAS", (EnumLit("INITMOV"), IntLit(0)))
    first_for = main.body[4]
    assert isinstance(first_for, For) and first_for.var == "LOOP_I" and first_for.step is None
    assert first_for.body[0] == Assign(Index(Name("$VEL_AXIS"), (Name("LOOP_I"),)), IntLit(10))
    home = main.body[6]
    assert isinstance(home, Motion) and home.kind == "PTP" and home.approx is None
    assert isinstance(home.target, Aggregate) and home.target.type_name == "E6AXIS"
    assert home.target.get("a2") == RealLit(-90.0)
    # positions are 1-based line/column of the statement's first token
    assert home.pos == Pos(20, 3)
    assert first_for.pos == Pos(15, 3)


def test_data_list_globals() -> None:
    dat = load("rgse_measure.dat")
    assert isinstance(dat, DataList) and dat.public and dat.name == "RGSE_MEASURE"
    names = {d.names[0].name: d for d in dat.globals}
    assert set(names) >= {"RGSE_LOOPS", "RGSE_GO", "RGSE_TRACE_NAME"}
    assert names["RGSE_LOOPS"].init == IntLit(10)
    assert names["RGSE_TRACE_NAME"].type_name == "CHAR" and names["RGSE_TRACE_NAME"].names[0].dims == (32,)
    warm = load("rgse_warmup.dat")
    assert isinstance(warm, DataList)
    xhome = next(d for d in warm.decls if d.names[0].name == "XHOME")
    assert not xhome.is_global and isinstance(xhome.init, Aggregate) and xhome.init.type_name is None


def test_walker_finds_nested_motions_waits_and_writes() -> None:
    module = load("rgse_measure.src")
    assert isinstance(module, Module)
    found = [(v.stmt.kind, v.stmt.pos.line, v.in_loop) for v in motions(module)]  # type: ignore[union-attr]
    assert found == [("PTP_REL", 15, True), ("PTP", 16, True), ("LIN", 31, False)]
    wait_lines = [v.stmt.pos.line for v in waits(module)]
    assert wait_lines == [17, 20, 23, 25]
    written = [format_expr(t) for v in walk(module) for t in written_targets(v.stmt)]
    assert "$TRACE.MODE" in written and "$TRACE.NAME[]" in written and "$VEL_AXIS[I]" in written
    assert written[0] == "I"  # the FOR counter comes first
    assert {root_name(t) for v in walk(module) for t in written_targets(v.stmt)} >= {"$ACC_AXIS", "$TRACE", "RGSE_GO"}
    exit_visit = next(v for v in walk(module) if isinstance(v.stmt, Exit))
    assert [type(b).__name__ for b in exit_visit.enclosing] == ["For", "If"]


def test_brake_program_control_flow_and_functions() -> None:
    module = load("rgse_brake.src")
    assert isinstance(module, Module)
    assert [r.name for r in module.routines] == ["RGSE_BRAKE", "CLAMP_AMP"]
    fct = module.routines[1]
    assert fct.is_function and fct.return_type == "REAL"
    assert [(p.name, p.direction) for p in fct.params] == [("VALUE", "IN"), ("LIMIT", "IN")]
    kinds = [type(v.stmt).__name__ for v in walk(module.main)]
    for kind in ("Loop", "If", "While", "Repeat", "Halt", "Exit"):
        assert kind in kinds
    loop = next(s for s in module.main.body if isinstance(s, Loop))
    branch = loop.body[1]
    assert isinstance(branch, If) and branch.else_body
    rel = branch.then_body[0]
    assert isinstance(rel, Motion) and rel.relative
    assert isinstance(rel.target, Aggregate) and rel.target.get("A5") == Unary("-", Name("AMP_DEG"))
    assert any(isinstance(v.stmt, Return) and isinstance(v.stmt.value, Call) for v in walk(fct))
    assert any(isinstance(v.stmt, While) for v in walk(module)) and any(
        isinstance(v.stmt, Repeat) for v in walk(module)
    )
    assert any(isinstance(v.stmt, Halt) for v in walk(module))


def test_case_insensitive_keywords_and_names() -> None:
    lower = parse_src("def Foo()\n  decl int Cnt\n  for cnt = 1 to 3 step 1\n    $vel_axis[cnt] = 20\n  endfor\nend\n")
    upper = parse_src("DEF FOO()\nDECL INT CNT\nFOR CNT = 1 TO 3 STEP 1\n$VEL_AXIS[CNT] = 20\nENDFOR\nEND\n")
    assert lower == upper


def test_system_variable_forms() -> None:
    module = parse_src(
        'DEF t()\n$VEL.CP = 0.2\n$TRACE.MODE = #T_START\n$TRACE.NAME[] = "x"\n$OV_PRO = 50\n'
        "$ACC_AXIS[6] = 100\nWAIT FOR $IN[3] == TRUE\nWAIT SEC 1.5E-1\nPTP $AXIS_ACT C_PTP\nEND\n"
    )
    body = module.main.body
    assert body[0] == Assign(Member(Name("$VEL"), "CP"), RealLit(0.2))
    assert body[1] == Assign(Member(Name("$TRACE"), "MODE"), EnumLit("T_START"))
    assert body[2] == Assign(Index(Member(Name("$TRACE"), "NAME"), ()), StrLit("x"))
    assert body[5] == WaitFor(Binary("==", Index(Name("$IN"), (IntLit(3),)), BoolLit(True)))
    assert body[6] == WaitSec(RealLit(0.15))
    assert body[7] == Motion("PTP", Name("$AXIS_ACT"), "C_PTP")


def test_operator_priorities_follow_krl() -> None:
    # comparisons bind loosest in KRL; NOT binds tightest; * before +; AND before EXOR before OR
    assert parse_expression("1 + 2 * 3") == Binary("+", IntLit(1), Binary("*", IntLit(2), IntLit(3)))
    assert parse_expression("a OR b AND c") == Binary("OR", Name("A"), Binary("AND", Name("B"), Name("C")))
    assert parse_expression("NOT a AND b") == Binary("AND", Unary("NOT", Name("A")), Name("B"))
    assert parse_expression("x > 1 AND y") == Binary(">", Name("X"), Binary("AND", IntLit(1), Name("Y")))
    assert parse_expression("a - b - c") == Binary("-", Binary("-", Name("A"), Name("B")), Name("C"))
    assert parse_expression("'B101' + 'H1F'") == Binary("+", IntLit(5), IntLit(31))
    assert format_expr(parse_expression("a - (b - c)")) == "A - (B - C)"


def test_value_strings_parse_as_expressions() -> None:
    value = parse_expression("{E6POS: X 1339.9, Y -15.9, Z 1787.3, A 0.0, B 89.99, C -0.68, S 6, T 19}")
    assert isinstance(value, Aggregate) and value.get("Y") == RealLit(-15.9) and value.get("S") == IntLit(6)
    nested = parse_expression("{M -1.0, CM {X 0.0, Y 0.0, Z 0.0, A 0.0, B 0.0, C 0.0}, J {X 0.0, Y 0.0, Z 0.0}}")
    assert isinstance(nested, Aggregate) and isinstance(nested.get("CM"), Aggregate)


@pytest.mark.parametrize(
    ("source", "line", "column", "fragment"),
    [
        ("DEF a()\n  x = \nEND\n", 2, 7, "expected an expression"),
        ("DEF a()\n  PTP {A1 0, A2 -90\nEND\n", 2, 20, "expected '}'"),
        ("DEF a()\n  IF x THEN\n    y = 1\nEND\n", 4, 1, "unexpected END"),
        ("DEF a()\n  FOR i = 1 10\n  ENDFOR\nEND\n", 2, 13, "expected TO"),
        ('DEF a()\n  $TRACE.NAME[] = "abc\nEND\n', 2, 19, "unterminated string"),
        ("DEF a()\n  x = 1\n  DECL INT y\nEND\n", 3, 3, "declarations must come before"),
        ("DEF a()\n  WAIT 3\nEND\n", 2, 8, "expected SEC or FOR"),
        ("DEF a()\n  x = 1 ? 2\nEND\n", 2, 9, "unexpected character"),
        ("DEF a()\n  5 = x\nEND\n", 2, 3, "expected a statement"),
        ("DEF a()\n  x + 1 = 2\nEND\n", 2, 5, "expected '=' or a call"),
        ("DEF a()\n  PTP {A1 0, A1 1}\nEND\n", 2, 14, "given twice"),
        ("DEF a()\n  x = 1\n", 3, 1, "expected END before the end of the file"),
        ("DEFDAT d\n  x = 1\nENDDAT\n", 2, 3, "expected a declaration"),
        ("DEFDAT d\n  DECL INT x[0]\nENDDAT\n", 2, 14, "positive array size"),
        ("DEF a()\nEND\nDEF a()\nEND\n", 3, 1, "defined twice"),
        ("\n\n", 3, 1, "no routine"),
        ("DEF a()\n  x = 12abc\nEND\n", 2, 7, "malformed number"),
    ],
)
def test_errors_name_file_line_and_column(source: str, line: int, column: int, fragment: str) -> None:
    with pytest.raises(KrlSyntaxError) as caught:
        parse(source, "bad.src")
    err = caught.value
    assert (err.file, err.line, err.column) == ("bad.src", line, column), str(err)
    assert fragment in str(err)
    assert str(err).startswith(f"bad.src:{line}:{column}: ")


def test_deep_nesting_is_a_syntax_error_not_a_crash() -> None:
    with pytest.raises(KrlSyntaxError, match="nested deeper"):
        parse_expression("(" * 500 + "1" + ")" * 500)
    with pytest.raises(KrlSyntaxError, match="nested deeper"):
        parse_expression("-" * 500 + "x")
    deep = "DEF a()\n" + "LOOP\n" * 200 + "ENDLOOP\n" * 200 + "END\n"
    with pytest.raises(KrlSyntaxError, match="nested deeper"):
        parse_src(deep)


def test_parse_dispatches_on_first_keyword_and_dat_rejects_trailing_text() -> None:
    assert isinstance(parse("&ACCESS RV\nDEFDAT x\nENDDAT\n"), DataList)
    with pytest.raises(KrlSyntaxError, match="after ENDDAT"):
        parse_dat("DEFDAT x\nENDDAT\nDEF a()\nEND\n")


def test_reading_stops_at_a_deadline_that_has_passed() -> None:
    """The interlock's budget counts from the first byte: the lexer and the parser look at the caller's deadline
    (issue #31: a 7.8 MB program took 96 s to read before the check's budget even started)."""
    import time

    from rgse_daemon.krl.lexer import OutOfTime, tokenize
    from rgse_daemon.krl.parser import parse_dat, parse_src

    src = "DEF big( )\n" + "  X = 1\n" * 5000 + "END\n"
    past = time.monotonic() - 1.0
    with pytest.raises(OutOfTime) as exc:
        tokenize(src, "big.src", past)
    assert 0 < exc.value.line <= 5002
    with pytest.raises(OutOfTime):
        parse_src(src, "big.src", past)
    with pytest.raises(OutOfTime):
        parse_dat("DEFDAT big\n" + "  DECL INT X = 1\n" * 5000 + "ENDDAT\n", "big.dat", past)
    assert len(parse_src(src, "big.src", time.monotonic() + 600.0).main.body) == 5000  # a deadline ahead: read
