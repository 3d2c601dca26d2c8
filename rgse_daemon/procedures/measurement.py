"""The in-line mass measurement run (paper Fig. 24) as a plan, and the function that runs it with its store record.

Flow: verify the controller (T1, or AUT with the area cleared; ``$LOAD.M = -1``; no stop message) → push the trace
configuration → warm-up move → measurement pose → ``loops`` × (brake-release move → settle → trace → pull, verify,
archive, delete the controller copy) → write ``manifest.toml`` → compute the mass **by the same code as**
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
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rgse_daemon.analysis import mass as mass_analysis
from rgse_daemon.config import Config
from rgse_daemon.durable import write_atomic
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.directory import setup_toml, traces_toml
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.loop import LoopOutcome, loop
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


def timing_summary(outcomes: list[LoopOutcome], compute_s: float) -> dict[str, Any]:
    robot = sum(o.timing.robot_s for o in outcomes)
    overhead = sum(o.timing.overhead_s for o in outcomes) + compute_s
    return {
        "robot_time_s": robot,
        "overhead_s": overhead,
        "compute_s": compute_s,
        "per_loop": [{"trace": o.trace, **o.timing.to_json()} for o in outcomes],
    }


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
    outcomes: list[LoopOutcome] = []
    for i in range(1, s.loops + 1):
        yield m.Checkpoint(f"loop {i}")
        yield m.Emit(Event("step", f"loop {i}/{s.loops}", step="loop", loop_index=i, loop_count=s.loops))
        out = yield from loop(i, f"dut_{tag}_l{i:02d}", run, s)
        outcomes.append(out)
        per_loop_s = sum(o.timing.robot_s + o.timing.overhead_s for o in outcomes) / len(outcomes)
        yield m.Emit(Event("loop", f"loop {i}/{s.loops} done", step="loop", loop_index=i, loop_count=s.loops,
                           eta_s=per_loop_s * (s.loops - i), data=out.timing.to_json()))
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
        "timing": timing_summary(outcomes, compute_s),
        **({"identity": s.identity} if s.identity else {}),
    }
    result = with_status(result)
    yield d.Result(result, shas)
    yield m.Emit(Event("result", result_line(result, f"mass {result['mass_kg']:.3f} kg ± {result['U_kg']:.3f} kg "
                                                     f"(k = 2)"), step="result", data=result))
    return result


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
