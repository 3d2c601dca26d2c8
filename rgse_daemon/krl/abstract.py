"""Abstract interpretation of a KRL main routine: what can be known about a run without running it.

The interlock (:mod:`rgse_daemon.safety.static`) subclasses :class:`AbstractInterpreter` with its T1 rules. This
module holds only KRL semantics, shared with the simulator through :mod:`rgse_daemon.krl.evaluate`:

* the set of poses the robot can be in (``None``: unknown), the motion settings in force ($VEL_AXIS as the *largest*
  value any path can have set, $OV_PRO) and the values of the program's own variables (routine locals, non-GLOBAL
  data-list entries) with their declared types. GLOBAL and system variables are :data:`~rgse_daemon.krl.values.UNKNOWN`:
  the daemon or the operator can change them while the program runs;
* every expression is evaluated twice, with binary32 and with binary64 intermediates, and converted to the type of
  the place it goes to (a variable's declared type, INT for FOR bounds and indices); if the two lanes differ, or the
  controller's result is not documented, the statement is refused (``UNSURE``); a run-time error is ``RUNTIME``;
* IF with a known condition takes its branch, otherwise both branches are joined; FOR with known bounds is unrolled;
  WHILE/REPEAT whose condition stays known are run pass by pass; any other loop is iterated until its entry state
  stops changing (``LOOP`` if it never settles). A FOR whose body writes its counter, or a variable its bounds read,
  is refused; EXIT outside a loop is refused (``STATEMENT``) and the check goes on after it.
* a budget of statements and wall-clock time (``COMPLEXITY``): the check ends by itself, it is never left running.

Anything the interpreter cannot decide with certainty becomes UNKNOWN or a refusal, never a guess.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from rgse_daemon.krl import ast as k
from rgse_daemon.krl.evaluate import BUILTINS, MAX_EXPR_DEPTH, Evaluator, expr_depth
from rgse_daemon.krl.values import (
    AXIS_FIELDS,
    CARTESIAN_FIELDS,
    EXT_FIELDS,
    INT_MAX,
    INT_MIN,
    STRUCT_FIELDS,
    UNKNOWN,
    EvalError,
    KrlArray,
    KrlStruct,
    Unsure,
    Value,
    check_index,
    convert,
    describe,
    element,
    field_type,
    is_int,
    member,
)
from rgse_daemon.krl.walk import iter_exprs, root_name

#: Loops with known bounds (or a known condition) are unrolled up to this many passes; longer ones: fixpoint.
MAX_UNROLL = 1000
#: Passes of a loop body before a loop whose state keeps changing is refused.
MAX_FIXPOINT_ITERATIONS = 12
#: More possible poses than this at one point of the program → unknown (refused at the next motion).
MAX_POSES = 64
#: Statements interpreted before the program is refused as too complex to verify.
MAX_STEPS = 50_000
CARTESIAN_TYPES = frozenset({"POS", "E6POS", "FRAME"})
#: Types whose values the interpreter tracks; a variable of any other type is UNKNOWN.
TRACKED_TYPES = frozenset({"INT", "REAL", "BOOL"}) | frozenset(STRUCT_FIELDS)


def system_type(target: k.Expr) -> str | None:
    """The declared type of a written system variable: $VEL_AXIS[i]/$ACC_AXIS[i]/$VEL.CP/$ACC.CP REAL, $OV_PRO INT."""
    match target:
        case k.Index(base=k.Name(name="$VEL_AXIS" | "$ACC_AXIS")) | k.Member(base=k.Name(name="$VEL" | "$ACC")):
            return "REAL"
        case k.Name(name="$OV_PRO"):
            return "INT"
    return None


Pose = tuple[float, ...]


def pose_key(q: Iterable[float]) -> Pose:
    return tuple(float(v) + 0.0 for v in q)


@dataclass(frozen=True)
class State:
    """What is known at one point of the program (see the module docstring)."""

    poses: frozenset[Pose] | None
    vel_axis_pct: tuple[float, ...]
    override_pct: float
    env: tuple[tuple[str, Any], ...]
    #: Upper bound of the motion time (s) since the start of the program (or of the loop pass being interpreted).
    motion_s: float = 0.0
    #: The *smallest* $VEL_AXIS, $ACC_AXIS (% per axis) and $OV_PRO (%) any path can have set, for the time bound
    #: (0: not set by the program, the subclass's floor applies; the override: 100 % unless the program lowers it).
    vel_axis_min_pct: tuple[float, ...] = (0.0,) * 6
    acc_axis_min_pct: tuple[float, ...] = (0.0,) * 6
    override_min_pct: float = 100.0

    def var(self, name: str) -> Any:
        for n, v in self.env:
            if n == name:
                return v
        return UNKNOWN

    def with_var(self, name: str, value: Any) -> State:
        env = dict(self.env)
        env[name] = value
        return replace(self, env=tuple(sorted(env.items())))


def _same(a: Any, b: Any) -> bool:
    return type(a) is type(b) and a == b


def join(states: Sequence[State | None]) -> State | None:
    """The state after either of ``states`` (``None``: a path that does not continue)."""
    live = [s for s in states if s is not None]
    if not live:
        return None
    if len(live) == 1:
        return live[0]
    poses: frozenset[Pose] | None = frozenset()
    for s in live:
        poses = None if s.poses is None or poses is None else poses | s.poses
    if poses is not None and len(poses) > MAX_POSES:
        poses = None
    vel = tuple(max(s.vel_axis_pct[i] for s in live) for i in range(6))
    ov = max(s.override_pct for s in live)
    names = sorted({n for s in live for n, _ in s.env})
    env = []
    for n in names:
        values = [s.var(n) for s in live]
        env.append((n, values[0] if all(_same(v, values[0]) for v in values) else UNKNOWN))
    return State(poses, vel, ov, tuple(env), **_join_timing(live))


def _join_timing(live: Sequence[State]) -> dict[str, Any]:
    """The time-bound fields of a join: the longest motion time, the smallest speed settings."""
    return {
        "motion_s": max(s.motion_s for s in live),
        "vel_axis_min_pct": tuple(min(s.vel_axis_min_pct[i] for s in live) for i in range(6)),
        "acc_axis_min_pct": tuple(min(s.acc_axis_min_pct[i] for s in live) for i in range(6)),
        "override_min_pct": min(s.override_min_pct for s in live),
    }


@dataclass
class Outcome:
    normal: State | None
    exits: list[State] = field(default_factory=list)
    returns: list[State] = field(default_factory=list)


class TooComplex(Exception):
    """The program is beyond the interpreter's budget: refused (``pos``: the statement where it ran out)."""

    def __init__(self, reason: str, pos: k.Pos = k.NOPOS) -> None:
        super().__init__(reason)
        self.pos = pos


def all_stmts(body: Sequence[k.Stmt]) -> Iterable[k.Stmt]:
    for s in body:
        yield s
        if isinstance(s, k.If):
            yield from all_stmts(s.then_body)
            yield from all_stmts(s.else_body)
        elif isinstance(s, k.For | k.While | k.Repeat | k.Loop):
            yield from all_stmts(s.body)


def written_names(body: Sequence[k.Stmt]) -> set[str]:
    """Variables a block writes: assignment targets and FOR counters, at any depth."""
    names: set[str] = set()
    for s in all_stmts(body):
        if isinstance(s, k.Assign):
            name = root_name(s.target)
            if name is not None:
                names.add(name)
        elif isinstance(s, k.For):
            names.add(s.var)
    return names


def read_names(expr: k.Expr) -> set[str]:
    return {e.name for e in iter_exprs(expr) if isinstance(e, k.Name)}


class AbstractInterpreter(ABC):
    """Interprets a main routine abstractly; subclasses supply the rules (the hooks below) and :meth:`report`."""

    def __init__(self, time_budget_s: float = 20.0, max_steps: int = MAX_STEPS) -> None:
        self.types: dict[str, str] = {}  # declared types of the program's own variables
        self.own: set[str] = set()
        self.params: set[str] = set()  # the main routine's parameters: own variables of unknown value
        self.start_poses: frozenset[Pose] | None = None
        self.loop_depth = 0
        self.steps = 0
        self.max_steps = max_steps
        self.deadline = time.monotonic() + time_budget_s
        self.time_budget_s = time_budget_s

    # --- hooks ---
    @abstractmethod
    def report(self, rule: str, pos: k.Pos, message: str) -> None:
        ...

    @abstractmethod
    def writable(self, target: k.Expr, pos: k.Pos) -> bool:
        """Whether the program may write ``target`` (a variable that is not its own); report if not."""
        ...

    @abstractmethod
    def system_write(self, name: str, target: k.Expr, value: Value, st: State, pos: k.Pos) -> State:
        ...

    @abstractmethod
    def check_target(self, q: Pose, pos: k.Pos) -> bool:
        ...

    @abstractmethod
    def check_relative(self, delta: Sequence[float], pos: k.Pos) -> None:
        ...

    @abstractmethod
    def check_path(self, start: Pose, target: Pose, st: State, pos: k.Pos) -> None:
        ...

    @abstractmethod
    def start_unknown(self, stmt: k.Motion) -> None:
        ...

    @abstractmethod
    def motion_time_s(self, start: Pose, target: Pose, st: State) -> float:
        """Upper bound of the time (s) of the motion ``start`` → ``target`` with the settings of ``st``."""
        ...

    @abstractmethod
    def host_written(self, name: str) -> bool:
        """Whether the host (the daemon, over the link) writes variable ``name`` (a pacing WAIT FOR reads one)."""
        ...

    @abstractmethod
    def loop_motion_s(self, stmt: k.Stmt, per_pass_s: float, passes: int | None, paced: bool, exits: bool) -> float:
        """The motion time of a loop interpreted as a fixpoint: ``per_pass_s`` per pass, ``passes`` known or not,
        ``paced``: every pass waits for the host first (:meth:`paced_by_host`), ``exits``: an EXIT can end it; report
        a loop whose motion time has no bound."""
        ...

    # --- declarations ---
    def declare(self, decl: k.Decl, st: State) -> State:
        """A declaration: its type is recorded, its variable gets its initial value (UNKNOWN if not tracked)."""
        for dn in decl.names:
            self.own.add(dn.name)
            self.types[dn.name] = decl.type_name
            value: Value = UNKNOWN
            if dn.name in self.params:
                pass  # a parameter's type declaration: its value comes from the caller
            elif decl.type_name in TRACKED_TYPES:
                if dn.dims:
                    value = KrlArray(decl.type_name, dn.dims)
                elif decl.init is not None:
                    value = self.sink(decl.init, st, decl.type_name, decl.pos)
                elif decl.type_name in STRUCT_FIELDS:
                    value = KrlStruct(decl.type_name, ())
            elif decl.init is not None:
                self.sink(decl.init, st, None, decl.pos)  # errors in it still count
            st = st.with_var(dn.name, value)
        return st

    # --- expressions ---
    def _evaluator(self, st: State, wide: bool) -> Evaluator:
        ev = Evaluator(read=lambda e: UNKNOWN, call=lambda c: UNKNOWN, wide=wide, strict=True)
        ev.read = lambda e: self.read(e, st, ev)
        return ev

    def read(self, expr: k.Expr, st: State, ev: Evaluator) -> Value:
        if isinstance(expr, k.Name):
            if expr.name.startswith("$") or expr.name not in self.own:
                return UNKNOWN
            return st.var(expr.name)
        if isinstance(expr, k.Member):
            return member(self.read(expr.base, st, ev), expr.member, expr.pos)
        if isinstance(expr, k.Index):
            base = self.read(expr.base, st, ev)
            idx = [ev.value(i) for i in expr.indices]
            if any(i is UNKNOWN for i in idx) or base is UNKNOWN:
                return UNKNOWN
            if not all(is_int(i) for i in idx):
                raise EvalError(f"array index {[describe(i) for i in idx]} is not an INT", expr.pos)
            return element(base, tuple(idx), expr.pos)  # type: ignore[arg-type]
        return UNKNOWN

    def sink(self, expr: k.Expr, st: State, type_name: str | None, pos: k.Pos, old: Value = UNKNOWN) -> Value:
        """``expr`` as stored into a ``type_name`` place: both lanes must agree, else refused (UNKNOWN returned)."""
        if expr_depth(expr) > MAX_EXPR_DEPTH:
            self.report("COMPLEXITY", pos, f"expression nested deeper than {MAX_EXPR_DEPTH} levels: too complex")
            return UNKNOWN
        self.check_calls(expr)
        try:
            narrow = convert(type_name, self._evaluator(st, False).evaluate(expr), old, pos)
            wide = convert(type_name, self._evaluator(st, True).evaluate(expr), old, pos)
        except Unsure as exc:
            self.report("UNSURE", exc.pos if exc.pos.line else pos, f"{exc.reason}: refused")
            return UNKNOWN
        except EvalError as exc:
            self.report("RUNTIME", exc.pos if exc.pos.line else pos, f"the controller stops here: {exc.reason}")
            return UNKNOWN
        if not _same(narrow, wide):
            self.report(
                "UNSURE",
                pos,
                f"the value is {describe(narrow)} computed in 32-bit REAL but {describe(wide)} with 64-bit "
                "intermediates: which one the controller gets is not documented, refused",
            )
            return UNKNOWN
        return narrow

    def index(self, expr: k.Expr, st: State, pos: k.Pos) -> Value:
        """An array index as written (``A[i] = ...``, ``$VEL_AXIS[i] = ...``): an INT, else refused.

        A REAL index is not converted: whether the controller rounds it (1.6 → 2), cuts it (1.6 → 1) or stops is not
        documented, and the two pick different elements (``UNSURE``; UNKNOWN returned)."""
        value = self.sink(expr, st, None, pos)
        if value is UNKNOWN or is_int(value):
            return value
        self.report(
            "UNSURE",
            pos,
            f"array index {describe(value)} is not an INT: whether the controller rounds it, cuts off its decimals "
            "or stops is not documented, refused",
        )
        return UNKNOWN

    def check_calls(self, expr: k.Expr) -> None:
        if expr_depth(expr) > MAX_EXPR_DEPTH:
            return  # refused by sink() as COMPLEXITY; not walked (it could exhaust Python's stack)
        for e in iter_exprs(expr):
            if isinstance(e, k.Call) and e.name not in BUILTINS:
                self.report("CALL", e.pos, f"call of {e.name}(): the check cannot see into functions, refused")

    def condition(self, expr: k.Expr, st: State, pos: k.Pos) -> bool | None:
        """A BOOL condition's value, or None if unknown (a non-BOOL is reported)."""
        v = self.sink(expr, st, None, pos)
        if v is UNKNOWN:
            return None
        if not isinstance(v, bool):
            self.report("RUNTIME", pos, f"the condition is {describe(v)}, not a BOOL")
            return None
        return v

    # --- statements ---
    def step(self, pos: k.Pos) -> None:
        self.steps += 1
        if self.steps > self.max_steps:
            raise TooComplex(f"more than {self.max_steps} statements to interpret", pos)
        self.check_time(pos)

    def check_time(self, pos: k.Pos) -> None:
        """Raise TooComplex past the wall-clock budget (called per statement and per motion check)."""
        if time.monotonic() > self.deadline:
            raise TooComplex(f"not verified within {self.time_budget_s:g} s", pos)

    def block(self, body: Sequence[k.Stmt], st: State) -> Outcome:
        out = Outcome(st)
        for stmt in body:
            if out.normal is None:
                break  # unreachable after EXIT/RETURN
            res = self.stmt(stmt, out.normal)
            out.normal = res.normal
            out.exits += res.exits
            out.returns += res.returns
        return out

    def stmt(self, stmt: k.Stmt, st: State) -> Outcome:
        self.step(stmt.pos)
        match stmt:
            case k.Decl():
                return Outcome(self.declare(stmt, st))
            case k.Assign(target=target, value=value):
                return Outcome(self.assign(target, value, st, stmt.pos))
            case k.Motion():
                return Outcome(self.motion(stmt, st))
            case k.WaitSec(seconds=e) | k.WaitFor(condition=e):
                self.sink(e, st, None, stmt.pos)
                return Outcome(st)
            case k.Halt():
                return Outcome(st)
            case k.Exit():
                if self.loop_depth == 0:
                    self.report("STATEMENT", stmt.pos, "EXIT outside a loop (the controller's compiler rejects it)")
                    return Outcome(st)
                return Outcome(None, exits=[st])
            case k.Return(value=value):
                if value is not None:
                    self.sink(value, st, None, stmt.pos)
                return Outcome(None, returns=[st])
            case k.If(condition=cond, then_body=then_body, else_body=else_body):
                known = self.condition(cond, st, stmt.pos)
                if known is not None:
                    return self.block(then_body if known else else_body, st)
                a = self.block(then_body, st)
                b = self.block(else_body, st)
                return Outcome(join([a.normal, b.normal]), a.exits + b.exits, a.returns + b.returns)
            case k.For():
                return self.in_loop(lambda: self.for_loop(stmt, st))
            case k.While() | k.Repeat():
                return self.in_loop(lambda: self.conditional_loop(stmt, st))
            case k.Loop(body=body):
                return self.in_loop(lambda: self.fixpoint(body, st, stmt.pos, counter=None, endless=True, loop=stmt))
            case k.CallStmt(name=name, args=args):
                for a in args:
                    self.check_calls(a)
                self.report("CALL", stmt.pos, f"call of subprogram {name}: the check cannot see into it, refused")
                return Outcome(replace(st, poses=None))
        self.report("STATEMENT", stmt.pos, f"statement {type(stmt).__name__} is not verified, refused")
        return Outcome(st)

    def in_loop(self, run: Any) -> Outcome:
        self.loop_depth += 1
        try:
            result: Outcome = run()
            return result
        finally:
            self.loop_depth -= 1

    # --- loops ---
    def for_loop(self, stmt: k.For, st: State) -> Outcome:
        if self.types.get(stmt.var) != "INT" or stmt.var not in self.own:
            self.report("LOOP", stmt.pos, f"FOR counter {stmt.var} is not a declared INT of this program")
        written = written_names(stmt.body)
        certain = True
        if stmt.var in written:
            self.report(
                "LOOP",
                stmt.pos,
                f"the body writes the counter {stmt.var} (an assignment or a nested FOR): the passes cannot be known",
            )
            certain = False
        bound_reads = read_names(stmt.start) | read_names(stmt.stop) | (read_names(stmt.step) if stmt.step else set())
        if bound_reads & written:
            self.report(
                "LOOP",
                stmt.pos,
                f"the body writes {', '.join(sorted(bound_reads & written))}, which the bounds read",
            )
            certain = False
        start = self.sink(stmt.start, st, "INT", stmt.pos)
        stop = self.sink(stmt.stop, st, "INT", stmt.pos)
        step = self.sink(stmt.step, st, "INT", stmt.pos) if stmt.step is not None else 1
        if step == 0:
            self.report("LOOP", stmt.pos, "FOR with STEP 0 never ends")
            certain = False
        if certain and all(is_int(v) for v in (start, stop, step)):
            count = max(0, (stop - start) // step + 1)  # type: ignore[operator]
            if not INT_MIN <= start + count * step <= INT_MAX:  # type: ignore[operator]
                # the counter's last increment leaves the INT range: wrap-around (an endless loop) or an error?
                self.report("UNSURE", stmt.pos, f"the counter {stmt.var} overflows after the last pass: refused")
            elif count <= MAX_UNROLL:
                out = Outcome(st)
                exits: list[State] = []
                returns: list[State] = []
                value = start
                for _ in range(count):
                    if out.normal is None:
                        break
                    res = self.block(stmt.body, out.normal.with_var(stmt.var, value))
                    out = Outcome(res.normal)
                    exits += res.exits
                    returns += res.returns
                    value += step  # type: ignore[operator]
                # the counter's value after the loop is not documented: unknown
                done = out.normal.with_var(stmt.var, UNKNOWN) if out.normal is not None else None
                return Outcome(join([done, *(e.with_var(stmt.var, UNKNOWN) for e in exits)]), [], returns)
        passes = None
        if certain and all(is_int(v) for v in (start, stop, step)):
            passes = max(0, (stop - start) // step + 1)  # type: ignore[operator]
        return self.fixpoint(stmt.body, st, stmt.pos, counter=stmt.var, endless=False, loop=stmt, passes=passes)

    def conditional_loop(self, stmt: k.While | k.Repeat, st: State) -> Outcome:
        """WHILE/REPEAT: run pass by pass while the condition is known; otherwise a fixpoint."""
        unrolled = self.unroll(stmt, st)
        if unrolled is not None:
            return unrolled
        return self.fixpoint(stmt.body, st, stmt.pos, counter=None, endless=False, loop=stmt)

    def unroll(self, stmt: k.While | k.Repeat, st: State) -> Outcome | None:
        cur: State | None = st
        exits: list[State] = []
        returns: list[State] = []
        for n in range(MAX_UNROLL + 1):
            assert cur is not None
            if isinstance(stmt, k.While) or n > 0:
                known = self.condition(stmt.condition, cur, stmt.pos)
                if known is None or n == MAX_UNROLL:
                    return None
                if known is isinstance(stmt, k.Repeat):  # WHILE ends on FALSE, REPEAT ... UNTIL on TRUE
                    return Outcome(join([cur, *exits]), [], returns)
            res = self.block(stmt.body, cur)
            exits += res.exits
            returns += res.returns
            if res.normal is None:
                return Outcome(join(exits), [], returns)
            cur = res.normal
        return None

    def fixpoint(self, body: Sequence[k.Stmt], st: State, pos: k.Pos, counter: str | None, endless: bool,
                 loop: k.Stmt | None = None, passes: int | None = None) -> Outcome:
        # Each pass is interpreted from a head whose motion time is 0: the passes' time is bounded separately (the
        # longest pass found, times the passes if they are known; see loop_motion_s), so the head can settle.
        head = replace(st.with_var(counter, UNKNOWN) if counter else st, motion_s=0.0)
        exits: list[State] = []
        returns: list[State] = []
        per_pass_s = 0.0
        for _ in range(MAX_FIXPOINT_ITERATIONS):
            res = self.block(body, head)
            exits += res.exits
            returns += res.returns
            per_pass_s = max([per_pass_s, *(s.motion_s for s in (res.normal, *res.exits, *res.returns) if s)])
            new_head = join([head, res.normal])
            assert new_head is not None
            new_head = replace(new_head, motion_s=0.0)
            if counter:
                new_head = new_head.with_var(counter, UNKNOWN)
            if new_head == head:
                break
            head = new_head
        else:
            self.report(
                "LOOP",
                pos,
                "the loop's effect does not settle (e.g. a relative motion repeated an unknown number of "
                "times): its motions cannot be bounded, refused",
            )
            head = replace(head, poses=None)
        loop_s = per_pass_s
        if loop is not None:
            paced = not isinstance(loop, k.For) and self.paced_by_host(body, st)
            loop_s = self.loop_motion_s(loop, per_pass_s, passes, paced, bool(exits) or not endless)
        normal = join(exits) if endless else join([head, *exits])
        after = st.motion_s + loop_s
        return Outcome(None if normal is None else replace(normal, motion_s=after), [],
                       [replace(r, motion_s=after) for r in returns])

    def paced_by_host(self, body: Sequence[k.Stmt], st: State) -> bool:
        """Whether every pass of a loop body waits for the host before it can move: a top-level ``WAIT FOR`` on a
        variable the host writes comes before any motion, and the body's last statement gives that variable a
        constant value for which the condition is FALSE (``RGSE_CMD = 0`` ... ``WAIT FOR RGSE_CMD <> 0``). The next
        pass then moves only after the host wrote a new value: one command, one pass."""
        wait = None
        for s in body:
            if isinstance(s, k.WaitFor):
                wait = s
                break
            if any(isinstance(x, k.Motion) for x in all_stmts([s])):
                return False
        last = body[-1] if body else None
        if wait is None or not isinstance(last, k.Assign) or not isinstance(last.target, k.Name):
            return False
        name = last.target.name
        if not self.host_written(name) or name not in read_names(wait.condition):
            return False
        try:
            reset = Evaluator(read=lambda e: UNKNOWN, call=lambda c: UNKNOWN, strict=True).evaluate(last.value)
            ev = Evaluator(read=lambda e: reset if isinstance(e, k.Name) and e.name == name else UNKNOWN,
                           call=lambda c: UNKNOWN, strict=True)
            return ev.evaluate(wait.condition) is False
        except (Unsure, EvalError):
            return False

    # --- assignments ---
    def assign(self, target: k.Expr, value_expr: k.Expr, st: State, pos: k.Pos) -> State:
        name = root_name(target)
        self.check_calls(target)
        if name is not None and name.startswith("$"):
            value = self.sink(value_expr, st, system_type(target), pos)
            return self.system_write(name, target, value, st, pos)
        if name is None or (name not in self.own and not self.writable(target, pos)):
            self.sink(value_expr, st, None, pos)
            return st
        if name not in self.own:
            self.sink(value_expr, st, None, pos)
            return st  # an allow-listed global: stays unknown (the daemon writes it too)
        type_name = self.types.get(name)
        old = st.var(name)
        if type_name not in TRACKED_TYPES:
            self.sink(value_expr, st, None, pos)
            return st.with_var(name, UNKNOWN)
        if isinstance(target, k.Name):
            if old is not UNKNOWN and isinstance(old, KrlArray):
                self.report("RUNTIME", pos, f"cannot assign to the whole array {name}")
                return st.with_var(name, UNKNOWN)
            value = self.sink(value_expr, st, type_name, pos, old)
            if (
                type_name in STRUCT_FIELDS
                and not isinstance(old, KrlStruct)
                and isinstance(value, KrlStruct)
                and not set(STRUCT_FIELDS[type_name]) <= set(value)
            ):
                # the fields the aggregate leaves out keep values that are not known (the join of two branches, a
                # loop, a parameter): not "uninitialised", which would let the check take the axis as staying put
                value = UNKNOWN
            return st.with_var(name, value)
        if isinstance(target, k.Member) and isinstance(target.base, k.Name) and type_name in STRUCT_FIELDS:
            if target.member not in STRUCT_FIELDS[type_name]:
                self.report("RUNTIME", pos, f"{type_name} has no field {target.member}")
                return st.with_var(name, UNKNOWN)
            value = self.sink(value_expr, st, field_type(target.member), pos)
            if value is UNKNOWN or not isinstance(old, KrlStruct):
                return st.with_var(name, UNKNOWN)
            return st.with_var(name, convert(type_name, KrlStruct(type_name, ((target.member, value),)), old, pos))
        if isinstance(target, k.Index) and isinstance(target.base, k.Name) and isinstance(old, KrlArray):
            idx = tuple(self.index(i, st, pos) for i in target.indices)
            value = self.sink(value_expr, st, old.type_name, pos, UNKNOWN)
            if value is UNKNOWN or any(i is UNKNOWN for i in idx):
                return st.with_var(name, UNKNOWN)  # which element changed is not known
            try:
                check_index(old, idx, pos)  # type: ignore[arg-type]
                current = element(old, idx, pos) if old.type_name in STRUCT_FIELDS else UNKNOWN  # type: ignore[arg-type]
                items = dict(old.items)
                items[idx] = convert(old.type_name, value, current, pos)  # type: ignore[index]
            except EvalError as exc:
                self.report("RUNTIME", pos, exc.reason)
                return st.with_var(name, UNKNOWN)
            return st.with_var(name, KrlArray(old.type_name, old.dims, items))
        self.sink(value_expr, st, None, pos)
        return st.with_var(name, UNKNOWN)

    # --- motions ---
    def declared_type(self, expr: k.Expr) -> str | None:
        if isinstance(expr, k.Name) and expr.name in self.own:
            return self.types.get(expr.name)
        if isinstance(expr, k.Index) and isinstance(expr.base, k.Name) and expr.base.name in self.own:
            return self.types.get(expr.base.name)
        return None

    def target_fields(self, stmt: k.Motion, st: State) -> dict[str, float] | None:
        value = self.sink(stmt.target, st, None, stmt.pos)
        declared = stmt.target.type_name if isinstance(stmt.target, k.Aggregate) else self.declared_type(stmt.target)
        if declared in CARTESIAN_TYPES or (
            isinstance(value, KrlStruct) and (value.type_name in CARTESIAN_TYPES or set(value) & {"X", "Y", "Z"})
        ):
            self.report(
                "CARTESIAN",
                stmt.pos,
                f"{stmt.kind} to a Cartesian target: cannot be verified without "
                "inverse kinematics (joint path, axis ranges, speeds), give the target as E6AXIS",
            )
            return None
        if not isinstance(value, KrlStruct):
            self.report("TARGET", stmt.pos, f"{stmt.kind} target does not resolve to a constant: refused")
            return None
        if value.type_name not in (None, "AXIS", "E6AXIS"):
            self.report("TARGET", stmt.pos, f"{stmt.kind} target of type {value.type_name}: only E6AXIS/AXIS")
            return None
        fields: dict[str, float] = {}
        for n, v in value.fields:
            if n not in AXIS_FIELDS and n not in EXT_FIELDS:
                self.report("TARGET", stmt.pos, f"{stmt.kind} target field {n} is not an axis")
                return None
            if n in CARTESIAN_FIELDS or not isinstance(v, float | int) or isinstance(v, bool):
                self.report("TARGET", stmt.pos, f"{stmt.kind} target field {n} is not a number")
                return None
            if n in AXIS_FIELDS:
                fields[n] = float(v)
            elif float(v) != 0.0:  # the cell has no external axes; one that moved would move unverified
                self.report("EXTERNAL_AXIS", stmt.pos,
                            f"{stmt.kind} target {n} {float(v):g}: external axes are not verified, only 0 is allowed")
                return None
        # A field the target leaves out (or a variable's field never assigned) keeps the axis where it is: on the
        # controller it does, or the uninitialised field stops the program; either way no other motion happens.
        return fields

    def motion(self, stmt: k.Motion, st: State) -> State:
        fields = self.target_fields(stmt, st)
        if fields is None:
            return replace(st, poses=None)
        if st.poses is None:
            self.start_unknown(stmt)
            if not stmt.relative and all(a in fields for a in AXIS_FIELDS):
                target = pose_key(fields[a] for a in AXIS_FIELDS)
                if self.check_target(target, stmt.pos):
                    return replace(st, poses=frozenset({target}))
            return st
        targets = set()
        time_s = 0.0
        for start in sorted(st.poses):
            if stmt.relative:
                delta = [fields.get(a, 0.0) for a in AXIS_FIELDS]
                self.check_relative(delta, stmt.pos)
                target = pose_key(s + d for s, d in zip(start, delta, strict=True))
            else:
                target = pose_key(fields.get(a, s) for a, s in zip(AXIS_FIELDS, start, strict=True))
            if self.check_target(target, stmt.pos):
                self.check_path(start, target, st, stmt.pos)
                time_s = max(time_s, self.motion_time_s(start, target, st))
                targets.add(target)
        if not targets:
            return st  # every target refused: the check goes on from the poses before (the program is refused anyway)
        st = replace(st, motion_s=st.motion_s + time_s)
        if len(targets) > MAX_POSES:
            return replace(st, poses=None)
        return replace(st, poses=frozenset(targets))
