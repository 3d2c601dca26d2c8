"""Faults a new user's trace files and manifests carry that the issue-33 checks did not cover, through ``rgse
calibrate`` / ``rgse mass`` on real KUKA trace files of the simulated KR 500: a frozen torque channel (a stuck sensor
or a stale trace buffer), and a calibration point whose declared mass is a typo."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.trace import read_trace_file
from simulators.krc4 import physics as ph
from tests.offline.test_integrity import DUT_KG, calibrated_plain, mass_argv, mass_json, refused, run_json
from tests.support.simcampaign import _bodies, _measure, simulate_campaign, simulate_measurement, write_dirs


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    return calibrated_plain(tmp_path_factory.mktemp("faults"))


def copy_dir(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def freeze(directory: Path, trace: str, module: str, offset_nm: float = 0.0, first: int = 0) -> None:
    """Overwrite (in this test's copy) the ``Istmoment`` samples of ``trace``'s ``module`` with one value: the whole
    loop at ``offset_nm`` from the loop's mean (a stale trace buffer), or from sample ``first`` > 0 on the value of
    sample ``first - 1`` (a sensor that stuck there)."""
    tf = read_trace_file(directory / f"{trace}_{module}.dat")
    path = directory / f"{trace}_{module}.r64"
    raw = np.fromfile(path, "<f8").reshape(tf.n_samples, -1)
    col = int(tf.channels["Istmoment"].header[221]) - 1
    raw[first:, col] = raw[first - 1, col] if first > 0 else raw[:, col].mean() + offset_nm
    raw.tofile(path)


def test_a_torque_channel_frozen_in_every_loop_is_refused_not_averaged(plain, tmp_path, capsys):
    """A3's torque stuck at a stale value 60 Nm off (about 5 kg) in every loop: the loops agree with each other
    (each has no scatter at all), so neither the step nor the loop-to-loop check saw it and the mass came out 5.4 kg
    low, U 2.9 kg, status ok. Each loop is now set aside as frozen and the measurement refused, naming the channel."""
    d = copy_dir(plain / "dut", tmp_path / "dut")
    for k in range(1, 6):
        freeze(d, f"dut_l{k:02d}", "NextGenDrive#3", 60.0)
    err = refused(capsys, mass_argv(d, plain / "CAL.json"))
    assert "measurement refused: 0 loop(s) left" in err
    for k in range(1, 6):
        assert f"loop dut_l{k:02d}: A3 torque frozen: " in err
    assert "for 250 of 250 samples in a row (a stuck sensor or a stale trace buffer" in err


def test_one_frozen_loop_is_set_aside_alone_with_its_reason(plain, tmp_path, capsys):
    """Loop 3's A3 torque stuck at its 125th sample for the rest of the loop: it was taken for a step ("the load
    moved during the measurement") and loops 4 and 5 were set aside with it. Now loop 3 alone is set aside, as
    frozen; the mass rests on the four others and covers the truth."""
    d = copy_dir(plain / "dut", tmp_path / "dut")
    freeze(d, "dut_l03", "NextGenDrive#3", first=125)
    res = mass_json(capsys, mass_argv(d, plain / "CAL.json"), "warning")
    assert [a["loop"] for a in res["loops_set_aside"]] == ["dut_l03"], res["loops_set_aside"]
    assert res["loops_set_aside"][0]["reason"].startswith("A3 torque frozen: ")
    assert "for 126 of 250 samples in a row" in res["loops_set_aside"][0]["reason"]
    assert res["loops_used"] == ["dut_l01", "dut_l02", "dut_l04", "dut_l05"]
    assert any(w.startswith("loop dut_l03 set aside: A3 torque frozen") for w in res["warnings"])
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_a_frozen_campaign_loop_is_set_aside_and_recorded(plain, tmp_path, capsys):
    """A frozen A3 channel in one loop of calibration point 6 (whole loop, at its mean + 30 Nm): it was taken for a
    step ("the load moved", 10^12 standard errors), the loop after it set aside too, and the campaign refused
    (point 6 kept 1 of 3 loops). Now it alone is set aside as frozen, recorded in CAL.json, the campaign calibrates
    and the DuT comes out right."""
    cal_dir = copy_dir(plain / "cal", tmp_path / "cal")
    freeze(cal_dir, "cal05_l02", "NextGenDrive#3", 30.0)
    cal = tmp_path / "CAL.json"
    summary = run_json(capsys, ["calibrate", "--campaign", str(cal_dir), "--out", str(cal), "--method",
                                "axis-quad", "--json"])
    assert [(a["point"], a["loop"]) for a in summary["set_aside"]] == [(6, "cal05_l02")]
    assert summary["set_aside"][0]["reason"].startswith("A3 torque frozen: ")
    assert [a.loop for a in calfile.read(cal).fit.set_aside] == ["cal05_l02"]
    res = mass_json(capsys, mass_argv(plain / "dut", cal), "ok")
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]



def copy_loop(directory: Path, source: str, target: str) -> None:
    """Trace ``target``'s files replaced by byte copies of ``source``'s (header and data)."""
    for module in ("NextGenDrive#3", "NextGenDrive#5"):
        for ext in ("dat", "r64"):
            (directory / f"{target}_{module}.{ext}").write_bytes((directory / f"{source}_{module}.{ext}").read_bytes())


def test_loops_that_repeat_another_loop_byte_for_byte_are_set_aside(plain, tmp_path, capsys):
    """Loops 4 and 5 of the DuT are copies of loop 2's files: 5 loops were averaged (loop 2 three times), status ok,
    the loop spread of U narrowed by two loops that were never measured. Now both are set aside naming loop 2, and the
    mass rests on the three loops measured."""
    d = copy_dir(plain / "dut", tmp_path / "dut")
    copy_loop(d, "dut_l02", "dut_l04")
    copy_loop(d, "dut_l02", "dut_l05")
    res = mass_json(capsys, mass_argv(d, plain / "CAL.json"), "warning")
    assert res["loops_used"] == ["dut_l01", "dut_l02", "dut_l03"]
    assert [(a["loop"], a["reason"][:31]) for a in res["loops_set_aside"]] == [
        ("dut_l04", "repeats loop dut_l02 sample for"), ("dut_l05", "repeats loop dut_l02 sample for")]
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_a_campaign_loop_copied_from_another_is_set_aside_and_recorded(plain, tmp_path, capsys):
    """Loop 3 of point 6 is a copy of loop 1's files: set aside naming loop 1 and recorded in CAL.json."""
    cal_dir = copy_dir(plain / "cal", tmp_path / "cal")
    copy_loop(cal_dir, "cal05_l01", "cal05_l03")
    summary = run_json(capsys, ["calibrate", "--campaign", str(cal_dir), "--out", str(tmp_path / "CAL.json"),
                                "--method", "axis-quad", "--json"])
    assert [(a["point"], a["loop"]) for a in summary["set_aside"]] == [(6, "cal05_l03")]
    assert summary["set_aside"][0]["reason"].startswith("repeats loop cal05_l01 sample for sample")
    assert [a.loop for a in calfile.read(tmp_path / "CAL.json").fit.set_aside] == ["cal05_l03"]

@pytest.mark.parametrize("typo_kg,heldout", [(204.65, "+100 kg"), (1046.5, "10x"), (140.65, "digits swapped")])
def test_a_calibration_point_with_a_mistyped_mass_is_refused_naming_it(plain, tmp_path, capsys, typo_kg, heldout):
    """Point 6 of the campaign (5 bodies, 104.65 kg) declared as 204.65 kg or 1046.5 kg: ``rgse calibrate`` wrote a
    calibration either way. With +100 kg its reproducibility term was 35 kg and the DuT's U 70 kg, status ok; with
    10x ``rgse mass`` refused the calibration file itself ("fit.alternatives[2].uncertainty: needs finite
    reproducibility"), naming neither the point nor its mass. Now the campaign is refused, naming point 6, its declared
    mass and the ~104.6 kg its torques weigh by the other points."""
    cal_dir = copy_dir(plain / "cal", tmp_path / "cal")
    manifest = cal_dir / "manifest.toml"
    text = manifest.read_text()
    assert text.count("mass_kg = 104.65\n") == 1
    manifest.write_text(text.replace("mass_kg = 104.65\n", f"mass_kg = {typo_kg!r}\n"))
    err = refused(capsys, ["calibrate", "--campaign", str(cal_dir), "--out", str(tmp_path / "CAL.json"),
                           "--method", "axis-quad"])
    assert err.startswith(f"rgse calibrate: error: {cal_dir}: calibration refused: point 6 (mass_kg {typo_kg:g} kg): "
                          f"the fit on the other points weighs its torques at 10"), (heldout, err)
    assert "is its mass_kg a typo" in err and "point 7" not in err and "point 5 " not in err
    assert not (tmp_path / "CAL.json").exists()


def test_two_points_of_one_load_with_different_masses_are_refused(plain, tmp_path, capsys):
    """Point 7 (6 bodies, 125.58 kg declared) measured with point 6's 5 bodies mounted again: one configuration under
    two masses. ``rgse calibrate`` wrote a calibration (reproducibility 7.4 kg instead of 1.4 kg) saying nothing; now
    point 7 is named, its torques weighing ~104.6 kg by the other points. Its loops copied from point 6's files instead
    are refused as copies, naming them."""
    camp, model = simulate_campaign(3)
    five = ph.Payload((ph.mpa(), *_bodies(camp.body_masses_kg[:5], ph.calibration_stack(5))))
    camp.loops[6] = _measure(model, five, 3, 250, 0.012, "cal06")
    meas = simulate_measurement(model, DUT_KG, 0.25, n_loops=3)
    write_dirs(camp, meas, tmp_path / "cal", tmp_path / "dut")
    argv = ["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "CAL.json"), "--method",
            "axis-quad"]
    err = refused(capsys, argv)
    assert "calibration refused: point 7 (mass_kg 125.58 kg): the fit on the other points weighs its torques at 10" \
        in err, err
    for k in (1, 2, 3):
        copy_loop(tmp_path / "cal", f"cal05_l{k:02d}", f"cal06_l{k:02d}")
    err = refused(capsys, argv)
    assert "calibration point 7 keeps 0 of 3 loops" in err and "loop cal06_l01: repeats loop cal05_l01" in err


def test_a_mistyped_lever_names_the_manifest_and_the_point(plain, tmp_path, capsys):
    """Point 12's lever_a5_m typed 7.94 instead of 0.794: the refusal named the point but no file; it names the
    manifest now."""
    cal_dir = copy_dir(plain / "cal", tmp_path / "cal")
    manifest = cal_dir / "manifest.toml"
    text = manifest.read_text()
    assert text.count("lever_a5_m = 0.794") == 1
    manifest.write_text(text.replace("lever_a5_m = 0.794", "lever_a5_m = 7.94"))
    err = refused(capsys, ["calibrate", "--campaign", str(cal_dir), "--out", str(tmp_path / "CAL.json")])
    assert err.startswith(f"rgse calibrate: error: {manifest}: calibration point 12: expected A3 torque "), err
    assert "(r_A3 − r_A5 must be positive)" in err
