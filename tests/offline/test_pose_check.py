"""A DuT's loops recorded in another pose than the calibration's (issue 33, found by the session-20 attack: A3 +10°
weighed a 120 kg DuT at 111.7 ± 2.9 kg, +20° at 93.5 ± 3.0 kg, both with status ok). The torques cannot show it; the
drives' ``Istposition`` can: ``rgse calibrate`` records the pose its loops were recorded in (CAL.json
``measurement_axes_deg``) and ``rgse mass`` sets aside a loop recorded more than 0.1° from it on A3 or A5. Real KUKA
trace files of the simulated KR 500, through the CLI."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon import kinematics as kin
from rgse_daemon.analysis.mass import AXIS_TOLERANCE_DEG, pose_reason
from rgse_daemon.cli import main
from tests.offline.test_integrity import DUT_KG, mass_argv, mass_json, refused
from tests.support.simcampaign import _write_loop, simulate_campaign, simulate_measurement, write_dirs

A3_UP_10 = (0.0, 0.0, 10.0, 0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory) -> tuple[Path, object]:
    root = tmp_path_factory.mktemp("pose")
    camp, model = simulate_campaign(3)
    meas = simulate_measurement(model, DUT_KG, 0.25, n_loops=5)
    write_dirs(camp, meas, root / "cal", root / "dut")
    assert main(["calibrate", "--campaign", str(root / "cal"), "--out", str(root / "CAL.json"),
                 "--method", "axis-quad"]) == 0
    return root, model


def _dut(root: Path, name: str, loops) -> Path:
    """A DuT directory of ``loops`` (real trace files), its manifest the plain DuT's with these traces."""
    d = root / name
    d.mkdir()
    for lp in loops:
        _write_loop(d, lp)
    text = (root / "dut" / "manifest.toml").read_text(encoding="utf-8")
    head = text[:text.index("traces = [")]
    (d / "manifest.toml").write_text(head + "traces = [" + ", ".join(f'"{lp.trace}"' for lp in loops) + "]\n",
                                     encoding="utf-8")
    return d


def test_calibration_records_its_pose_and_a_dut_in_it_is_weighed(calibrated, capsys):
    root, _ = calibrated
    doc = json.loads((root / "CAL.json").read_text())
    q = kin.measurement_pose()
    assert doc["measurement_axes_deg"]["A3"] == pytest.approx(q[2], abs=0.01)
    assert doc["measurement_axes_deg"]["A5"] == pytest.approx(q[4], abs=0.01)
    assert calfile.read(root / "CAL.json").provenance.axes_deg == doc["measurement_axes_deg"]
    res = mass_json(capsys, mass_argv(root / "dut", root / "CAL.json"), "ok")
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_a_dut_recorded_in_another_pose_is_refused_naming_the_pose(calibrated, capsys):
    root, model = calibrated
    off = simulate_measurement(model, DUT_KG, 0.25, n_loops=3, pose_offset_deg=A3_UP_10).loops
    err = refused(capsys, mass_argv(_dut(root, "dut-a3-up", off), root / "CAL.json"))
    assert "measurement refused: 0 loop(s) left" in err
    q = kin.measurement_pose()
    for lp in off:
        assert f"loop {lp.trace}: recorded in another pose than the calibration's (A3 at {q[2] + 10:.3f}° instead " \
               f"of {q[2]:.3f}°; limit 0.1°)" in err, err


def test_one_loop_in_another_pose_is_set_aside_and_the_rest_weighed(calibrated, capsys):
    root, model = calibrated
    good = simulate_measurement(model, DUT_KG, 0.25, n_loops=3).loops
    odd = simulate_measurement(model, DUT_KG, 0.25, n_loops=1, pose_offset_deg=(0, 0, 0, 0, 0.5, 0)).loops[0]
    loops = [*good, dataclasses.replace(odd, trace="dut_l09")]
    res = mass_json(capsys, mass_argv(_dut(root, "dut-one-off", loops), root / "CAL.json"), "warning")
    assert [a["loop"] for a in res["loops_set_aside"]] == ["dut_l09"]
    assert "A5 at" in res["loops_set_aside"][0]["reason"] and "A3 at" not in res["loops_set_aside"][0]["reason"]
    assert res["loops_used"] == [lp.trace for lp in good]
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_the_pose_rule_at_its_limit_and_without_positions():
    cal = {"A3": 10.0, "A5": -20.0}
    assert AXIS_TOLERANCE_DEG == 0.1
    assert pose_reason((10.099, -20.0), cal) is None
    assert pose_reason((10.0, -20.099), cal) is None
    assert "A3 at 10.101° instead of 10.000°" in pose_reason((10.101, -20.0), cal)
    assert "A5 at -20.101° instead of -20.000°" in pose_reason((10.0, -20.101), cal)
    assert pose_reason(None, cal) is None  # a trace without Istposition: nothing to compare
    assert pose_reason((40.0, 0.0), None) is None  # a CAL.json written before the pose was recorded
