"""The calibration campaign (paper Fig. 23, Table 1) as a resumable plan.

Points: the zero point (empty MPA: the bias M_0), n = 1…10 calibration bodies (mass-based), and the torque-based
points (test adapter with the bodies on a longer lever). For each point the operator mounts the configuration and
confirms (a ``Confirm`` message, answered by CLI/MQTT ``confirm``); then ``loops`` × (brake-release move → settle →
trace → pull → archive). Each point's state is stored, so the campaign **survives a daemon restart**: started again
on the same run, it skips finished points and measures the first incomplete one anew (its earlier, partial loops are
marked ``failed`` and left out of the manifest). At the end it writes the campaign ``manifest.toml`` and fits the
calibration **by the same code as** ``rgse calibrate --campaign DIR`` (:func:`fit_campaign`), stores it and makes it
the robot's active calibration.

::

    cal = await run_calibration(engine, store, cfg, points=table1_points())             # a new campaign
    cal = await run_calibration(engine, store, cfg, points=..., run_id=interrupted_id)   # continue after a restart
"""

from __future__ import annotations

import asyncio
import math
import secrets
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from rgse_daemon import calfile, robots
from rgse_daemon import kinematics as kin
from rgse_daemon.analysis import calibration as campaign_analysis
from rgse_daemon.config import Config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.io.topics import Topics
from rgse_daemon.manifest import TORSIONAL_KIND, read_loops
from rgse_daemon.pipeline.cog import cog_poses
from rgse_daemon.pipeline.stopping import StopDecision, decide, point_loop_term_nm, point_prediction
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.directory import setup_toml, traces_toml
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.loop import LoopOutcome, collect, loop
from rgse_daemon.procedures.preconditions import PreconditionError, verify_start
from rgse_daemon.procedures.programs import (
    COG_TRACE_CONFIG_NAME,
    COG_TRACE_MODULES,
    move_to,
    render_program,
    run_checked,
    trace_config_xml,
)
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import motor_temps_k, prepare, warm_up
from rgse_daemon.robots import CalibrationLoads
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.store import LoopState, PointState, RunKind, Store
from rgse_daemon.verdict import with_status

CALIBRATION_FILE = "CAL.json"

# The calibration equipment is the robot's (rgse_daemon/robots/: ``calibration``, paper §2.4.2–2.4.3, Table 1): the
# functions below take the active robot's. These names are the default robot's (KR 500) figures, kept as aliases.
_KR500_LOADS = robots.get(robots.DEFAULT_KEY).calibration
CB_MASS_KG = _KR500_LOADS.body_mass_kg
ZERO_LEVER_A5_M = _KR500_LOADS.zero_lever_a5_m
STACK_LEVER_A5_M = _KR500_LOADS.stack_lever_a5_m
STACK_STEP_M = _KR500_LOADS.stack_step_m
TA_MASS_KG = _KR500_LOADS.adapter_mass_kg
TA_TORQUE_A5_NM = _KR500_LOADS.adapter_torque_a5_nm
TORQUE_LEVERS_A5_M = _KR500_LOADS.torque_levers_a5_m


def _loads() -> CalibrationLoads:
    return robots.active().calibration


@dataclass(frozen=True)
class CampaignPoint:
    """One load configuration: a manifest ``[[point]]`` plus what the operator mounts (``n_cb`` bodies, on the test
    adapter at ``cb_lever_a5_m`` for a torque point)."""

    kind: str
    mass_kg: float
    lever_a3_m: float
    lever_a5_m: float
    n_cb: int
    cb_lever_a5_m: float | None = None
    cb_cog_flange_m: tuple[float, float, float] | None = None
    """A torsional point: the bodies' common CoG on the torsional bracket, flange frame (m)."""
    scheme: str | None = None
    """A torsional point: the CoG scheme whose poses it is measured in (:func:`~rgse_daemon.pipeline.cog.cog_poses`)."""

    @property
    def label(self) -> str:
        if self.kind == "zero":
            return "empty MPA"
        if self.kind == "mass":
            return f"{self.n_cb} calibration bod{'y' if self.n_cb == 1 else 'ies'} on the MPA"
        if self.kind == TORSIONAL_KIND:
            if self.n_cb == 0:
                return "empty MPA (torsional bias, every CoG pose)"
            x, y, z = (1000.0 * v for v in self.cb_cog_flange_m or (0.0, 0.0, 0.0))
            return (f"torsional bracket with {self.n_cb} calibration bodies at flange x {x:.0f} mm, y {y:.0f} mm, "
                    f"z {z:.0f} mm (every CoG pose)")
        return f"test adapter with {self.n_cb} calibration bodies at {self.cb_lever_a5_m:.3f} m from A5"

    def payload(self) -> tuple[float, tuple[float, float, float]]:
        """Mass (kg) and CoG (flange frame, m) of this point's load, for the load diagram check of its pushes. A
        torsional point's bodies sit at ``cb_cog_flange_m``; the others on the flange axis, ``lever_a5_m`` in front of
        the A5 axis in the measurement pose (where the flange axis is horizontal, d6 in front of the wrist centre)."""
        if self.cb_cog_flange_m is not None:
            return self.mass_kg, self.cb_cog_flange_m
        return self.mass_kg, (0.0, 0.0, max(0.0, self.lever_a5_m - kin.D6_M))

    def spec(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> CampaignPoint:
        spec = dict(spec)
        if spec.get("cb_cog_flange_m") is not None:
            spec["cb_cog_flange_m"] = tuple(float(v) for v in spec["cb_cog_flange_m"])
        return cls(**spec)


def mass_point(n_cb: int, dr_m: float | None = None) -> CampaignPoint:
    """MPA + ``n_cb`` stacked bodies (n = 0: the zero point) of the active robot's load set; ``dr_m`` default its
    Δr."""
    c = _loads()
    dr_m = robots.active().lever_difference_m if dr_m is None else dr_m
    if n_cb == 0:
        return CampaignPoint("zero", 0.0, c.zero_lever_a5_m + dr_m, c.zero_lever_a5_m, 0)
    lever_a5 = c.stack_lever_a5_m + c.stack_step_m * n_cb
    return CampaignPoint("mass", c.body_mass_kg * n_cb, lever_a5 + dr_m, lever_a5, n_cb)


def torque_point(cb_lever_a5_m: float, n_cb: int | None = None, g_m_s2: float = kin.G_PAPER_M_S2,
                 dr_m: float | None = None) -> CampaignPoint:
    """Test adapter + ``n_cb`` bodies (default: the robot's ``torque_body_count``) at ``cb_lever_a5_m``: mass and
    effective lever of the combined load."""
    c = _loads()
    dr_m = robots.active().lever_difference_m if dr_m is None else dr_m
    n_cb = c.torque_body_count if n_cb is None else n_cb
    ta_lever_a5 = c.adapter_torque_a5_nm / (g_m_s2 * c.adapter_mass_kg)
    mass = c.adapter_mass_kg + c.body_mass_kg * n_cb
    lever_a5 = (c.adapter_mass_kg * ta_lever_a5 + c.body_mass_kg * n_cb * cb_lever_a5_m) / mass
    return CampaignPoint("torque", mass, lever_a5 + dr_m, lever_a5, n_cb, cb_lever_a5_m)


#: The torsional points (issue #14): bodies on a bracket on the MPA whose common CoG sits off the flange axis at a
#: known point (flange frame, m), so that the payload torques of A3..A6 span a DuT's in every CoG pose (interfaces
#: §2). The robot's ``calibration.torsional_points``; this name is the default robot's (an alias).
TORSIONAL_POINTS: tuple[tuple[int, tuple[float, float, float]], ...] = _KR500_LOADS.torsional_points


def torsional_point(n_cb: int, cb_cog_flange_m: Sequence[float], scheme: str = "full") -> CampaignPoint:
    """``n_cb`` bodies on the torsional bracket with their CoG at ``cb_cog_flange_m`` (n = 0: the bare MPA, the
    bias of every pose), measured in every pose of ``scheme``."""
    c = tuple(float(v) for v in cb_cog_flange_m)
    if len(c) != 3:
        raise ValueError("cb_cog_flange_m needs three coordinates (m)")
    cog_poses(kin.measurement_pose(), scheme)  # an unknown scheme is refused here, not at the robot
    mass_kg = _loads().body_mass_kg * n_cb
    return CampaignPoint(TORSIONAL_KIND, mass_kg, 0.0, 0.0, n_cb, None, c, scheme)  # type: ignore[arg-type]


def torsional_points(scheme: str = "full",
                     loads: Sequence[tuple[int, Sequence[float]]] | None = None) -> list[CampaignPoint]:
    """The bare MPA and the loaded torsional points (default: the robot's), for the CoG calibration in ``scheme``'s
    poses."""
    loads = _loads().torsional_points if loads is None else loads
    return [torsional_point(0, (0.0, 0.0, 0.0), scheme), *(torsional_point(n, c, scheme) for n, c in loads)]


def table1_points(n_bodies: Sequence[int] | None = None,
                  torque_levers_a5_m: Sequence[float] | None = None) -> list[CampaignPoint]:
    """The paper's campaign (Table 1) with the active robot's load set: zero, 1…10 bodies, three torque points; pass
    subsets for short campaigns."""
    c = _loads()
    n_bodies = range(0, c.body_count_max + 1) if n_bodies is None else n_bodies
    torque_levers_a5_m = c.torque_levers_a5_m if torque_levers_a5_m is None else torque_levers_a5_m
    pts = [mass_point(n) for n in n_bodies]
    if not any(p.kind == "zero" for p in pts):
        pts.insert(0, mass_point(0))
    return pts + [torque_point(lever) for lever in torque_levers_a5_m]


def check_points_support(points: Sequence[CampaignPoint], method: str, s: RunSettings) -> None:
    """Refuse a campaign, before its first load is asked for and before anything moves, whose points cannot give a
    ``method`` calibration (too few loaded points for the model, no torque point where the method needs one, ...):
    :class:`PreconditionError` naming the cause. Hours of mounting loads are not spent to learn it at the end."""
    mass_points = [p for p in points if p.kind != TORSIONAL_KIND]
    try:
        campaign_analysis.check_planned([p.kind for p in mass_points], [p.mass_kg for p in mass_points],
                                        [p.lever_a3_m for p in mass_points], [p.lever_a5_m for p in mass_points],
                                        method, s.g_m_s2, s.lever_difference_m)
    except DataError as exc:
        raise PreconditionError(f"refused to start: the campaign's {len(mass_points)} mass and torque points cannot "
                                f"give a {method} calibration: {exc}") from None


# --- the offline path ---------------------------------------------------------------------------------------------
def fit_campaign(directory: Path, method: str = "auto", drift_prior_per_k: float = DRIFT_PRIOR_PER_K
                 ) -> tuple[calfile.CalFile, dict[str, Any]]:
    """``rgse calibrate --campaign DIR --out DIR/CAL.json --method M --drift-prior PER_K --json`` as a function (the
    same :func:`analysis.calibration.fit_campaign`); writes CAL.json into the campaign directory."""
    doc, summary = campaign_analysis.fit_campaign(directory, method, drift_prior_per_k=drift_prior_per_k)
    calfile.write(directory / CALIBRATION_FILE, doc)
    return doc, summary


def pose_trace_name(point_index: int, session: str, pose_number: int, loop_number: int) -> str:
    """The trace of one loop of a torsional point in its ``pose_number``-th pose (1-based)."""
    return f"tor{point_index:02d}_{session}_p{pose_number:02d}_l{loop_number:02d}"


def _pose_of_trace(trace: str) -> int:
    """The 1-based pose number of a torsional point's trace (:func:`pose_trace_name`)."""
    return int(trace.rsplit("_", 2)[-2][1:])


def write_campaign_manifest(run_dir: Path, s: RunSettings, points: list[tuple[CampaignPoint, list[str]]]) -> None:
    """The campaign's manifest.toml: the mass points as ``[[point]]`` tables; the torsional points with their
    traces per pose (``[point.poses]``) and the scheme's poses (``[torsional]``, interfaces §2)."""
    lines = setup_toml(s)
    schemes = sorted({p.scheme or "full" for p, _ in points if p.kind == TORSIONAL_KIND})
    if len(schemes) > 1:
        raise DataError(f"a campaign's torsional points must share one scheme, got {schemes}")
    poses = cog_poses(s.meas_pose_deg, schemes[0]) if schemes else []
    if poses:
        lines += ["[torsional]", f'scheme = "{schemes[0]}"', ""]
        for pose in poses:
            lines += ["[[torsional.pose]]", f'name = "{pose.name}"', f"q_deg = {list(pose.q_deg)!r}", ""]
    for p, traces in points:
        if p.kind == TORSIONAL_KIND:
            lines += ["[[point]]", f'kind = "{p.kind}"', f"mass_kg = {p.mass_kg!r}",
                      f"cog_flange_m = {list(p.cb_cog_flange_m or (0.0, 0.0, 0.0))!r}", f"bodies = {p.n_cb}",
                      "[point.poses]"]
            for k, pose in enumerate(poses, 1):
                lines.append(f'"{pose.name}" = [' + ", ".join(
                    f'"{t}"' for t in traces if _pose_of_trace(t) == k) + "]")
            lines.append("")
            continue
        lines += ["[[point]]", f'kind = "{p.kind}"', f"mass_kg = {p.mass_kg!r}", f"lever_a3_m = {p.lever_a3_m!r}",
                  f"lever_a5_m = {p.lever_a5_m!r}", traces_toml(traces), ""]
    run_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(run_dir / "manifest.toml", "\n".join(lines))


def _finish(run_dir: Path, s: RunSettings, points: list[tuple[CampaignPoint, list[str]]],
            method: str) -> tuple[calfile.CalFile, dict[str, Any]]:
    write_campaign_manifest(run_dir, s, points)
    return fit_campaign(run_dir, method, s.drift_prior_per_k)


# --- the plan ---------------------------------------------------------------------------------------------------------
def reproducibility_of(cal_doc: dict[str, Any] | None) -> tuple[float, float] | None:
    """The A3/A5 reproducibility (Nm) of a calibration document: the scatter a new mounting adds, what a campaign
    point's loops are weighed against (None: no calibration, or one written before it: each point takes ``loops``)."""
    if cal_doc is None:
        return None
    try:
        u = calfile.load(cal_doc, "the active calibration").fit.uncertainty
    except DataError:
        return None
    if u is None:
        return None
    out = (u.reproducibility.rms_a3_nm, u.reproducibility.rms_a5_nm)
    return out if all(math.isfinite(v) and v > 0 for v in out) else None


def point_loop_term(run_dir: Path, traces: list[str]) -> tuple[float, float] | None:
    """The loop term (Nm, A3 and A5) of a campaign point's loops archived so far; None if they give none."""
    try:
        loops = read_loops(run_dir, tuple(traces))
        out = point_loop_term_nm([(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in loops])
    except (DataError, ValueError):
        return None
    return out if all(math.isfinite(v) for v in out) else None


def _point_decision(run: d.RunContext, s: RunSettings, outcomes: list[LoopOutcome],
                    reproducibility_nm: tuple[float, float] | None) -> Generator[m.Msg, Any, StopDecision]:
    """The stop rule for a campaign point after ``len(outcomes)`` loops (pipeline/stopping.py; share test only)."""
    rule = replace(s.stop_rule, target_U_kg=None)
    i = len(outcomes)
    analysed = [o.trace for o in outcomes if not o.pending]
    prediction = None
    if reproducibility_nm is not None and analysed and rule.min_loops <= i < rule.max_loops and not rule.fixed:
        got = yield m.Process("point loop term", point_loop_term, (run.run_dir, analysed))
        if got is not None:
            prediction = point_prediction(i, len(analysed), got, reproducibility_nm)
    return decide(rule, i, prediction)


def campaign_plan(
    run: d.RunContext,
    s: RunSettings,
    *,
    method: str = "auto",
    inputs: Callable[[], SafetyInputs] | None = None,
    reference: dict[str, Any] | None = None,
) -> m.Plan:
    """The campaign as a plan over the points recorded for the run (see the module docstring); returns the
    calibration summary (None in a dry run). ``reference``: the robot's active calibration document, if any: its
    reproducibility is what each point's loops are weighed against by the stop rule (pipeline/stopping.py)."""
    reproducibility_nm = reproducibility_of(reference)
    progress: d.CampaignProgress = yield m.ReadCampaign()
    next_index = 1 + max((lp.index for lp in progress.loops), default=0)
    session = secrets.token_hex(2)  # new trace names on every (re)start: raw files are never replaced
    prepared = False
    warnings: list[str] = []
    warm_temps: tuple[float, ...] | None = None
    n = len(progress.points)
    stops: list[dict[str, Any]] = []
    robot_s = 0.0
    decision = StopDecision(False, "")
    for rec in progress.points:
        point = CampaignPoint.from_spec(rec.spec)
        if rec.state == PointState.DONE:
            continue
        yield m.Checkpoint(f"point {rec.index}")
        yield m.Emit(Event("step", f"point {rec.index + 1}/{n}: {point.label}", step="point",
                           data={"point_index": rec.index, **point.spec()}))
        note = yield m.Confirm(f"mount {point.label} (point {rec.index + 1}/{n}) and confirm",
                               data={"point_index": rec.index, **point.spec()})
        yield d.PointStarted(rec.index, f"point {rec.index + 1}/{n} ({point.label}): {note or 'confirmed'}", note)
        yield m.Mounted(*point.payload())  # every push from here checks the load diagram with this point's load
        if not prepared:
            warnings += yield from prepare(s, inputs)
            prepared = True
        else:  # a new load was mounted: verify again, warm up again if the motors cooled, back to the pose
            snap = yield from verify_start(inputs)
            temps = motor_temps_k(snap)
            if (s.warmup_cycles > 0 and s.warmup_until_steady and temps is not None and warm_temps is not None
                    and max(w - t for w, t in zip(warm_temps, temps, strict=True)) > s.warmup_steady_k):
                snap, more = yield from warm_up(s, snap)
                warnings += more
            yield from run_checked((yield from render_program("rgse_meas_pose", s, snap)), s)
        if point.kind == TORSIONAL_KIND:
            next_index, point_robot_s = yield from _torsional_point(run, s, point, rec.index, n, next_index, session)
            robot_s += point_robot_s
            yield d.PointDone(rec.index)
            warm_temps = motor_temps_k((yield m.ReadState()))
            continue
        outcomes: list[LoopOutcome] = []
        previous: LoopOutcome | None = None
        for j in range(1, s.loops + 1):
            yield m.Checkpoint(f"point {rec.index} loop {j}")
            trace = f"cal{rec.index:02d}_{session}_l{j:02d}"
            # the pull of loop j overlaps loop j+1 (collected before the point ends)
            out = yield from loop(next_index, trace, run, s, point_index=rec.index, previous=previous, defer=True)
            previous = out
            next_index += 1
            outcomes.append(out)
            decision = yield from _point_decision(run, s, outcomes, reproducibility_nm)
            yield m.Emit(Event("loop", f"point {rec.index + 1}/{n} loop {j}/{s.loops} done"
                               + (f" ({decision.reason})" if decision.stop else ""), step="loop",
                               loop_index=j, loop_count=s.loops, data={"point_index": rec.index,
                                                                       **out.timing.to_json(), **decision.to_json()}))
            if decision.stop:
                break
        if previous is not None:
            yield from collect(previous, run, s)
        stops.append({"point_index": rec.index, "loops": len(outcomes), "stop_reason": decision.reason,
                      "robot_time_s": sum(o.timing.robot_s for o in outcomes)})
        robot_s += stops[-1]["robot_time_s"]
        yield d.PointDone(rec.index)
        warm_temps = motor_temps_k((yield m.ReadState()))  # the thermal state the point was measured in
    # every point done: the campaign directory from the recorded loops (this session's and earlier ones)
    progress = yield m.ReadCampaign()
    used = [lp for lp in progress.loops if lp.state == LoopState.ARCHIVED]
    manifest_points = [(CampaignPoint.from_spec(r.spec), [lp.trace_name for lp in used if lp.point_index == r.index])
                       for r in progress.points]
    yield m.Emit(Event("step", "fitting the calibration (offline path)", step="compute"))
    t0 = time.monotonic()
    fitted = yield m.Process("fit calibration", _finish, (run.run_dir, s, manifest_points, method))
    if fitted is None:  # dry run
        return None
    doc, summary = fitted
    used_idx = {lp.index for lp in used}
    shas = sorted({f.sha256 for f in progress.trace_files if f.loop_index in used_idx})
    # a loop the fit left out of its point is the operator's to know (the console, the report): a warning
    aside = [f"campaign point {a['point']} loop {a['loop']} set aside: {a['reason']}"
             for a in summary.get("set_aside") or ()]
    summary = with_status({
        **summary, "run_id": run.run_id, "robot": s.robot, "trace_sha256": shas, "warnings": [*warnings, *aside],
        "compute_s": time.monotonic() - t0, "points_stop": stops,
        "robot_time_s": robot_s, "robot_time_note": "loops (motion, settling, recording) of this session",
        "stop_rule": {"max_loops": s.loops, "min_loops": s.stop_rule.min_loops, "loop_share": s.stop_loop_share,
                      "reproducibility_nm": None if reproducibility_nm is None else list(reproducibility_nm)}})
    yield d.Result(summary, shas, calibration=doc.to_dict())
    n = len(summary["warnings"] or ())
    yield m.Emit(Event("result", f"{summary['status']}: calibration {doc.calibration_id} ({summary['method']}) "
                                 f"active" + (f"; {n} warning{'s' if n != 1 else ''}" if n else ""),
                       step="result", data=summary))
    return summary


def _torsional_point(run: d.RunContext, s: RunSettings, point: CampaignPoint, index: int, n: int, next_index: int,
                     session: str) -> Generator[m.Msg, Any, tuple[int, float]]:
    """A torsional point: in every pose of its scheme, approached as :func:`cog_poses` prescribes (A4/A6 from
    below), ``loops`` × (brake-release move about the pose → settle → trace of the A3–A6 drives), then back to the
    measurement pose. Returns the next loop index and the loops' robot time (s)."""
    robot_s = 0.0
    yield m.PutFile(TRACE_DIR + COG_TRACE_CONFIG_NAME, trace_config_xml(s, COG_TRACE_MODULES).encode("utf-8"))
    poses = cog_poses(s.meas_pose_deg, point.scheme or "full")
    for k, pose in enumerate(poses, 1):
        yield m.Checkpoint(f"point {index} pose {pose.name}")
        yield m.Emit(Event("step", f"point {index + 1}/{n}: CoG pose {k}/{len(poses)} ({pose.name})", step="pose",
                           data={"point_index": index, "pose": pose.name, "pose_index": k,
                                 "pose_count": len(poses), "q_deg": list(pose.q_deg)}))
        yield from move_to(pose.q_approach_deg, s)
        yield from move_to(pose.q_deg, s)
        at_pose = replace(s, meas_pose_deg=pose.q_deg)  # the brake-release move turns A3/A5 about this pose
        previous: LoopOutcome | None = None
        for j in range(1, s.loops + 1):
            trace = pose_trace_name(index, session, k, j)
            out = yield from loop(next_index, trace, run, at_pose, point_index=index,
                                  trace_config=COG_TRACE_CONFIG_NAME, previous=previous, defer=j < s.loops)
            previous = out
            robot_s += out.timing.robot_s
            next_index += 1
            yield m.Emit(Event("loop", f"point {index + 1}/{n} pose {pose.name} loop {j}/{s.loops} done",
                               step="loop", loop_index=j, loop_count=s.loops,
                               data={"point_index": index, "pose": pose.name, **out.timing.to_json()}))
    yield from move_to(s.meas_pose_deg, s)
    return next_index, robot_s


async def run_calibration(
    engine: RunEngine,
    store: Store,
    cfg: Config,
    *,
    points: Sequence[CampaignPoint] | None = None,
    settings: RunSettings | None = None,
    method: str = "auto",
    run_id: str | None = None,
    inputs: Callable[[], SafetyInputs] | None = None,
) -> dict[str, Any] | None:
    """Start a campaign over ``points`` (default: Table 1), or continue run ``run_id`` (its stored points win).

    The run's state records the end: completed, failed, aborted, or interrupted when this task is cancelled (daemon
    shutdown) — then call again with the same ``run_id`` to continue at the first incomplete point.
    """
    s = settings or RunSettings.from_config(cfg)
    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    if run_id is None:
        pts = list(points) if points is not None else table1_points()
        await asyncio.to_thread(check_points_support, pts, method, s)
        opening = d.OpenRun(RunKind.CALIBRATION, s.robot, {"settings": s.to_json(), "method": method},
                            points=tuple(p.spec() for p in pts))
    else:
        opening = d.OpenRun(RunKind.CALIBRATION, s.robot, resume_run_id=run_id)
    active = await recorder.active_calibration(s.robot)
    reference = None if active is None else active.document
    return await engine.execute(opening, lambda run: campaign_plan(run, s, method=method, inputs=inputs,
                                                                   reference=reference), recorder)
