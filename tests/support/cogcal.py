"""A CAL.json with a torsional (CoG) section for the simulated KR 500, fitted offline as ``rgse calibrate --campaign``
does: the mass campaign of :mod:`tests.support.simcampaign` plus the torsional points of
:mod:`tests.support.cogcampaign` in one campaign directory (same physics as the simulated KR C4)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rgse_daemon.analysis.calibration import fit_campaign
from tests.support import cogcampaign as cc
from tests.support import simcampaign as sc


def fit_sim_cog_calibration(directory: Path, scheme: str = "paper", seed: int = 5) -> dict[str, Any]:
    """CAL.json (as a dict) with mass and torsional sections; the torsional points measured in ``scheme``'s poses."""
    campaign, model = sc.simulate_campaign(seed, n_loops=2)
    sc.write_dirs(campaign, sc.simulate_measurement(model, 50.0, n_loops=1), directory / "campaign",
                  directory / "dut")
    cc.warm_up(model)
    torsional = cc.simulate_torsional(model, scheme, seed=seed)
    lines = cc.torsional_manifest_lines(directory / "campaign", torsional)
    with (directory / "campaign" / "manifest.toml").open("a", encoding="utf-8") as f:
        f.write("\n" + "\n".join(lines))
    doc, _ = fit_campaign(directory / "campaign", "auto")
    return doc.to_dict()
