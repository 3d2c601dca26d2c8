"""What the measurement run and the calibration campaign share: settings, programs, preconditions, one loop.

A *loop* (paper §2.4.4, Fig. 23/24) is: brake-release move (A3 and A5 rotate by φ' and back) → settle → trace of
``trace_samples`` at ``trace_period_s`` → pull the trace files, verify and archive them → record the loop. Its
timing is split into **robot time** (program start → ``#P_END`` as the controller reports it, the settling wait and
trace start → ``#T_END``) and **daemon overhead** (pulling, archiving, recording), both stored in the loop event.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rgse_daemon import kinematics as kin
from rgse_daemon.aio import within
from rgse_daemon.config import Config, LimitsConfig
from rgse_daemon.controller import Snapshot
from rgse_daemon.errors import InterlockError, KrlSyntaxError, RgseError
from rgse_daemon.krl.render import RenderedProgram, TemplateDefaults, cube_corners, default_params, render
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import ProgramChecker, run_program
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.retrieval import TRACE_DIR, PulledTrace
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.static import CheckContext, ensure_allowed
from rgse_daemon.store import LoopState, RunState, Store, archive_root, relative_path
from rgse_daemon.trace.config import TraceConfig, TraceModule, TraceTrigger, render_trace_config

_log = logging.getLogger(__name__)

#: Trace configuration file the daemon writes into the controller's TRACE folder.
TRACE_CONFIG_NAME = "rgse_meas.xml"
#: Modules recorded: the interpolator (pose, override) and the drives of A3 and A5 (torque, current, temperature).
TRACE_MODULES = ("KRCIpo", "NextGenDrive#3", "NextGenDrive#5")
#: Opaque channel IDs requested per module (the ID-to-name mapping is not public; the drive modules record their
#: seven standard channels).
TRACE_CHANNELS = (1, 2, 3, 4, 5, 6, 7)
#: $LOAD.M of KUKA's "unknown payload" mode, which the paper's method requires (the controller then does not
#: compensate the payload, so the torques carry it).
UNKNOWN_PAYLOAD_KG = -1.0


class PreconditionError(InterlockError):
    """The controller is not in a state in which a plan may start (mode, $LOAD, stop message, program running)."""


@dataclass(frozen=True)
class RunSettings:
    """The parameters of a run, from ``[measurement]`` of the config; tests and the demo shorten them."""

    robot: str
    loops: int
    settle_s: float
    trace_period_s: float
    trace_samples: int
    brake_release_deg: float
    warmup_cycles: int
    warmup_amplitude_deg: float
    fixture_mass_kg: float
    payload_lever_max_m: float
    speed_limit_mm_s: float
    program_timeout_s: float
    trace_timeout_s: float
    warmup_until_steady: bool = False
    warmup_steady_k: float = 1.0
    warmup_steady_window_s: float = 300.0
    warmup_max_s: float = 2400.0
    g_m_s2: float = kin.G_PAPER_M_S2
    lever_difference_m: float = kin.D4_M
    meas_pose_deg: tuple[float, ...] = tuple(float(v) for v in kin.measurement_pose())

    @classmethod
    def from_config(cls, cfg: Config, **overrides: Any) -> RunSettings:
        ms = cfg.measurement
        base = cls(
            robot=cfg.robot.name,
            loops=ms.loops,
            settle_s=ms.settle_s,
            trace_period_s=ms.trace_period_s,
            trace_samples=ms.trace_samples,
            brake_release_deg=ms.brake_release_deg,
            warmup_cycles=ms.warmup_cycles,
            warmup_amplitude_deg=ms.warmup_amplitude_deg,
            fixture_mass_kg=ms.fixture_mass_kg,
            payload_lever_max_m=ms.payload_lever_max_m,
            speed_limit_mm_s=cfg.limits.t1_speed_mm_s,
            program_timeout_s=ms.program_timeout_s,
            trace_timeout_s=ms.trace_timeout_s,
            warmup_until_steady=ms.warmup_until_steady,
            warmup_steady_k=ms.warmup_steady_k,
            warmup_steady_window_s=ms.warmup_steady_window_s,
            warmup_max_s=ms.warmup_max_s,
        )
        return replace(base, **overrides)

    @property
    def trace_time_s(self) -> float:
        return self.trace_samples * self.trace_period_s

    def to_json(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


# --- programs and trace configuration -----------------------------------------------------------------------------
def program(name: str, s: RunSettings, start_deg: Sequence[float], **extra: Any) -> RenderedProgram:
    """Render template ``name`` for this run: axis speed chosen for the T1 limit from the current pose, with every
    point within ``payload_lever_max_m`` of the flange counted (the static check re-verifies it before the push)."""
    defaults = TemplateDefaults(
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
    rendered = yield m.Process(f"render {name}", program, (name, s, axes_of(snap, s.meas_pose_deg)), timeout_s=60.0,
                               dry_run_safe=True)
    return rendered


def trace_config_xml(s: RunSettings) -> str:
    """The KUKA Trace configuration for one loop: ``trace_samples`` at ``trace_period_s``, triggered at once."""
    rate_us = round(s.trace_period_s * 1e6)
    cfg = TraceConfig(
        time_s=s.trace_time_s,
        pretrigger_s=0.0,
        basename="rgse",
        modules=tuple(TraceModule(name, rate_us, TRACE_CHANNELS) for name in TRACE_MODULES),
        trigger=TraceTrigger("KRCIpo", 1),
    )
    return render_trace_config(cfg)


def static_checker(
    limits: LimitsConfig, payload_lever_max_m: float, inputs: Callable[[], SafetyInputs] | None = None
) -> ProgramChecker:
    """The engine's ``Push`` check: the interlock's static check (:func:`~rgse_daemon.safety.static.ensure_allowed`)
    against the live context — mode, safety inputs and axes from the snapshot, every point within
    ``payload_lever_max_m`` of the flange for the speed bound. The DuT's mass is what is being measured, so the load
    diagram check gets none (0 kg); the runtime monitor's speed watcher still applies."""
    points = tuple(tuple(p) for p in cube_corners(payload_lever_max_m))

    def check(prog: m.Program, snap: Snapshot) -> None:
        inp = inputs() if inputs is not None else None
        ctx = CheckContext(
            limits=limits,
            mode=snap.mode_op or "UNREADABLE",
            area_cleared=bool(inp is not None and inp.valid and inp.area_cleared and inp.estop_ok),
            key_confirmed=bool(inp is not None and inp.valid and inp.aut_permitted),
            payload_points_flange_m=points,  # type: ignore[arg-type]
            start_axes_deg=snap.axes_deg,
        )
        try:
            ensure_allowed(prog.src_text, prog.dat_text, ctx, file=f"{prog.name}.src")
        except KrlSyntaxError as exc:
            raise InterlockError(f"{prog.name}.src: refused, does not parse: {exc}") from exc

    return check


# --- preconditions ----------------------------------------------------------------------------------------------
def check_preconditions(snap: Snapshot, inputs: SafetyInputs | None) -> str:
    """The state a run may start from (paper Fig. 24 'verify'); returns the operating mode, else
    :class:`PreconditionError` naming every problem. Unreadable means refused."""
    problems: list[str] = []
    mode = snap.mode_op
    if mode == "AUT":
        if inputs is None or not inputs.safe:
            why = "no safety inputs" if inputs is None else (inputs.reason or "area not cleared / key / E-stop")
            problems.append(f"AUT needs the area cleared, the AUT key and E-stop OK ({why})")
    elif mode != "T1":
        problems.append(f"$MODE_OP is #{mode}: the RGSE runs in T1 (or AUT with the area cleared)")
    elif inputs is not None and not (inputs.valid and inputs.estop_ok):
        problems.append("E-stop chain not OK on the safety I/O module" if inputs.valid else
                        f"E-stop state unknown: safety inputs invalid ({inputs.reason})")
    if snap.load is None:
        problems.append("$LOAD unreadable")
    elif snap.load.mass_kg != UNKNOWN_PAYLOAD_KG:
        problems.append(f"$LOAD.M is {snap.load.mass_kg:g} kg: the method needs the unknown-payload mode (-1)")
    if snap.stopmess is not False:
        problems.append("a stop message is active ($STOPMESS): acknowledge it on the smartPAD" if snap.stopmess
                        else "$STOPMESS unreadable")
    if snap.user_saf is not True:
        problems.append("operator safety ($USER_SAF) not closed or unreadable")
    if snap.pro_state1 in (None, "P_ACTIVE"):
        problems.append(f"robot interpreter is #{snap.pro_state1}: a program is running or the state is unreadable")
    if snap.trace_state != "T_END":
        problems.append(f"$TRACE.STATE is #{snap.trace_state}: a trace is active or the state is unreadable")
    if snap.axes_deg is None:
        problems.append("$AXIS_ACT unreadable")
    if problems:
        raise PreconditionError("refused to start: " + "; ".join(problems))
    assert mode is not None
    return mode


def verify_start(inputs: Callable[[], SafetyInputs] | None) -> Generator[m.Msg, Any, Snapshot | None]:
    """Read the controller and check :func:`check_preconditions`; returns the snapshot."""
    yield m.Emit(Event("step", "verifying the controller state", step="verify"))
    snap = yield m.ReadState()
    if snap is not None:
        check_preconditions(snap, inputs() if inputs is not None else None)
    return snap


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


#: The axes whose motor temperature sets the thermal state of the measurement (the measurement axes).
THERMAL_AXES = (3, 5)


def motor_temps_k(snap: Snapshot | None) -> tuple[float, ...] | None:
    """$MOT_TEMP of A3 and A5 (K), or None when the snapshot lacks one of them."""
    if snap is None:
        return None
    temps = tuple(snap.motor_temps_k[a - 1] for a in THERMAL_AXES)
    return None if any(t is None for t in temps) else tuple(float(t) for t in temps)  # type: ignore[arg-type]


@dataclass
class ThermalHistory:
    """Motor temperatures of the measurement axes against accumulated warm-up motion time."""

    samples: list[tuple[float, tuple[float, ...]]] = field(default_factory=list)

    def add(self, motion_s: float, temps_k: tuple[float, ...]) -> None:
        self.samples.append((motion_s, temps_k))

    def steady(self, window_s: float, band_k: float) -> bool:
        """True when the temperatures stayed within ``band_k`` of the latest ones over the last ``window_s`` of
        motion (and at least that much motion has been observed)."""
        if not self.samples:
            return False
        t_now, now = self.samples[-1]
        if t_now - self.samples[0][0] < window_s:
            return False
        recent = [temps for t, temps in self.samples if t_now - t <= window_s]
        recent.append(next(temps for t, temps in reversed(self.samples) if t_now - t >= window_s))
        return all(abs(a - b) <= band_k for temps in recent for a, b in zip(temps, now, strict=True))

    def describe(self) -> str:
        (_, first), (t_last, last) = self.samples[0], self.samples[-1]
        axes = ", ".join(f"A{a} {t0:.0f} -> {t1:.0f} K" for a, t0, t1 in zip(THERMAL_AXES, first, last, strict=True))
        return f"{axes} in {t_last:.0f} s of warm-up motion"


def warm_up(s: RunSettings, snap: Snapshot | None) -> Generator[m.Msg, Any, tuple[Snapshot | None, list[str]]]:
    """The warm-up (paper §2.4.4 A): one run of ``warmup_cycles`` cycles, repeated while ``warmup_until_steady``
    and the A3/A5 motor temperatures still move by more than ``warmup_steady_k`` over ``warmup_steady_window_s``
    of warm-up motion, at most ``warmup_max_s``. Returns the last snapshot and warnings for the result."""
    history = ThermalHistory()
    motion_s = 0.0
    temps = motor_temps_k(snap)
    if temps is not None:
        history.add(motion_s, temps)
    runs = 0
    while True:
        runs += 1
        yield m.Emit(Event("step", f"warm-up move, run {runs} ({s.warmup_cycles} cycles)", step="warm-up",
                           data={"run": runs, "motor_temps_k": temps}))
        ran_s = (yield from run_checked((yield from render_program("rgse_warmup", s, snap)), s)) or 0.0
        motion_s += ran_s
        snap = yield m.ReadState()
        if not s.warmup_until_steady or ran_s <= 0.0:  # one run asked for, or nothing moved (dry run)
            return snap, []
        temps = motor_temps_k(snap)
        if temps is None:
            return snap, ["warm-up: the controller does not report $MOT_TEMP of A3/A5; thermal state not verified"]
        history.add(motion_s, temps)
        if history.steady(s.warmup_steady_window_s, s.warmup_steady_k):
            _log.info("warm-up: thermal state steady after %d runs: %s", runs, history.describe())
            return snap, []
        if motion_s >= s.warmup_max_s:
            return snap, [f"warm-up: motor temperatures not steady within {s.warmup_steady_k:g} K over "
                          f"{s.warmup_steady_window_s:g} s after {s.warmup_max_s:g} s ({history.describe()}); the "
                          f"calibration's thermal state may differ"]


def prepare(s: RunSettings, inputs: Callable[[], SafetyInputs] | None) -> Generator[m.Msg, Any, list[str]]:
    """Verify, push the trace configuration, warm up (if cycles > 0) and move to the measurement pose; returns the
    warm-up's warnings."""
    snap = yield from verify_start(inputs)
    yield m.PutFile(TRACE_DIR + TRACE_CONFIG_NAME, trace_config_xml(s).encode("utf-8"))
    warnings: list[str] = []
    if s.warmup_cycles > 0:
        snap, warnings = yield from warm_up(s, snap)
    yield m.Emit(Event("step", "moving to the measurement pose", step="measurement-pose"))
    yield from run_checked((yield from render_program("rgse_meas_pose", s, snap)), s)
    return warnings


# --- one loop ----------------------------------------------------------------------------------------------
@dataclass
class LoopTiming:
    """Robot time (motion, settling, recording: what the controller takes) and daemon overhead (pull, archive,
    store), both in s."""

    motion_s: float = 0.0
    settle_s: float = 0.0
    record_s: float = 0.0
    pull_s: float = 0.0
    store_s: float = 0.0

    @property
    def robot_s(self) -> float:
        return self.motion_s + self.settle_s + self.record_s

    @property
    def overhead_s(self) -> float:
        return self.pull_s + self.store_s

    def to_json(self) -> dict[str, float]:
        return {"robot_s": self.robot_s, "overhead_s": self.overhead_s, "motion_s": self.motion_s,
                "settle_s": self.settle_s, "record_s": self.record_s, "pull_s": self.pull_s, "store_s": self.store_s}


@dataclass
class LoopOutcome:
    trace: str
    timing: LoopTiming
    sha256s: tuple[str, ...] = ()
    deleted: bool = False
    delete_note: str = ""
    files: list[str] = field(default_factory=list)


def loop(
    store: Store,
    run_id: str,
    run_dir: Path,
    archive: Path,
    index: int,
    trace: str,
    s: RunSettings,
    *,
    point_index: int | None = None,
) -> Generator[m.Msg, Any, LoopOutcome]:
    """One measurement loop (see the module docstring); records the loop and its files in the store."""
    timing = LoopTiming()
    yield m.Call("add loop", store.add_loop, (run_id, index, trace), {"point_index": point_index})
    snap = yield m.ReadState()
    brake = yield from render_program("rgse_brake_release", s, snap)
    yield m.Call("loop robot start", store.update_loop, (run_id, index), {"robot_start_utc": _now()})
    timing.motion_s = (yield from run_checked(brake, s)) or 0.0
    t0 = time.monotonic()
    yield m.Sleep(s.settle_s)
    timing.settle_s = time.monotonic() - t0
    yield m.Call("loop recording", store.update_loop, (run_id, index),
                 {"state": LoopState.RECORDING, "robot_end_utc": _now(), "record_start_utc": _now()})
    t0 = time.monotonic()
    yield m.TraceStart(trace, TRACE_CONFIG_NAME)
    yield m.TraceWait(s.trace_timeout_s)
    timing.record_s = time.monotonic() - t0
    yield m.Call("loop recorded", store.update_loop, (run_id, index),
                 {"state": LoopState.RECORDED, "record_end_utc": _now()})
    pulled: PulledTrace | None = yield m.Pull(trace, run_dir, s.trace_timeout_s)
    outcome = LoopOutcome(trace, timing)
    if pulled is None:  # dry run
        return outcome
    timing.pull_s = pulled.duration_s
    t0 = time.monotonic()
    for f in pulled.files:
        rel = relative_path(f.path, archive)
        yield m.Call("index trace file", store.add_trace_file, (run_id, rel, f.sha256, f.size),
                     {"loop_index": index})
        outcome.files.append(rel)
    yield m.Call("loop archived", store.update_loop, (run_id, index), {"state": LoopState.ARCHIVED})
    if not pulled.deleted:
        yield m.Call("note trace left", store.add_event, ("warning", "trace_left_on_controller",
                                                          f"{trace}: {pulled.delete_note}"),
                     {"run_id": run_id, "data": {"trace": trace}})
    timing.store_s = time.monotonic() - t0
    outcome.sha256s = pulled.sha256s
    outcome.deleted = pulled.deleted
    outcome.delete_note = pulled.delete_note
    return outcome


def _now() -> datetime:
    return datetime.now(UTC)


# --- manifest ----------------------------------------------------------------------------------------------
def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def setup_toml(s: RunSettings) -> list[str]:
    return ["[setup]", f"robot = {_toml_str(s.robot)}", f"g = {s.g_m_s2!r}",
            f"lever_difference_m = {s.lever_difference_m!r}", ""]


def traces_toml(traces: Sequence[str]) -> str:
    return "traces = [" + ", ".join(_toml_str(t) for t in traces) + "]"


# --- run lifecycle ----------------------------------------------------------------------------------------------
def run_directory(cfg_data_dir: Path, directory: str) -> tuple[Path, Path]:
    """(archive root, run directory) of a run."""
    archive = archive_root(cfg_data_dir)
    return archive, archive / directory


async def close_run(store: Store, run_id: str, exc: BaseException | None) -> None:
    """Record how a run ended: completed, aborted, failed (with the cause) or, when the daemon is cancelled (shut
    down), interrupted — so a campaign resumes after the restart. Bounded; a store error here is logged."""
    from rgse_daemon.procedures.engine import PlanAborted

    if exc is None:
        state, detail = RunState.COMPLETED, None
    elif isinstance(exc, asyncio.CancelledError):
        state, detail = RunState.INTERRUPTED, "daemon stopped during the run"
    elif isinstance(exc, PlanAborted):
        state, detail = RunState.ABORTED, str(exc)
    else:
        state, detail = RunState.FAILED, f"{type(exc).__name__}: {exc}"
    try:
        await asyncio.shield(within(store.set_run_state(run_id, state, detail), 10.0))
    except (TimeoutError, RgseError) as err:
        _log.error("run %s: could not record state %s: %r", run_id, state, err)
