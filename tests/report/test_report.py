"""The HTML report of a measurement run and of a calibration, rendered from a real store and opened in headless
Chromium: every figure must load, and every number shown must be the stored one."""

from __future__ import annotations

import argparse
import html
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rgse_daemon.commands import report as report_cmd
from rgse_daemon.report import ReportConsistencyError, build_report
from rgse_daemon.store import ArchiveError, Repository, archive_root
from tests.report.conftest import DUT_KG, FIXTURE_KG, World, write_config
from tests.support.campaign import write_campaign, write_measurement
from tests.support.chromium import REPO, Dom, dump_dom, screenshot
from tests.support.storefill import fill


def _assert_all_images_loaded(dom: Dom, n_expected: int) -> None:
    assert len(dom.images) == n_expected
    assert dom.body.get("data-images-total") == str(n_expected)
    assert dom.body.get("data-images-loaded") == str(n_expected)
    for img in dom.images:
        assert img.get("data-loaded") == "yes", img.get("data-figure")
        assert int(img.get("data-natural-width") or 0) > 0, img.get("data-figure")
        assert (img.get("src") or "").startswith("data:image/png;base64,")  # self-contained: nothing fetched


def _value(dom: Dom, field: str) -> str:
    values = set(dom.fields[field])
    assert len(values) == 1, (field, values)
    return values.pop()


def test_measurement_report_in_chromium(world: World, tmp_path: Path) -> None:
    with Repository.open(None, world.data_dir) as repo:
        path = build_report(repo, world.data_dir, tmp_path / "out", run_id=world.filled.run_id)
        result = repo.results(world.filled.run_id)[-1]
        files = repo.trace_files(world.filled.run_id)
        loops = repo.loops(world.filled.run_id)
        cal = repo.get_calibration(world.filled.calibration_id)
    text = path.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    # run config text is escaped, never markup
    assert "&lt;ReFEx&gt; &amp; fixture" in text and "<ReFEx>" not in text

    dom = Dom(dump_dom(path))
    # 1 mass vs ECSS, 1 loop masses, one per loop, calibration curves, K fits, calibration results
    _assert_all_images_loaded(dom, 2 + len(loops) + 3)
    res = result.result
    assert res == world.filled.result
    for key in ("mass_kg", "U_kg", "u_kg", "gross_mass_kg", "fixture_mass_kg"):
        assert float(_value(dom, key)) == res[key], key
    assert dom.shown["mass_kg"][0] == f"{res['mass_kg']:.3f}"
    assert dom.shown["U_kg"][0] == f"{res['U_kg']:.3f} kg"
    assert float(_value(dom, "headline_mass_kg")) == res["mass_kg"]
    assert int(_value(dom, "loops")) == res["loops"] == len(loops) == 4
    assert int(_value(dom, "samples_used")) == res["samples_used"]
    assert int(_value(dom, "samples_total")) == res["samples_total"]
    assert _value(dom, "calibration_id") == _value(dom, "result_calibration_id") == cal.id == res["calibration_id"]
    assert _value(dom, "result_id") == result.id
    assert _value(dom, "run_id") == world.filled.run_id
    assert sorted(dom.fields["file.sha256"]) == sorted(f.sha256 for f in files)
    assert sorted(int(v) for v in dom.fields["file.size_bytes"]) == sorted(f.size_bytes for f in files)
    assert sorted(dom.fields["source_sha256"]) == sorted(cal.document["source_sha256"].values())
    assert [d.get("data-figure") for d in dom.images if (d.get("data-figure") or "").startswith("loop_")] == [
        "loop_masses", *[f"loop_{i + 1}" for i in range(len(loops))]]
    # loop-by-loop masses are recomputed: their mean sits within the loop spread of the stored result
    loop_net = [float(v) for v in dom.fields["loop.net_mass_kg"]]
    assert len(loop_net) == 4
    assert abs(sum(loop_net) / 4 - res["mass_kg"]) < res["U_kg"]
    assert float(_value(dom, "bias_a3_nm")) == cal.document["bias_nm"]["A3"]
    assert "ECSS-E-10-03C" in text

    shot = screenshot(path, tmp_path / "measurement.png")
    assert shot.stat().st_size > 10_000


def test_calibration_report_in_chromium(world: World, tmp_path: Path) -> None:
    with Repository.open(None, world.data_dir) as repo:
        path = build_report(repo, world.data_dir, tmp_path, calibration_id=world.filled.calibration_id)
        cal = repo.get_calibration(world.filled.calibration_id)
        files = repo.trace_files(world.filled.calibration_run_id)
        points = repo.points(world.filled.calibration_run_id)
    dom = Dom(dump_dom(path))
    _assert_all_images_loaded(dom, 3)
    doc = cal.document
    assert _value(dom, "calibration_id") == doc["calibration_id"]
    assert _value(dom, "calibration_method") == doc["method"]
    assert float(_value(dom, "bias_a3_nm")) == doc["bias_nm"]["A3"]
    assert float(_value(dom, "bias_a5_nm")) == doc["bias_nm"]["A5"]
    assert float(_value(dom, "loo_pct")) == doc["fit"]["loo_mean_abs_err_pct"]
    stored = [*doc["models"]["A3"]["coef"], *doc["models"]["A5"]["coef"]]
    shown = [float(v) for k, vals in dom.fields.items() if k.startswith("param_A") for v in vals]
    assert shown == stored
    assert [float(v) for v in dom.fields["point.mass_kg"]] == [p.spec["mass_kg"] for p in points]
    assert sorted(dom.fields["cal_file.sha256"]) == sorted(f.sha256 for f in files)
    assert sorted(dom.fields["source_sha256"]) == sorted(doc["source_sha256"].values())


def test_measurement_report_shows_the_trace_period_warning(tmp_path: Path) -> None:
    """A DuT traced at 12 ms with a calibration campaign traced at 4 ms: the stored result carries a warning naming
    both periods, and the report shows it where it shows the other warnings of the result."""
    write_campaign(tmp_path / "campaign", seed=3, n_samples=600)
    write_measurement(tmp_path / "dut", DUT_KG, fixture_mass_kg=FIXTURE_KG, seed=11, n_loops=3, n_samples=600,
                      period_s=0.012)
    with Repository.open(None, tmp_path / "data") as repo:
        filled = fill(repo, tmp_path / "data", tmp_path / "campaign", tmp_path / "dut", tmp_path,
                      method="axis-linear")
        path = build_report(repo, tmp_path / "data", tmp_path / "out", run_id=filled.run_id)
    assert filled.cal_doc["fit"]["sample_period_s"] == 0.004
    period = [w for w in filled.result["warnings"] if "sample period" in w]
    assert len(period) == 1 and period[0].startswith("trace sample period 12 ms differs from the calibration "
                                                     "campaign's 4 ms"), filled.result["warnings"]
    text = html.unescape(path.read_text(encoding="utf-8"))
    shown = f'<p class="warn">warning: <span data-field="warning" data-value="{period[0]}">{period[0]}</span></p>'
    # at the top, with the status, before the first section
    assert shown in text and text.index(shown) < text.index("<h2>Result</h2>"), text[:3000]
    assert '<span class="status warning" data-field="status" data-value="warning">warning</span>' in text


def test_report_refuses_a_corrupted_raw_file(world: World, tmp_path: Path) -> None:
    w = world.copy(tmp_path)
    with Repository.open(None, w.data_dir) as repo:
        victim = next(f for f in repo.trace_files(w.filled.run_id) if f.path.endswith(".r64"))
        target = archive_root(w.data_dir) / victim.path
        target.chmod(0o644)
        blob = bytearray(target.read_bytes())
        blob[-1] ^= 0xFF
        target.write_bytes(bytes(blob))
        with pytest.raises(ArchiveError, match="sha256"):
            build_report(repo, w.data_dir, tmp_path / "out", run_id=w.filled.run_id)
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_report_refuses_a_result_the_raw_files_do_not_reproduce(world: World, tmp_path: Path) -> None:
    w = world.copy(tmp_path)
    with Repository.open(None, w.data_dir) as repo:
        hashes = [f.sha256 for f in repo.trace_files(w.filled.run_id)]
        forged = {**w.filled.result, "mass_kg": w.filled.result["mass_kg"] + 0.01}
        repo.record_result(w.filled.run_id, forged, hashes)
        with pytest.raises(ReportConsistencyError, match="mass_kg"):
            build_report(repo, w.data_dir, tmp_path / "out", run_id=w.filled.run_id)


def test_report_command_and_module_entry(world: World, tmp_path: Path, capsys) -> None:
    cfg = write_config(tmp_path / "rgse.toml", world.data_dir)
    ns = argparse.Namespace(run_id=world.filled.run_id, calibration=None, out=tmp_path / "a", config=cfg)
    assert report_cmd.run(ns) == 0
    printed = Path(capsys.readouterr().out.strip())
    assert printed == tmp_path / "a" / f"report-{world.filled.run_id}.html" and printed.is_file()

    proc = subprocess.run([sys.executable, "-m", "rgse_daemon.commands.report", "--calibration",
                           world.filled.calibration_id, "--out", str(tmp_path / "b"), "--config", str(cfg)],
                          cwd=REPO, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert Path(proc.stdout.strip()).is_file()

    bad = subprocess.run([sys.executable, "-m", "rgse_daemon.commands.report", "no-such-run", "--config", str(cfg),
                          "--out", str(tmp_path / "c")], cwd=REPO, capture_output=True, text=True, timeout=60,
                         check=False)
    assert bad.returncode == 2
    assert "no-such-run" in bad.stderr and "Traceback" not in bad.stderr
    assert str(world.data_dir / "rgse.sqlite3") in bad.stderr  # the store it searched
    calib_as_run = subprocess.run([sys.executable, "-m", "rgse_daemon.commands.report", world.filled.calibration_run_id,
                                   "--config", str(cfg), "--out", str(tmp_path / "c")], cwd=REPO,
                                  capture_output=True, text=True, timeout=60, check=False)
    # a campaign's run id gives the report of the calibration it made (issue #34: it was refused)
    assert calib_as_run.returncode == 0, calib_as_run.stderr
    assert Path(calib_as_run.stdout.strip()).name == f"report-calibration-{world.filled.calibration_id}.html"


def test_report_of_a_missing_run_names_the_store_and_creates_none(tmp_path: Path) -> None:
    """Without --config the default store is ./data/rgse.sqlite3: a report from a directory without one says so,
    suggests --config, and leaves no empty store behind."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RGSE_")}
    for args in (["no-such-run"], ["--calibration", "no-such-cal"]):
        proc = subprocess.run([sys.executable, "-m", "rgse_daemon.commands.report", *args], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=60, check=False)
        assert proc.returncode == 2, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr, proc.stderr
        for fragment in (args[-1], "sqlite store data/rgse.sqlite3 does not exist", "--config FILE"):
            assert fragment in proc.stderr, (fragment, proc.stderr)
    assert list(tmp_path.iterdir()) == []


def test_json_roundtrip_of_numbers_is_exact(world: World, tmp_path: Path) -> None:
    """The page writes repr(float); the store keeps canonical JSON: both must give back the very float computed."""
    with Repository.open(None, world.data_dir) as repo:
        stored = repo.results(world.filled.run_id)[-1].result
        page = build_report(repo, world.data_dir, tmp_path / "out", run_id=world.filled.run_id)
    dom = Dom(page.read_text(encoding="utf-8"))  # the data-value attributes as written, no browser needed
    floats = {k: v for k, v in world.filled.result.items() if isinstance(v, float)}
    shown = [k for k in floats if k in dom.fields]
    assert {"mass_kg", "U_kg", "u_kg", "gross_mass_kg", "fixture_mass_kg"} <= set(shown), sorted(floats)
    for key, v in floats.items():
        assert isinstance(stored[key], float) and stored[key].hex() == v.hex(), (key, stored[key], v)
    for key in shown:
        assert set(dom.fields[key]) == {repr(floats[key])}, (key, dom.fields[key])
        assert float(dom.fields[key][0]).hex() == floats[key].hex(), key
