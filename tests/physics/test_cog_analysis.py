"""compute_cog and the torsional calibration on the simulated KR C4: refusals, and the CoG of an asymmetric DuT."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon import kinematics as kin
from rgse_daemon.analysis import cog as acog
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import load_manifest
from simulators.krc4 import physics as ph
from tests.support import cogcampaign as cc


def _doc(campaign: cc.TorsionalCampaign) -> calfile.Torsional:
    """The campaign's CAL.json ``torsional`` section, through JSON and back as the daemon reads it."""
    fit = campaign.fit()
    poses = [calfile.TorsionalPose(t.name, t.q_deg, t.reading().torque_nm, t.reading().sigma_nm)
             for t in campaign.bias]
    every = [t.reading() for t in campaign.bias] + [t.reading() for _, _, ts in campaign.points for t in ts]
    tors = calfile.Torsional(campaign.scheme, {p.name: p for p in poses}, dict(fit.gains), dict(fit.evaluations),
                             len(campaign.points), acog.thermal_state_k(every))
    return calfile.parse_torsional(json.loads(json.dumps(calfile.torsional_dict(tors))))


def _cog(readings, tors: calfile.Torsional | None, **kw) -> acog.CogResult:
    return acog.compute_cog(readings, tors, g_m_s2=9.81, calibration_id="sim", **kw)


@pytest.fixture(scope="module")
def measured():
    model = ph.RobotModel(seed=5)
    cc.warm_up(model)
    campaign = cc.simulate_torsional(model, "full", seed=5)
    run = cc.simulate_properties(model, ph.refex_wing_box(), "full")
    return campaign, run


def test_old_calibration_without_torsional_section_is_refused(measured):
    _, run = measured
    with pytest.raises(DataError, match=r"CAL.json: the calibration has no 'torsional' section"):
        _cog([t.reading() for t in run.poses], None, mass_kg=107.3, u_mass_kg=0.1,
                         fixture=run.fixture)


def test_missing_pose_bias_is_named(measured):
    campaign, run = measured
    full = _doc(campaign)
    doc = dataclasses.replace(full, poses={k: v for k, v in full.poses.items() if k != "A5-45"})
    with pytest.raises(DataError, match=r"CAL.json: torsional section has no bias for pose 'A5-45'"):
        _cog([t.reading() for t in run.poses], doc, mass_kg=107.3, u_mass_kg=0.1, fixture=run.fixture)


def test_bad_inputs_are_refused(measured):
    campaign, run = measured
    doc = _doc(campaign)
    readings = [t.reading() for t in run.poses]
    with pytest.raises(DataError, match="mass"):
        _cog(readings, doc, mass_kg=float("nan"), u_mass_kg=0.1, fixture=run.fixture)
    moved = [acog.PoseReading(readings[0].pose, (0.0, -90.0, 90.0, 0.0, 3.0, 0.0), readings[0].torque_nm,
                              readings[0].sigma_nm), *readings[1:]]
    with pytest.raises(DataError, match="differs from the calibration's"):
        _cog(moved, doc, mass_kg=107.3, u_mass_kg=0.1, fixture=run.fixture)
    with pytest.raises(DataError, match="fixture frame"):
        acog.FixtureFrame(-1.0, (0.0, 0.0, 0.0))
    with pytest.raises(DataError, match="do not determine"):
        _cog(readings[:1], doc, mass_kg=107.3, u_mass_kg=0.1, fixture=run.fixture)


def test_cog_of_the_wing_box_across_the_launch_axis(measured):
    """Across the flange axis (x, y) the CoG is within the ECSS ±1 mm and U covers it; along it (z) see bench/cog.py:
    the calibration bodies' seating scatter limits z to several mm."""
    campaign, run = measured
    res = _cog([t.reading() for t in run.poses], _doc(campaign), mass_kg=107.3, u_mass_kg=0.15,
                           fixture=run.fixture)
    err_mm = (np.array(res.cog_flange_m) - run.true_cog_flange_m) * 1000.0
    U_mm = np.array(res.U_cog_flange_m) * 1000.0
    assert np.all(np.abs(err_mm[:2]) < 1.0), err_mm
    assert np.all(np.abs(err_mm) <= U_mm), (err_mm, U_mm)
    assert np.all(U_mm[:2] < 2.0) and U_mm[2] < 15.0
    # the DuT frame: the same point, rotated 90° about the flange axis
    dut = run.dut
    true_dut = dut.rotation.T @ (run.true_cog_flange_m - np.array(dut.dut_origin_flange_m))
    np.testing.assert_allclose(res.cog_dut_m, true_dut, atol=np.max(U_mm) / 1000.0)
    assert res.U_cog_dut_m[0] == pytest.approx(res.U_cog_flange_m[1]) and res.scheme == "full"
    assert res.to_json()["k"] == 2 and res.n_poses == 8


def test_eq5_7_levers_beside_the_least_squares(measured):
    """The paper's eq. 5–7 (A5 at 0°, A6 at 0° and 90°, K applied) give the levers of fixture + DuT: a to the A5
    axis, b and c the flange-transverse offsets; within a few mm of the least-squares CoG (they cannot remove the
    mounting's offsets)."""
    campaign, run = measured
    res = _cog([t.reading() for t in run.poses], _doc(campaign), mass_kg=107.3, u_mass_kg=0.0,
                           fixture=run.fixture)
    lev = res.budget["eq5_7_levers_m"]
    m_fix, c_fix = ph.FIXTURE_MASS_KG, np.array(ph.fixture_cog_flange_m())
    total = (107.3 * np.array(res.cog_flange_m) + m_fix * c_fix) / (107.3 + m_fix)
    assert lev["a"] == pytest.approx(kin.D6_M + total[2], abs=0.01)
    assert sorted(abs(v) for v in (lev["b"], lev["c"])) == pytest.approx(sorted(abs(v) for v in total[:2]), abs=0.005)


def _write(tmp_path, text: str):
    (tmp_path / "manifest.toml").write_text(text, encoding="utf-8")
    return tmp_path


SETUP = '[setup]\nrobot = "R"\ng = 9.81\nlever_difference_m = 1.025\n'


@pytest.mark.parametrize(("body", "message"), [
    ("", "no \\[properties\\] table"),
    ('[properties]\nscheme = "full"\n[properties.fixture]\nmass_kg = 1.0\ncog_flange_m = [0, 0, 0]\n',
     "no mass_kg and no \\[measurement\\] loops"),
    ('[properties]\nmass_kg = -3.0\n', "mass_kg must be > 0"),
    ('[properties]\nmass_kg = 10.0\n[properties.fixture]\nmass_kg = 1.0\n', "needs mass_kg and cog_flange_m"),
    ('[properties]\nmass_kg = 10.0\n[properties.fixture]\nmass_kg = 1.0\ncog_flange_m = [0, 0, 0]\n',
     "needs \\[\\[properties.pose\\]\\] entries"),
    ('[properties]\nmass_kg = 10.0\n[properties.fixture]\nmass_kg = 1.0\ncog_flange_m = [0, 0, 0]\n'
     '[[properties.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0]\ntraces = ["t1"]\n', "q_deg must be six"),
    ('[properties]\nmass_kg = 10.0\n[properties.fixture]\nmass_kg = 1.0\ncog_flange_m = [0, 0, 0]\n'
     '[[properties.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0, 0, 0]\ntraces = ["../t1"]\n', "t1"),
    ('[properties]\nmass_kg = 10.0\n[properties.fixture]\nmass_kg = 1.0\ncog_flange_m = [0, 0, 0]\n'
     '[[properties.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0, 0, 0]\ntraces = ["t1"]\n', "no trace files"),
])
def test_a_bad_properties_directory_is_named(tmp_path, body, message):
    with pytest.raises(DataError, match=message) as err:
        acog.read_properties_dir(_write(tmp_path, SETUP + body))
    assert "manifest.toml" in str(err.value) or "t1" in str(err.value)


@pytest.mark.parametrize(("body", "message"), [
    ('[[point]]\nkind = "torsional"\nmass_kg = 0.0\ncog_flange_m = [0, 0, 0]\n[point.poses]\nmeas = ["a"]\n',
     "need a \\[torsional\\] table"),
    ('[torsional]\nscheme = "paper"\n[[torsional.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0, 0, 0]\n'
     '[[point]]\nkind = "torsional"\nmass_kg = 0.0\ncog_flange_m = [0, 0]\n[point.poses]\nmeas = ["a"]\n',
     "cog_flange_m = \\[x, y, z\\]"),
    ('[torsional]\nscheme = "paper"\n[[torsional.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0, 0, 0]\n'
     '[[point]]\nkind = "torsional"\nmass_kg = 0.0\ncog_flange_m = [0, 0, 0]\n[point.poses]\nA6 = ["a"]\n',
     "exactly the poses meas"),
    ('[torsional]\nscheme = "paper"\n[[torsional.pose]]\nname = "meas"\nq_deg = [0, -90, 90, 0, 0, 0]\n'
     '[[point]]\nkind = "torsional"\nmass_kg = 20.0\ncog_flange_m = [0, 0, 0.3]\n[point.poses]\nmeas = ["a"]\n',
     "one with mass_kg = 0"),
])
def test_a_bad_torsional_manifest_is_named(tmp_path, body, message):
    with pytest.raises(DataError, match=message) as err:
        load_manifest(_write(tmp_path, SETUP + body))
    assert "manifest.toml" in str(err.value)


def test_a_thermal_mismatch_with_the_torsional_campaign_is_warned(measured):
    campaign, run = measured
    doc = _doc(campaign)
    readings = [t.reading() for t in run.poses]
    same = _cog(readings, doc, mass_kg=107.3, u_mass_kg=0.1, fixture=run.fixture)
    assert not any("motor temperatures" in w for w in same.warnings), same.warnings
    warmer = [dataclasses.replace(r, motor_temp_k=tuple(t + 5.0 for t in r.motor_temp_k)) for r in readings]
    res = _cog(warmer, doc, mass_kg=107.3, u_mass_kg=0.1, fixture=run.fixture)
    assert any("motor temperatures in the CoG poses differ" in w and "A5 +5." in w for w in res.warnings)


def test_a_dut_beyond_the_calibrated_torques_is_warned(measured):
    """A 300 kg DuT loads A3..A5 far beyond the torsional points (at most 126 kg): the result says so (U does not
    cover an extrapolated K)."""
    campaign, _ = measured
    model = ph.RobotModel(seed=6)
    cc.warm_up(model)
    heavy = dataclasses.replace(ph.refex_wing_box(), mass_kg=300.0, cog_dut_m=(-0.02, 0.03, 0.45))
    run = cc.simulate_properties(model, heavy, "full")
    res = _cog([t.reading() for t in run.poses], _doc(campaign), mass_kg=300.0, u_mass_kg=1.0,
                           fixture=run.fixture)
    assert any("outside what the torsional calibration covered" in w for w in res.warnings), res.warnings
