"""The real SafetyIo client against the real pymodbus simulator over TCP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import struct
from collections.abc import AsyncIterator, Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from rgse_daemon.config import ModbusConfig
from rgse_daemon.io import IoDeviceRefused, IoLinkError
from rgse_daemon.io.modbus import ConnectionState, LightColor, SafetyIo, backoff_s
from rgse_daemon.safety.inputs import SafetyInputs
from simulators.modbus_io import ModbusIoSim
from tests.support.iodev import fast_cfg
from tests.support.polling import wait_until


async def test_inputs_seen_by_client(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        await wait_until(lambda: io.inputs.valid, what="first reading")
        assert not io.inputs.safe  # the simulator starts with every input off
        modbus_sim.set_input("area_cleared", True)
        await wait_until(lambda: io.inputs.area_cleared, what="area cleared")
        assert not io.inputs.aut_permitted and not io.inputs.estop_ok and not io.inputs.safe
        modbus_sim.set_input("aut_permitted", True)
        modbus_sim.set_input("estop_ok", True)
        await wait_until(lambda: io.inputs.safe, what="all safe")
        assert io.inputs.reason == ""
        modbus_sim.set_input("estop_ok", False)
        await wait_until(lambda: not io.inputs.estop_ok, what="E-stop pressed")
        assert io.inputs.valid and not io.inputs.safe
        assert io.counters.reads > 0 and io.counters.read_errors == 0 and io.counters.connects == 1


async def test_inputs_on_coils_with_custom_addresses() -> None:
    cfg = fast_cfg(
        502,  # the register map is what matters here; the port is set once the simulator is bound
        input_table="coils",
        inputs={"area_cleared": 40, "aut_permitted": 17, "estop_ok": 33},
        outputs={"light_green": 8, "light_yellow": 2, "light_red": 5, "running": 0},
    )
    async with ModbusIoSim(cfg) as sim:
        sim.set_input("aut_permitted", True)
        sim.set_input("estop_ok", True)
        async with SafetyIo(cfg.model_copy(update={"port": sim.port})) as io:
            await wait_until(lambda: io.inputs.valid, what="first reading")
            assert (io.inputs.area_cleared, io.inputs.aut_permitted, io.inputs.estop_ok) == (False, True, True)
            await io.set_light(LightColor.RED)  # non-contiguous light coils: written one by one
            assert sim.light == "red"
            assert sim.coils[8] is False and sim.coils[2] is False and sim.coils[5] is True
            # writing outputs did not disturb the inputs living in the same table
            await wait_until(lambda: io.counters.reads >= 3, what="more readings")
            assert (io.inputs.area_cleared, io.inputs.aut_permitted, io.inputs.estop_ok) == (False, True, True)


async def test_outputs_seen_by_simulator(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        await wait_until(lambda: io.state is ConnectionState.CONNECTED, what="connected")
        for color in (LightColor.GREEN, LightColor.YELLOW, LightColor.RED, LightColor.OFF):
            await io.set_light(color)
            assert modbus_sim.light == color.value
        assert not modbus_sim.running
        await io.set_running(True)
        assert modbus_sim.running and modbus_sim.light == "off"
        await io.set_running(False)
        assert not modbus_sim.running
        assert io.outputs == (LightColor.OFF, False) and io.outputs_confirmed
        assert io.counters.write_errors == 0 and io.counters.writes >= 12


async def test_changes_iterator_reports_each_change(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io, io.changes() as changes:
        first = await anext(changes)
        assert not first.safe  # before the first reading: "no reading yet"
        seen: list[SafetyInputs] = []
        modbus_sim.set_all_inputs(True)
        async for item in changes:
            seen.append(item)
            if item.safe:
                break
        modbus_sim.set_input("area_cleared", False)
        item = await anext(changes)
        assert item.valid and not item.area_cleared and item.aut_permitted and item.estop_ok
        assert all(a.key() != b.key() for a, b in itertools.pairwise(seen))


async def test_changes_iterator_ends_on_stop(modbus_sim: ModbusIoSim) -> None:
    io = SafetyIo(fast_cfg(modbus_sim.port))
    await io.start()
    changes = io.changes()
    await anext(changes)
    await io.stop()
    with pytest.raises(StopAsyncIteration):
        while True:
            await anext(changes)
    assert io.state is ConnectionState.STOPPED and not io.inputs.safe


async def test_link_loss_is_unsafe_within_a_bounded_number_of_polls(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        modbus_sim.set_all_inputs(True)
        await wait_until(lambda: io.inputs.safe, what="all safe")
        polls_before = io.counters.reads + io.counters.read_errors
        await modbus_sim.stop()
        await wait_until(lambda: not io.inputs.safe, what="unsafe after link loss")
        # unsafe no later than the first poll that could not reach the module, long before staleness
        assert io.counters.reads + io.counters.read_errors - polls_before <= 2
        assert io.inputs.reason.startswith("link lost"), io.inputs.reason
        assert (io.inputs.area_cleared, io.inputs.aut_permitted, io.inputs.estop_ok) == (False, False, False)
        with pytest.raises(IoLinkError) as err:
            await io.set_light(LightColor.RED)
        assert err.value.device == io.name


async def test_reconnect_after_simulator_restart_reapplies_outputs(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        modbus_sim.set_all_inputs(True)
        await wait_until(lambda: io.inputs.safe, what="all safe")
        await io.set_light(LightColor.YELLOW)
        await io.set_running(True)
        await modbus_sim.stop()
        await wait_until(lambda: io.state is ConnectionState.DISCONNECTED, what="disconnected")
        await wait_until(lambda: io.counters.connects == 1 and io.inputs.reason != "", what="doubt")
        await modbus_sim.start()  # a rebooted module: same port, outputs off
        assert modbus_sim.light == "off"
        await wait_until(lambda: io.inputs.safe, what="safe again after the restart")
        assert io.counters.reconnects >= 1 and io.counters.connects >= 2
        await wait_until(lambda: modbus_sim.light == "yellow" and modbus_sim.running, what="outputs re-applied")


async def test_dropped_connection_reconnects(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        modbus_sim.set_all_inputs(True)
        await wait_until(lambda: io.inputs.safe, what="all safe")
        modbus_sim.drop_connections()
        await wait_until(lambda: io.counters.reconnects >= 1 and io.inputs.safe, what="reconnected and safe")


async def test_mute_module_reads_stale_before_the_request_times_out(modbus_sim: ModbusIoSim) -> None:
    # a long request deadline: the poller hangs in its read, so only the staleness check can flag the doubt
    cfg = fast_cfg(modbus_sim.port, request_timeout_s=20.0, stale_after_polls=3)
    async with SafetyIo(cfg) as io, io.changes() as changes:
        modbus_sim.set_all_inputs(True)
        async for item in changes:
            if item.safe:
                break
        modbus_sim.mute = True
        async for item in changes:
            if not item.safe:
                break
        assert item.reason.startswith("stale") and not item.valid
        assert io.inputs.reason.startswith("stale")
        assert io.counters.read_errors == 0  # no read failed yet: it was the age of the reading
        modbus_sim.mute = False


async def test_device_exception_response_becomes_typed_error_and_unsafe(modbus_sim: ModbusIoSim) -> None:
    async with SafetyIo(fast_cfg(modbus_sim.port)) as io:
        modbus_sim.set_all_inputs(True)
        await wait_until(lambda: io.inputs.safe, what="all safe")
        modbus_sim.refuse = True
        with pytest.raises(IoDeviceRefused) as err:
            await io.set_light(LightColor.GREEN)
        assert err.value.code == 4 and "exception response" in str(err.value) and io.name in str(err.value)
        await wait_until(lambda: io.inputs.reason.startswith("read refused"), what="refused read")
        assert not io.inputs.safe and io.counters.read_errors >= 1 and io.counters.write_errors >= 1
        assert io.counters.connects == 1  # the link itself is fine: no reconnect for a refusal
        modbus_sim.refuse = False
        await wait_until(lambda: io.inputs.safe, what="safe again")
        await wait_until(lambda: modbus_sim.light == "green", what="wanted light re-applied")


async def test_not_started_reads_unsafe() -> None:
    io = SafetyIo(ModbusConfig())
    assert not io.inputs.safe and not io.inputs.valid
    with pytest.raises(IoLinkError):
        await io.set_running(True)
    changes = io.changes()
    assert not (await anext(changes)).safe
    with pytest.raises(StopAsyncIteration):
        await anext(changes)


@pytest.mark.parametrize(
    "bad",
    [
        {"outputs": {"light_green": 1, "light_yellow": 1, "light_red": 2, "running": 3}},
        {"inputs": {"area_cleared": 0, "aut_permitted": 0, "estop_ok": 2}},
        {"input_table": "coils"},  # default inputs 0..2 collide with the default light coils
        {"inputs": {"area_cleared": 0, "aut_permitted": 1, "estop_ok": 5000}},
        {"reconnect_min_s": 3.0, "reconnect_max_s": 1.0},
        {"stale_after_polls": 1},
        {"unknown_key": 1},
    ],
)
def test_bad_config_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        ModbusConfig.model_validate(bad)


@given(attempt=st.integers(0, 60), seed=st.integers(0, 2**32 - 1))
def test_backoff_is_bounded_and_jittered(attempt: int, seed: int) -> None:
    delay = backoff_s(attempt, 0.2, 5.0, random.Random(seed))
    base = min(5.0, 0.2 * 2.0**attempt)
    assert base / 2 <= delay <= base <= 5.0


# --- answers that are not the answer to the request (a raw Modbus TCP peer) ------------------------------------------
def _mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


@contextlib.asynccontextmanager
async def _raw_peer(read_answer: Callable[[int, int, bytes], bytes | None],
                    write_answer: Callable[[int, int, bytes], bytes] | None = None) -> AsyncIterator[int]:
    """A module on a free port (yielded) that answers every read with ``read_answer(tid, unit, request_pdu)``
    (``None`` closes the connection instead) and every coil write with ``write_answer`` (the same signature), by
    default the right answer."""
    handlers: dict[asyncio.Task[None], asyncio.StreamWriter] = {}

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                tid, _pid, length, unit = struct.unpack(">HHHB", await reader.readexactly(7))
                pdu = await reader.readexactly(length - 1)
                if pdu[0] in (1, 2):
                    answer = read_answer(tid, unit, pdu)
                    if answer is None:
                        return
                    writer.write(answer)
                elif write_answer is not None:
                    writer.write(write_answer(tid, unit, pdu))
                else:  # FC 5 echoes the request, FC 15 its address and count
                    writer.write(_mbap(tid, unit, pdu if pdu[0] == 5 else pdu[:5]))
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        handlers[task] = writer
        try:
            await serve(reader, writer)
        finally:
            handlers.pop(task, None)

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    try:
        yield server.sockets[0].getsockname()[1]
    finally:
        server.close()
        # Each handler is ended by closing its connection (it reads EOF and returns), and cancelled only if it does
        # not end: Python 3.11's start_server calls exception() on the finished handler task, which raises for a
        # cancelled one, and asyncio logs "Exception in callback StreamReaderProtocol.connection_made...".
        running = list(handlers)
        for writer in list(handlers.values()):
            writer.close()
        if running:
            _, late = await asyncio.wait(running, timeout=2.0)
            for task in late:
                task.cancel()
            await asyncio.gather(*late, return_exceptions=True)
        await server.wait_closed()


ALL_SAFE = 0b111  # the three default inputs, bits 0..2, all 1 = safe


@pytest.mark.parametrize(
    ("answer", "problem"),
    [
        # the coil table (FC 1) in answer to a read of the discrete inputs (FC 2)
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([1, 1, ALL_SAFE])), "function code 1, asked with 2"),
        # function codes pymodbus cannot decode: unknown, or known with a short payload
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([0x55, 1, ALL_SAFE])), "function code 85, asked with 2"),
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([3, 5, 1])), "function code 3, asked with 2"),
        (lambda tid, unit, pdu: _mbap(0, unit, bytes([pdu[0], 1, ALL_SAFE])), "without a transaction id"),
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0], 3, ALL_SAFE, 0xFF, 0xFF])), "3 data bytes, expected 1"),
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0], 9, ALL_SAFE])), "byte count 9 disagrees"),
        # a refusal of another request (read coils, 0x81) is no refusal of this one: the stream is out of step
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([0x81, 4])), "function code 129, asked with 2"),
        # an exception response carries exactly one byte, its exception code
        (lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0] | 0x80, 4, ALL_SAFE])),
         "exception response (function code 130) with 2 data bytes, expected 1 (the exception code)"),
        (lambda tid, unit, pdu: _mbap(0, unit, bytes([pdu[0] | 0x80, 4])), "without a transaction id"),
    ],
    ids=["wrong function code", "unknown function code", "short FC 3 answer", "transaction id 0", "long answer",
         "byte count lies", "refusal of another function", "long refusal", "refusal without transaction id"],
)
async def test_an_answer_to_another_request_reads_unsafe(answer: Callable[[int, int, bytes], bytes],
                                                         problem: str) -> None:
    async with _raw_peer(answer) as port, SafetyIo(fast_cfg(port)) as io:
        await wait_until(lambda: io.counters.read_errors >= 3, what="several answered reads")
        assert io.counters.reads == 0 and not io.inputs.safe and not io.inputs.valid
        assert io.inputs.reason.startswith("bad answer: " + io.name) and problem in io.inputs.reason
        assert io.counters.connects >= 2  # each bad answer resyncs the stream with a new connection


@pytest.mark.parametrize("pdu_of", [lambda pdu: bytes([pdu[0], 1, ALL_SAFE]), lambda pdu: bytes([pdu[0] | 0x80, 4])],
                         ids=["reading", "refusal"])
async def test_unit_0_answer_from_another_unit_reads_unsafe(pdu_of: Callable[[bytes], bytes]) -> None:
    # pymodbus checks the answering unit only for a non-zero unit id; another unit's refusal is no refusal either
    answer = lambda tid, unit, pdu: _mbap(tid, 5, pdu_of(pdu))  # noqa: E731
    async with _raw_peer(answer) as port, SafetyIo(fast_cfg(port, unit_id=0)) as io:
        await wait_until(lambda: io.counters.read_errors >= 2, what="answered reads")
        assert io.counters.reads == 0 and not io.inputs.safe
        assert io.inputs.reason.startswith("bad answer: ") and "answer from unit 5, asked unit 0" in io.inputs.reason
        assert io.counters.connects >= 2  # out of step: a new connection, where a refusal would keep the link


async def test_a_well_formed_raw_answer_reads_safe() -> None:
    # the raw peer itself is right: the same answer with the right header is a good reading
    answer = lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0], 1, ALL_SAFE | 0b1111_1000]))  # noqa: E731
    async with _raw_peer(answer) as port, SafetyIo(fast_cfg(port)) as io:
        await wait_until(lambda: io.inputs.safe, what="safe")  # padding bits set: ignored
        assert io.counters.read_errors == 0 and io.counters.connects == 1


async def test_a_module_that_drops_every_connection_after_one_answer_is_retried_ever_more_slowly(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    attempts: list[int] = []

    def spy(attempt: int, min_s: float, max_s: float, rng: random.Random) -> float:
        attempts.append(attempt)
        return backoff_s(attempt, min_s, max_s, rng)

    monkeypatch.setattr("rgse_daemon.io.modbus.backoff_s", spy)
    reads = itertools.count()
    answer = lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0], 1, ALL_SAFE])) if next(reads) % 2 == 0 else None  # noqa: E731
    async with _raw_peer(answer) as port, SafetyIo(fast_cfg(port, reconnect_min_s=0.005, reconnect_max_s=5.0)) as io:
        await wait_until(lambda: len(attempts) >= 5, what="five reconnects")
        assert io.counters.reads >= 5  # each connection did give one good reading ...
    assert attempts[:5] == [0, 1, 2, 3, 4]  # ... and still the backoff grew


# --- answers pymodbus' decoder gives up on: named, no asyncio traceback ---------------------------------------------
def _spy_backoff(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    attempts: list[int] = []

    def spy(attempt: int, min_s: float, max_s: float, rng: random.Random) -> float:
        attempts.append(attempt)
        return backoff_s(attempt, min_s, max_s, rng)

    monkeypatch.setattr("rgse_daemon.io.modbus.backoff_s", spy)
    return attempts


def _tracebacks(caplog: pytest.LogCaptureFixture) -> list[str]:
    """Records of asyncio's exception handler (a protocol callback that raised, an exception never retrieved) and
    any record that carries a traceback."""
    return [f"{r.name}: {r.getMessage()}" for r in caplog.records if r.name == "asyncio" or r.exc_info]


async def test_an_exception_response_without_exception_code_is_a_named_bad_answer(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
) -> None:
    # MBAP length 2: the unit id and the exception function code, no exception-code byte (8 bytes on the wire)
    answer = lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0] | 0x80]))  # noqa: E731
    attempts = _spy_backoff(monkeypatch)
    caplog.set_level("DEBUG", logger="asyncio")
    async with _raw_peer(answer) as port, SafetyIo(fast_cfg(port)) as io:
        await wait_until(lambda: io.counters.read_errors >= 3, what="several answered reads")
        assert io.counters.reads == 0 and not io.inputs.safe and not io.inputs.valid
        assert io.inputs.reason == (f"bad answer: {io.name}: read discrete inputs 0+3: exception response (function "
                                    "code 130) without an exception code in 'function code 130, unit 1, data (none)'")
        assert io.counters.connects >= 3  # each bad answer resyncs the stream with a new connection ...
    assert attempts[:3] == [0, 1, 2]  # ... after a growing backoff
    assert _tracebacks(caplog) == []


async def test_a_write_answer_too_short_to_decode_is_a_named_bad_answer(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
) -> None:
    # a write-coils answer with its function code and nothing else: pymodbus cannot unpack address and count
    read = lambda tid, unit, pdu: _mbap(tid, unit, bytes([pdu[0], 1, ALL_SAFE]))  # noqa: E731
    write = lambda tid, unit, pdu: _mbap(tid, unit, pdu[:1])  # noqa: E731
    attempts = _spy_backoff(monkeypatch)
    caplog.set_level("DEBUG", logger="asyncio")
    async with _raw_peer(read, write) as port, SafetyIo(fast_cfg(port)) as io:
        await wait_until(lambda: len(attempts) >= 3, what="several reconnects")
        # the outputs are re-applied on every connect: the answer to that write is the bad one
        assert io.inputs.reason == (f"bad answer: {io.name}: write coils 0..2: answer with function code 15 that "
                                    "cannot be decoded (0 data bytes) in 'function code 15, unit 1, data (none)'")
        assert not io.outputs_confirmed and not io.inputs.safe
    assert attempts[:3] == [0, 1, 2]
    assert _tracebacks(caplog) == []
