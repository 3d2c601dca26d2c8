"""The inertia step of a mass-properties run (issue #15): the DuT's excitation, the tare's, and the identification.

It runs after the CoG poses, once mass and CoG of the same run are computed (they enter the design and the
identification)::

    design       the excitation for the measured payload (:func:`~rgse_daemon.pipeline.excitation.design`): every
                 swing at the largest $VEL_AXIS that keeps every corner of the interlock's payload cube
                 (``measurement.payload_lever_max_m``, the points the static check uses) under the T1 limit; one
                 ``rgse_inertia`` program per wrist orientation (a part: the move there and its swings, the last
                 part also the move back), ``REST_S`` of standstill after each move
    DuT          per part: push (static check) and select it, arm KUKA Trace of A4..A6 (``INERTIA_TRACE_PERIOD_S``),
                 start it, wait for the end, check the trace still records, stop and pull it, archive it as a loop
                 of the run. A part lasts ~30-70 s: far within the trace buffer (200 s at 4 ms) whatever the payload
                 reach, and a retry or an abort loses one part, not the whole excitation
    tare         the operator takes the DuT off (MPA and fixture stay) and confirms (the engine's Confirm: MQTT/CLI
                 ``confirm``); the start is verified again (mode, safety inputs) and the *same* programs run, traced
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
from rgse_daemon.analysis.inertia import MANIFEST, InertiaManifest, compute_inertia_dir, moves_program
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
#: The trace is armed for the whole buffer and stopped when the program ends; the planned program must leave this
#: much of the buffer free (fraction, plus ``TRACE_MARGIN_S``) for a controller slower than planned.
TRACE_MARGIN_FRACTION = 0.25
TRACE_MARGIN_S = 10.0
#: Deadline of the design (s): the interlock's speed bound over every swing, in a worker thread.
DESIGN_TIMEOUT_S = 300.0
#: Deadline of the identification (s): the stroke bootstrap.
COMPUTE_TIMEOUT_S = 600.0
#: $TRACE.STATE while the trace still records (docs/controller.md §5.1).
RECORDING_STATES = ("TRIGGERED",)
#: Swings of each wrist axis per orientation unless ``[properties] inertia_repeats`` says otherwise.
REPEATS = ex.REPEATS
#: The prompt data that marks the tare's mounting change (a client shows it; the demo's operator acts on it).
TARE_PROMPT = "inertia_tare"


@dataclass(frozen=True)
class InertiaPlan:
    """A designed excitation and its programs (one per part), the planned robot time (s, rests included) and the
    trace length each part is armed for."""

    design: ex.Excitation
    programs: tuple[RenderedProgram, ...]
    planned_s: float
    trace_time_s: float
    repeats: int = REPEATS

    def to_json(self) -> dict[str, Any]:
        return {"moves": len(self.design.moves), "parts": len(self.programs), "planned_robot_time_s": self.planned_s,
                "trace_time_s": self.trace_time_s, "rest_s": REST_S, "trace_period_s": INERTIA_TRACE_PERIOD_S,
                "repeats": self.repeats,
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


def split(design: ex.Excitation, n_blocks: int = ex.N_BLOCKS, repeats: int = ex.REPEATS
          ) -> list[tuple[tuple[float, ...], tuple[ex.Move, ...]]]:
    """The parts of ``design`` (start pose, moves): per orientation the move there and its block
    (``excitation.program_moves``), the move back to the start in the last part."""
    per_block = 1 + len(ex.SWING_AXES) * (2 + 2 * repeats)
    moves = design.moves
    if len(moves) != n_blocks * per_block + 1:
        raise DataError(f"inertia: a design of {len(moves)} moves is not {n_blocks} blocks of {per_block} and the "
                        "move back")
    parts = []
    start = tuple(design.start_deg)
    for k in range(n_blocks):
        chunk = moves[k * per_block:(k + 1) * per_block] + (moves[-1:] if k == n_blocks - 1 else ())
        parts.append((start, chunk))
        start = tuple(chunk[-1].target_deg)
    return parts


def plan_excitation(s: RunSettings, payload: ex.Payload, repeats: int = REPEATS) -> InertiaPlan:
    """The excitation for ``payload`` from the measurement pose, ``repeats`` swings of each wrist axis per
    orientation, in parts that each fit the trace buffer at 4 ms; DataError when a part does not (the cube of
    ``payload_lever_max_m`` sets the speeds, the repeats the number of swings, hence the duration)."""
    limit_s = buffer_limit_s(INERTIA_TRACE_PERIOD_S)
    try:
        design = ex.design(payload, base_deg=s.meas_pose_deg, limit_mm_s=s.speed_limit_mm_s, optimise=False,
                           repeats=repeats)
    except ValueError as exc:
        raise DataError(f"inertia: {exc}") from None
    planned = design.robot_time_s + REST_S * len(design.moves)
    parts = split(design, repeats=repeats)
    longest = max(planned * len(moves) / len(design.moves) for _, moves in parts)  # the parts are alike
    if longest * (1.0 + TRACE_MARGIN_FRACTION) + TRACE_MARGIN_S > limit_s:
        raise DataError(f"inertia: a part of the excitation takes ~{longest:.0f} s of robot time, more than KUKA "
                        f"Trace holds at {1000 * INERTIA_TRACE_PERIOD_S:g} ms ({limit_s:g} s with margin): the "
                        f"swings are slow because every point within measurement.payload_lever_max_m = "
                        f"{s.payload_lever_max_m:g} m is kept under {s.speed_limit_mm_s:g} mm/s; a smaller (true) "
                        f"payload reach shortens them, and fewer swings (properties.inertia_repeats = {repeats})")
    programs = tuple(moves_program(start, moves, REST_S) for start, moves in parts)
    return InertiaPlan(design, programs, planned, limit_s, repeats)


def check_feasible(s: RunSettings, fixture: FixtureFrame, gains_axes: Sequence[int], repeats: int = REPEATS
                   ) -> None:
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
        plan_excitation(s, payload_of(s, fixture, 0.0, (0.0, 0.0, 0.0)), repeats)
    except DataError as exc:
        raise PreconditionError(str(exc)) from None


def inertia_trace_xml(s: RunSettings, trace_time_s: float) -> str:
    samples = math.ceil(trace_time_s / INERTIA_TRACE_PERIOD_S)
    return trace_config_xml(replace(s, trace_period_s=INERTIA_TRACE_PERIOD_S, trace_samples=samples),
                            INERTIA_TRACE_MODULES)


def trace_name(tag: str, which: str, part: int) -> str:
    """The excitation trace of part ``part`` (1-based) of the DuT (``which`` = ``dut``) or the tare (``tare``)."""
    return f"inertia_{tag}_{which}_p{part}"


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
    armed = yield m.TraceStart(trace, INERTIA_TRACE_CONFIG_NAME)  # None in a dry run
    yield m.Start()
    reply = yield m.WaitProgram(frozenset({"P_END"}), s.program_timeout_s)
    timing.motion_s = reply[1] if reply is not None else 0.0
    yield m.VerifyDone("RGSE_DONE")
    yield d.LoopRecording(index, robot_end_utc=_now(), record_start_utc=record_start)
    state = yield m.ReadVar("$TRACE.STATE")
    state_name = str(getattr(state, "name", state)).strip().lstrip("#").upper()
    if armed is not None and state_name not in RECORDING_STATES:
        raise DataError(f"inertia: the trace {trace} ended ($TRACE.STATE #{state_name}) before the excitation did: "
                        f"the program ran longer than the trace buffer holds at {INERTIA_TRACE_PERIOD_S * 1000:g} ms")
    yield m.TraceStop()
    yield m.TraceWait(s.trace_timeout_s)
    timing.record_s = max(0.0, time.monotonic() - t0 - timing.motion_s)
    yield d.LoopRecorded(index, _now())
    pulled: PulledTrace | None = yield m.Pull(trace, run.run_dir, s.trace_timeout_s, INERTIA_TRACE_MODULES[1:])
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
                 inputs: Callable[[], SafetyInputs] | None, repeats: int = REPEATS
                 ) -> Generator[m.Msg, Any, tuple[dict[str, Any] | None, list[LoopOutcome]]]:
    """The inertia of the DuT (see the module docstring) from ``static``, the run's mass and CoG result (None in a
    dry run: the design is then made for the fixture alone), ``repeats`` swings of each wrist axis per orientation.
    Returns the result's inertia part (None in a dry run) and the two excitation loops."""
    mass = float(static["mass_kg"]) if static is not None else 0.0
    cog = tuple(static["cog_m"]) if static is not None else (0.0, 0.0, 0.0)
    plan: InertiaPlan = yield m.Compute("design the inertia excitation", plan_excitation,
                                        (s, payload_of(s, fixture, mass, cog), repeats),
                                        timeout_s=DESIGN_TIMEOUT_S)
    yield m.PutFile(TRACE_DIR + INERTIA_TRACE_CONFIG_NAME, inertia_trace_xml(s, plan.trace_time_s).encode("utf-8"))
    n = len(plan.programs)
    dut_traces = [trace_name(tag, "dut", k) for k in range(1, n + 1)]
    tare_traces = [trace_name(tag, "tare", k) for k in range(1, n + 1)]
    yield m.Emit(Event("step", f"inertia: DuT excitation ({len(plan.design.moves)} moves in {n} parts, "
                               f"{plan.planned_s:.0f} s planned)", step="inertia",
                       data={"phase": "inertia", "which": "dut", **plan.to_json()}))
    dut = yield from _parts("DuT", dut_traces, first_index, run, s, plan)
    yield m.Checkpoint("inertia: tare")
    note = yield m.Confirm("inertia tare: take the DuT off (leave MPA and fixture mounted) and confirm",
                           data={TARE_PROMPT: True, "phase": "inertia", "fixture_mass_kg": fixture.mass_kg})
    yield m.Emit(Event("step", f"inertia: tare excitation (MPA and fixture): {note or 'confirmed'}", step="inertia",
                       data={"phase": "inertia", "which": "tare"}))
    snap = yield from verify_start(inputs)  # a new mounting: mode and safety inputs again, then to the start pose
    yield from run_checked((yield from render_program("rgse_meas_pose", s, snap)), s)
    tare = yield from _parts("tare", tare_traces, first_index + n, run, s, plan)
    if static is None:  # dry run
        return None, [*dut, *tare]
    yield m.Emit(Event("step", "computing the inertia (offline path)", step="compute-inertia"))
    man = InertiaManifest(tuple(dut_traces), tuple(tare_traces), tuple(s.meas_pose_deg), mass,
                          cog,  # type: ignore[arg-type]
                          tuple(static["U_cog_m"]), tuple(float(v) for v in dut_abc_deg),  # type: ignore[arg-type]
                          fixture.mass_kg, tuple(fixture.cog_flange_m))  # type: ignore[arg-type]
    t0 = time.monotonic()
    result = yield m.Process("compute the inertia", compute_inertia, (run.run_dir, man), timeout_s=COMPUTE_TIMEOUT_S)
    if result is None:
        return None, [*dut, *tare]
    result["inertia"]["compute_s"] = time.monotonic() - t0
    result["inertia"]["excitation"] = plan.to_json()
    return result, [*dut, *tare]


def _parts(which: str, traces: Sequence[str], first_index: int, run: d.RunContext, s: RunSettings,
           plan: InertiaPlan) -> Generator[m.Msg, Any, list[LoopOutcome]]:
    """Every part of the excitation, traced, as loops ``first_index``…"""
    outcomes = []
    n = len(plan.programs)
    for k, (trace, prog) in enumerate(zip(traces, plan.programs, strict=True), 1):
        yield m.Checkpoint(f"inertia: {which} part {k}")
        out = yield from excite(first_index + k - 1, trace, run, s, prog)
        outcomes.append(out)
        yield m.Emit(Event("loop", f"inertia: {which} excitation part {k}/{n} done", step="loop", loop_index=k,
                           loop_count=n, data={"phase": "inertia", "which": which.lower(), **out.timing.to_json()}))
    return outcomes


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
        "inertia_traces": {"dut": list(man.dut_trace), "tare": list(man.tare_trace)},
        "inertia": {**r, "mass_kg": man.mass_kg, "cog_flange_m": list(man.cog_flange_m),
                    "U_cog_flange_m": list(man.U_cog_flange_m), "dut_abc_deg": list(man.dut_abc_deg)},
    }


def _now() -> datetime:
    return datetime.now(UTC)
