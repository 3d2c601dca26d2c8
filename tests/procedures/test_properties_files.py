"""The properties run's directory and computation (:mod:`rgse_daemon.procedures.properties`) on real KUKA trace
files of the simulated robot: what the daemon stores is what ``rgse mass`` and ``rgse cog`` give on the directory
it writes (one code path), the CoG's warnings are surfaced in the result, and a bad fixture frame is refused with
the setting named."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon.cli import main
from rgse_daemon.pipeline.cog import cog_poses
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.properties import PropertiesSettings, compute_properties, write_properties_dir
from rgse_daemon.procedures.settings import RunSettings
from simulators.krc4 import physics as ph
from tests.support import cogcampaign as cc
from tests.support.cogcal import fit_sim_cog_calibration
from tests.support.simcampaign import ROBOT


def _settings() -> RunSettings:
    return RunSettings(robot=ROBOT, loops=2, settle_s=0.0, trace_period_s=0.012, trace_samples=250,
                       brake_release_deg=35.0, warmup_cycles=0, warmup_amplitude_deg=20.0,
                       fixture_mass_kg=ph.FIXTURE_MASS_KG, payload_lever_max_m=1.0, speed_limit_mm_s=200.0,
                       program_timeout_s=60.0, trace_timeout_s=30.0)


@pytest.mark.slow
def test_the_stored_result_is_what_rgse_mass_and_cog_give_on_its_directory(tmp_path: Path, capsys) -> None:
    cal_doc = fit_sim_cog_calibration(tmp_path / "cal", "paper", seed=4)
    model = ph.RobotModel(seed=8)
    cc.warm_up(model)
    heavy = dataclasses.replace(ph.refex_wing_box(), mass_kg=300.0, cog_dut_m=(-0.02, 0.03, 0.45))
    run = cc.simulate_properties(model, heavy, "paper")
    # the traces as the daemon pulls them (the mass loops are copies of the measurement pose's)
    src = tmp_path / "src"
    cc.write_properties_dir(src, run, robot=ROBOT, measurement_pose_traces=True)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for f in src.iterdir():
        if f.name != "manifest.toml":
            (run_dir / f.name).write_bytes(f.read_bytes())
    man = tomllib.loads((src / "manifest.toml").read_text())
    poses = {p.name: p for p in cog_poses(kin.measurement_pose(), "paper")}
    measured = [(poses[p["name"]], p["traces"]) for p in man["properties"]["pose"]]
    fixture = run.fixture
    write_properties_dir(run_dir, _settings(), man["measurement"]["traces"], "paper", fixture, measured, cal_doc)

    result = compute_properties(run_dir)
    code = main(["cog", "--traces", str(run_dir), "--calibration", str(run_dir / "CAL.json"), "--json"])
    cog = json.loads(capsys.readouterr().out)
    assert code == (4 if cog["warnings"] else 0) and cog["status"] == ("warning" if cog["warnings"] else "ok")
    code = main(["mass", "--traces", str(run_dir), "--calibration", str(run_dir / "CAL.json"), "--json"])
    mass = json.loads(capsys.readouterr().out)
    assert code == (4 if mass["warnings"] else 0)
    assert result["status"] == "warning"  # the daemon's result of the same directory says the same
    assert result["cog_m"] == cog["cog_flange_m"] and result["U_cog_m"] == cog["U_cog_flange_m"]
    assert result["cog_dut_m"] == cog["cog_dut_m"] and result["mass_kg"] == mass["mass_kg"]
    # a 300 kg DuT loads the axes far beyond the torsional points: the result says so
    assert any("outside what the torsional calibration covered" in w for w in result["warnings"]), result["warnings"]


def test_a_fixture_with_mass_but_no_cog_is_refused_naming_the_setting() -> None:
    with pytest.raises(PreconditionError, match=r"properties\.fixture\.cog_flange_m"):
        PropertiesSettings("paper", 1, None).fixture(10.288)
    assert PropertiesSettings("paper", 1, None).fixture(0.0).cog_flange_m == (0.0, 0.0, 0.0)
    with pytest.raises(PreconditionError, match="scheme 'eq5'"):
        PropertiesSettings("eq5", 1, (0.0, 0.0, 0.05)).fixture(10.288)
