"""A simulated Kern crane scale on a pseudo-terminal or on TCP (for ``socket://`` URLs).

Public API
----------
``ScaleSimConfig``      true mass, resolution d, noise, settling phase, unit, stream period, garbling, checksum.
``ScaleSim(cfg, transport="pty" | "tcp")``
    ``await sim.start()`` / ``await sim.stop()`` or ``async with``; ``sim.url`` is the pty's device path or
    ``socket://127.0.0.1:PORT``, ready for ``ScaleConfig(port=sim.url)``.
    ``sim.set_mass(kg)`` hangs a new load: the scale swings (unstable frames) for ``settle_s`` again.
    ``sim.lines_sent``, ``sim.garbled_sent``, ``sim.requests`` (commands received), ``sim.dropped``.

Behaviour (see ``rgse_daemon.io.scale`` for the line format it speaks):

* After a load change it sends ``US`` frames with a decaying swing for ``settle_s`` seconds (forever with
  ``never_stable``), then ``ST`` frames whose noise is clipped to the stability band ±d/2, so a stable
  reading lies within ±d of the true mass (half a digit of noise plus half a digit of rounding).
* Values are shown rounded to the display step: d converted to the configured unit and rounded down to a
  1-2-5 step (0.1 kg -> 100 g, 0.0001 t, 0.2 lb).
* Commands (bare ASCII, no CR LF): ``S``/``s`` answers with the next stable frame (waits while settling; several
  waiting ``S`` give one answer), ``W``/``w`` answers at once; ``T``, ``Z`` and unknown bytes are ignored.
* With ``stream_period_s`` set it also sends a frame every period (continuous output).
* With ``garble_rate`` > 0 that fraction of frames is garbled: characters replaced by bytes that cannot
  appear in a frame, the line truncated, or the unit replaced by ``pcs`` (counting mode).
* On a pty, frames that nobody reads are dropped once the kernel buffer is full (as on a real RS-232 line).
"""

from __future__ import annotations

import asyncio
import math
import os
import random
import time
import tty
from dataclasses import dataclass
from typing import Literal

from rgse_daemon.io.scale import UNIT_TO_KG, xor8

Transport = Literal["pty", "tcp"]
_GARBLE_KINDS = ("bad_chars", "truncated", "wrong_unit")
_BAD_BYTES = b"\x00\xff\x1b~"


@dataclass
class ScaleSimConfig:
    true_mass_kg: float = 117.6
    resolution_kg: float = 0.1
    noise_kg: float = 0.03
    """Standard deviation of the reading noise; when stable it is clipped to ±d/2."""
    settle_s: float = 0.3
    swing_kg: float = 4.0
    """Amplitude of the swinging load right after it was hung; decays over ``settle_s``."""
    never_stable: bool = False
    unit: Literal["kg", "g", "t", "lb"] = "kg"
    stream_period_s: float | None = None
    garble_rate: float = 0.0
    checksum: bool = False
    net: bool = False
    seed: int | None = 0
    tick_s: float = 0.005


def display_step(resolution_kg: float, unit: str) -> float:
    """The resolution converted to ``unit`` and rounded down to a 1-2-5 step."""
    raw = resolution_kg / UNIT_TO_KG[unit]
    decade = 10.0 ** math.floor(math.log10(raw))
    return max(m * decade for m in (1.0, 2.0, 5.0) if m * decade <= raw * (1 + 1e-9))


class ScaleSim:
    """One simulated scale. The frame logic is transport-agnostic; ``_emit`` writes to the pty or every client."""

    def __init__(self, cfg: ScaleSimConfig | None = None, transport: Transport = "pty") -> None:
        self.cfg = cfg or ScaleSimConfig()
        self.transport = transport
        self.url = ""
        self.lines_sent = 0
        self.garbled_sent = 0
        self.requests = 0
        self.dropped = 0
        self._rng = random.Random(self.cfg.seed)
        self._mass_kg = self.cfg.true_mass_kg
        self._loaded_at = time.monotonic()
        self._pending_stable = False
        self._ticker: asyncio.Task[None] | None = None
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._server: asyncio.Server | None = None
        self._clients: dict[asyncio.Task[None], asyncio.StreamWriter] = {}
        self._step = display_step(self.cfg.resolution_kg, self.cfg.unit)
        self._decimals = max(0, -math.floor(math.log10(self._step) + 1e-9))

    # test-side controls -----------------------------------------------------------------------------------
    @property
    def true_mass_kg(self) -> float:
        return self._mass_kg

    def set_mass(self, mass_kg: float) -> None:
        """Hang a new load: the reading swings again for ``settle_s``."""
        self._mass_kg = mass_kg
        self._loaded_at = time.monotonic()

    @property
    def stable_now(self) -> bool:
        return not self.cfg.never_stable and time.monotonic() - self._loaded_at >= self.cfg.settle_s

    # frames -----------------------------------------------------------------------------------------------
    def frame_line(self) -> bytes:
        """The line the scale would send now (CR LF included), garbled at the configured rate."""
        cfg = self.cfg
        stable = self.stable_now
        noise = self._rng.gauss(0.0, cfg.noise_kg)
        if stable:
            half_band = cfg.resolution_kg / 2.0
            noise = min(half_band, max(-half_band, noise))
            mass = self._mass_kg + noise
        else:
            t = time.monotonic() - self._loaded_at
            decay = math.exp(-t / max(cfg.settle_s, 1e-3) * 2.0)
            mass = self._mass_kg + cfg.swing_kg * decay * math.sin(2 * math.pi * t / 0.15) + noise
        shown = round(mass / UNIT_TO_KG[cfg.unit] / self._step) * self._step
        body = (
            f"{'ST' if stable else 'US'},{'NT' if cfg.net else 'GS'},{'-' if shown < 0 else '+'}"
            f"{abs(shown):>10.{self._decimals}f} {cfg.unit:>2}"
        )
        if cfg.checksum:
            body += f"*{xor8(body.encode('ascii')):02X}"
        raw = body.encode("ascii")
        if cfg.garble_rate > 0.0 and self._rng.random() < cfg.garble_rate:
            raw = self._garble(raw)
            self.garbled_sent += 1
        return raw + b"\r\n"

    def _garble(self, body: bytes) -> bytes:
        kind = self._rng.choice(_GARBLE_KINDS)
        if kind == "bad_chars":
            out = bytearray(body)
            for _ in range(self._rng.randint(1, 3)):
                out[self._rng.randrange(len(out))] = self._rng.choice(_BAD_BYTES)
            return bytes(out)
        if kind == "truncated":
            unit_at = body.rfind(self.cfg.unit.encode("ascii"))
            return body[: self._rng.randint(3, max(3, unit_at + len(self.cfg.unit) - 1))]
        text = body.decode("ascii")
        unit_field = f" {self.cfg.unit:>2}"
        head, _, tail = text.rpartition(unit_field)
        return (head + " pcs" + tail).encode("ascii")

    def _on_command_bytes(self, data: bytes) -> None:
        for byte in data:
            char = chr(byte)
            if char in "\r\n":
                continue
            self.requests += 1
            if char in "Ss":
                self._pending_stable = True
            elif char in "Ww":
                self._emit(self.frame_line())

    def _emit(self, line: bytes) -> None:
        self.lines_sent += 1
        if self._master_fd is not None:
            try:
                os.write(self._master_fd, line)
            except (BlockingIOError, OSError):
                self.dropped += 1
        for writer in list(self._clients.values()):
            if not writer.is_closing():
                writer.write(line)

    async def _tick(self) -> None:
        """Serve waiting ``S`` requests once stable and send the continuous output when due."""
        next_stream = time.monotonic()
        while True:
            if self._pending_stable and self.stable_now:
                self._pending_stable = False
                self._emit(self.frame_line())
            period = self.cfg.stream_period_s
            if period is not None and time.monotonic() >= next_stream:
                next_stream = max(next_stream + period, time.monotonic() - period)
                self._emit(self.frame_line())
            await asyncio.sleep(self.cfg.tick_s)

    # transports -------------------------------------------------------------------------------------------
    async def start(self) -> None:
        if self._ticker is not None:
            return
        self._loaded_at = time.monotonic()
        if self.transport == "pty":
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no CR/LF translation: bytes pass as on a serial line
            os.set_blocking(master, False)
            self._master_fd, self._slave_fd = master, slave  # keep the slave open: no EIO when clients go
            asyncio.get_running_loop().add_reader(master, self._read_pty)
            self.url = os.ttyname(slave)
        else:
            self._server = await asyncio.start_server(self._serve_client, "127.0.0.1", 0)
            port = self._server.sockets[0].getsockname()[1]
            self.url = f"socket://127.0.0.1:{port}"
        self._ticker = asyncio.create_task(self._tick(), name="scale sim tick")

    async def stop(self) -> None:
        ticker, self._ticker = self._ticker, None
        if ticker is not None:
            ticker.cancel()
            await asyncio.wait({ticker})
        if self._master_fd is not None:
            asyncio.get_running_loop().remove_reader(self._master_fd)
            os.close(self._master_fd)
            self._master_fd = None
        if self._slave_fd is not None:
            os.close(self._slave_fd)
            self._slave_fd = None
        server, self._server = self._server, None
        if server is not None:
            server.close()
        clients, self._clients = self._clients, {}
        for task, writer in clients.items():
            writer.close()
            task.cancel()
        if clients:
            await asyncio.wait(list(clients))
        if server is not None:
            async with asyncio.timeout(5.0):
                await server.wait_closed()

    async def __aenter__(self) -> ScaleSim:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def _read_pty(self) -> None:
        if self._master_fd is None:
            return
        try:
            data = os.read(self._master_fd, 1024)
        except (BlockingIOError, OSError):
            return
        self._on_command_bytes(data)

    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients[task] = writer
        try:
            while data := await reader.read(256):
                self._on_command_bytes(data)
        except (ConnectionError, OSError):
            pass  # the client went away: its task ends
        finally:
            self._clients.pop(task, None)
            writer.close()
