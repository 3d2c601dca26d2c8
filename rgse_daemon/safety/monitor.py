"""The runtime interlock: polls the controller while a plan runs and trips on the first sign of danger or doubt.

Interlocks are **declarative watchers** (bluesky suspenders, architecture lesson 3): :data:`DEFAULT_WATCHERS` is a
list of small :class:`Watcher` objects, each a name, a message, the snapshot fields it needs and a predicate —
not ``if``\\ s scattered through the plans. A watcher whose fields are unreadable (``None``) trips: doubt = trip.

Every ``poll_period_s`` (default 50 ms, i.e. 20 Hz) the monitor takes one :meth:`KrcController.snapshot` (one
multi-read with C3 Bridge) with a deadline of ``stale_periods`` poll periods; a failed or late snapshot is link
loss. If the monitor itself fails (a bug, a reply no check foresaw), that is a trip of the ``monitor`` watcher: the
robot is never left moving unwatched. On a trip it, in this order and each step bounded by ``stop_timeout_s``:

1. stops the robot program (``#10 STOP``) — a STOP 2 equivalent: the robot ramps down on its path and holds;
2. stops the trace (``$TRACE.MODE = #T_STOP``) if one is armed or recording;
3. calls ``on_trip(trip)`` (the engine publishes the alarm and fails the plan with :class:`InterlockTrip`);
4. keeps stopping until a read-back confirms program and trace stopped
   (:func:`~rgse_daemon.safety.makesafe.stop_until_confirmed`, with backoff, at most ``make_safe_deadline_s``):
   after a stall or a lost link the first stop may never have arrived. Not confirmed by the deadline, it calls
   ``on_unsafe(report)`` (the daemon latches: :mod:`rgse_daemon.safety.latch`). The plan's block does not end before
   this step has, so no new run starts while the stop is still unconfirmed.

A plan that ends without a trip gets the same check once its block ends (:meth:`Monitor.running`): a program still
active or a trace still recording (the plan's own finaliser failed, e.g. its stop was refused) is stopped until
confirmed, or latched. A plan that ended normally costs one read of three variables.

The plan tells the monitor what to expect through :attr:`Monitor.context` (allowed modes, program expected
running or idle, safety inputs): the engine updates it as it starts and ends programs.

**File transfers** (:meth:`Monitor.file_window`). The real C3 Bridge server does file work on its single thread: while
it loads a trace file for a pull (seconds for a large one), every status read waits behind it, so a snapshot cannot
be fresh. The rule, which keeps "doubt = stop" intact:

1. *Only at standstill.* A window opens only on a fresh, complete snapshot that shows no program running
   (``$PRO_STATE1`` not ``#P_ACTIVE``), ``$ROB_STOPPED`` TRUE and ``$VEL_ACT`` ≈ 0, and the engine sends no motion
   command while it is open (a plan is sequential). Moving the robot then needs a person at the smartPAD (T1:
   enabling switch and start or jog keys), which the controller's own T1 speed monitoring covers.
2. *Late, not lost, and bounded.* Inside the window a snapshot may be late by exactly the file work in flight: its
   deadline is the end of that work's own deadline (bytes at ``controller.file_rate_bytes_s``, see
   :class:`~rgse_daemon.link.connection.ServerLoad`) plus the normal limit. Later than that is link loss: trip.
3. *Every snapshot that does arrive is judged fully*, by every watcher and by the standstill check: a program
   running, ``$ROB_STOPPED`` FALSE, a speed, or any axis more than :data:`WINDOW_AXIS_TOLERANCE_DEG` away from where it
   stood when the window opened trips the interlock at once (program stop, trace stop).
4. *Doubt holds the next motion.* A snapshot later than the normal limit is doubt (counted in
   ``stats.window_late_polls``). The window closes only after a snapshot taken *after* the last file byte arrives
   within the normal limit and passes the same checks, pose unchanged; until then nothing else runs, so the next
   motion command waits. If no such snapshot comes, the monitor trips as for any stale link.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

from rgse_daemon.aio import within
from rgse_daemon.config import LimitsConfig
from rgse_daemon.errors import InterlockError, LinkError, RgseError
from rgse_daemon.krc import KrcController, Snapshot
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.makesafe import STOP_DEADLINE_S, TRACE_ACTIVE_STATES, StopReport, stop_until_confirmed

_log = logging.getLogger(__name__)

#: The monitor's poll period (s): 20 Hz.
DEFAULT_POLL_PERIOD_S = 0.05
#: A snapshot older than this many poll periods is link loss.
STALE_PERIODS = 2.0
#: Deadline of each stop step after a trip (s).
STOP_TIMEOUT_S = 2.0
#: An axis further than this from where it stood when a file window opened has moved: trip (deg).
WINDOW_AXIS_TOLERANCE_DEG = 0.01
#: Above this $VEL_ACT (m/s) the robot is not standing still.
STANDSTILL_SPEED_M_S = 0.001
#: How long opening or closing a file window waits for the fresh snapshot it needs, beyond the file work (s).
WINDOW_SNAPSHOT_WAIT_S = 5.0


class InterlockTrip(InterlockError):
    """The runtime monitor tripped: ``watcher`` names the watcher, ``detail`` what it saw."""

    def __init__(self, watcher: str, message: str, detail: str) -> None:
        super().__init__(f"interlock trip [{watcher}]: {message}: {detail}")
        self.watcher = watcher
        self.message = message
        self.detail = detail


class Expect(StrEnum):
    """What the plan expects of the robot interpreter right now."""

    IDLE = "idle"  # no program may be running
    RUNNING = "running"  # our program runs; stopping by itself is unexpected
    ANY = "any"  # in transition (the engine itself is stopping the program)


#: Program states that are fine while a program is expected running (reset just before start, end just before the
#: engine noticed), and states that are not while the daemon expects none.
RUNNING_OK = frozenset({"P_RESET", "P_ACTIVE", "P_END"})
IDLE_BAD = frozenset({"P_ACTIVE"})


@dataclass(frozen=True)
class WatchContext:
    """What the plan allows right now; the engine replaces it (it is immutable) as the plan goes on."""

    allowed_modes: frozenset[str] = frozenset({"T1"})
    expect: Expect = Expect.IDLE
    speed_limit_mm_s: float = LimitsConfig().t1_speed_mm_s


@dataclass(frozen=True)
class Observation:
    """One poll: the snapshot (``None`` if the read failed), the link error if any, the time since the last
    good snapshot (s) and the safety inputs (``None``: no Modbus I/O configured)."""

    snapshot: Snapshot | None
    link_error: str | None
    age_s: float
    stale_after_s: float
    inputs: SafetyInputs | None


Predicate = Callable[[Observation, WatchContext], str | None]


@dataclass(frozen=True)
class Watcher:
    """One interlock condition. ``check`` returns a detail text when unsafe, else ``None``. ``needs`` names the
    :class:`Snapshot` fields the check reads; one of them unreadable trips the watcher by itself."""

    name: str
    message: str
    check: Predicate
    needs: tuple[str, ...] = ()

    def evaluate(self, obs: Observation, ctx: WatchContext) -> str | None:
        snap = obs.snapshot
        if self.needs:
            if snap is None:
                return None  # the link watcher reports a missing snapshot
            missing = [f for f in self.needs if getattr(snap, f) is None]
            if missing:
                why = "; ".join(f"{f}: {snap.errors.get(_VARIABLE.get(f, f), 'unreadable')}" for f in missing)
                return f"cannot read {why} (doubt = trip)"
        return self.check(obs, ctx)


_VARIABLE = {
    "mode_op": "$MODE_OP",
    "pro_state1": "$PRO_STATE1",
    "stopmess": "$STOPMESS",
    "peri_rdy": "$PERI_RDY",
    "user_saf": "$USER_SAF",
    "vel_act_m_s": "$VEL_ACT",
}


def _link(obs: Observation, ctx: WatchContext) -> str | None:
    if obs.link_error is not None:
        return obs.link_error
    if obs.snapshot is None or obs.age_s > obs.stale_after_s:
        return f"last good snapshot {obs.age_s * 1e3:.0f} ms old (limit {obs.stale_after_s * 1e3:.0f} ms)"
    return None


def _mode(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    mode = obs.snapshot.mode_op
    if mode not in ctx.allowed_modes:
        return f"$MODE_OP is #{mode}, allowed: {', '.join('#' + m for m in sorted(ctx.allowed_modes))}"
    return None


def _aut_inputs(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    if obs.snapshot.mode_op != "AUT":
        return None
    if obs.inputs is None:
        return "AUT without safety inputs (no Modbus I/O configured)"
    if not obs.inputs.valid:
        return f"safety inputs invalid: {obs.inputs.reason}"
    bad = [
        n
        for n, ok in (
            ("E-stop", obs.inputs.estop_ok),
            ("area cleared", obs.inputs.area_cleared),
            ("AUT key", obs.inputs.aut_permitted),
        )
        if not ok
    ]
    return f"safety inputs not OK in AUT: {', '.join(bad)}" if bad else None


def _estop(obs: Observation, ctx: WatchContext) -> str | None:
    """In every mode, when the safety I/O module is configured: its E-stop chain must read OK, and an unknown state
    (module unreachable, stale read) is a doubt that stops the run. In T1 the operator works in the cell, so "area
    cleared" and the AUT key are not required there (``_aut_inputs`` covers AUT)."""
    if obs.inputs is None:
        return None
    if not obs.inputs.valid:
        return f"E-stop state unknown: safety inputs invalid ({obs.inputs.reason})"
    return None if obs.inputs.estop_ok else "the safety I/O module reports the E-stop chain open"


def _stop2(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    return (
        "$STOPMESS is TRUE (enabling switch released, STOP 2 or another stop message)"
        if obs.snapshot.stopmess
        else None
    )


def _program_state(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    state = obs.snapshot.pro_state1
    if ctx.expect is Expect.RUNNING and state not in RUNNING_OK:
        return f"program {obs.snapshot.pro_name1 or '?'} is #{state} while it should run (stopped unexpectedly)"
    if ctx.expect is Expect.IDLE and state in IDLE_BAD:
        return f"program {obs.snapshot.pro_name1 or '?'} is #{state} while the daemon runs none"
    return None


def _drives(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    if ctx.expect is Expect.RUNNING and obs.snapshot.pro_state1 == "P_ACTIVE" and not obs.snapshot.peri_rdy:
        return "$PERI_RDY is FALSE while the program runs (drives off)"
    return None


def _safety_gate(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None
    return None if obs.snapshot.user_saf else "$USER_SAF is FALSE (operator safety / safety gate open)"


def _speed(obs: Observation, ctx: WatchContext) -> str | None:
    assert obs.snapshot is not None and obs.snapshot.vel_act_m_s is not None
    speed_mm_s = abs(obs.snapshot.vel_act_m_s) * 1000.0
    if speed_mm_s > ctx.speed_limit_mm_s:
        return f"$VEL_ACT {speed_mm_s:.1f} mm/s above the limit {ctx.speed_limit_mm_s:.1f} mm/s"
    return None


#: The interlock, in the order the watchers are evaluated (the first that trips names the trip).
DEFAULT_WATCHERS: tuple[Watcher, ...] = (
    Watcher("link", "controller link lost or snapshot stale", _link),
    Watcher("mode", "operating mode changed from the allowed one", _mode, ("mode_op",)),
    Watcher("aut_inputs", "automatic mode without E-stop OK, area cleared and key", _aut_inputs, ("mode_op",)),
    Watcher("estop", "E-stop not OK or unknown on the safety I/O module", _estop),
    Watcher("stop2", "enabling switch released / STOP 2 / stop message", _stop2, ("stopmess",)),
    Watcher("program_state", "unexpected program state", _program_state, ("pro_state1",)),
    Watcher("drives", "drives not ready while the program runs", _drives, ("pro_state1", "peri_rdy")),
    Watcher("safety_gate", "operator safety open", _safety_gate, ("user_saf",)),
    Watcher("speed", "Cartesian speed above the T1 limit", _speed, ("vel_act_m_s",)),
)


def standstill_problem(snap: Snapshot | None, axes_deg: tuple[float, ...] | None = None) -> str | None:
    """Why ``snap`` does not show the robot standing idle (at ``axes_deg`` if given), or ``None`` if it does.
    An unreadable field is a reason: doubt."""
    if snap is None:
        return "no snapshot"
    if snap.pro_state1 is None or snap.rob_stopped is None or snap.vel_act_m_s is None or snap.axes_deg is None:
        return "standstill unknown ($PRO_STATE1, $ROB_STOPPED, $VEL_ACT or $AXIS_ACT unreadable)"
    if snap.pro_state1 == "P_ACTIVE":
        return f"program {snap.pro_name1 or '?'} is running"
    if not snap.rob_stopped:
        return "$ROB_STOPPED is FALSE"
    if abs(snap.vel_act_m_s) > STANDSTILL_SPEED_M_S:
        return f"$VEL_ACT is {snap.vel_act_m_s * 1000.0:.1f} mm/s"
    if axes_deg is not None:
        for i, (was, now) in enumerate(zip(axes_deg, snap.axes_deg, strict=True), 1):
            if abs(now - was) > WINDOW_AXIS_TOLERANCE_DEG:
                return f"A{i} moved from {was:.3f} to {now:.3f} deg during the file transfer"
    return None


#: Names a trip seen by the file-window rule (it is evaluated in the poll loop, not as one of the watchers).
_FILE_WINDOW_WATCHER = Watcher("file_window", "robot not standing still during a file transfer", lambda o, c: None)


@dataclass
class _FileWindow:
    what: str
    axes_deg: tuple[float, ...] | None
    closed_at: float | None = None


@dataclass
class MonitorStats:
    polls: int = 0
    snapshot_s_max: float = 0.0
    window_polls: int = 0
    """Polls taken while a file window was open."""
    window_late_polls: int = 0
    """... of which later than the normal staleness limit (doubt that the window's close had to clear)."""
    window_snapshot_s_max: float = 0.0
    """Longest snapshot while a file window was open (s): the status-poll latency during a pull."""
    trip_latency_s: float | None = None
    """Time from the start of the poll that saw the trip until the program stop was acknowledged."""
    stop_errors: list[str] = field(default_factory=list)
    stop_report: StopReport | None = None
    """How the stop after the trip was confirmed (or not)."""


TripHandler = Callable[[InterlockTrip], None]
UnsafeHandler = Callable[[InterlockTrip, StopReport], Awaitable[None]]


class Monitor:
    """Polls the controller and evaluates the watchers; see the module docstring.

    ``inputs`` returns the current Modbus safety inputs (``SafetyIo.inputs``) or is ``None`` when there are none.
    Use as ``async with monitor.running(on_trip):`` around a plan.
    """

    def __init__(
        self,
        krc: KrcController,
        *,
        watchers: Sequence[Watcher] = DEFAULT_WATCHERS,
        context: WatchContext | None = None,
        poll_period_s: float = DEFAULT_POLL_PERIOD_S,
        stale_periods: float = STALE_PERIODS,
        stop_timeout_s: float = STOP_TIMEOUT_S,
        inputs: Callable[[], SafetyInputs] | None = None,
        make_safe_deadline_s: float = STOP_DEADLINE_S,
        on_unsafe: UnsafeHandler | None = None,
    ) -> None:
        if not 0.0 < poll_period_s <= 0.05:
            raise InterlockError(f"monitor poll period {poll_period_s} s: must be > 0 and <= 0.05 s (>= 20 Hz)")
        if stale_periods < 1.0:
            raise InterlockError(f"monitor stale_periods {stale_periods}: must be >= 1")
        self.krc = krc
        self.watchers = tuple(watchers)
        self.context = context or WatchContext()
        self.poll_period_s = poll_period_s
        self.stale_after_s = stale_periods * poll_period_s
        self.stop_timeout_s = stop_timeout_s
        self.inputs = inputs
        self.make_safe_deadline_s = make_safe_deadline_s
        self.on_unsafe = on_unsafe
        self.stats = MonitorStats()
        self.latest: Snapshot | None = None
        self.trip: InterlockTrip | None = None
        self._task: asyncio.Task[None] | None = None
        self._confirming = False
        self._window: _FileWindow | None = None
        self._cleared_at = 0.0  # start of the last poll that passed every check on time
        self._polled = asyncio.Event()  # set after every poll

    @contextlib.asynccontextmanager
    async def file_window(self, what: str):  # type: ignore[no-untyped-def]
        """Run a file transfer under the file-window rule (module docstring). Raises :class:`InterlockError` if
        the robot does not stand idle at the start, and the trip if one happens meanwhile or before the close is
        cleared. Without a running monitor (tools, dry runs) it only runs the block."""
        if self._task is None or self._task.done():
            yield
            return
        snap = await self._fresh_after(time.monotonic(), f"{what}: opening the file window")
        problem = standstill_problem(snap)
        if problem is not None:
            raise InterlockError(f"{what}: refused: the robot must stand still with no program running ({problem})")
        self._window = _FileWindow(what, snap.axes_deg if snap is not None else None)
        try:
            yield
        finally:
            self._window.closed_at = time.monotonic()
            try:
                await self._fresh_after(self._window.closed_at, f"{what}: closing the file window")
            finally:
                self._window = None

    async def _fresh_after(self, t: float, what: str) -> Snapshot | None:
        """Wait for a poll that started after ``t`` and passed every check on time; raise the trip if one comes."""
        wait_s = WINDOW_SNAPSHOT_WAIT_S + max(0.0, self.krc.busy_until() - time.monotonic())
        try:
            async with asyncio.timeout(wait_s):
                while self._cleared_at <= t:
                    if self.trip is not None:
                        raise self.trip
                    if self._task is None or self._task.done():
                        raise InterlockError(f"{what}: the interlock monitor is not running")
                    self._polled.clear()
                    await self._polled.wait()
        except TimeoutError as exc:
            raise InterlockError(f"{what}: no fresh, complete snapshot within {wait_s:.1f} s (doubt: nothing moves)"
                                 ) from exc
        if self.trip is not None:
            raise self.trip
        return self.latest

    def expect(self, expect: Expect) -> None:
        self.context = replace(self.context, expect=expect)

    def check_once(self, obs: Observation, ctx: WatchContext) -> tuple[Watcher, str] | None:
        """The first watcher that trips on ``obs`` (pure: no I/O), or ``None``."""
        for w in self.watchers:
            detail = w.evaluate(obs, ctx)
            if detail is not None:
                return w, detail
        return None

    @contextlib.asynccontextmanager
    async def running(self, on_trip: TripHandler):  # type: ignore[no-untyped-def]
        """Poll in a background task while the block runs; the task ends with the block (or at a trip)."""
        self.trip = None
        self._confirming = False
        self._task = asyncio.get_running_loop().create_task(self._poll(on_trip), name="rgse-interlock-monitor")
        try:
            yield self
        finally:
            task, self._task = self._task, None
            if task is not None:
                try:
                    if self._confirming and not task.done():
                        # a trip's stop is not confirmed yet: the block ends once it is, or latched (bounded)
                        await asyncio.wait({task}, timeout=self.make_safe_deadline_s + 2 * self.stop_timeout_s)
                finally:
                    task.cancel()
                    await asyncio.wait({task})  # a cancel of *this* task still propagates from here
                    if not task.cancelled() and task.exception() is not None:  # (only after a trip: see _poll)
                        _log.critical("interlock: the stop after the trip failed: %r", task.exception())
                if not self._confirming:
                    await self._confirm_idle()

    def _allowed_s(self, t0: float) -> float:
        """How long the poll that started at ``t0`` may take: the normal limit, or, inside a file window, until the
        end of the file work in flight (its deadline) plus the normal limit."""
        if self._window is None:
            return self.stale_after_s
        return max(t0, self.krc.busy_until()) + self.stale_after_s - t0

    async def _timed_snapshot(self, t0: float) -> Snapshot:
        """The snapshot, within :meth:`_allowed_s` (re-evaluated as file work starts behind it); TimeoutError."""
        task = asyncio.get_running_loop().create_task(self.krc.snapshot(), name="rgse-interlock-snapshot")
        try:
            while True:
                remaining = t0 + self._allowed_s(t0) - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError
                done, _ = await asyncio.wait({task}, timeout=remaining)
                if done:
                    return task.result()
        finally:
            if not task.done():
                task.cancel()
                await asyncio.wait({task})

    async def _poll(self, on_trip: TripHandler) -> None:
        """:meth:`_watch`, and if the monitor itself fails (a bug, a reply no check foresaw) that is doubt too: the
        robot is stopped as at a trip of the ``monitor`` watcher, never left moving unwatched."""
        try:
            await self._watch(on_trip)
        except Exception as exc:
            _log.critical("interlock: the monitor failed: %r", exc, exc_info=exc)
            if self._confirming:
                raise  # it had tripped already and handed the trip on; the stop confirmation itself failed
            await self._trip(InterlockTrip("monitor", "the interlock monitor failed", repr(exc)[:200]), None,
                             on_trip, time.monotonic())

    async def _trip(self, trip: InterlockTrip, snap: Snapshot | None, on_trip: TripHandler, t0: float) -> None:
        """Steps 1-4 of the module docstring: record the trip, make safe, hand it to the plan, confirm the stop."""
        self.trip = trip
        self._polled.set()
        _log.error("%s", trip, extra={"watcher": trip.watcher, "detail": trip.detail})
        await self.make_safe(snap)
        self.stats.trip_latency_s = time.monotonic() - t0
        self._confirming = True
        on_trip(trip)
        await self._confirm_stop(trip)

    async def _watch(self, on_trip: TripHandler) -> None:
        last_good = time.monotonic()
        while True:
            t0 = time.monotonic()
            ctx = self.context
            window = self._window
            snap: Snapshot | None = None
            error: str | None = None
            try:
                snap = await self._timed_snapshot(t0)
            except TimeoutError:
                error = f"no snapshot within {self._allowed_s(t0) * 1e3:.0f} ms"
            except (LinkError, RgseError) as exc:
                error = f"{type(exc).__name__}: {exc}"
            except Exception as exc:  # a reply the decoder did not foresee: a failed poll, as a link error is
                _log.error("interlock: snapshot failed: %r", exc)
                error = f"{type(exc).__name__}: {exc}"
            now = time.monotonic()
            took_s = now - t0
            self.stats.polls += 1
            self.stats.snapshot_s_max = max(self.stats.snapshot_s_max, took_s)
            if window is not None:
                self.stats.window_polls += 1
                self.stats.window_snapshot_s_max = max(self.stats.window_snapshot_s_max, took_s)
                if took_s > self.stale_after_s:
                    self.stats.window_late_polls += 1  # doubt: the window's close needs a fresh snapshot
            if snap is not None:
                last_good = now
                self.latest = snap
            if self.context.expect is not ctx.expect:
                # the plan changed its expectation while this snapshot was in flight: judge the program state
                # by neither (the next poll, < one period away, sees the new state)
                ctx = replace(ctx, expect=Expect.ANY)
            stale_after_s = max(self.stale_after_s, self._allowed_s(t0)) if window is not None else self.stale_after_s
            obs = Observation(snap, error, now - last_good, stale_after_s,
                              self.inputs() if self.inputs is not None else None)
            found = self.check_once(obs, ctx)
            if found is None and window is not None and snap is not None:
                problem = standstill_problem(snap, window.axes_deg)
                if problem is not None:
                    found = (_FILE_WINDOW_WATCHER, f"{window.what}: {problem}")
            if found is None and snap is not None and took_s <= self.stale_after_s:
                self._cleared_at = t0
            if found is not None:
                watcher, detail = found
                await self._trip(InterlockTrip(watcher.name, watcher.message, detail), snap, on_trip, t0)
                return
            self._polled.set()
            await asyncio.sleep(max(0.0, self.poll_period_s - (time.monotonic() - t0)))

    async def _confirm_stop(self, trip: InterlockTrip) -> None:
        """Step 4 of the module docstring: stop until a read-back confirms it, or hand the failure on."""
        report = await stop_until_confirmed(self.krc, deadline_s=self.make_safe_deadline_s)
        self.stats.stop_report = report
        if report.confirmed:
            _log.info("interlock: stop confirmed: %s", report.describe(), extra={"watcher": trip.watcher})
            return
        _log.critical("interlock: stop NOT confirmed: %s", report.describe(), extra={"watcher": trip.watcher})
        if self.on_unsafe is not None:
            await self.on_unsafe(trip, report)

    async def _confirm_idle(self) -> None:
        """The block ended without a trip: nothing may still move or record (see the module docstring)."""
        report = await stop_until_confirmed(self.krc, deadline_s=self.make_safe_deadline_s, deselect=False)
        self.stats.stop_report = report
        if report.acted:
            _log.error("interlock: the plan ended with something still running: %s", report.describe())
        if not report.confirmed:
            _log.critical("interlock: stop at the end of the plan NOT confirmed: %s", report.describe())
            if self.on_unsafe is not None:
                trip = InterlockTrip("plan_end", "the plan ended with program or trace not confirmed stopped",
                                     report.describe())
                await self.on_unsafe(trip, report)

    async def make_safe(self, snap: Snapshot | None) -> None:
        """Stop the program, then the trace; each step bounded, errors recorded (never raised: the trip is the
        cause that must reach the plan)."""
        if snap is None or snap.pro_state1 in (None, "P_ACTIVE"):
            try:
                await within(self.krc.stop_program(), self.stop_timeout_s)
            except (TimeoutError, RgseError) as exc:
                self.stats.stop_errors.append(f"stop program: {exc!r}")
                _log.error(
                    "interlock: could not stop the program: %r",
                    exc,
                    extra={"watcher": self.trip.watcher if self.trip else None},
                )
        trace_state = snap.trace_state if snap is not None else None
        if trace_state is None or trace_state in TRACE_ACTIVE_STATES:
            try:
                await within(self.krc.write_raw("$TRACE.MODE", "#T_STOP"), self.stop_timeout_s)
            except (TimeoutError, RgseError) as exc:
                self.stats.stop_errors.append(f"stop trace: {exc!r}")
                _log.error(
                    "interlock: could not stop the trace: %r",
                    exc,
                    extra={"watcher": self.trip.watcher if self.trip else None},
                )
