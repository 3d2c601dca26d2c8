"""``rgse runs``: the store's history as a table, CSV and JSON, with filters (issue #34, "History and export"): a
calibration run, a measurement run, a named DuT's result with warnings and a failed run, in a real SQLite store
filled the way the daemon records runs."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import pytest

from rgse_daemon.cli import main
from rgse_daemon.commands.runs import FIELDS
from rgse_daemon.store import Repository
from tests.support.storefill import _archive_manifest, _archive_trace

from .conftest import World, write_config

IDENTITY = {"dut_name": "ReFEx wing box", "serial_number": "SN-0042", "part_number": "RFX-WB-1", "project": "ReFEx",
            "operator": "A. Kottmeier", "note": "flight unit, 2nd weighing"}


def _history(world: World, tmp_path: Path) -> tuple[Path, dict[str, str]]:
    w = world.copy(tmp_path)
    ids = {"cal": w.filled.calibration_run_id, "meas": w.filled.run_id}
    with Repository.open(None, w.data_dir) as repo:
        named = repo.create_run("measurement", "KR500R2830", {"operators": 1}, run_id="meas-named")
        repo.set_run_state(named.id, "running")
        src = Path(repo.get_run(w.filled.run_id).directory)
        root = w.data_dir / "archive" / src
        hashes = [_archive_manifest(repo, w.data_dir, named.id, named.directory, root)]
        traces = sorted({f.name.split("_NextGenDrive")[0] for f in root.glob("*_NextGenDrive#3.dat")})
        for i, trace in enumerate(traces[:2]):
            repo.add_loop(named.id, i, trace)
            hashes += _archive_trace(repo, w.data_dir, named.id, named.directory, root, trace, i)
            repo.update_loop(named.id, i, state="archived")
        result = {**w.filled.result, "identity": IDENTITY, "status": "warning",
                  "warnings": ["loop 2 set aside: a step of 31 Nm in A5", "outside the calibrated envelope"]}
        repo.record_result(named.id, result, hashes)
        repo.set_run_state(named.id, "completed")
        failed = repo.create_run("measurement", "KR500R2830", {"operators": 1}, run_id="meas-failed")
        repo.set_run_state(failed.id, "running")
        repo.set_run_state(failed.id, "failed", "interlock trip [mode]: $MODE_OP changed to #AUT")
    ids.update(named="meas-named", failed="meas-failed")
    return write_config(tmp_path / "rgse.toml", w.data_dir), ids


def test_runs_lists_exports_and_filters_the_history(world: World, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    config, ids = _history(world, tmp_path)

    assert main(["runs", "--config", str(config)]) == 0
    table = capsys.readouterr().out
    assert "ReFEx wing box SN-0042" in table and "(2 warning(s))" in table
    assert "failed: interlock trip [mode]: $MODE_OP changed to #AUT" in table
    assert f"calibration {world.filled.calibration_id}" in table

    assert main(["runs", "--config", str(config), "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert tuple(rows[0]) == FIELDS and [r["run_id"] for r in rows] == [ids["cal"], ids["meas"], ids["named"],
                                                                         ids["failed"]]
    named = next(r for r in rows if r["run_id"] == ids["named"])
    assert {k: named[k] for k in IDENTITY} == IDENTITY
    assert named["status"] == "warning" and float(named["mass_kg"]) == pytest.approx(world.filled.result["mass_kg"])
    assert named["warnings"] == "loop 2 set aside: a step of 31 Nm in A5 | outside the calibrated envelope"
    failed = next(r for r in rows if r["run_id"] == ids["failed"])
    assert failed["state"] == "failed" and failed["mass_kg"] == "" and "interlock trip" in failed["detail"]
    assert failed["reason"] == failed["detail"] and named["reason"] == "" and failed["status"] == ""

    # filters: status, DuT text, kind, state, dates; JSON carries the same fields
    assert main(["runs", "--config", str(config), "--json", "--status", "warning"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["fields"] == list(FIELDS) and [r["run_id"] for r in doc["runs"]] == [ids["named"]]
    assert doc["runs"][0]["warnings"] == ["loop 2 set aside: a step of 31 Nm in A5", "outside the calibrated envelope"]
    assert main(["runs", "--config", str(config), "--json", "--dut", "sn-0042"]) == 0
    assert [r["run_id"] for r in json.loads(capsys.readouterr().out)["runs"]] == [ids["named"]]
    assert main(["runs", "--config", str(config), "--json", "--kind", "calibration"]) == 0
    assert [r["run_id"] for r in json.loads(capsys.readouterr().out)["runs"]] == [ids["cal"]]
    assert main(["runs", "--config", str(config), "--json", "--kind", "properties"]) == 0  # a kind of its own
    assert json.loads(capsys.readouterr().out)["runs"] == []
    assert main(["runs", "--config", str(config), "--json", "--state", "failed"]) == 0
    assert [r["run_id"] for r in json.loads(capsys.readouterr().out)["runs"]] == [ids["failed"]]
    assert main(["runs", "--config", str(config), "--json", "--until", "2000-01-01"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"] == []
    out = tmp_path / "history.csv"
    assert main(["runs", "--config", str(config), "--csv", "--out", str(out), "--since", "2000-01-01"]) == 0
    assert len(list(csv.DictReader(io.StringIO(out.read_text())))) == 4
    assert "4 run(s) written" in capsys.readouterr().err

    # bad input: one line, exit 2
    assert main(["runs", "--config", str(config), "--since", "yesterday"]) == 2
    assert "--since 'yesterday': expected a date" in capsys.readouterr().err
    assert main(["runs", "--config", str(config), "--since", "2026-12-01", "--until", "2026-11-01"]) == 2


def test_certificate_is_one_page_with_identity_result_status_and_calibration(
        world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue #34: the one-page PDF certificate, read back as text as a person (or a PDM import) would."""
    from pypdf import PdfReader

    config, ids = _history(world, tmp_path)
    out = tmp_path / "cert.pdf"
    assert main(["certificate", ids["named"], "--config", str(config), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    reader = PdfReader(out)
    assert len(reader.pages) == 1
    text = " ".join(reader.pages[0].extract_text().split())
    mass, u = world.filled.result["mass_kg"], world.filled.result["U_kg"]
    for needed in ("Mass properties measurement certificate", "STATUS: WARNING - 2 warning(s)",
                   "loop 2 set aside: a step of 31 Nm in A5", "ReFEx wing box", "SN-0042", "RFX-WB-1",
                   "A. Kottmeier", f"{mass:.3f} kg", f"{u:.3f} kg", world.filled.calibration_id, "SHA-256",
                   "ECSS-E-10-03C", "k = 2"):
        assert needed in text, (needed, text)
    assert f"+/- {0.0005 * mass:.3f} kg (0.05 %)" in text  # the ECSS band beside U

    # a run without a result has nothing to certify: exit 2 naming why
    assert main(["certificate", ids["failed"], "--config", str(config), "--out", str(tmp_path / "x.pdf")]) == 2
    err = capsys.readouterr().err
    assert "has no result" in err and "interlock trip" in err and not (tmp_path / "x.pdf").exists()


def test_report_of_a_campaign_run_and_of_a_failed_run(world: World, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Issue #34: ``rgse report`` refused a calibration run's id and made no report for a failed run. A campaign's
    run id now gives the report of the calibration it made; a run without a result gives its run record: why it
    ended, what it recorded, its archived files in an appendix."""
    config, ids = _history(world, tmp_path)
    out = tmp_path / "reports"
    assert main(["report", ids["cal"], "--config", str(config), "--out", str(out)]) == 0
    path = Path(capsys.readouterr().out.strip())
    assert path.name == f"report-calibration-{world.filled.calibration_id}.html"
    assert main(["report", ids["failed"], "--config", str(config), "--out", str(out)]) == 0
    text = Path(capsys.readouterr().out.strip()).read_text()
    assert "Run record, measurement run meas-failed" in text and "no result" in text
    assert "interlock trip [mode]: $MODE_OP changed to #AUT" in text and "No loop was recorded." in text
    # a measurement's report: loops numbered 1..n in the table as in the plot, the files' hashes in the appendix
    assert main(["report", ids["meas"], "--config", str(config), "--out", str(out)]) == 0
    text = Path(capsys.readouterr().out.strip()).read_text()
    assert text.index("Appendix: archived raw files") > text.index("Consistency checks")
    assert text.index("<h2>Result</h2>") < text.index("SHA-256")
    numbers = re.findall(r'data-field="loop.number" data-value="(\d+)"', text)
    assert numbers == [str(i) for i in range(1, len(numbers) + 1)] and len(numbers) == 4
