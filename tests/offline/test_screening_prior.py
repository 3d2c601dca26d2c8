"""The campaign's loop screening allows each loop the thermal drift ``measurement.drift_prior_per_k`` bounds
(``rgse calibrate --drift-prior``): the same loop is kept under a wide bound and set aside under a narrow one."""

from __future__ import annotations

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


def test_the_daemons_campaign_fit_takes_the_configs_prior(monkeypatch, tmp_path):
    """procedures.calibration.fit_campaign hands its prior to the screening (the daemon's campaign: RunSettings'
    drift_prior_per_k from ``measurement.drift_prior_per_k``)."""
    from rgse_daemon.analysis import calibration as analysis
    from rgse_daemon.procedures import calibration as procedure

    seen: list[float] = []

    class Seen(Exception):
        pass

    def fake_fit(directory, method, pre=pp.PAPER, drift_prior_per_k=DRIFT_PRIOR_PER_K):
        seen.append(drift_prior_per_k)
        raise Seen

    monkeypatch.setattr(analysis, "fit_campaign", fake_fit)
    with pytest.raises(Seen):
        procedure.fit_campaign(tmp_path, "auto", 0.0012)
    assert seen == [0.0012]


def test_the_prior_reaches_the_screening_from_the_command_line_and_the_daemons_campaign(monkeypatch, tmp_path):
    """``rgse calibrate --campaign DIR --drift-prior P`` and the daemon's campaign (its settings' prior, after the
    manifest is written) both hand P to the fit: not only the bound's refusals."""
    from types import SimpleNamespace

    from rgse_daemon.commands import calibrate as command
    from rgse_daemon.procedures import calibration as procedure

    seen: list[float] = []

    class Seen(Exception):
        pass

    def fake_fit(directory, method, pre=pp.PAPER, drift_prior_per_k=DRIFT_PRIOR_PER_K):
        seen.append(drift_prior_per_k)
        raise Seen

    monkeypatch.setattr(command, "fit_campaign", fake_fit)
    with pytest.raises(Seen):
        main(["calibrate", "--campaign", str(tmp_path), "--out", str(tmp_path / "CAL.json"), "--drift-prior", "0.0007"])
    monkeypatch.setattr(procedure, "write_campaign_manifest", lambda run_dir, s, points: None)
    monkeypatch.setattr(procedure.campaign_analysis, "fit_campaign", fake_fit)
    with pytest.raises(Seen):
        procedure._finish(tmp_path, SimpleNamespace(drift_prior_per_k=0.0009), [], "auto")
    assert seen == [0.0007, 0.0009]
