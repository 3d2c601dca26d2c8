"""``rgse calibrate`` / ``rgse mass`` / ``rgse study`` end to end, in-process, on generated directories."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.pipeline.calibration import MODELS
from tests.support.campaign import Drive, write_campaign, write_measurement
from tests.support.cli import fitted_dirs


def run_json(capsys, argv: list[str]) -> dict:
    code = main(argv)
    out = capsys.readouterr().out
    assert out.count("\n") == 1  # exactly one JSON object
    doc = json.loads(out)
    # rgse mass: exit 0 for a result without warnings, 4 with warnings (interfaces §1.1); the other commands 0
    assert code == (4 if doc.get("status") == "warning" else 0), (code, doc.get("status"), doc.get("warnings"))
    return doc


def test_calibrate_points_paper_and_auto(tmp_path, capsys, paper_dir):
    csv = str(paper_dir / "table1_calibration.csv")
    paper = run_json(capsys, ["calibrate", "--points", csv, "--out", str(tmp_path / "p.json"), "--json"])
    assert paper["method"] == "paper"
    assert paper["in_sample_mean_abs_err_pct"] == pytest.approx(0.6986, abs=0.05)
    assert paper["points"] == 14
    auto = run_json(capsys, ["calibrate", "--points", csv, "--out", str(tmp_path / "a.json"), "--method", "auto",
                             "--json"])
    assert auto["loo_mean_abs_err_pct"] < paper["loo_mean_abs_err_pct"]
    assert {m["method"] for m in auto["models"]} >= {"paper", "gain-linear"}
    doc = json.loads((tmp_path / "a.json").read_text())
    assert doc["schema"] == 1 and doc["method"] == auto["method"] and doc["calibration_id"] == auto["calibration_id"]
    assert set(doc["source_sha256"]) == {"table1_calibration.csv"}


def test_calibrate_text_output_says_whose_nested_figure_it_is_and_gives_r2(tmp_path, capsys, paper_dir):
    """The nested out-of-sample figure is always auto's selection, whatever was fitted; R² is printed."""
    csv = str(paper_dir / "table1_calibration.csv")
    assert main(["calibrate", "--points", csv, "--out", str(tmp_path / "p.json"), "--method", "paper"]) == 0
    out = capsys.readouterr().out
    assert "out of sample of --method auto (nested: " in out and "not of the paper calibration written" in out
    assert "R² of the K fits: A3 0.8922, A5 " in out and "(CAL.json fit.r2)" in out
    assert "trace sample period" not in out  # averaged points carry no period
    r2 = json.loads((tmp_path / "p.json").read_text())["fit"]["r2"]
    assert f"{r2['A3']:.4f}" == "0.8922"
    assert main(["calibrate", "--points", csv, "--out", str(tmp_path / "a.json"), "--method", "auto"]) == 0
    out = capsys.readouterr().out
    assert "out of sample of --method auto (nested: " in out and "not of the" not in out


@pytest.mark.parametrize(("seed", "sign", "period_s", "factor", "storage"), [
    (0, 1.0, 0.004, 1.0, "BLOCK"),
    (1, -1.0, 0.012, 0.5, "CHANNEL"),
    (2, 1.0, 0.001, 2.0, "BLOCK"),
])
def test_campaign_then_mass_recovers_truth(tmp_path, capsys, seed, sign, period_s, factor, storage):
    drive = Drive(sign_a3=sign, sign_a5=sign, gain_a3=1.09 + 0.01 * seed, gain_a5=0.86 + 0.01 * seed)
    kw = {"drive": drive, "period_s": period_s, "factor": factor, "storage": storage}
    write_campaign(tmp_path / "cal", seed=seed, **kw)
    true_dut = 60.0 + 40.0 * seed
    write_measurement(tmp_path / "dut", true_dut, seed=seed + 100, **kw)
    cal = run_json(capsys, ["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "CAL.json"),
                            "--method", "auto", "--json"])
    assert cal["loo_mean_abs_err_pct"] < 0.3
    res = run_json(capsys, ["mass", "--traces", str(tmp_path / "dut"), "--calibration", str(tmp_path / "CAL.json"),
                            "--json"])
    assert abs(res["mass_kg"] - true_dut) < 0.5
    assert res["k"] == 2 and res["U_kg"] == pytest.approx(2 * res["u_kg"])
    assert abs(res["mass_kg"] - true_dut) <= res["U_kg"] + 0.2
    assert res["loops"] == 5 and res["fixture_mass_kg"] == pytest.approx(10.288)
    assert 0 < res["samples_used"] <= res["samples_total"] == 5 * 1500
    assert res["calibration_id"] == cal["calibration_id"]
    # CAL.json records the campaign's period; a DuT traced at the same one draws no period warning
    assert json.loads((tmp_path / "CAL.json").read_text())["fit"]["sample_period_s"] == period_s
    assert not any("sample period" in w for w in res["warnings"]), res["warnings"]
    fixed = run_json(capsys, ["mass", "--traces", str(tmp_path / "dut"), "--calibration",
                              str(tmp_path / "CAL.json"), "--fixture-mass", "0", "--json"])
    assert fixed["mass_kg"] == pytest.approx(res["gross_mass_kg"])


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    return fitted_dirs(tmp_path_factory.mktemp("offline"), "gain-linear", n_samples=600)


def expect_error(capsys, argv: list[str], needle: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "error:" in err and needle in err, err
    assert "Traceback" not in err
    return err


def test_operating_point_outside_widens_u_and_far_outside_is_refused(tmp_path, capsys, dirs):
    """A DuT a little heavier than every calibration load: a warning, U widened by the admissible models' spread;
    far heavier: refused with the reason, unless the limit is raised."""
    inside = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(dirs / "CAL.json"),
                               "--json"])
    assert inside["operating_point"] == "inside"
    assert not any("envelope" in w for w in inside["warnings"])
    write_measurement(tmp_path / "heavy", 420.0, seed=7, n_samples=600, n_loops=2)
    res = run_json(capsys, ["mass", "--traces", str(tmp_path / "heavy"), "--calibration", str(dirs / "CAL.json"),
                            "--json"])
    assert res["operating_point"] == "outside"
    assert any("outside the calibrated envelope" in w and "A3 torque" in w for w in res["warnings"])
    assert abs(res["mass_kg"] - 420.0) <= res["U_kg"]
    write_measurement(tmp_path / "big", 600.0, seed=7, n_samples=600, n_loops=2)
    expect_error(capsys, ["mass", "--traces", str(tmp_path / "big"), "--calibration", str(dirs / "CAL.json")],
                 "far outside the calibrated envelope")
    res = run_json(capsys, ["mass", "--traces", str(tmp_path / "big"), "--calibration", str(dirs / "CAL.json"),
                            "--envelope-limit", "2", "--json"])
    assert res["operating_point"] == "outside" and res["U_kg"] > 0


def test_status_exit_4_for_warnings_and_a_json_refusal_is_one_object_with_its_reason(tmp_path, capsys, dirs):
    """interfaces §1.1/§1.3: a result with warnings is status "warning" and exit 4 (the text says so first); a
    refusal with --json prints one JSON object on stdout, status "refused" with the reason, and exits 2."""
    write_measurement(tmp_path / "heavy", 420.0, seed=7, n_samples=600, n_loops=2)
    argv = ["mass", "--traces", str(tmp_path / "heavy"), "--calibration", str(dirs / "CAL.json")]
    assert main([*argv, "--json"]) == 4
    res = json.loads(capsys.readouterr().out)
    assert res["status"] == "warning" and res["warnings"]
    assert main(argv) == 4
    out = capsys.readouterr().out
    assert out.startswith(f"status: warning ({len(res['warnings'])} warning(s)") and "warning: " in out
    ok = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(dirs / "CAL.json"), "--json"])
    assert ok["status"] == ("warning" if ok["warnings"] else "ok")

    write_measurement(tmp_path / "big", 600.0, seed=7, n_samples=600, n_loops=2)
    assert main(["mass", "--traces", str(tmp_path / "big"), "--calibration", str(dirs / "CAL.json"), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out.count("\n") == 1, captured.out  # exactly one JSON object
    refused = json.loads(captured.out)
    assert refused["status"] == "refused" and "far outside the calibrated envelope" in refused["reason"]
    assert refused["error"] == "OperatingPointError" and refused["warnings"] == []
    assert "far outside the calibrated envelope" in captured.err  # the line on stderr stays


def test_missing_trace(tmp_path, capsys, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    (d / "dut_l02_NextGenDrive#5.dat").unlink()
    expect_error(capsys, ["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json")], "dut_l02")


def test_truncated_r64(tmp_path, capsys, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    f = d / "dut_l01_NextGenDrive#3.r64"
    f.write_bytes(f.read_bytes()[:-12])
    expect_error(capsys, ["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json")], "dut_l01")


def test_nan_in_trace_is_a_missing_sample_the_loop_is_used_without_it(tmp_path, capsys, dirs):
    """A NaN in the file is a missing sample (issue 33): left out, the loop used, the result says so."""
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    f = d / "dut_l03_NextGenDrive#3.r64"
    raw = np.fromfile(f, "<f8")
    raw[raw.size // 2] = np.nan
    raw.tofile(f)
    res = run_json(capsys, ["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json"), "--json"])
    assert "dut_l03" in res["loops_used"] and res["loops_set_aside"] == []
    assert any("loop dut_l03: 1 of" in w and "samples missing" in w for w in res["warnings"]), res["warnings"]


def test_manifest_names_absent_trace(tmp_path, capsys, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    m = d / "manifest.toml"
    m.write_text(m.read_text().replace('"dut_l03"', '"dut_l09"'))
    expect_error(capsys, ["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json")], "dut_l09")


def test_calibration_of_another_robot(tmp_path, capsys, dirs):
    write_measurement(tmp_path / "other", 50.0, seed=8, n_samples=300, n_loops=2, robot="KR500R2830-OTHER")
    expect_error(capsys, ["mass", "--traces", str(tmp_path / "other"), "--calibration", str(dirs / "CAL.json")],
                 "KR500R2830-OTHER")


def test_bad_calibration_and_manifest(tmp_path, capsys, dirs):
    bad = tmp_path / "CAL.json"
    doc = json.loads((dirs / "CAL.json").read_text())
    doc["schema"] = 7
    bad.write_text(json.dumps(doc))
    expect_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(bad)], str(bad))
    d = tmp_path / "cal"
    shutil.copytree(dirs / "cal", d)
    (d / "manifest.toml").write_text('[setup]\nrobot = "x"\ng = "fast"\nlever_difference_m = 1.0\n')
    expect_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")], "manifest.toml")
    expect_error(capsys, ["calibrate", "--points", str(tmp_path / "none.csv"), "--out", str(tmp_path / "o.json")],
                 "none.csv")


def test_points_csv_with_nan(tmp_path, capsys, paper_dir):
    text = (paper_dir / "table1_calibration.csv").read_text().replace("495.68", "nan")
    p = Path(tmp_path / "t.csv")
    p.write_text(text)
    expect_error(capsys, ["calibrate", "--points", str(p), "--out", str(tmp_path / "o.json")], "t.csv")


def test_study_points_ranks_every_model(tmp_path, capsys, paper_dir):
    """``rgse study --points``: every model of the catalogue once, ranked by its leave-one-out error, with the figures
    ``rgse calibrate`` gives the same model; the printed table in the same order."""
    csv = str(paper_dir / "table1_calibration.csv")
    res = run_json(capsys, ["study", "--points", csv, "--json"])
    assert res["kind"] == "models"
    methods = [r["method"] for r in res["rows"]]
    assert sorted(methods) == sorted(MODELS)  # Table 1's 14 points fit every model of the catalogue
    loo = [r["loo_mean_abs_err_pct"] for r in res["rows"]]
    assert loo == sorted(loo)
    paper = run_json(capsys, ["calibrate", "--points", csv, "--out", str(tmp_path / "p.json"), "--method", "paper",
                              "--json"])
    row = res["rows"][methods.index("paper")]
    assert row["loo_mean_abs_err_pct"] == pytest.approx(paper["loo_mean_abs_err_pct"], rel=1e-12)
    assert row["in_sample_mean_abs_err_pct"] == pytest.approx(paper["in_sample_mean_abs_err_pct"], rel=1e-12)
    assert main(["study", "--points", csv]) == 0
    table = capsys.readouterr().out.splitlines()
    assert [line.split()[:2] for line in table[1:]] == [[str(i), m] for i, m in enumerate(methods, 1)]


def test_study_campaign_end_to_end(capsys, dirs):
    res = run_json(capsys, ["study", "--campaign", str(dirs / "cal"), "--json"])
    assert res["kind"] == "preprocessing" and res["method"] == "paper"
    rows = res["rows"]
    assert 0 < len(rows) <= res["combinations"]
    errs = [r["mass_err_pct"] for r in rows]
    assert errs == sorted(errs) and all(np.isfinite(errs))
    assert {r["filter"] for r in rows} == {"moving_average", "gaussian", "median"}
    assert {r["order"] for r in rows} == {"backward", "forward"}
    # linear drive, 1 % spikes: the best combination recovers the masses well, and the ranking spreads
    assert errs[0] < 0.5 and errs[0] < errs[-1]
    assert main(["study", "--campaign", str(dirs / "cal")]) == 0
    assert "combinations" in capsys.readouterr().out


def test_study_best_row_feeds_calibrate_and_mass(tmp_path, capsys, dirs):
    """The study's best row as ``--preprocessing``: recorded in CAL.json, and ``rgse mass`` pre-processes with it."""
    rows = run_json(capsys, ["study", "--campaign", str(dirs / "cal"), "--json"])["rows"]
    best = rows[0]
    spec = best["preprocessing"]
    cal = run_json(capsys, ["calibrate", "--campaign", str(dirs / "cal"), "--out", str(tmp_path / "CAL.json"),
                            "--method", "paper", "--preprocessing", spec, "--json"])
    doc = json.loads((tmp_path / "CAL.json").read_text(encoding="utf-8"))
    assert doc["preprocessing"] == {"crop_sigma": best["crop_sigma"], "filter": best["filter"],
                                    "window": best["window"], "order": best["order"], "location": best["location"],
                                    "settle_s": 0.0}
    paper = run_json(capsys, ["calibrate", "--campaign", str(dirs / "cal"), "--out", str(tmp_path / "F.json"),
                              "--method", "paper", "--json"])
    assert cal["calibration_id"] != paper["calibration_id"]  # another pre-processing, another calibration
    mass = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(tmp_path / "CAL.json"),
                             "--json"])
    assert mass["calibration_id"] == cal["calibration_id"] and np.isfinite(mass["mass_kg"])


@pytest.mark.parametrize(("spec", "needle"), [
    ("window=abc", "not a number"),
    ("filter=kalman", "unknown filter"),
    ("colour=red", "KEY one of crop_sigma"),
    ("window=5,window=7", "window given twice"),
    ("crop_sigma=-1", "crop_sigma must be a finite number > 0"),
    ("settle_s=inf", "settle_s must be a number 0..3600 s"),
])
def test_calibrate_refuses_a_bad_preprocessing_spec(tmp_path, capsys, dirs, spec, needle):
    expect_error(capsys, ["calibrate", "--campaign", str(dirs / "cal"), "--out", str(tmp_path / "o.json"),
                          "--preprocessing", spec], needle)
    assert not (tmp_path / "o.json").exists()


def test_calibration_file_of_the_former_schema_still_reads(tmp_path, capsys, dirs):
    """A CAL.json written before held-out validation, bootstrap and envelope existed: the former five-term budget."""
    doc = json.loads((dirs / "CAL.json").read_text())
    for key in ("validation", "uncertainty", "envelope"):
        del doc["fit"][key]
    for alt in doc["fit"]["alternatives"]:
        alt.pop("uncertainty", None)
    old = tmp_path / "old.json"
    old.write_text(json.dumps(calfile.seal(doc)))  # as the former version wrote it, sealed over what it held
    res = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(old), "--json"])
    assert set(res["u_components_kg"]) == {"loops", "calibration", "model", "reference", "g"}
    new = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(dirs / "CAL.json"),
                            "--json"])
    assert "reproducibility" in new["u_components_kg"]
    assert res["mass_kg"] == pytest.approx(new["mass_kg"])
    doc["fit"]["uncertainty"] = {"reproducibility": {"rms_a3_nm": 1.0}}
    old.write_text(json.dumps(calfile.seal(doc)))
    expect_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(old)], "fit.uncertainty")


PERIOD_WARNING = ("trace sample period 12 ms differs from the calibration campaign's 4 ms: the moving_average window "
                  "of 150 samples spans 1.8 s instead of 0.6 s, and the calibration was not validated at this rate; "
                  "record the DuT at 4 ms or calibrate at 12 ms")


def test_a_measurement_at_another_trace_period_than_the_calibration_draws_a_warning(tmp_path, capsys, dirs):
    """The campaign was traced at 4 ms (CAL.json fit.sample_period_s); a DuT traced at 12 ms is measured, with a
    warning naming both periods in the JSON result and the printed one. A warning only: U is not widened for it."""
    assert json.loads((dirs / "CAL.json").read_text())["fit"]["sample_period_s"] == 0.004
    write_measurement(tmp_path / "dut12", 100.0, seed=6, n_samples=600, n_loops=3, period_s=0.012)
    argv = ["mass", "--traces", str(tmp_path / "dut12"), "--calibration", str(dirs / "CAL.json")]
    res = run_json(capsys, [*argv, "--json"])
    assert PERIOD_WARNING in res["warnings"], res["warnings"]
    assert abs(res["mass_kg"] - 100.0) <= res["U_kg"]
    same = run_json(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(dirs / "CAL.json"), "--json"])
    assert not any("sample period" in w for w in same["warnings"]), same["warnings"]
    assert set(res["u_components_kg"]) == set(same["u_components_kg"])
    assert main(argv) == 4  # a result with warnings (interfaces §1.1)
    assert f"warning: {PERIOD_WARNING}\n" in capsys.readouterr().out
    # rgse calibrate's summary names the period to measure at (a points CSV has none, and says nothing)
    assert main(["calibrate", "--campaign", str(dirs / "cal"), "--out", str(tmp_path / "again.json")]) == 0
    assert "trace sample period 4 ms: measure the DuT at the same period\n" in capsys.readouterr().out


def test_a_calibration_without_its_sample_period_still_measures_unchecked(tmp_path, capsys, dirs):
    """A CAL.json written before fit.sample_period_s existed loads and measures a DuT at any period, the same mass
    as with the period recorded; there is nothing to compare, so no period warning (interfaces §3)."""
    doc = json.loads((dirs / "CAL.json").read_text())
    del doc["fit"]["sample_period_s"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(calfile.seal(doc)))  # as the former version wrote it, sealed over what it held
    write_measurement(tmp_path / "dut12", 100.0, seed=6, n_samples=600, n_loops=3, period_s=0.012)
    res = run_json(capsys, ["mass", "--traces", str(tmp_path / "dut12"), "--calibration", str(old), "--json"])
    assert not any("sample period" in w for w in res["warnings"]), res["warnings"]
    new = run_json(capsys, ["mass", "--traces", str(tmp_path / "dut12"), "--calibration", str(dirs / "CAL.json"),
                            "--json"])
    assert PERIOD_WARNING in new["warnings"]
    assert res["mass_kg"] == new["mass_kg"] and res["U_kg"] == new["U_kg"]


def test_calibrate_says_when_the_torques_do_not_follow_the_loads(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Issue #34: a campaign on an empty flange (every point reads about the same torque) failed with "no admissible
    start (degenerate calibration factors)", a symptom of the fit; now the cause is named."""
    table1 = Path(__file__).resolve().parents[2] / "data" / "paper" / "table1_calibration.csv"
    lines = table1.read_text().splitlines()
    data = [ln for ln in lines if ln.strip() and not ln.startswith("#")]
    header = data[0].split(",")
    flat = [data[0]]
    for k, row in enumerate(data[1:]):
        cells = row.split(",")
        for col in ("m_a3_measured_nm", "m_a5_measured_nm"):
            cells[header.index(col)] = f"{0.5 + 0.01 * k:g}"
        flat.append(",".join(cells))
    csv = tmp_path / "empty_flange.csv"
    csv.write_text("\n".join(flat) + "\n")
    assert main(["calibrate", "--points", str(csv), "--out", str(tmp_path / "CAL.json")]) == 2
    err = capsys.readouterr().err
    assert "do not follow the calibration loads" in err and "were the loads mounted" in err, err
    assert not (tmp_path / "CAL.json").exists()
