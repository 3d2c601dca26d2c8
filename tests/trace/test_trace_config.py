"""Trace configuration XML: parse, render, round trip, buffer limit and refusals."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import DataError
from rgse_daemon.trace.config import (
    SUPPORTED_RATES_US,
    TraceConfig,
    TraceModule,
    TraceTrigger,
    buffer_limit_s,
    parse_trace_config,
    render_trace_config,
)

KUKA_EXAMPLE = """<Trace><Time>600</Time><PreTrigger>0</PreTrigger><Basename>12_ms_v2</Basename>
  <Modules>
    <Module><Name>KRCIpo</Name><Rate>12000</Rate><Channel>500</Channel></Module>
    <Module><Name>NextGenDrive#3</Name><Rate>12000</Rate><Channel>1</Channel><Channel>202</Channel></Module>
  </Modules>
  <Trigger><ModuleName>KRCIpo</ModuleName><ID>1</ID></Trigger></Trace>"""


def test_parse_kuka_example() -> None:
    cfg = parse_trace_config(KUKA_EXAMPLE, "12_ms_v2.xml")
    assert cfg == TraceConfig(
        time_s=600.0,
        pretrigger_s=0.0,
        basename="12_ms_v2",
        modules=(TraceModule("KRCIpo", 12000, (500,)), TraceModule("NextGenDrive#3", 12000, (1, 202))),
        trigger=TraceTrigger("KRCIpo", 1),
    )
    assert cfg.modules[1].period_s == pytest.approx(0.012)
    assert parse_trace_config(render_trace_config(cfg)) == cfg


def test_buffer_limit() -> None:
    assert buffer_limit_s(0.012) == pytest.approx(600.0)
    assert buffer_limit_s(0.004) == pytest.approx(200.0)
    assert buffer_limit_s(0.001) == pytest.approx(50.0)
    with pytest.raises(ValueError):
        buffer_limit_s(0.0)


def test_render_layout() -> None:
    cfg = TraceConfig(12.5, 0.5, "dut_l01", (TraceModule("NextGenDrive#5", 4000, (1, 2, 3)),))
    text = render_trace_config(cfg)
    assert text.startswith('<?xml version="1.0" encoding="utf-8"?>\n<Trace>')
    assert "<Time>12.5</Time>" in text
    assert "<Rate>4000</Rate>" in text
    assert "<Trigger>" not in text
    assert parse_trace_config(text) == cfg


modules_st = st.lists(
    st.builds(
        TraceModule,
        name=st.sampled_from(["KRCIpo", *(f"NextGenDrive#{k}" for k in range(1, 7))]),
        rate_us=st.sampled_from(sorted(SUPPORTED_RATES_US)),
        channels=st.lists(st.integers(0, 999), min_size=1, max_size=8, unique=True).map(tuple),
    ),
    min_size=1,
    max_size=7,
    unique_by=lambda m: m.name,
).map(tuple)


@settings(max_examples=150, deadline=None)
@given(
    modules=modules_st,
    fraction=st.floats(0.001, 1.0),
    pre_fraction=st.floats(0.0, 1.0),
    basename=st.from_regex(r"[A-Za-z0-9_]{1,20}", fullmatch=True),
    with_trigger=st.booleans(),
)
def test_round_trip(modules, fraction: float, pre_fraction: float, basename: str, with_trigger: bool) -> None:
    time_s = buffer_limit_s(min(m.period_s for m in modules)) * fraction
    trigger = TraceTrigger(modules[0].name, 1) if with_trigger else None
    cfg = TraceConfig(time_s, time_s * pre_fraction, basename, modules, trigger)
    assert parse_trace_config(render_trace_config(cfg)) == cfg


def _with(old: str, new: str) -> str:
    assert old in KUKA_EXAMPLE
    return KUKA_EXAMPLE.replace(old, new)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("<Trace>", "not well-formed"),
        ("", "not well-formed"),
        ('<!DOCTYPE t [<!ENTITY a "b">]><Trace/>', "DTD or entity"),
        ('<?xml version="1.0"?><!doctype Trace SYSTEM "x.dtd"><Trace/>', "DTD or entity"),
        ("<Config/>", "root element must be <Trace>"),
        (_with("<Time>600</Time>", "<Time>601</Time>"), "exceeds the controller's trace buffer"),
        (_with("<Time>600</Time>", "<Time>-1</Time>"), "Time must be a positive"),
        (_with("<Time>600</Time>", "<Time>ten</Time>"), "Time is not a number"),
        (_with("<Time>600</Time>", "<Time>nan</Time>"), "Time is not finite"),
        (_with("<Time>600</Time>", ""), "exactly one <Time>"),
        (_with("<PreTrigger>0</PreTrigger>", "<PreTrigger>700</PreTrigger>"), "PreTrigger must be between"),
        (_with("<Rate>12000</Rate><Channel>500", "<Rate>4000</Rate><Channel>500"), r"buffer \(200 s at 4 ms\)"),
        (_with("<Rate>12000</Rate><Channel>500", "<Rate>2000</Rate><Channel>500"), "Rate 2000 µs is not offered"),
        (_with("<Rate>12000</Rate><Channel>500", "<Rate>12 ms</Rate><Channel>500"), "Rate is not an integer"),
        (_with("<Channel>500</Channel>", ""), "KRCIpo: no Channel"),
        (_with("<Channel>202</Channel>", "<Channel>1</Channel>"), "distinct"),
        (_with("<Channel>202</Channel>", "<Channel>x</Channel>"), "Channel is not an integer"),
        (_with("<Name>NextGenDrive#3</Name>", "<Name>KRCIpo</Name>"), "listed twice"),
        (_with("<ModuleName>KRCIpo</ModuleName>", "<ModuleName>Other</ModuleName>"), "not in Modules"),
        (_with("<Basename>12_ms_v2</Basename>", "<Basename>a/b</Basename>"), "Basename"),
        (_with("<Basename>12_ms_v2</Basename>", "<Basename>x</Basename><Colour>red</Colour>"), "<Colour>"),
        (_with("<Channel>500</Channel>", "<Channel>500</Channel><Gain>2</Gain>"), "<Gain> in <Module>"),
        (_with("<ID>1</ID>", "<ID>1</ID><ID>2</ID>"), "exactly one <ID>"),
    ],
)
def test_refusals(text: str, problem: str) -> None:
    with pytest.raises(DataError, match=problem) as info:
        parse_trace_config(text, "cfg/12_ms_v2.xml")
    assert str(info.value).startswith("cfg/12_ms_v2.xml: ")


def test_render_validates() -> None:
    too_long = TraceConfig(250.0, 0.0, "x", (TraceModule("NextGenDrive#3", 4000, (1,)),))
    with pytest.raises(DataError, match="exceeds"):
        render_trace_config(too_long)
