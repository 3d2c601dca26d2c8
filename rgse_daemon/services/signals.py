"""What the people at the robot see of the daemon without a screen: the stack light, and daemon-level alarms."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

from rgse_daemon.errors import RgseError
from rgse_daemon.procedures.engine import EngineState

log = logging.getLogger("rgse_daemon.app")

#: Deadline of one stack light update (s).
LIGHT_TIMEOUT_S = 2.0

#: Stack light colour of each engine state (states not named leave the light as it is).
STATE_LIGHT: dict[str, str] = {
    EngineState.RUNNING: "yellow", EngineState.PAUSED: "yellow", EngineState.CONFIRM: "yellow",
    EngineState.DONE: "green", EngineState.IDLE: "green", EngineState.FAILED: "red", EngineState.ABORTED: "red",
}


class StackLight:
    """The safety I/O module's stack light and "measurement running" output.

    Wishes are kept, and one task writes the latest, in order (yellow also sets "running"). The module remembers
    both and writes them again after a reconnect, so a failed write is only logged. Without a module it does nothing.
    """

    def __init__(self, io: Any) -> None:
        self.io = io  # rgse_daemon.io.modbus.SafetyIo, or None
        self._wanted: str | None = None
        self._wake = asyncio.Event()

    @property
    def color(self) -> str | None:
        """The colour last asked for (``None`` without a module or before any)."""
        return self._wanted

    def want(self, color: str) -> None:
        if self.io is None:
            return
        self._wanted = color
        self._wake.set()

    def want_for_state(self, state: str | None) -> None:
        color = STATE_LIGHT.get(state or "")
        if color is not None:
            self.want(color)

    async def run(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            if self._wanted is not None:
                await self.write(self._wanted)

    async def write(self, color: str) -> None:
        from rgse_daemon.io import IoLinkError
        from rgse_daemon.io.modbus import LightColor

        io = self.io
        for what, write in (("stack light", lambda: io.set_light(LightColor(color))),
                            ("running output", lambda: io.set_running(color == "yellow"))):
            try:
                async with asyncio.timeout(LIGHT_TIMEOUT_S):
                    await write()
            except IoLinkError as exc:  # the module's own poller reports its link; the wish is kept
                log.debug("%s %s not written now: %s", what, color, exc)
            except (TimeoutError, RgseError) as exc:
                log.warning("%s %s not written: %s", what, color, exc)


class Alarms:
    """Daemon-level alarms (link lost, controller unreachable): each kind is logged and published once, and again only
    after it cleared (architecture lesson 11). An alarm turns the stack light red."""

    def __init__(self, publish: Callable[[dict[str, Any]], None], light: StackLight) -> None:
        self._publish = publish
        self._light = light
        self.active: set[str] = set()

    def raise_(self, kind: str, message: str) -> None:
        if kind in self.active:
            return
        self.active.add(kind)
        log.error("%s", message)
        self._publish({"kind": kind, "message": message})
        self._light.want("red")

    def clear(self, kind: str) -> None:
        if kind in self.active:
            self.active.discard(kind)
            log.info("%s alarm cleared", kind)
