"""Run admission: the robot is one resource, so one run at a time, and a run starts only on a connected controller,
in T1 — or in AUT with the safety I/O module's inputs all good."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from dataclasses import replace
from typing import Any

from rgse_daemon.config import Config
from rgse_daemon.errors import LinkError, RgseError
from rgse_daemon.krc import KrcController
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.makesafe import STOP_DEADLINE_S
from rgse_daemon.services.link import DaemonCounters
from rgse_daemon.store import RunKind, Store

log = logging.getLogger("rgse_daemon.app")

#: Bounded wait for a cancelled run to end (s).
STOP_TIMEOUT_S = 15.0
#: Bounded wait for a run to end by itself after the controller link was lost (s): the interlock's stop confirmation
#: (at most :data:`~rgse_daemon.safety.makesafe.STOP_DEADLINE_S`) and the run's finaliser and records after it.
LINK_LOSS_END_S = STOP_DEADLINE_S + STOP_TIMEOUT_S
#: How long ``measure``/``calibrate`` wait for the run to start before answering without its run id (s).
RUN_START_TIMEOUT_S = 10.0


class Busy(RgseError):
    """A run is already in progress: the robot is one resource."""


class NotConnected(RgseError):
    """The controller link is not up (yet): no run can start."""


class RunAdmission:
    """Admits one run at a time and holds it: ``task``, ``kind``, its run id once started, its outcome.

    ``on_failed(kind, run_id, error)`` is told when a run ends in an error (the daemon alarms and lights red);
    ``on_link_lost(why)`` before it when that error is the controller link's (the daemon raises the ``link`` alarm).
    ``on_refused(kind, reason)`` is told when a run request is refused before the run started — busy, stopping, not
    connected, the safety latch (:meth:`refuse`), or the run's own start checks (:class:`PreconditionError`: mode,
    no active calibration, ...). A refusal is a request answered "no": nothing was recorded or moved, so it is not a
    failed run (the daemon publishes ``run_refused`` and leaves the stack light as it is).
    """

    def __init__(self, cfg: Config, counters: DaemonCounters, inputs: Callable[[], SafetyInputs | None],
                 on_failed: Callable[[RunKind, str | None, str], None],
                 on_refused: Callable[[RunKind, str], None],
                 on_link_lost: Callable[[str], None] | None = None) -> None:
        self.cfg = cfg
        self.counters = counters
        self._inputs = inputs
        self._on_failed = on_failed
        self._on_refused = on_refused
        self._on_link_lost = on_link_lost
        self.task: asyncio.Task[Any] | None = None
        self.kind: RunKind | None = None
        self.engine: RunEngine | None = None
        """The engine of the current (or last) run: the daemon's own, or a dry run's (abort and confirm go to it)."""
        self.stopping = False
        self.last_result: Any = None
        self.last_error: str | None = None
        self._started: asyncio.Future[str | None] | None = None

    @property
    def active(self) -> bool:
        return self.task is not None and not self.task.done()

    @property
    def run_id(self) -> str | None:
        """The run id of the current (or last) run, once it has started."""
        started = self._started
        return started.result() if started is not None and started.done() else None

    def mark_started(self, run_id: str | None) -> None:
        """The engine says the run is running (its ``state`` event)."""
        started = self._started
        if started is not None and not started.done():
            started.set_result(run_id)
            self.counters.runs_started += 1

    def refuse(self, kind: RunKind, exc: RgseError) -> RgseError:
        """Count and report the refusal of a ``kind`` run request for the reason ``exc``; returns ``exc`` to raise."""
        self.counters.runs_refused += 1
        log.warning("%s run refused: %s", kind, exc)
        self._on_refused(kind, str(exc))
        return exc

    def start(self, kind: RunKind, coro_factory: Callable[[RunEngine, Store], Awaitable[Any]], *,
              engine: RunEngine | None, krc: KrcController | None, store: Store, connected: bool,
              link_error: str | None) -> asyncio.Task[Any]:
        """Reserve the robot for one run (synchronously: no second request can slip in) and start it in a task."""
        if self.stopping:
            raise self.refuse(kind, Busy("busy: the daemon is stopping"))
        if self.active:
            run_id = self.run_id
            raise self.refuse(kind, Busy(f"busy: a {self.kind} run{f' ({run_id})' if run_id else ''} is in progress; "
                                         "abort it first or wait"))
        if engine is None or krc is None or not connected:
            c = self.cfg.controller
            why = f" ({link_error})" if link_error else ""
            raise self.refuse(kind, NotConnected(f"not connected: controller {c.host}:{c.port} is not connected{why}"))
        self.kind = kind
        self.engine = engine
        self._started = started = asyncio.get_running_loop().create_future()

        async def runner() -> Any:
            try:
                await self.check_start_mode(krc, engine)
                result = await coro_factory(engine, store)
            except asyncio.CancelledError:
                raise
            except PreconditionError as exc:
                if started.done():  # a check inside the run (the plan's 'verify'): the run failed
                    self._failed(kind, exc)
                else:  # refused in its start checks (mode, no active calibration, ...): not a run
                    self.refuse(kind, exc)
                raise
            except Exception as exc:  # link, store, a bug: a failure even before the run started
                self._failed(kind, exc)
                raise
            self.last_result = result
            return result

        self.task = asyncio.create_task(runner(), name=f"rgse-run-{kind}")
        self.task.add_done_callback(lambda t: t.cancelled() or t.exception())  # retrieved: logged above
        return self.task

    def _failed(self, kind: RunKind, exc: Exception) -> None:
        self.last_error = f"{type(exc).__name__}: {exc}"
        log.error("%s run failed: %s", kind, self.last_error)
        if isinstance(exc, LinkError) and self._on_link_lost is not None:  # the run's own request saw the link go
            self._on_link_lost(str(exc) or type(exc).__name__)
        self._on_failed(kind, self.run_id, self.last_error)

    async def check_start_mode(self, krc: KrcController, engine: RunEngine) -> None:
        """Before anything is recorded or moved: AUT only with the safety I/O module's inputs all good (area
        cleared, key switch AUT permitted, E-stop OK, a fresh reading), in T1 with a configured module only when it
        reads and says E-stop OK, else :class:`PreconditionError` — the plan's
        own preconditions, the static check and the monitor check it again. The runtime monitor then allows exactly
        the mode the run starts in (T1, or AUT when the module is configured): a mode change during the run trips."""
        timeout_s = self.cfg.controller.request_timeout_s * 2
        try:
            async with asyncio.timeout(timeout_s):
                snap = await krc.snapshot()
        except TimeoutError as exc:
            raise LinkError(f"no controller snapshot within {timeout_s:g} s") from exc
        mode = snap.mode_op
        inputs = self._inputs()
        if mode == "AUT":
            if inputs is None or not inputs.safe:
                why = "no safety I/O module configured" if inputs is None else (
                    inputs.reason or ", ".join(n for n, ok in (("area not cleared", inputs.area_cleared),
                                                               ("AUT key not turned", inputs.aut_permitted),
                                                               ("E-stop not OK", inputs.estop_ok)) if not ok))
                raise PreconditionError(f"refused to start: AUT needs the area cleared, the AUT key and E-stop OK "
                                        f"({why})")
        elif inputs is not None and not (inputs.valid and inputs.estop_ok):
            # a configured safety I/O module that cannot be read (or reads E-stop not OK) refuses the run here, before
            # a campaign's first prompt asks somebody to mount a load, not after it (issue #34)
            raise PreconditionError("refused to start: " + (
                "E-stop chain not OK on the safety I/O module" if inputs.valid else
                f"E-stop state unknown: safety inputs invalid ({inputs.reason}); check it with rgse doctor"))
        if engine.monitor is not None:
            allowed = {mode} if mode == "T1" or (mode == "AUT" and inputs is not None) else {"T1"}
            engine.monitor.context = replace(engine.monitor.context, allowed_modes=frozenset(allowed))

    async def started(self, task: asyncio.Task[Any]) -> str | None:
        """Wait until the run has started (its run id; None for a dry run) or has failed before (raises why)."""
        started = self._started
        assert started is not None
        await asyncio.wait({started, task}, timeout=RUN_START_TIMEOUT_S, return_when=asyncio.FIRST_COMPLETED)
        if started.done():
            return started.result()
        if task.done():
            if task.cancelled():
                raise RgseError("the run was cancelled before it started")
            exc = task.exception()
            if exc is not None:
                raise exc
        return None

    async def stop(self) -> None:
        """Cancel the run in progress (its finaliser makes the robot safe, the store marks it interrupted) and wait,
        bounded — call it while the controller link is still open."""
        task = self.task
        if task is None or task.done():
            return
        if task.cancelling() == 0:  # once: a second cancel would interrupt the finaliser that makes the robot safe
            log.warning("stopping: cancelling the %s run in progress", self.kind)
            task.cancel()
        done, _ = await asyncio.wait({task}, timeout=STOP_TIMEOUT_S)
        if not done:
            log.error("the %s run did not end within %.0f s of its cancellation", self.kind, STOP_TIMEOUT_S)

    async def wait_end(self) -> None:
        """After a lost link: the run ends by itself (the interlock trips on the lost link, then confirms its stop,
        at most the make-safe deadline), bounded by :data:`LINK_LOSS_END_S`; a run still going then is stopped as
        :meth:`stop` does."""
        task = self.task
        if task is None or task.done():
            return
        done, _ = await asyncio.wait({task}, timeout=LINK_LOSS_END_S)
        if not done:
            log.error("the %s run did not end within %.0f s of the lost link: cancelling it", self.kind,
                      LINK_LOSS_END_S)
            await self.stop()
