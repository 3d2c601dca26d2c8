"""Issue 33 through ``rgse calibrate`` / ``rgse mass`` on real KUKA trace files of the simulated KR 500: a knocked
loop named and set aside, missing samples (DIAdem's no-value marker) in every channel alike, a campaign with one
gapped loop that still calibrates, and the thermal drift left uncorrected where the campaign does not resolve it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.config import config_from_mapping
from rgse_daemon.errors import EXIT_OK, EXIT_WARNINGS
from rgse_daemon.manifest import load_manifest
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.procedures import measurement
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.trace import read_trace_file
from tests.support.simcampaign import Knock, simulate_campaign, simulate_measurement, with_gap, write_dirs

DUT_KG = 120.0


def run_json(capsys, argv: list[str]) -> dict:
    capsys.readouterr()
    assert main(argv) == EXIT_OK
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    return json.loads(out)


def mass_json(capsys, argv: list[str], status: str) -> dict:
    """``rgse mass --json``'s result, with the ``status`` it is expected to have: ``ok`` (exit 0, no warnings) or
    ``warning`` (exit 4, EXIT_WARNINGS, and the warnings to read)."""
    capsys.readouterr()
    code = main(argv)
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    res = json.loads(out)
    assert (res["status"], code) == (status, {"ok": EXIT_OK, "warning": EXIT_WARNINGS}[status]), res["warnings"]
    assert bool(res["warnings"]) == (status == "warning")
    return res


def refused(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and err.count("\n") == 0, err
    return err


def mass_argv(dut: Path, cal: Path) -> list[str]:
    return ["mass", "--traces", str(dut), "--calibration", str(cal), "--json"]


def _campaign(root: Path, seed: int = 3, knock: Knock | None = None, n_loops: int = 5, gaps=None,
              temperature_gaps=None, **campaign_kw):
    camp, model = simulate_campaign(seed, **campaign_kw)
    if gaps:
        camp.loops[:] = [[gaps.get(lp.trace, lambda x: x)(lp) for lp in point] for point in camp.loops]
    meas = simulate_measurement(model, DUT_KG, 0.25, n_loops=n_loops, knock=knock)
    write_dirs(camp, meas, root / "cal", root / "dut", temperature_gaps)
    return camp, meas


def calibrated_plain(root: Path) -> Path:
    """A campaign and a clean 5-loop DuT on the simulated robot in ``root``, calibrated (axis-quad)."""
    _campaign(root)
    assert main(["calibrate", "--campaign", str(root / "cal"), "--out", str(root / "CAL.json"),
                 "--method", "axis-quad"]) == 0
    return root


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    return calibrated_plain(tmp_path_factory.mktemp("integrity"))


def test_a_clean_measurement_sets_nothing_aside(plain, capsys):
    res = mass_json(capsys, mass_argv(plain / "dut", plain / "CAL.json"), "ok")
    assert res["loops_used"] == [f"dut_l{k:02d}" for k in range(1, 6)] and res["loops_set_aside"] == []
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_a_knocked_loop_is_named_and_set_aside_with_the_loops_after_it(plain, tmp_path, capsys):
    """The load is knocked in the middle of loop 3 (A3 +15 Nm, A5 −10 Nm, about 2.5 kg): loop 3 holds a step and
    is set aside, and so are loops 4 and 5 measured after it; the mass rests on loops 1 and 2 and covers the truth."""
    _campaign(tmp_path, knock=Knock(2, 0.5, 15.0, -10.0))
    res = mass_json(capsys, mass_argv(tmp_path / "dut", plain / "CAL.json"), "warning")
    aside = {a["loop"]: a["reason"] for a in res["loops_set_aside"]}
    assert res["loops_used"] == ["dut_l01", "dut_l02"] and res["loops"] == 2
    assert "a step of" in aside["dut_l03"] and "inside the loop" in aside["dut_l03"]
    assert "after the step in loop dut_l03" in aside["dut_l04"] and "dut_l05" in aside
    assert any(w.startswith("loop dut_l03 set aside: a step") for w in res["warnings"])
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]
    capsys.readouterr()
    assert main(["mass", "--traces", str(tmp_path / "dut"), "--calibration", str(plain / "CAL.json")]) == EXIT_WARNINGS
    text = capsys.readouterr().out
    assert text.startswith("status: warning (")
    assert "loops used: dut_l01, dut_l02" in text and "set aside: loop dut_l03: a step of" in text


def test_a_knock_in_the_first_loop_leaves_too_few_and_is_refused_with_the_reason(plain, tmp_path, capsys):
    _campaign(tmp_path, knock=Knock(0, 0.4, 15.0, -10.0))
    err = refused(capsys, mass_argv(tmp_path / "dut", plain / "CAL.json"))
    assert "measurement refused: 0 loop(s) left" in err and "loop dut_l01: a step of" in err
    assert "re-mount the DuT and measure again" in err


@pytest.mark.parametrize("module,channel", [("NextGenDrive#3", "Istmoment"), ("NextGenDrive#5", "Istmoment"),
                                            ("NextGenDrive#3", "Motortemperatur"),
                                            ("NextGenDrive#5", "Motortemperatur")])
def test_no_value_samples_are_missing_samples_in_every_channel_alike(plain, tmp_path, capsys, module, channel):
    """DIAdem's no-value marker (global header code 111) in any channel of a DuT loop: a missing sample, never a
    refusal; a short gap leaves the loop in use, a long one in a torque channel sets it aside with its reason."""
    clean = mass_json(capsys, mass_argv(plain / "dut", plain / "CAL.json"), "ok")
    for length, name in ((0.1, "short"), (0.7, "long")):
        d = tmp_path / name
        d.mkdir()
        for f in (plain / "dut").iterdir():
            (d / f.name).write_bytes(f.read_bytes())
        dat = d / f"dut_l02_{module}.dat"
        tf = read_trace_file(dat)
        raw = np.fromfile(d / f"dut_l02_{module}.r64", "<f8").reshape(tf.n_samples, -1)
        n = tf.n_samples
        assert float(tf.global_header[111]) == 9.9e34
        raw[n // 5: n // 5 + int(length * n), int(tf.channels[channel].header[221]) - 1] = 9.9e34
        raw.tofile(d / f"dut_l02_{module}.r64")
        assert read_trace_file(dat).channel(channel).n_missing == int(length * n)
        # a temperature gap leaves the loop's temperature to the samples there are, nothing to warn of; a torque gap
        # is said (the short one's loop kept with a warning, the long one's set aside)
        res = mass_json(capsys, mass_argv(d, plain / "CAL.json"), "ok" if channel == "Motortemperatur" else "warning")
        if channel == "Motortemperatur":  # the loop's temperature from the samples there are
            assert res["loops_used"] == clean["loops_used"] and res["motor_temp_k"] == pytest.approx(
                clean["motor_temp_k"], abs=0.05)
        elif name == "short":
            assert "dut_l02" in res["loops_used"]
            assert any(w.startswith(f"loop dut_l02: {int(length * n)} of") for w in res["warnings"]), res["warnings"]
        else:
            assert [a["loop"] for a in res["loops_set_aside"]] == ["dut_l02"]
            assert "samples missing" in res["loops_set_aside"][0]["reason"]
        assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]


def test_a_campaign_with_one_gapped_loop_still_calibrates_and_says_what_it_set_aside(tmp_path, capsys):
    """One loop of one point lost 70 % of its samples in every channel (written as no value), another 10 % of its
    A5 torque: the first is set aside and recorded in CAL.json and the printout, the second used; the campaign
    calibrates, and a DuT measured with it comes out right."""
    gaps = {"cal05_l02": lambda lp: with_gap(lp, "all", 0.2, 0.7), "cal12_l01": lambda lp: with_gap(lp, "A5", 0.5, 0.1)}
    _campaign(tmp_path, seed=4, gaps=gaps, temperature_gaps={"cal05_l02": slice(50, 225)})
    cal = tmp_path / "CAL.json"
    summary = run_json(capsys, ["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(cal), "--method",
                                "axis-quad", "--json"])
    assert [(a["point"], a["loop"]) for a in summary["set_aside"]] == [(6, "cal05_l02")]
    assert "samples missing" in summary["set_aside"][0]["reason"]
    doc = calfile.read(cal)
    assert [{"point": a.point, "loop": a.loop, "reason": a.reason} for a in doc.fit.set_aside] == summary["set_aside"]
    res = mass_json(capsys, mass_argv(tmp_path / "dut", cal), "ok")
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]
    capsys.readouterr()
    assert main(["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "again.json"),
                 "--method", "axis-quad"]) == 0
    assert "set aside: point 6 loop cal05_l02: 175 of 250 samples missing" in capsys.readouterr().out


def test_a_point_left_with_too_few_loops_refuses_the_campaign_naming_point_and_loops(tmp_path, capsys):
    gaps = {f"cal03_l0{k}": (lambda lp: with_gap(lp, "A3", 0.1, 0.8)) for k in (1, 2)}
    _campaign(tmp_path, seed=4, gaps=gaps)
    err = refused(capsys, ["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "CAL.json"),
                           "--method", "axis-quad"])
    assert "calibration point 4 keeps 1 of 3 loops, fewer than the 2 it needs" in err
    assert "loop cal03_l01: 200 of 250 samples missing" in err and "cal03_l02" in err


def test_beta_fitted_on_a_small_span_is_not_applied_and_u_carries_the_drift(tmp_path, capsys):
    """A warm, steady campaign (loops 0.2 K apart within a point) and a DuT measured 12 K cooler: β is printed
    with its uncertainty and span and not applied; U carries the prior's bound, a warning says how to avoid it."""
    _campaign(tmp_path, seed=2, n_loops=3, warm_s=3600.0, change_s=5.0, loop_s=40.0)
    cal = tmp_path / "CAL.json"
    capsys.readouterr()
    assert main(["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(cal), "--method", "axis-quad"]) == 0
    text = capsys.readouterr().out
    assert "thermal drift A5 β = " in text and "not resolved (its loops spanned 0." in text and "not applied" in text
    doc = calfile.read(cal)
    assert doc.fit.thermal.span_k["A5"] < 0.5
    res = mass_json(capsys, mass_argv(tmp_path / "dut", cal), "warning")
    assert res["thermal_applied"] == {"A3": False, "A5": False}
    assert any(w.startswith("thermal drift of A5 not corrected") and "Measure the DuT at the campaign's motor "
               "temperature" in w for w in res["warnings"]), res["warnings"]
    assert res["u_components_kg"]["thermal"] > 0
    assert abs(res["mass_kg"] - DUT_KG) <= res["U_kg"]
    # the daemon's path: the config's measurement.drift_prior_per_k → the run's settings → its result and the stop
    # rule's budget, the same computation as `rgse mass --drift-prior` (the span resolves nothing: U carries the prior)
    assert config_from_mapping({}).measurement.drift_prior_per_k == DRIFT_PRIOR_PER_K
    cfg = config_from_mapping({"measurement": {"drift_prior_per_k": DRIFT_PRIOR_PER_K / 2}}, "<drift prior>")
    man = load_manifest(tmp_path / "dut")
    s = RunSettings.from_config(cfg, robot=man.setup.robot, g_m_s2=man.setup.g_m_s2,
                                lever_difference_m=man.setup.lever_difference_m,
                                fixture_mass_kg=man.fixture_mass_kg or 0.0)
    assert s.drift_prior_per_k == DRIFT_PRIOR_PER_K / 2
    run_dir = tmp_path / "run"
    shutil.copytree(tmp_path / "dut", run_dir)
    traces, cal_doc = list(man.measurement_traces), json.loads(cal.read_text())
    daemon = measurement._finish(run_dir, s, traces, cal_doc)
    assert daemon["loops_used"] == res["loops_used"] and daemon["mass_kg"] == res["mass_kg"]
    assert daemon["u_components_kg"]["thermal"] == pytest.approx(res["u_components_kg"]["thermal"] / 2)
    assert daemon["U_kg"] < res["U_kg"]
    again = mass_json(capsys, [*mass_argv(run_dir, run_dir / "CAL.json"), "--drift-prior",
                               str(DRIFT_PRIOR_PER_K / 2)], "warning")
    assert again["U_kg"] == pytest.approx(daemon["U_kg"])  # reproducible offline with the run's prior
    screened = measurement.screen_loops(run_dir, s, traces, cal_doc)
    assert screened is not None and screened.budget is not None
    assert screened.budget[0] == pytest.approx(daemon["u_kg"])


def test_a_dut_in_the_gap_between_mass_stack_and_torque_rows_is_outside(plain, tmp_path, capsys):
    """150 kg with its CoG 0.7 m out: (M_A3, M_A5) ≈ (−3.1, −1.5) kNm lies inside the box of the campaign's torques
    but between the mass stack (A5 ≤ 0.84 kNm) and the torque rows (A5 ≥ 2.1 kNm), far from every calibrated
    configuration: outside, with a warning saying so and a U that covers the truth."""
    camp, model = simulate_campaign(3)
    meas = simulate_measurement(model, 150.0, 0.7, n_loops=3)
    write_dirs(camp, meas, tmp_path / "cal", tmp_path / "dut")
    res = mass_json(capsys, mass_argv(tmp_path / "dut", plain / "CAL.json"), "warning")
    assert res["operating_point"] == "outside"
    assert any("from the nearest calibrated configuration" in w for w in res["warnings"]), res["warnings"]
    # the widening comes from the calibration's own held-out configurations at their distance (out of sample)
    assert any("U widened by what the calibration's own held-out configurations erred at that distance" in w
               for w in res["warnings"]), res["warnings"]
    assert abs(res["mass_kg"] - 150.0) <= res["U_kg"]
    doc = calfile.read(plain / "CAL.json")
    assert len(doc.fit.envelope.points_nm) == 14
