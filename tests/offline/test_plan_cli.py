"""``rgse plan`` end to end, in-process: the points file it writes is a campaign the daemon accepts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rgse_daemon.app import campaign_point
from rgse_daemon.cli import main
from rgse_daemon.client import load_points
from rgse_daemon.commands.plan import check_file
from rgse_daemon.config import load_config
from rgse_daemon.errors import DataError
from rgse_daemon.io.commands import CalibrationPoint
from rgse_daemon.procedures.calibration import check_points_support
from rgse_daemon.procedures.settings import RunSettings


def test_plan_writes_a_points_file_the_daemon_reads_and_accepts(tmp_path, capsys):
    out = tmp_path / "campaign.toml"
    code = main(["plan", "--mass", "50", "250", "--lever-a5", "0.4", "0.9", "--points-out", str(out), "--json"])
    text = capsys.readouterr().out
    assert code == 0 and text.count("\n") == 1
    doc = json.loads(text)
    assert doc["covered"] == doc["duts"] == 81 and doc["uncovered"] == []
    assert doc["points_checked"] == len(doc["points"])
    # read back as `rgse run calibrate --points` reads it, then as the daemon turns it into loads to mount
    points = load_points(out)
    assert [(p.kind, p.mass_kg) for p in points] == [(q["kind"], pytest.approx(q["mass_kg"], abs=1e-4))
                                                    for q in doc["points"]]
    s = RunSettings.from_config(load_config(None))
    camp = [campaign_point(CalibrationPoint.model_validate(p.as_command()), s.g_m_s2) for p in points]
    assert [c.n_cb for c in camp] == [q["bodies"] for q in doc["points"]]
    for c, q in zip(camp, doc["points"], strict=True):
        if q["kind"] == "torque":  # the rail position the operator is asked for is the planned one, on the rail
            assert c.cb_lever_a5_m == pytest.approx(q["cb_lever_a5_m"], abs=2e-3)
            assert 0.60 <= c.cb_lever_a5_m <= 1.50
    check_points_support(camp, "auto", s)  # raises if the campaign cannot give an auto calibration
    # the time the command reports is the sum of its parts
    t = doc["time"]
    assert t["robot_s"] == pytest.approx(t["loops_s"] + t["warmup_initial_s"] + t["rewarm_s"])
    assert t["loops_s"] == pytest.approx(t["loops"] * t["loop_s"])


def test_the_file_check_refuses_a_campaign_the_daemon_would_refuse(tmp_path):
    f = tmp_path / "short.toml"
    f.write_text('[[point]]\nkind = "zero"\nmass_kg = 0.0\nlever_a3_m = 1.29\nlever_a5_m = 0.265\n\n'
                 '[[point]]\nkind = "mass"\nmass_kg = 20.93\nlever_a3_m = 1.3075\nlever_a5_m = 0.2825\n')
    with pytest.raises(DataError, match="refused by the daemon's pre-check"):
        check_file(f, load_config(None))
    f.write_text('[[point]]\nkind = "mass"\nmass_kg = 30.0\nlever_a3_m = 1.3\nlever_a5_m = 0.3\n')
    with pytest.raises(DataError, match="whole number of calibration bodies"):
        check_file(f, load_config(None))


def test_plan_text_names_time_U_and_assumptions(capsys):
    assert main(["plan", "--mass", "50", "250", "--lever-a5", "0.4", "0.9"]) == 0
    out = capsys.readouterr().out
    assert "predicted robot time" in out and "paper: 480 min" in out and "predicted U (k = 2)" in out
    assert "assumptions:" in out and "69 s" in out


@pytest.mark.parametrize(("argv", "word"), [
    (["--mass", "250", "50", "--lever-a5", "0.4", "0.9"], "--mass"),
    (["--mass", "50", "250", "--lever-a5", "-0.4", "0.9"], "--lever-a5"),
    (["--mass", "50", "650", "--lever-a5", "0.4", "0.5"], "611"),
    (["--mass", "50", "500", "--lever-a5", "0.4", "0.9"], "3330"),
    (["--mass", "50", "250"], "--lever-a5"),
    (["--dut", "100", "0.5", "--mass", "50", "250", "--lever-a5", "0.4", "0.9"], "--dut"),
    (["--mass", "50", "250", "--lever-a5", "0.4", "0.9", "--loops-per-point", "0"], "--loops-per-point"),
])
def test_bad_input_exits_2_naming_the_argument(argv, word, capsys):
    assert main(["plan", *argv]) == 2
    assert word in capsys.readouterr().err


def test_duts_the_equipment_cannot_cover_exit_4_and_are_listed(capsys, tmp_path: Path):
    assert main(["plan", "--dut", "80", "0.1", "--dut", "120", "0.6", "--json"]) == 4
    doc = json.loads(capsys.readouterr().out)
    assert doc["duts"] == 2 and doc["covered"] == 1 and "80 kg at 0.1 m" in doc["uncovered"][0]
