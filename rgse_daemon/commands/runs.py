"""``rgse runs``: the history of runs and their results from the daemon's store, filtered, as a table, CSV or JSON
for a spreadsheet, a test report or a PDM system (the fields: :data:`FIELDS`, docs/interfaces.md §1.4).

One row per run: its kind, robot, state and times, why it failed or was aborted, the DuT's identity as the run was
given it, and its result (status, mass and CoG with U at k = 2, calibration, warnings). A run without a result
(failed, aborted, interrupted) has empty result fields and its reason in ``detail``. ``reason`` is why there is no
figure, whichever way: a refused result's reason, else the reason a run failed, was aborted or interrupted; the table
shows it shortened (:data:`REASON_CHARS`), the CSV and JSON in full. A properties run also says where its mass came
from (``mass_method``, :mod:`rgse_daemon.massmethod`).
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import io
import json
import sys
from datetime import UTC, date, datetime, time
from pathlib import Path
from typing import Any

from rgse_daemon.commands import absent_store, add_json
from rgse_daemon.config import load_config
from rgse_daemon.errors import EXIT_OK, ConfigError, DataError
from rgse_daemon.massmethod import mass_method_text
from rgse_daemon.store import RunKind, RunState, Store
from rgse_daemon.store.records import ResultRecord, RunRecord
from rgse_daemon.verdict import REFUSED, STATUSES

#: The columns, in order (docs/interfaces.md §1.4). Times are ISO 8601 UTC; masses kg, CoG m, U at k = 2.
FIELDS = (
    "run_id", "kind", "robot", "state", "created_utc", "started_utc", "ended_utc", "detail",
    "dut_name", "serial_number", "part_number", "project", "operator", "note",
    "result_id", "status", "reason",
    "mass_kg", "U_kg", "cog_x_m", "cog_y_m", "cog_z_m", "U_cog_x_m", "U_cog_y_m", "U_cog_z_m",
    "calibration_id", "method", "mass_method", "robot_time_s", "warnings",
)
IDENTITY = ("dut_name", "serial_number", "part_number", "project", "operator", "note")
#: Separator of the warnings in one CSV cell.
WARNING_SEPARATOR = " | "
#: Longest reason in the table (characters); CSV and JSON carry it whole.
REASON_CHARS = 72
#: Run states that end without a result, for a reason (``detail``).
ENDED_WITHOUT_RESULT = (RunState.FAILED, RunState.ABORTED, RunState.INTERRUPTED)


def _time(value: datetime | None) -> str | None:
    return value.astimezone(UTC).isoformat().replace("+00:00", "Z") if value is not None else None


def row(run: RunRecord, result: ResultRecord | None) -> dict[str, Any]:
    """One run as a flat record of :data:`FIELDS`."""
    out: dict[str, Any] = dict.fromkeys(FIELDS)
    out.update(run_id=run.id, kind=run.kind.value, robot=run.robot, state=run.state.value,
               created_utc=_time(run.created_utc), started_utc=_time(run.started_utc), ended_utc=_time(run.ended_utc),
               detail=run.detail, reason=run.detail if run.state in ENDED_WITHOUT_RESULT else None)
    settings = run.config.get("settings") if isinstance(run.config, dict) else None
    given = settings.get("identity") if isinstance(settings, dict) else None  # a run without a result: as it was given
    doc = result.result if result is not None else {}
    identity = doc.get("identity") if isinstance(doc.get("identity"), dict) else given or {}
    for key in IDENTITY:
        out[key] = identity.get(key) if isinstance(identity, dict) else None
    if result is None:
        return out
    cog = doc.get("cog_dut_m") or doc.get("cog_m")  # the DuT frame where the run knew it, else the flange frame
    u_cog = doc.get("U_cog_dut_m") or doc.get("U_cog_m")
    cog = cog if isinstance(cog, list) else None
    u_cog = u_cog if isinstance(u_cog, list) else None
    for i, axis in enumerate("xyz"):
        out[f"cog_{axis}_m"] = cog[i] if cog and len(cog) == 3 else None
        out[f"U_cog_{axis}_m"] = u_cog[i] if u_cog and len(u_cog) == 3 else None
    warnings = doc.get("warnings") if isinstance(doc.get("warnings"), list) else []
    out.update(result_id=result.id, status=result.status, mass_kg=doc.get("mass_kg"), U_kg=doc.get("U_kg"),
               calibration_id=result.calibration_id or doc.get("calibration_id"), method=doc.get("method"),
               mass_method=mass_method_text(doc), robot_time_s=doc.get("robot_time_s"),
               warnings=[str(w) for w in warnings])
    if result.status == REFUSED:
        out["reason"] = str(doc.get("reason") or "no reason given")
    return out


def _when(text: str | None, what: str, end_of_day: bool) -> datetime | None:
    """``--since``/``--until``: a date (the whole day, UTC) or an ISO 8601 time (UTC unless it says otherwise)."""
    if text is None:
        return None
    try:
        if len(text) == 10:
            d = date.fromisoformat(text)
            return datetime.combine(d, time.max if end_of_day else time.min, UTC)
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise ConfigError(f"{what} {text!r}: expected a date (2026-11-28) or an ISO 8601 time") from None
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


async def collect(args: argparse.Namespace) -> list[dict[str, Any]]:
    config_path = getattr(args, "config", None)
    cfg = load_config(config_path)
    since, until = _when(args.since, "--since", False), _when(args.until, "--until", True)
    if since is not None and until is not None and since > until:
        raise ConfigError(f"--since {args.since} is after --until {args.until}")
    kind = RunKind(args.kind) if args.kind else None
    state = RunState(args.state) if args.state else None
    if absent_store(cfg, "runs", config_path) is not None:  # nothing stored yet: an empty history, no store made
        return []
    rows = []
    needle = args.dut.casefold() if args.dut else None
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        made_by = {c.run_id: c for c in await store.calibrations(args.robot) if c.run_id is not None}
        for run in await store.list_runs(robot=args.robot, kind=kind, state=state):
            if (since is not None and run.created_utc < since) or (until is not None and run.created_utc > until):
                continue
            results = await store.results(run.id)
            r = row(run, results[-1] if results else None)
            cal = made_by.get(run.id)
            if cal is not None and r["calibration_id"] is None:  # a campaign: the calibration it made
                r.update(calibration_id=cal.id, method=cal.method)
            if args.status and r["status"] != args.status:
                continue
            if needle and not any(needle in str(r[k] or "").casefold() for k in ("dut_name", "serial_number",
                                                                                 "part_number", "project")):
                continue
            rows.append(r)
    return rows


def as_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=FIELDS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: WARNING_SEPARATOR.join(v or ()) if k == "warnings" else ("" if v is None else v)
                    for k, v in r.items()})
    return buf.getvalue()


def _short(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= REASON_CHARS else text[:REASON_CHARS - 1] + "…"


def as_table(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return "no runs match"
    lines = [f"{'run':16s}  {'kind':11s}  {'state':11s}  {'created (UTC)':20s}  {'DuT':24s}  {'status':7s}  result"]
    for r in rows:
        dut = " ".join(str(r[k]) for k in ("dut_name", "serial_number") if r[k]) or "-"
        if r["mass_kg"] is not None:
            figure = f"{r['mass_kg']:.3f} ± {r['U_kg']:.3f} kg" if r["U_kg"] is not None else f"{r['mass_kg']:.3f} kg"
        elif r["kind"] == "calibration" and r["calibration_id"]:
            figure = f"calibration {r['calibration_id']} ({r['method']})"
        elif r["reason"]:
            figure = ("refused: " if r["status"] == REFUSED else f"{r['state']}: ") + _short(r["reason"])
        else:
            figure = r["detail"] or "-"
        warn = f" ({len(r['warnings'])} warning(s))" if r["warnings"] else ""
        lines.append(f"{r['run_id'][:16]:16s}  {r['kind']:11s}  {r['state']:11s}  {(r['created_utc'] or '')[:19]:20s}  "
                     f"{dut[:24]:24s}  {r['status'] or '-':7s}  {figure}{warn}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse runs``."""
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its store)")
    p.add_argument("--robot", metavar="NAME", help="only this robot's runs (default: every robot in the store)")
    p.add_argument("--kind", choices=[k.value for k in RunKind])
    p.add_argument("--state", choices=[s.value for s in RunState])
    p.add_argument("--status", choices=STATUSES, help="only results of this status")
    p.add_argument("--dut", metavar="TEXT", help="DuT name, serial or part number or project contains TEXT")
    p.add_argument("--since", metavar="DATE", help="created on or after (2026-11-28 or an ISO 8601 time, UTC)")
    p.add_argument("--until", metavar="DATE", help="created on or before")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--csv", action="store_true", help="CSV with the fields of docs/interfaces.md §1.4")
    add_json(fmt)
    p.add_argument("--out", type=Path, metavar="FILE", help="write to FILE instead of stdout")


def run(args: argparse.Namespace) -> int:
    rows = asyncio.run(collect(args))
    if args.csv:
        text = as_csv(rows)
    elif args.json:
        text = json.dumps({"fields": list(FIELDS), "runs": rows}) + "\n"
    else:
        text = as_table(rows) + "\n"
    if args.out is not None:
        out: Path = args.out
        try:
            out.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise DataError(f"--out {out}: cannot write: {exc.strerror or exc}") from exc
        print(f"{len(rows)} run(s) written to {out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return EXIT_OK
