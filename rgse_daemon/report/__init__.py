"""Plots and the HTML report of a measurement run or a calibration (one self-contained page); the one-page PDF
certificate of a run's result (:mod:`.certificate`).

Public API
----------
``build_report(repo, data_dir, out_dir, run_id=... | calibration_id=...) -> Path``
    Gathers from the store and the archive, checks (see below), renders and writes ``report-<id>.html``
    atomically into ``out_dir``; returns its path.
``load_measurement(repo, data_dir, run_id)`` / ``load_calibration(repo, data_dir, calibration_id)``
    The checked views a page is drawn from (:mod:`.data`).
``render_measurement(view, meta)`` / ``render_calibration(view, meta)``
    The page as a string (:mod:`.page`); figures from :mod:`.plots`.
``ReportConsistencyError``
    A recomputation from the archived raw files disagrees with the store: no report is written.

Every number comes from the store or is recomputed from the archived raw files with the pipeline code that made
the stored result, and then asserted equal to it (file hashes, mass, u, U, sample counts, bias, K parameters).
"""

from __future__ import annotations

from pathlib import Path

from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.report.data import (
    CalibrationView,
    MeasurementView,
    ReportConsistencyError,
    ReportMeta,
    load_calibration,
    load_measurement,
    meta,
)
from rgse_daemon.report.page import render_calibration, render_measurement, render_run_record
from rgse_daemon.store import Repository, RunKind

__all__ = [
    "CalibrationView",
    "MeasurementView",
    "ReportConsistencyError",
    "ReportMeta",
    "build_report",
    "load_calibration",
    "load_measurement",
    "render_calibration",
    "render_measurement",
]


def build_report(repo: Repository, data_dir: Path, out_dir: Path, *, run_id: str | None = None,
                 calibration_id: str | None = None) -> Path:
    """Render the report of a measurement run or of a calibration into ``out_dir``; returns the file written."""
    if (run_id is None) == (calibration_id is None):
        raise DataError("report: give either a run id or a calibration id")
    m = meta(repo)
    if run_id is not None:
        run = repo.get_run(run_id)
        made = [c for c in repo.calibrations(run.robot) if c.run_id == run_id] if run.kind == RunKind.CALIBRATION \
            else []
        if made:  # a campaign's run id: the report of the calibration it made
            return build_report(repo, data_dir, out_dir, calibration_id=made[-1].id)
        results = repo.results(run_id)
        refused = results[-1].result if results and results[-1].status == "refused" else None
        if not results or refused is not None:  # failed, aborted, interrupted or refused: what it recorded and why
            text = render_run_record(run, repo.loops(run_id), repo.trace_files(run_id),
                                     repo.events(run_id=run_id), m, refused)
        else:
            text = render_measurement(load_measurement(repo, Path(data_dir), run_id), m)
        name = f"report-{run_id}.html"
    else:
        assert calibration_id is not None
        text = render_calibration(load_calibration(repo, Path(data_dir), calibration_id), m)
        name = f"report-calibration-{calibration_id}.html"
    path = Path(out_dir) / name
    try:
        write_atomic(path, text)
    except OSError as exc:
        raise DataError(f"{path}: cannot write the report: {exc}") from exc
    return path
