"""The campaign's loop screening allows each loop the thermal drift ``measurement.drift_prior_per_k`` bounds
(``rgse calibrate --drift-prior``): the same loop is kept under a wide bound and set aside under a narrow one."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rgse_daemon.analysis.calibration import CampaignData, screen_campaign
from rgse_daemon.cli import main
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from tests.support.simcampaign import simulate_campaign

POINT = 5  # MPA + 5 bodies: A5 reads about -0.77 kNm


def _warm_loop(seed: int, shift_nm: float, warmer_k: float) -> CampaignData:
    """The simulated campaign in memory, its point ``POINT``'s last loop read ``shift_nm`` higher on A5 and
    ``warmer_k`` warmer on both motors: what a drift of |shift| / (|reading| · ΔT) per K would give."""
    camp, _ = simulate_campaign(seed, n_loops=4)
    loops = [[(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point] for point in camp.loops]
    temps = [[(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in point] for point in camp.loops]
    a3, a5, dt = loops[POINT][-1]
    loops[POINT][-1] = (a3, a5 + shift_nm, dt)
    t3, t5 = temps[POINT][-1]
    temps[POINT][-1] = (t3 + warmer_k, t5 + warmer_k)
    return CampaignData(camp.manifest, loops, [], loop_temps_k=temps)


def test_the_drift_prior_sets_the_screenings_thermal_allowance():
    data = _warm_loop(3, shift_nm=-6.0, warmer_k=4.0)
    a5 = float(np.mean(data.loops[POINT][-1][1]))
    # 6 Nm over 4 K on ~770 Nm is 0.19 %/K: within the default 0.3 %/K, far beyond 0.01 %/K
    assert 6.0 / (abs(a5) * 4.0) < DRIFT_PRIOR_PER_K
    wide = screen_campaign(data, pp.PAPER)
    assert [a.loop for _, a in wide.set_aside] == []
    # a bound below the simulated drives' own drift (0.2 %/K) also sets aside the first, cooler loop of other points
    narrow = screen_campaign(data, pp.PAPER, drift_prior_per_k=1e-4)
    reasons = {(i, a.loop): a.reason for i, a in narrow.set_aside}
    assert "disagrees" in reasons[(POINT + 1, data.manifest.points[POINT].traces[-1])]
    assert len(narrow.loops[POINT]) < 4 and len(wide.loops[POINT]) == 4


@pytest.mark.parametrize(("value", "why"), [("0", "a bound on |β| must lie in (0, 0.05] per K"),
                                           ("-0.001", "a bound on |β| must lie in (0, 0.05] per K"),
                                           ("0.06", "a bound on |β| must lie in (0, 0.05] per K"),
                                           ("nan", "must be a finite number")])
def test_calibrate_refuses_a_drift_prior_the_config_would_refuse(value, why, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--campaign", str(tmp_path), "--out", str(tmp_path / "CAL.json"), "--drift-prior", value])
    assert exc.value.code == 2
    assert f"argument --drift-prior: {why}" in capsys.readouterr().err


@pytest.mark.timeout(300)  # four campaign fits: 98-101 s alone at load 3.5, over the default 120 s in a batch
def test_the_prior_reaches_the_screening_through_the_files_from_the_command_line_and_the_daemons_fit(tmp_path,
                                                                                                   capsys):
    """The same warmer loop written as KUKA trace files: ``rgse calibrate --campaign DIR --drift-prior P`` and the
    daemon's campaign fit (``procedures.calibration.fit_campaign``, which its runs call with the settings' prior) keep
    it under the default bound and set it aside, recorded in CAL.json, under a narrow one."""
    from dataclasses import replace

    from rgse_daemon import calfile
    from rgse_daemon.procedures import calibration as procedure
    from tests.support.simcampaign import simulate_measurement, write_dirs

    camp, model = simulate_campaign(3, n_loops=4)
    warm = camp.loops[POINT][-1]
    camp.loops[POINT][-1] = replace(warm, torque_a5_nm=warm.torque_a5_nm - 6.0,
                                    motor_temp_a3_k=warm.motor_temp_a3_k + 4.0,
                                    motor_temp_a5_k=warm.motor_temp_a5_k + 4.0)
    write_dirs(camp, simulate_measurement(model, 50.0, n_loops=1), tmp_path / "cal", tmp_path / "dut")
    key = {"point": POINT + 1, "loop": warm.trace}

    def cli(*prior: str) -> tuple[list[dict], list[str]]:
        """The loops set aside by ``rgse calibrate`` (as CAL.json records them), and what it printed: its JSON
        summary under the default prior, its text under another."""
        capsys.readouterr()
        assert main(["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "cli.json"),
                     "--method", "paper", *prior, *([] if prior else ["--json"])]) == 0
        out, written = capsys.readouterr().out, calfile.read(tmp_path / "cli.json")
        # the prior the screen allowed is recorded with what it set aside: in CAL.json, and in the summary
        assert written.fit.screening_drift_prior_per_k == (float(prior[1]) if prior else DRIFT_PRIOR_PER_K)
        if not prior:
            assert json.loads(out)["screening_drift_prior_per_k"] == DRIFT_PRIOR_PER_K
        return [{"point": a.point, "loop": a.loop} for a in written.fit.set_aside or ()], out.splitlines()

    assert key not in cli()[0]
    aside, lines = cli("--drift-prior", "1e-4")
    assert key in aside
    # rgse calibrate prints the prior with the thermal section, between β and the loops it set aside
    said = ("loop screening allowed a point's loops a thermal drift of up to 0.01 %/K (--drift-prior 0.0001; "
            "CAL.json fit.screening_drift_prior_per_k)")
    assert said in lines, lines[-15:]
    at = lines.index(said)
    assert lines[at - 1].startswith("thermal drift A5 β = ") and lines[at + 1].startswith("set aside: point "), lines
    doc, _ = procedure.fit_campaign(tmp_path / "cal", "paper", 1e-4)
    written = calfile.read(tmp_path / "cal" / "CAL.json")
    assert doc.fit.set_aside == written.fit.set_aside
    assert any(a.point == POINT + 1 and a.loop == warm.trace and "disagrees" in a.reason for a in written.fit.set_aside)
    assert written.fit.screening_drift_prior_per_k == 1e-4
    wide, _ = procedure.fit_campaign(tmp_path / "cal", "paper")
    assert not any(a.loop == warm.trace for a in wide.fit.set_aside or ())
    assert calfile.read(tmp_path / "cal" / "CAL.json").fit.screening_drift_prior_per_k == DRIFT_PRIOR_PER_K

