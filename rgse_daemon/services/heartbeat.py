"""The heartbeat of the controller-side watchdog (docs/security.md "Controller-side watchdog").

Every program the daemon pushes arms an interrupt on ``$TIMER_FLAG[16] OR $TIMER_STOP[16]`` before its first motion
(``krl/``, rule ``WATCHDOG`` of :mod:`rgse_daemon.safety.static`). This job keeps that timer below zero: every
``controller.watchdog_period_s`` it writes ``$TIMER[16] = -bound_ms`` and ``$TIMER_STOP[16] = FALSE``. The KR C4 counts
the timer up in ms; if no beat comes for ``controller.watchdog_bound_s``, it reaches 0, the interrupt fires and the
program brakes on its path and halts, with nothing needed from the host.

It beats on a connection of its own (one request at a time per connection: a snapshot, a file transfer or a stuck
request of the link's pool never delays a beat on the client side), and only while the controller link is up
(``link_up()``): a daemon that lost its link does not watch the robot, so the controller must stop it. A beat that
fails raises the ``heartbeat`` alarm (once; cleared by the next good beat). On a clean stop it stops the timer, which
trips the watchdog at once: the host no longer watches.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable

from rgse_daemon.aio import within
from rgse_daemon.config import ControllerConfig
from rgse_daemon.errors import LinkError, VariableError
from rgse_daemon.link.connection import Connection
from rgse_daemon.safety.allowlist import WATCHDOG_TIMER, writable
from rgse_daemon.services.signals import Alarms

log = logging.getLogger("rgse_daemon.heartbeat")

TIMER = f"$TIMER[{WATCHDOG_TIMER}]"
TIMER_STOP = f"$TIMER_STOP[{WATCHDOG_TIMER}]"
ALARM = "heartbeat"


class Heartbeat:
    """Feeds the controller-side watchdog; see the module docstring. ``beats``/``failures`` count what it did,
    ``last_beat_s`` is the monotonic time of the last good beat (``None``: none yet)."""

    def __init__(self, cfg: ControllerConfig, alarms: Alarms, link_up: Callable[[], bool]) -> None:
        for name in (TIMER, TIMER_STOP):
            assert writable(name), name  # the allow-list admits exactly these two for the heartbeat
        self.cfg = cfg
        self.alarms = alarms
        self.link_up = link_up
        self.bound_ms = round(cfg.watchdog_bound_s * 1000.0)
        self.beats = 0
        self.failures = 0
        self.last_beat_s: float | None = None
        self._conn = Connection.from_config(cfg, name="heartbeat")

    @property
    def deadline_s(self) -> float:
        """A beat that takes longer than this is late: the next one is due."""
        return min(self.cfg.request_timeout_s, self.cfg.watchdog_bound_s)

    async def beat(self) -> None:
        """One beat: the timer to -bound (first, so that starting it never runs from a stale value), then running."""
        await self._conn.write_var(TIMER, str(-self.bound_ms), timeout_s=self.deadline_s)
        await self._conn.write_var(TIMER_STOP, "FALSE", timeout_s=self.deadline_s)

    async def run(self, stop: asyncio.Event) -> None:
        """Beat every ``watchdog_period_s`` while the link is up, until ``stop``; then stop the timer."""
        period_s = self.cfg.watchdog_period_s
        try:
            while not stop.is_set():
                t0 = time.monotonic()
                if self.link_up():
                    await self._beat_once()
                with contextlib.suppress(TimeoutError):
                    await within(stop.wait(), max(0.0, period_s - (time.monotonic() - t0)))
            with contextlib.suppress(LinkError, VariableError, TimeoutError):
                await self._conn.write_var(TIMER_STOP, "TRUE", timeout_s=self.deadline_s)
        finally:
            await self._conn.close()

    async def _beat_once(self) -> None:
        try:
            await self.beat()
        except (LinkError, VariableError) as exc:
            self.failures += 1
            self.alarms.raise_(ALARM, f"controller-side watchdog: heartbeat failed ({exc}); the controller stops any "
                                      f"motion {self.cfg.watchdog_bound_s:g} s after the last good beat")
            return
        self.beats += 1
        self.last_beat_s = time.monotonic()
        self.alarms.clear(ALARM)
