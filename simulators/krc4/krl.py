"""The simulated KR C4's robot interpreter: runs parsed KRL programs as an asyncio task in scaled time.

:class:`KrlInterpreter` implements the :class:`~simulators.krc4.variables.ProgramHost` protocol (C3 Bridge message
#10), so the server's select/run/start/stop/reset/cancel drive it; it keeps ``$PRO_STATE1``/``$PRO_NAME1[]`` as the
real controller does:

``#P_FREE`` → select → ``#P_RESET`` → start → ``#P_ACTIVE`` → end → ``#P_END``; stop (or HALT, or a safety stop) →
``#P_STOP``, start resumes where it stopped; reset → ``#P_RESET`` (from the beginning); cancel → ``#P_FREE``.

Time: ``time_scale`` simulated seconds pass per wall second (100 in tests). Motions, ``WAIT SEC`` and ``WAIT FOR``
polling all run on that clock.

Operating mode (``$MODE_OP``): in T1/T2 a program runs only while the simulated operator holds the enabling switch
and the start key (:meth:`KrlInterpreter.set_enabling_switch`, :meth:`KrlInterpreter.set_start_key`; both held by
default). Releasing the enabling switch is a STOP 2: the motion ramps down on its path, the program stops and
``$STOPMESS`` stays TRUE until :meth:`KrlInterpreter.acknowledge`; releasing the start key stops the same way without
a message. In T1 the flange speed is clamped to 250 mm/s (see :mod:`simulators.krc4.motion`).

Variables: routine locals and non-GLOBAL data-list entries live in the interpreter (data-list values are persistent,
as on the controller: reset keeps them, and so does a new select while the module's ``.dat`` text is unchanged);
``DECL GLOBAL`` entries of the module's ``.dat`` become store globals at select (so the daemon reads and writes them
over the link and ``WAIT FOR`` sees its writes); system variables the store knows (``$OV_PRO``, ``$TRACE.MODE``,
``$TRACE.NAME[]``, ``$AXIS_ACT`` …) are read and written *through the store*, so registered getters and setters (the
trace engine) see them. The motion settings (``$VEL_AXIS[i]``, ``$ACC_AXIS[i]``, ``$VEL.CP``, ``$ACC.CP``,
``$APO``) are the interpreter's own.

Simplifications (said, not hidden): no advance run, so approximation (``C_PTP``/``C_DIS``) is accepted and ignored;
motions to Cartesian targets are refused (no inverse kinematics) and LIN is joint-interpolated; ``BAS`` knows
``#INITMOV``, ``#VEL_PTP``, ``#ACC_PTP``, ``#VEL_CP``, ``#ACC_CP``.

Interrupts: ``INTERRUPT DECL prio WHEN condition DO routine( )``, ``INTERRUPT ON|OFF [prio]`` (ENABLE/DISABLE as
ON/OFF). An interrupt that is on fires when its condition turns from FALSE to TRUE (edge: a condition already TRUE
at ``INTERRUPT ON`` does not fire). Conditions are checked at every interpolation cycle of a motion or a wait and
between statements; the routine runs in the program's task with the interrupted motion held, one interrupt at a
time (no priorities among simultaneous ones: the lowest number first). ``BRAKE`` (``BRAKE F``) in the routine brakes
the interrupted motion on its path to rest (the STOP 2 ramp; ``F`` the same here), outside an interrupt routine it
is a run-time error; when the routine returns, the motion continues to its target. System timers ``$TIMER[n]``,
``$TIMER_STOP[n]``, ``$TIMER_FLAG[n]`` (:class:`~simulators.krc4.variables.SystemTimers`) count wall-clock ms.

Physics hooks: :meth:`KrlInterpreter.add_motion_listener` gets a :class:`MotionEvent` at every motion start and end
(with the axes and the direction each axis came from: what brake-release and settling transients depend on).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import PurePath

import numpy as np

from rgse_daemon.errors import KrlSyntaxError, RgseError, VariableError
from rgse_daemon.kinematics import flange_pose_xyzabc
from rgse_daemon.krl import ast as k
from rgse_daemon.krl import values as kv
from rgse_daemon.krl.evaluate import BUILTINS, Evaluator
from rgse_daemon.krl.parser import parse_dat, parse_src
from rgse_daemon.krl.values import (
    AXIS_FIELDS,
    EXT_FIELDS,
    KrlArray,
    Value,
    check_index,
    convert,
    element,
    member,
    merge,
)
from rgse_daemon.krl.walk import iter_exprs
from rgse_daemon.link.krlvalue import KrlBits, KrlEnum, KrlStruct, KrlValue, ProtocolError, format_value, parse_value
from simulators.krc4.files import ShareFiles
from simulators.krc4.motion import (
    T1_LIMIT_MM_S,
    JointMove,
    MotionError,
    MotionSettings,
    flange_speed_mm_s,
    plan_joint_move,
)
from simulators.krc4.variables import (
    CODE_ARGUMENT,
    INTERPRETER_ROBOT,
    Kind,
    ProgramControlError,
    ProState,
    StateOnlyProgramHost,
    VariableStore,
    e6axis,
    module_name,
)

#: Interpolation cycle of the KR C4 (s, simulated): the period of axis updates and WAIT FOR polling.
IPO_PERIOD_S = 0.012
#: Shortest wall-clock sleep between ticks (s): keeps scaled-time runs from spinning the CPU.
MIN_TICK_WALL_S = 0.002


_log = logging.getLogger(__name__)


class KrlRuntimeError(RgseError):
    """A program failed while running (unknown variable, division by zero, refused motion ...): it stops."""

    def __init__(self, message: str, pos: k.Pos | None = None, file: str | None = None) -> None:
        where = f"{file or '<program>'}:{pos.line}:{pos.column}: " if pos is not None and pos.line else ""
        super().__init__(where + message)
        self.message = message
        self.pos = pos
        self.file = file


@dataclass(frozen=True)
class MotionEvent:
    """A motion started (``kind`` ``"start"``), began to brake on its path (``"brake"``: a stop) or came to rest
    (``"end"``; ``stopped`` if a stop cut it short).

    ``q_deg``: axes now (deg); ``target_deg``: where the motion goes; ``directions``: sign of each axis' travel (+1,
    −1, 0), i.e. the side an axis approaches its rest position from; ``t_s``: simulated time; ``move``: the planned
    motion that begins now (``"start"``, ``"brake"``), the profile the axes will follow (the dynamics use it).
    """

    kind: str
    q_deg: tuple[float, ...]
    target_deg: tuple[float, ...]
    directions: tuple[int, ...]
    t_s: float
    stopped: bool = False
    move: JointMove | None = None


MotionListener = Callable[[MotionEvent], None]
ProgramLoader = Callable[[str], tuple[str, str, str | None]]
"""``load(name) -> (module name, .src text, .dat text or None)``; raises ProgramControlError if not found."""


def share_loader(files: ShareFiles) -> ProgramLoader:
    """Load ``NAME.SRC`` and its ``NAME.DAT`` from the simulated controller's share (ISO-8859-1 text)."""

    def load(name: str) -> tuple[str, str, str | None]:
        stem = name.strip()
        suffix = PurePath(stem.replace("\\", "/")).suffix
        if suffix.upper() in (".SRC", ".DAT"):
            stem = stem[: -len(suffix)]
        try:
            src = files.load(stem + ".SRC").decode("latin-1")
        except RgseError as exc:
            raise ProgramControlError(f"program {name!r} not found: {exc}", CODE_ARGUMENT) from exc
        dat = files.load(stem + ".DAT").decode("latin-1") if files.exists(stem + ".DAT") else None
        return module_name(name), src, dat

    return load


# --- values ---------------------------------------------------------------------------------------------------------
def default_value(type_name: str) -> KrlValue:
    """The value a fresh variable of ``type_name`` holds (structures: every field uninitialised)."""
    value = kv.default_value(type_name)
    if value is kv.UNKNOWN or isinstance(value, KrlArray):
        raise KrlRuntimeError(f"type {type_name} is not known to the simulator")
    return value  # type: ignore[return-value]


def coerce(type_name: str, value: Value, old: Value = kv.UNKNOWN) -> Value:
    """KRL's assignment conversion (:func:`rgse_daemon.krl.values.convert`, the simulator's choices where the
    controller's is not documented: a tie rounds away from zero, ABS of an INT is an INT)."""
    return convert(type_name or None, value, old, strict=False)


def _truth(value: Value, pos: k.Pos) -> bool:
    if isinstance(value, bool):
        return value
    raise KrlRuntimeError(f"expected a BOOL, got {value!r}", pos)


def _number(value: Value, pos: k.Pos) -> int | float:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return value
    raise KrlRuntimeError(f"expected a number, got {value!r}", pos)


class _ExitLoop(Exception):
    """KRL ``EXIT``: leaves the innermost loop."""


class _Return(Exception):
    def __init__(self, value: Value | None) -> None:
        self.value = value


@dataclass
class _Interrupt:
    """A declared interrupt: its condition (evaluated in the declaring frame), routine, on/off and last value."""

    decl: k.InterruptDecl
    frame: _Frame
    on: bool = False
    last: bool = False


@dataclass
class _Frame:
    """One routine activation: its locals and their declared types."""

    values: dict[str, Value] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)


@dataclass
class _Program:
    name: str
    module: k.Module
    data: k.DataList | None
    file: str

    def routine(self, name: str) -> k.Routine | None:
        return next((r for r in self.module.routines if r.name == name), None)


# --- the interpreter ----------------------------------------------------------------------------------------------
class KrlInterpreter:
    """Runs one robot program at a time against a :class:`VariableStore`; a :class:`ProgramHost` for message #10.

    Parameters
    ----------
    store:
        The controller's variables; the interpreter keeps ``$PRO_STATE1``, ``$AXIS_ACT``, ``$AXIS_ACT_MEAS``,
        ``$POS_ACT``, ``$VEL_ACT``, ``$ROB_STOPPED``, ``$PERI_RDY`` and ``$STOPMESS`` current.
    loader:
        Finds a program's text by the name message #10 sends (see :func:`share_loader`).
    time_scale:
        Simulated seconds per wall second.
    t1_limit_mm_s:
        Flange speed limit applied in T1 (mm/s).
    """

    def __init__(
        self,
        store: VariableStore,
        loader: ProgramLoader,
        *,
        time_scale: float = 1.0,
        t1_limit_mm_s: float = T1_LIMIT_MM_S,
    ) -> None:
        if not time_scale > 0.0:
            raise ValueError("time_scale must be positive")
        self.store = store
        self.loader = loader
        self.time_scale = time_scale
        self.t1_limit_mm_s = t1_limit_mm_s
        self.enabling_switch_held = True
        self.start_key_pressed = True
        self.last_error: str | None = None
        self.axes_deg = np.array(parse_axes(store.read("$AXIS_ACT")))
        self._submit = StateOnlyProgramHost(store)
        self._program: _Program | None = None
        self._module_data: dict[str, Value] = {}
        self._module_types: dict[str, str] = {}
        #: Module name → (.dat text, values, types): data-list values persist across reset and a new select.
        self._data_lists: dict[str, tuple[str | None, dict[str, Value], dict[str, str]]] = {}
        self._global_types: dict[str, str] = {}
        self._task: asyncio.Task[None] | None = None
        self._resume = asyncio.Event()
        self._state_changed = asyncio.Event()
        self._stop_reason: str | None = None
        self._listeners: list[MotionListener] = []
        self._sim_time_s = 0.0
        self._settings = _Settings()
        self._interrupts: dict[int, _Interrupt] = {}
        self._in_interrupt = False
        #: The motion an interrupt routine's BRAKE acts on: (move, t_move, target, directions); None when at rest.
        self._moving: tuple[JointMove, float, np.ndarray, tuple[int, ...]] | None = None
        self._braked = False
        self._publish(self.axes_deg, np.zeros(6))

    # --- hooks and operator ----------------------------------------------------------------------------------------
    def add_motion_listener(self, listener: MotionListener) -> None:
        """Call ``listener(event)`` at every motion start and end (synchronously; it must not block)."""
        self._listeners.append(listener)

    @property
    def state(self) -> ProState:
        return ProState(self.store.read("$PRO_STATE1").strip().upper())

    def set_enabling_switch(self, held: bool) -> None:
        """The simulated operator holds (``True``) or releases the enabling switch; release in T1/T2 = STOP 2."""
        self.enabling_switch_held = held
        if self._manual_mode():
            self.store.update("$PERI_RDY", "TRUE" if held else "FALSE")
        if not held and self._manual_mode() and self.state is ProState.ACTIVE:
            self.store.update("$STOPMESS", "TRUE")
            self._request_stop("enabling switch released (STOP 2)")

    def set_start_key(self, pressed: bool) -> None:
        """The simulated operator presses or releases the start key; in T1/T2 releasing it stops the program."""
        self.start_key_pressed = pressed
        if not pressed and self._manual_mode() and self.state is ProState.ACTIVE:
            self._request_stop("start key released")

    def acknowledge(self) -> None:
        """Acknowledge the stop message (``$STOPMESS`` → FALSE), as the operator does on the smartPAD."""
        self.store.update("$STOPMESS", "FALSE")

    def _manual_mode(self) -> bool:
        return self.store.read("$MODE_OP").strip().upper() in ("#T1", "#T2")

    # --- ProgramHost -----------------------------------------------------------------------------------------------
    def select(self, name: str, params: str, force: bool) -> None:
        if not name.strip():
            raise ProgramControlError("no program name given", CODE_ARGUMENT)
        if self.state is ProState.ACTIVE:
            raise ProgramControlError("a program is running: stop it before selecting another")
        mod_name, src, dat = self.loader(name)
        try:
            module = parse_src(src, f"{mod_name}.SRC")
            data = parse_dat(dat, f"{mod_name}.DAT") if dat is not None else None
        except KrlSyntaxError as exc:
            raise ProgramControlError(f"program {mod_name} does not compile: {exc}", CODE_ARGUMENT) from exc
        self._drop_task()
        self._program = _Program(mod_name, module, data, f"{mod_name}.SRC")
        self._load_data(data)
        kept = self._data_lists.get(mod_name)
        if kept is not None and kept[0] == dat:  # the same .dat: its values are those the last run left
            self._module_data, self._module_types = kept[1], kept[2]
        self._data_lists[mod_name] = (dat, self._module_data, self._module_types)
        self.last_error = None
        self.store.update("$PRO_NAME1[]", f'"{mod_name}"')
        self._set_state(ProState.RESET)

    def run(self, name: str, params: str, force: bool) -> None:
        self.select(name, params, force)
        self.start(INTERPRETER_ROBOT)

    def reset(self, interpreter: int) -> None:
        if interpreter != INTERPRETER_ROBOT:
            self._submit.reset(interpreter)
            return
        state = self.state
        if state is ProState.ACTIVE:
            raise ProgramControlError("cannot reset a running program: stop it first")
        if state is ProState.FREE or self._program is None:
            raise ProgramControlError("no program selected")
        self._drop_task()
        module_data, module_types = self._module_data, self._module_types
        self._load_data(self._program.data)
        self._module_data, self._module_types = module_data, module_types  # persistent: reset keeps them
        self.last_error = None
        self._set_state(ProState.RESET)

    def start(self, interpreter: int) -> None:
        if interpreter != INTERPRETER_ROBOT:
            self._submit.start(interpreter)
            return
        state = self.state
        if state is ProState.FREE or self._program is None:
            raise ProgramControlError("no program selected")
        if state is ProState.END:
            raise ProgramControlError("program has ended: reset it before starting")
        if state is ProState.ACTIVE:
            return
        if self.last_error is not None:
            raise ProgramControlError(f"program stopped on an error ({self.last_error}): reset it")
        if self._manual_mode():
            if not self.enabling_switch_held:
                raise ProgramControlError("T1/T2: the enabling switch is not held")
            if not self.start_key_pressed:
                raise ProgramControlError("T1/T2: the start key is not pressed")
        if self.store.read("$STOPMESS").strip().upper() == "TRUE":
            raise ProgramControlError("a stop message is active: acknowledge it first")
        self.store.update("$PERI_RDY", "TRUE")
        self._stop_reason = None
        self._set_state(ProState.ACTIVE)
        if state is ProState.RESET:
            self._resume.clear()
            self._task = asyncio.get_running_loop().create_task(self._run_program(), name=f"krl:{self._program.name}")
        else:
            self._resume.set()

    def stop(self, interpreter: int) -> None:
        if interpreter != INTERPRETER_ROBOT:
            self._submit.stop(interpreter)
            return
        if self.state is ProState.ACTIVE:
            self._request_stop("stopped by program control")

    def cancel(self, interpreter: int) -> None:
        if interpreter != INTERPRETER_ROBOT:
            self._submit.cancel(interpreter)
            return
        if self.state is ProState.ACTIVE:
            raise ProgramControlError("cannot cancel a running program: stop it first")
        self._drop_task()
        self._program = None
        self.store.update("$PRO_NAME1[]", '""')
        self._set_state(ProState.FREE)

    # --- task lifecycle --------------------------------------------------------------------------------------------
    async def wait_state(self, *states: ProState, timeout_s: float = 10.0) -> ProState:
        """Wait (wall clock, at most ``timeout_s``) until ``$PRO_STATE1`` is one of ``states``; return it."""
        async with asyncio.timeout(timeout_s):
            while True:
                changed = self._state_changed
                if self.state in states:
                    return self.state
                await changed.wait()

    async def aclose(self, timeout_s: float = 2.0) -> None:
        """Cancel the program task (if any) and wait for it, at most ``timeout_s``."""
        task, self._task = self._task, None
        if task is None or task.done():
            return
        task.cancel()
        async with asyncio.timeout(timeout_s):
            await asyncio.gather(task, return_exceptions=True)

    def _drop_task(self) -> None:
        self._interrupts = {}
        self._moving = None
        task, self._task = self._task, None
        if task is not None and not task.done():
            task.cancel()

    def _set_state(self, state: ProState) -> None:
        self.store.update("$PRO_STATE1", state.value)
        changed, self._state_changed = self._state_changed, asyncio.Event()
        changed.set()

    def _request_stop(self, reason: str) -> None:
        self._stop_reason = reason
        self._resume.clear()

    # --- data ------------------------------------------------------------------------------------------------------
    def _load_data(self, data: k.DataList | None) -> None:
        """(Re)initialise the data list: module variables here, GLOBAL ones in the store."""
        self._module_data = {}
        self._module_types = {}
        self._global_types = {}
        self._settings = _Settings()
        if data is None:
            return
        frame = _Frame()
        for decl in data.decls:
            for dn in decl.names:
                value = self._initial_value(decl, dn, frame)
                if decl.is_global:
                    self._declare_global(decl.type_name, dn, value)
                else:
                    self._module_data[dn.name] = value
                    self._module_types[dn.name] = decl.type_name

    def _initial_value(self, decl: k.Decl, dn: k.DeclName, frame: _Frame) -> Value:
        try:
            if dn.dims and decl.type_name != "CHAR":
                return KrlArray(decl.type_name, dn.dims)
            base = default_value(decl.type_name)
            if decl.init is None:
                return base
            return coerce(decl.type_name, self._eval(decl.init, frame, {}))
        except KrlRuntimeError as exc:
            raise ProgramControlError(f"data list: {dn.name}: {exc}", CODE_ARGUMENT) from exc

    def _declare_global(self, type_name: str, dn: k.DeclName, value: Value) -> None:
        kind = {"INT": Kind.INT, "REAL": Kind.REAL, "BOOL": Kind.BOOL, "CHAR": Kind.CHAR}.get(type_name, Kind.STRUC)
        try:
            if isinstance(value, KrlArray):
                for idx in _indices(value.dims):
                    key = f"{dn.name}[{','.join(map(str, idx))}]"
                    self.store.declare_global(key, kind, format_value(default_value(type_name)))
            else:
                key = f"{dn.name}[]" if type_name == "CHAR" else dn.name
                self.store.declare_global(key, kind, format_value(value))
        except (VariableError, ProtocolError) as exc:
            raise ProgramControlError(f"cannot declare global {dn.name}: {exc}", CODE_ARGUMENT) from exc
        self._global_types[dn.name] = type_name

    # --- running ---------------------------------------------------------------------------------------------------
    async def _run_program(self) -> None:
        program = self._program
        assert program is not None
        main = program.module.main
        try:
            await self._invoke(main, (), (), _Frame(), main.pos)
        except _ExitLoop:
            self._fail("EXIT outside a loop")
            return
        except RgseError as exc:
            self._fail(str(exc))
            return
        except Exception as exc:  # a simulator bug must not kill the task silently
            _log.exception("KRL interpreter failed")
            self._fail(f"internal error: {exc!r}")
            return
        self._set_state(ProState.END)

    def _fail(self, message: str) -> None:
        """A runtime error stops the program where it is; only reset (or select) clears it. The real controller shows
        it in its message window; the simulator logs it (a program stopped for no visible reason helps nobody)."""
        _log.warning("KRL runtime error, program stopped: %s", message)
        self.last_error = message
        self._set_state(ProState.STOP)

    async def _checkpoint(self) -> None:
        """Between statements: if a stop was requested, stop here until started again."""
        if self._stop_reason is None:
            return
        self._set_state(ProState.STOP)
        await self._resume.wait()  # cancelled by reset/cancel/aclose
        self._stop_reason = None

    async def _tick(self) -> float:
        """Sleep one interpolation cycle; the simulated seconds that passed."""
        loop = asyncio.get_running_loop()
        before = loop.time()
        await asyncio.sleep(max(IPO_PERIOD_S / self.time_scale, MIN_TICK_WALL_S))
        dt = (loop.time() - before) * self.time_scale
        self._sim_time_s += dt
        return dt

    async def _invoke(
        self,
        routine: k.Routine,
        arg_exprs: tuple[k.Expr, ...],
        args: tuple[Value, ...],
        caller: _Frame,
        pos: k.Pos,
    ) -> Value:
        """Run a DEF or DEFFCT; :OUT arguments that are variables get the parameter's final value back."""
        if len(args) != len(routine.params):
            raise KrlRuntimeError(f"{routine.name} takes {len(routine.params)} arguments, got {len(args)}", pos)
        frame = _Frame()
        for param, value in zip(routine.params, args, strict=True):
            frame.values[param.name] = value
        result: Value | None = None
        try:
            await self._exec_block(routine.body, frame)
        except _Return as ret:
            result = ret.value
        for param, arg in zip(routine.params, arg_exprs, strict=True):
            if param.direction == "OUT" and isinstance(arg, k.Name | k.Index | k.Member):
                self._assign(arg, frame.values[param.name], caller, {})
        if not routine.is_function:
            return False
        if result is None:
            raise KrlRuntimeError(f"function {routine.name} ended without returning a value", pos)
        return coerce(routine.return_type or "", result)

    async def _exec_block(self, body: tuple[k.Stmt, ...], frame: _Frame) -> None:
        for stmt in body:
            await self._checkpoint()
            await self._poll_interrupts()
            await self._exec(stmt, frame)

    async def _exec(self, stmt: k.Stmt, frame: _Frame) -> None:
        file = self._program.file if self._program else "<program>"
        try:
            await self._exec_inner(stmt, frame)
        except KrlRuntimeError as exc:
            if exc.file is None:  # raised deep inside an expression: name the file and the statement
                raise KrlRuntimeError(exc.message, exc.pos or stmt.pos, file) from None
            raise
        except kv.EvalError as exc:  # the shared evaluator: a run-time error, or semantics the model does not know
            raise KrlRuntimeError(exc.reason, exc.pos if exc.pos.line else stmt.pos, file) from None
        except (VariableError, ProtocolError, MotionError, ZeroDivisionError, ValueError, OverflowError) as exc:
            raise KrlRuntimeError(str(exc) or type(exc).__name__, stmt.pos, file) from exc

    async def _evaluate(self, expr: k.Expr, frame: _Frame) -> Value:
        """Evaluate an expression, running the user functions (DEFFCT) it calls first."""
        return self._eval(expr, frame, await self._call_functions(expr, frame))

    async def _call_functions(self, expr: k.Expr, frame: _Frame) -> dict[int, Value]:
        """Results of the DEFFCT calls inside ``expr`` by node id, innermost first."""
        results: dict[int, Value] = {}
        for node in reversed(list(iter_exprs(expr))):  # reversed pre-order: arguments before their call
            if isinstance(node, k.Call) and node.name not in BUILTINS:
                routine = self._program.routine(node.name) if self._program else None
                if routine is None or not routine.is_function:
                    raise KrlRuntimeError(f"unknown function {node.name}", node.pos)
                args = tuple(self._eval(a, frame, results) for a in node.args)
                results[id(node)] = await self._invoke(routine, node.args, args, frame, node.pos)
        return results

    async def _exec_inner(self, stmt: k.Stmt, frame: _Frame) -> None:
        match stmt:
            case k.Decl():
                for dn in stmt.names:
                    frame.types[dn.name] = stmt.type_name
                    if dn.dims and stmt.type_name != "CHAR":
                        frame.values[dn.name] = KrlArray(stmt.type_name, dn.dims)
                    elif stmt.init is not None:
                        frame.values[dn.name] = coerce(stmt.type_name, await self._evaluate(stmt.init, frame))
                    elif dn.name not in frame.values:  # a parameter's type declaration keeps its value
                        frame.values[dn.name] = default_value(stmt.type_name)
                    else:
                        frame.values[dn.name] = coerce(stmt.type_name, frame.values[dn.name])
            case k.Assign(target=target, value=value):
                pre = await self._call_functions(target, frame)
                self._assign(target, await self._evaluate(value, frame), frame, pre)
            case k.Motion():
                await self._motion(stmt, frame)
            case k.WaitSec(seconds=seconds):
                remaining = float(_number(await self._evaluate(seconds, frame), stmt.pos))
                while remaining > 0.0:
                    await self._checkpoint()
                    remaining -= await self._tick()
                    await self._poll_interrupts()
            case k.WaitFor(condition=cond):
                while not _truth(await self._evaluate(cond, frame), stmt.pos):
                    await self._checkpoint()
                    await self._tick()
                    await self._poll_interrupts()
            case k.For(var=var, start=start, stop=stop, step=step):
                # the counter is an INT; REAL bounds are rounded as an assignment to an INT rounds them
                first = coerce("INT", await self._evaluate(start, frame))
                last = coerce("INT", await self._evaluate(stop, frame))
                inc = coerce("INT", await self._evaluate(step, frame)) if step is not None else 1
                if inc == 0:
                    raise KrlRuntimeError("FOR with STEP 0", stmt.pos)
                counter = first
                try:
                    while (counter <= last) if inc > 0 else (counter >= last):
                        self._assign(k.Name(var, stmt.pos), counter, frame, {})
                        await self._exec_block(stmt.body, frame)
                        counter = _number(await self._evaluate(k.Name(var), frame), stmt.pos) + inc
                    self._assign(k.Name(var, stmt.pos), counter, frame, {})
                except _ExitLoop:
                    pass
            case k.If(condition=cond, then_body=then_body, else_body=else_body):
                branch = then_body if _truth(await self._evaluate(cond, frame), stmt.pos) else else_body
                await self._exec_block(branch, frame)
            case k.While(condition=cond, body=body):
                try:
                    while _truth(await self._evaluate(cond, frame), stmt.pos):
                        await self._exec_block(body, frame)
                        await asyncio.sleep(0)
                except _ExitLoop:
                    pass
            case k.Repeat(body=body, condition=cond):
                try:
                    while True:
                        await self._exec_block(body, frame)
                        await asyncio.sleep(0)
                        if _truth(await self._evaluate(cond, frame), stmt.pos):
                            break
                except _ExitLoop:
                    pass
            case k.Loop(body=body):
                try:
                    while True:
                        await self._exec_block(body, frame)
                        await asyncio.sleep(0)  # an empty LOOP still lets the event loop run
                except _ExitLoop:
                    pass
            case k.Exit():
                raise _ExitLoop
            case k.Halt():
                self._request_stop("HALT")
                await self._checkpoint()
            case k.Brake():
                await self._brake_in_interrupt(stmt)
            case k.InterruptDecl(prio=prio):
                number = int(_number(await self._evaluate(prio, frame), stmt.pos))
                self._interrupts[number] = _Interrupt(stmt, frame)  # a new DECL replaces the old one, switched off
            case k.InterruptCtl(action=action, prio=prio):
                numbers = (
                    list(self._interrupts)
                    if prio is None
                    else [int(_number(await self._evaluate(prio, frame), stmt.pos))]
                )
                for number in numbers:
                    irq = self._interrupts.get(number)
                    if irq is None:
                        raise KrlRuntimeError(f"interrupt {number} is not declared", stmt.pos)
                    irq.on = action in ("ON", "ENABLE")
                    if irq.on:  # edge-triggered: a condition TRUE already when switched on does not fire
                        irq.last = _truth(await self._evaluate(irq.decl.condition, irq.frame), stmt.pos)
            case k.Return(value=value):
                raise _Return(await self._evaluate(value, frame) if value is not None else None)
            case k.CallStmt(name=name, args=args):
                await self._call_stmt(name, args, frame, stmt.pos)
            case _:
                raise KrlRuntimeError(f"statement {type(stmt).__name__} is not supported", stmt.pos)

    async def _call_stmt(self, name: str, args: tuple[k.Expr, ...], frame: _Frame, pos: k.Pos) -> None:
        values = tuple([await self._evaluate(a, frame) for a in args])
        if name == "BAS":
            self._bas(values, pos)
            return
        routine = self._program.routine(name) if self._program else None
        if routine is None:
            raise KrlRuntimeError(f"unknown subprogram {name}", pos)
        await self._invoke(routine, args, values, frame, pos)

    def _bas(self, args: tuple[Value, ...], pos: k.Pos) -> None:
        """The few BAS functions the daemon's programs use (KUKA's BAS.SRC sets motion defaults)."""
        if not args or not isinstance(args[0], KrlEnum):
            raise KrlRuntimeError("BAS needs an enum as its first argument", pos)
        what = args[0].name
        value = float(_number(args[1], pos)) if len(args) > 1 else 0.0
        s = self._settings
        if what == "INITMOV":
            self._settings = _Settings()
        elif what == "VEL_PTP":
            s.vel_axis_pct = [value] * 6
        elif what == "ACC_PTP":
            s.acc_axis_pct = [value] * 6
        elif what == "VEL_CP":
            s.vel_cp_m_s = value
        elif what == "ACC_CP":
            s.acc_cp_m_s2 = value
        else:
            raise KrlRuntimeError(f"BAS(#{what}) is not simulated", pos)

    # --- motion ----------------------------------------------------------------------------------------------------
    async def _motion_target(self, stmt: k.Motion, frame: _Frame) -> np.ndarray:
        value = await self._evaluate(stmt.target, frame)
        if not isinstance(value, KrlStruct):
            raise KrlRuntimeError(f"{stmt.kind} needs an axis or Cartesian target, got {value!r}", stmt.pos)
        fields = dict(value.fields)
        if any(f in fields for f in ("X", "Y", "Z")) and not any(a in fields for a in AXIS_FIELDS):
            raise KrlRuntimeError(
                f"{stmt.kind} to a Cartesian target needs inverse kinematics, which the simulator does not have: "
                "give the target as E6AXIS",
                stmt.pos,
            )
        target = self.axes_deg.copy() if not stmt.relative else np.zeros(6)
        for i, name in enumerate(AXIS_FIELDS):
            if name in fields:
                target[i] = float(_number(fields[name], stmt.pos))
        return self.axes_deg + target if stmt.relative else target

    def _motion_settings(self) -> MotionSettings:
        ov = float(_number(self._read_store("$OV_PRO"), k.NOPOS))
        s = self._settings
        return MotionSettings(tuple(s.vel_axis_pct), tuple(s.acc_axis_pct), ov, s.vel_cp_m_s)

    def _plan(self, kind: str, target: np.ndarray) -> JointMove:
        t1 = self.t1_limit_mm_s if self.store.read("$MODE_OP").strip().upper() == "#T1" else None
        return plan_joint_move(kind, self.axes_deg, target, self._motion_settings(), t1_limit_mm_s=t1)

    async def _motion(self, stmt: k.Motion, frame: _Frame) -> None:
        kind = "PTP" if stmt.kind.startswith("PTP") else "LIN"
        target = await self._motion_target(stmt, frame)
        move = self._plan(kind, target)
        directions = move.directions()
        self._emit(MotionEvent("start", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s, move=move))
        t_move = 0.0
        while True:
            q, qd = move.state(t_move)
            self._publish(q, qd)
            if t_move >= move.duration_s:
                break
            self._moving, self._braked = (move, t_move, target, directions), False
            await self._poll_interrupts()
            self._moving = None
            if self._braked:  # an interrupt routine braked it to rest and returned: on to the target from here
                move = self._plan(kind, target)
                t_move = 0.0
                self._emit(
                    MotionEvent("start", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s, move=move)
                )
                continue
            if self._stop_reason is not None:
                await self._brake(move, t_move, target, directions)
                await self._checkpoint()  # stays here until started again
                move = self._plan(kind, target)  # continue on the same joint line to the target
                t_move = 0.0
                self._emit(
                    MotionEvent("start", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s, move=move)
                )
                continue
            t_move += await self._tick()
        self._publish(np.asarray(move.q_end_deg), np.zeros(6))
        self._emit(MotionEvent("end", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s))

    async def _poll_interrupts(self) -> None:
        """Run the routine of each interrupt that is on and whose condition turned TRUE (one at a time)."""
        if self._in_interrupt or not self._interrupts:
            return
        for number in sorted(self._interrupts):
            irq = self._interrupts.get(number)
            if irq is None or not irq.on:
                continue
            now = _truth(await self._evaluate(irq.decl.condition, irq.frame), irq.decl.pos)
            rising, irq.last = now and not irq.last, now
            if not rising:
                continue
            routine = self._program.routine(irq.decl.routine) if self._program else None
            if routine is None or routine.is_function:
                raise KrlRuntimeError(f"interrupt routine {irq.decl.routine} not found", irq.decl.pos)
            args = tuple([await self._evaluate(a, irq.frame) for a in irq.decl.args])
            self._in_interrupt = True
            try:
                await self._invoke(routine, irq.decl.args, args, irq.frame, irq.decl.pos)
            finally:
                self._in_interrupt = False

    async def _brake_in_interrupt(self, stmt: k.Brake) -> None:
        """``BRAKE``: only in an interrupt routine; brakes the interrupted motion on its path to rest."""
        if not self._in_interrupt:
            raise KrlRuntimeError("BRAKE is only allowed in an interrupt routine", stmt.pos)
        moving, self._moving = self._moving, None
        if moving is None:
            return  # the robot is at rest (the interrupt came during a wait or between statements)
        move, t_move, target, directions = moving
        await self._brake(move, t_move, target, directions)
        self._braked = True

    async def _brake(self, move: JointMove, t_move: float, target: np.ndarray, directions: tuple[int, ...]) -> None:
        """Ramp down on the path (STOP 2 / program stop); the robot ends at rest."""
        braking = move.stopped_at(t_move)
        self._emit(
            MotionEvent("brake", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s, move=braking)
        )
        t = 0.0
        while t < braking.duration_s:
            q, qd = braking.state(t)
            self._publish(q, qd)
            t += await self._tick()
        self._publish(np.asarray(braking.q_end_deg), np.zeros(6))
        self._emit(MotionEvent("end", tuple(self.axes_deg), tuple(target), directions, self._sim_time_s, True))

    def _publish(self, q_deg: np.ndarray, qd_deg_s: np.ndarray) -> None:
        """Write the axis state into the store (setpoint and, lacking a physics getter, measured)."""
        self.axes_deg = np.asarray(q_deg, dtype=float).copy()
        axes = e6axis(float(round(v, 6)) for v in self.axes_deg)
        self.store.update("$AXIS_ACT", axes)
        self.store.update("$AXIS_ACT_MEAS", axes)
        x, y, z, a, b, c = (float(round(v, 5)) for v in flange_pose_xyzabc(self.axes_deg))
        turn = sum(1 << i for i, v in enumerate(self.axes_deg) if v < 0.0)
        self.store.update(
            "$POS_ACT",
            format_value(
                KrlStruct(
                    "E6POS",
                    (
                        ("X", x),
                        ("Y", y),
                        ("Z", z),
                        ("A", a),
                        ("B", b),
                        ("C", c),
                        ("S", 2),
                        ("T", turn),
                        *((e, 0.0) for e in EXT_FIELDS),
                    ),
                )
            ),
        )
        speed_m_s = flange_speed_mm_s(self.axes_deg, qd_deg_s) / 1000.0
        self.store.update("$VEL_ACT", format_value(float(round(speed_m_s, 6))))
        self.store.update("$ROB_STOPPED", "TRUE" if not np.any(qd_deg_s) else "FALSE")

    def _emit(self, event: MotionEvent) -> None:
        for listener in self._listeners:
            listener(event)

    # --- variables -------------------------------------------------------------------------------------------------
    def _read_store(self, key: str) -> KrlValue:
        text = self.store.read(key)
        if self.store.kind_of(key) is Kind.BITS:
            return KrlBits(text.strip()[1:])
        return parse_value(text)

    def _write_store(self, key: str, value: Value) -> None:
        if isinstance(value, KrlArray):
            raise KrlRuntimeError(f"cannot assign an array to {key}")
        kind = self.store.kind_of(key)
        if kind is Kind.INT:
            value = coerce("INT", value)
        elif kind is Kind.REAL:
            value = coerce("REAL", value)
        elif kind is Kind.STRUC and isinstance(value, KrlStruct):
            old = self._read_store(key)
            if isinstance(old, KrlStruct):
                value = merge(old.type_name, old, value, strict=False)
        self.store.write(key, format_value(value))  # type: ignore[arg-type]

    def _resolve(
        self, target: k.Expr, frame: _Frame, pre: dict[int, Value]
    ) -> tuple[str, str, list[tuple[str, object]]]:
        """Where a variable reference lives: (``"frame"|"module"|"store"|"settings"``, root key, remaining path)."""
        ops: list[tuple[str, object]] = []
        node = target
        while isinstance(node, k.Index | k.Member):
            if isinstance(node, k.Index):
                idx = tuple(int(_number(self._eval(i, frame, pre), node.pos)) for i in node.indices)
                ops.append(("idx", idx))
            else:
                ops.append(("mem", node.member))
            node = node.base
        if not isinstance(node, k.Name):
            raise KrlRuntimeError("not a variable", target.pos)
        ops.reverse()
        name = node.name
        if not name.startswith("$"):
            if name in frame.values or name in frame.types:
                return "frame", name, ops
            if name in self._module_data:
                return "module", name, ops
        for cut in range(len(ops), -1, -1):  # the longest prefix the store knows as one key
            key = name + "".join(_render(op) for op in ops[:cut])
            if self.store.is_declared(key):
                return "store", key, ops[cut:]
            if cut == 0 and name in self._global_types and self._global_types[name] == "CHAR":
                return "store", name + "[]", ops
        if name.startswith("$") and self._settings.knows(name):
            return "settings", name, ops
        raise KrlRuntimeError(f"unknown variable {name}", target.pos)

    def _read_var(self, target: k.Expr, frame: _Frame, pre: dict[int, Value]) -> Value:
        where, key, ops = self._resolve(target, frame, pre)
        value: Value
        if where == "frame":
            value = frame.values[key]
        elif where == "module":
            value = self._module_data[key]
        elif where == "store":
            value = self._read_store(key)
        else:
            value = self._settings.get(key)
        for op, arg in ops:
            value = _step(value, op, arg, target.pos)
        return value

    def _assign(self, target: k.Expr, value: Value, frame: _Frame, pre: dict[int, Value]) -> None:
        where, key, ops = self._resolve(target, frame, pre)
        if where == "store":
            if not ops:
                self._write_store(key, value)
            else:
                self._write_store(key, _replace(self._read_store(key), ops, value, target.pos))
            return
        if where == "settings":
            self._settings.set(key, ops, value, target.pos)
            return
        values, types = (frame.values, frame.types) if where == "frame" else (self._module_data, self._module_types)
        type_name = types.get(key, "")
        if not ops:
            values[key] = coerce(type_name, value, values.get(key, kv.UNKNOWN))
        else:
            old = values[key]
            elem_type = old.type_name if isinstance(old, KrlArray) else ""
            values[key] = _replace(old, ops, coerce(elem_type, value) if len(ops) == 1 else value, target.pos)

    # --- expressions -----------------------------------------------------------------------------------------------
    def _eval(self, expr: k.Expr, frame: _Frame, pre: dict[int, Value]) -> Value:
        """Evaluate ``expr``; ``pre`` holds the results of its DEFFCT calls (see :meth:`_call_functions`)."""

        def call(node: k.Call) -> Value:
            if id(node) in pre:
                return pre[id(node)]
            raise KrlRuntimeError(f"unknown function {node.name}", node.pos)

        evaluator = Evaluator(read=lambda e: self._read_var(e, frame, pre), call=call, wide=False, strict=False)
        return evaluator.evaluate(expr)


# --- motion settings ----------------------------------------------------------------------------------------------
@dataclass
class _Settings:
    """``$VEL_AXIS``, ``$ACC_AXIS`` (% of maximum), ``$VEL`` (m/s, deg/s), ``$ACC`` (m/s², deg/s²), ``$APO``.

    The defaults are what ``BAS(#INITMOV, 0)`` sets on a KR C4 (100 % axis speed and acceleration, 2 m/s CP).
    """

    vel_axis_pct: list[float] = field(default_factory=lambda: [100.0] * 6)
    acc_axis_pct: list[float] = field(default_factory=lambda: [100.0] * 6)
    vel_cp_m_s: float = 2.0
    acc_cp_m_s2: float = 2.3
    apo: KrlStruct = field(
        default_factory=lambda: KrlStruct(None, (("CPTP", 0), ("CDIS", 0.0), ("CVEL", 0), ("CORI", 0.0)))
    )

    _NAMES = ("$VEL_AXIS", "$ACC_AXIS", "$VEL", "$ACC", "$APO")

    def knows(self, name: str) -> bool:
        return name in self._NAMES

    def get(self, name: str) -> Value:
        if name == "$VEL_AXIS":
            return KrlArray("REAL", (6,), {(i + 1,): v for i, v in enumerate(self.vel_axis_pct)})
        if name == "$ACC_AXIS":
            return KrlArray("REAL", (6,), {(i + 1,): v for i, v in enumerate(self.acc_axis_pct)})
        if name == "$VEL":
            return KrlStruct(None, (("CP", self.vel_cp_m_s), ("ORI1", 200.0), ("ORI2", 200.0)))
        if name == "$ACC":
            return KrlStruct(None, (("CP", self.acc_cp_m_s2), ("ORI1", 400.0), ("ORI2", 400.0)))
        return self.apo

    def set(self, name: str, ops: list[tuple[str, object]], value: Value, pos: k.Pos) -> None:
        new = _replace(self.get(name), ops, value, pos) if ops else value
        if name in ("$VEL_AXIS", "$ACC_AXIS"):
            if not isinstance(new, KrlArray):
                raise KrlRuntimeError(f"{name} is an array of 6 percentages", pos)
            pct = [float(_number(new.items.get((i,), 0.0), pos)) for i in range(1, 7)]
            if any(not 0.0 <= p <= 100.0 for p in pct):
                raise KrlRuntimeError(f"{name} values must lie in 0..100 %", pos)
            if name == "$VEL_AXIS":
                self.vel_axis_pct = pct
            else:
                self.acc_axis_pct = pct
        elif name in ("$VEL", "$ACC"):
            if not isinstance(new, KrlStruct) or "CP" not in new:
                raise KrlRuntimeError(f"{name} is a structure with CP", pos)
            cp = float(_number(new["CP"], pos))
            if cp <= 0.0:
                raise KrlRuntimeError(f"{name}.CP must be positive", pos)
            if name == "$VEL":
                self.vel_cp_m_s = cp
            else:
                self.acc_cp_m_s2 = cp
        else:
            if not isinstance(new, KrlStruct):
                raise KrlRuntimeError("$APO is a structure", pos)
            self.apo = new


# --- helpers ------------------------------------------------------------------------------------------------------
def parse_axes(text: str) -> tuple[float, ...]:
    """A1..A6 (deg) of an ``E6AXIS``/``AXIS`` value string."""
    value = parse_value(text)
    if not isinstance(value, KrlStruct):
        raise ValueError(f"not an axis structure: {text!r}")
    return tuple(float(value[a]) for a in AXIS_FIELDS)  # type: ignore[arg-type]


def _indices(dims: tuple[int, ...]) -> Iterator[tuple[int, ...]]:
    """Every 1-based index tuple of an array of size ``dims``."""
    for idx in np.ndindex(*dims):
        yield tuple(i + 1 for i in idx)


def _render(op: tuple[str, object]) -> str:
    kind, arg = op
    if kind == "mem":
        return f".{arg}"
    assert isinstance(arg, tuple)
    return "[" + ",".join(str(i) for i in arg) + "]"


def _step(value: Value, op: str, arg: object, pos: k.Pos) -> Value:
    """One index or member access on a runtime value."""
    if op == "mem":
        return member(value, str(arg), pos)
    assert isinstance(arg, tuple)
    return element(value, arg, pos)


def _replace(old: Value, ops: list[tuple[str, object]], value: Value, pos: k.Pos) -> Value:
    """``old`` with the element at path ``ops`` replaced by ``value`` (structures are immutable: rebuild)."""
    if not ops:
        if isinstance(old, KrlStruct) and isinstance(value, KrlStruct):
            return merge(old.type_name, old, value, pos, strict=False)
        if isinstance(old, float) and kv.is_int(value):
            return coerce("REAL", value)
        return value
    (op, arg), rest = ops[0], ops[1:]
    if op == "mem":
        assert isinstance(arg, str)
        if not isinstance(old, KrlStruct):
            raise KrlRuntimeError(f"no member {arg} in {old!r}", pos)
        inner = old[arg] if arg in old else kv.UNKNOWN
        new_field = _replace(inner, rest, value, pos) if rest else value
        return merge(old.type_name, old, KrlStruct(None, ((arg, new_field),)), pos, strict=False)  # type: ignore[arg-type]
    assert isinstance(arg, tuple)
    if isinstance(old, str):
        if arg == () and not rest and isinstance(value, str):
            return value
        raise KrlRuntimeError('only whole strings (name[] = "...") can be assigned', pos)
    if isinstance(old, KrlArray):
        check_index(old, arg, pos)
        current = old.items.get(arg, kv.default_value(old.type_name))
        items = dict(old.items)
        items[arg] = _replace(current, rest, value, pos)
        return KrlArray(old.type_name, old.dims, items)
    raise KrlRuntimeError(f"cannot index {old!r}", pos)
