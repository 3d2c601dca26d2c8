"""The reference measurement of paper Table 2: a crane-scale weighing recorded next to an in-line mass result.

In the paper the DuT with its fixture was weighed free-hanging on a Kern HFB 300K100 crane scale (117.6 ± 0.1 kg,
net 107.3 ± 0.1 kg) and compared with the in-line result (117.94 ± 0.7 kg, net 107.65 ± 0.7 kg). Here the scale is
read by the daemon itself (:func:`rgse_daemon.procedures.reference.take_reference`), so the number is not typed
in by hand, and the raw line it came from is kept.

Storage: the store has no table for reference weighings yet, so each weighing is an *event* of kind
:data:`EVENT_KIND` on the run (``events.data`` holds the fields of :class:`ReferenceRecord`); a failed reading is an
event of kind :data:`FAILED_KIND`. A proper home would be a table
``reference_weighings(id, run_id → runs, result_id → results, mass_kg, u_kg, resolution_kg, weighed, net_mass_kg,
fixture_mass_kg, raw_line, device, weighed_utc, operators, operation_min, bad_frames, recorded_utc)``.

Comparison (Table 2): in-line net mass ± U (k = 2) against the scale's net mass ± u; the difference in kg and %,
and agreement when ``|Δ| ≤ √(U² + (2u)²)`` (both sides at k = 2). The scale's u is d/√3 (``ScaleConfig.u_kg``);
an uncertainty of the fixture mass, when the scale weighed DuT and fixture together, is not known and not added.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from datetime import datetime
from typing import Any, Literal

from rgse_daemon.errors import DataError
from rgse_daemon.store import EventRecord, Repository, RunRecord

EVENT_KIND = "reference_weighing"
FAILED_KIND = "reference_failed"
Weighed = Literal["gross", "net"]
#: Coverage factor of the agreement test (the in-line U is already k = 2).
K = 2.0


@dataclass(frozen=True)
class ReferenceRecord:
    """One crane-scale weighing as stored (an event's data) plus the event's id and time."""

    event_id: int
    recorded_utc: datetime
    run_id: str
    result_id: str
    mass_kg: float
    """The scale reading in kg."""
    u_kg: float
    """Standard uncertainty of the reading (d/√3)."""
    resolution_kg: float
    """The scale's d; the paper quotes the reading as ± d."""
    weighed: str
    """``gross``: DuT and fixture hung together (the paper's 117.6 kg); ``net``: the DuT alone."""
    fixture_mass_kg: float
    net_mass_kg: float
    raw_line: str
    device: str
    weighed_utc: str
    operators: int | None
    operation_min: float | None
    bad_frames: int

    def data(self) -> dict[str, Any]:
        d = asdict(self)
        for key in ("event_id", "recorded_utc", "run_id"):
            d.pop(key)
        return d

    @classmethod
    def from_event(cls, ev: EventRecord) -> ReferenceRecord:
        d = ev.data or {}
        try:
            return cls(event_id=ev.id, recorded_utc=ev.time_utc, run_id=str(ev.run_id), **d)
        except TypeError as exc:
            raise DataError(f"event {ev.id} ({ev.kind}): malformed reference weighing {d!r}: {exc}") from exc


@dataclass(frozen=True)
class Comparison:
    """Paper Table 2, the mass rows: in-line against crane scale."""

    inline_gross_kg: float
    inline_net_kg: float
    inline_U_kg: float
    fixture_mass_kg: float
    scale_gross_kg: float
    scale_net_kg: float
    scale_u_kg: float
    scale_resolution_kg: float
    difference_kg: float
    """In-line net minus scale net."""
    difference_pct: float
    """Relative to the scale's net mass."""
    limit_kg: float
    """√(U² + (2u)²)."""
    agree: bool

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def compare(result: dict[str, Any], reference: ReferenceRecord) -> Comparison:
    """Table 2 comparison of a stored in-line result (``rgse mass --json``) with a reference weighing."""
    try:
        net, big_u = float(result["mass_kg"]), float(result["U_kg"])
        fixture = float(result.get("fixture_mass_kg", 0.0))
        gross = float(result.get("gross_mass_kg", net + fixture))
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"result of run {reference.run_id}: no usable mass_kg/U_kg: {exc}") from exc
    scale_net = reference.net_mass_kg
    scale_gross = reference.mass_kg if reference.weighed == "gross" else reference.mass_kg + fixture
    diff = net - scale_net
    limit = math.sqrt(big_u**2 + (K * reference.u_kg) ** 2)
    pct = 100.0 * diff / scale_net if scale_net != 0 else math.nan
    return Comparison(gross, net, big_u, fixture, scale_gross, scale_net, reference.u_kg, reference.resolution_kg,
                      diff, pct, limit, abs(diff) <= limit)


def references(repo: Repository, run_id: str) -> list[ReferenceRecord]:
    """The run's reference weighings, oldest first."""
    return [ReferenceRecord.from_event(e) for e in repo.events(run_id=run_id, limit=100_000) if e.kind == EVENT_KIND]


def inline_operation_min(run: RunRecord) -> float | None:
    """The in-line run's time of operation (start to end), minutes; None while unknown."""
    if run.started_utc is None or run.ended_utc is None:
        return None
    return (run.ended_utc - run.started_utc).total_seconds() / 60.0


def table2_rows(run: RunRecord, cmp: Comparison, reference: ReferenceRecord) -> list[tuple[str, str, str]]:
    """The rows of paper Table 2 (parameter, crane scale, in-line) that this record can fill; unknown is blank."""

    def opt(v: float | int | None, fmt: str) -> str:
        return "" if v is None else format(v, fmt)

    inline_ops = run.config.get("operators")
    d = cmp.scale_resolution_kg
    return [
        ("total time of operation (min)", opt(reference.operation_min, ".0f"), opt(inline_operation_min(run), ".1f")),
        ("total number of operators", opt(reference.operators, "d"),
         opt(inline_ops if isinstance(inline_ops, int) else None, "d")),
        ("payload fixture mass (kg)", "", f"{cmp.fixture_mass_kg:.3f}"),
        ("total measured mass (kg)", f"{cmp.scale_gross_kg:.1f} ± {d:g}",
         f"{cmp.inline_gross_kg:.2f} ± {cmp.inline_U_kg:.2f}"),
        ("net mass (kg)", f"{cmp.scale_net_kg:.1f} ± {d:g}", f"{cmp.inline_net_kg:.2f} ± {cmp.inline_U_kg:.2f}"),
        ("difference in-line − scale (kg)", "", f"{cmp.difference_kg:+.3f} ({cmp.difference_pct:+.3f} %)"),
        ("agreement |Δ| ≤ √(U² + (2u)²)", "", f"{'yes' if cmp.agree else 'NO'} (limit {cmp.limit_kg:.3f} kg)"),
    ]
