"""The KRL programs and the trace configuration of a run, and the plan stubs that run a program checked.

Every program is rendered for the live pose (its axis speed chosen for the T1 limit) and pushed only after the
interlock's static check against the live controller state (:func:`static_checker`, run by the engine's ``Push``).
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Sequence
from typing import Any

from rgse_daemon.config import CellConfig, LimitsConfig
from rgse_daemon.errors import InterlockError, KrlSyntaxError
from rgse_daemon.krc import Snapshot
from rgse_daemon.krl.render import RenderedProgram, TemplateDefaults, cube_corners, default_params, render
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import ProgramChecker
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.static import CheckContext, ensure_allowed
from rgse_daemon.trace.config import TraceConfig, TraceModule, TraceTrigger, render_trace_config

#: Trace configuration file the daemon writes into the controller's TRACE folder.
TRACE_CONFIG_NAME = "rgse_meas.xml"
#: Modules recorded: the interpolator (pose, override) and the drives of A3 and A5 (torque, current, temperature).
TRACE_MODULES = ("KRCIpo", "NextGenDrive#3", "NextGenDrive#5")
#: The trace configuration of the CoG poses of a mass-properties run: the drives of A3 to A6 (the linear axes A3/A5
#: and the torsional axes A4/A6 that see the CoG's offsets, paper eq. 5-7).
COG_TRACE_CONFIG_NAME = "rgse_cog.xml"
COG_TRACE_MODULES = ("KRCIpo", "NextGenDrive#3", "NextGenDrive#4", "NextGenDrive#5", "NextGenDrive#6")
#: How many "allowed" verdicts the static check keeps by their exact inputs (program text and context).
CHECK_MEMO = 4
#: Opaque channel IDs requested per module (the ID-to-name mapping is not public; the drive modules record their
#: seven standard channels).
TRACE_CHANNELS = (1, 2, 3, 4, 5, 6, 7)


def program(name: str, s: RunSettings, start_deg: Sequence[float], *, cal_pose_deg: Sequence[float] | None = None,
            **extra: Any) -> RenderedProgram:
    """Render template ``name`` for this run: axis speed chosen for the T1 limit from the current pose, with every
    point within ``payload_lever_max_m`` of the flange counted (the static check re-verifies it before the push).
    ``cal_pose_deg``: the target of ``rgse_cal_pose`` (the speed is chosen for the motion to it)."""
    defaults = TemplateDefaults(
        **({"cal_pose": tuple(float(v) for v in cal_pose_deg)} if cal_pose_deg is not None else {}),
        limit_mm_s=s.speed_limit_mm_s,
        payload_points_flange_m=cube_corners(s.payload_lever_max_m),
        start_deg=tuple(float(v) for v in start_deg),
        meas_pose=s.meas_pose_deg,
        warmup_amplitude_deg=s.warmup_amplitude_deg,
        warmup_cycles=s.warmup_cycles,
        brake_angle_deg=s.brake_release_deg,
    )
    params = default_params(name, defaults)
    if extra:
        params = params.model_copy(update=extra)
    return render(name, params)



def render_program(name: str, s: RunSettings, snap: Snapshot | None) -> Generator[m.Msg, Any, RenderedProgram]:
    """:func:`program` from the current axes, rendered in a worker thread (choosing the safe axis speed is numeric
    work that must not stall the event loop, or the interlock monitor's snapshots would go stale)."""
    rendered = yield m.Compute(f"render {name}", program, (name, s, axes_of(snap, s.meas_pose_deg)),
                               timeout_s=60.0)
    return rendered


def trace_config_xml(s: RunSettings, modules: Sequence[str] = TRACE_MODULES) -> str:
    """The KUKA Trace configuration for one loop: ``trace_samples`` at ``trace_period_s``, triggered at once, of
    ``modules`` (the mass loops: A3 and A5; the CoG poses: :data:`COG_TRACE_MODULES`)."""
    rate_us = round(s.trace_period_s * 1e6)
    cfg = TraceConfig(
        time_s=s.trace_time_s,
        pretrigger_s=0.0,
        basename="rgse",
        modules=tuple(TraceModule(name, rate_us, TRACE_CHANNELS) for name in modules),
        trigger=TraceTrigger("KRCIpo", 1),
    )
    return render_trace_config(cfg)


def static_checker(
    limits: LimitsConfig, payload_lever_max_m: float, inputs: Callable[[], SafetyInputs] | None = None, *,
    require_watchdog: bool = True, payload: tuple[float, tuple[float, float, float]] = (0.0, (0.0, 0.0, 0.0)),
    cell: CellConfig | None = None,
) -> ProgramChecker:
    """The engine's ``Push`` check: the interlock's static check (:func:`~rgse_daemon.safety.static.ensure_allowed`)
    against the live context — mode, safety inputs and axes from the snapshot, every point within
    ``payload_lever_max_m`` of the flange for the speed bound, ``payload`` (mass kg, CoG in the flange frame m: what
    the run mounts, :func:`~rgse_daemon.safety.static.mounted_payload` of the config) for the load diagram, and
    ``cell`` (default: the default cell) for the workspace. The engine passes ``payload=`` to the returned check once
    a plan declared what it mounted (``m.Mounted``: a calibration point's bodies)."""
    points = tuple(tuple(p) for p in cube_corners(payload_lever_max_m))
    default_kg, default_cog = payload
    allowed: list[tuple[str, str, str | None, str]] = []  # the last verdicts "allowed", by their exact inputs

    def check(prog: m.Program, snap: Snapshot,
              payload: tuple[float, tuple[float, float, float]] | None = None) -> None:
        """``payload``: the load a plan declared mounted (``m.Mounted``), instead of the configured one."""
        mass_kg, cog = payload if payload is not None else (default_kg, default_cog)
        inp = inputs() if inputs is not None else None
        ctx = CheckContext(
            limits=limits,
            mode=snap.mode_op or "UNREADABLE",
            area_cleared=bool(inp is not None and inp.valid and inp.area_cleared and inp.estop_ok),
            key_confirmed=bool(inp is not None and inp.valid and inp.aut_permitted),
            payload_points_flange_m=points,  # type: ignore[arg-type]
            payload_mass_kg=mass_kg,
            payload_cog_flange_m=cog,
            start_axes_deg=snap.axes_deg,
            require_watchdog=require_watchdog,
            **({"cell": cell} if cell is not None else {}),
        )
        # the check is a function of the program's text and the context alone: the same program in the very same
        # context (a loop's next move, checked while the robot stood still, checked again at its push) is allowed
        # again without recomputing the path; any change of the context (an axis, the mode, an input) recomputes it
        key = (prog.name, prog.src_text, prog.dat_text, repr(ctx))
        if key in allowed:
            return
        try:
            ensure_allowed(prog.src_text, prog.dat_text, ctx, file=f"{prog.name}.src")
        except KrlSyntaxError as exc:
            raise InterlockError(f"{prog.name}.src: refused, does not parse: {exc}") from exc
        allowed.append(key)
        del allowed[:-CHECK_MEMO]

    return check



def axes_of(snap: Snapshot | None, fallback: Sequence[float]) -> tuple[float, ...]:
    if snap is None or snap.axes_deg is None:
        return tuple(fallback)
    return snap.axes_deg


def run_checked(prog: RenderedProgram, s: RunSettings) -> Generator[m.Msg, Any, float]:
    """Push (static check), select, start, wait for ``#P_END``, verify the handshake ``RGSE_DONE``; returns the robot
    time in s (start → end as the controller reported it)."""
    _, robot_s = yield from run_program(prog, s.program_timeout_s)
    yield m.VerifyDone("RGSE_DONE")
    return robot_s


def move_to(pose: Sequence[float], s: RunSettings) -> Generator[m.Msg, Any, float]:
    """PTP to ``pose`` with ``rgse_cal_pose`` (the CoG poses of the torsional campaign and of a properties run),
    rendered for the T1 limit from the live axes; the engine's ``Push`` runs the interlock's static check first, as
    for every program. Returns the robot time in s."""
    snap = yield m.ReadState()
    prog = yield m.Compute("render rgse_cal_pose", _pose_program, (s, axes_of(snap, s.meas_pose_deg), tuple(pose)),
                           timeout_s=60.0)
    return (yield from run_checked(prog, s)) or 0.0


def _pose_program(s: RunSettings, start: tuple[float, ...], pose: tuple[float, ...]) -> RenderedProgram:
    return program("rgse_cal_pose", s, start, cal_pose_deg=pose)



def run_program(program: m.Program, timeout_s: float) -> Generator[m.Msg, Any, tuple[float, float]]:
    """Push (static check first), select, start and wait for ``#P_END``. Returns (start time, robot time in s):
    the time from the start command until the controller reported the end (motion and the program's own waits)."""
    name = yield m.Push(program)
    yield m.Select(name)
    t_start = yield m.Start()
    reply = yield m.WaitProgram(frozenset({"P_END"}), timeout_s)
    waited_s = reply[1] if reply is not None else 0.0
    return (t_start or 0.0), waited_s
