"""The real CraneScale client against the simulated Kern scale, on a pty and over socket://."""

from __future__ import annotations

import asyncio
import math
import os
import threading
import time
import tty

import pytest
import serial
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from rgse_daemon.config import UNIT_TO_KG, ScaleConfig
from rgse_daemon.io import IoFrameError, IoLinkError, IoTimeout
from rgse_daemon.io.scale import CraneScale, parse_line, xor8
from simulators.scale import ScaleSim, ScaleSimConfig, display_step
from tests.support.polling import wait_until

D_KG = 0.1  # Kern HFB 300K100
TRANSPORTS = ["pty", "tcp"]


def client_cfg(sim: ScaleSim, **overrides: object) -> ScaleConfig:
    values: dict[str, object] = {"port": sim.url, "request_interval_s": 0.05, "resolution_kg": D_KG}
    values.update(overrides)
    return ScaleConfig.model_validate(values)


# --- parsing -------------------------------------------------------------------------------------------------
CFG = ScaleConfig()


@pytest.mark.parametrize(
    ("line", "stable", "mass_kg"),
    [
        ("ST,GS,+     117.6 kg", True, 117.6),
        ("US,GS,+     119.3 kg", False, 119.3),
        ("ST,NT,-       2.5 kg", True, -2.5),
        ("ST,GS,+1.000KG", True, 1.0),
        ("ST,GS,+    117600  g", True, 117.6),
        ("ST,GS,+    0.1176  t", True, 117.6),
        ("ST,GS,+     259.2 lb", True, 259.2 * 0.45359237),
    ],
)
def test_parse_good_lines(line: str, stable: bool, mass_kg: float) -> None:
    frame = parse_line(line, CFG, "scale X")
    assert frame.stable is stable
    assert frame.mass_kg == pytest.approx(mass_kg, abs=1e-9)
    assert frame.raw_line == line


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("ST,GS,+  \x00117.6 kg", "non-printable"),
        ("ST,GS,+  117.6 k\xe9", "non-printable"),
        ("ST,GS,+     117.6", "does not match"),
        ("ST,GS,+     11", "does not match"),
        ("ST,GS,+     117.", "does not match"),
        ("ST,GS,+     117.6 pcs", "unknown unit"),
        ("ST,GS,+     117.6 k", "unknown unit"),
        ("XX,GS,+     117.6 kg", "does not match"),
        ("OL,GS,+            ", "overload"),
        ("", "does not match"),
    ],
)
def test_parse_bad_lines_name_device_and_line(line: str, problem: str) -> None:
    with pytest.raises(IoFrameError) as err:
        parse_line(line, CFG, "scale /dev/ttyS9")
    assert problem in str(err.value)
    assert err.value.device == "scale /dev/ttyS9" and err.value.raw == line
    assert str(err.value).startswith("scale /dev/ttyS9: ") and repr(line) in str(err.value)


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("ST nan kg", "not a decimal number"),
        ("ST inf kg", "not a decimal number"),
        ("ST -Infinity kg", "not a decimal number"),
        ("ST 1_000 kg", "not a decimal number"),
        ("ST 1e999 kg", "not a decimal number"),
        ("ST " + "9" * 400 + " kg", "out of range"),
        ("ST kg", "not a decimal number"),  # the value group left out
        ("ST 117.6", "no unit"),  # the unit group left out
    ],
)
def test_a_loose_line_regex_still_takes_only_decimal_numbers(line: str, problem: str) -> None:
    # a dialect whose value group takes any non-blank text and whose groups are optional: what float() would take,
    # or nothing at all, is not a weight
    cfg = ScaleConfig(line_regex=r"^(?P<stab>ST|US) *(?P<value>[^ k]+)? *(?P<unit>kg)?$")
    with pytest.raises(IoFrameError, match=problem) as err:
        parse_line(line, cfg, "scale X")
    assert err.value.raw == line
    assert parse_line("ST 117.6 kg", cfg, "scale X").mass_kg == pytest.approx(117.6)


def test_parse_checksum() -> None:
    cfg = ScaleConfig(checksum="xor8")
    body = "ST,GS,+     117.6 kg"
    good = f"{body}*{xor8(body.encode()):02X}"
    assert parse_line(good, cfg, "s").mass_kg == pytest.approx(117.6)
    for bad, problem in [
        (body, "missing"),
        (f"{body}*ZZ", "not hexadecimal"),
        (f"{body.replace('6', '8')}*{xor8(body.encode()):02X}", "checksum mismatch"),
    ]:
        with pytest.raises(IoFrameError, match=problem):
            parse_line(bad, cfg, "s")


@given(
    mass_kg=st.floats(-50.0, 600.0, allow_nan=False),
    unit=st.sampled_from(sorted(UNIT_TO_KG)),
    seed=st.integers(0, 1000),
)
def test_simulated_stable_frames_parse_within_d(mass_kg: float, unit: str, seed: int) -> None:
    sim = ScaleSim(ScaleSimConfig(true_mass_kg=mass_kg, unit=unit, settle_s=0.0, seed=seed))  # type: ignore[arg-type]
    line = sim.frame_line()
    assert line.endswith(b"\r\n")
    frame = parse_line(line[:-2].decode(), CFG, "sim")
    assert frame.stable and frame.unit == unit
    assert abs(frame.mass_kg - mass_kg) <= D_KG + 1e-9


def test_display_steps() -> None:
    assert display_step(0.1, "kg") == pytest.approx(0.1)
    assert display_step(0.1, "g") == pytest.approx(100.0)
    assert display_step(0.1, "t") == pytest.approx(1e-4)
    assert display_step(0.1, "lb") == pytest.approx(0.2)


@pytest.mark.parametrize(
    "bad",
    [
        {"line_regex": r"^(?P<value>\d+)$"},  # no unit group
        {"line_regex": r"^(?P<value>[$"},
        {"resolution_kg": 0.0},
        {"mode": "poll"},
        {"baud": 9600},
    ],
)
def test_bad_scale_config_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        ScaleConfig.model_validate(bad)


def test_uncertainty_from_resolution() -> None:
    assert ScaleConfig(resolution_kg=0.1).u_kg == pytest.approx(0.1 / math.sqrt(3))


# --- end to end ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize(("mode", "cmd"), [("request", "S"), ("request", "W"), ("stream", "S")])
async def test_stable_reading_within_d_of_truth(transport: str, mode: str, cmd: str) -> None:
    sim_cfg = ScaleSimConfig(true_mass_kg=117.63, settle_s=0.1, stream_period_s=0.01 if mode == "stream" else None)
    async with ScaleSim(sim_cfg, transport) as sim:  # type: ignore[arg-type]
        async with CraneScale(client_cfg(sim, mode=mode, request_cmd=cmd)) as scale:
            for _ in range(3):
                weighing = await scale.read_stable(timeout_s=10.0)
                assert weighing.stable
                assert abs(weighing.mass_kg - 117.63) <= D_KG
                assert weighing.u_kg == pytest.approx(D_KG / math.sqrt(3))
                assert weighing.raw_line.startswith("ST,GS,+") and weighing.time_utc.tzinfo is not None
            assert scale.counters.bad_frames == 0 and scale.counters.opens == 1
        if mode == "request":
            assert sim.requests >= 3
        else:
            assert sim.requests == 0  # continuous output: the client never writes


@pytest.mark.parametrize("transport", TRANSPORTS)
async def test_unstable_then_stable_after_a_new_load(transport: str) -> None:
    sim_cfg = ScaleSimConfig(true_mass_kg=10.0, settle_s=1.0, stream_period_s=0.01)
    async with ScaleSim(sim_cfg, transport) as sim:  # type: ignore[arg-type]
        async with CraneScale(client_cfg(sim, mode="stream", stable_frames_required=3)) as scale:
            first = await scale.read_stable(timeout_s=10.0)
            assert abs(first.mass_kg - 10.0) <= D_KG
            sim.set_mass(107.3)
            unstable_before = scale.counters.unstable_frames
            frame = await scale.read_frame(timeout_s=10.0)
            assert not frame.stable  # right after hanging the load it swings
            second = await scale.read_stable(timeout_s=10.0)
            assert abs(second.mass_kg - 107.3) <= D_KG
            assert scale.counters.unstable_frames > unstable_before
            assert scale.counters.stable_frames >= 6


@pytest.mark.parametrize("transport", TRANSPORTS)
async def test_garbled_frames_are_counted_and_skipped(transport: str) -> None:
    sim_cfg = ScaleSimConfig(true_mass_kg=117.6, settle_s=0.05, stream_period_s=0.005, garble_rate=0.4, seed=7)
    async with ScaleSim(sim_cfg, transport) as sim:  # type: ignore[arg-type]
        async with CraneScale(client_cfg(sim, mode="stream", stable_frames_required=5)) as scale:
            for _ in range(3):
                weighing = await scale.read_stable(timeout_s=10.0)
                assert abs(weighing.mass_kg - 117.6) <= D_KG
            assert sim.garbled_sent > 0
            assert scale.counters.bad_frames > 0
            err = scale.last_error
            assert isinstance(err, IoFrameError) and err.device == f"scale {sim.url}" and err.raw


async def test_garbled_frames_caught_by_checksum() -> None:
    sim_cfg = ScaleSimConfig(settle_s=0.0, stream_period_s=0.005, garble_rate=0.5, checksum=True, seed=3)
    async with ScaleSim(sim_cfg, "tcp") as sim:
        async with CraneScale(client_cfg(sim, mode="stream", checksum="xor8", stable_frames_required=5)) as scale:
            weighing = await scale.read_stable(timeout_s=10.0)
            assert abs(weighing.mass_kg - 117.6) <= D_KG and "*" in weighing.raw_line
            assert scale.counters.bad_frames > 0


@pytest.mark.parametrize("transport", TRANSPORTS)
async def test_only_garbage_raises_frame_error_naming_port_and_line(transport: str) -> None:
    sim_cfg = ScaleSimConfig(settle_s=0.0, stream_period_s=0.005, garble_rate=1.0)
    async with ScaleSim(sim_cfg, transport) as sim:  # type: ignore[arg-type]
        async with CraneScale(client_cfg(sim, mode="stream", max_consecutive_bad_frames=5)) as scale:
            with pytest.raises(IoFrameError) as err:
                await scale.read_stable(timeout_s=10.0)
            assert "5 bad frames in a row" in str(err.value)
            assert err.value.device == f"scale {sim.url}" and repr(err.value.raw) in str(err.value)
            assert str(err.value).count(repr(err.value.raw)) == 1


@pytest.mark.parametrize("transport", TRANSPORTS)
@pytest.mark.parametrize("mode", ["request", "stream"])
async def test_timeout_when_never_stable(transport: str, mode: str) -> None:
    sim_cfg = ScaleSimConfig(never_stable=True, stream_period_s=0.01 if mode == "stream" else None)
    async with ScaleSim(sim_cfg, transport) as sim:  # type: ignore[arg-type]
        async with CraneScale(client_cfg(sim, mode=mode, request_cmd="S")) as scale:
            with pytest.raises(IoTimeout) as err:
                await scale.read_stable(timeout_s=1.0)
            assert "no stable weighing within 1.0 s" in str(err.value) and str(err.value).startswith("scale ")
            assert scale.counters.timeouts == 1 and scale.counters.stable_frames == 0
            if mode == "stream":
                assert scale.counters.unstable_frames > 0  # frames came, none of them stable
                frame = await scale.read_frame(timeout_s=5.0)  # the port survives a timeout
                assert not frame.stable
            else:
                assert sim.requests >= 2  # the S request was repeated; a real scale stays silent while unstable


@pytest.mark.parametrize("unit", ["g", "t", "lb"])
async def test_unit_conversion_end_to_end(unit: str) -> None:
    sim_cfg = ScaleSimConfig(true_mass_kg=117.6, unit=unit, settle_s=0.0)  # type: ignore[arg-type]
    async with ScaleSim(sim_cfg, "pty") as sim, CraneScale(client_cfg(sim)) as scale:
        weighing = await scale.read_stable(timeout_s=10.0)
        assert weighing.raw_line.rstrip().endswith(unit)
        assert abs(weighing.mass_kg - 117.6) <= D_KG


async def test_peer_hang_up_is_a_link_error_and_the_port_reopens() -> None:
    sim_cfg = ScaleSimConfig(never_stable=True, stream_period_s=0.01)
    async with ScaleSim(sim_cfg, "tcp") as sim, CraneScale(client_cfg(sim, mode="stream")) as scale:
        await scale.read_frame(timeout_s=5.0)
        await sim.stop()
        with pytest.raises(IoLinkError, match="closed"):
            await scale.read_stable(timeout_s=5.0)
        with pytest.raises(IoLinkError, match="open"):  # reopening a closed server fails, as it should
            await scale.read_stable(timeout_s=5.0)
        assert scale.counters.opens == 1


async def test_non_ascii_bytes_are_recorded_as_sent() -> None:
    """A scale at 7E1 read as 8N1 sets the top bit of some characters: the bad line keeps those bytes (as \\xNN),
    not U+FFFD in their place, so that the event and the error show what came."""
    master, slave = os.openpty()
    tty.setraw(slave)
    cfg = ScaleConfig(port=os.ttyname(slave), mode="stream", max_consecutive_bad_frames=3)
    try:
        async with CraneScale(cfg) as scale:
            reading = asyncio.ensure_future(scale.read_stable(timeout_s=10.0))
            await asyncio.sleep(0.1)  # lines buffered before a read are not fresh
            os.write(master, b"ST,GS,+   117.6 k\xe7\r\n" * 3)
            with pytest.raises(IoFrameError, match="non-ASCII") as err:
                await reading
            assert err.value.raw == "ST,GS,+   117.6 k\\xe7" and "\\xe7" in str(err.value)
            assert scale.last_error is not None and scale.last_error.raw == err.value.raw
    finally:
        os.close(master)
        os.close(slave)


async def test_a_line_longer_than_max_line_bytes_is_a_bad_frame_also_when_it_comes_whole() -> None:
    """An over-long line is garbage whether it comes in pieces (cut by the reader) or whole in one chunk: a line
    that the scale's format allows, padded to 195 bytes and sent in one write over socket://, is not a weighing."""
    line = b"ST,GS,+" + b" " * 180 + b"117.6 kg\r\n"

    handlers: set[asyncio.Task[None]] = set()

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        handlers.add(asyncio.current_task())  # type: ignore[arg-type]
        try:
            await asyncio.sleep(0.2)  # lines buffered before a read are not fresh
            writer.write(line * 3)  # one write, one segment on loopback: each line arrives whole
            await writer.drain()
            await reader.read()  # until the client closes
        finally:
            writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    cfg = ScaleConfig(port=f"socket://127.0.0.1:{port}", mode="stream", max_consecutive_bad_frames=3,
                      max_line_bytes=64)
    try:
        async with CraneScale(cfg) as scale:
            with pytest.raises(IoFrameError, match="3 bad frames in a row, last: line of 195 bytes, longer than "
                                                   "max_line_bytes 64"):
                await scale.read_stable(timeout_s=10.0)
    finally:
        server.close()
        for task in handlers:  # (the loop must not end with a handler, and its writer, still open)
            task.cancel()
        await asyncio.gather(*handlers, return_exceptions=True)
        await server.wait_closed()


async def test_a_scale_that_stops_mid_line_is_a_timeout_naming_the_bytes_that_came() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        async with CraneScale(ScaleConfig(port=os.ttyname(slave), mode="stream")) as scale:
            reading = asyncio.ensure_future(scale.read_stable(timeout_s=1.0))
            await asyncio.sleep(0.1)
            os.write(master, b"US,GS,+   117.5 kg\r\nST,GS,+   11")
            with pytest.raises(IoTimeout) as err:
                await reading
            message = str(err.value)
            assert "1 unstable" in message and "last line 'US,GS,+   117.5 kg'" in message
            assert "then 12 bytes without a line end: 'ST,GS,+   11'" in message
    finally:
        os.close(master)
        os.close(slave)


async def test_missing_device_is_a_link_error() -> None:
    scale = CraneScale(ScaleConfig(port="/dev/does-not-exist-rgse"))
    with pytest.raises(IoLinkError) as err:
        await scale.read_stable(timeout_s=1.0)
    assert err.value.device == "scale /dev/does-not-exist-rgse"
    await scale.close()


async def test_a_hung_buffer_reset_on_open_is_a_timeout(monkeypatch: pytest.MonkeyPatch) -> None:
    """Opening includes dropping what the scale sent before: a driver that hangs there is an open timeout, not a
    read that never returns."""
    release = threading.Event()
    monkeypatch.setattr(serial.Serial, "reset_input_buffer", lambda self: release.wait(10.0))
    before = asyncio.all_tasks()
    async with ScaleSim(ScaleSimConfig(), "pty") as sim:  # (over socket:// there is no buffer to reset)
        scale = CraneScale(client_cfg(sim, open_timeout_s=0.2))
        t0 = time.monotonic()
        with pytest.raises(IoTimeout, match=r"open: not done within 0\.2 s"):
            await scale.read_stable(timeout_s=5.0)
        assert time.monotonic() - t0 < 5.0
        release.set()  # the driver comes back: the abandoned port's close can finish
        await scale.close()
    await wait_until(lambda: all(t.done() for t in asyncio.all_tasks() - before - {asyncio.current_task()}),
                     "the abandoned port closed")
