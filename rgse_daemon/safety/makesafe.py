"""A stop that reaches the robot: stop program and trace, and keep at it until a read-back confirms it.

One attempt is not enough. After a controller stall or a lost link the first ``#10 STOP`` times out, and a program
the daemon started keeps moving the robot. :func:`stop_until_confirmed` therefore loops, with backoff, until one
read of the controller shows nothing left to do, or a bounded deadline passes:

1. read ``$PRO_STATE1``, ``$PRO_NAME1[]`` and ``$TRACE.STATE`` (one snapshot);
2. a program ``#P_ACTIVE`` → stop it (``#10 STOP``, a STOP 2 equivalent: the robot ramps down on its path);
3. one of *our* programs (``RGSE_*``) stopped or reset → cancel it (deselect): nobody can press start and
   resume half a move, and the next run selects its program anew;
4. a trace armed or recording → ``$TRACE.MODE = #T_STOP``;
5. a read that needed none of this is the confirmation.

Every request has its own deadline (:data:`STEP_TIMEOUT_S`). The result is a :class:`StopReport`; a stop that is
not confirmed by the deadline is the caller's to latch (:mod:`rgse_daemon.safety.latch`).

:func:`sweep` is the same stop for what a previous daemon (SIGKILL, power loss) or a previous link left behind: at
daemon start and on every reconnect, before any run is admitted, only for ``RGSE_*`` programs — a program the
daemon did not start is the operator's (the run preconditions refuse to start while it runs).
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass

from rgse_daemon.aio import within
from rgse_daemon.errors import RgseError
from rgse_daemon.krc import KrcController

_log = logging.getLogger(__name__)

#: Our programs' names start with this (``$PRO_NAME1[]`` is the module name, upper case on a KR C4).
OUR_PREFIX = "RGSE_"
#: How long the stop is retried before it is given up and latched (s).
STOP_DEADLINE_S = 30.0
#: Deadline of each request of the stop (s).
STEP_TIMEOUT_S = 2.0
#: Backoff between rounds: first pause and cap (s); doubled each round.
BACKOFF_MIN_S = 0.05
BACKOFF_MAX_S = 2.0
#: Trace states in which a trace is armed, recording or being written.
TRACE_ACTIVE_STATES = frozenset({"T_WAIT", "TRIGGERED", "T_START"})
#: Program states of one of our programs that are cancelled (deselected) once it does not move: it could be
#: started (again) from there. ``#P_END`` needs a reset first and is left as it is.
DESELECT_STATES = frozenset({"P_STOP", "P_RESET"})


@dataclass(frozen=True)
class StopReport:
    """What :func:`stop_until_confirmed` saw and did."""

    confirmed: bool
    rounds: int
    program: str | None
    """``$PRO_NAME1[]`` at the first read that worked (None: never read)."""
    first_state: str | None
    """``$PRO_STATE1`` at the first read that worked."""
    last_state: str | None
    trace_state: str | None
    actions: tuple[str, ...]
    errors: tuple[str, ...]
    duration_s: float

    @property
    def acted(self) -> bool:
        return bool(self.actions)

    def describe(self) -> str:
        what = f"program {self.program or '?'} was #{self.first_state or '?'}"
        did = ", ".join(dict.fromkeys(self.actions)) or "nothing to do"
        if self.confirmed:
            return f"{what}; {did}; confirmed #{self.last_state} after {self.duration_s:.1f} s"
        last = self.errors[-1] if self.errors else f"still #{self.last_state}"
        return (f"{what}; {did}; NOT confirmed within {self.duration_s:.1f} s ({self.rounds} rounds; last: "
                f"{last})")


async def _read_state(krc: KrcController) -> tuple[str, str, str]:
    """``$PRO_STATE1``, ``$PRO_NAME1[]``, ``$TRACE.STATE``: the three variables the stop needs, not a whole snapshot
    (a fault in any other variable must not keep the stop from being confirmed)."""
    values = [str(await krc.read_raw(n)).strip() for n in ("$PRO_STATE1", "$PRO_NAME1[]", "$TRACE.STATE")]
    state, name, trace = values
    return state.lstrip("#").upper(), name.strip('"'), trace.lstrip("#").upper()


def ours(program: str | None) -> bool:
    return bool(program) and str(program).strip().strip('"').upper().startswith(OUR_PREFIX)


async def stop_until_confirmed(
    krc: KrcController,
    *,
    deadline_s: float = STOP_DEADLINE_S,
    any_program: bool = True,
    deselect: bool = True,
    step_timeout_s: float = STEP_TIMEOUT_S,
) -> StopReport:
    """Stop program and trace until a read-back confirms both (see the module docstring), at most ``deadline_s``.

    ``any_program``: stop an active program whatever its name (the interlock: doubt = stop); False stops only
    ``RGSE_*`` programs (the sweep at connect). ``deselect`` False leaves a stopped program selected (step 3).
    Never raises but for cancellation: the report says how it went.
    """
    t0 = time.monotonic()
    deadline = t0 + deadline_s
    actions: list[str] = []
    errors: list[str] = []
    program = first_state = last_state = trace_state = None
    rounds = 0
    pause_s = BACKOFF_MIN_S
    while True:
        rounds += 1
        try:
            state, name, trace_state = await within(_read_state(krc), step_timeout_s)
            if first_state is None:
                program, first_state = name, state
            last_state = state
            todo = False
            if state == "P_ACTIVE" and (any_program or ours(name)):
                todo = True
                actions.append("stop program")
                await within(krc.stop_program(), step_timeout_s)
            elif deselect and state in DESELECT_STATES and ours(name):
                todo = True
                actions.append("cancel program")
                await within(krc.cancel_program(), step_timeout_s)
            if trace_state in TRACE_ACTIVE_STATES:
                todo = True
                actions.append("stop trace")
                await within(krc.write_raw("$TRACE.MODE", "#T_STOP"), step_timeout_s)
            if not todo:
                return StopReport(True, rounds, program, first_state, last_state, trace_state, tuple(actions),
                                  tuple(errors), time.monotonic() - t0)
        except (TimeoutError, RgseError, OSError) as exc:
            errors.append(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__)
            _log.warning("make safe: round %d: %s", rounds, errors[-1])
        now = time.monotonic()
        if now >= deadline:
            return StopReport(False, rounds, program, first_state, last_state, trace_state, tuple(actions),
                              tuple(errors), now - t0)
        await asyncio.sleep(min(pause_s, deadline - now))
        pause_s = min(BACKOFF_MAX_S, pause_s * 2.0)


async def sweep(krc: KrcController, *, deadline_s: float = STOP_DEADLINE_S) -> StopReport:
    """At start and on every (re)connect: stop and deselect an ``RGSE_*`` program left active, stopped or reset,
    and stop a trace left running. The report's :attr:`StopReport.acted` says whether anything was left."""
    return await stop_until_confirmed(krc, deadline_s=deadline_s, any_program=False)
