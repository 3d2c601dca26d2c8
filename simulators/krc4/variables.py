"""The simulated KR C4's variable store and program host: what C3 Bridge messages #0/#1/#4–#7 and #10 act on.

Values are held as KRL value *strings*, exactly as a real controller returns them over KUKAVARPROXY / C3 Bridge
(docs/controller.md §4): ``#T1``, ``100``, ``TRUE``, ``"12_ms_v2.xml"``, ``{E6AXIS: A1 0.0, ...}``. Array elements
(``$TORQUE_AXIS_ACT[3]``) and structure members (``$TRACE.STATE``) are plain keys; names are case-insensitive as in
KRL and stored upper-case.

Extension points, for the parts of the simulator that come later (physics, KRL interpreter, KUKA Trace):

``VariableStore.register_getter(name, fn)``
    ``fn() -> str`` is called on every read of ``name`` (e.g. ``$AXIS_ACT`` from the motion model). The stored
    value is then only a fallback and is not consulted.
``VariableStore.register_setter(name, fn)``
    ``fn(value: str) -> None`` is called on every *accepted* write of ``name``, after validation and before the
    value is stored (e.g. ``$TRACE.MODE = #T_START`` arms a trace). Raising :class:`VariableError` refuses the
    write; the stored value then stays unchanged. Setters run on read-only variables never (the write is refused
    first), so a setter cannot open a read-only variable by accident.
``VariableStore.update(name, value)``
    The simulator's own way to change a value, read-only or not (e.g. ``$PRO_STATE1`` from the interpreter,
    ``$TRACE.STATE`` from the trace engine). Never used for client writes.
``ProgramHost``
    What message #10 (program control) calls. :class:`StateOnlyProgramHost` is the default: it runs nothing
    and only keeps ``$PRO_STATE1`` / ``$PRO_NAME1[]`` (robot interpreter) and ``$PRO_STATE0`` (submit interpreter)
    consistent with the real state machine. The KRL interpreter will provide its own implementation.

All callbacks are synchronous and must not block: the server calls them while it serialises requests across all
clients, as the real single-threaded server does. Long work belongs in a task the callback starts.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol, runtime_checkable

from rgse_daemon import robots
from rgse_daemon.errors import ProtocolError, RgseError, VariableError
from rgse_daemon.krl.values import INT_FIELDS
from rgse_daemon.link.krlvalue import KrlBits, KrlEnum, KrlStruct, KrlValue, format_value, parse_value
from rgse_daemon.robots import RobotModel

# C3 Bridge error codes used by the store and the program host (docs/protocol.md §1).
CODE_GENERAL = 0
CODE_ACCESS = 2
CODE_ARGUMENT = 3
CODE_UNEXPECTED = 6
CODE_NOT_IMPLEMENTED = 7

AXES = range(1, 7)


class Kind(StrEnum):
    """The KRL data type of a variable; a client write must parse as this kind."""

    INT = "INT"
    REAL = "REAL"
    BOOL = "BOOL"
    ENUM = "ENUM"
    CHAR = "CHAR[]"  # a string, written and read with double quotes
    STRUC = "STRUC"
    BITS = "BITS"  # e.g. $BRAKE_SIG B000000


Getter = Callable[[], str]
Setter = Callable[[str], None]
Check = Callable[[str], str | None]
"""A write check: returns ``None`` if the value is acceptable, else a message saying why not."""


@dataclass
class Variable:
    """One entry of the store: its kind, current KRL value string and whether clients may write it."""

    name: str
    kind: Kind
    value: str
    writable: bool
    check: Check | None = None
    getter: Getter | None = None
    setters: list[Setter] = field(default_factory=list)


_WS = re.compile(r"\s+")


def normalize_name(name: str) -> str:
    """KRL names are case-insensitive and contain no blanks: ``$torque_axis_act[ 3 ]`` → ``$TORQUE_AXIS_ACT[3]``."""
    return _WS.sub("", name).upper()


_KIND_TEST: dict[Kind, Callable[[KrlValue], bool]] = {
    Kind.INT: lambda v: isinstance(v, int) and not isinstance(v, bool),
    Kind.REAL: lambda v: isinstance(v, int | float) and not isinstance(v, bool),
    Kind.BOOL: lambda v: isinstance(v, bool),
    Kind.ENUM: lambda v: isinstance(v, KrlEnum),
    Kind.CHAR: lambda v: isinstance(v, str),
    Kind.STRUC: lambda v: isinstance(v, KrlStruct),
    Kind.BITS: lambda v: isinstance(v, KrlBits),
}


def canonical(kind: Kind, text: str) -> str:
    """The text the controller reads back after ``text`` was written to a ``kind`` variable.

    ``35`` written to a REAL reads back ``35.0``; blanks around and inside structures are normalised.

    Raises
    ------
    ValueError
        ``text`` is no KRL value, or not one of ``kind``; the message says which.
    """
    try:
        value = parse_value(text)
    except ProtocolError as exc:
        raise ValueError(f"not a KRL value: {exc}") from exc
    if not _KIND_TEST[kind](value):
        raise ValueError(f"expected a {kind.value} value, got {text.strip()[:40]!r}")
    if kind is Kind.REAL:
        value = float(value)  # type: ignore[arg-type]
    elif isinstance(value, KrlEnum):
        value = KrlEnum(value.name.upper())  # KRL is case-insensitive; the controller answers upper case
    elif isinstance(value, KrlStruct):
        value = _reals_in(value)
    return format_value(value)


def _reals_in(struct: KrlStruct) -> KrlStruct:
    """``{M 12, ...}`` reads back as ``{M 12.0, ...}``: numbers in the system structures (E6AXIS, E6POS, FRAME,
    LOAD, INERTIA) are REAL except the status and turn of a POS (``INT_FIELDS``)."""
    fields: list[tuple[str, KrlValue]] = []
    for name, v in struct.fields:
        if isinstance(v, KrlStruct):
            v = _reals_in(v)
        elif isinstance(v, int) and not isinstance(v, bool) and name.upper() not in INT_FIELDS:
            v = float(v)
        fields.append((name, v))
    return KrlStruct(struct.type_name, tuple(fields))


def _int_range(lo: int, hi: int) -> Check:
    def check(value: str) -> str | None:
        number = int(value.strip())
        return None if lo <= number <= hi else f"{number} is outside {lo}..{hi}"

    return check


def _enum_of(*allowed: str) -> Check:
    allowed_upper = {a.upper() for a in allowed}

    def check(value: str) -> str | None:
        return None if value.strip().upper() in allowed_upper else f"expected one of {', '.join(allowed)}"

    return check


def e6axis(a_deg: Iterable[float]) -> str:
    """Format six axis angles (deg) as the controller prints an ``E6AXIS`` (external axes E1–E6 at 0)."""
    fields: list[tuple[str, KrlValue]] = [(f"A{i}", float(v)) for i, v in enumerate(a_deg, 1)]
    fields += [(f"E{i}", 0.0) for i in range(1, 7)]
    return format_value(KrlStruct("E6AXIS", tuple(fields)))


#: Where the robot rests when the simulator starts (deg): the simulated (active) robot's home; for the KR 500 the
#: pose of the ``$AXIS_ACT`` example in docs/controller.md §4. This name is the default robot's (an alias).
HOME_AXES_DEG = robots.get(robots.DEFAULT_KEY).home_deg


def model_name_of(robot: RobotModel) -> str:
    """``$MODEL_NAME[]`` of a KR C4 driving ``robot``: ``#KR500R2830 C4``."""
    return f"#{robot.title.replace(' ', '')} C4"


class VariableStore:
    """The controller's variables, as KRL value strings.

    Parameters
    ----------
    model_name, serial_no:
        What ``$MODEL_NAME[]`` and ``$KR_SERIALNO`` read (also the UDP discovery answer).
    seed_system:
        Seed the system variables a KR C4 has (``$MODE_OP``, ``$AXIS_ACT``, ``$TRACE.STATE`` ...). Tests of the
        store itself may start empty.
    """

    def __init__(
        self, *, model_name: str | None = None, serial_no: int = 1234567, seed_system: bool = True
    ) -> None:
        self.robot = robots.active()
        model_name = model_name_of(self.robot) if model_name is None else model_name
        self._vars: dict[str, Variable] = {}
        if seed_system:
            self._seed(model_name, serial_no)

    # --- declaring -----------------------------------------------------------------------------------------------
    def declare_system(
        self, name: str, kind: Kind, value: str, *, writable: bool = False, check: Check | None = None
    ) -> None:
        """Add (or redefine) a system variable. ``check`` adds a constraint beyond the kind (e.g. 0..100 %)."""
        key = normalize_name(name)
        self._vars[key] = Variable(key, kind, value, writable, check)

    def declare_global(self, name: str, kind: Kind, value: str) -> None:
        """Declare a user global (as a ``GLOBAL`` declaration in a ``.dat`` would): readable and writable.

        Raises
        ------
        VariableError
            ``name`` is a system variable (starts with ``$``) or ``value`` is not a ``kind`` value.
        """
        key = normalize_name(name)
        if key.startswith("$"):
            raise VariableError(key, "a user global cannot start with $", CODE_ARGUMENT)
        try:
            value = canonical(kind, value)
        except ValueError as exc:
            raise VariableError(key, str(exc), CODE_ARGUMENT) from exc
        existing = self._vars.get(key)
        if existing is not None and existing.kind is kind:
            existing.value = value  # re-declaration (program re-loaded) keeps callbacks
            return
        self._vars[key] = Variable(key, kind, value, True)

    def is_declared(self, name: str) -> bool:
        return normalize_name(name) in self._vars

    def names(self) -> list[str]:
        """All declared names, sorted."""
        return sorted(self._vars)

    def kind_of(self, name: str) -> Kind:
        return self._get(name).kind

    # --- extension points -----------------------------------------------------------------------------------------
    def register_getter(self, name: str, fn: Getter) -> None:
        """Compute ``name`` on every read by calling ``fn() -> str`` (replaces an earlier getter)."""
        self._get(name).getter = fn

    def register_setter(self, name: str, fn: Setter) -> None:
        """Call ``fn(value)`` on every accepted client write of ``name``; it may raise VariableError to refuse."""
        self._get(name).setters.append(fn)

    def update(self, name: str, value: str) -> None:
        """Set a value from inside the simulator, read-only or not (no kind check, no setters)."""
        self._get(name).value = value

    # --- client access (messages #0/#1, #4/#5, #6/#7) ---------------------------------------------------------------
    def read(self, name: str) -> str:
        """The KRL value string of ``name``.

        Raises
        ------
        VariableError
            The name is not declared (the real controller answers an empty value with success 0).
        """
        var = self._get(name)
        return var.getter() if var.getter is not None else var.value

    def write(self, name: str, value: str) -> str:
        """Write ``value`` as a client would and return the value as read back afterwards.

        Raises
        ------
        VariableError
            Unknown name, read-only variable (code 2), value not of the variable's kind or outside its range
            (code 3), or refused by a registered setter.
        """
        var = self._get(name)
        if not var.writable:
            raise VariableError(var.name, "is read-only", CODE_ACCESS)
        try:
            value = canonical(var.kind, value)
        except ValueError as exc:
            raise VariableError(var.name, str(exc), CODE_ARGUMENT) from exc
        problem = var.check(value) if var.check else None
        if problem:
            raise VariableError(var.name, problem, CODE_ARGUMENT)
        for setter in var.setters:
            setter(value)
        var.value = value
        return self.read(var.name)

    def _get(self, name: str) -> Variable:
        key = normalize_name(name)
        var = self._vars.get(key)
        if var is None:
            raise VariableError(key or repr(name), "unknown variable", CODE_GENERAL)
        return var

    # --- the system variables of a KR C4 (docs/controller.md §4) -------------------------------------------------
    def _seed(self, model_name: str, serial_no: int) -> None:
        ro = self.declare_system
        ro("$MODE_OP", Kind.ENUM, "#T1")
        ro("$AXIS_ACT", Kind.STRUC, e6axis(self.robot.home_deg))
        ro("$AXIS_ACT_MEAS", Kind.STRUC, e6axis(self.robot.home_deg))
        ro(
            "$POS_ACT",
            Kind.STRUC,
            "{E6POS: X 1339.90503, Y 15.9216757, Z 1787.32227, A 0.0, B 89.9999466, C -0.680795908, S 6, T 19, "
            "E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}",
        )
        ro("$VEL_ACT", Kind.REAL, "0.0")  # Cartesian TCP speed, m/s
        ro("$OV_PRO", Kind.INT, "100", writable=True, check=_int_range(0, 100))
        ro("$BRAKE_SIG", Kind.BITS, "B000000")  # one bit per axis, 1 = brake released
        ro("$ROB_STOPPED", Kind.BOOL, "TRUE")
        for i in AXES:
            ro(f"$TORQUE_AXIS_ACT[{i}]", Kind.REAL, "0.0")  # Nm at the gear output
            ro(f"$CURR_ACT[{i}]", Kind.REAL, "0.0")
            ro(f"$MOT_TEMP[{i}]", Kind.INT, "298")  # Kelvin
        ro(
            "$LOAD",
            Kind.STRUC,
            "{M -1.0, CM {X 0.0, Y 0.0, Z 0.0, A 0.0, B 0.0, C 0.0}, J {X 0.0, Y 0.0, Z 0.0}}",
            writable=True,
        )
        ro("$TRACE.STATE", Kind.ENUM, "#T_END")
        ro("$TRACE.CONFIG[]", Kind.CHAR, '""', writable=True)
        ro("$TRACE.NAME[]", Kind.CHAR, '""', writable=True)
        ro("$TRACE.MODE", Kind.ENUM, "#T_STOP", writable=True, check=_enum_of("#T_START", "#T_STOP"))
        ro("$PRO_STATE0", Kind.ENUM, "#P_ACTIVE")  # the submit interpreter (SPS) runs from power-on
        ro("$PRO_NAME0[]", Kind.CHAR, '"SPS"')
        ro("$PRO_STATE1", Kind.ENUM, "#P_FREE")
        ro("$PRO_NAME1[]", Kind.CHAR, '""')
        ro("$PERI_RDY", Kind.BOOL, "FALSE")  # drives on; in T1 only while the enabling switch is held
        ro("$USER_SAF", Kind.BOOL, "TRUE")  # safety gate / operator safety closed
        ro("$STOPMESS", Kind.BOOL, "FALSE")
        ro("$MODEL_NAME[]", Kind.CHAR, f'"{model_name}"')
        ro("$ROBNAME[]", Kind.CHAR, f'"{self.robot.title.replace(" ", "")}"')
        ro("$KR_SERIALNO", Kind.INT, str(serial_no))
        ro("$ACCU_STATE", Kind.ENUM, "#CHARGE_OK")
        self.timers = SystemTimers(self)


#: The KR C4's system timers $TIMER[1..64] (KSS 8.x).
TIMER_COUNT = 64


class SystemTimers:
    """``$TIMER[n]`` (INT, ms), ``$TIMER_STOP[n]`` (BOOL) and ``$TIMER_FLAG[n]`` (BOOL, read-only), n = 1..64.

    As on a KR C4: a timer counts up in ms while ``$TIMER_STOP[n]`` is FALSE; writing ``$TIMER[n]`` sets it (running
    or not); ``$TIMER_FLAG[n]`` is TRUE while ``$TIMER[n] >= 0``. At power-on every timer is stopped at 0.

    Clock: the timers count **wall-clock** milliseconds (``time.monotonic``), not the simulator's scaled time. A
    simplification, said here: the simulator runs its motions ``time_scale`` times faster than real time, but the
    timers are what a host's heartbeat is measured against (the daemon's controller-side watchdog,
    ``docs/security.md``), and the host lives in real time. Scaling them would make a heartbeat of a real-time host
    look ``time_scale`` times slower than it is.
    """

    def __init__(self, store: VariableStore, clock: Callable[[], float] | None = None) -> None:
        self._clock = clock or time.monotonic
        self._base_ms = [0] * (TIMER_COUNT + 1)
        self._since = [0.0] * (TIMER_COUNT + 1)
        self._running = [False] * (TIMER_COUNT + 1)
        for n in range(1, TIMER_COUNT + 1):
            store.declare_system(f"$TIMER[{n}]", Kind.INT, "0", writable=True)
            store.declare_system(f"$TIMER_STOP[{n}]", Kind.BOOL, "TRUE", writable=True)
            store.declare_system(f"$TIMER_FLAG[{n}]", Kind.BOOL, "TRUE")
            store.register_getter(f"$TIMER[{n}]", lambda n=n: str(self.value_ms(n)))  # type: ignore[misc]
            store.register_setter(f"$TIMER[{n}]", lambda v, n=n: self.set_ms(n, int(v)))  # type: ignore[misc]
            store.register_getter(f"$TIMER_STOP[{n}]", lambda n=n: "FALSE" if self._running[n] else "TRUE")  # type: ignore[misc]
            store.register_setter(f"$TIMER_STOP[{n}]", lambda v, n=n: self.set_stopped(n, v == "TRUE"))  # type: ignore[misc]
            store.register_getter(f"$TIMER_FLAG[{n}]", lambda n=n: "TRUE" if self.value_ms(n) >= 0 else "FALSE")  # type: ignore[misc]

    def value_ms(self, n: int) -> int:
        if not self._running[n]:
            return self._base_ms[n]
        return self._base_ms[n] + int((self._clock() - self._since[n]) * 1000.0)

    def set_ms(self, n: int, value_ms: int) -> None:
        self._base_ms[n] = value_ms
        self._since[n] = self._clock()

    def set_stopped(self, n: int, stopped: bool) -> None:
        if stopped and self._running[n]:
            self._base_ms[n] = self.value_ms(n)
        elif not stopped and not self._running[n]:
            self._since[n] = self._clock()
        self._running[n] = not stopped


# --- program control (message #10) ------------------------------------------------------------------------------------
class ProgramControlError(RgseError):
    """The simulated controller refuses a program-control command; ``code`` is the C3 Bridge error code."""

    def __init__(self, message: str, code: int = CODE_UNEXPECTED) -> None:
        super().__init__(message)
        self.code = code


class ProState(StrEnum):
    """``$PRO_STATE1`` values (docs/controller.md §4)."""

    FREE = "#P_FREE"
    RESET = "#P_RESET"
    ACTIVE = "#P_ACTIVE"
    STOP = "#P_STOP"
    END = "#P_END"


INTERPRETER_SUBMIT = 0
INTERPRETER_ROBOT = 1


@runtime_checkable
class ProgramHost(Protocol):
    """What message #10 calls (C3 Bridge passes these to Cross3 ``IKSyncSelect``).

    Subtype I: ``reset/start/stop/cancel(interpreter)`` with interpreter 0 = Submit, 1 = Robot.
    Subtype II: ``select/run(name, params, force)``; ``run`` is select + start. ``name`` is as the client sent it
    (e.g. ``KRC:\\R1\\PROGRAM\\TEST.SRC`` or ``/R1/TEST``). Raise :class:`ProgramControlError` to refuse; its code
    goes on the wire. Calls must not block.
    """

    def select(self, name: str, params: str, force: bool) -> None: ...

    def run(self, name: str, params: str, force: bool) -> None: ...

    def reset(self, interpreter: int) -> None: ...

    def start(self, interpreter: int) -> None: ...

    def stop(self, interpreter: int) -> None: ...

    def cancel(self, interpreter: int) -> None: ...


def module_name(program: str) -> str:
    """``KRC:\\R1\\PROGRAM\\Test.src`` → ``TEST``: what ``$PRO_NAME1[]`` shows for a selected program."""
    last = re.split(r"[\\/]", program.strip())[-1]
    stem = last.rsplit(".", 1)[0] if "." in last else last
    return stem.upper()


class StateOnlyProgramHost:
    """The default :class:`ProgramHost`: runs nothing, keeps the interpreter state variables honest.

    Robot interpreter: ``#P_FREE`` → select → ``#P_RESET`` → start → ``#P_ACTIVE`` → stop → ``#P_STOP`` → start →
    ``#P_ACTIVE`` …; reset from ``#P_STOP``/``#P_END`` → ``#P_RESET``; cancel (not while ``#P_ACTIVE``) →
    ``#P_FREE``. Refusals mirror what the HMI refuses: selecting or cancelling while running, starting with no
    program selected. The submit interpreter (0) is lenient: reset → ``#P_RESET``, start → ``#P_ACTIVE``,
    stop → ``#P_STOP``, cancel → ``#P_FREE`` from any state.

    Parameters
    ----------
    exists:
        Optional ``exists(name) -> bool``; when given, selecting a program it does not know is refused (code 3).
    """

    def __init__(self, store: VariableStore, exists: Callable[[str], bool] | None = None) -> None:
        self.store = store
        self._exists = exists

    def _state(self, interpreter: int) -> ProState:
        return ProState(self.store.read(self._state_var(interpreter)).strip().upper())

    @staticmethod
    def _state_var(interpreter: int) -> str:
        if interpreter not in (INTERPRETER_SUBMIT, INTERPRETER_ROBOT):
            raise ProgramControlError(f"interpreter {interpreter} does not exist", CODE_ARGUMENT)
        return f"$PRO_STATE{interpreter}"

    def _set(self, interpreter: int, state: ProState) -> None:
        self.store.update(self._state_var(interpreter), state.value)

    def select(self, name: str, params: str, force: bool) -> None:
        if not name.strip():
            raise ProgramControlError("no program name given", CODE_ARGUMENT)
        if self._state(INTERPRETER_ROBOT) is ProState.ACTIVE:
            raise ProgramControlError("a program is running: stop it before selecting another")
        if self._exists is not None and not self._exists(name):
            raise ProgramControlError(f"program {name!r} not found", CODE_ARGUMENT)
        self.store.update("$PRO_NAME1[]", f'"{module_name(name)}"')
        self._set(INTERPRETER_ROBOT, ProState.RESET)

    def run(self, name: str, params: str, force: bool) -> None:
        self.select(name, params, force)
        self.start(INTERPRETER_ROBOT)

    def reset(self, interpreter: int) -> None:
        state = self._state(interpreter)
        if interpreter == INTERPRETER_SUBMIT:
            self._set(interpreter, ProState.RESET)  # lenient: the spec's own vector resets a submit interpreter
            return
        if state is ProState.ACTIVE:
            raise ProgramControlError("cannot reset a running program: stop it first")
        if state is ProState.FREE:
            raise ProgramControlError("no program selected")
        self._set(interpreter, ProState.RESET)

    def start(self, interpreter: int) -> None:
        state = self._state(interpreter)
        if state is ProState.FREE and interpreter == INTERPRETER_ROBOT:
            raise ProgramControlError("no program selected")
        if state is ProState.END and interpreter == INTERPRETER_ROBOT:
            raise ProgramControlError("program has ended: reset it before starting")
        self._set(interpreter, ProState.ACTIVE)

    def stop(self, interpreter: int) -> None:
        if self._state(interpreter) is ProState.ACTIVE:
            self._set(interpreter, ProState.STOP)

    def cancel(self, interpreter: int) -> None:
        if self._state(interpreter) is ProState.ACTIVE and interpreter == INTERPRETER_ROBOT:
            raise ProgramControlError("cannot cancel a running program: stop it first")
        self._set(interpreter, ProState.FREE)
        if interpreter == INTERPRETER_ROBOT:
            self.store.update("$PRO_NAME1[]", '""')
