"""Property tests: random valid trees survive format → parse unchanged; random text never crashes the parser."""

from __future__ import annotations

import string

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import KrlSyntaxError
from rgse_daemon.krl import format_module, parse, parse_expression
from rgse_daemon.krl.ast import (
    APPROX_KINDS,
    BINARY_LEVELS,
    MOTION_KINDS,
    AggItem,
    Aggregate,
    Assign,
    Binary,
    BoolLit,
    Call,
    CallStmt,
    DataList,
    Decl,
    DeclName,
    EnumLit,
    Exit,
    Expr,
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
    Param,
    RealLit,
    Repeat,
    Return,
    Routine,
    Stmt,
    StrLit,
    Unary,
    WaitFor,
    WaitSec,
    While,
)
from rgse_daemon.krl.formatter import format_expr
from rgse_daemon.krl.parser import BUILTIN_TYPES, KEYWORDS

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

_FIRST = string.ascii_uppercase + "_$"
_REST = string.ascii_uppercase + string.digits + "_"
words = st.builds(lambda a, b: a + b, st.sampled_from(_FIRST), st.text(_REST, max_size=8))
#: Variable and routine names: no keywords and no type names (``INT X`` would read as a declaration).
names = words.filter(lambda w: w not in KEYWORDS and w not in BUILTIN_TYPES)
#: Member and aggregate field names may be any word, keywords included (``$TRACE.MODE``, ``{S 6, T 19}``).
fields = words
binary_ops = st.sampled_from([op for level in BINARY_LEVELS for op in level])

leaves = st.one_of(
    st.builds(IntLit, st.integers(-(2**31), 2**31 - 1)),
    st.builds(RealLit, st.floats(allow_nan=False, allow_infinity=False)),
    st.builds(BoolLit, st.booleans()),
    st.builds(StrLit, st.text(st.characters(blacklist_characters='"\r\n', blacklist_categories=["Cs"]), max_size=12)),
    st.builds(EnumLit, words),
    st.builds(Name, names),
)


def _aggregate(exprs: st.SearchStrategy[Expr]) -> st.SearchStrategy[Aggregate]:
    items = st.lists(st.tuples(fields, exprs), min_size=1, max_size=4, unique_by=lambda t: t[0])
    return st.builds(Aggregate, st.none() | names, items.map(lambda its: tuple(AggItem(n, v) for n, v in its)))


def _extend(exprs: st.SearchStrategy[Expr]) -> st.SearchStrategy[Expr]:
    calls = st.builds(Call, names, st.lists(exprs, max_size=3).map(tuple))
    # what Index and Member may apply to (a name, a call, an index or member of those), built directly rather than
    # filtered out of all expressions: a filter rejects most draws and trips Hypothesis' filter_too_much check
    # (their own subscripts and arguments are leaves, keeping the expressions small)
    small = st.lists(leaves, max_size=2).map(tuple)
    chains = st.recursive(
        st.builds(Name, names) | st.builds(Call, names, small),
        lambda c: st.builds(Index, c, small) | st.builds(Member, c, fields),
        max_leaves=2,
    )
    return st.one_of(
        st.builds(Unary, st.sampled_from(["-", "+", "NOT", "B_NOT"]), exprs),
        st.builds(Binary, binary_ops, exprs, exprs),
        _aggregate(exprs),
        calls,
        st.builds(Index, chains, st.lists(exprs, max_size=3).map(tuple)),
        st.builds(Member, chains, fields),
    )


expressions = st.recursive(leaves, _extend, max_leaves=8)
#: Statements hold smaller expressions, keeping generated programs (and Hypothesis' reprs of them) small.
small_expressions = st.recursive(leaves, _extend, max_leaves=3)
targets = st.recursive(
    st.builds(Name, names),
    lambda inner: (
        st.builds(Index, inner, st.lists(small_expressions, max_size=2).map(tuple)) | st.builds(Member, inner, fields)
    ),
    max_leaves=3,
)
decl_names = st.builds(DeclName, names, st.lists(st.integers(1, 64), max_size=2).map(tuple))


@st.composite
def declarations(draw: st.DrawFn) -> Decl:
    decl_list = draw(st.lists(decl_names, min_size=1, max_size=3))
    init = draw(st.none() | small_expressions) if len(decl_list) == 1 else None
    return Decl(draw(names), tuple(decl_list), init, draw(st.booleans()), draw(st.booleans()))


simple_statements = st.one_of(
    st.builds(Assign, targets, small_expressions),
    st.builds(Motion, st.sampled_from(MOTION_KINDS), small_expressions, st.none() | st.sampled_from(APPROX_KINDS)),
    st.builds(WaitSec, small_expressions),
    st.builds(WaitFor, small_expressions),
    st.builds(Exit),
    st.builds(Halt),
    st.builds(Return, st.none() | small_expressions),
    st.builds(CallStmt, names, st.lists(small_expressions, max_size=3).map(tuple)),
)


def _compound(stmts: st.SearchStrategy[Stmt]) -> st.SearchStrategy[Stmt]:
    bodies = st.lists(stmts, max_size=3).map(tuple)
    return st.one_of(
        st.builds(For, names, small_expressions, small_expressions, st.none() | small_expressions, bodies),
        st.builds(If, small_expressions, bodies, bodies),
        st.builds(While, small_expressions, bodies),
        st.builds(Repeat, bodies, small_expressions),
        st.builds(Loop, bodies),
    )


statements = st.recursive(simple_statements, _compound, max_leaves=6)


@st.composite
def routines(draw: st.DrawFn) -> Routine:
    decls = draw(st.lists(declarations(), max_size=2))
    body = draw(st.lists(statements, max_size=5))
    params = draw(st.lists(st.builds(Param, names, st.sampled_from([None, "IN", "OUT"])), max_size=3))
    return Routine(draw(names), tuple(params), (*decls, *body), draw(st.none() | names), draw(st.booleans()))


headers = st.lists(
    st.text(st.characters(min_codepoint=33, max_codepoint=126), max_size=15).map(lambda s: "&" + s), max_size=3
).map(tuple)
modules = st.builds(
    Module, st.lists(routines(), min_size=1, max_size=3, unique_by=lambda r: r.name).map(tuple), headers
)
data_lists = st.builds(DataList, names, st.lists(declarations(), max_size=5).map(tuple), st.booleans(), headers)


@SETTINGS
@given(expressions)
def test_expressions_round_trip(expr: Expr) -> None:
    text = format_expr(expr)
    assert parse_expression(text) == expr, text


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(modules)
def test_modules_round_trip(module: Module) -> None:
    text = format_module(module)
    assert parse(text, "gen.src") == module, text


@SETTINGS
@given(data_lists)
def test_data_lists_round_trip(data: DataList) -> None:
    text = format_module(data)
    assert parse(text, "gen.dat") == data, text


_SOUP = [
    "DEF",
    "END",
    "DEFFCT",
    "ENDFCT",
    "DEFDAT",
    "ENDDAT",
    "DECL",
    "GLOBAL",
    "INT",
    "REAL",
    "E6AXIS",
    "IF",
    "THEN",
    "ELSE",
    "ENDIF",
    "FOR",
    "TO",
    "STEP",
    "ENDFOR",
    "LOOP",
    "ENDLOOP",
    "WHILE",
    "ENDWHILE",
    "REPEAT",
    "UNTIL",
    "EXIT",
    "WAIT",
    "SEC",
    "HALT",
    "RETURN",
    "PTP",
    "PTP_REL",
    "LIN",
    "C_PTP",
    "NOT",
    "AND",
    "OR",
    "TRUE",
    "x",
    "$VEL",
    "$VEL_AXIS",
    "a1",
    "#T_START",
    '"s"',
    '"',
    "1",
    "-2.5",
    "1E3",
    "'B101'",
    "'H1G'",
    "(",
    ")",
    "[",
    "]",
    "{",
    "}",
    ",",
    ":",
    ".",
    "=",
    "==",
    "<>",
    "+",
    "-",
    "*",
    "/",
    ";c",
    "&ACCESS RVP",
    "\n",
    "\n",
    "\n",
    "?",
    "@",
    "12ab",
]


@SETTINGS
@given(st.lists(st.sampled_from(_SOUP), max_size=60), st.sampled_from([" ", "", "\n"]))
def test_token_soup_parses_or_raises_syntax_error(tokens: list[str], sep: str) -> None:
    text = sep.join(tokens)
    try:
        tree = parse(text, "soup.src")
    except KrlSyntaxError as err:
        assert err.file == "soup.src" and err.line >= 1 and err.column >= 1
    else:
        assert parse(format_module(tree)) == tree


@SETTINGS
@given(st.text(max_size=200))
def test_arbitrary_text_parses_or_raises_syntax_error(text: str) -> None:
    for parser in (parse, parse_expression):
        try:
            parser(text, "text.src")
        except KrlSyntaxError:
            pass
