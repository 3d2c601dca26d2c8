"""The interlock's static check: may this KRL program be pushed to the robot and started?

:func:`check_program` returns every rule the program breaks (empty list: allowed); :func:`ensure_allowed` raises
:class:`ProgramRefused` (an :class:`~rgse_daemon.errors.InterlockError`) listing them. The program is interpreted
abstractly by :class:`~rgse_daemon.krl.abstract.AbstractInterpreter` with the controller's KRL semantics
(:mod:`rgse_daemon.krl.evaluate`, ``docs/krl-semantics.md``); this module adds the T1 rules at each motion and write.

Rules (``Violation.rule``):

``MODE``          mode must be T1; AUT only with the hazard area cleared *and* the key switch confirmed; T2/EX never.
``SPEED``         worst-case Cartesian speed of the elbow, wrist centre, flange and every payload point over the whole
                  joint path of every PTP (``kinematics.max_point_speed_mm_s(...).bound_mm_s``, axis speeds from the
                  robot's ``max_axis_speed_deg_s`` × $VEL_AXIS % × override) ≤ ``limits.t1_speed_mm_s``.
                  The override is the larger of what the program assigns and ``ctx.override_max_pct`` (the operator
                  can raise it on the smartPAD at any time).
``JOINT_LIMIT``   every target within the axis ranges; ``A1_ENVELOPE``: |A1| ≤ ``limits.a1_range_deg``.
``START_UNKNOWN`` a motion whose start pose is unknown cannot be verified.
``TARGET``        a target that does not resolve to constant axis angles; ``CARTESIAN``: Cartesian targets (no IK);
                  ``EXTERNAL_AXIS``: a target with a non-zero E1..E6 (the cell has none; their motion is not verified).
``PAYLOAD``       payload mass ≤ ``limits.max_payload_kg``; ``A5_TORQUE``: static A5 torque of the payload along
                  every motion ≤ ``limits.max_a5_torque_nm`` (load diagram, paper Fig. 16).
``WORKSPACE``     the flange, the wrist centre, the elbow or the DuT's box (``cell.payload_box_flange_m``) leaves
                  the cell (``ctx.cell``: floor, walls) or enters a keep-out box anywhere on a PTP's joint path
                  (sampled, with a margin for the path between samples: :meth:`_Checker.workspace_violation`); names
                  the pose.
``MOTION_TIME``   the upper bound of the program's motion time (or of a FOR's passes) is above ``limits.max_motion_s``
                  (:meth:`_Checker.motion_time_s`); ``UNBOUNDED``: motions inside a loop whose passes cannot be
                  counted (a LOOP without EXIT, a WHILE/REPEAT the check cannot follow), unless every pass waits for
                  a host command (:meth:`~rgse_daemon.krl.abstract.AbstractInterpreter.paced_by_host`): then the bound
                  applies per pass (docs/security.md).
``REL_AMPLITUDE`` a relative (brake-release) move of more than ``limits.brake_release_max_deg`` on any axis.
``WRITE``         a variable written that is neither the program's own nor on the allow-list; ``SYSVAR``: a system
                  variable other than $VEL_AXIS/$ACC_AXIS/$VEL.CP/$APO/$OV_PRO and the $TRACE members the daemon
                  writes (exactly those of the allow-list); ``OV_PRO``: $OV_PRO not a
                  constant in 1..100 (0 stalls every motion);
                  ``VELOCITY``: a motion setting that is not a constant in range.
``CALL``          a subprogram or function call the check cannot see into (only pure math built-ins are allowed).
``WATCHDOG``      the controller-side watchdog (:func:`watchdog_violations`): the only interrupt allowed is the
                  watchdog's (``INTERRUPT DECL 1 WHEN $TIMER_FLAG[16] OR $TIMER_STOP[16] DO R( )`` at the top level
                  of the main routine, switched on with ``INTERRUPT ON 1``, never off), its routine ``R`` moves
                  nothing (BRAKE, HALT, assignments to RGSE_ globals, IF/WHILE of those); with
                  ``CheckContext.require_watchdog`` it must be declared, switched on and waited fresh
                  (``WAIT FOR NOT (...)``) before the first statement that holds a motion. BRAKE outside it.
``STATEMENT``     other INTERRUPT forms, TRIGGER, GOTO, SWITCH, LIN/LIN_REL (Cartesian path: unverifiable without IK),
                  approximate positioning, extra routines.
``LOOP``          a loop whose effect does not settle, a FOR whose body writes its counter or what its bounds read;
                  ``COMPLEXITY``: too much to verify (statements, motion checks, expression depth, a file above
                  :data:`MAX_PROGRAM_BYTES`, the time budget, which counts from the first byte: reading too).
``UNSURE``        the controller's result is not documented (INT overflow, a REAL rounding tie, 32-bit and 64-bit
                  REAL evaluation disagree, an uninitialised field); ``RUNTIME``: the controller would stop with an
                  error (division by zero, a type mismatch); ``LINE_END``: a line end or character whose meaning on
                  the controller is not known (lone CR, form feed), or a line longer than :data:`MAX_LINE_CHARS`
                  (whether the controller cuts it is not known); ``INTERNAL``: the check itself failed.

Any doubt refuses: the check may be stricter than the robot needs, never looser.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from rgse_daemon import robots
from rgse_daemon.config import CellConfig, Config, LimitsConfig
from rgse_daemon.errors import InterlockError, KrlSyntaxError
from rgse_daemon.kinematics import (
    G_PAPER_M_S2,
    gravity_torques_nm,
    joint_frames_path,
    max_point_speed_mm_s,
)
from rgse_daemon.krl import ast as k
from rgse_daemon.krl.abstract import (
    AbstractInterpreter,
    Outcome,
    Pose,
    State,
    TooComplex,
    all_stmts,
    pose_key,
    written_names,
)
from rgse_daemon.krl.formatter import format_expr
from rgse_daemon.krl.lexer import OutOfTime, Tok, tokenize
from rgse_daemon.krl.parser import parse_dat, parse_src
from rgse_daemon.krl.render import MIN_VEL_AXIS_PCT
from rgse_daemon.krl.values import UNKNOWN, Value, describe, is_number
from rgse_daemon.krl.walk import iter_exprs, root_name
from rgse_daemon.robots import RobotModel
from rgse_daemon.safety.allowlist import WATCHDOG_CONDITION, WATCHDOG_INTERRUPT, WRITABLE_PREFIX, WRITABLE_VARIABLES

#: Statement keywords the check refuses outright (the parser does not accept them either).
FORBIDDEN_KEYWORDS = frozenset({"TRIGGER", "GOTO", "SWITCH", "CONTINUE", "ANIN", "ANOUT"})
#: Refused outright in a data list too (in a program the WATCHDOG rule judges them).
FORBIDDEN_IN_DATA = FORBIDDEN_KEYWORDS | {"INTERRUPT", "BRAKE"}
#: Motion checks (pairs start → target) before the program is refused as too complex to verify.
MAX_MOTION_CHECKS = 20_000
#: Sampling of the joint path for the static A5 torque (deg, sum over the axes between samples).
TORQUE_STEP_DEG = 0.25
#: Sampling of the joint path for the workspace rule (deg, sum over the axes between samples); the margin that
#: covers the path between samples is computed from it (:meth:`_Checker.workspace_violation`).
WORKSPACE_STEP_DEG = 0.5
#: The smallest $OV_PRO a program may set (%): an INT, so the smallest above the renderer's 0.01 % axis speed floor
#: (0 stalls every motion; 0.4 is stored as 0).
MIN_OV_PRO_PCT = 1
#: Largest .src or .dat text the check reads (characters, ISO-8859-1: bytes). The templates' largest rendering is
#: a few kB; a bigger file is refused before it is read or parsed (a 7.8 MB program took 96 s and 1.2 GB).
MAX_PROGRAM_BYTES = 256 * 1024


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
    override that can be in force during the run (100 unless the daemon knows it is locked lower). ``robot``: the
    arm (axis ranges, axis speeds, geometry); default the active robot, the configured one.
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
    #: The controller-side watchdog must be armed before the first motion (``WATCHDOG``; the daemon's push and
    #: ``rgse krl check`` set it from ``controller.watchdog_required``).
    require_watchdog: bool = False
    #: The cell (floor, walls, keep-out boxes) the flange, wrist, elbow and payload must stay in; None: ``robot``'s
    #: default cell (``CellConfig.of_robot``).
    cell: CellConfig | None = None
    #: Well below the 60 s the daemon's push waits for the check (procedures/engine.py): the check always ends first.
    time_budget_s: float = 20.0
    robot: RobotModel = field(default_factory=robots.active)

    def link_writable(self, name: str) -> bool:
        """Whether the allow-list admits writing ``name`` (what the daemon itself may write over the link)."""
        n = name.strip().upper()
        return n in self.writable_variables or n.startswith(self.writable_prefix.upper())


class _Checker(AbstractInterpreter):
    """The T1 rules, applied at each motion and write the abstract interpreter finds."""

    def __init__(self, ctx: CheckContext, deadline: float | None = None) -> None:
        super().__init__(time_budget_s=ctx.time_budget_s)
        if deadline is not None:
            self.deadline = deadline  # the budget counts from the check's first byte (check_program)
        self.ctx = ctx
        self.limits = ctx.limits
        #: the configured limit, never above the robot's load diagram
        self.max_a5_torque_nm_limit = min(ctx.limits.max_a5_torque_nm, ctx.robot.max_a5_torque_nm)
        self.found: dict[tuple[str, int, int], Violation] = {}
        self.motion_checks = 0
        self._speed_cache: dict[tuple[Pose, Pose, tuple[float, ...]], float] = {}
        self._torque_cache: dict[tuple[Pose, Pose], float] = {}
        self._workspace_cache: dict[tuple[Pose, Pose], str | None] = {}
        self.cell = ctx.cell if ctx.cell is not None else CellConfig.of_robot(ctx.robot)
        b = self.cell.payload_box_flange_m
        corners = [(x, y, z) for x in (b.min_m[0], b.max_m[0]) for y in (b.min_m[1], b.max_m[1])
                   for z in (b.min_m[2], b.max_m[2])]
        self.box_points = np.array([(0.0, 0.0, 0.0), *corners, ctx.payload_cog_flange_m], dtype=float)
        self.points = [tuple(map(float, p)) for p in ctx.payload_points_flange_m]
        self.points.append(tuple(map(float, ctx.payload_cog_flange_m)))

    def report(self, rule: str, pos: k.Pos, message: str) -> None:
        key = (rule, pos.line, pos.column)
        if key not in self.found:
            self.found[key] = Violation(pos.line, pos.column, rule, message)

    # --- writes ------------------------------------------------------------------------------------------------------
    def writable(self, target: k.Expr, pos: k.Pos) -> bool:
        name = root_name(target)
        if name is not None and self.ctx.link_writable(name):
            return True
        what = name if name is not None else "an expression that is not a variable"
        self.report("WRITE", pos, f"write to {what}: not a variable of this program and not on the allow-list")
        return False

    def system_write(self, name: str, target: k.Expr, value: Value, st: State, pos: k.Pos) -> State:
        if name in ("$VEL_AXIS", "$ACC_AXIS"):
            idx: Value = UNKNOWN
            if isinstance(target, k.Index) and isinstance(target.base, k.Name) and len(target.indices) == 1:
                idx = self.index(target.indices[0], st, pos)
            if not (isinstance(idx, int) and not isinstance(idx, bool) and 1 <= idx <= 6):
                self.report("VELOCITY", pos, f"{name} must be set per axis with a constant index 1..6")
                idx = UNKNOWN
            # (below the renderer's smallest axis speed a motion takes hours: a stalled program, not a measurement;
            # compared as the controller's REAL holds it, so the rendered 0.01 passes)
            if not (is_number(value) and float(np.float32(MIN_VEL_AXIS_PCT)) <= value <= 100.0):  # type: ignore[operator]
                self.report("VELOCITY", pos, f"{name} must be set to a constant in [{MIN_VEL_AXIS_PCT:g}, 100] %, "
                                             f"not {_show(value)}")
                value = 100.0
            if name == "$VEL_AXIS":
                vel = list(st.vel_axis_pct)
                for i in range(6) if idx is UNKNOWN else (idx - 1,):  # type: ignore[operator]
                    vel[i] = 100.0 if idx is UNKNOWN else float(value)  # type: ignore[arg-type]
                st = replace(st, vel_axis_pct=tuple(vel))
            return _set_slowest(st, name, idx, value)
        if name == "$VEL":
            if not (isinstance(target, k.Member) and isinstance(target.base, k.Name) and target.member == "CP"):
                self.report("SYSVAR", pos, "only $VEL.CP of $VEL may be written")
            elif not (is_number(value) and 0.0 < value <= 2.0):  # type: ignore[operator]
                self.report("VELOCITY", pos, f"$VEL.CP must be a constant in (0, 2] m/s, not {_show(value)}")
            return st
        if name == "$OV_PRO":
            if not isinstance(target, k.Name):
                self.report("SYSVAR", pos, "$OV_PRO is a scalar")
                return replace(st, override_pct=100.0)
            if not (is_number(value) and MIN_OV_PRO_PCT <= value <= 100):  # type: ignore[operator]
                # (an INT: 0.4 is stored as 0, and 0 stalls every motion, as $VEL_AXIS below its floor would)
                low = is_number(value) and value < MIN_OV_PRO_PCT  # type: ignore[operator]
                self.report("OV_PRO", pos, f"$OV_PRO must be a constant in {MIN_OV_PRO_PCT}..100 %, not {_show(value)}"
                            + (" (below the smallest speed a motion is allowed: it would stall)" if low else ""))
                return replace(st, override_pct=100.0, override_min_pct=float(MIN_OV_PRO_PCT))
            return replace(st, override_pct=max(st.override_pct, float(value)),  # type: ignore[arg-type]
                           override_min_pct=float(value))  # type: ignore[arg-type]
        if name == "$APO" and isinstance(target, k.Name | k.Member):
            return st  # approximation is refused at the motions that would use it
        written = _written_text(target)
        if name == "$TRACE" and written is not None and written in self.ctx.writable_variables:
            return st
        self.report("SYSVAR", pos, f"write to system variable {written or name} is not allowed")
        return st

    def stmt(self, stmt: k.Stmt, st: State) -> Outcome:
        if isinstance(stmt, k.InterruptDecl | k.InterruptCtl | k.Brake):
            self.step(stmt.pos)
            return Outcome(st)  # judged by watchdog_violations (BRAKE and other forms refused there)
        return super().stmt(stmt, st)

    def start_unknown(self, stmt: k.Motion) -> None:
        self.report(
            "START_UNKNOWN",
            stmt.pos,
            f"{stmt.kind} from an unknown start pose: its path and speed "
            "cannot be verified (read the robot's axes before the push)",
        )

    # --- motions -----------------------------------------------------------------------------------------------------
    def motion(self, stmt: k.Motion, st: State) -> State:
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
        return super().motion(stmt, st)

    def check_relative(self, delta: Sequence[float], pos: k.Pos) -> None:
        big = [f"A{i}" for i, d in enumerate(delta, 1) if abs(d) > self.limits.brake_release_max_deg]
        if big:
            self.report(
                "REL_AMPLITUDE",
                pos,
                f"relative move of {', '.join(big)} by more than "
                f"{self.limits.brake_release_max_deg:g} deg (brake_release_max_deg)",
            )

    def check_target(self, q: Pose, pos: k.Pos) -> bool:
        ok = True
        for i, (v, (lo, hi)) in enumerate(zip(q, self.ctx.robot.axis_range_deg, strict=True), 1):
            if not lo <= v <= hi:
                self.report("JOINT_LIMIT", pos, f"A{i} target {v:g} deg outside the axis range {lo:g}..{hi:g} deg")
                ok = False
        if abs(q[0]) > self.limits.a1_range_deg:
            self.report(
                "A1_ENVELOPE", pos, f"A1 target {q[0]:g} deg outside the ±{self.limits.a1_range_deg:g} deg envelope"
            )
            ok = False
        return ok

    def check_path(self, start: Pose, target: Pose, st: State, pos: k.Pos) -> None:
        self.check_time(pos)
        self.motion_checks += 1
        if self.motion_checks > MAX_MOTION_CHECKS:
            raise TooComplex(f"more than {MAX_MOTION_CHECKS} motion checks", pos)
        if start != target:
            self.check_speed(start, target, st, pos)
        self.check_workspace(start, target, pos)
        # The load diagram applies to holding a pose as much as to moving: a motion to where the robot already is
        # still has to be within it (found by the property test: PTP {A1 0} with 611 kg at 0.5 m from the flange).
        torque = self._torque_cache.get((start, target))
        if torque is None:
            torque = self.max_a5_torque_nm(start, target)
            self._torque_cache[(start, target)] = torque
        if not torque <= self.max_a5_torque_nm_limit:
            self.report(
                "A5_TORQUE",
                pos,
                f"static A5 torque of the payload reaches {torque:.1f} Nm on this motion, "
                f"above the load diagram's {self.max_a5_torque_nm_limit:g} Nm",
            )

    def check_speed(self, start: Pose, target: Pose, st: State, pos: k.Pos) -> None:
        override = max(st.override_pct, self.ctx.override_max_pct)
        vmax = tuple(
            round(p / 100.0 * m * override / 100.0, 9)
            for p, m in zip(st.vel_axis_pct, self.ctx.robot.max_axis_speed_deg_s, strict=True)
        )
        key = (start, target, vmax)
        speed = self._speed_cache.get(key)
        if speed is None:
            speed = max_point_speed_mm_s(start, target, vmax, self.points, robot=self.ctx.robot).bound_mm_s
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
        d6_m = self.ctx.robot.dh[5].d_m
        cog_from_wrist_m = float(np.linalg.norm(np.asarray(self.ctx.payload_cog_flange_m) + np.array([0, 0, d6_m])))
        bound = self.ctx.payload_mass_kg * G_PAPER_M_S2 * cog_from_wrist_m
        if bound <= self.max_a5_torque_nm_limit:
            return bound
        q0, q1 = np.array(start), np.array(target)
        l1_deg = float(np.abs(q1 - q0).sum())
        n = max(2, int(np.ceil(l1_deg / TORQUE_STEP_DEG)) + 1)
        body = [(self.ctx.payload_mass_kg, self.ctx.payload_cog_flange_m)]
        worst = 0.0
        for s in np.linspace(0.0, 1.0, n):
            worst = max(worst, abs(float(gravity_torques_nm(q0 + s * (q1 - q0), body, robot=self.ctx.robot)[4])))
        # Between samples the links beyond A5 turn by at most the L1 joint step, which turns both the A5 axis and the
        # lever of the CoG: the torque changes by at most 2·m·g·|lever|·step. That margin covers the unsampled path.
        lever_m = d6_m + float(np.linalg.norm(self.ctx.payload_cog_flange_m))
        step_rad = math.radians(l1_deg / (n - 1))
        return worst + 2.0 * self.ctx.payload_mass_kg * G_PAPER_M_S2 * lever_m * step_rad

    # --- bounded motion ----------------------------------------------------------------------------------------------
    def motion_time_s(self, start: Pose, target: Pose, st: State) -> float:
        """Upper bound of a PTP's time: per axis the time of a trapezoid at the *smallest* speed and acceleration
        any path can have set (``$VEL_AXIS``/``$ACC_AXIS`` not set by the program: their floor, 0.01 %), at the
        program's own override (100 % unless it sets a lower $OV_PRO; the operator lowering it on the smartPAD holds
        the motion, enabling switch in hand); the synchronised PTP ends with its slowest axis. Accelerations: full
        speed within ``limits.axis_ramp_max_s`` at 100 % (KUKA publishes none; the override scales time, so the
        acceleration goes with its square)."""
        ov = max(st.override_min_pct, float(MIN_OV_PRO_PCT)) / 100.0
        floor = float(np.float32(MIN_VEL_AXIS_PCT))
        worst = 0.0
        for i, (q0, q1) in enumerate(zip(start, target, strict=True)):
            d = abs(q1 - q0)
            if d == 0.0:
                continue
            vmax = self.ctx.robot.max_axis_speed_deg_s[i]
            v = vmax * max(st.vel_axis_min_pct[i], floor) / 100.0 * ov
            a = vmax / self.limits.axis_ramp_max_s * max(st.acc_axis_min_pct[i], floor) / 100.0
            a *= ov * ov
            worst = max(worst, d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a))
        return worst

    def host_written(self, name: str) -> bool:
        return self.ctx.link_writable(name)

    def loop_motion_s(self, stmt: k.Stmt, per_pass_s: float, passes: int | None, paced: bool, exits: bool) -> float:
        if per_pass_s <= 0.0:
            return 0.0
        if passes is not None:
            total = per_pass_s * passes
            if not total <= self.limits.max_motion_s:
                self.report("MOTION_TIME", stmt.pos,
                            f"{passes} passes of up to {per_pass_s:.3g} s of motion each: up to {total:.3g} s, above "
                            f"limits.max_motion_s = {self.limits.max_motion_s:g} s")
            return total
        if paced and exits:
            return per_pass_s  # one pass per host command: bounded per command (docs/security.md)
        why = ("a LOOP without a reachable EXIT" if isinstance(stmt, k.Loop) and not exits
               else "a loop whose number of passes cannot be proven")
        self.report("UNBOUNDED", stmt.pos,
                    f"motions inside {why} (and not paced by a host command each pass): its motion time has no bound")
        return per_pass_s

    # --- workspace ---------------------------------------------------------------------------------------------------
    def check_workspace(self, start: Pose, target: Pose, pos: k.Pos) -> None:
        key = (start, target)
        if key not in self._workspace_cache:
            self._workspace_cache[key] = self.workspace_violation(start, target)
        problem = self._workspace_cache[key]
        if problem is not None:
            self.report("WORKSPACE", pos, problem)

    def workspace_violation(self, start: Pose, target: Pose) -> str | None:
        """The first place on the joint path ``start`` → ``target`` where the payload box (DuT and fixture,
        ``cell.payload_box_flange_m``), the flange, the wrist centre or the elbow leaves the cell or enters a keep-out
        box; None: none. The cell's walls and floor are half-spaces, so the box's corners decide; a keep-out box is
        tested against the rotated payload box exactly (separating axes). A touch counts: a point on the floor, a
        wall or a keep-out box's face (after the margin) is refused.

        Sampling argument: between two samples the joints turn by at most ``step`` (rad, L1), so any point moves by
        at most ``step·r`` with r its largest distance from an axis, and from the nearer sample by half that. r grows
        along the step by at most 2·step·r: every test is made with ``margin = step/2·r_max·(1 + 2·step)`` to spare,
        r_max the largest distance of a tested point from an axis origin over the samples (≥ its distance from the
        axis line)."""
        q0, q1 = np.array(start), np.array(target)
        l1 = float(np.abs(q1 - q0).sum())
        n = max(1, int(np.ceil(l1 / WORKSPACE_STEP_DEG))) + 1
        cell = self.cell
        lo = np.array(cell.walls.min_m, dtype=float)
        lo[2] = max(lo[2], cell.floor_z_m)
        hi = np.array(cell.walls.max_m, dtype=float)
        step = math.radians(l1 / (n - 1)) if n > 1 else 0.0
        box = cell.payload_box_flange_m
        b_centre = (np.array(box.min_m) + np.array(box.max_m)) / 2.0
        b_half = (np.array(box.max_m) - np.array(box.min_m)) / 2.0
        corners = self.box_points[1:9]
        samples = []
        r_max = 0.0
        qs = q0[None, :] + np.linspace(0.0, 1.0, n)[:, None] * (q1 - q0)[None, :]
        for q, frames in zip(qs, joint_frames_path(qs, robot=self.ctx.robot), strict=True):
            origins = frames[:, :3, 3]  # frame i's origin lies on axis Ai (kinematics.joint_frames)
            rot, o6 = frames[5, :3, :3], frames[5, :3, 3]
            pts = np.vstack([corners @ rot.T + o6, o6, frames[4, :3, 3], frames[2, :3, 3]])
            r_max = max(r_max, float(np.linalg.norm(pts[:, None, :] - origins[None, :, :], axis=2).max()))
            samples.append((q, rot, pts))
        margin = step / 2.0 * r_max * (1.0 + 2.0 * step)
        names = ["the payload box"] * 8 + ["the flange", "the wrist centre", "the elbow"]
        for q, rot, pts in samples:
            where = "A1..A6 = (" + ", ".join(f"{v:.1f}" for v in q) + ") deg"
            spare = f"margin {margin * 1000:.0f} mm between path samples"
            for what, p in zip(names, pts, strict=True):
                if p[2] - margin <= lo[2]:  # at the floor is at or below it: a touch is a collision
                    floor = "floor" if lo[2] == cell.floor_z_m else "cell"
                    return (f"{what} reaches z = {p[2] * 1000:.0f} mm at {where}, at or below the {floor} at "
                            f"z = {lo[2] * 1000:.0f} mm (cell.floor_z_m; {spare})")
                out = [f"{'xyz'[i]} = {v * 1000:.0f} mm" for i, v in enumerate(p)
                       if v - margin <= lo[i] or v + margin >= hi[i]]
                if out:
                    return f"{what} leaves the cell at ({', '.join(out)}) at {where} (cell.walls; {spare})"
            for j, kb in enumerate(cell.keep_out):
                k_lo, k_hi = np.array(kb.min_m) - margin, np.array(kb.max_m) + margin
                hit = next((what for what, p in zip(names[8:], pts[8:], strict=True)
                            if np.all(p >= k_lo) and np.all(p <= k_hi)), None)
                box_lo, box_hi = pts[:8].min(axis=0), pts[:8].max(axis=0)  # apart: the box is too (cheap first)
                if (hit is None and np.all(box_hi >= k_lo) and np.all(box_lo <= k_hi)
                        and _box_hits_box(pts[8] + rot @ b_centre, rot, b_half, k_lo, k_hi)):
                    hit = "the payload box"
                if hit is not None:
                    return (f"{hit} enters keep-out box {j + 1} ({_mm(kb.min_m)} .. {_mm(kb.max_m)} mm) at {where} "
                            f"(cell.keep_out; {spare})")
        return None


def _box_hits_box(centre: np.ndarray, rot: np.ndarray, half: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether a box (``centre``, axes the columns of ``rot``, half sizes ``half``) and an axis-aligned box ``lo`` ..
    ``hi`` overlap (separating axis theorem: they are apart iff some face normal or edge cross product separates)."""
    a_centre, a_half = (lo + hi) / 2.0, (hi - lo) / 2.0
    d = centre - a_centre
    axes = np.vstack([np.eye(3), rot.T, np.cross(np.eye(3)[:, None, :], rot.T[None, :, :]).reshape(9, 3)])
    for axis in axes:
        norm = float(np.linalg.norm(axis))
        if norm < 1e-9:
            continue
        u = axis / norm
        r_box = float(np.sum(half * np.abs(rot.T @ u)))
        r_aabb = float(np.sum(a_half * np.abs(u)))
        if abs(float(d @ u)) > r_box + r_aabb:
            return False
    return True


def _set_slowest(st: State, name: str, idx: Value, value: Value) -> State:
    """The smallest $VEL_AXIS/$ACC_AXIS any path can have set, after writing ``value`` (% or UNKNOWN) to axis
    ``idx`` (UNKNOWN: any axis; a refused value counts as the floor, 0)."""
    pct = float(value) if is_number(value) else 0.0  # type: ignore[arg-type]
    attr = "vel_axis_min_pct" if name == "$VEL_AXIS" else "acc_axis_min_pct"
    values = list(getattr(st, attr))
    for i in range(6):
        if idx is UNKNOWN:
            values[i] = min(values[i], pct)
        elif i == idx - 1:  # type: ignore[operator]
            values[i] = pct
    return replace(st, **{attr: tuple(values)})


def _mm(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v * 1000:.0f}" for v in p) + ")"


def _written_text(target: k.Expr) -> str | None:
    """A written system variable as the allow-list names it: ``$TRACE.MODE``, ``$TRACE.NAME[]`` (None: indexed)."""
    match target:
        case k.Name(name=n):
            return n
        case k.Member(base=base, member=m):
            inner = _written_text(base)
            return None if inner is None else f"{inner}.{m}"
        case k.Index(base=base, indices=()):
            inner = _written_text(base)
            return None if inner is None else f"{inner}[]"
    return None


def _show(value: Value) -> str:
    return "a value that is not a constant" if value is UNKNOWN else describe(value)


def _pcts(values: Sequence[float]) -> str:
    return "/".join(f"{v:g}" for v in values)


# --- the payload ------------------------------------------------------------------------------------------------------
#: Margin below the A5 torque limit for the CoG of a DuT whose CoG is not configured.
A5_TORQUE_MARGIN = 0.9


def mounted_payload(cfg: Config, dut_mass_kg: float | None = None,
                    dut_cog_flange_m: Sequence[float] | None = None) -> tuple[float, tuple[float, float, float]]:
    """Mass (kg) and CoG (flange frame, m) of what a run mounts, for the load diagram: the fixture
    (``measurement.fixture_mass_kg`` at ``properties.fixture.cog_flange_m``, the flange if not set) plus the DuT
    (``dut_mass_kg``/``dut_cog_flange_m`` if given, else ``cell.dut_mass_kg``/``cell.dut_cog_flange_m``).

    What is not configured is the worst credible: the DuT's mass the heaviest the limits allow with the fixture; its
    CoG (the whole payload's) on the flange axis as far out as the A5 torque limit allows that mass with 10 % margin in
    the measurement pose. A configured DuT heavier or farther out than that is what the load diagram check refuses."""
    fixture_kg = cfg.measurement.fixture_mass_kg
    fixture_cog = np.array(cfg.properties.fixture.cog_flange_m or (0.0, 0.0, 0.0), dtype=float)
    dut_kg = dut_mass_kg if dut_mass_kg is not None else cfg.cell.dut_mass_kg
    if dut_kg is None:
        dut_kg = max(0.0, cfg.limits.max_payload_kg - fixture_kg)
    total = fixture_kg + dut_kg
    if total <= 0.0:
        return 0.0, (0.0, 0.0, 0.0)
    cog = dut_cog_flange_m if dut_cog_flange_m is not None else cfg.cell.dut_cog_flange_m
    if cog is None:
        lever_m = A5_TORQUE_MARGIN * cfg.limits.max_a5_torque_nm / (total * G_PAPER_M_S2)
        return total, (0.0, 0.0, max(0.0, lever_m - cfg.robot_model.dh[5].d_m))
    both = (fixture_kg * fixture_cog + dut_kg * np.array(cog, dtype=float)) / total
    return total, (float(both[0]), float(both[1]), float(both[2]))


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


def _forbidden_tokens(text: str, file: str, deadline: float | None = None,
                      keywords: frozenset[str] = FORBIDDEN_KEYWORDS) -> list[Violation]:
    found = []
    for tok in tokenize(text, file, deadline):
        if tok.kind is Tok.NAME and tok.text in keywords:
            found.append(Violation(tok.line, tok.column, "STATEMENT", f"{tok.text} is not allowed in RGSE programs"))
    return found


#: Longest source or data-list line the check accepts (characters). The templates' longest is 118; how the controller
#: reads a line beyond its editor's length (cut, wrapped, refused) is not documented, and a cut line can change
#: meaning (``$VEL_AXIS[1] = 100.0 <spaces> - 99.0``).
MAX_LINE_CHARS = 250


def _size_violations(src_text: str, dat_text: str | None) -> list[Violation]:
    """A .src or .dat text above :data:`MAX_PROGRAM_BYTES`: refused before it is parsed."""
    found = []
    for what, text in (("program", src_text), ("data list", dat_text)):
        if text is not None and len(text) > MAX_PROGRAM_BYTES:
            found.append(Violation(0, 0, "COMPLEXITY", f"{what} of {len(text)} characters, above the "
                                                       f"{MAX_PROGRAM_BYTES} the check reads: too big to verify"))
    return found


def _line_end_violations(text: str) -> list[Violation]:
    """Characters whose meaning on the controller is not known: a CR not followed by LF, form feed, vertical tab,
    and other control characters, the C1 ones of ISO-8859-1 too (0x80..0x9F: NEL, U+0085, is a line end to some
    readers), and the Unicode line and paragraph separators (KRL files are ISO-8859-1 text with CR LF line ends)."""
    found = []
    for line_no, line in enumerate(text.split("\n"), 1):
        body = line[:-1] if line.endswith("\r") else line
        if len(body) > MAX_LINE_CHARS:
            found.append(Violation(line_no, MAX_LINE_CHARS + 1, "LINE_END",
                                   f"line of {len(body)} characters (limit {MAX_LINE_CHARS}): whether the controller "
                                   f"cuts it is not known, refused"))
            continue
        for col, ch in enumerate(body, 1):
            if ch == "\r" or (ord(ch) < 32 and ch != "\t") or 127 <= ord(ch) <= 159 or ch in "\u2028\u2029":
                what = "a CR without LF" if ch == "\r" else f"control character {ch!r}"
                found.append(
                    Violation(line_no, col, "LINE_END", f"{what}: how the controller reads it is not known, refused")
                )
                break
    return found


def check_program(src_text: str, dat_text: str | None, ctx: CheckContext, file: str = "<program>") -> list[Violation]:
    """Every rule ``src_text`` (with its data list ``dat_text``) breaks in context ``ctx``; empty: allowed.

    Raises
    ------
    KrlSyntaxError
        The program (or data list) does not parse (and holds none of the refused keywords).
    """
    deadline = time.monotonic() + ctx.time_budget_s  # the budget counts from the first byte: parsing too
    violations: list[Violation] = []
    mode = _mode_violation(ctx)
    if mode is not None:
        violations.append(mode)
    too_big = _size_violations(src_text, dat_text)
    if too_big:
        return sorted(violations + too_big)
    line_ends = _line_end_violations(src_text) + (_line_end_violations(dat_text) if dat_text is not None else [])
    if line_ends:
        return sorted(violations + line_ends)
    try:
        forbidden = _forbidden_tokens(src_text, file, deadline)
        if dat_text is not None:
            forbidden += _forbidden_tokens(dat_text, _dat_name(file), deadline, FORBIDDEN_IN_DATA)
        try:
            module = parse_src(src_text, file, deadline)
            data = parse_dat(dat_text, _dat_name(file), deadline) if dat_text is not None else None
        except KrlSyntaxError:
            if forbidden:
                return sorted(violations + forbidden)
            raise
    except OutOfTime as exc:
        return sorted([*violations, Violation(exc.line, 0, "COMPLEXITY",
                                              f"not read within {ctx.time_budget_s:g} s: too complex to verify")])
    violations += forbidden
    main = module.main
    # the configured limit, and never more than the robot's own load diagram (a limit set for another arm)
    max_payload_kg = min(ctx.limits.max_payload_kg, ctx.robot.max_payload_kg)
    if not 0.0 <= ctx.payload_mass_kg <= max_payload_kg:
        violations.append(
            Violation(
                main.pos.line,
                main.pos.column,
                "PAYLOAD",
                f"payload {ctx.payload_mass_kg:g} kg outside 0..{max_payload_kg:g} kg "
                f"(load diagram of the {ctx.robot.title}, paper Fig. 16)",
            )
        )
    wd_found, wd_routines = watchdog_violations(module, ctx)
    violations += wd_found
    for extra in module.routines[1:]:
        if extra.name in wd_routines:
            continue
        violations.append(
            Violation(
                extra.pos.line,
                extra.pos.column,
                "STATEMENT",
                f"routine {extra.name}: only a module's main routine is verified",
            )
        )
    checker = _Checker(ctx, deadline)
    try:
        checker.check_time(main.pos)
        checker.found.update(_start_pose(checker, ctx, violations))
        state = State(None, (100.0,) * 6, 0.0, ())
        if data is not None:
            # Data-list values are persistent: a run leaves what it wrote in the .dat, and a later run of the same
            # program (reset and started again without a new push) begins with those values, not the pushed ones.
            rewritten = written_names(main.body)
            for decl in data.decls:
                if decl.is_global or any(ctx.link_writable(dn.name) for dn in decl.names):
                    if decl.init is not None:
                        checker.check_calls(decl.init)
                    continue  # the daemon (or anyone on the link) may change it: never a constant
                state = checker.declare(decl, state)
                for dn in decl.names:
                    if dn.name in rewritten:
                        state = state.with_var(dn.name, UNKNOWN)
        checker.params = {p.name for p in main.params}
        checker.own.update(checker.params)
        state = replace(state, poses=checker.start_poses)
        end = checker.block(main.body, state)
        total_s = max((s.motion_s for s in (end.normal, *end.returns) if s is not None), default=0.0)
        if not total_s <= ctx.limits.max_motion_s:
            violations.append(Violation(main.pos.line, main.pos.column, "MOTION_TIME",
                                        f"the program's motion takes up to {total_s:.4g} s, above "
                                        f"limits.max_motion_s = {ctx.limits.max_motion_s:g} s"))
    except TooComplex as exc:
        where = exc.pos if exc.pos.line else main.pos
        violations.append(Violation(where.line, where.column, "COMPLEXITY", f"{exc}: too complex to verify"))
    except Exception as exc:  # any failure of the check is a refusal, never a crash or an allow
        violations.append(
            Violation(main.pos.line, main.pos.column, "INTERNAL", f"the check failed ({type(exc).__name__}: {exc})")
        )
    violations += checker.found.values()
    return sorted(set(violations))


# --- the controller-side watchdog ------------------------------------------------------------------------------------
def _holds_motion(stmt: k.Stmt) -> bool:
    return any(isinstance(s, k.Motion) for s in all_stmts((stmt,)))


def _has_call(exprs: Sequence[k.Expr]) -> bool:
    return any(isinstance(e, k.Call) for x in exprs for e in iter_exprs(x))


def _routine_problems(body: Sequence[k.Stmt], ctx: CheckContext) -> list[tuple[k.Pos, str]]:
    """What in an interrupt routine's body is more than stopping: only BRAKE, HALT, assignments to RGSE_ globals
    (no calls), and IF/WHILE of those."""
    found: list[tuple[k.Pos, str]] = []
    for s in body:
        match s:
            case k.Brake() | k.Halt():
                continue  # it stops: what the routine is for
            case k.Assign(target=k.Name(name=name), value=value) if ctx.link_writable(name) and not name.startswith(
                "$"
            ) and not _has_call((value,)):
                continue  # a handshake global the daemon reads (RGSE_WD_TRIP)
            case k.If(condition=c, then_body=a, else_body=b) if not _has_call((c,)):
                found += _routine_problems(a, ctx) + _routine_problems(b, ctx)
            case k.While(condition=c, body=a) if not _has_call((c,)):
                found += _routine_problems(a, ctx)
            case _:
                found.append((s.pos, f"{type(s).__name__} in an interrupt routine: it may only stop the robot "
                                     "(BRAKE, HALT, assignments to RGSE_ globals, IF/WHILE of those)"))
    return found


def watchdog_violations(module: k.Module, ctx: CheckContext) -> tuple[list[Violation], set[str]]:
    """The ``WATCHDOG`` rule (module docstring); also the names of the interrupt routines it allowed."""
    found: list[Violation] = []
    main = module.main
    routines = {r.name: r for r in module.routines[1:]}
    allowed: set[str] = set()
    top = list(main.body)
    top_ids = {id(s) for s in top}
    for s in all_stmts(main.body):
        if isinstance(s, k.InterruptDecl | k.InterruptCtl) and id(s) not in top_ids:
            found.append(Violation(s.pos.line, s.pos.column, "WATCHDOG",
                                   "INTERRUPT only at the top level of the main routine"))
        elif isinstance(s, k.Brake):
            found.append(Violation(s.pos.line, s.pos.column, "WATCHDOG",
                                   "BRAKE outside an interrupt routine (the controller stops with an error)"))
    first_motion = next((i for i, s in enumerate(top) if _holds_motion(s)), len(top))
    declared = False
    switched_on = False
    armed = False
    for s in top[:first_motion]:
        if isinstance(s, k.InterruptDecl):
            problem = None
            if not (isinstance(s.prio, k.IntLit) and s.prio.value == WATCHDOG_INTERRUPT):
                problem = f"only the watchdog's interrupt {WATCHDOG_INTERRUPT} may be declared"
            elif format_expr(s.condition) != WATCHDOG_CONDITION:
                problem = f"the watchdog's condition must be {WATCHDOG_CONDITION}"
            elif declared:
                problem = "the watchdog's interrupt is declared twice"
            elif s.args or s.routine not in routines or routines[s.routine].is_function \
                    or routines[s.routine].params:
                problem = f"{s.routine} is not a routine of this module without parameters"
            if problem is not None:
                found.append(Violation(s.pos.line, s.pos.column, "WATCHDOG", problem))
                continue
            routine = routines[s.routine]
            problems = _routine_problems(routine.body, ctx)
            if not (routine.body and isinstance(routine.body[0], k.Brake)
                    and any(isinstance(x, k.Halt) for x in all_stmts(routine.body))):
                problems.append((routine.pos, f"the watchdog's routine {routine.name} must begin with BRAKE and "
                                              "HALT: otherwise the motion goes on"))
            found += [Violation(p.line, p.column, "WATCHDOG", msg) for p, msg in problems]
            if not problems:
                allowed.add(routine.name)
            declared = True
        elif isinstance(s, k.InterruptCtl):
            if s.action == "ON" and declared and isinstance(s.prio, k.IntLit) and s.prio.value == WATCHDOG_INTERRUPT:
                switched_on = True
            else:
                found.append(Violation(s.pos.line, s.pos.column, "WATCHDOG",
                                       f"only INTERRUPT ON {WATCHDOG_INTERRUPT} after the watchdog's declaration"))
        elif isinstance(s, k.WaitFor) and switched_on and format_expr(s.condition) == f"NOT ({WATCHDOG_CONDITION})":
            armed = True
    for s in top[first_motion:]:
        if isinstance(s, k.InterruptDecl | k.InterruptCtl):
            found.append(Violation(s.pos.line, s.pos.column, "WATCHDOG",
                                   "INTERRUPT after the first motion: the watchdog is declared and switched on "
                                   "before it"))
    motion_at = top[first_motion] if first_motion < len(top) else None
    if ctx.require_watchdog and motion_at is not None and not armed:
        found.append(Violation(motion_at.pos.line, motion_at.pos.column, "WATCHDOG",
                               f"motion before the controller-side watchdog is armed: declare INTERRUPT "
                               f"{WATCHDOG_INTERRUPT} WHEN {WATCHDOG_CONDITION} with a routine that brakes and halts, "
                               f"INTERRUPT ON {WATCHDOG_INTERRUPT}, WAIT FOR NOT ({WATCHDOG_CONDITION})"))
    return found, allowed


def _start_pose(
    checker: _Checker, ctx: CheckContext, violations: list[Violation]
) -> dict[tuple[str, int, int], Violation]:
    """Set ``checker.start_poses`` from the context; the start's own violations (prefixed "start pose:")."""
    checker.start_poses = None
    if ctx.start_axes_deg is None:
        return {}
    q = pose_key(ctx.start_axes_deg)
    if len(q) != 6 or not all(math.isfinite(v) for v in q):
        violations.append(Violation(0, 0, "START_UNKNOWN", "start pose is not six finite axis angles"))
        return {}
    checker.check_target(q, k.Pos(0, 0))  # nothing was reported before: these are the start's
    if all(lo <= v <= hi for v, (lo, hi) in zip(q, ctx.robot.axis_range_deg, strict=True)):
        checker.start_poses = frozenset({q})  # (outside the axis ranges: no path from there is checked)
    found = {key: replace(v, message="start pose: " + v.message) for key, v in checker.found.items()}
    checker.found.clear()
    return found


def _dat_name(file: str) -> str:
    return file[:-4] + ".dat" if file.lower().endswith(".src") else file + ".dat"


def ensure_allowed(src_text: str, dat_text: str | None, ctx: CheckContext, file: str = "<program>") -> None:
    """Raise :class:`ProgramRefused` unless :func:`check_program` finds nothing (KrlSyntaxError: does not parse)."""
    violations = check_program(src_text, dat_text, ctx, file)
    if violations:
        raise ProgramRefused(file, violations)
