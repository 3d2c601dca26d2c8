"""The reference weighing of paper Table 2 as a procedure: read one stable weighing from the crane scale, record it
on the run, and compare it with the in-line result (:mod:`rgse_daemon.analysis.reference` holds the records and the
comparison)."""

from __future__ import annotations

from rgse_daemon.analysis.reference import (
    EVENT_KIND,
    FAILED_KIND,
    Comparison,
    ReferenceRecord,
    Weighed,
    compare,
)
from rgse_daemon.errors import DataError
from rgse_daemon.io import IoDeviceError
from rgse_daemon.io.scale import CraneScale
from rgse_daemon.store import EventLevel, NotFound, ResultRecord, RunRecord, Store


async def run_and_result(store: Store, run_id: str) -> tuple[RunRecord, ResultRecord]:
    """The run and its newest result; :class:`DataError` if either is missing (nothing to compare with)."""
    try:
        run = await store.get_run(run_id)
    except NotFound as exc:
        raise DataError(str(exc)) from exc
    results = await store.results(run_id)
    if not results:
        raise DataError(f"run {run_id}: no in-line result stored yet; measure before weighing the reference")
    return run, results[-1]


async def take_reference(
    store: Store,
    scale: CraneScale,
    run_id: str,
    *,
    weighed: Weighed = "gross",
    timeout_s: float | None = None,
    operators: int | None = None,
    operation_min: float | None = None,
) -> tuple[RunRecord, ReferenceRecord, Comparison]:
    """Read one stable weighing, record it on the run (an event, see the module docstring) and compare.

    A scale that times out or sends only bad frames raises its :class:`~rgse_daemon.io.IoDeviceError` after a
    ``reference_failed`` event (with the bad-frame count and last bad line) is recorded on the run.
    """
    if weighed not in ("gross", "net"):
        raise DataError(f"weighed must be 'gross' or 'net', got {weighed!r}")
    run, result = await run_and_result(store, run_id)
    fixture = float(result.result.get("fixture_mass_kg", 0.0))
    bad_before = scale.counters.bad_frames
    try:
        w = await scale.read_stable(timeout_s)
    except IoDeviceError as exc:
        last = scale.last_error
        await store.add_event(
            EventLevel.WARNING, FAILED_KIND, f"reference weighing failed: {exc}", run_id=run_id,
            data={"device": scale.name, "error": str(exc), "error_type": type(exc).__name__,
                  "bad_frames": scale.counters.bad_frames - bad_before,
                  "last_bad_line": None if last is None else last.raw},
        )
        raise
    net = w.mass_kg - fixture if weighed == "gross" else w.mass_kg
    if not net > 0.0:  # a stable reading of an empty hook, or a scale tared with the load on: no reference of a DuT
        problem = (f"the crane scale read {w.mass_kg:.3f} kg ({weighed}"
                   + (f", fixture {fixture:.3f} kg" if weighed == "gross" else "")
                   + f"): a net mass of {net:.3f} kg is no weighing of the DuT (nothing hung yet, or tared with the "
                   f"load on?); nothing compared")
        await store.add_event(
            EventLevel.WARNING, FAILED_KIND, f"reference weighing failed: {problem}", run_id=run_id,
            data={"device": scale.name, "error": problem, "error_type": "DataError",
                  "bad_frames": scale.counters.bad_frames - bad_before, "last_bad_line": None,
                  "mass_kg": w.mass_kg, "weighed": weighed, "raw_line": w.raw_line},
        )
        raise DataError(f"run {run_id}: {problem}")
    rec = ReferenceRecord(
        event_id=0, recorded_utc=w.time_utc, run_id=run_id, result_id=result.id, mass_kg=w.mass_kg, u_kg=w.u_kg,
        resolution_kg=scale.cfg.resolution_kg, weighed=weighed, fixture_mass_kg=fixture, net_mass_kg=net,
        raw_line=w.raw_line, device=scale.name, weighed_utc=w.time_utc.isoformat().replace("+00:00", "Z"),
        operators=operators, operation_min=operation_min, bad_frames=scale.counters.bad_frames - bad_before,
    )
    ev = await store.add_event(
        EventLevel.INFO, EVENT_KIND,
        f"crane scale {w.mass_kg:.3f} kg ({weighed}, ± {scale.cfg.resolution_kg:g} kg) for result {result.id}",
        run_id=run_id, data=rec.data(),
    )
    stored = ReferenceRecord.from_event(ev)
    return run, stored, compare(result.result, stored)
