"""The run engine: executes plans (generators of :mod:`~rgse_daemon.procedures.messages`) against the controller.

::

    engine = RunEngine(krc, checker=static_checker(cfg), monitor=Monitor(krc), share_dir=cfg.controller.share_dir)
    engine.subscribe(lambda ev: queue.put_nowait(ev))          # progress, alarms, confirm prompts, results
    engine.subscribe_documents(on_document)                    # run documents, once the recorder has them
    result = await engine.execute(OpenRun(...), lambda run: measurement_plan(run, ...), recorder)
    engine.pause(); engine.resume(); engine.abort("operator"); engine.confirm()   # from CLI/MQTT commands

What the engine guarantees, whatever the plan does (bluesky's RunEngine + ``finalize_wrapper``, architecture
lessons 1–3):

* **Finaliser.** Every plan runs inside :func:`finalize_wrapper` with :func:`make_safe`: stop the trace if one is
  armed or recording, stop the program, leave the robot holding still — on success, error, abort, interlock trip or
  task cancellation. Each cleanup step has a deadline; a cleanup error is logged and never masks the plan's error.
* **Interlock.** A :class:`~rgse_daemon.safety.monitor.Monitor` polls while the plan runs (not in a dry run). A trip
  stops program and trace at once, publishes an ``alarm`` event and fails the plan with
  :class:`~rgse_daemon.safety.monitor.InterlockTrip`, interrupting whatever message was executing.
* **Static check before motion.** ``Push`` runs the checker (the interlock's static check against the live
  snapshot) and refuses before a byte reaches the controller; a refusal is an ``alarm`` too. Every ``Push`` is
  checked; one whose bytes this plan already wrote to the controller since the last program start (a move pushed
  ahead while the robot stood still) sends nothing again.
* **Pause/resume** take effect at ``Checkpoint`` messages (robot still, nothing recording); **abort** interrupts
  at once with :class:`PlanAborted` (then the finaliser runs); cancelling the task does the same and re-raises.
* **Dry run:** only messages whose type is ``inert`` execute; every other one is logged and answered with its
  ``dry_reply()`` (``Push`` still runs the static check on the live state first). Nothing is sent, nothing recorded.
* **One run skeleton** (:meth:`RunEngine.execute`): ``OpenRun`` to the recorder, the plan, ``CloseRun`` with how it
  ended (completed, aborted, failed, interrupted on cancellation) — for the measurement and the campaign alike.
  Documents the plan yields go to the recorder (awaited, bounded), then to the document subscribers.
* **States** (:class:`EngineState`) change only along :data:`TRANSITIONS`; anything else is a bug and raises.
* Every wait on the outside world has a deadline; ``CancelledError`` is never swallowed.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import logging
import time
from collections.abc import Callable, Coroutine
from enum import StrEnum
from pathlib import Path
from typing import Any

from rgse_daemon.aio import within
from rgse_daemon.errors import InterlockError, LinkError, RgseError
from rgse_daemon.krc import KrcController, Snapshot
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.events import Event, Subscriber
from rgse_daemon.procedures.messages import PROGRAM_DIR
from rgse_daemon.procedures.retrieval import TRACE_DIR, pull_trace
from rgse_daemon.safety.monitor import TRACE_ACTIVE_STATES, Expect, InterlockTrip, Monitor
from rgse_daemon.store import RunState
from rgse_daemon.store.final import retry_final

_log = logging.getLogger(__name__)

__all__ = ["PROGRAM_DIR", "EngineState", "PlanAborted", "ProgramChecker", "RunEngine"]

#: Deadline of each step of the finaliser (s).
CLEANUP_TIMEOUT_S = 5.0
#: Deadline of single requests the engine sends (select, start, write) (s).
REQUEST_TIMEOUT_S = 10.0
#: How often waits poll the controller (s).
WAIT_POLL_S = 0.02
#: Deadline of one document's recording (the store) (s).
RECORD_TIMEOUT_S = 30.0
#: Deadline of recording how a run ended (s); shielded from cancellation.
CLOSE_TIMEOUT_S = 10.0

DocumentSubscriber = Callable[[d.Document], None]
"""Sees every document after the recorder made it durable; called on the event loop, must not block."""

ProgramChecker = Callable[..., None]
"""``checker(program, snapshot)``: raise :class:`InterlockError` if ``program`` may not run in the state ``snapshot``
shows. After a plan's ``Mounted`` it is called with ``payload=(kg, cog_flange_m)`` too (the load just mounted)."""


class EngineState(StrEnum):
    """What the engine is doing; published as ``state`` events and in the daemon's retained ``state`` topic."""

    IDLE = "idle"  # no plan has run yet
    RUNNING = "running"
    PAUSED = "paused"  # at a checkpoint, waiting for resume (or abort)
    CONFIRM = "confirm"  # waiting for the operator's confirmation (a campaign point mounted)
    DONE = "done"
    FAILED = "failed"
    ABORTED = "aborted"


_ENDED = frozenset({EngineState.DONE, EngineState.FAILED, EngineState.ABORTED})
#: The legal state changes. A plan ends from any state it can be in when an error, an abort or a cancellation
#: arrives (paused or waiting for the operator included); ended states start the next plan.
TRANSITIONS: dict[EngineState, frozenset[EngineState]] = {
    EngineState.IDLE: frozenset({EngineState.RUNNING}),
    EngineState.RUNNING: frozenset({EngineState.PAUSED, EngineState.CONFIRM, *_ENDED}),
    EngineState.PAUSED: frozenset({EngineState.RUNNING, *_ENDED}),
    EngineState.CONFIRM: frozenset({EngineState.RUNNING, *_ENDED}),
    **{s: frozenset({EngineState.RUNNING}) for s in _ENDED},
}


class EngineStateError(RgseError):
    """A state change outside :data:`TRANSITIONS` (a bug in the engine)."""


class PlanAborted(RgseError):
    """The plan was aborted (operator, MQTT ``abort``); the finaliser ran."""


class StepTimeout(RgseError):
    """A controller wait (program end, trace written, operator confirmation) passed its deadline."""


class ProgramStopped(RgseError):
    """The program stopped (``#P_STOP``) or was reset while the plan waited for its end."""


# --- plan helpers ---------------------------------------------------------------------------------------------------
def make_safe() -> m.Plan:
    """The finaliser: stop the trace, stop the program. Each step is independent: a failure is logged and the next
    step still runs (a cleanup error must not hide the cause, and must not leave the program running)."""
    for msg in (m.TraceStop(), m.StopProgram()):
        try:
            yield msg
        except Exception as exc:
            _log.error("finaliser: %s failed: %r", msg.describe(), exc)


def finalize_wrapper(plan: m.Plan, final: Callable[[], m.Plan] = make_safe) -> m.Plan:
    """Run ``plan``; then, however it ended, ``final()`` (bluesky's ``finalize_wrapper``). Returns the plan's value."""
    try:
        result = yield from plan
    finally:
        yield from final()
    return result


# --- the engine -------------------------------------------------------------------------------------------------------
class RunEngine:
    """Executes one plan at a time; see the module docstring."""

    def __init__(
        self,
        krc: KrcController,
        *,
        checker: ProgramChecker,
        monitor: Monitor | None = None,
        dry_run: bool = False,
        share_dir: Path | None = None,
        trace_dir: str = TRACE_DIR,
    ) -> None:
        if monitor is None and not dry_run:
            raise InterlockError("a run engine that may move the robot needs the runtime monitor")
        self.krc = krc
        self.checker = checker
        self.monitor = monitor
        self.dry_run = dry_run
        self.share_dir = share_dir
        self.trace_dir = trace_dir
        self.run_id: str | None = None
        self.state = EngineState.IDLE
        self._subscribers: list[Subscriber] = []
        self._document_subscribers: list[DocumentSubscriber] = []
        self._recorder: d.Recorder | None = None
        self._resume = asyncio.Event()
        self._resume.set()
        self._confirm = asyncio.Event()
        self._confirm_note = ""
        self._current: asyncio.Task[Any] | None = None
        self._interrupt: BaseException | None = None
        self._delivered = False
        self._trace_armed = False
        self._running = False
        self._pulls: dict[str, tuple[asyncio.Task[Any], float]] = {}
        #: Controller file -> SHA-256 of the bytes a ``Push`` of this plan wrote there since the last program start:
        #: a push of the same bytes (a move pushed ahead, while the robot stood still) is checked again but not sent.
        self._written: dict[str, bytes] = {}
        #: (kg, flange-frame CoG m) of the load a ``Mounted`` message declared in this plan; None: the checker's own
        self._mounted: tuple[float, tuple[float, float, float]] | None = None

    # --- control from outside (CLI, MQTT) -----------------------------------------------------------------------
    def subscribe(self, subscriber: Subscriber) -> Callable[[], None]:
        """Call ``subscriber(event)`` for every event; returns a function that unsubscribes."""
        self._subscribers.append(subscriber)
        return lambda: self._subscribers.remove(subscriber) if subscriber in self._subscribers else None

    def subscribe_documents(self, subscriber: DocumentSubscriber) -> Callable[[], None]:
        """Call ``subscriber(doc)`` for every run document once the recorder has it; returns the unsubscriber."""
        self._document_subscribers.append(subscriber)
        return lambda: (self._document_subscribers.remove(subscriber)
                        if subscriber in self._document_subscribers else None)

    def pause(self) -> None:
        """Pause at the next checkpoint."""
        self._resume.clear()

    def resume(self) -> None:
        self._resume.set()

    def abort(self, reason: str = "aborted") -> None:
        """Interrupt the running message now; the finaliser runs and :meth:`run` raises :class:`PlanAborted`."""
        self._deliver(PlanAborted(reason))

    def confirm(self, note: str = "") -> None:
        """The operator confirms the pending :class:`~messages.Confirm` (e.g. 'calibration body 3 mounted')."""
        self._confirm_note = note
        self._confirm.set()

    @property
    def pulls_in_flight(self) -> tuple[str, ...]:
        """Traces whose background pull (:class:`~messages.PullStart`) has not been joined yet."""
        return tuple(self._pulls)

    @property
    def waiting_for_confirmation(self) -> bool:
        return self.state == EngineState.CONFIRM

    # --- events -------------------------------------------------------------------------------------------------
    def emit(self, event: Event) -> None:
        if event.run_id is None and self.run_id is not None:
            event = Event(**{**event.__dict__, "run_id": self.run_id})
        for sub in list(self._subscribers):
            try:
                sub(event)
            except Exception:
                _log.exception("event subscriber %r failed", sub)

    def _set_state(self, state: EngineState) -> None:
        if state not in TRANSITIONS[self.state]:
            raise EngineStateError(f"engine state {self.state.value} -> {state.value}: not a legal transition")
        self.state = state
        self.emit(Event("state", state.value, data={"state": state.value}))

    # --- running a plan -----------------------------------------------------------------------------------------
    async def execute(self, opening: d.OpenRun, plan_for: Callable[[d.RunContext], m.Plan],
                      recorder: d.Recorder) -> Any:
        """The run skeleton of every recorded run: record ``opening`` (the recorder creates or continues the run),
        run ``plan_for(run)``, then record :class:`~documents.CloseRun` with how it ended — whatever happened,
        cancellation included (bounded, shielded; a store error there is logged). Returns the plan's value.

        A dry run opens nothing (the plan gets :meth:`RunContext.dry`), records nothing and carries no run id."""
        if self._running:
            raise RgseError("the engine already runs a plan")
        self._recorder = recorder
        self.run_id = None
        try:
            run: d.RunContext = await self._execute(opening)
            if self.dry_run:
                return await self.run(plan_for(run))
            error: BaseException | None = None
            try:
                return await self.run(plan_for(run), run_id=run.run_id)
            except BaseException as exc:
                error = exc
                raise
            finally:
                await self._close(run.run_id, error)
        finally:
            self._recorder = None

    async def _close(self, run_id: str, exc: BaseException | None) -> None:
        if exc is None:
            doc = d.CloseRun(RunState.COMPLETED)
        elif isinstance(exc, asyncio.CancelledError):
            doc = d.CloseRun(RunState.INTERRUPTED, "daemon stopped during the run")
        elif isinstance(exc, PlanAborted):
            doc = d.CloseRun(RunState.ABORTED, str(exc))
        else:
            doc = d.CloseRun(RunState.FAILED, f"{type(exc).__name__}: {exc}")
        # retried until the store takes it (disk full, database restarting): store/final.py
        await retry_final(lambda: asyncio.shield(self._record(doc, run_id, CLOSE_TIMEOUT_S)),
                          f"run {run_id}: state {doc.state}")

    async def run(self, plan: m.Plan, *, run_id: str | None = None) -> Any:
        """Execute ``plan`` inside the finaliser; returns its value or raises what failed it."""
        if self._running:
            raise RgseError("the engine already runs a plan")
        self._running = True
        self.run_id = run_id
        self._interrupt = None
        self._trace_armed = False
        self._mounted = None
        self._written = {}
        self._set_state(EngineState.RUNNING)
        outcome = EngineState.FAILED
        try:
            if self.monitor is not None and not self.dry_run:
                self.monitor.expect(Expect.IDLE)
                async with self.monitor.running(self._on_trip):
                    result = await self._drive_plan(plan)
            else:
                result = await self._drive_plan(plan)
            if self._interrupt is not None:  # a trip or abort after the plan's last step: not a completed run
                raise self._interrupt
            outcome = EngineState.DONE
            return result
        except PlanAborted:
            outcome = EngineState.ABORTED
            raise
        finally:
            self._running = False
            self._set_state(outcome)

    async def _drive_plan(self, plan: m.Plan) -> Any:
        """The plan inside its finaliser; background pulls end with it, still under the monitor."""
        try:
            result = await self._drive(finalize_wrapper(plan))
            if self._pulls:  # a plan bug: a background pull never collected (its files would not be indexed)
                raise RgseError(f"the plan ended with pulls not joined: {', '.join(sorted(self._pulls))}")
            return result
        finally:
            await self._cancel_pulls()

    def _on_trip(self, trip: InterlockTrip) -> None:
        self.emit(Event("alarm", str(trip), data={"watcher": trip.watcher, "detail": trip.detail}))
        self._deliver(trip)

    def _deliver(self, exc: BaseException) -> None:
        if not self._running or self._interrupt is not None:
            return
        self._interrupt = exc
        self._resume.set()
        for task, _ in self._pulls.values():  # nothing was deleted: the files stay on the controller
            task.cancel()
        if self._current is not None and not self._current.done():
            self._current.cancel()

    async def _drive(self, gen: m.Plan) -> Any:
        reply: Any = None
        error: BaseException | None = None
        cancelled: asyncio.CancelledError | None = None
        self._delivered = False
        while True:
            try:
                msg = gen.throw(error) if error is not None else gen.send(reply)
            except StopIteration as stop:
                if cancelled is not None:
                    raise cancelled from None
                if self._interrupt is not None:
                    # an abort or trip that the plan did not let through (it came during the finaliser, whose
                    # steps log their errors and go on): the run still ends aborted or failed, never completed
                    raise self._interrupt from None
                return stop.value
            reply, error = None, None
            self._current = asyncio.get_running_loop().create_task(self._execute(msg), name=f"rgse:{msg.describe()}")
            try:
                reply = await self._current
            except asyncio.CancelledError as exc:
                task = asyncio.current_task()
                if task is not None and task.cancelling():
                    # this task is cancelled: let the plan's finaliser run, then re-raise
                    cancelled = cancelled or exc
                    error = exc
                elif self._interrupt is not None and not self._delivered:
                    error = self._interrupt
                else:
                    error = exc
            except Exception as exc:
                error = exc
            finally:
                self._current = None
            if error is None and self._interrupt is not None and not self._delivered:
                error = self._interrupt  # a trip/abort between two messages
            if error is self._interrupt and error is not None:
                self._delivered = True

    # --- message execution --------------------------------------------------------------------------------------
    async def _execute(self, msg: m.Msg) -> Any:
        if self.dry_run and not msg.inert:
            if isinstance(msg, m.Push):
                await self._check(msg.program)  # a dry run refuses what the real run would refuse
            _log.info("dry run: %s", msg.describe())
            return msg.dry_reply()
        # the handler of the message's type, else of its nearest base (Compute → Process, any Document)
        handler = next((h for cls in type(msg).__mro__ if (h := getattr(self, f"_do_{cls.__name__}", None))), None)
        if handler is None:
            raise RgseError(f"the engine does not know message {type(msg).__name__}")
        _log.debug("%s", msg.describe())
        if isinstance(msg, _AFTER_PULLS):
            await self._pulls_ended(msg.describe())
        return await handler(msg)

    async def _snapshot(self) -> Snapshot:
        try:
            return await within(self.krc.snapshot(), REQUEST_TIMEOUT_S)
        except TimeoutError as exc:
            raise LinkError(f"no snapshot within {REQUEST_TIMEOUT_S:g} s") from exc

    async def _bounded(self, what: str, aw: Any, timeout_s: float = REQUEST_TIMEOUT_S) -> Any:
        try:
            return await within(aw, timeout_s)
        except TimeoutError as exc:
            raise StepTimeout(f"{what}: no answer within {timeout_s:g} s") from exc

    async def _check(self, prog: m.Program) -> None:
        """The static check of ``prog`` against the live snapshot; a refusal is an alarm too."""
        snap = await self._snapshot()
        try:
            # the check is numeric work: off the event loop, so the monitor keeps polling
            check = self.checker if self._mounted is None else functools.partial(self.checker, payload=self._mounted)
            await self._bounded(f"static check {prog.name}", asyncio.to_thread(check, prog, snap), 60.0)
        except InterlockError as exc:
            self.emit(Event("alarm", f"program {prog.name} refused: {exc}",
                            data={"watcher": "static_check", "program": prog.name, "detail": str(exc)}))
            raise

    async def _do_Mounted(self, msg: m.Mounted) -> None:
        self._mounted = (float(msg.mass_kg), msg.cog_flange_m)

    async def _do_Push(self, msg: m.Push) -> str:
        prog = msg.program
        await self._check(prog)
        src_name = msg.dry_reply()
        files = [*([(PROGRAM_DIR + prog.name.upper() + ".DAT", prog.dat_text.encode("latin-1"))]
                   if prog.dat_text is not None else []), (src_name, prog.src_text.encode("latin-1"))]
        digests = [hashlib.sha256(data).digest() for _, data in files]
        if all(self._written.get(name) == h for (name, _), h in zip(files, digests, strict=True)):
            return src_name  # checked now; these very bytes went there since the last program start (a push ahead)
        async with self._file_window(f"push {prog.name}"):
            for (name, data), h in zip(files, digests, strict=True):
                self._written.pop(name, None)
                await self._bounded(f"put {name}", self.krc.put_file(name, data))
                self._written[name] = h
        return src_name

    def _file_window(self, what: str) -> contextlib.AbstractAsyncContextManager[Any]:
        """File work blocks the controller's status reads: only under the monitor's file-window rule."""
        if self.monitor is None or self.dry_run:
            return contextlib.nullcontext()
        return self.monitor.file_window(what)

    async def _do_Select(self, msg: m.Select) -> None:
        self._expect(Expect.IDLE)
        await self._bounded(f"select {msg.name}", self.krc.select_program(msg.name, force=True))

    async def _do_Start(self, msg: m.Start) -> float:
        self._written.clear()  # a push after a program ran sends its files again
        self._expect(Expect.RUNNING)
        t0 = time.monotonic()
        await self._bounded("start", self.krc.start_program())
        return t0

    async def _do_WaitProgram(self, msg: m.WaitProgram) -> tuple[str, float]:
        t0 = time.monotonic()
        deadline = t0 + msg.timeout_s
        while True:
            self._raise_if_interrupted()
            state = _enum(await self._bounded("read $PRO_STATE1", self.krc.read("$PRO_STATE1")))
            if state in msg.states:
                if state in ("P_END", "P_FREE", "P_RESET"):
                    self._expect(Expect.IDLE)
                return state, time.monotonic() - t0
            if state in ("P_STOP", "P_FREE") and state not in msg.states:
                if self.monitor is not None and not self.dry_run:
                    # the monitor names the cause (STOP 2, mode, ...): give it a few polls to trip first
                    await asyncio.sleep(3 * self.monitor.stale_after_s)
                raise ProgramStopped(f"program #{state} while waiting for {'/'.join(sorted(msg.states))}")
            if time.monotonic() >= deadline:
                raise StepTimeout(f"program did not reach {'/'.join(sorted(msg.states))} within {msg.timeout_s:g} s"
                                  f" (it is #{state})")
            await asyncio.sleep(WAIT_POLL_S)

    async def _do_VerifyDone(self, msg: m.VerifyDone) -> None:
        value = await self._bounded(f"read {msg.variable}", self.krc.read(msg.variable))
        if value is not True:
            raise ProgramStopped(f"program ended but {msg.variable} is {value!r}: it did not reach its end state")

    async def _do_StopProgram(self, msg: m.StopProgram) -> None:
        self._expect(Expect.ANY)
        state = _enum(await self._bounded("read $PRO_STATE1", self.krc.read("$PRO_STATE1"), CLEANUP_TIMEOUT_S))
        if state == "P_ACTIVE":
            await self._bounded("stop program", self.krc.stop_program(), CLEANUP_TIMEOUT_S)
        self._expect(Expect.IDLE)

    async def _do_ReadState(self, msg: m.ReadState) -> Snapshot:
        return await self._snapshot()

    async def _do_ReadVar(self, msg: m.ReadVar) -> Any:
        return await self._bounded(f"read {msg.name}", self.krc.read(msg.name))

    async def _do_WriteVar(self, msg: m.WriteVar) -> None:
        await self._bounded(f"write {msg.name}", self.krc.write_raw(msg.name, msg.text))

    async def _do_PutFile(self, msg: m.PutFile) -> None:
        self._written.pop(msg.name, None)
        async with self._file_window(f"put {msg.name}"):
            await self._bounded(f"put {msg.name}", self.krc.put_file(msg.name, msg.data),
                                REQUEST_TIMEOUT_S + self.krc.file_timeout_s(len(msg.data)))

    async def _do_TraceStart(self, msg: m.TraceStart) -> float:
        await self._bounded("write $TRACE.CONFIG[]", self.krc.write("$TRACE.CONFIG[]", msg.config))
        await self._bounded("write $TRACE.NAME[]", self.krc.write("$TRACE.NAME[]", msg.name))
        self._trace_armed = True
        t0 = time.monotonic()
        await self._bounded("write $TRACE.MODE", self.krc.write_raw("$TRACE.MODE", "#T_START"))
        return t0

    async def _do_TraceWait(self, msg: m.TraceWait) -> float:
        t0 = time.monotonic()
        deadline = t0 + msg.timeout_s
        while True:
            self._raise_if_interrupted()
            state = _enum(await self._bounded("read $TRACE.STATE", self.krc.read("$TRACE.STATE")))
            if state == "T_END":
                self._trace_armed = False
                return time.monotonic() - t0
            if time.monotonic() >= deadline:
                raise StepTimeout(f"trace not written within {msg.timeout_s:g} s ($TRACE.STATE #{state})")
            await asyncio.sleep(WAIT_POLL_S)

    async def _do_TraceStop(self, msg: m.TraceStop) -> None:
        state = _enum(await self._bounded("read $TRACE.STATE", self.krc.read("$TRACE.STATE"), CLEANUP_TIMEOUT_S))
        if state in TRACE_ACTIVE_STATES or (self._trace_armed and state != "T_END"):
            await self._bounded("stop trace", self.krc.write_raw("$TRACE.MODE", "#T_STOP"), CLEANUP_TIMEOUT_S)
        self._trace_armed = False

    async def _do_Pull(self, msg: m.Pull) -> Any:
        # every step of a pull has its own deadline, a file's sized by its bytes (Controller.get_file); the whole
        # pull is bounded by those, not by msg.timeout_s (a large trace set at the controller's slow file rate
        # may need longer than a trace takes to record)
        async with self._file_window(f"pull {msg.trace}"):
            return await pull_trace(self.krc, msg.trace, msg.dest_dir, trace_dir=self.trace_dir,
                                    share_dir=self.share_dir, **({"modules": msg.modules} if msg.modules else {}))

    async def _do_PullStart(self, msg: m.PullStart) -> None:
        if msg.trace in self._pulls:
            raise RgseError(f"trace {msg.trace}: a pull of it is already in flight")
        task = asyncio.get_running_loop().create_task(self._do_Pull(m.Pull(msg.trace, msg.dest_dir,
                                                                             modules=msg.modules)),
                                                      name=f"rgse:pull {msg.trace}")
        task.add_done_callback(self._pull_ended)
        self._pulls[msg.trace] = (task, time.monotonic())

    def _pull_ended(self, task: asyncio.Task[Any]) -> None:
        """A background pull that failed stops the run now, as a pull on the plan's own path would."""
        if not task.cancelled() and task.exception() is not None:
            self._deliver(task.exception())  # type: ignore[arg-type]

    async def _do_PullJoin(self, msg: m.PullJoin) -> tuple[Any, float, float]:
        entry = self._pulls.get(msg.trace)
        if entry is None:
            raise RgseError(f"trace {msg.trace}: no pull of it in flight")
        task, started = entry
        t0 = time.monotonic()
        try:
            pulled = await self._bounded(f"pull {msg.trace}", asyncio.shield(task), msg.timeout_s)
        finally:
            if task.done():
                self._pulls.pop(msg.trace, None)
        t1 = time.monotonic()
        return pulled, t1 - t0, t1 - started

    async def _pulls_ended(self, what: str) -> None:
        """Before a motion or file message: every background pull must have ended (the file-window rule: no motion
        while file work blocks the controller's status reads); a failed one raises its error."""
        for trace, (task, _) in list(self._pulls.items()):
            if not task.done():
                _log.debug("%s waits for the pull of %s", what, trace)
                await self._bounded(f"{what}: the pull of {trace}", asyncio.shield(task), REQUEST_TIMEOUT_S + 600.0)
            if not task.cancelled() and task.exception() is not None:
                raise task.exception()  # type: ignore[misc]

    async def _cancel_pulls(self) -> None:
        pulls, self._pulls = self._pulls, {}
        for task, _ in pulls.values():
            task.cancel()
        if pulls:
            await asyncio.wait([t for t, _ in pulls.values()], timeout=CLEANUP_TIMEOUT_S)
        for task, _ in pulls.values():
            if task.done() and not task.cancelled() and task.exception() is not None:
                _log.warning("background pull %s ended with %r", task.get_name(), task.exception())

    async def _do_DeleteTraceCopies(self, msg: m.DeleteTraceCopies) -> tuple[bool, str]:
        return await self._bounded(f"delete {msg.pulled.trace} on the controller", msg.pulled.delete_copies(),
                                   msg.timeout_s)

    async def _do_Sleep(self, msg: m.Sleep) -> None:
        await asyncio.sleep(msg.seconds)

    async def _do_Checkpoint(self, msg: m.Checkpoint) -> None:
        if self._resume.is_set():
            return
        self._set_state(EngineState.PAUSED)
        await self._resume.wait()  # abort also sets it; the interrupt is then thrown into the plan
        self._set_state(EngineState.RUNNING)

    async def _do_Confirm(self, msg: m.Confirm) -> str:
        self._confirm.clear()
        self._confirm_note = ""
        self.emit(Event("confirm", msg.prompt, data=dict(msg.data)))
        self._set_state(EngineState.CONFIRM)
        try:
            if msg.timeout_s is None:
                await self._confirm.wait()
            else:
                await self._bounded(f"confirm '{msg.prompt}'", self._confirm.wait(), msg.timeout_s)
        finally:
            self._set_state(EngineState.RUNNING)  # also on abort: the finaliser runs, nobody waits for a confirm
        return self._confirm_note

    async def _do_Emit(self, msg: m.Emit) -> None:
        self.emit(msg.event)

    async def _do_Process(self, msg: m.Process) -> Any:
        return await self._bounded(msg.label, asyncio.to_thread(msg.fn, *msg.args), msg.timeout_s)

    async def _do_ReadCampaign(self, msg: m.ReadCampaign) -> d.CampaignProgress:
        if self._recorder is None or self.run_id is None:
            return d.CampaignProgress()  # nothing recorded (a dry run, a plan run without a recorder)
        return await self._bounded("read the campaign", self._recorder.campaign(self.run_id), RECORD_TIMEOUT_S)

    async def _do_Document(self, doc: d.Document) -> Any:
        return await self._record(doc, self.run_id)

    def _record(self, doc: d.Document, run_id: str | None,
                timeout_s: float = RECORD_TIMEOUT_S) -> Coroutine[Any, Any, Any]:
        """The recorder makes ``doc`` durable (its error fails the plan), then the subscribers see it. The recorder
        is taken now, so a shielded recording finishes even if the run ends meanwhile."""
        if self._recorder is None:
            raise RgseError(f"{doc.describe()}: this run has no recorder (run it with RunEngine.execute)")
        return self._recorded(doc, self._recorder.record(run_id, doc), timeout_s)

    async def _recorded(self, doc: d.Document, recording: Coroutine[Any, Any, Any], timeout_s: float) -> Any:
        reply = await self._bounded(f"record {doc.describe()}", recording, timeout_s)
        for sub in list(self._document_subscribers):
            try:
                sub(doc)
            except Exception:
                _log.exception("document subscriber %r failed", sub)
        return reply

    def _raise_if_interrupted(self) -> None:
        """Polling waits check this each round: Python 3.11's ``wait_for`` can swallow a cancellation that arrives
        just as its inner call completes, so a cancel alone may not end a long wait."""
        if self._interrupt is not None and not self._delivered and self._current is asyncio.current_task():
            raise asyncio.CancelledError

    def _expect(self, expect: Expect) -> None:
        if self.monitor is not None:
            self.monitor.expect(expect)


#: Messages that wait for every background pull first (motion, or file work of their own).
_AFTER_PULLS = (m.Push, m.Select, m.Start, m.PutFile, m.Pull)


def _enum(value: object) -> str:
    """``#P_END`` / KrlEnum → ``P_END``."""
    name = getattr(value, "name", None)
    return str(name if name is not None else value).lstrip("#")

