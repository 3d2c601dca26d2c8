"""The in-line mass measurement run (paper Fig. 24) as a plan, and the function that runs it with its store record.

Flow: verify the controller (T1, or AUT with the area cleared; ``$LOAD.M = -1``; no stop message) → push the trace
configuration → warm-up move → measurement pose → up to ``loops`` × (brake-release move → settle → trace → pull,
verify, archive, delete the controller copy; the pull of loop N runs while loop N+1 settles and records), stopped
once more loops no longer change U (the stop rule of :mod:`rgse_daemon.pipeline.stopping`, recorded as the result's
``stop_reason``) → write ``manifest.toml`` → compute the mass **by the same code as**
``rgse mass --traces DIR --calibration CAL.json`` (:func:`compute_mass`) with the robot's *active* calibration, whose
document is written beside the traces as ``CAL.json`` → the :class:`~documents.Result` with the SHA-256 of its
raw files (the recorder stores it and queues it for MQTT). The run directory is thus a complete contract-§2
measurement directory: the result is always reproducible from it with the offline command.

::

    result = await run_measurement(engine, store, cfg)                     # settings from cfg.measurement
    result = await run_measurement(engine, store, cfg, settings=RunSettings.from_config(cfg, loops=3))
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import Any

from rgse_daemon.analysis import mass as mass_analysis
from rgse_daemon.config import Config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.io.topics import Topics
from rgse_daemon.pipeline.stopping import StopDecision, decide, predict
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.directory import setup_toml, traces_toml
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.loop import LoopOutcome, collect, loop
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import prepare
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.store import RunKind, Store
from rgse_daemon.verdict import with_status

CALIBRATION_FILE = "CAL.json"


def compute_mass(directory: Path, calibration_path: Path, fixture_mass_kg: float | None = None) -> dict[str, Any]:
    """``rgse mass --traces DIR --calibration CAL --json`` as a function (the same :func:`analysis.mass.compute`).
    Returns the contract-§1 JSON object."""
    return mass_analysis.compute(directory, calibration_path, fixture_mass_kg).to_json()


def write_measurement_dir(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]) -> None:
    """manifest.toml (contract §2, ``[measurement]``) and the calibration used, as ``CAL.json``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    lines = [*setup_toml(s), "[measurement]", f"fixture_mass_kg = {float(s.fixture_mass_kg)!r}", traces_toml(traces)]
    write_atomic(run_dir / "manifest.toml", "\n".join(lines) + "\n")
    write_atomic(run_dir / CALIBRATION_FILE, json.dumps(cal_doc, indent=2) + "\n")


def _finish(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]) -> dict[str, Any]:
    write_measurement_dir(run_dir, s, traces, cal_doc)
    return compute_mass(run_dir, run_dir / CALIBRATION_FILE, s.fixture_mass_kg)


def result_line(result: dict[str, Any], figure: str) -> str:
    """The text of a run's ``result`` event: its status, the DuT's name, the figure and the warnings' count, e.g.
    ``warning: Refex wing box: mass 107.312 kg ± 0.220 kg (k = 2); 2 warnings``."""
    name = (result.get("identity") or {}).get("dut_name")
    n = len(result.get("warnings") or ())
    return (f"{result['status']}: " + (f"{name}: " if name else "") + figure
            + (f"; {n} warning{'s' if n != 1 else ''}" if n else ""))


def timing_summary(outcomes: list[LoopOutcome], compute_s: float, loops_wall_s: float | None = None
                   ) -> dict[str, Any]:
    """Robot time, the daemon's overhead on the robot's path (pull waits, store, computation) and, with
    ``loops_wall_s``, the wall time from the first loop's start to the last loop's files indexed."""
    robot = sum(o.timing.robot_s for o in outcomes)
    overhead = sum(o.timing.overhead_s for o in outcomes) + compute_s
    out: dict[str, Any] = {
        "robot_time_s": robot,
        "overhead_s": overhead,
        "compute_s": compute_s,
        "per_loop": [{"trace": o.trace, **o.timing.to_json()} for o in outcomes],
    }
    if loops_wall_s is not None:
        out["loops_wall_s"] = loops_wall_s
    return out


def interim_budget(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]
                   ) -> tuple[float, float] | None:
    """(u, its loop term) in kg from the loops ``traces`` archived so far, with the run's calibration (written as
    ``CAL.json`` beside the traces, as the result's); None if the loops do not give a budget (the final
    computation says why)."""
    path = run_dir / CALIBRATION_FILE
    if not path.exists():
        write_atomic(path, json.dumps(cal_doc, indent=2) + "\n")
    try:
        r = mass_analysis.budget(run_dir, traces, path, s.fixture_mass_kg, s.g_m_s2)
    except (DataError, ValueError):
        return None
    u_loops = r.u_components_kg.get("loops")
    if u_loops is None or not (math.isfinite(r.u_kg) and math.isfinite(u_loops)):
        return None
    return r.u_kg, u_loops


def measurement_loops(run: d.RunContext, s: RunSettings, cal_doc: dict[str, Any] | None, name: Callable[[int], str],
                      first_index: int = 1, *, event_data: dict[str, Any] | None = None,
                      label: str = "loop") -> Generator[m.Msg, Any, tuple[list[LoopOutcome], StopDecision]]:
    """The mass loops in the measurement pose under the stop rule (pipeline/stopping.py): each loop's files are
    pulled while the next loop settles and records; from ``s.min_loops`` loops on, U is predicted from the loops
    archived so far with ``cal_doc`` (none: the configured ``loops``). Returns the loops (all archived) and why they
    stopped."""
    rule = s.stop_rule
    outcomes: list[LoopOutcome] = []
    previous: LoopOutcome | None = None
    decision = StopDecision(False, "")
    for i in range(1, s.loops + 1):
        yield m.Checkpoint(f"{label} {i}")
        yield m.Emit(Event("step", f"{label} {i}/{s.loops}", step="loop", loop_index=i, loop_count=s.loops,
                           data=dict(event_data or {})))
        out = yield from loop(first_index + i - 1, name(i), run, s, previous=previous, defer=True)
        outcomes.append(out)
        previous = out
        prediction = None
        analysed = [o.trace for o in outcomes if not o.pending]
        if cal_doc is not None and analysed and rule.min_loops <= i < rule.max_loops and not rule.fixed:
            t0 = time.monotonic()
            got = yield m.Process("predict U", interim_budget, (run.run_dir, s, analysed, cal_doc))
            out.timing.predict_s = time.monotonic() - t0
            if got is not None:
                prediction = predict(i, len(analysed), got[0], got[1])
        decision = decide(rule, i, prediction)
        per_loop_s = sum(o.timing.robot_s + o.timing.overhead_s for o in outcomes) / len(outcomes)
        left = 0 if decision.stop else s.loops - i
        yield m.Emit(Event("loop", f"{label} {i}/{s.loops} done" + (f" ({decision.reason})" if decision.stop else ""),
                           step="loop", loop_index=i, loop_count=s.loops, eta_s=per_loop_s * left,
                           data={**(event_data or {}), **out.timing.to_json(), **decision.to_json()}))
        if decision.stop:
            break
    if previous is not None:
        yield from collect(previous, run, s)
    return outcomes, decision


def measurement_plan(
    run: d.RunContext,
    s: RunSettings,
    cal_doc: dict[str, Any],
    *,
    inputs: Callable[[], SafetyInputs] | None = None,
) -> m.Plan:
    """The measurement run as a plan (see the module docstring); returns the result (or None in a dry run)."""
    warnings = yield from prepare(s, inputs)
    tag = run.run_id.rsplit("-", 1)[-1][:8].lower()
    t_loops = time.monotonic()
    outcomes, decision = yield from measurement_loops(run, s, cal_doc, lambda i: f"dut_{tag}_l{i:02d}")
    loops_wall_s = time.monotonic() - t_loops
    yield m.Emit(Event("step", "computing the mass (offline path)", step="compute"))
    t0 = time.monotonic()
    result = yield m.Process("compute mass", _finish, (run.run_dir, s, [o.trace for o in outcomes], cal_doc))
    if result is None:  # dry run
        return None
    compute_s = time.monotonic() - t0
    shas = sorted({h for o in outcomes for h in o.sha256s})
    result = {
        **result,
        "run_id": run.run_id,
        "robot": s.robot,
        "trace_sha256": shas,
        "warnings": [*result.get("warnings", []), *(warnings or [])],
        "controller_copies_deleted": all(o.deleted for o in outcomes),
        "stop_reason": decision.reason,
        "stop_rule": stop_json(s, decision),
        "timing": timing_summary(outcomes, compute_s, loops_wall_s),
        **({"identity": s.identity} if s.identity else {}),
    }
    result = with_status(result)
    yield d.Result(result, shas)
    yield m.Emit(Event("result", result_line(result, f"mass {result['mass_kg']:.3f} kg ± {result['U_kg']:.3f} kg "
                                                     f"(k = 2)"), step="result", data=result))
    return result


def stop_json(s: RunSettings, decision: StopDecision) -> dict[str, Any]:
    """The rule's settings and its decision (the prediction it stopped on), for the result."""
    r = s.stop_rule
    return {"max_loops": r.max_loops, "min_loops": r.min_loops, "loop_share": r.loop_share,
            "target_U_kg": r.target_U_kg, **decision.to_json()}


async def run_measurement(
    engine: RunEngine,
    store: Store,
    cfg: Config,
    *,
    settings: RunSettings | None = None,
    inputs: Callable[[], SafetyInputs] | None = None,
) -> dict[str, Any] | None:
    """Execute :func:`measurement_plan` on ``engine`` as a recorded run (:meth:`RunEngine.execute`).

    Refuses (PreconditionError) without an active calibration for this robot. In a dry run nothing is stored.
    """
    s = settings or RunSettings.from_config(cfg)
    recorder = StoreRecorder(store, cfg.paths.data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    cal = await recorder.active_calibration(s.robot)
    if cal is None:
        raise PreconditionError(f"robot {s.robot}: no active calibration; run a calibration campaign first")
    opening = d.OpenRun(RunKind.MEASUREMENT, s.robot, {"settings": s.to_json(), "calibration_id": cal.id})
    return await engine.execute(opening, lambda run: measurement_plan(run, s, cal.document, inputs=inputs), recorder)
