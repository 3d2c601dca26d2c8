"""CAL.json and `rgse calibrate --out` as outside input: nothing is overwritten but a calibration, an edited
calibration is refused, implausible values name their key, and a DuT that cannot be what the calibration measured
(sign-flipped torque channels, a gross load below the fixture, another pose or g) is refused in one line."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.errors import DataError
from tests.support.campaign import Drive, write_measurement
from tests.support.cli import fitted_dirs, one_line_error


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fitted_dirs(tmp_path_factory.mktemp("calfile"), "axis-linear")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()



# --- --out never overwrites raw data ----------------------------------------------------------------------------
@pytest.mark.parametrize("target", ["cal/manifest.toml", "cal/cal00_l01_NextGenDrive#3.r64",
                                    "cal/cal03_l02_NextGenDrive#5.trc"])
def test_calibrate_out_onto_an_input_is_refused_and_the_input_kept(capsys, dirs, target):
    path = dirs / target
    assert path.is_file(), sorted(p.name for p in (dirs / "cal").iterdir())[:6]
    before = _digest(path)
    err = one_line_error(capsys, ["calibrate", "--campaign", str(dirs / "cal"), "--out", str(path)])
    assert "not a calibration file" in err and str(path) in err, err
    assert _digest(path) == before


def test_calibrate_out_onto_the_points_csv_is_refused(capsys, tmp_path, paper_dir):
    csv = tmp_path / "t1.csv"
    csv.write_bytes((paper_dir / "table1_calibration.csv").read_bytes())
    before = _digest(csv)
    err = one_line_error(capsys, ["calibrate", "--points", str(csv), "--out", str(csv)])
    assert "not a calibration file" in err, err
    assert _digest(csv) == before


def test_calibrate_out_onto_something_not_a_regular_file_is_refused(capsys, dirs, tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    err = one_line_error(capsys, ["calibrate", "--campaign", str(dirs / "cal"), "--out", str(fifo)])
    assert "not a regular file" in err, err
    assert fifo.is_fifo()


def test_calibrate_out_onto_a_calibration_keeps_the_old_one_beside_it(capsys, dirs, tmp_path):
    out = tmp_path / "CAL.json"
    assert main(["calibrate", "--campaign", str(dirs / "cal"), "--out", str(out), "--method", "axis-linear"]) == 0
    old_id = json.loads(out.read_text())["calibration_id"]
    capsys.readouterr()
    assert main(["calibrate", "--campaign", str(dirs / "cal"), "--out", str(out), "--method", "ratio-linear"]) == 0
    assert f"is kept as {tmp_path / f'CAL.{old_id}.json'}" in capsys.readouterr().err
    assert json.loads((tmp_path / f"CAL.{old_id}.json").read_text())["calibration_id"] == old_id
    assert json.loads(out.read_text())["method"] == "ratio-linear"


# --- an edited calibration ----------------------------------------------------------------------------------------
def _edited(dirs: Path, tmp_path: Path, edit, *, reseal: bool) -> Path:
    doc = json.loads((dirs / "CAL.json").read_text())
    edit(doc)
    path = tmp_path / "CAL.json"
    path.write_text(json.dumps(calfile.seal(doc) if reseal else doc))
    return path


def _scale_a3(doc: dict) -> None:
    doc["models"]["A3"]["coef"][0] *= 1.1


@pytest.mark.parametrize("edit", [_scale_a3, lambda d: d["bias_nm"].update(A3=d["bias_nm"]["A3"] + 200.0),
                                  lambda d: d.update(calibration_id="0" * 16)])
def test_a_calibration_edited_after_its_fit_is_refused(capsys, dirs, tmp_path, edit):
    bad = _edited(dirs, tmp_path, edit, reseal=False)
    err = one_line_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(bad)])
    assert "does not match its calibration_id" in err and str(bad) in err, err


@pytest.mark.parametrize(("edit", "needle"), [
    (lambda d: d.update(g=0.0), "g = 0.0 m/s² is outside the plausible 9.7..9.9"),
    (lambda d: d.update(g=-9.81), "g = -9.81"),
    (lambda d: d.update(lever_difference_m=-1.025), "lever_difference_m = -1.025 is outside the plausible"),
    (lambda d: d.update(lever_difference_m=1e-300), "lever_difference_m"),
    (lambda d: d["preprocessing"].update(settle_s=float("nan")), "settle_s must be a number"),
    (lambda d: d["preprocessing"].update(settle_s=1e308), "settle_s must be a number"),
    (lambda d: d["preprocessing"].update(window=2.5), "window must be a whole number"),
    (lambda d: d["fit"].update(sample_period_s="4 ms"), "fit.sample_period_s must be a finite number, got '4 ms'"),
    (lambda d: d["fit"].update(sample_period_s=float("nan")), "fit.sample_period_s must be a finite number, got nan"),
    (lambda d: d["fit"].update(sample_period_s=True), "fit.sample_period_s must be a finite number, got True"),
    (lambda d: d["fit"].update(sample_period_s=12), "fit.sample_period_s = 12 s is outside the plausible 0.0005..1 s"),
    (lambda d: d["fit"].update(sample_period_s=0.0), "fit.sample_period_s = 0.0 s is outside the plausible"),
    (lambda d: d["fit"].update(sample_period_s=-0.004), "fit.sample_period_s = -0.004 s is outside the plausible"),
])
def test_implausible_values_in_a_sealed_calibration_name_their_key(capsys, dirs, tmp_path, edit, needle):
    bad = _edited(dirs, tmp_path, edit, reseal=True)
    err = one_line_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(bad)])
    assert needle in err and str(bad) in err, err
    with pytest.raises(DataError, match=re.escape(needle)):  # refused on reading, whatever reads it
        calfile.read(bad)


# --- a DuT the calibration cannot have measured ------------------------------------------------------------------
def test_sign_flipped_torque_channels_are_refused(capsys, dirs, tmp_path):
    write_measurement(tmp_path / "dut", 100.0, seed=6, n_samples=300, n_loops=3,
                      drive=Drive(sign_a3=-1.0, sign_a5=-1.0))
    err = one_line_error(capsys, ["mass", "--traces", str(tmp_path / "dut"), "--calibration", str(dirs / "CAL.json")])
    assert "refused" in err and "A3 torque -" in err, err


def test_a_gross_load_below_the_fixture_is_refused(capsys, dirs):
    err = one_line_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(dirs / "CAL.json"),
                                  "--fixture-mass", "1000"])
    assert "below zero" in err and "fixture" in err, err


@pytest.mark.parametrize(("old", "new", "needle"), [("g = 9.81", "g = 9.5", "g = 9.5 m/s² is outside the plausible"),
                                                    ("lever_difference_m = 1.025", "lever_difference_m = 1.1",
                                                     "are not the calibration's")])
def test_a_measurement_in_another_pose_or_at_another_g_is_refused(capsys, dirs, tmp_path, old, new, needle):
    dut = tmp_path / "dut"
    shutil.copytree(dirs / "dut", dut)
    text = (dut / "manifest.toml").read_text()
    assert old in text
    (dut / "manifest.toml").write_text(text.replace(old, new))
    err = one_line_error(capsys, ["mass", "--traces", str(dut), "--calibration", str(dirs / "CAL.json")])
    assert needle in err, err
