"""The heartbeat of the controller-side watchdog (docs/security.md "Controller-side watchdog").

Every program the daemon pushes arms an interrupt on ``$TIMER_FLAG[16] OR $TIMER_STOP[16]`` before its first motion
(``krl/``, rule ``WATCHDOG`` of :mod:`rgse_daemon.safety.static`). This job keeps that timer below zero: every
``controller.watchdog_period_s`` it writes ``$TIMER[16] = -bound_ms`` and ``$TIMER_STOP[16] = FALSE``. The KR C4 counts
the timer up in ms; if no beat comes for ``controller.watchdog_bound_s``, it reaches 0, the interrupt fires and the
program brakes on its path and halts, with nothing needed from the host.

It beats on a connection of its own (one request at a time per connection: a snapshot, a file transfer or a stuck
request of the link's pool never delays a beat on the client side), and only while the controller link is up
(``link_up()``): a daemon that lost its link does not watch the robot, so the controller must stop it. A beat that
fails raises the ``heartbeat`` alarm (once; cleared by the next good beat). Once a second it reads the programs'
``RGSE_WD_TRIP``: while it is TRUE (the watchdog stopped a program; the next program start clears it) the
``watchdog_tripped`` alarm is up, so that a stop the daemon did not send is seen, with its cause. On a clean stop it
stops the timer, which trips the watchdog at once: the host no longer watches.
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
TRIPPED_ALARM = "watchdog_tripped"
#: The programs' flag (krl/rgse_globals.dat): TRUE once the watchdog's routine stopped a program.
TRIP_FLAG = "RGSE_WD_TRIP"
#: How often the trip flag is read (s).
TRIP_CHECK_S = 1.0


class Heartbeat:
    """Feeds the controller-side watchdog; see the module docstring. ``beats``/``failures`` count what it did,
    ``last_beat_s`` is the monotonic time of the last good beat (``None``: none yet)."""

    def __init__(self, cfg: ControllerConfig, alarms: Alarms, link_up: Callable[[], bool], *,
                 connection: Connection | None = None) -> None:
        """``connection``: the one it beats on; by default its own TCP connection to ``cfg``'s controller."""
        for name in (TIMER, TIMER_STOP):
            assert writable(name), name  # the allow-list admits exactly these two for the heartbeat
        self.cfg = cfg
        self.alarms = alarms
        self.link_up = link_up
        self.bound_ms = round(cfg.watchdog_bound_s * 1000.0)
        self.beats = 0
        self.failures = 0
        self.last_beat_s: float | None = None
        self._next_trip_check_s = 0.0
        self._conn = connection if connection is not None else Connection.from_config(cfg, name="heartbeat")

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
        if self.last_beat_s >= self._next_trip_check_s:
            self._next_trip_check_s = self.last_beat_s + TRIP_CHECK_S
            await self._check_tripped()

    async def _check_tripped(self) -> None:
        try:
            tripped = (await self._conn.read_var(TRIP_FLAG, timeout_s=self.deadline_s)).strip().upper() == "TRUE"
        except (LinkError, VariableError):
            return  # the next beat says whether the link is up; the globals' presence is rgse doctor's check
        if tripped:
            self.alarms.raise_(TRIPPED_ALARM, f"controller-side watchdog: it stopped a program ({TRIP_FLAG} is TRUE): "
                                              f"no heartbeat reached the controller within "
                                              f"{self.cfg.watchdog_bound_s:g} s; the program is halted")
        else:
            self.alarms.clear(TRIPPED_ALARM)
