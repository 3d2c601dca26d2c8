"""The interlock's static check: may this KRL program be pushed to the robot and started?

:func:`check_program` returns every rule the program breaks (empty list: allowed); :func:`ensure_allowed` raises
:class:`ProgramRefused` (an :class:`~rgse_daemon.errors.InterlockError`) listing them. The check interprets the
program abstractly, statement by statement from its main routine, tracking what can be known without running it:

* the set of poses the robot can be in (starting at ``ctx.start_axes_deg``; ``None`` = unknown);
* the motion settings in force ($VEL_AXIS per axis as the *largest* value any path can have set, $OV_PRO);
* the constant values of the program's own variables (routine locals, non-GLOBAL data-list entries).

IF takes both branches and joins them (union of poses, worst-case settings); FOR loops with constant bounds are
unrolled; any other loop is iterated until its entry state stops changing (a loop that never settles, e.g. a
relative move repeated an unknown number of times, is refused). GLOBAL variables and system variables are unknown:
the daemon or the operator can change them while the program runs.

Rules (``Violation.rule``):

``MODE``          mode must be T1; AUT only with the hazard area cleared *and* the key switch confirmed; T2/EX never.
``SPEED``         worst-case Cartesian speed of the elbow, wrist centre, flange and every payload point over the whole
                  joint path of every PTP (``kinematics.max_point_speed_mm_s(...).bound_mm_s``, axis speeds from the
                  ``kinematics.MAX_AXIS_SPEED_DEG_S`` × $VEL_AXIS % × override) ≤ ``limits.t1_speed_mm_s``.
                  The override is the larger of what the program assigns and ``ctx.override_max_pct`` (the operator
                  can raise it on the smartPAD at any time).
``JOINT_LIMIT``   every target within the axis ranges; ``A1_ENVELOPE``: |A1| ≤ ``limits.a1_range_deg``.
``START_UNKNOWN`` a motion whose start pose is unknown cannot be verified.
``TARGET``        a target that does not resolve to constant axis angles; ``CARTESIAN``: Cartesian targets (no IK).
``PAYLOAD``       payload mass ≤ ``limits.max_payload_kg``; ``A5_TORQUE``: static A5 torque of the payload along
                  every motion ≤ ``limits.max_a5_torque_nm`` (load diagram, paper Fig. 16).
``REL_AMPLITUDE`` a relative (brake-release) move of more than ``limits.brake_release_max_deg`` on any axis.
``WRITE``         a variable written that is neither the program's own nor on the allow-list; ``SYSVAR``: a system
                  variable other than $VEL_AXIS/$ACC_AXIS/$VEL.CP/$APO/$OV_PRO/$TRACE.*; ``OV_PRO``: $OV_PRO not a
                  constant in 0..100; ``VELOCITY``: a motion setting that is not a constant in range.
``CALL``          a subprogram or function call the check cannot see into (only pure math built-ins are allowed).
``STATEMENT``     INTERRUPT, TRIGGER, GOTO, SWITCH, LIN/LIN_REL (Cartesian path: unverifiable without IK),
                  approximate positioning, extra routines.
``LOOP``          a loop whose effect does not settle; ``COMPLEXITY``: too much to verify.

Any doubt refuses: the check may be stricter than the robot needs, never looser.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rgse_daemon.config import LimitsConfig
from rgse_daemon.errors import InterlockError, KrlSyntaxError
from rgse_daemon.kinematics import (
    D6_M,
    G_PAPER_M_S2,
    JOINT_LIMITS_DEG,
    MAX_AXIS_SPEED_DEG_S,
    gravity_torques_nm,
    max_point_speed_mm_s,
)
from rgse_daemon.krl import ast as k
from rgse_daemon.krl.lexer import Tok, tokenize
from rgse_daemon.krl.parser import parse_dat, parse_src
from rgse_daemon.krl.walk import iter_exprs, root_name, stmt_exprs
from rgse_daemon.safety.allowlist import WRITABLE_PREFIX, WRITABLE_VARIABLES

#: Statement keywords the check refuses outright (the parser does not accept them either).
FORBIDDEN_KEYWORDS = frozenset({"INTERRUPT", "TRIGGER", "GOTO", "SWITCH", "CONTINUE", "ANIN", "ANOUT", "BRAKE"})
#: Functions without side effects that expressions may call.
PURE_FUNCTIONS = frozenset({"ABS", "SQRT", "SIN", "COS", "TAN", "ASIN", "ACOS", "ATAN2"})
AXIS_FIELDS = ("A1", "A2", "A3", "A4", "A5", "A6")
EXT_FIELDS = ("E1", "E2", "E3", "E4", "E5", "E6")
CARTESIAN_FIELDS = frozenset({"X", "Y", "Z", "A", "B", "C", "S", "T"})
CARTESIAN_TYPES = frozenset({"POS", "E6POS", "FRAME"})
#: FOR loops with constant bounds are unrolled up to this many iterations; longer ones are iterated to a fixpoint.
MAX_UNROLL = 1000
#: Iterations of a loop body before a loop whose state keeps changing is refused.
MAX_FIXPOINT_ITERATIONS = 12
#: More possible poses than this at one point of the program → treated as unknown (refused at the next motion).
MAX_POSES = 64
#: Motion checks (pairs start → target) before the program is refused as too complex to verify.
MAX_MOTION_CHECKS = 20_000
#: Sampling of the joint path for the static A5 torque (deg, sum over the axes between samples).
TORQUE_STEP_DEG = 0.25


@dataclass(frozen=True, order=True)
class Violation:
    """One broken rule at a place in the program (``line``/``column`` 1-based; 0 for the program as a whole)."""

    line: int
    column: int
    rule: str
    message: str

    def __str__(self) -> str:
        return f"{self.line}:{self.column}: {self.rule}: {self.message}"


class ProgramRefused(InterlockError):
    """The static check refused a program; ``violations`` lists why."""

    def __init__(self, file: str, violations: Sequence[Violation]) -> None:
        lines = "\n".join(f"{file}:{v}" for v in violations)
        super().__init__(f"{file}: refused by the interlock ({len(violations)} violation(s)):\n{lines}")
        self.file = file
        self.violations = tuple(violations)


@dataclass(frozen=True)
class CheckContext:
    """What the check needs to know besides the program.

    ``mode``: ``$MODE_OP`` (``"T1"``, ``"#AUT"`` ...). ``area_cleared``: the hazard area is cleared and cordoned (Modbus
    safety I/O). ``key_confirmed``: the key switch for automatic modes is turned. ``payload_mass_kg`` and
    ``payload_cog_flange_m`` (flange frame, m): for the load diagram. ``payload_points_flange_m``: flange-frame points
    whose speed matters (CoG and extreme corners of fixture and DuT). ``start_axes_deg``: A1..A6 read from the robot
    before the push (``None``: unknown, every first motion is refused). ``override_max_pct``: the largest program
    override that can be in force during the run (100 unless the daemon knows it is locked lower).
    """

    limits: LimitsConfig = field(default_factory=LimitsConfig)
    mode: str = "T1"
    area_cleared: bool = False
    key_confirmed: bool = False
    payload_mass_kg: float = 0.0
    payload_cog_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    payload_points_flange_m: tuple[tuple[float, float, float], ...] = ()
    start_axes_deg: tuple[float, ...] | None = None
    writable_variables: frozenset[str] = WRITABLE_VARIABLES
    writable_prefix: str = WRITABLE_PREFIX
    override_max_pct: float = 100.0

    def link_writable(self, name: str) -> bool:
        """Whether the allow-list admits writing ``name`` (what the daemon itself may write over the link)."""
        n = name.strip().upper()
        return n in self.writable_variables or n.startswith(self.writable_prefix.upper())


# --- abstract values --------------------------------------------------------------------------------------------------
class _Top:
    """An unknown value."""

    _instance: _Top | None = None

    def __new__(cls) -> _Top:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "TOP"


TOP = _Top()


@dataclass(frozen=True)
class _Agg:
    """A constant aggregate: ``{E6AXIS: A1 0.0, ...}`` with its fields in order."""

    type_name: str | None
    items: tuple[tuple[str, Any], ...]

    def get(self, name: str) -> Any:
        for n, v in self.items:
            if n == name:
                return v
        return None


def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


Pose = tuple[float, ...]


@dataclass(frozen=True)
class _State:
    """What is known at one point of the program (see the module docstring)."""

    poses: frozenset[Pose] | None
    vel_axis_pct: tuple[float, ...]
    override_pct: float
    env: tuple[tuple[str, Any], ...]

    def var(self, name: str) -> Any:
        for n, v in self.env:
            if n == name:
                return v
        return TOP

    def with_var(self, name: str, value: Any) -> _State:
        env = dict(self.env)
        env[name] = value
        return replace(self, env=tuple(sorted(env.items())))


def _pose_key(q: Iterable[float]) -> Pose:
    return tuple(round(float(v), 6) + 0.0 for v in q)


def _join(states: Sequence[_State | None]) -> _State | None:
    live = [s for s in states if s is not None]
    if not live:
        return None
    if len(live) == 1:
        return live[0]
    poses: frozenset[Pose] | None = frozenset()
    for s in live:
        if s.poses is None or poses is None:
            poses = None
        else:
            poses = poses | s.poses
    if poses is not None and len(poses) > MAX_POSES:
        poses = None
    vel = tuple(max(s.vel_axis_pct[i] for s in live) for i in range(6))
    ov = max(s.override_pct for s in live)
    names = sorted({n for s in live for n, _ in s.env})
    env = []
    for n in names:
        values = [s.var(n) for s in live]
        first = values[0]
        same = all(type(v) is type(first) and v == first for v in values)
        env.append((n, first if same else TOP))
    return _State(poses, vel, ov, tuple(env))


@dataclass
class _Outcome:
    normal: _State | None
    exits: list[_State] = field(default_factory=list)
    returns: list[_State] = field(default_factory=list)


class _TooComplex(Exception):
    """The program's control flow is beyond what the checker follows: refused."""


class _Checker:
    def __init__(self, ctx: CheckContext, own_locals: set[str], dat_consts: dict[str, Any]) -> None:
        self.ctx = ctx
        self.limits = ctx.limits
        self.own_locals = own_locals
        self.dat_consts = dat_consts
        self.found: dict[tuple[str, int, int], Violation] = {}
        self.motion_checks = 0
        self._speed_cache: dict[tuple[Pose, Pose, tuple[float, ...]], float] = {}
        self._torque_cache: dict[tuple[Pose, Pose], float] = {}
        self.points = [tuple(map(float, p)) for p in ctx.payload_points_flange_m]
        self.points.append(tuple(map(float, ctx.payload_cog_flange_m)))

    # --- reporting --------------------------------------------------------------------------------------------------
    def report(self, rule: str, pos: k.Pos, message: str) -> None:
        key = (rule, pos.line, pos.column)
        if key not in self.found:
            self.found[key] = Violation(pos.line, pos.column, rule, message)

    # --- expressions -----------------------------------------------------------------------------------------------
    def check_calls(self, expr: k.Expr) -> None:
        for e in iter_exprs(expr):
            if isinstance(e, k.Call) and e.name not in PURE_FUNCTIONS:
                self.report("CALL", e.pos, f"call of {e.name}(): the check cannot see into functions, refused")

    def eval(self, expr: k.Expr, st: _State) -> Any:
        """The constant value of ``expr`` in state ``st``, or TOP."""
        match expr:
            case k.IntLit(value=v) | k.RealLit(value=v) | k.BoolLit(value=v) | k.StrLit(value=v):
                return v
            case k.EnumLit(name=n):
                return ("#", n)
            case k.Name(name=n):
                if n.startswith("$"):
                    return TOP
                return st.var(n)
            case k.Member(base=base, member=m):
                b = self.eval(base, st)
                if isinstance(b, _Agg):
                    v = b.get(m)
                    return TOP if v is None else v
                return TOP
            case k.Index():
                return TOP
            case k.Aggregate(type_name=t, items=items):
                return _Agg(t, tuple((i.name, self.eval(i.value, st)) for i in items))
            case k.Unary(op=op, operand=operand):
                v = self.eval(operand, st)
                if op == "NOT" and isinstance(v, bool):
                    return not v
                if op in ("-", "+") and _is_num(v):
                    return -v if op == "-" else v
                return TOP
            case k.Binary(op=op, left=left, right=right):
                return _binary(op, self.eval(left, st), self.eval(right, st))
            case k.Call(name=name, args=args):
                values = [self.eval(a, st) for a in args]
                if name not in PURE_FUNCTIONS or not all(_is_num(v) for v in values):
                    return TOP
                try:
                    result = _PURE[name](*values)
                except (ValueError, TypeError, ZeroDivisionError):
                    return TOP
                return result if math.isfinite(result) else TOP
        return TOP

    # --- blocks ------------------------------------------------------------------------------------------------------
    def block(self, body: Sequence[k.Stmt], st: _State) -> _Outcome:
        out = _Outcome(st)
        for stmt in body:
            if out.normal is None:
                break  # unreachable after EXIT/RETURN
            res = self.stmt(stmt, out.normal)
            out.normal = res.normal
            out.exits += res.exits
            out.returns += res.returns
        return out

    def stmt(self, stmt: k.Stmt, st: _State) -> _Outcome:
        for e in stmt_exprs(stmt):
            self.check_calls(e)
        match stmt:
            case k.Decl():
                for dn in stmt.names:
                    value = self.eval(stmt.init, st) if stmt.init is not None and not dn.dims else TOP
                    st = st.with_var(dn.name, value)
                return _Outcome(st)
            case k.Assign(target=target, value=value):
                return _Outcome(self.assign(target, value, st, stmt.pos))
            case k.Motion():
                return _Outcome(self.motion(stmt, st))
            case k.WaitSec() | k.WaitFor() | k.Halt():
                return _Outcome(st)
            case k.Exit():
                return _Outcome(None, exits=[st])
            case k.Return():
                return _Outcome(None, returns=[st])
            case k.If(then_body=then_body, else_body=else_body):
                a = self.block(then_body, st)
                b = self.block(else_body, st)
                return _Outcome(_join([a.normal, b.normal]), a.exits + b.exits, a.returns + b.returns)
            case k.For():
                return self.for_loop(stmt, st)
            case k.While(body=body) | k.Repeat(body=body):
                return self.fixpoint(body, st, stmt.pos, counter=None, endless=False)
            case k.Loop(body=body):
                return self.fixpoint(body, st, stmt.pos, counter=None, endless=True)
            case k.CallStmt(name=name):
                self.report("CALL", stmt.pos, f"call of subprogram {name}: the check cannot see into it, refused")
                return _Outcome(replace(st, poses=None))
        self.report("STATEMENT", stmt.pos, f"statement {type(stmt).__name__} is not verified, refused")
        return _Outcome(st)

    def for_loop(self, stmt: k.For, st: _State) -> _Outcome:
        self.check_write(k.Name(stmt.var, stmt.pos), stmt.pos)
        start, stop = self.eval(stmt.start, st), self.eval(stmt.stop, st)
        step = self.eval(stmt.step, st) if stmt.step is not None else 1
        writes_counter = any(isinstance(s, k.Assign) and root_name(s.target) == stmt.var for s in _all_stmts(stmt.body))
        consts = all(isinstance(v, int) and not isinstance(v, bool) for v in (start, stop, step))
        if consts and step != 0 and not writes_counter:
            count = max(0, (stop - start) // step + 1)
            if count <= MAX_UNROLL:
                out = _Outcome(st)
                exits: list[_State] = []
                returns: list[_State] = []
                value = start
                for _ in range(count):
                    if out.normal is None:
                        break
                    res = self.block(stmt.body, out.normal.with_var(stmt.var, value))
                    out = _Outcome(res.normal)
                    exits += res.exits
                    returns += res.returns
                    value += step
                done = out.normal.with_var(stmt.var, value) if out.normal is not None else None
                return _Outcome(_join([done, *exits]), [], returns)
        return self.fixpoint(stmt.body, st, stmt.pos, counter=stmt.var, endless=False)

    def fixpoint(self, body: Sequence[k.Stmt], st: _State, pos: k.Pos, counter: str | None, endless: bool) -> _Outcome:
        head = st.with_var(counter, TOP) if counter else st
        exits: list[_State] = []
        returns: list[_State] = []
        for _ in range(MAX_FIXPOINT_ITERATIONS):
            res = self.block(body, head)
            exits += res.exits
            returns += res.returns
            new_head = _join([head, res.normal])
            assert new_head is not None
            if counter:
                new_head = new_head.with_var(counter, TOP)
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
        normal = _join(exits) if endless else _join([head, *exits])
        return _Outcome(normal, [], returns)

    # --- writes ------------------------------------------------------------------------------------------------------
    def check_write(self, target: k.Expr, pos: k.Pos) -> bool:
        """Report a write to a variable that is neither the program's own nor allow-listed; True if allowed."""
        name = root_name(target)
        if name is None:
            self.report("WRITE", pos, "write to an expression that is not a variable, refused")
            return False
        if name.startswith("$"):
            return True  # system variables: see assign()
        if name in self.own_locals or name in self.dat_consts:
            return True
        if self.ctx.link_writable(name):
            return True
        self.report("WRITE", pos, f"write to {name}: not a variable of this program and not on the allow-list")
        return False

    def assign(self, target: k.Expr, value_expr: k.Expr, st: _State, pos: k.Pos) -> _State:
        name = root_name(target)
        value = self.eval(value_expr, st)
        if name is not None and name.startswith("$"):
            return self.assign_system(name, target, value, st, pos)
        if not self.check_write(target, pos) or name is None:
            return st
        if name not in self.own_locals and name not in self.dat_consts:
            return st  # an allow-listed global: stays unknown (the daemon writes it too)
        if isinstance(target, k.Name):
            return st.with_var(name, value)
        if isinstance(target, k.Member) and isinstance(target.base, k.Name):
            old = st.var(name)
            if isinstance(old, _Agg) and value is not TOP:
                items = dict(old.items)
                items[target.member] = value
                return st.with_var(name, _Agg(old.type_name, tuple(items.items())))
        return st.with_var(name, TOP)

    def assign_system(self, name: str, target: k.Expr, value: Any, st: _State, pos: k.Pos) -> _State:
        if name in ("$VEL_AXIS", "$ACC_AXIS"):
            ok_target = isinstance(target, k.Index) and isinstance(target.base, k.Name) and len(target.indices) == 1
            idx = self.eval(target.indices[0], st) if ok_target else TOP  # type: ignore[union-attr]
            if not (isinstance(idx, int) and not isinstance(idx, bool) and 1 <= idx <= 6):
                self.report("VELOCITY", pos, f"{name} must be set per axis with a constant index 1..6")
                idx = None
            if not (_is_num(value) and 0.0 < value <= 100.0):
                self.report("VELOCITY", pos, f"{name} must be set to a constant in (0, 100] %, not {_show(value)}")
                value = 100.0
            if name == "$VEL_AXIS":
                vel = list(st.vel_axis_pct)
                for i in range(6) if idx is None else (idx - 1,):
                    vel[i] = 100.0 if idx is None else float(value)
                return replace(st, vel_axis_pct=tuple(vel))
            return st
        if name == "$VEL":
            if not (isinstance(target, k.Member) and isinstance(target.base, k.Name) and target.member == "CP"):
                self.report("SYSVAR", pos, "only $VEL.CP of $VEL may be written")
            elif not (_is_num(value) and 0.0 < value <= 2.0):
                self.report("VELOCITY", pos, f"$VEL.CP must be a constant in (0, 2] m/s, not {_show(value)}")
            return st
        if name == "$OV_PRO":
            if not isinstance(target, k.Name):
                self.report("SYSVAR", pos, "$OV_PRO is a scalar")
                return replace(st, override_pct=100.0)
            if not (_is_num(value) and 0.0 <= value <= 100.0):
                self.report("OV_PRO", pos, f"$OV_PRO must be a constant in 0..100 %, not {_show(value)}")
                return replace(st, override_pct=100.0)
            return replace(st, override_pct=max(st.override_pct, float(value)))
        if name in ("$APO", "$TRACE"):
            return st
        self.report("SYSVAR", pos, f"write to system variable {name} is not allowed")
        return st

    # --- motions -----------------------------------------------------------------------------------------------------
    def motion(self, stmt: k.Motion, st: _State) -> _State | None:
        if stmt.kind.startswith("LIN"):
            self.report(
                "STATEMENT",
                stmt.pos,
                f"{stmt.kind}: a Cartesian straight-line path cannot be verified without "
                "inverse kinematics (joint path, payload point speeds): use PTP with E6AXIS targets",
            )
        if stmt.approx is not None:
            self.report(
                "STATEMENT",
                stmt.pos,
                f"approximate positioning {stmt.approx} blends paths whose speed is not verified: remove it",
            )
        fields = self.target_fields(stmt, st)
        if fields is None:
            return replace(st, poses=None)
        if st.poses is None:
            self.report(
                "START_UNKNOWN",
                stmt.pos,
                f"{stmt.kind} from an unknown start pose: its path and speed "
                "cannot be verified (read the robot's axes before the push)",
            )
            if not stmt.relative and all(a in fields for a in AXIS_FIELDS):
                target = _pose_key(fields[a] for a in AXIS_FIELDS)
                self.check_target(target, stmt.pos)
                return replace(st, poses=frozenset({target}))
            return st
        targets = set()
        for start in sorted(st.poses):
            if stmt.relative:
                delta = [fields.get(a, 0.0) for a in AXIS_FIELDS]
                big = [f"A{i}" for i, d in enumerate(delta, 1) if abs(d) > self.limits.brake_release_max_deg]
                if big:
                    self.report(
                        "REL_AMPLITUDE",
                        stmt.pos,
                        f"relative move of {', '.join(big)} by more than "
                        f"{self.limits.brake_release_max_deg:g} deg (brake_release_max_deg)",
                    )
                target = _pose_key(s + d for s, d in zip(start, delta, strict=True))
            else:
                target = _pose_key(fields.get(a, s) for a, s in zip(AXIS_FIELDS, start, strict=True))
            if self.check_target(target, stmt.pos):
                self.check_path(start, target, st, stmt.pos)
            targets.add(target)
        if len(targets) > MAX_POSES:
            return replace(st, poses=None)
        return replace(st, poses=frozenset(targets))

    def target_fields(self, stmt: k.Motion, st: _State) -> dict[str, float] | None:
        value = self.eval(stmt.target, st)
        if not isinstance(value, _Agg):
            self.report("TARGET", stmt.pos, f"{stmt.kind} target does not resolve to a constant aggregate: refused")
            return None
        names = {n for n, _ in value.items}
        if (value.type_name in CARTESIAN_TYPES) or (names & CARTESIAN_FIELDS):
            self.report(
                "CARTESIAN",
                stmt.pos,
                f"{stmt.kind} to a Cartesian target: cannot be verified without "
                "inverse kinematics (joint path, axis ranges, speeds), give the target as E6AXIS",
            )
            return None
        if value.type_name not in (None, "AXIS", "E6AXIS"):
            self.report("TARGET", stmt.pos, f"{stmt.kind} target of type {value.type_name}: only E6AXIS/AXIS")
            return None
        fields: dict[str, float] = {}
        for n, v in value.items:
            if n not in AXIS_FIELDS and n not in EXT_FIELDS:
                self.report("TARGET", stmt.pos, f"{stmt.kind} target field {n} is not an axis")
                return None
            if not _is_num(v):
                self.report("TARGET", stmt.pos, f"{stmt.kind} target field {n} is not a constant number")
                return None
            if n in AXIS_FIELDS:
                fields[n] = float(v)
        return fields

    def check_target(self, q: Pose, pos: k.Pos) -> bool:
        ok = True
        for i, (v, (lo, hi)) in enumerate(zip(q, JOINT_LIMITS_DEG, strict=True), 1):
            if not lo <= v <= hi:
                self.report("JOINT_LIMIT", pos, f"A{i} target {v:g} deg outside the axis range {lo:g}..{hi:g} deg")
                ok = False
        if abs(q[0]) > self.limits.a1_range_deg:
            self.report(
                "A1_ENVELOPE", pos, f"A1 target {q[0]:g} deg outside the ±{self.limits.a1_range_deg:g} deg envelope"
            )
            ok = False
        return ok

    def check_path(self, start: Pose, target: Pose, st: _State, pos: k.Pos) -> None:
        self.motion_checks += 1
        if self.motion_checks > MAX_MOTION_CHECKS:
            raise _TooComplex
        if start != target:
            self.check_speed(start, target, st, pos)
        # The load diagram applies to holding a pose as much as to moving: a motion to where the robot already is
        # still has to be within it (found by the property test: PTP {A1 0} with 611 kg at 0.5 m from the flange).
        torque = self._torque_cache.get((start, target))
        if torque is None:
            torque = self.max_a5_torque_nm(start, target)
            self._torque_cache[(start, target)] = torque
        if not torque <= self.limits.max_a5_torque_nm:
            self.report(
                "A5_TORQUE",
                pos,
                f"static A5 torque of the payload reaches {torque:.0f} Nm on this motion, "
                f"above the load diagram's {self.limits.max_a5_torque_nm:g} Nm",
            )

    def check_speed(self, start: Pose, target: Pose, st: _State, pos: k.Pos) -> None:
        override = max(st.override_pct, self.ctx.override_max_pct)
        vmax = tuple(
            round(p / 100.0 * m * override / 100.0, 9)
            for p, m in zip(st.vel_axis_pct, MAX_AXIS_SPEED_DEG_S, strict=True)
        )
        key = (start, target, vmax)
        speed = self._speed_cache.get(key)
        if speed is None:
            speed = max_point_speed_mm_s(start, target, vmax, self.points).bound_mm_s
            self._speed_cache[key] = speed
        if not speed <= self.limits.t1_speed_mm_s:
            self.report(
                "SPEED",
                pos,
                f"worst-case point speed {speed:.0f} mm/s exceeds {self.limits.t1_speed_mm_s:g}"
                f" mm/s ($VEL_AXIS {_pcts(st.vel_axis_pct)} %, override {override:g} %)",
            )

    def max_a5_torque_nm(self, start: Pose, target: Pose) -> float:
        if self.ctx.payload_mass_kg <= 0.0:
            return 0.0
        # The CoG is rigidly |c + d6·z| from the wrist centre, a point on the A5 axis, in every pose: if that lever
        # is short enough, no pose can exceed the limit and the path need not be sampled.
        cog_from_wrist_m = float(np.linalg.norm(np.asarray(self.ctx.payload_cog_flange_m) + np.array([0, 0, D6_M])))
        bound = self.ctx.payload_mass_kg * G_PAPER_M_S2 * cog_from_wrist_m
        if bound <= self.limits.max_a5_torque_nm:
            return bound
        q0, q1 = np.array(start), np.array(target)
        l1_deg = float(np.abs(q1 - q0).sum())
        n = max(2, int(np.ceil(l1_deg / TORQUE_STEP_DEG)) + 1)
        body = [(self.ctx.payload_mass_kg, self.ctx.payload_cog_flange_m)]
        worst = 0.0
        for s in np.linspace(0.0, 1.0, n):
            worst = max(worst, abs(float(gravity_torques_nm(q0 + s * (q1 - q0), body)[4])))
        # Between samples the links beyond A5 turn by at most the L1 joint step, which turns both the A5 axis and the
        # lever of the CoG: the torque changes by at most 2·m·g·|lever|·step. That margin covers the unsampled path.
        lever_m = D6_M + float(np.linalg.norm(self.ctx.payload_cog_flange_m))
        step_rad = math.radians(l1_deg / (n - 1))
        return worst + 2.0 * self.ctx.payload_mass_kg * G_PAPER_M_S2 * lever_m * step_rad


def _all_stmts(body: Sequence[k.Stmt]) -> Iterable[k.Stmt]:
    for s in body:
        yield s
        if isinstance(s, k.If):
            yield from _all_stmts(s.then_body)
            yield from _all_stmts(s.else_body)
        elif isinstance(s, k.For | k.While | k.Repeat | k.Loop):
            yield from _all_stmts(s.body)


_PURE = {
    "ABS": abs,
    "SQRT": math.sqrt,
    "SIN": lambda x: math.sin(math.radians(x)),
    "COS": lambda x: math.cos(math.radians(x)),
    "TAN": lambda x: math.tan(math.radians(x)),
    "ASIN": lambda x: math.degrees(math.asin(x)),
    "ACOS": lambda x: math.degrees(math.acos(x)),
    "ATAN2": lambda y, x: math.degrees(math.atan2(y, x)),
}


def _binary(op: str, a: Any, b: Any) -> Any:
    if a is TOP or b is TOP or isinstance(a, _Agg) or isinstance(b, _Agg):
        return TOP
    if op in ("==", "<>"):
        return (a == b) if op == "==" else (a != b)
    if op in ("AND", "OR", "EXOR"):
        if not (isinstance(a, bool) and isinstance(b, bool)):
            return TOP
        return (a and b) if op == "AND" else (a or b) if op == "OR" else (a != b)
    if not (_is_num(a) and _is_num(b)):
        return TOP
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        if b == 0:
            return TOP
        return int(a / b) if isinstance(a, int) and isinstance(b, int) else a / b
    if op in ("<", ">", "<=", ">="):
        return {"<": a < b, ">": a > b, "<=": a <= b, ">=": a >= b}[op]
    return TOP


def _show(value: Any) -> str:
    return "a value that is not a constant" if value is TOP else repr(value)


def _pcts(values: Sequence[float]) -> str:
    return "/".join(f"{v:g}" for v in values)


# --- entry points -----------------------------------------------------------------------------------------------------
def _mode_violation(ctx: CheckContext) -> Violation | None:
    mode = ctx.mode.strip().upper().lstrip("#")
    if mode == "T1":
        return None
    if mode == "AUT":
        if ctx.area_cleared and ctx.key_confirmed:
            return None
        missing = [
            w
            for w, ok in (
                ("the hazard area is not cleared", ctx.area_cleared),
                ("the key switch is not confirmed", ctx.key_confirmed),
            )
            if not ok
        ]
        return Violation(0, 0, "MODE", f"mode AUT refused: {' and '.join(missing)}")
    return Violation(0, 0, "MODE", f"mode {ctx.mode!r} refused: only T1 (or AUT with cleared area and key switch)")


def _forbidden_tokens(text: str, file: str) -> list[Violation]:
    found = []
    for tok in tokenize(text, file):
        if tok.kind is Tok.NAME and tok.text in FORBIDDEN_KEYWORDS:
            found.append(Violation(tok.line, tok.column, "STATEMENT", f"{tok.text} is not allowed in RGSE programs"))
    return found


def check_program(src_text: str, dat_text: str | None, ctx: CheckContext, file: str = "<program>") -> list[Violation]:
    """Every rule ``src_text`` (with its data list ``dat_text``) breaks in context ``ctx``; empty: allowed.

    Raises
    ------
    KrlSyntaxError
        The program (or data list) does not parse (and holds none of the refused keywords).
    """
    violations: list[Violation] = []
    mode = _mode_violation(ctx)
    if mode is not None:
        violations.append(mode)
    forbidden = _forbidden_tokens(src_text, file)
    if dat_text is not None:
        forbidden += _forbidden_tokens(dat_text, file)
    try:
        module = parse_src(src_text, file)
        data = parse_dat(dat_text, _dat_name(file)) if dat_text is not None else None
    except KrlSyntaxError:
        if forbidden:
            return sorted(violations + forbidden)
        raise
    violations += forbidden
    main = module.main
    if not 0.0 <= ctx.payload_mass_kg <= ctx.limits.max_payload_kg:
        violations.append(
            Violation(
                main.pos.line,
                main.pos.column,
                "PAYLOAD",
                f"payload {ctx.payload_mass_kg:g} kg outside 0..{ctx.limits.max_payload_kg:g} kg "
                "(load diagram, paper Fig. 16)",
            )
        )
    for extra in module.routines[1:]:
        violations.append(
            Violation(
                extra.pos.line,
                extra.pos.column,
                "STATEMENT",
                f"routine {extra.name}: only a module's main routine is verified",
            )
        )
    dat_consts: dict[str, Any] = {}
    checker = _Checker(ctx, set(), dat_consts)
    env_state = _State(None, (100.0,) * 6, 0.0, ())
    if data is not None:
        for decl in data.decls:
            if decl.init is not None:
                checker.check_calls(decl.init)
            for dn in decl.names:
                if decl.is_global or ctx.link_writable(dn.name):
                    continue  # the daemon (or anyone on the link) may change it: never a constant
                value = checker.eval(decl.init, env_state) if decl.init is not None and not dn.dims else TOP
                dat_consts[dn.name] = value
                env_state = env_state.with_var(dn.name, value)
    checker.own_locals.update(dn.name for s in _all_stmts(main.body) if isinstance(s, k.Decl) for dn in s.names)
    checker.own_locals.update(p.name for p in main.params)
    start = ctx.start_axes_deg
    poses: frozenset[Pose] | None = None
    if start is not None:
        q = _pose_key(start)
        if len(q) != 6 or not all(math.isfinite(v) for v in q):
            violations.append(Violation(0, 0, "START_UNKNOWN", "start pose is not six finite axis angles"))
        else:
            poses = frozenset({q})
            checker.check_target(q, k.Pos(0, 0))  # nothing was reported before: these are the start's
            checker.found = {key: replace(v, message="start pose: " + v.message) for key, v in checker.found.items()}
    state = replace(env_state, poses=poses)
    for p in main.params:
        state = state.with_var(p.name, TOP)
    try:
        checker.block(main.body, state)
    except _TooComplex:
        violations.append(
            Violation(
                main.pos.line,
                main.pos.column,
                "COMPLEXITY",
                f"more than {MAX_MOTION_CHECKS} motion checks: too complex to verify",
            )
        )
    violations += checker.found.values()
    return sorted(set(violations))


def _dat_name(file: str) -> str:
    return file[:-4] + ".dat" if file.lower().endswith(".src") else file + ".dat"


def ensure_allowed(src_text: str, dat_text: str | None, ctx: CheckContext, file: str = "<program>") -> None:
    """Raise :class:`ProgramRefused` unless :func:`check_program` finds nothing (KrlSyntaxError: does not parse)."""
    violations = check_program(src_text, dat_text, ctx, file)
    if violations:
        raise ProgramRefused(file, violations)
