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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rgse_daemon.analysis import mass as mass_analysis
from rgse_daemon.config import Config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.io.topics import Topics
from rgse_daemon.pipeline import integrity
from rgse_daemon.pipeline.envelope import OperatingPointError
from rgse_daemon.pipeline.stopping import StopDecision, StopRule, decide, predict
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.directory import setup_toml, traces_toml
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.loop import LoopOutcome, collect, loop
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import prepare
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.store import RunKind, Store
from rgse_daemon.verdict import REFUSED, refusal, with_status

CALIBRATION_FILE = "CAL.json"


def compute_mass(directory: Path, calibration_path: Path, fixture_mass_kg: float | None = None,
                 drift_prior_per_k: float = DRIFT_PRIOR_PER_K) -> dict[str, Any]:
    """``rgse mass --traces DIR --calibration CAL [--drift-prior P] --json`` as a function (the same
    :func:`analysis.mass.compute`). Returns the contract-§1 JSON object."""
    return mass_analysis.compute(directory, calibration_path, fixture_mass_kg,
                                 drift_prior_per_k=drift_prior_per_k).to_json()


def write_measurement_dir(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]) -> None:
    """manifest.toml (contract §2, ``[measurement]``) and the calibration used, as ``CAL.json``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    lines = [*setup_toml(s), "[measurement]", f"fixture_mass_kg = {float(s.fixture_mass_kg)!r}", traces_toml(traces)]
    write_atomic(run_dir / "manifest.toml", "\n".join(lines) + "\n")
    write_atomic(run_dir / CALIBRATION_FILE, json.dumps(cal_doc, indent=2) + "\n")


#: What the pipeline refuses a measurement for: too few loops left after setting the disturbed ones aside, an
#: operating point far outside the calibration. A result with status ``refused`` and its reason, not a failed run.
REFUSALS = (integrity.TooFewLoops, OperatingPointError)


def refused_result(exc: DataError, cal_doc: dict[str, Any]) -> dict[str, Any]:
    """The result object of a refused measurement (rgse_daemon.verdict): the reason, the kind of refusal and the loops
    it judged (those kept, those set aside with their reasons)."""
    return refusal(str(exc), error=type(exc).__name__, calibration_id=cal_doc.get("calibration_id"),
                   loops=len(getattr(exc, "used", ())), loops_used=list(getattr(exc, "used", ())),
                   loops_set_aside=[a.to_dict() for a in getattr(exc, "set_aside", ())])


def _finish(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]) -> dict[str, Any]:
    """The result (``rgse mass --json``) of the run's loops, or its refusal object (:data:`REFUSALS`)."""
    write_measurement_dir(run_dir, s, traces, cal_doc)
    try:
        return compute_mass(run_dir, run_dir / CALIBRATION_FILE, s.fixture_mass_kg, s.drift_prior_per_k)
    except REFUSALS as exc:
        return refused_result(exc, cal_doc)


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


@dataclass(frozen=True)
class Screened:
    """The integrity check of the loops archived so far (:mod:`rgse_daemon.pipeline.integrity`): the loops kept and
    those set aside (trace names), and (u, its loop term) in kg from the kept ones (None: no budget)."""

    used: list[str]
    set_aside: list[str]
    budget: tuple[float, float] | None


def screen_loops(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]) -> Screened | None:
    """The loops ``traces`` archived so far, with the run's calibration (written as ``CAL.json`` beside the traces, as
    the result's), through the same :func:`~rgse_daemon.analysis.mass.measure` as the result: which are kept, and the
    budget they give. None if they cannot be judged (e.g. far outside the envelope: the final computation says why)."""
    path = run_dir / CALIBRATION_FILE
    if not path.exists():
        write_atomic(path, json.dumps(cal_doc, indent=2) + "\n")
    try:
        r = mass_analysis.budget(run_dir, traces, path, s.fixture_mass_kg, s.g_m_s2,
                                 drift_prior_per_k=s.drift_prior_per_k)
    except integrity.TooFewLoops as exc:
        return Screened(list(exc.used), [a.loop for a in exc.set_aside], None)
    except (DataError, ValueError):
        return None
    u_loops = r.u_components_kg.get("loops")
    ok = u_loops is not None and math.isfinite(r.u_kg) and math.isfinite(u_loops)
    return Screened(list(r.loops_used), [a["loop"] for a in r.loops_set_aside], (r.u_kg, u_loops) if ok else None)


def interim_budget(run_dir: Path, s: RunSettings, traces: list[str], cal_doc: dict[str, Any]
                   ) -> tuple[float, float] | None:
    """(u, its loop term) in kg from the loops ``traces`` archived so far (:func:`screen_loops`); None if they do
    not give a budget."""
    got = screen_loops(run_dir, s, traces, cal_doc)
    return None if got is None else got.budget


def measurement_loops(run: d.RunContext, s: RunSettings, cal_doc: dict[str, Any] | None, name: Callable[[int], str],
                      first_index: int = 1, *, event_data: dict[str, Any] | None = None,
                      label: str = "loop", trace_config: str = TRACE_CONFIG_NAME
                      ) -> Generator[m.Msg, Any, tuple[list[LoopOutcome], StopDecision]]:
    """The mass loops in the measurement pose under the stop rule (pipeline/stopping.py): each loop's files are
    pulled while the next loop settles and records; from ``s.min_loops`` loops on, the loops archived so far are
    screened (pipeline/integrity.py) and U predicted from the kept ones with ``cal_doc`` (none: the configured
    ``loops``). The rule counts only kept loops: from the configured ``loops`` on, every loop is screened as soon as
    it is archived, and while fewer than the rule needs are kept, replacement loops follow (at most
    ``s.replacement_loops``). ``trace_config``: the trace configuration the loops record with (a properties run's
    mass loops: the CoG poses' A3..A6). Returns the loops (all archived, those set aside included) and why they
    stopped."""
    rule = s.stop_rule
    outcomes: list[LoopOutcome] = []
    previous: LoopOutcome | None = None
    decision = StopDecision(False, "")
    aside: list[str] = []
    i = 0
    while not decision.stop:
        i += 1
        count = max(i, s.loops)
        text = (f"{label} {i}/{s.loops}" if i <= s.loops else
                f"replacement {label} {i} ({i - s.loops} of at most {rule.replacements}; set aside: "
                f"{', '.join(aside)})")
        yield m.Checkpoint(f"{label} {i}")
        yield m.Emit(Event("step", text, step="loop", loop_index=i, loop_count=count,
                           data={**(event_data or {}), "replacement": i > s.loops}))
        out = yield from loop(first_index + i - 1, name(i), run, s, trace_config=trace_config, previous=previous,
                              defer=True)
        outcomes.append(out)
        previous = out
        final = i >= s.loops  # a stop at the configured loops, or a replacement: judge every loop, this one too
        if final and cal_doc is not None:
            yield from collect(out, run, s)
        decision, aside = yield from _judge(rule, i, outcomes, run, s, cal_doc, final)
        if decision.stop and cal_doc is not None and out.pending:
            # the rule would stop on a loop not yet pulled (its files come after the next loop's start): it counted
            # as kept. Judged before the stop, so that a loop the check sets aside is replaced, not found in the
            # result with fewer loops than the rule keeps (seen under load: a result on 2 loops, "loop term below
            # share")
            yield from collect(out, run, s)
            decision, aside = yield from _judge(rule, i, outcomes, run, s, cal_doc, True)
        per_loop_s = sum(o.timing.robot_s + o.timing.overhead_s for o in outcomes) / len(outcomes)
        left = 0 if decision.stop else max(s.loops - i, 1)
        yield m.Emit(Event("loop", f"{label} {i}/{count} done" + (f" ({decision.reason})" if decision.stop else "")
                           + (f"; set aside: {', '.join(aside)}" if aside else ""),
                           step="loop", loop_index=i, loop_count=count, eta_s=per_loop_s * left,
                           data={**(event_data or {}), **out.timing.to_json(), **decision.to_json(),
                                 "loops_set_aside": list(aside)}))
    if previous is not None:
        yield from collect(previous, run, s)
    return outcomes, decision


def _judge(rule: StopRule, i: int, outcomes: list[LoopOutcome], run: d.RunContext, s: RunSettings,
           cal_doc: dict[str, Any] | None, final: bool) -> Generator[m.Msg, Any, tuple[StopDecision, list[str]]]:
    """The stop rule after loop ``i``: the loops pulled so far screened (on the final loop, or from the rule's
    fewest loops on) and U predicted for those kept; the loops set aside so far."""
    analysed = [o.trace for o in outcomes if not o.pending]
    screened = None
    if cal_doc is not None and analysed and (final or (rule.min_loops <= i and not rule.fixed)):
        t0 = time.monotonic()
        screened = yield m.Process("screen loops, predict U", screen_loops, (run.run_dir, s, analysed, cal_doc))
        outcomes[-1].timing.predict_s += time.monotonic() - t0
    kept, prediction, aside = None, None, []
    if screened is not None:
        aside = list(screened.set_aside)
        kept = i - len(aside)
        if screened.budget is not None and not rule.fixed:
            prediction = predict(kept, len(analysed) - len(aside), *screened.budget)
    return decide(rule, i, prediction, kept), aside


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
    figure = (str(result["reason"]) if result["status"] == REFUSED else
              f"mass {result['mass_kg']:.3f} kg ± {result['U_kg']:.3f} kg (k = 2)")
    yield m.Emit(Event("result", result_line(result, figure), step="result", data=result))
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
