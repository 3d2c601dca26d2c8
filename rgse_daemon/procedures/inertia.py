"""The inertia step of a mass-properties run (issue #15): the DuT's excitation, the tare's, and the identification.

It runs after the CoG poses, once mass and CoG of the same run are computed (they enter the design and the
identification)::

    design       the excitation for the measured payload (:func:`~rgse_daemon.pipeline.excitation.design`): every
                 swing at the largest $VEL_AXIS that keeps every corner of the interlock's payload cube
                 (``measurement.payload_lever_max_m``, the points the static check uses) under the T1 limit, rendered
                 as ``rgse_inertia`` with ``REST_S`` of standstill after each move
    DuT          push (static check) and select it, arm KUKA Trace of A4..A6 (``INERTIA_TRACE_PERIOD_S``), start it,
                 wait for the end, stop and pull the trace, archive it as a loop of the run
    tare         the operator takes the DuT off (MPA and fixture stay) and confirms (the engine's Confirm: MQTT/CLI
                 ``confirm``); the start is verified again (mode, safety inputs) and the *same* program runs, traced
    compute      ``inertia.toml`` in the run directory (the traces, mass and CoG of the run, the fixture, the DuT
                 frame) and the identification **by the same code as** ``rgse inertia --traces DIR --calibration
                 DIR/CAL.json`` (:func:`~rgse_daemon.analysis.inertia.compute_inertia_dir`)

Why the tare comes last: the design depends on the DuT's measured mass and CoG (the load diagram's torque check),
and the tare must run the very program the DuT ran. Taking the DuT off at the end is one more mounting change and no
guess at the DuT before it is measured.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rgse_daemon.analysis.cog import FixtureFrame
from rgse_daemon.analysis.inertia import MANIFEST, InertiaManifest, compute_inertia_dir, excitation_program
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.krl.render import RenderedProgram, cube_corners
from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.pipeline import inertia as inr
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.loop import LoopOutcome, LoopTiming
from rgse_daemon.procedures.measurement import CALIBRATION_FILE
from rgse_daemon.procedures.preconditions import PreconditionError, verify_start
from rgse_daemon.procedures.programs import render_program, run_checked, trace_config_xml
from rgse_daemon.procedures.retrieval import TRACE_DIR, PulledTrace
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.trace.config import buffer_limit_s

#: The trace configuration of the excitation: the drives of the wrist axes (and the interpolator, which triggers).
INERTIA_TRACE_CONFIG_NAME = "rgse_inertia.xml"
INERTIA_TRACE_MODULES = ("KRCIpo", "NextGenDrive#4", "NextGenDrive#5", "NextGenDrive#6")
#: 4 ms: the identification's Gaussian (σ = 20 ms, ``pipeline.inertia.SMOOTH_SIGMA_S``) spans 5 samples.
INERTIA_TRACE_PERIOD_S = 0.004
#: Standstill after each move of the excitation (s): one stroke per move in the trace.
REST_S = 0.3
#: The trace runs this much longer than the planned program (fraction, plus ``TRACE_MARGIN_S``); it is stopped when
#: the program ends, so the margin costs nothing but covers a slower controller.
TRACE_MARGIN_FRACTION = 0.25
TRACE_MARGIN_S = 10.0
#: Deadline of the design (s): the interlock's speed bound over every swing, in a worker thread.
DESIGN_TIMEOUT_S = 300.0
#: Deadline of the identification (s): the stroke bootstrap.
COMPUTE_TIMEOUT_S = 600.0
#: The prompt data that marks the tare's mounting change (a client shows it; the demo's operator acts on it).
TARE_PROMPT = "inertia_tare"


@dataclass(frozen=True)
class InertiaPlan:
    """A designed excitation and its program, the planned robot time (s, rests included) and the trace length."""

    design: ex.Excitation
    program: RenderedProgram
    planned_s: float
    trace_time_s: float

    def to_json(self) -> dict[str, Any]:
        return {"moves": len(self.design.moves), "planned_robot_time_s": self.planned_s,
                "trace_time_s": self.trace_time_s, "rest_s": REST_S, "trace_period_s": INERTIA_TRACE_PERIOD_S,
                "condition_number": self.design.condition_number, "log_det": self.design.log_det,
                "limit_mm_s": self.design.limit_mm_s, "max_point_speed_mm_s": self.design.max_point_speed_mm_s}


def payload_of(s: RunSettings, fixture: FixtureFrame, mass_kg: float, cog_flange_m: Sequence[float]) -> ex.Payload:
    """What the design knows: fixture and DuT together (mass, CoG in the flange frame) for the load diagram, and the
    corners of the cube the interlock's static check bounds the speed on (``payload_lever_max_m``)."""
    total = fixture.mass_kg + mass_kg
    cog = [(fixture.mass_kg * f + mass_kg * c) / total if total > 0 else 0.0
           for f, c in zip(fixture.cog_flange_m, cog_flange_m, strict=True)]
    points = tuple(tuple(float(v) for v in p) for p in cube_corners(s.payload_lever_max_m))
    return ex.Payload(total, (cog[0], cog[1], cog[2]), points)  # type: ignore[arg-type]


def plan_excitation(s: RunSettings, payload: ex.Payload) -> InertiaPlan:
    """The excitation for ``payload`` from the measurement pose, within the trace buffer at 4 ms: the default
    design, or with one swing per axis and orientation when that one is too long; DataError when even that does not
    fit (the cube of ``payload_lever_max_m`` sets the speeds, hence the duration)."""
    limit_s = buffer_limit_s(INERTIA_TRACE_PERIOD_S)
    planned = math.inf
    for repeats in (ex.REPEATS, 1):
        try:
            design = ex.design(payload, base_deg=s.meas_pose_deg, limit_mm_s=s.speed_limit_mm_s, repeats=repeats,
                               optimise=False)
        except ValueError as exc:
            raise DataError(f"inertia: {exc}") from None
        planned = design.robot_time_s + REST_S * len(design.moves)
        trace_s = planned * (1.0 + TRACE_MARGIN_FRACTION) + TRACE_MARGIN_S
        if trace_s <= limit_s:
            return InertiaPlan(design, excitation_program(design, REST_S), planned, trace_s)
    raise DataError(f"inertia: the excitation takes {planned:.0f} s of robot time, more than KUKA Trace holds at "
                    f"{1000 * INERTIA_TRACE_PERIOD_S:g} ms ({limit_s:g} s with margin): the swings are slow because "
                    f"every point within measurement.payload_lever_max_m = {s.payload_lever_max_m:g} m is kept "
                    f"under {s.speed_limit_mm_s:g} mm/s; a smaller (true) payload reach shortens them")


def check_feasible(s: RunSettings, fixture: FixtureFrame, gains_axes: Sequence[int]) -> None:
    """Refuse (PreconditionError, before the run opens) an inertia run that cannot succeed: no torque calibration of
    every wrist axis, or an excitation longer than the trace buffer (planned for the fixture alone; the DuT's own
    mass changes only the accelerations)."""
    missing = [ax for ax in inr.WRIST_AXES if ax not in gains_axes]
    if missing:
        raise PreconditionError(
            f"inertia: the active calibration's torsional section has no gain of A{', A'.join(map(str, missing))}: "
            f"the wrist torques would be taken 1:1 (the drive's gain is off by up to 20 %); calibrate A4..A6 "
            f"(torsional points in a scheme that traces them) first")
    try:
        plan_excitation(s, payload_of(s, fixture, 0.0, (0.0, 0.0, 0.0)))
    except DataError as exc:
        raise PreconditionError(str(exc)) from None


def inertia_trace_xml(s: RunSettings, trace_time_s: float) -> str:
    samples = math.ceil(trace_time_s / INERTIA_TRACE_PERIOD_S)
    return trace_config_xml(replace(s, trace_period_s=INERTIA_TRACE_PERIOD_S, trace_samples=samples),
                            INERTIA_TRACE_MODULES)


def trace_name(tag: str, which: str) -> str:
    """The excitation trace of the DuT (``which`` = ``dut``) or the tare (``tare``)."""
    return f"inertia_{tag}_{which}"


def excite(index: int, trace: str, run: d.RunContext, s: RunSettings,
           prog: RenderedProgram) -> Generator[m.Msg, Any, LoopOutcome]:
    """One traced run of the excitation, recorded as loop ``index`` of the run: push (the static check) and select,
    arm the trace, start, wait for the end and verify the handshake, stop the trace, pull and archive it."""
    timing = LoopTiming()
    name = yield m.Push(prog)
    yield m.Select(name)
    yield d.LoopStarted(index, trace, _now())
    record_start = _now()
    t0 = time.monotonic()
    yield m.TraceStart(trace, INERTIA_TRACE_CONFIG_NAME)
    yield m.Start()
    reply = yield m.WaitProgram(frozenset({"P_END"}), s.program_timeout_s)
    timing.motion_s = reply[1] if reply is not None else 0.0
    yield m.VerifyDone("RGSE_DONE")
    yield d.LoopRecording(index, robot_end_utc=_now(), record_start_utc=record_start)
    yield m.TraceStop()
    yield m.TraceWait(s.trace_timeout_s)
    timing.record_s = max(0.0, time.monotonic() - t0 - timing.motion_s)
    yield d.LoopRecorded(index, _now())
    pulled: PulledTrace | None = yield m.Pull(trace, run.run_dir, s.trace_timeout_s)
    outcome = LoopOutcome(trace, timing)
    if pulled is None:  # dry run
        return outcome
    timing.pull_s = pulled.duration_s
    t0 = time.monotonic()
    yield d.TraceArchived(index, trace, pulled.files, False)
    deleted, note = yield m.DeleteTraceCopies(pulled)
    if not deleted:
        yield d.TraceArchived(index, trace, pulled.files, False, note)
    timing.store_s = time.monotonic() - t0
    outcome.sha256s = pulled.sha256s
    outcome.deleted = deleted
    outcome.delete_note = note
    return outcome


def inertia_step(run: d.RunContext, s: RunSettings, fixture: FixtureFrame, dut_abc_deg: Sequence[float],
                 static: dict[str, Any] | None, tag: str, first_index: int,
                 inputs: Callable[[], SafetyInputs] | None) -> Generator[m.Msg, Any, tuple[dict[str, Any] | None,
                                                                                         list[LoopOutcome]]]:
    """The inertia of the DuT (see the module docstring) from ``static``, the run's mass and CoG result (None in a
    dry run: the design is then made for the fixture alone). Returns the result's inertia part (None in a dry run)
    and the two excitation loops."""
    mass = float(static["mass_kg"]) if static is not None else 0.0
    cog = tuple(static["cog_m"]) if static is not None else (0.0, 0.0, 0.0)
    plan: InertiaPlan = yield m.Compute("design the inertia excitation", plan_excitation,
                                        (s, payload_of(s, fixture, mass, cog)), timeout_s=DESIGN_TIMEOUT_S)
    yield m.PutFile(TRACE_DIR + INERTIA_TRACE_CONFIG_NAME, inertia_trace_xml(s, plan.trace_time_s).encode("utf-8"))
    dut_trace, tare_trace = trace_name(tag, "dut"), trace_name(tag, "tare")
    yield m.Checkpoint("inertia: DuT excitation")
    yield m.Emit(Event("step", f"inertia: DuT excitation ({len(plan.design.moves)} moves, {plan.planned_s:.0f} s "
                               "planned)", step="inertia", data={"phase": "inertia", "which": "dut",
                                                                 **plan.to_json()}))
    dut = yield from excite(first_index, dut_trace, run, s, plan.program)
    yield m.Emit(Event("loop", "inertia: DuT excitation done", step="loop",
                       data={"phase": "inertia", "which": "dut", **dut.timing.to_json()}))
    yield m.Checkpoint("inertia: tare")
    note = yield m.Confirm("inertia tare: take the DuT off (leave MPA and fixture mounted) and confirm",
                           data={TARE_PROMPT: True, "phase": "inertia", "fixture_mass_kg": fixture.mass_kg})
    yield m.Emit(Event("step", f"inertia: tare excitation (MPA and fixture): {note or 'confirmed'}", step="inertia",
                       data={"phase": "inertia", "which": "tare"}))
    snap = yield from verify_start(inputs)  # a new mounting: mode and safety inputs again, then to the start pose
    yield from run_checked((yield from render_program("rgse_meas_pose", s, snap)), s)
    tare = yield from excite(first_index + 1, tare_trace, run, s, plan.program)
    yield m.Emit(Event("loop", "inertia: tare excitation done", step="loop",
                       data={"phase": "inertia", "which": "tare", **tare.timing.to_json()}))
    if static is None:  # dry run
        return None, [dut, tare]
    yield m.Emit(Event("step", "computing the inertia (offline path)", step="compute-inertia"))
    man = InertiaManifest(dut_trace, tare_trace, tuple(s.meas_pose_deg), mass, cog,  # type: ignore[arg-type]
                          tuple(static["U_cog_m"]), tuple(float(v) for v in dut_abc_deg),  # type: ignore[arg-type]
                          fixture.mass_kg, tuple(fixture.cog_flange_m))  # type: ignore[arg-type]
    t0 = time.monotonic()
    result = yield m.Process("compute the inertia", compute_inertia, (run.run_dir, man), timeout_s=COMPUTE_TIMEOUT_S)
    if result is None:
        return None, [dut, tare]
    result["inertia"]["compute_s"] = time.monotonic() - t0
    result["inertia"]["excitation"] = plan.to_json()
    return result, [dut, tare]


def compute_inertia(run_dir: Path, man: InertiaManifest) -> dict[str, Any]:
    """Write ``inertia.toml`` and identify the inertia as ``rgse inertia --traces RUN_DIR --calibration
    RUN_DIR/CAL.json`` does; the result's inertia keys (tensor about the CoG in the DuT frame, principal moments
    ascending and axes, each with U, k = 2; the whole identification under ``inertia``)."""
    write_atomic(run_dir / MANIFEST, man.to_toml())
    r = compute_inertia_dir(run_dir, run_dir / CALIBRATION_FILE).to_json()
    for key in ("principal_moments_kgm2", "U_principal_moments_kgm2"):
        if not all(math.isfinite(v) for v in r[key]):
            raise DataError(f"{run_dir}: the identification gave non-finite {key} {r[key]}")
    return {
        "inertia_cog_dut_kgm2": r["inertia_cog_dut_kgm2"],
        "U_inertia_cog_dut_kgm2": r["U_inertia_cog_dut_kgm2"],
        "principal_moments_kgm2": r["principal_moments_kgm2"],
        "U_principal_moments_kgm2": r["U_principal_moments_kgm2"],
        "principal_axes_dut": r["principal_axes_dut"],
        "U_principal_axes_deg": r["U_principal_axes_deg"],
        "inertia_traces": {"dut": man.dut_trace, "tare": man.tare_trace},
        "inertia": {**r, "mass_kg": man.mass_kg, "cog_flange_m": list(man.cog_flange_m),
                    "U_cog_flange_m": list(man.U_cog_flange_m), "dut_abc_deg": list(man.dut_abc_deg)},
    }


def _now() -> datetime:
    return datetime.now(UTC)
