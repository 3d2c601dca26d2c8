"""The reference crane scale (paper §6: a Kern HFB 300K100, d = 0.1 kg) read over its RS-232 interface.

Why it exists: the in-line mass from the robot's joint torques is checked against a free-hanging crane-scale
weighing (paper Table 2: 117.6 ± 0.1 kg including the fixture). Typing that number in by hand is where
mistakes creep in, so the daemon reads the scale itself and records the raw line it came from.

Public API
----------
``ScaleConfig``                        port (device path or pyserial URL), line settings, protocol, resolution.
``CraneScale(cfg)``                    ``async open()`` / ``async close()`` or ``async with``; opens lazily.
``await scale.read_stable(timeout_s)`` -> ``Weighing(mass_kg, u_kg, stable, raw_line, time_utc)``: the first
                                       stable weighing (``stable_frames_required`` consecutive stable frames
                                       agreeing within d) received after the call; unstable frames are skipped,
                                       garbled ones counted and skipped (``IoFrameError`` after
                                       ``max_consecutive_bad_frames`` in a row); ``IoTimeout`` at the deadline.
``await scale.read_frame(timeout_s)``  the next frame, stable or not.
``parse_line(line, cfg, device)``      one line -> ``ScaleFrame``, or ``IoFrameError`` naming device and line.
``scale.counters``                     frames, stable, unstable, bad frames, reads, timeouts, opens.

The port is opened with ``serial.serial_for_url`` (via pyserial-asyncio-fast), so ``/dev/ttyUSB0``, a pty path
and ``socket://host:port`` (a serial-to-Ethernet converter, or the simulator) all work.

Line format (default, KERN "ST,GS" style, ASCII, terminated by CR LF)
----------------------------------------------------------------------
``<stability>,<kind>,<sign><blanks><value><blanks><unit>`` e.g. ``ST,GS,+    117.6 kg``

* stability ``ST`` (stable) or ``US`` (unstable); ``OL`` (overload) is reported as a bad frame;
* kind ``GS`` (gross) or ``NT`` (net); sign ``+`` or ``-``; value with optional decimal point;
* unit ``kg``, ``g``, ``t`` or ``lb`` (case-insensitive), converted to kg;
* optional checksum (``checksum = "xor8"``): ``*HH`` after the unit, HH = XOR of all preceding bytes in hex.

Requests (``mode = "request"``): the command is sent as bare ASCII without CR LF, as KERN scales expect:
``S`` = send the stable value (the scale answers once stable), ``W`` = send the current value (stable or not).
It is re-sent every ``request_interval_s`` until the deadline. In ``mode = "stream"`` the scale sends
continuously and nothing is written. Another dialect is a matter of ``line_regex`` (named groups ``stab``,
``sign``, ``value``, ``unit``), ``stable_tokens`` and ``request_cmd``.

Uncertainty: a reading is taken to lie within ±d of the true mass (the scale's resolution, which is how the
paper quotes it); as a rectangular distribution that gives the standard uncertainty u = d/√3 (GUM 4.3.7).
"""

from __future__ import annotations

import asyncio
import logging
import math
import re
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Self

import serial
from serial_asyncio_fast import create_serial_connection

from rgse_daemon.config import UNIT_TO_KG, ScaleConfig
from rgse_daemon.io import IoFrameError, IoLinkError, IoTimeout

log = logging.getLogger(__name__)

#: The ``value`` group must be a plain decimal number (sign apart: that is the ``sign`` group's, or a leading one).
_DECIMAL_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)")



@dataclass(frozen=True)
class ScaleFrame:
    """One parsed line. ``stable`` is False when the line has no stability group or an unstable token."""

    stable: bool
    mass_kg: float
    value: float
    unit: str
    raw_line: str


@dataclass(frozen=True)
class Weighing:
    """A weighing as recorded with a measurement: the mass, its standard uncertainty and where it came from."""

    mass_kg: float
    u_kg: float
    stable: bool
    raw_line: str
    time_utc: datetime


@dataclass
class ScaleCounters:
    frames: int = 0
    stable_frames: int = 0
    unstable_frames: int = 0
    bad_frames: int = 0
    reads: int = 0
    timeouts: int = 0
    opens: int = 0


def xor8(data: bytes) -> int:
    """The XOR of all bytes: the checksum of ``checksum = "xor8"`` lines."""
    value = 0
    for byte in data:
        value ^= byte
    return value


def parse_line(line: str, cfg: ScaleConfig, device: str, *, _regex: re.Pattern[str] | None = None) -> ScaleFrame:
    """Parse one line (without its CR LF) into a frame, or raise ``IoFrameError`` naming the device and line."""
    if not line.isascii() or not line.isprintable():
        raise IoFrameError(device, "non-printable or non-ASCII characters", line)
    body = line
    if cfg.checksum == "xor8":
        body, star, given = line.rpartition("*")
        if not star or len(given) != 2:
            raise IoFrameError(device, "missing *HH checksum", line)
        try:
            given_value = int(given, 16)
        except ValueError:
            raise IoFrameError(device, "checksum is not hexadecimal", line) from None
        if given_value != xor8(body.encode("ascii")):
            raise IoFrameError(device, f"checksum mismatch (computed {xor8(body.encode('ascii')):02X})", line)
    if body.startswith("OL"):
        raise IoFrameError(device, "scale reports overload", line)
    regex = _regex or re.compile(cfg.line_regex, re.IGNORECASE)
    match = regex.match(body.strip())
    if match is None:
        raise IoFrameError(device, "line does not match the configured format", line)
    groups = match.groupdict()
    if groups["unit"] is None:  # a line_regex may make the group optional
        raise IoFrameError(device, "no unit", line)
    unit = groups["unit"].lower()
    if unit not in UNIT_TO_KG:
        raise IoFrameError(device, f"unknown unit {groups['unit']!r} (expected one of {sorted(UNIT_TO_KG)})", line)
    # a plain decimal number only: with a looser line_regex float() would also take "nan", "inf", "1e999" (inf)
    # and "1_000" (1000.0), none of which a scale sends
    text = groups["value"] or ""
    if not _DECIMAL_RE.fullmatch(text):
        raise IoFrameError(device, f"value {text!r} is not a decimal number", line)
    value = float(text)
    if not math.isfinite(value):
        raise IoFrameError(device, f"value {text!r} is out of range", line)
    if groups.get("sign") == "-":
        value = -value
    stab = groups.get("stab")
    stable = stab is not None and stab.upper() in {t.upper() for t in cfg.stable_tokens}
    return ScaleFrame(stable=stable, mass_kg=value * UNIT_TO_KG[unit], value=value, unit=unit, raw_line=line)


class _LineProtocol(asyncio.Protocol):
    """Splits the byte stream into lines; each line is queued with its arrival time so that a read can
    ignore what was buffered before it started. Over-long garbage is cut and queued as its own line."""

    def __init__(self, max_line_bytes: int) -> None:
        self.lines: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(maxsize=256)
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._buffer = bytearray()
        self._max = max_line_bytes

    def data_received(self, data: bytes) -> None:
        self._buffer += data
        while True:
            end = self._buffer.find(b"\n")
            if end < 0:
                if len(self._buffer) > self._max:
                    self._queue(bytes(self._buffer))
                    self._buffer.clear()
                return
            line = bytes(self._buffer[:end]).rstrip(b"\r")
            del self._buffer[: end + 1]
            if line:
                self._queue(line)

    @property
    def pending(self) -> bytes:
        """What arrived after the last line end (a line not finished yet)."""
        return bytes(self._buffer)

    def _queue(self, line: bytes) -> None:
        if self.lines.full():
            self.lines.get_nowait()
        self.lines.put_nowait((time.monotonic(), line))

    def connection_lost(self, exc: Exception | None) -> None:
        if self.lines.full():
            self.lines.get_nowait()
        self.lines.put_nowait(None)
        if not self.closed.done():
            self.closed.set_result(None)


class CraneScale:
    """The crane scale on one serial port. One read at a time (a lock); the port is opened on first use and
    closed after a link failure, so that the next read reopens it."""

    def __init__(self, cfg: ScaleConfig) -> None:
        self.cfg = cfg
        self.name = f"scale {cfg.port}"
        self.counters = ScaleCounters()
        self.last_error: IoFrameError | None = None
        self._regex = re.compile(cfg.line_regex, re.IGNORECASE)
        self._lock = asyncio.Lock()
        self._transport: asyncio.BaseTransport | None = None
        self._protocol: _LineProtocol | None = None
        self._last_logged = ""

    # lifecycle -----------------------------------------------------------------------------------------------
    async def open(self) -> None:
        if self._transport is not None:
            return
        cfg = self.cfg
        loop = asyncio.get_running_loop()
        protocol = _LineProtocol(cfg.max_line_bytes)
        transport: asyncio.BaseTransport | None = None
        try:
            async with asyncio.timeout(cfg.open_timeout_s):  # the open and the buffer reset: a hung driver is doubt
                transport, _ = await create_serial_connection(
                    loop,
                    lambda: protocol,
                    cfg.port,
                    baudrate=cfg.baudrate,
                    bytesize=cfg.bytesize,
                    parity=cfg.parity,
                    stopbits=cfg.stopbits,
                )
                port = getattr(transport, "serial", None)
                if port is not None and port.is_open:
                    await loop.run_in_executor(None, port.reset_input_buffer)  # drop what the scale sent before
        except TimeoutError as exc:
            if transport is not None:
                transport.close()
            raise IoTimeout(self.name, f"open: not done within {cfg.open_timeout_s} s") from exc
        except (serial.SerialException, OSError, ValueError) as exc:
            if transport is not None:
                transport.close()
            raise IoLinkError(self.name, f"open: {exc}") from exc
        self._transport, self._protocol = transport, protocol
        self.counters.opens += 1

    async def close(self) -> None:
        transport, protocol = self._transport, self._protocol
        self._transport = self._protocol = None
        if transport is None or protocol is None:
            return
        transport.close()
        try:
            async with asyncio.timeout(self.cfg.open_timeout_s):
                await protocol.closed
        except TimeoutError:
            log.warning("%s: port did not report closed within %s s", self.name, self.cfg.open_timeout_s)

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # reads ---------------------------------------------------------------------------------------------------
    async def read_stable(self, timeout_s: float | None = None) -> Weighing:
        """The first stable weighing received after this call (see the module docstring)."""
        return await self._read(timeout_s, require_stable=True)

    async def read_frame(self, timeout_s: float | None = None) -> Weighing:
        """The next well-formed frame, stable or not (``Weighing.stable`` tells)."""
        return await self._read(timeout_s, require_stable=False)

    async def _read(self, timeout_s: float | None, *, require_stable: bool) -> Weighing:
        timeout = self.cfg.default_timeout_s if timeout_s is None else timeout_s
        async with self._lock:
            self.counters.reads += 1
            await self.open()
            seen = _ReadLog()
            try:
                async with asyncio.timeout(timeout):
                    return await self._read_until_done(seen, require_stable)
            except TimeoutError as exc:
                self.counters.timeouts += 1
                what = "stable weighing" if require_stable else "frame"
                protocol = self._protocol
                pending = b"" if protocol is None else protocol.pending
                raise IoTimeout(self.name, f"no {what} within {timeout} s ({seen.summary(pending)})") from exc
            except IoLinkError:
                await self.close()
                raise

    async def _read_until_done(self, seen: _ReadLog, require_stable: bool) -> Weighing:
        cfg = self.cfg
        started = time.monotonic()
        run: list[ScaleFrame] = []
        bad_in_a_row = 0
        next_request = started
        while True:
            wait_s: float | None = None
            if cfg.mode == "request":
                now = time.monotonic()
                if now >= next_request:
                    self._send_request()
                    next_request = now + cfg.request_interval_s
                wait_s = max(0.0, next_request - time.monotonic())
            item = await self._next_line(wait_s)
            if item is None:
                continue  # request mode: time to ask again
            received, raw = item
            if received < started:
                continue  # buffered before this read began: not a fresh value
            # bytes that are not ASCII are kept visible as \xNN (a parity or baud mismatch shows in them), not
            # replaced by U+FFFD; and a line that has any is a bad frame before its text is looked at
            line = raw.decode("ascii", errors="backslashreplace")
            seen.last_line = line
            try:
                if not raw.isascii():
                    raise IoFrameError(self.name, "non-ASCII bytes (shown as \\xNN)", line)
                if len(raw) > cfg.max_line_bytes:  # also when it came whole in one chunk, not only cut from garbage
                    raise IoFrameError(self.name, f"line of {len(raw)} bytes, longer than max_line_bytes "
                                                  f"{cfg.max_line_bytes}", line)
                frame = parse_line(line, cfg, self.name, _regex=self._regex)
            except IoFrameError as exc:
                seen.bad += 1
                self.counters.bad_frames += 1
                self.last_error = exc
                self._log_once(exc)
                bad_in_a_row += 1
                if bad_in_a_row >= cfg.max_consecutive_bad_frames:
                    raise IoFrameError(
                        self.name, f"{bad_in_a_row} bad frames in a row, last: {exc.problem}", exc.raw
                    ) from exc
                continue
            bad_in_a_row = 0
            self.counters.frames += 1
            if not frame.stable:
                seen.unstable += 1
                self.counters.unstable_frames += 1
                run.clear()
                if require_stable:
                    continue
                return self._weighing(frame)
            seen.stable += 1
            self.counters.stable_frames += 1
            if not require_stable:
                return self._weighing(frame)
            if run and abs(frame.mass_kg - run[0].mass_kg) > cfg.resolution_kg:
                run.clear()  # stable, but a different value: start counting again
            run.append(frame)
            if len(run) >= cfg.stable_frames_required:
                return self._weighing(frame)

    async def _next_line(self, wait_s: float | None) -> tuple[float, bytes] | None:
        """The next queued line; None if ``wait_s`` passed first. A closed port is an ``IoLinkError``."""
        protocol = self._protocol
        if protocol is None:
            raise IoLinkError(self.name, "port is not open")
        try:
            if wait_s is None:
                item = await protocol.lines.get()
            else:
                async with asyncio.timeout(wait_s):
                    item = await protocol.lines.get()
        except TimeoutError:
            return None
        if item is None:
            protocol.lines.put_nowait(None)  # stay closed for whoever looks next
            raise IoLinkError(self.name, "the port closed (peer hung up or device removed)")
        return item

    def _send_request(self) -> None:
        transport = self._transport
        if transport is None or transport.is_closing():
            raise IoLinkError(self.name, "port is not open")
        try:
            transport.write(self.cfg.request_cmd.encode("ascii"))  # type: ignore[attr-defined]
        except (serial.SerialException, OSError) as exc:
            raise IoLinkError(self.name, f"write request: {exc}") from exc

    def _weighing(self, frame: ScaleFrame) -> Weighing:
        self._last_logged = ""
        return Weighing(
            mass_kg=frame.mass_kg,
            u_kg=self.cfg.u_kg,
            stable=frame.stable,
            raw_line=frame.raw_line,
            time_utc=datetime.now(UTC),
        )

    def _log_once(self, exc: IoFrameError) -> None:
        """Log each distinct bad-frame problem once per streak, not every line."""
        if exc.problem != self._last_logged:
            log.warning("%s", exc)
            self._last_logged = exc.problem


@dataclass
class _ReadLog:
    """What one read saw, for the timeout message."""

    stable: int = 0
    unstable: int = 0
    bad: int = 0
    last_line: str | None = None

    def summary(self, pending: bytes = b"") -> str:
        """The counts and the last line; ``pending``: bytes received after the last line end (a scale that stopped
        mid-line), shown so that the message says something did arrive."""
        text = f"{self.stable} stable, {self.unstable} unstable, {self.bad} bad frames; last line {self.last_line!r}"
        if pending:
            text += f"; then {len(pending)} bytes without a line end: {pending.decode('ascii', 'backslashreplace')!r}"
        return text
