"""Controller supervision: keep the KR C4 link up, notice its loss while idle, and reconnect with backoff.

During a run the interlock monitor reads the controller at 20 Hz and trips on a lost link (the daemon then raises
the ``link`` alarm through :meth:`ControllerLink.lost_during_run`); while idle this job probes it every
:data:`LINK_PROBE_S`. A loss clears ``connected``, raises the ``link`` alarm once, and the link is opened anew with
jittered exponential backoff between ``reconnect_min_s`` and ``reconnect_max_s``.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import random
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from rgse_daemon.aio import within
from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.errors import LinkError, VariableError
from rgse_daemon.filelayout import load_layout
from rgse_daemon.link.connection import Connection, ServerLoad
from rgse_daemon.services.signals import Alarms

log = logging.getLogger("rgse_daemon.app")

#: How often the idle controller link is probed (s).
LINK_PROBE_S = 1.0


@dataclass
class DaemonCounters:
    """What the daemon did since it started; published in the ``state`` message under ``"daemon"``."""

    controller_connects: int = 0
    controller_connect_failures: int = 0
    link_losses: int = 0
    """Losses of an established controller link."""
    runs_started: int = 0
    """Runs that started (the engine ran them): a run refused in its start checks is not one."""
    runs_refused: int = 0
    """Run requests refused: busy, stopping, not connected, safety latch, or the run's own start checks (mode,
    no active calibration, ...) before it started; each is also published as a ``run_refused`` alarm. A run that
    fails before it started for another reason (link, store) is a failed run, counted in neither."""

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class ControllerLink:
    """The controller link as a standing job: ``krc`` is the open controller (None while down), ``connected`` is set
    while it is up, ``error`` says why it is not.

    ``on_up(krc)`` runs after every (re)connect, before the link counts as supervised; ``on_down(lost)`` runs before
    the link closes, with ``lost`` None on a requested stop, else why the link was lost. ``prepare(krc)`` (optional)
    runs after every (re)connect *before* ``connected`` is set: no run can be admitted while it runs (the daemon
    stops what a previous daemon or link left running, :mod:`rgse_daemon.services.recovery`).
    """

    def __init__(self, cfg: ControllerConfig, counters: DaemonCounters, alarms: Alarms,
                 busy: Callable[[], bool], data_dir: Path | None = None) -> None:
        self.cfg = cfg
        self.data_dir = data_dir  # where `rgse doctor` recorded the controller's file layout
        self.counters = counters
        self.alarms = alarms
        self.busy = busy
        self.connected = asyncio.Event()
        self.load = ServerLoad()
        """The controller's file work in flight, one for its single-threaded server across reconnects: the pool's
        connections and the heartbeat's share it, so a request queued behind a pull is late, not lost."""
        self.krc: Controller | None = None
        self.error: str | None = None
        self.connecting = False
        """True while a connect attempt is in flight (the only phase a shutdown may cancel)."""

    def heartbeat_connection(self) -> Connection:
        """The heartbeat's connection of its own to this controller, sharing :attr:`load`: a beat queued behind a
        pull longer than ``watchdog_bound_s`` gets the pull's deadline added (late, not lost), as every request of
        the pool does. The controller's bound is not touched: its timer still runs out ``watchdog_bound_s`` after
        the last beat that arrived, and no program runs during file work (docs/file-window.md), so nothing the
        watchdog guards moves meanwhile."""
        return Connection.from_config(self.cfg, name="heartbeat", load=self.load)

    @property
    def where(self) -> str:
        return f"controller {self.cfg.host}:{self.cfg.port}"

    def backoff_s(self, attempt: int) -> float:
        """Exponential backoff between ``reconnect_min_s`` and ``reconnect_max_s``, jittered (× 0.5…1)."""
        c = self.cfg
        return min(c.reconnect_max_s, c.reconnect_min_s * 2.0 ** min(attempt, 30)) * random.uniform(0.5, 1.0)

    async def run(self, stop: asyncio.Event, on_up: Callable[[Controller], Awaitable[None]],
                  on_down: Callable[[str | None], Awaitable[None]],
                  prepare: Callable[[Controller], Awaitable[None]] | None = None) -> None:
        """Keep the controller connected until ``stop``; the first connect may fail (controller booting), a link may
        be lost: back off and connect anew."""
        attempt = 0
        while not stop.is_set():
            up_at: float | None = None
            self.connecting = True
            try:
                # the TRACE path form and listing format `rgse doctor` found on this controller (probed if none)
                layout = load_layout(self.data_dir) if self.data_dir is not None else None
                async with Controller.connect(self.cfg, layout=layout, load=self.load) as krc:
                    self.connecting = False
                    if prepare is not None:
                        await prepare(krc)
                    self.krc = krc
                    self.counters.controller_connects += 1
                    self.error = None
                    self.connected.set()
                    up_at = time.monotonic()
                    log.info("%s connected (%s)", self.where, krc.protocol)
                    self.alarms.clear("link")
                    await on_up(krc)
                    lost = await self._supervise(krc, stop)
                    self.connected.clear()
                    if lost is not None:
                        self.counters.link_losses += 1
                        self.error = lost
                        self.alarms.raise_("link", f"{self.where} link lost: {lost}")
                    await on_down(lost)
            except LinkError as exc:
                self.counters.controller_connect_failures += 1
                self.error = str(exc) or type(exc).__name__
                self.alarms.raise_("link", f"{self.where} unreachable: {self.error}")
            except Exception as exc:  # a bug must not end the controller link for good: say so, back off, retry
                log.exception("controller loop: unexpected error")
                self.error = f"{type(exc).__name__}: {exc}"
                self.alarms.raise_("link", f"{self.where}: unexpected error: {self.error}")
            finally:
                self.connecting = False
                self.connected.clear()
                self.krc = None
            if stop.is_set():
                return
            if up_at is not None and time.monotonic() - up_at >= self.cfg.reconnect_max_s:
                attempt = 0  # the link held: the next connect starts quick again (a link that fails right after
                #              its connect, e.g. in ``prepare``, keeps backing off instead of retrying at once)
            with contextlib.suppress(TimeoutError):
                await within(stop.wait(), self.backoff_s(attempt))
            attempt += 1

    def lost_during_run(self, why: str) -> None:
        """The link failed under a run (the interlock's ``link`` trip, or a request of the run): the run's own
        supervision saw it, not this job's idle probe, and the link may be back before the run has ended. Counted and
        alarmed as any loss; cleared by the next good probe or connect."""
        if "link" not in self.alarms.active:
            self.counters.link_losses += 1
        self.alarms.raise_("link", f"{self.where} link lost during a run: {why}")

    async def _supervise(self, krc: Controller, stop: asyncio.Event) -> str | None:
        """Wait for ``stop`` (returns None) or for the loss of the idle link (returns why)."""
        c = self.cfg
        probe_s = c.connect_timeout_s + c.request_timeout_s
        while True:
            with contextlib.suppress(TimeoutError):
                await within(stop.wait(), LINK_PROBE_S)
                return None
            if self.busy():
                continue  # the interlock monitor reads the controller at 20 Hz and trips on link loss
            try:
                async with asyncio.timeout(probe_s):
                    await krc.read_raw("$MODE_OP")
            except VariableError:
                self.alarms.clear("link")
                continue  # the controller answered: the link is up
            except TimeoutError:
                return f"no answer to a probe within {probe_s:g} s"
            except LinkError as exc:
                return str(exc) or type(exc).__name__
            self.alarms.clear("link")  # it answered: a loss seen during a run is over
