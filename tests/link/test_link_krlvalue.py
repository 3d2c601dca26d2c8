"""KRL value strings: the examples of docs/controller.md §4, round trips of generated values, garbage →
ProtocolError."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import ProtocolError
from rgse_daemon.link.krlvalue import KrlBits, KrlEnum, KrlStruct, format_value, parse_value

AXIS = "{E6AXIS: A1 0.0, A2 -90.0, A3 90.0, A4 0.0, A5 0.0, A6 0.0, E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}"
POS = (
    "{E6POS: X 1339.90503, Y 15.9216757, Z 1787.32227, A 0.0, B 89.9999466, C -0.680795908, S 6, T 19, "
    "E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}"
)
LOAD = "{M -1.0, CM {X 0.0, Y 0.0, Z 0.0, A 0.0, B 0.0, C 0.0}, J {X 0.0, Y 0.0, Z 0.0}}"


def test_examples_from_kuka_facts() -> None:
    axis = parse_value(AXIS)
    assert isinstance(axis, KrlStruct)
    assert axis.type_name == "E6AXIS"
    assert [axis[f"A{i}"] for i in range(1, 7)] == [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
    pos = parse_value(POS)
    assert pos["X"] == 1339.90503 and pos["S"] == 6 and isinstance(pos["S"], int)
    load = parse_value(LOAD)
    assert load.type_name is None and load["M"] == -1.0 and load["CM"]["C"] == 0.0 and load["J"]["Z"] == 0.0
    assert parse_value("#T1") == KrlEnum("T1")
    assert parse_value("100") == 100
    assert parse_value("TRUE") is True and parse_value("false") is False
    assert parse_value("B100000") == KrlBits("100000")
    assert parse_value("-1320.46") == -1320.46
    assert parse_value('"12_ms_v2.xml"') == "12_ms_v2.xml"
    assert parse_value("1.5E-05") == 1.5e-05
    assert parse_value("  #P_ACTIVE ") == KrlEnum("P_ACTIVE")
    for text in (AXIS, POS, LOAD, "#T1", "B100000", '"12_ms_v2.xml"', "TRUE", "-1320.46", "318"):
        assert format_value(parse_value(text)) == text


def test_struct_is_a_mapping_in_wire_order() -> None:
    s = KrlStruct.of("FRAME", X=1.0, Y=2.0, Z=3.0)
    assert list(s) == ["X", "Y", "Z"] and dict(s) == {"X": 1.0, "Y": 2.0, "Z": 3.0}
    assert format_value(s) == "{FRAME: X 1.0, Y 2.0, Z 3.0}"
    assert format_value(KrlStruct(None, ())) == "{}"
    with pytest.raises(KeyError):
        s["A"]


def test_formatting_reals_keeps_them_real() -> None:
    assert format_value(1e-5) == "1.0E-05"
    assert format_value(1e16) == "1.0E+16"
    assert isinstance(parse_value(format_value(3.0)), float)
    assert isinstance(parse_value(format_value(3)), int)


@pytest.mark.parametrize(
    "bad",
    [
        "",
        "   ",
        "{",
        "{X}",
        "{X 1,}",
        "{X 1 Y 2}",
        '"open',
        "#",
        "#1A",
        "B102",
        "TRU",
        "1.0.0",
        "{A: B}",
        "{X 1, X 2}",
        "1e999",
        "12abc",
        "{E6AXIS: A1 0.0",
        "}",
        "[1]",
        "{" * 40 + "}" * 40,
        "TRUE FALSE",
        "9" * 5000,  # beyond int()'s 4300 digits: a ValueError escaped the parser once
        "-" + "1" * 4301,
    ],
)
def test_garbage_is_protocol_error(bad: str) -> None:
    with pytest.raises(ProtocolError):
        parse_value(bad)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), 'say "hi"', object(), [1], KrlStruct])
def test_unformattable_is_protocol_error(bad: object) -> None:
    with pytest.raises(ProtocolError):
        format_value(bad)  # type: ignore[arg-type]


def test_bad_names_rejected_at_construction() -> None:
    with pytest.raises(ProtocolError):
        KrlEnum("T 1")
    with pytest.raises(ProtocolError):
        KrlBits("012")
    with pytest.raises(ProtocolError):
        KrlStruct.of("E6 AXIS")
    with pytest.raises(ProtocolError):
        KrlStruct(None, (("X", 1), ("X", 2)))


ident = st.from_regex(r"[A-Za-z_$][A-Za-z0-9_$]{0,8}", fullmatch=True)
leaf = st.one_of(
    st.booleans(),
    st.integers(-(2**31), 2**31 - 1),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=20).filter(lambda s: '"' not in s),
    ident.map(KrlEnum),
    st.from_regex(r"[01]{1,16}", fullmatch=True).map(KrlBits),
)


def _structs(children):
    fields = st.dictionaries(ident, children, max_size=6).map(lambda d: tuple(d.items()))
    return st.builds(KrlStruct, st.one_of(st.none(), ident), fields)


values = st.recursive(leaf, _structs, max_leaves=20)


@settings(max_examples=300, deadline=None)
@given(values)
def test_round_trip(value) -> None:
    text = format_value(value)
    back = parse_value(text)
    assert back == value
    assert type(back) is type(value)
    assert format_value(back) == text


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet='{}:, "#.-+eE01B9XAT\t', max_size=40))
def test_fuzz_parse_only_raises_protocol_error(text: str) -> None:
    try:
        value = parse_value(text)
    except ProtocolError:
        return
    assert parse_value(format_value(value)) == value
