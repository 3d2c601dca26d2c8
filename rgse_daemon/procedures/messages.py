"""The small messages a plan yields; :class:`~rgse_daemon.procedures.engine.RunEngine` executes them.

A plan is a generator: ``reply = yield Msg(...)``. Keeping every action a plain, inspectable value is what gives
a dry run (the engine logs and checks, sends nothing), limit checks before motion (``Push`` runs the interlock's
static check against the live controller state), pause/resume at ``Checkpoint`` and a resumable campaign
(:class:`ReadCampaign`) — bluesky's plan/engine split (architecture lesson 1). What a plan wants *recorded* it yields
as a run document (:mod:`~rgse_daemon.procedures.documents`, also messages); it holds no store.

Replies (what ``yield`` returns) are named in each docstring.

**Dry runs are inert by construction.** A message type is executed in a dry run only if its class says it is
``inert`` (it changes nothing outside the daemon: reads, progress, pure computation, pause points). Every other
message — whatever moves the robot, writes to the controller, waits for what such a message began, or records to
the store — is logged and answered with :meth:`Msg.dry_reply` instead. A new message type is therefore skipped in
a dry run until someone declares it inert; no list has to be kept up to date.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

from rgse_daemon.procedures.events import Event

#: Where the daemon's programs go on the controller.
PROGRAM_DIR = "KRC:\\R1\\PROGRAM\\"


class Program(Protocol):
    """A rendered KRL program (``rgse_daemon.krl.render.RenderedProgram``): module name, .src and .dat text."""

    @property
    def name(self) -> str: ...
    @property
    def src_text(self) -> str: ...
    @property
    def dat_text(self) -> str | None: ...


@dataclass(frozen=True)
class Msg:
    """Base of every message. Not inert: a dry run skips it (see the module docstring)."""

    #: True only if executing this message changes nothing outside the daemon; a dry run executes only these.
    inert: ClassVar[bool] = False

    def describe(self) -> str:
        return type(self).__name__

    def dry_reply(self) -> Any:
        """What a dry run answers instead of executing a message that is not inert."""
        return None


Plan = Generator[Msg, Any, Any]


# --- programs ----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Push(Msg):
    """Statically check ``program`` against the live context and, only if allowed, write its .src/.dat to the
    controller. Reply: the controller name of the .src (``KRC:\\R1\\PROGRAM\\<NAME>.SRC``). A refusal raises
    :class:`~rgse_daemon.errors.InterlockError` before a byte is sent. Dry run: the check runs, nothing is sent."""

    program: Program

    def describe(self) -> str:
        return f"Push {self.program.name}"

    def dry_reply(self) -> str:
        """The controller name the program would have (a dry run still checks it: see the engine)."""
        return PROGRAM_DIR + self.program.name.upper() + ".SRC"


@dataclass(frozen=True)
class Select(Msg):
    """Select a pushed program (controller name) in the robot interpreter."""

    name: str

    def describe(self) -> str:
        return f"Select {self.name}"


@dataclass(frozen=True)
class Start(Msg):
    """Start the selected program; from here the monitor expects it running. Reply: wall time of the start (s,
    monotonic). In T1 the operator still holds the enabling switch; the controller refuses a start without it."""

    def dry_reply(self) -> float:
        return time.monotonic()


@dataclass(frozen=True)
class WaitProgram(Msg):
    """Wait until ``$PRO_STATE1`` is one of ``states`` (without ``#``), polling, at most ``timeout_s``.
    Reply: (state, waited_s). ``P_STOP`` while waiting for the end is an error (the program stopped)."""

    states: frozenset[str] = frozenset({"P_END"})
    timeout_s: float = 600.0

    def describe(self) -> str:
        return f"WaitProgram {'/'.join(sorted(self.states))} ≤ {self.timeout_s:g} s"

    def dry_reply(self) -> tuple[str, float]:
        return "P_END", 0.0  # nothing was started: nothing to wait for


@dataclass(frozen=True)
class VerifyDone(Msg):
    """Read the program's handshake flag after ``#P_END`` and fail unless it is TRUE: the daemon never claims a
    motion happened without reading it back. Not sent in a dry run."""

    variable: str = "RGSE_DONE"


@dataclass(frozen=True)
class StopProgram(Msg):
    """Stop the robot interpreter if a program is active (idempotent; part of every finaliser)."""


# --- variables and files -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReadState(Msg):
    """Reply: a fresh :class:`~rgse_daemon.controller.Snapshot` (also in a dry run: reading changes nothing)."""

    inert: ClassVar[bool] = True


@dataclass(frozen=True)
class ReadVar(Msg):
    """Reply: the parsed value of one variable (also in a dry run)."""

    inert: ClassVar[bool] = True

    name: str


@dataclass(frozen=True)
class WriteVar(Msg):
    """Write KRL value text (``#T_START``, ``"name"``, ``30``) to an allow-listed variable."""

    name: str
    text: str

    def describe(self) -> str:
        return f"WriteVar {self.name} = {self.text}"


@dataclass(frozen=True)
class PutFile(Msg):
    """Write a controller file (e.g. the trace configuration XML in the TRACE folder)."""

    name: str
    data: bytes

    def describe(self) -> str:
        return f"PutFile {self.name} ({len(self.data)} bytes)"


# --- trace -------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TraceStart(Msg):
    """``$TRACE.CONFIG[]``, ``$TRACE.NAME[]``, then ``$TRACE.MODE = #T_START``; the monitor/finaliser knows a
    trace may be recording from here."""

    name: str
    config: str

    def describe(self) -> str:
        return f"TraceStart {self.name} ({self.config})"


@dataclass(frozen=True)
class TraceWait(Msg):
    """Wait until the trace has been written (``$TRACE.STATE`` back to ``#T_END`` after leaving it), at most
    ``timeout_s``. Reply: waited_s (0 in a dry run: no trace was started)."""

    timeout_s: float = 120.0

    def dry_reply(self) -> float:
        return 0.0


@dataclass(frozen=True)
class TraceStop(Msg):
    """``$TRACE.MODE = #T_STOP`` if a trace is armed or recording (idempotent; part of every finaliser)."""


@dataclass(frozen=True)
class Pull(Msg):
    """Fetch every file of trace ``trace`` from the controller's TRACE folder into ``dest_dir`` durably, verified.
    The controller copies stay until :class:`DeleteTraceCopies`. Reply:
    :class:`~rgse_daemon.procedures.retrieval.PulledTrace`."""

    trace: str
    dest_dir: Path
    timeout_s: float = 120.0
    modules: tuple[str, ...] = ()
    """The modules whose files must be there (``.dat`` and ``.r64``); empty: the drives of A3 and A5."""

    def describe(self) -> str:
        return f"Pull {self.trace} → {self.dest_dir}"


@dataclass(frozen=True)
class PullStart(Msg):
    """Start pulling trace ``trace`` like :class:`Pull`, in the background, so that the next loop's settling and
    recording overlap it (the pull stays under the monitor's file-window rule: it opens only at standstill, and the
    engine lets no motion message (``Push``, ``Select``, ``Start``, ``PutFile``, ``Pull``) run before every pull in
    flight has ended). A failed pull interrupts the plan at once. Collect it with :class:`PullJoin`. Reply: None."""

    trace: str
    dest_dir: Path
    modules: tuple[str, ...] = ()

    def describe(self) -> str:
        return f"PullStart {self.trace} → {self.dest_dir}"


@dataclass(frozen=True)
class PullJoin(Msg):
    """Wait for the background pull of ``trace`` (:class:`PullStart`). Reply: (``PulledTrace``, the seconds the plan
    waited for it, the seconds the pull took in all); a failed pull raises its error."""

    trace: str
    timeout_s: float = 600.0

    def describe(self) -> str:
        return f"PullJoin {self.trace}"


@dataclass(frozen=True)
class DeleteTraceCopies(Msg):
    """Delete the controller copies of a pulled trace — only once the store indexed its files. Reply: (deleted,
    note); a failed delete is not an error (the note says why)."""

    pulled: Any
    timeout_s: float = 60.0

    def describe(self) -> str:
        return f"DeleteTraceCopies {getattr(self.pulled, 'trace', '?')}"


# --- flow --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sleep(Msg):
    """Wait ``seconds`` of daemon (wall) time. Controller-timed waits (settling) belong in the KRL program.
    Skipped in a dry run (it waits for the robot to settle)."""

    seconds: float


@dataclass(frozen=True)
class Checkpoint(Msg):
    """A point where the plan may pause (robot still, nothing recording)."""

    inert: ClassVar[bool] = True

    label: str = ""


@dataclass(frozen=True)
class Confirm(Msg):
    """Ask the operator (CLI/MQTT ``confirm``) and wait for :meth:`RunEngine.confirm`; ``timeout_s`` None: no limit.
    Reply: the operator's note (str) or ``""``. Dry run: confirmed at once (nobody mounts anything)."""

    prompt: str
    timeout_s: float | None = None
    data: dict[str, Any] = field(default_factory=dict)

    def dry_reply(self) -> str:
        return ""


@dataclass(frozen=True)
class Emit(Msg):
    """Publish a progress event to the engine's subscribers."""

    inert: ClassVar[bool] = True

    event: Event


@dataclass(frozen=True)
class Process(Msg):
    """Run blocking work with effects (writing the manifest, fitting and writing CAL.json) in a worker thread, at
    most ``timeout_s``. Reply: ``fn(*args)``. Skipped in a dry run (reply None)."""

    label: str
    fn: Callable[..., Any]
    args: tuple[Any, ...] = ()
    timeout_s: float = 300.0

    def describe(self) -> str:
        return f"Process {self.label}"


@dataclass(frozen=True)
class Compute(Process):
    """A pure computation (rendering a program: choosing the safe axis speed) in a worker thread, so the event loop
    and the interlock monitor keep going. Executed in a dry run too."""

    inert: ClassVar[bool] = True

    def describe(self) -> str:
        return f"Compute {self.label}"


@dataclass(frozen=True)
class ReadCampaign(Msg):
    """Where the run's campaign stands, from the engine's recorder (the store): reply
    :class:`~rgse_daemon.procedures.documents.CampaignProgress` (points, loops and trace files recorded so far),
    so a campaign resumes at the first incomplete point."""

    inert: ClassVar[bool] = True
