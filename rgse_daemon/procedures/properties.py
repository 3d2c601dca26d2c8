"""The mass-properties run (issue #14) as a plan: the DuT's mass, then its centre of gravity, one step after the other.

Steps, in this order::

    prepare      verify the controller (T1 …), push the trace configuration, warm up, measurement pose
    mass         the measurement pose approached as the scheme's CoG pose ``meas`` (A4/A6 from below, as in the
                 torsional calibration), then the measurement run's loops (brake-release move → settle → trace →
                 pull, archive) under its stop rule, recorded with the CoG poses' A3..A6 trace: they are that pose's
                 loops too (:func:`shared_pose`; a scheme without it: the A3/A5 trace, no approach); when the
                 run gives the multi-pose mass, ``loops_per_pose`` of them, its visits of that lever pose, and not
                 the single pose's stop rule (:func:`visits_settings`): the single-pose figure beside it comes from
                 those visits
    cog poses    for every other pose of the scheme (:func:`~rgse_daemon.pipeline.cog.cog_poses`): PTP to its
                 approach, PTP into it, ``loops_per_pose`` × (brake-release move about the pose → settle → trace of
                 the A3..A6 drives → pull, archive); in the shared pose only the loops the mass kept fewer than
                 ``loops_per_pose``; back to the measurement pose
    compute      write the properties run directory (``manifest.toml`` with ``[measurement]`` and ``[properties]``,
                 the calibration as ``CAL.json``) and compute mass and CoG **by the same code as** ``rgse cog
                 --traces DIR --calibration DIR/CAL.json`` (:func:`~rgse_daemon.analysis.cog.compute_cog_dir`)
    inertia      only with ``inertia`` (``[properties] inertia``, the command's ``inertia``): the DuT's excitation
                 designed from that mass and CoG, the tare's after the operator took the DuT off, and the inertia by
                 the same code as ``rgse inertia`` (:mod:`rgse_daemon.procedures.inertia`)

A mass the pipeline refuses (too few loops kept, far outside the calibration: ``measurement.REFUSALS``) ends the
run with a result whose status is ``refused`` and its reason, as the measurement run's: the CoG (and the inertia)
need the mass and are not computed; the run directory still lists every loop.

Every motion is a program pushed through the engine, so the interlock's static check sees it before a byte reaches
the controller, and the runtime monitor watches it. The result is the measurement's result plus ``cog_m`` /
``U_cog_m`` (flange frame, m, k = 2), ``cog_dut_m`` / ``U_cog_dut_m`` (the DuT's frame) and the whole CoG result
under ``cog``; with the inertia also the tensor about the CoG in the DuT frame, the principal moments (ascending)
and axes, each with U (``inertia_cog_dut_kgm2``, ``principal_moments_kgm2``, … and the whole identification under
``inertia``). The run is stored as a measurement run (its config carries ``properties``); the daemon calls it a
``properties`` run.

::

    result = await run_properties(engine, store, cfg)                                  # [properties] of cfg
    result = await run_properties(engine, store, cfg, props=PropertiesSettings.from_config(cfg, scheme="paper"))
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rgse_daemon import calfile
from rgse_daemon.analysis.cog import FixtureFrame, compute_cog_dir, properties_manifest_toml
from rgse_daemon.analysis.multipose import compute_multipose_dir, predict_methods
from rgse_daemon.config import Config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.io.topics import Topics
from rgse_daemon.pipeline.cog import SCHEMES, CogPose, cog_poses
from rgse_daemon.pipeline.multipose import choose_method, lever_poses
from rgse_daemon.pipeline.stopping import StopDecision
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.directory import setup_toml, traces_toml
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.inertia import REPEATS, check_feasible, inertia_step
from rgse_daemon.procedures.loop import LoopOutcome, loop
from rgse_daemon.procedures.measurement import (
    CALIBRATION_FILE,
    REFUSALS,
    compute_mass,
    measurement_loops,
    refused_result,
    result_line,
    stop_json,
    timing_summary,
    write_measurement_dir,
)
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.programs import (
    COG_TRACE_CONFIG_NAME,
    COG_TRACE_MODULES,
    TRACE_CONFIG_NAME,
    move_to,
    trace_config_xml,
)
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import motor_temps_k, prepare
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.store import RunKind, Store
from rgse_daemon.verdict import REFUSED, with_status


@dataclass(frozen=True)
class PropertiesSettings:
    """What a properties run adds to the measurement's :class:`RunSettings`: the CoG scheme, the loops in each pose
    and the fixture frame (its mass is the run's ``fixture_mass_kg``)."""

    scheme: str
    loops_per_pose: int
    fixture_cog_flange_m: tuple[float, float, float] | None
    dut_origin_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dut_abc_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: bool = False
    """Also the inertia: DuT and tare excitation after the CoG poses (issue #15)."""
    inertia_repeats: int = REPEATS
    """Swings of each wrist axis per orientation in the excitation (``[properties] inertia_repeats``)."""
    mass_method: str = "single"
    """Where the mass comes from (``[properties] mass_method``): ``single`` (the paper's pose, eq. 21), ``multipose``
    (the lever poses of scheme ``lever``, :mod:`rgse_daemon.pipeline.multipose`; the single pose's figure beside it,
    from the measurement pose's visits: :func:`visits_settings`) or
    ``auto`` (chosen before the run by predicted U² × robot minutes, :func:`choose_mass_method`; with ``single``
    chosen the raised lever pose is not measured)."""

    @classmethod
    def from_config(cls, cfg: Config, **overrides: Any) -> PropertiesSettings:
        p = cfg.properties
        base = cls(p.scheme, p.loops_per_pose, p.fixture.cog_flange_m, p.fixture.dut_origin_flange_m,
                   p.fixture.dut_abc_deg, p.inertia, p.inertia_repeats, p.mass_method)
        return replace(base, **{k: v for k, v in overrides.items() if v is not None})

    def fixture(self, fixture_mass_kg: float) -> FixtureFrame:
        """The fixture frame; PreconditionError (naming the setting) when a fixture with mass has no CoG, or the
        values are unusable."""
        if self.scheme not in SCHEMES:
            raise PreconditionError(f"properties scheme {self.scheme!r}: use one of {', '.join(SCHEMES)}")
        if self.loops_per_pose < 1:
            raise PreconditionError(f"properties loops_per_pose {self.loops_per_pose}: must be >= 1")
        if self.mass_method not in MASS_METHODS:
            raise PreconditionError(f"properties mass_method {self.mass_method!r}: use one of "
                                    f"{', '.join(MASS_METHODS)}")
        if self.mass_method != "single" and (self.scheme != "lever" or self.loops_per_pose < 2):
            raise PreconditionError(f"properties mass_method {self.mass_method!r} needs scheme 'lever' (the lever "
                                    f"poses) and loops_per_pose >= 2 (their repeatability), got scheme "
                                    f"{self.scheme!r} with {self.loops_per_pose} loop(s) per pose")
        cog = self.fixture_cog_flange_m
        if cog is None:
            if fixture_mass_kg > 0:
                raise PreconditionError(
                    f"properties run: the fixture has {fixture_mass_kg:g} kg but no CoG: set properties.fixture."
                    f"cog_flange_m (or the command's fixture.cog_flange_m), the fixture's CoG in the flange frame (m)")
            cog = (0.0, 0.0, 0.0)
        try:
            return FixtureFrame(float(fixture_mass_kg), tuple(cog), tuple(self.dut_origin_flange_m),  # type: ignore[arg-type]
                                tuple(self.dut_abc_deg))  # type: ignore[arg-type]
        except DataError as exc:
            raise PreconditionError(f"properties run: {exc}") from None

    def to_json(self) -> dict[str, Any]:
        return {"scheme": self.scheme, "loops_per_pose": self.loops_per_pose,
                "fixture_cog_flange_m": None if self.fixture_cog_flange_m is None else list(self.fixture_cog_flange_m),
                "dut_origin_flange_m": list(self.dut_origin_flange_m), "dut_abc_deg": list(self.dut_abc_deg),
                "inertia": self.inertia, "inertia_repeats": self.inertia_repeats, "mass_method": self.mass_method}


def pose_trace_name(tag: str, pose_number: int, loop_number: int) -> str:
    """The trace of loop ``loop_number`` in the ``pose_number``-th CoG pose (1-based)."""
    return f"cog_{tag}_p{pose_number:02d}_l{loop_number:02d}"


def write_properties_dir(run_dir: Path, s: RunSettings, mass_traces: Sequence[str], scheme: str,
                         fixture: FixtureFrame, poses: Sequence[tuple[CogPose, Sequence[str]]],
                         cal_doc: dict[str, Any], shared: str | None = None) -> None:
    """The properties run directory (interfaces §2): ``[setup]``, the mass loops as ``[measurement]``, the CoG
    poses as ``[properties]`` (:func:`~rgse_daemon.analysis.cog.properties_manifest_toml`), and ``CAL.json``.
    ``shared``: the pose the mass loops were recorded in, whose traces may list them (a pose without traces is
    left out: no loop of it is usable)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    lines = [*setup_toml(s), "[measurement]", f"fixture_mass_kg = {float(s.fixture_mass_kg)!r}",
             traces_toml(mass_traces), ""]
    text = "\n".join(lines) + "\n" + properties_manifest_toml(
        scheme, fixture, [(p.name, p.q_deg, traces) for p, traces in poses if traces], shared_pose=shared)
    write_atomic(run_dir / "manifest.toml", text)
    write_atomic(run_dir / CALIBRATION_FILE, json.dumps(cal_doc, indent=2) + "\n")


def compute_properties(run_dir: Path, mass_method: str = "single",
                       robot_time_s: Mapping[str, float] | None = None,
                       single: dict[str, Any] | None = None,
                       drift_prior_per_k: float = DRIFT_PRIOR_PER_K) -> dict[str, Any]:
    """Mass and CoG of a properties run directory, as ``rgse mass`` and ``rgse cog`` compute them from its files;
    the mass by ``mass_method`` (:class:`PropertiesSettings`), ``robot_time_s``: the robot seconds each method's
    loops took (``single``, ``multipose``) for ``auto``; ``single``: the single pose's mass of this directory if
    already computed (:func:`~rgse_daemon.procedures.measurement.compute_mass`), else computed with
    ``drift_prior_per_k`` (``measurement.drift_prior_per_k``)."""
    cal = run_dir / CALIBRATION_FILE
    mass = {**_chosen_mass(run_dir, single or compute_mass(run_dir, cal, drift_prior_per_k=drift_prior_per_k),
                           mass_method, robot_time_s or {}, drift_prior_per_k),
            "mass_method_requested": mass_method}  # what was asked for: the surfaces say when auto chose
    cog = compute_cog_dir(run_dir, cal, mass_kg=mass["mass_kg"], u_mass_kg=mass["u_kg"])
    c = cog.to_json()
    return {**mass, "cog_m": c["cog_flange_m"], "U_cog_m": c["U_cog_flange_m"], "cog_dut_m": c["cog_dut_m"],
            "U_cog_dut_m": c["U_cog_dut_m"], "cog": c,
            # (a trace-period warning is the mass loops' and the poses' alike: said once)
            "warnings": list(dict.fromkeys([*mass.get("warnings", []), *cog.warnings]))}


#: The mass methods of a properties run (``[properties] mass_method``).
MASS_METHODS = ("single", "multipose", "auto")


def _chosen_mass(run_dir: Path, single: dict[str, Any], mass_method: str, robot_time_s: Mapping[str, float],
                 drift_prior_per_k: float = DRIFT_PRIOR_PER_K) -> dict[str, Any]:
    """The mass result of ``mass_method``: the single pose's as it is, or with the multi-pose mass's figures in its
    place; both under ``mass_methods`` (each with its robot time), which one under ``mass_method``."""
    methods: dict[str, Any] = {"single": {"mass_kg": single["mass_kg"], "U_kg": single["U_kg"],
                                          "u_components_kg": single["u_components_kg"],
                                          "robot_time_s": robot_time_s.get("single")}}
    if mass_method == "single":
        return {**single, "mass_method": "single", "mass_methods": methods}
    try:
        multi = compute_multipose_dir(run_dir, run_dir / CALIBRATION_FILE, drift_prior_per_k=drift_prior_per_k)
    except DataError as exc:
        if mass_method == "multipose":
            raise
        return {**single, "mass_method": "single", "mass_methods": methods,
                "warnings": [*single["warnings"], f"multi-pose mass not available ({exc}): the single pose's used"]}
    mj = multi.to_json()
    methods["multipose"] = {"mass_kg": mj["mass_kg"], "U_kg": mj["U_kg"], "u_components_kg": mj["budget_kg"],
                            "robot_time_s": robot_time_s.get("multipose"), "visits": mj["visits"],
                            "thermal": mj["thermal"], "drift_prior_per_k": drift_prior_per_k}
    chosen = mass_method
    if mass_method == "auto":
        chosen = choose_method({k: (v["U_kg"], max(float(v["robot_time_s"] or 0.0), 1.0) / 60.0)
                                for k, v in methods.items()})
    if chosen == "single":
        return {**single, "mass_method": "single", "mass_methods": methods}
    return {**single, "mass_kg": mj["mass_kg"], "u_kg": mj["u_kg"], "U_kg": mj["U_kg"],
            "gross_mass_kg": mj["gross_mass_kg"], "u_components_kg": mj["budget_kg"], "mass_method": "multipose",
            "mass_methods": methods, "warnings": [*single["warnings"], *(f"multi-pose: {w}" for w in multi.warnings)]}


def choose_mass_method(cal_doc: dict[str, Any], s: RunSettings, p: PropertiesSettings,
                       motor_temp_a3_k: float | None = None) -> dict[str, Any]:
    """``auto``'s choice before the run (:func:`choose_method` on :func:`predict_methods`): the predicted U and robot
    minutes of each method from CAL.json, the stop rule's loops for the single pose, ``loops_per_pose`` in each lever
    pose for the multi-pose mass, its thermal term for visits at ``motor_temp_a3_k`` (A3 now, K) under
    ``measurement.drift_prior_per_k``. Where the multi-pose mass cannot be predicted, the single pose, with the
    reason."""
    rule = s.stop_rule
    single_loops = rule.min_loops if (rule.loop_share > 0 or rule.target_U_kg is not None) else rule.max_loops
    loop_s = s.trace_time_s + s.settle_s * s.time_scale  # the same kind of loop in every pose
    try:
        predicted = predict_methods(calfile.load(cal_doc, "the active calibration"), s.meas_pose_deg, single_loops,
                                    p.loops_per_pose, loop_s, motor_temp_a3_k=motor_temp_a3_k,
                                    drift_prior_per_k=s.drift_prior_per_k)
    except DataError as exc:
        return {"method": "single", "predicted": {}, "reason": f"the multi-pose mass cannot be predicted ({exc})"}
    method = choose_method({k: (v["U_kg"], v["robot_min"]) for k, v in predicted.items()})
    text = ", ".join(f"{k} U {v['U_kg']:.2f} kg in {v['loops']} loops" for k, v in predicted.items())
    thermal = predicted.get("multipose", {}).get("thermal")
    return {"method": method, "predicted": predicted,
            "reason": f"least predicted U² × robot time ({text}; k = 2)"
                      + (f"; the multi-pose mass's thermal drift: {thermal}" if thermal else "")}


def _finish(run_dir: Path, s: RunSettings, mass_traces: list[str], scheme: str, fixture: FixtureFrame,
            poses: list[tuple[CogPose, list[str]]], cal_doc: dict[str, Any], mass_method: str = "single",
            robot_time_s: Mapping[str, float] | None = None, shared: str | None = None) -> dict[str, Any]:
    """The run directory and its result: the mass of the mass loops first; the pose ``shared`` (the mass loops were
    recorded in it) keeps of them the loops the mass kept (a loop the integrity check set aside as disturbed is
    not read for the CoG either); then the CoG. A refused mass: the refusal, the CoG not computed."""
    write_measurement_dir(run_dir, s, mass_traces, cal_doc)
    try:
        single: dict[str, Any] | None = compute_mass(run_dir, run_dir / CALIBRATION_FILE,
                                                     drift_prior_per_k=s.drift_prior_per_k)
        refusal: DataError | None = None
        kept = set(single["loops_used"]) if single is not None else set(mass_traces)
    except REFUSALS as exc:
        single, refusal = None, exc
        kept = set(getattr(exc, "used", mass_traces))
    poses = [(p, [t for t in traces if t in kept or t not in mass_traces] if p.name == shared else traces)
             for p, traces in poses]
    write_properties_dir(run_dir, s, mass_traces, scheme, fixture, poses, cal_doc, shared)
    listing = {"mass_traces": list(mass_traces),
               "cog_poses": [{"name": p.name, "q_deg": list(p.q_deg), "traces": list(t)} for p, t in poses]}
    if refusal is not None:
        refused = refused_result(refusal, cal_doc)
        return {**refused, "reason": f"{refused['reason']}; the CoG is not computed: it needs the DuT's mass",
                **listing}
    return {**compute_properties(run_dir, mass_method, robot_time_s, single, s.drift_prior_per_k), **listing}


def shared_pose(s: RunSettings, scheme: str) -> CogPose | None:
    """The CoG pose the mass loops are recorded in, when ``scheme`` has it: ``meas``, whose axes are the
    measurement pose's (checked, not assumed). Approached as every CoG pose is (A4/A6 from below) and traced with
    A3..A6, the mass loops are then that pose's loops exactly as :func:`cog_step` would record them: the same
    axes, the same brake-release move about them, the same load, the same trace. (The A4/A6 approach cannot move
    the mass: a joint's friction is held in that joint, and the static A3/A5 torques are the gravity moments of
    what lies beyond them.)"""
    for pose in cog_poses(s.meas_pose_deg, scheme):
        if pose.name == "meas" and pose.q_approach_deg and max(
                abs(a - b) for a, b in zip(pose.q_deg, s.meas_pose_deg, strict=True)) <= 1e-9:
            return pose
    return None


def visits_settings(s: RunSettings, p: PropertiesSettings) -> RunSettings:
    """The run settings of the mass loops when the run gives the multi-pose mass: ``loops_per_pose`` loops in the
    measurement pose, as in every other lever pose (the prediction auto chose by counted these, ``predict_methods``).
    They still go through :func:`~rgse_daemon.procedures.measurement.measurement_loops`: each loop is screened when
    archived (samples missing: the step and loop-to-loop checks need three loops, so at two the visits' F test of
    the multi-pose mass guards them, as it guards the raised pose's) and a loop set aside is replaced (at most
    ``replacement_loops``); the stop rule then stops at ``max loops`` = ``loops_per_pose``."""
    return replace(s, loops=p.loops_per_pose)


def _single_from_visits(result: dict[str, Any], loops: int) -> dict[str, Any]:
    """The result of a run that gave the multi-pose mass: its single-pose figure comes from the multi-pose mass's
    visits of the measurement pose, not from loops of its own under its stop rule; said beside it."""
    methods = result.get("mass_methods")
    if not isinstance(methods, Mapping) or not isinstance(methods.get("single"), Mapping):
        return result
    note = (f"from the {loops} visit(s) of the multi-pose mass in the measurement pose: no loops of its own (its stop "
            f"rule's at least three were not spent)")
    return {**result, "mass_methods": {**methods, "single": {**methods["single"], "loops": loops,
                                                             "loops_from": "multipose visits", "note": note}}}


# --- the steps ----------------------------------------------------------------------------------------------------
def mass_step(run: d.RunContext, s: RunSettings, tag: str, first_index: int, cal_doc: dict[str, Any] | None = None,
              trace_config: str = TRACE_CONFIG_NAME
              ) -> Generator[m.Msg, Any, tuple[list[LoopOutcome], StopDecision]]:
    """The mass loops in the measurement pose (as the measurement run's, under the same stop rule), recorded with
    ``trace_config``."""
    return (yield from measurement_loops(run, s, cal_doc, lambda i: f"dut_{tag}_l{i:02d}", first_index,
                                         event_data={"phase": "mass"}, label="mass loop", trace_config=trace_config))


def cog_step(run: d.RunContext, s: RunSettings, p: PropertiesSettings, tag: str, first_index: int,
             shared: CogPose | None = None, shared_loops: int = 0
             ) -> Generator[m.Msg, Any, tuple[list[tuple[CogPose, list[str]]], list[LoopOutcome]]]:
    """The CoG poses: every pose of the scheme, approached as :func:`cog_poses` prescribes, ``loops_per_pose``
    loops each with the A3..A6 trace; then back to the measurement pose. ``shared``: the pose the mass loops were
    just recorded in (the robot stands in it, the A3..A6 trace configuration is on the controller): only
    ``shared_loops`` more loops there, without a move."""
    if shared is None:
        yield m.PutFile(TRACE_DIR + COG_TRACE_CONFIG_NAME, trace_config_xml(s, COG_TRACE_MODULES).encode("utf-8"))
    poses = cog_poses(s.meas_pose_deg, p.scheme)
    index = first_index
    measured: list[tuple[CogPose, list[str]]] = []
    outcomes: list[LoopOutcome] = []
    for k, pose in enumerate(poses, 1):
        in_shared = shared is not None and pose.name == shared.name
        n = shared_loops if in_shared else p.loops_per_pose
        if n == 0:
            measured.append((pose, []))
            continue
        yield m.Checkpoint(f"CoG pose {pose.name}")
        yield m.Emit(Event("step", f"CoG pose {k}/{len(poses)} ({pose.name})"
                           + (f": {n} loop(s) beyond the mass loops" if in_shared else ""), step="pose",
                           data={"phase": "cog", "pose": pose.name, "pose_index": k, "pose_count": len(poses),
                                 "q_deg": list(pose.q_deg)}))
        if not in_shared:
            yield from move_to(pose.q_approach_deg, s)
            yield from move_to(pose.q_deg, s)
        at_pose = replace(s, meas_pose_deg=pose.q_deg)  # the brake-release move turns A3/A5 about this pose
        traces = []
        previous: LoopOutcome | None = None
        for j in range(1, n + 1):
            yield m.Checkpoint(f"CoG pose {pose.name} loop {j}")
            out = yield from loop(index, pose_trace_name(tag, k, j), run, at_pose, trace_config=COG_TRACE_CONFIG_NAME,
                                  previous=previous, defer=j < n)  # a pull overlaps the pose's next loop
            previous = out
            index += 1
            outcomes.append(out)
            traces.append(out.trace)
            yield m.Emit(Event("loop", f"CoG pose {pose.name} loop {j}/{n} done", step="loop", loop_index=j,
                               loop_count=n, data={"phase": "cog", "pose": pose.name, "pose_index": k,
                                                   "pose_count": len(poses), **out.timing.to_json()}))
        measured.append((pose, traces))
    yield from move_to(s.meas_pose_deg, s)
    return measured, outcomes


def properties_plan(
    run: d.RunContext,
    s: RunSettings,
    p: PropertiesSettings,
    cal_doc: dict[str, Any],
    *,
    inputs: Callable[[], SafetyInputs] | None = None,
) -> m.Plan:
    """The properties run as a plan (see the module docstring); returns the result (None in a dry run)."""
    fixture = p.fixture(s.fixture_mass_kg)
    warnings = yield from prepare(s, inputs)
    tag = run.run_id.rsplit("-", 1)[-1][:8].lower()
    mass_method, choice = p.mass_method, None
    if p.mass_method == "auto":  # chosen by prediction before anything moves: only its poses are measured
        # the A3 motor temperature the visits will start from (after the warm-up): the multi-pose mass's thermal term
        temps = motor_temps_k((yield m.ReadState()))
        choice = choose_mass_method(cal_doc, s, p, None if temps is None else temps[0])
        mass_method = choice["method"]
        if mass_method == "single":  # the CoG from the paper's poses: the raised lever pose is not measured
            p = replace(p, scheme="paper")
        yield m.Emit(Event("log", f"mass method {mass_method}: {choice['reason']}", step="mass",
                           data={"phase": "mass", "mass_choice": choice}))
    shared = shared_pose(s, p.scheme)
    # the multi-pose mass chosen (by auto before the run, or by the lab): the measurement pose is one of its lever
    # poses and gets what every lever pose gets, ``loops_per_pose`` visits; the single pose's stop rule (at least
    # three loops, up to ``loops``) would spend robot time on a mass the run does not give (:func:`visits_settings`)
    mass_s = visits_settings(s, p) if mass_method == "multipose" and shared is not None else s
    if shared is None:
        yield m.Emit(Event("step", f"mass: {s.loops} loops in the measurement pose", step="mass",
                           data={"phase": "mass", "loops": s.loops}))
        mass_loops, decision = yield from mass_step(run, s, tag, 1, cal_doc)
        more = 0
    else:  # the mass loops are the shared pose's loops too: approached and traced as that pose
        text = (f"{mass_s.loops} loops in the measurement pose" if mass_s is s else
                f"{mass_s.loops} visits of the multi-pose mass in the measurement pose (loops_per_pose; the single "
                f"pose's own stop rule is not spent, its figure comes from these visits)")
        yield m.Emit(Event("step", f"mass: {text}, approached and traced (A3..A6) as CoG pose {shared.name}, whose "
                                   f"loops they are too", step="mass",
                           data={"phase": "mass", "loops": mass_s.loops, "pose": shared.name}))
        yield m.PutFile(TRACE_DIR + COG_TRACE_CONFIG_NAME, trace_config_xml(s, COG_TRACE_MODULES).encode("utf-8"))
        yield from move_to(shared.q_approach_deg, s)
        yield from move_to(shared.q_deg, s)
        mass_loops, decision = yield from mass_step(run, mass_s, tag, 1, cal_doc, COG_TRACE_CONFIG_NAME)
        more = max(0, p.loops_per_pose - (len(mass_loops) if decision.kept is None else decision.kept))
    yield m.Emit(Event("step", f"CoG: {len(cog_poses(s.meas_pose_deg, p.scheme))} poses ({p.scheme}) x "
                               f"{p.loops_per_pose} loops", step="cog", data={"phase": "cog", "scheme": p.scheme}))
    poses, pose_loops = yield from cog_step(run, s, p, tag, 1 + len(mass_loops), shared, more)
    if shared is not None:
        poses = [(q, [*(o.trace for o in mass_loops), *t] if q.name == shared.name else t) for q, t in poses]
    yield m.Emit(Event("step", "computing mass and CoG (offline path)", step="compute"))
    t0 = time.monotonic()
    lever = {t for pose, traces in poses or [] if pose.name == "meas" or pose.name.startswith("A3") for t in traces}
    robot_s = {"single": sum(o.timing.robot_s for o in mass_loops),
               "multipose": sum(o.timing.robot_s for o in [*mass_loops, *pose_loops] if o.trace in lever)}
    result = yield m.Process("compute mass and CoG", _finish,
                             (run.run_dir, s, [o.trace for o in mass_loops], p.scheme, fixture, poses, cal_doc,
                              mass_method, robot_s, None if shared is None else shared.name))
    if result is not None and choice is not None:  # auto chose before the run: what was asked for, and why
        result = {**result, "mass_choice": choice, "mass_method_requested": "auto"}
    if result is not None and mass_s is not s:
        result = _single_from_visits(result, len(mass_loops))
    compute_s = time.monotonic() - t0
    inertia_loops: list[LoopOutcome] = []
    refused = result is not None and result.get("status") == REFUSED
    if p.inertia and not refused:  # (the excitation is designed from the mass and CoG)
        yield m.Emit(Event("step", "inertia: DuT and tare excitation", step="inertia-start",
                           data={"phase": "inertia"}))
        inertia, inertia_loops = yield from inertia_step(run, s, fixture, p.dut_abc_deg, result, tag,
                                                         1 + len(mass_loops) + len(pose_loops), inputs,
                                                         repeats=p.inertia_repeats)
        if result is not None and inertia is not None:
            compute_s += float(inertia["inertia"]["compute_s"])
            result = {**result, **inertia,
                      "warnings": [*result.get("warnings", []),
                                   *(f"inertia: {w}" for w in inertia["inertia"].get("warnings", []))]}
    if result is None:  # dry run
        return None
    outcomes = [*mass_loops, *pose_loops, *inertia_loops]
    shas = sorted({h for o in outcomes for h in o.sha256s})
    result = {
        **result,
        "run_id": run.run_id,
        "robot": s.robot,
        "run_kind": RunKind.PROPERTIES.value,
        "trace_sha256": shas,
        "warnings": [*result.get("warnings", []), *(warnings or [])],
        "controller_copies_deleted": all(o.deleted for o in outcomes),
        "stop_reason": decision.reason,
        "stop_rule": stop_json(mass_s, decision),
        "timing": {**timing_summary(outcomes, compute_s),
                   "mass_robot_time_s": sum(o.timing.robot_s for o in mass_loops),
                   "cog_robot_time_s": sum(o.timing.robot_s for o in pose_loops),
                   "inertia_robot_time_s": sum(o.timing.robot_s for o in inertia_loops)},
        **({"identity": s.identity} if s.identity else {}),
    }
    result = with_status(result)
    yield d.Result(result, shas)
    for w in result["warnings"]:  # e.g. payload torques beyond what the torsional calibration covered
        yield m.Emit(Event("log", f"warning: {w}", step="result", data={"warning": w}))
    if refused:
        yield m.Emit(Event("result", result_line(result, str(result["reason"])), step="result", data=result))
        return result
    mm = [1000.0 * v for v in result["cog_m"]]
    umm = [1000.0 * v for v in result["U_cog_m"]]
    yield m.Emit(Event("result", result_line(result, f"mass {result['mass_kg']:.3f} kg ± {result['U_kg']:.3f} kg, "
                                                     f"CoG (flange) x {mm[0]:.1f} ± {umm[0]:.1f}, y {mm[1]:.1f} ± "
                                                     f"{umm[1]:.1f}, z {mm[2]:.1f} ± {umm[2]:.1f} mm (k = 2)"
                                                     + _inertia_text(result)), step="result", data=result))
    return result


def _inertia_text(result: dict[str, Any]) -> str:
    if "principal_moments_kgm2" not in result:
        return ""
    pm = ", ".join(f"{v:.3f} ± {u:.3f}" for v, u in zip(result["principal_moments_kgm2"],
                                                       result["U_principal_moments_kgm2"], strict=True))
    return f", principal moments {pm} kg·m² (k = 2)"


async def run_properties(
    engine: RunEngine,
    store: Store,
    cfg: Config,
    *,
    settings: RunSettings | None = None,
    props: PropertiesSettings | None = None,
    inputs: Callable[[], SafetyInputs] | None = None,
) -> dict[str, Any] | None:
    """Execute :func:`properties_plan` on ``engine`` as a recorded run (:meth:`RunEngine.execute`).

    Refused (PreconditionError, before anything moves or is stored) without an active calibration for this robot,
    when that calibration has no torsional section (no CoG calibration), or with an unusable fixture frame."""
    s = settings or RunSettings.from_config(cfg)
    p = props or PropertiesSettings.from_config(cfg)
    fixture = p.fixture(s.fixture_mass_kg)  # refuse a bad fixture before the run opens
    cog_poses(s.meas_pose_deg, p.scheme)
    if p.mass_method != "single":  # a robot without lever poses (robots/<model>.py multipose_a3_deg)
        try:
            lever_poses(s.meas_pose_deg)
        except DataError as exc:
            raise PreconditionError(f"properties mass_method {p.mass_method!r}: {exc}") from None
    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    cal = await recorder.active_calibration(s.robot)
    if cal is None:
        raise PreconditionError(f"robot {s.robot}: no active calibration; run a calibration campaign first")
    try:
        tors = calfile.load(cal.document, f"calibration {cal.id}").torsional
    except DataError as exc:
        raise PreconditionError(str(exc)) from None
    if tors is None:
        raise PreconditionError(f"robot {s.robot}: the active calibration {cal.id} has no torsional section (no CoG "
                                f"calibration): run a campaign with torsional points first")
    missing = [q.name for q in cog_poses(s.meas_pose_deg, p.scheme) if q.name not in tors.poses]
    if missing:
        raise PreconditionError(f"robot {s.robot}: the active calibration {cal.id} calibrated the CoG poses "
                                f"{', '.join(tors.poses)} ({tors.scheme}), not {', '.join(missing)} of scheme "
                                f"{p.scheme!r}: use scheme {tors.scheme!r} or calibrate those poses")
    if p.inertia:  # gains of A4..A6, an excitation that fits the trace buffer: numeric work, off the event loop
        await asyncio.to_thread(check_feasible, s, fixture, tuple(tors.gains), p.inertia_repeats)
    opening = d.OpenRun(RunKind.PROPERTIES, s.robot, {"settings": s.to_json(), "calibration_id": cal.id,
                                                      "properties": p.to_json()})
    return await engine.execute(opening, lambda run: properties_plan(run, s, p, cal.document, inputs=inputs),
                                recorder)
