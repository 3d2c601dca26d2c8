"""The Modbus TCP safety I/O module: three fail-safe inputs in, a stack light and a "running" lamp out.

Why it exists: the paper's cell allows automatic operation only with a cleared, cordoned hazard area and the
key switch turned to permit AUT. The daemon polls those contacts (plus the E-stop chain) and drives a stack
light. It never *relies* on them for personal safety (the KR C4 safety controller does that); it refuses to
start or continue a plan when they are not all good.

Public API
----------
``ModbusConfig``            host, port, unit id, register map, poll period, timeouts, backoff (pydantic).
``SafetyIo(cfg)``           ``async start()`` / ``async stop()`` or ``async with SafetyIo(cfg) as io``.
``io.inputs``               ``SafetyInputs`` (frozen): the latest reading, or an all-unsafe one on link loss or
                            when the latest good reading is older than ``stale_after_polls`` poll periods.
``io.changes()``            async iterator of ``SafetyInputs`` whenever a safety-relevant field changes (the
                            current state first); ends when the I/O stops.
``await io.set_light(c)``   ``LightColor.GREEN`` idle, ``YELLOW`` measuring, ``RED`` alarm, ``OFF``.
``await io.set_running(b)`` the "measurement running" output.
``io.outputs``              the wanted (light, running); ``io.outputs_confirmed``: written since last change or
                            reconnect (the wish is re-applied after every reconnect: a rebooted module
                            starts with its outputs off).
``io.counters``             reads, read errors, writes, write errors, connects, reconnects.
``io.state``                ``ConnectionState``.

Register map (defaults; zero-based Modbus addresses, one bit each)
------------------------------------------------------------------
==========================  ==========================  =====================================
signal                      table (function codes)      default address
==========================  ==========================  =====================================
hazard area cleared         discrete inputs (FC 2)      0
key switch AUT permitted    discrete inputs (FC 2)      1
E-stop OK                   discrete inputs (FC 2)      2
stack light green           coils (FC 1 / 5 / 15)       0
stack light yellow          coils                       1
stack light red             coils                       2
measurement running         coils                       3
==========================  ==========================  =====================================

``input_table = "coils"`` reads the inputs from coils instead (then input and output addresses must differ).
Inputs are fail-safe wired: 1 means "safe" (cleared / permitted / E-stop chain closed), so a broken wire
reads as unsafe. The inputs are read in one request spanning their addresses.

An answer counts only if it answers that request: same function code, same unit, a transaction id, exactly the
data bytes asked for and a byte count that says so (pymodbus lets the first three through when zero or not
checked; an answer with a function code the daemon does not use, or one pymodbus cannot decode, such as an exception
response without its exception code, is kept raw, so that it is named too).
Anything else is an ``IoFrameError``: the inputs read unsafe ("bad answer: ...") and the poller reconnects, so
that a stream out of step starts afresh.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import random
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Self

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import DecodePDU, ModbusPDU
from pymodbus.pdu.bit_message import ReadCoilsResponse, ReadDiscreteInputsResponse

from rgse_daemon.config import Address, ModbusConfig
from rgse_daemon.io import IoDeviceError, IoDeviceRefused, IoFrameError, IoLinkError, IoTimeout
from rgse_daemon.safety.inputs import SafetyInputs

log = logging.getLogger(__name__)

# --- values --------------------------------------------------------------------------------------------------
class LightColor(enum.StrEnum):
    OFF = "off"
    GREEN = "green"  # idle
    YELLOW = "yellow"  # measuring
    RED = "red"  # alarm


class ConnectionState(enum.StrEnum):
    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    CONNECTED = "connected"
    STOPPED = "stopped"


@dataclass
class SafetyIoCounters:
    reads: int = 0
    read_errors: int = 0
    writes: int = 0
    write_errors: int = 0
    connects: int = 0
    reconnects: int = 0


class InputChanges:
    """Async iterator of ``SafetyInputs``: the state at subscription, then every safety-relevant change.

    It ends (``StopAsyncIteration``) when the I/O stops. The queue is bounded and never blocks the poller: on
    overflow the oldest entry is dropped, since the newest state is what the interlock needs. Use as
    ``async with io.changes() as changes: async for s in changes: ...`` or call ``close()``.
    """

    def __init__(self, owner: SafetyIo, maxsize: int = 32) -> None:
        self._owner = owner
        self._queue: asyncio.Queue[SafetyInputs | None] = asyncio.Queue(maxsize=maxsize)

    def put_latest(self, item: SafetyInputs | None) -> None:
        if self._queue.full():
            self._queue.get_nowait()
        self._queue.put_nowait(item)

    def __aiter__(self) -> InputChanges:
        return self

    async def __anext__(self) -> SafetyInputs:
        item = await self._queue.get()
        if item is None:
            self._queue.put_nowait(None)  # stay ended
            raise StopAsyncIteration
        return item

    def close(self) -> None:
        self._owner._unsubscribe(self)
        self.put_latest(None)

    async def __aenter__(self) -> InputChanges:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


class _ReadCoilsAnswer(ReadCoilsResponse):
    """A read-coils answer that keeps its byte-count field (pymodbus' own decoder drops it), so that an answer
    whose byte count disagrees with the data it carries is not taken for a reading."""

    byte_count: int | None = None

    def decode(self, data: bytes) -> None:
        self.byte_count = data[0] if data else None
        super().decode(data)


class _ReadDiscreteInputsAnswer(ReadDiscreteInputsResponse):
    """The same for read-discrete-inputs answers."""

    byte_count: int | None = None

    def decode(self, data: bytes) -> None:
        self.byte_count = data[0] if data else None
        super().decode(data)


class _OtherAnswer(ModbusPDU):
    """An answer with a function code the daemon never asks with, kept as raw bytes. pymodbus cannot decode many
    of these (an unknown code, or a known one with a short payload): its decoder then raises inside the protocol
    callback, asyncio logs a traceback and closes the connection, and the read only sees "closed by the peer".
    Decoded like this, the answer reaches ``_request``, which names it."""

    payload: bytes = b""

    def decode(self, data: bytes) -> None:
        self.payload = bytes(data)

    def __str__(self) -> str:
        return f"function code {self.function_code}, unit {self.dev_id}, data {self.payload.hex(' ') or '(none)'}"


class _MalformedAnswer(ModbusPDU):
    """An answer pymodbus' decoder gives up on (it returns ``None``), kept raw with what is wrong with it: an
    exception response without its exception code (MBAP length 2), a write answer too short for its fields. pymodbus'
    framer raises for these inside the protocol callback: asyncio logs a traceback ("protocol.data_received() call
    failed"), closes the connection, and the read only sees "closed by the peer". Decoded like this, the answer
    reaches ``_request``, which names it."""

    def __init__(self, function_code: int, payload: bytes, problem: str) -> None:
        super().__init__()
        self.function_code = function_code
        self.payload = payload
        self.problem = problem

    def isError(self) -> bool:
        return False  # not a refusal by the device (even with an exception function code): a frame out of protocol

    def __str__(self) -> str:
        return f"function code {self.function_code}, unit {self.dev_id}, data {self.payload.hex(' ') or '(none)'}"


class _AnswerDecoder(DecodePDU):
    """pymodbus' client decoder, except that it never gives up on an answer: what it cannot decode becomes a
    ``_MalformedAnswer`` (see there)."""

    def decode(self, frame: bytes) -> ModbusPDU | None:
        function_code, payload = frame[0], bytes(frame[1:])  # the framer passes no empty frame
        if function_code > 0x80 and not payload:  # pymodbus' exception decoder would index past the end
            return _MalformedAnswer(function_code, payload, f"exception response (function code {function_code}) "
                                    "without an exception code")
        if function_code > 0x80 and len(payload) != 1:  # pymodbus would read the first byte and drop the rest
            return _MalformedAnswer(function_code, payload, f"exception response (function code {function_code}) "
                                    f"with {len(payload)} data bytes, expected 1 (the exception code)")
        pdu = super().decode(frame)
        if pdu is None:
            return _MalformedAnswer(function_code, payload, f"answer with function code {function_code} that cannot "
                                    f"be decoded ({len(payload)} data bytes)")
        return pdu


_ASKED_WITH = (1, 2, 5, 15)  # read coils, read discrete inputs, write coil, write coils
#: One class per function code the daemon does not use (0x81 and above are exception responses).
_OTHER_ANSWERS: list[type[ModbusPDU]] = [
    type(f"_OtherAnswer{fc}", (_OtherAnswer,), {"function_code": fc}) for fc in range(0x81) if fc not in _ASKED_WITH
]


def backoff_s(attempt: int, min_s: float, max_s: float, rng: random.Random) -> float:
    """Exponential backoff with "equal jitter": half fixed, half random, so that many clients do not
    reconnect in lockstep after the module reboots."""
    base = min(max_s, min_s * 2.0**attempt)
    return base / 2.0 + rng.uniform(0.0, base / 2.0)


# --- the device ----------------------------------------------------------------------------------------------
class SafetyIo:
    """The safety I/O module as the daemon sees it: a polled, self-reconnecting view of three inputs plus two
    outputs. One lock serialises every request on the bus; device-side errors become exceptions in
    ``_request`` only."""

    def __init__(self, cfg: ModbusConfig, *, rng: random.Random | None = None) -> None:
        self.cfg = cfg
        self.name = f"modbus {cfg.host}:{cfg.port} unit {cfg.unit_id}"
        self.counters = SafetyIoCounters()
        self.state = ConnectionState.STOPPED
        self._rng = rng or random.Random()
        self._lock = asyncio.Lock()
        self._client: AsyncModbusTcpClient | None = None
        self._link_lost: asyncio.Future[None] | None = None  # resolved when the peer closes the connection
        self._latest = SafetyInputs.unsafe("not started")
        self._latest_mono = -float("inf")
        self._published: tuple[bool, bool, bool, bool] | None = None
        self._subscribers: list[InputChanges] = []
        self._tasks: list[asyncio.Task[None]] = []
        self._light = LightColor.OFF
        self._running = False
        self._outputs_dirty = False  # desired outputs not yet confirmed written on this connection
        self._last_logged_error = ""
        span = list(cfg.inputs.model_dump().values())
        self._in_first = min(span)
        self._in_count = max(span) - self._in_first + 1

    # lifecycle ---------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Start polling. Does not wait for the first reading: until it arrives, ``inputs`` reads unsafe."""
        if self._tasks:
            return
        self.state = ConnectionState.DISCONNECTED
        self._latest = SafetyInputs.unsafe("no reading yet")
        self._tasks = [
            asyncio.create_task(self._poll_loop(), name=f"{self.name} poll"),
            asyncio.create_task(self._watchdog(), name=f"{self.name} watchdog"),
        ]

    async def stop(self) -> None:
        """Stop polling, close the connection and end every ``changes()`` iterator. Outputs are left as they
        are: what the light shows after a stop is the caller's decision (set it before stopping)."""
        tasks, self._tasks = self._tasks, []
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)  # their CancelledError stays theirs; a cancel of stop() itself propagates
            for task in tasks:
                if not task.cancelled() and task.exception() is not None:
                    log.warning("safety I/O: task %s had failed: %r", task.get_name(), task.exception())
        self._close_client()
        self.state = ConnectionState.STOPPED
        self._latest = SafetyInputs.unsafe("stopped")
        for sub in self._subscribers:
            sub.put_latest(None)
        self._subscribers.clear()

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # inputs ------------------------------------------------------------------------------------------------
    @property
    def inputs(self) -> SafetyInputs:
        """The latest reading, unless the link is down or the reading is stale: then all-unsafe."""
        latest = self._latest
        if latest.valid:
            age_s = time.monotonic() - self._latest_mono
            if age_s > self.cfg.stale_after_s:
                return SafetyInputs.unsafe(f"stale: last good reading {age_s:.3f} s ago")
        return latest

    def changes(self) -> InputChanges:
        """Subscribe to the current inputs and every change of a safety-relevant field, until ``stop()``."""
        sub = InputChanges(self)
        sub.put_latest(self.inputs)
        if self._tasks:
            self._subscribers.append(sub)
        else:
            sub.put_latest(None)
        return sub

    def _unsubscribe(self, sub: InputChanges) -> None:
        with contextlib.suppress(ValueError):
            self._subscribers.remove(sub)

    def _publish(self) -> None:
        now = self.inputs
        if now.key() != self._published:
            self._published = now.key()
            for sub in self._subscribers:
                sub.put_latest(now)

    # outputs -----------------------------------------------------------------------------------------------
    async def set_light(self, color: LightColor) -> None:
        """Show one colour (or none). The wish is remembered and re-applied after a reconnect; raises
        ``IoDeviceError`` when it could not be written now."""
        self._light = LightColor(color)
        self._outputs_dirty = True
        await self._reapply_outputs()

    async def set_running(self, running: bool) -> None:
        """Set the "measurement running" output; remembered and re-applied after a reconnect like the light."""
        self._running = bool(running)
        self._outputs_dirty = True
        await self._reapply_outputs()

    async def _write_light(self) -> None:
        out = self.cfg.outputs
        await self._write_coils(
            {
                out.light_green: self._light is LightColor.GREEN,
                out.light_yellow: self._light is LightColor.YELLOW,
                out.light_red: self._light is LightColor.RED,
            }
        )

    async def _write_coils(self, bits: dict[Address, bool]) -> None:
        """Write in one request when the addresses are contiguous, else one by one turning bits off first
        (so that two light colours are never on together)."""
        client = self._connected_client()
        first = min(bits)
        try:
            if sorted(bits) == list(range(first, first + len(bits))):
                values = [bits[a] for a in range(first, first + len(bits))]
                await self._request(
                    f"write coils {first}..{first + len(bits) - 1}",
                    15,
                    lambda: client.write_coils(first, values, device_id=self.cfg.unit_id),
                )
            else:
                for addr, value in sorted(bits.items(), key=lambda kv: kv[1]):
                    await self._request(
                        f"write coil {addr}",
                        5,
                        lambda a=addr, v=value: client.write_coil(a, v, device_id=self.cfg.unit_id),
                    )
        except IoDeviceError:
            self.counters.write_errors += 1
            raise
        self.counters.writes += 1

    @property
    def outputs(self) -> tuple[LightColor, bool]:
        """The wanted outputs (light colour, running); ``outputs_confirmed`` says whether they are written."""
        return self._light, self._running

    @property
    def outputs_confirmed(self) -> bool:
        return not self._outputs_dirty

    async def _reapply_outputs(self) -> None:
        """Write the wanted light and running outputs; only a complete success marks them confirmed."""
        await self._write_light()
        await self._write_coils({self.cfg.outputs.running: self._running})
        self._outputs_dirty = False

    # the one place where the bus is touched -------------------------------------------------------------------
    def _connected_client(self) -> AsyncModbusTcpClient:
        client = self._client
        if client is None or self.state is not ConnectionState.CONNECTED:
            raise IoLinkError(self.name, f"not connected ({self.state})")
        if not client.connected:
            raise IoLinkError(self.name, "connection closed by the peer")
        return client

    async def _request(self, what: str, fc: int, call: Callable[[], Awaitable[ModbusPDU]]) -> ModbusPDU:
        """Run one request (function code ``fc``) under the bus lock with a deadline; map every failure to a
        typed error.

        The request also ends early when the peer closes the connection (pymodbus would otherwise wait for
        its own timeout): a module that reboots reads unsafe at once, not after a deadline. An answer that is not
        the answer to this request (another function code, another unit, no transaction id: pymodbus lets these
        through), or one pymodbus could not decode, is an ``IoFrameError``."""
        async with self._lock:
            link_lost = self._link_lost
            if link_lost is None or link_lost.done():
                raise IoLinkError(self.name, f"{what}: connection closed by the peer")
            try:
                async with asyncio.timeout(self.cfg.request_timeout_s):
                    request = asyncio.ensure_future(call())
                    try:
                        await asyncio.wait({request, link_lost}, return_when=asyncio.FIRST_COMPLETED)
                    finally:
                        if not request.done():
                            request.cancel()
                            await asyncio.wait({request})
                    if request.cancelled():
                        raise IoLinkError(self.name, f"{what}: connection closed by the peer")
                    response = request.result()
            except TimeoutError as exc:
                raise IoTimeout(self.name, f"{what}: no answer within {self.cfg.request_timeout_s} s") from exc
            except ModbusIOException as exc:
                raise IoTimeout(self.name, f"{what}: {exc}") from exc
            except ConnectionException as exc:
                raise IoLinkError(self.name, f"{what}: {exc}") from exc
            except ModbusException as exc:
                raise IoLinkError(self.name, f"{what}: {exc}") from exc
            except OSError as exc:
                raise IoLinkError(self.name, f"{what}: {exc}") from exc
        if isinstance(response, _MalformedAnswer):
            raise IoFrameError(self.name, f"{what}: {response.problem}", str(response))
        # a refusal counts only as the refusal of this request: its function code is the request's + 0x80
        expected_fc = fc | 0x80 if response.isError() else fc
        if response.function_code != expected_fc:
            raise IoFrameError(self.name, f"{what}: answer has function code {response.function_code}, asked with "
                               f"{fc}", str(response))
        if response.dev_id != self.cfg.unit_id:
            raise IoFrameError(self.name, f"{what}: answer from unit {response.dev_id}, asked unit "
                               f"{self.cfg.unit_id}", str(response))
        if not response.transaction_id:  # pymodbus numbers its requests from 1 and matches only non-zero ids
            raise IoFrameError(self.name, f"{what}: answer without a transaction id", str(response))
        if response.isError():
            code = getattr(response, "exception_code", None)
            raise IoDeviceRefused(self.name, f"{what}: exception response, code {code}", code)
        return response

    async def _read_inputs(self) -> SafetyInputs:
        client = self._connected_client()
        first, count, unit = self._in_first, self._in_count, self.cfg.unit_id
        if self.cfg.input_table == "coils":
            what = f"read coils {first}+{count}"
            response = await self._request(what, 1, lambda: client.read_coils(first, count=count, device_id=unit))
        else:
            what = f"read discrete inputs {first}+{count}"
            response = await self._request(
                what, 2, lambda: client.read_discrete_inputs(first, count=count, device_id=unit)
            )
        bits = list(response.bits)
        # exactly the bytes asked for (padding bits of the last byte are ignored), and a byte count that says so
        want_bytes, got_bytes = (count + 7) // 8, len(bits) // 8
        if got_bytes != want_bytes:
            raise IoFrameError(self.name, f"{what}: answer carries {got_bytes} data bytes, expected {want_bytes}",
                               str(response))
        byte_count = getattr(response, "byte_count", got_bytes)
        if byte_count != got_bytes:
            raise IoFrameError(self.name, f"{what}: answer's byte count {byte_count} disagrees with the "
                               f"{got_bytes} data bytes it carries", str(response))
        ins = self.cfg.inputs
        return SafetyInputs(
            area_cleared=bool(bits[ins.area_cleared - first]),
            aut_permitted=bool(bits[ins.aut_permitted - first]),
            estop_ok=bool(bits[ins.estop_ok - first]),
            valid=True,
            time_utc=datetime.now(UTC),
        )

    # background tasks ----------------------------------------------------------------------------------------
    async def _connect(self) -> None:
        self._close_client()
        self.state = ConnectionState.CONNECTING
        self._link_lost = asyncio.get_running_loop().create_future()
        client = AsyncModbusTcpClient(
            self.cfg.host,
            port=self.cfg.port,
            # pymodbus uses one timeout for connect and for each answer; our own deadlines are the ones that count
            timeout=max(self.cfg.connect_timeout_s, self.cfg.request_timeout_s),
            retries=0,
            reconnect_delay=0,  # we reconnect ourselves, with jitter
            name=self.name,
            trace_connect=self._on_connection_change,
        )
        client.ctx.framer.decoder = _AnswerDecoder(is_server=False)  # the decoder that client.register() fills
        for answer_class in (_ReadCoilsAnswer, _ReadDiscreteInputsAnswer, *_OTHER_ANSWERS):
            client.register(answer_class)
        self._client = client
        try:
            async with asyncio.timeout(self.cfg.connect_timeout_s):
                ok = await client.connect()
        except TimeoutError as exc:
            raise IoTimeout(self.name, f"connect: no answer within {self.cfg.connect_timeout_s} s") from exc
        if not ok:
            raise IoLinkError(self.name, "connect: refused or unreachable")
        self.state = ConnectionState.CONNECTED
        self.counters.connects += 1
        self._outputs_dirty = True  # the module may have rebooted and reset its outputs

    def _on_connection_change(self, connected: bool) -> None:
        """pymodbus calls this when the TCP connection comes up or goes down."""
        if not connected and self._link_lost is not None and not self._link_lost.done():
            self._link_lost.set_result(None)

    def _close_client(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    def _doubt(self, reason: str) -> None:
        """Something went wrong: from now until a good reading, every input reads unsafe."""
        self._latest = SafetyInputs.unsafe(reason)
        self._publish()
        if reason != self._last_logged_error:  # log each distinct error once
            log.warning("%s", reason)
            self._last_logged_error = reason

    async def _poll_loop(self) -> None:
        """Connect, poll until the link fails, back off, again. The backoff starts afresh only after a connection
        that lasted ``reconnect_max_s``: a module that accepts, answers once and drops the link is retried ever more
        slowly, not a few times a second."""
        attempt = 0
        first_connect = True
        while True:
            connected_at: float | None = None
            try:
                await self._connect()
                connected_at = time.monotonic()
                if not first_connect:
                    self.counters.reconnects += 1
                first_connect = False
                await self._reapply_outputs_quietly()
                next_tick = time.monotonic()
                while True:
                    await self._poll_once()
                    next_tick += self.cfg.poll_period_s
                    await asyncio.sleep(max(0.0, next_tick - time.monotonic()))
                    next_tick = max(next_tick, time.monotonic() - self.cfg.poll_period_s)
            except (IoTimeout, IoLinkError) as exc:
                self._doubt(f"link lost: {exc}")
            except IoFrameError as exc:  # not an answer to what was asked: reconnect, so that the stream is in step
                self._doubt(f"bad answer: {exc}")
            except Exception as exc:  # a bug or a library surprise must not end polling silently
                log.exception("%s: unexpected error in the poll loop", self.name)
                self._doubt(f"poll loop error: {exc!r}")
            self._close_client()
            self.state = ConnectionState.DISCONNECTED
            if connected_at is not None and time.monotonic() - connected_at >= self.cfg.reconnect_max_s:
                attempt = 0  # the link had been fine for a while: this is a new outage
            await asyncio.sleep(backoff_s(attempt, self.cfg.reconnect_min_s, self.cfg.reconnect_max_s, self._rng))
            attempt += 1

    async def _reapply_outputs_quietly(self) -> None:
        """Re-assert the wanted outputs after (re)connecting; a refusal here is logged, not fatal to polling."""
        if not self._outputs_dirty:
            return
        try:
            await self._reapply_outputs()
        except IoDeviceRefused as exc:
            self._doubt(f"outputs refused: {exc}")

    async def _poll_once(self) -> None:
        try:
            reading = await self._read_inputs()
        except IoDeviceRefused as exc:  # the module is there but refused: keep the link, doubt the inputs
            self.counters.read_errors += 1
            self._doubt(f"read refused: {exc}")
            return
        except IoDeviceError:
            self.counters.read_errors += 1
            raise
        self.counters.reads += 1
        self._latest = reading
        self._latest_mono = time.monotonic()
        if self._last_logged_error:
            log.info("%s: inputs readable again", self.name)
            self._last_logged_error = ""
        self._publish()
        await self._reapply_outputs_quietly()

    async def _watchdog(self) -> None:
        """Publish staleness even while the poller is stuck in a slow request."""
        while True:
            await asyncio.sleep(self.cfg.poll_period_s)
            self._publish()
