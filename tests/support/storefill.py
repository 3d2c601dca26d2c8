"""Put generated campaign and measurement directories into a real store the way the daemon records runs.

Conventions (those :mod:`rgse_daemon.report.data` reads): one loop per trace, its ``.dat``/``.r64`` files archived
into the run directory and indexed with the loop's index; the manifest archived too (no loop); calibration points
as manifest ``[[point]]`` specs; the result of ``rgse mass --json`` recorded with every archived file as input.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from rgse_daemon.commands import calibrate as calibrate_cmd
from rgse_daemon.commands import mass as mass_cmd
from rgse_daemon.manifest import load_manifest
from rgse_daemon.store import Repository, archive_file, archive_root, relative_path


@dataclass(frozen=True)
class Filled:
    calibration_id: str
    calibration_run_id: str
    run_id: str
    result: dict[str, Any]
    cal_doc: dict[str, Any]


def _archive_trace(repo: Repository, data_dir: Path, run_id: str, run_dir: str, src_dir: Path, trace: str,
                   loop_index: int | None) -> list[str]:
    dest = archive_root(data_dir) / run_dir
    hashes = []
    for src in sorted(src_dir.glob(f"{trace}_*")):
        f = archive_file(src, dest)
        repo.add_trace_file(run_id, relative_path(f.path, archive_root(data_dir)), f.sha256, f.size,
                            loop_index=loop_index)
        hashes.append(f.sha256)
    assert hashes, f"no files of trace {trace} in {src_dir}"
    return hashes


def _archive_manifest(repo: Repository, data_dir: Path, run_id: str, run_dir: str, src_dir: Path) -> str:
    f = archive_file(src_dir / "manifest.toml", archive_root(data_dir) / run_dir)
    repo.add_trace_file(run_id, relative_path(f.path, archive_root(data_dir)), f.sha256, f.size)
    return f.sha256


def _quiet(fn, args: argparse.Namespace) -> str:
    """Run a command's ``run``; it must succeed: exit 0, or 4 for a result with warnings (interfaces §1.1)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = fn(args)
    assert code == 0 or (code == 4 and '"status": "warning"' in out.getvalue()), (code, out.getvalue()[-500:])
    return out.getvalue()


def fill(repo: Repository, data_dir: Path, campaign_dir: Path, measurement_dir: Path, work: Path,
         method: str = "paper") -> Filled:
    """Calibrate (``rgse calibrate --campaign``), measure (``rgse mass``) and record both runs in the store."""
    cal_path = work / "CAL.json"
    _quiet(calibrate_cmd.run, argparse.Namespace(points=None, campaign=campaign_dir, out=cal_path, method=method,
                                                 json=True))
    doc = json.loads(cal_path.read_text())
    result = json.loads(_quiet(mass_cmd.run, argparse.Namespace(traces=measurement_dir, calibration=cal_path,
                                                                fixture_mass=None, json=True)))
    t0 = datetime(2024, 5, 1, 8, 0, tzinfo=UTC)

    man = load_manifest(campaign_dir)
    crun = repo.create_run("calibration", man.setup.robot, {"campaign": campaign_dir.name, "operators": 1},
                           run_id="cal-20240501")
    repo.set_run_state(crun.id, "running")
    repo.add_points(crun.id, [{"kind": p.kind, "mass_kg": p.mass_kg, "lever_a3_m": p.lever_a3_m,
                               "lever_a5_m": p.lever_a5_m, "traces": list(p.traces)} for p in man.points])
    _archive_manifest(repo, data_dir, crun.id, crun.directory, campaign_dir)
    idx = 0
    for pi, p in enumerate(man.points):
        for trace in p.traces:
            repo.add_loop(crun.id, idx, trace, point_index=pi)
            _archive_trace(repo, data_dir, crun.id, crun.directory, campaign_dir, trace, idx)
            repo.update_loop(crun.id, idx, state="archived")
            idx += 1
        repo.set_point_state(crun.id, pi, "done")
    repo.add_calibration(doc, run_id=crun.id, activate=True)
    repo.set_run_state(crun.id, "completed")

    mman = load_manifest(measurement_dir)
    run = repo.create_run("measurement", mman.setup.robot,
                          {"operators": 1, "software_version": "0.1.0", "note": "DuT <ReFEx> & fixture"},
                          run_id="meas-20240501")
    repo.set_run_state(run.id, "running")
    hashes = [_archive_manifest(repo, data_dir, run.id, run.directory, measurement_dir)]
    for i, trace in enumerate(mman.measurement_traces):
        repo.add_loop(run.id, i, trace)
        hashes += _archive_trace(repo, data_dir, run.id, run.directory, measurement_dir, trace, i)
        repo.update_loop(run.id, i, state="archived", robot_start_utc=t0 + timedelta(minutes=3 * i),
                         record_end_utc=t0 + timedelta(minutes=3 * i + 2))
    repo.record_result(run.id, result, hashes)
    repo.set_run_state(run.id, "completed")
    return Filled(doc["calibration_id"], crun.id, run.id, result, doc)
