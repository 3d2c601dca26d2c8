"""``rgse study``: the pre-processing parameter study (paper Table A2), ranked.

With ``--campaign`` the whole grid crop σ × filter × window × order is run on the campaign's traces and each
combination is ranked by the mass error of the paper's calibration method. With ``--points`` (pre-averaged
torques, nothing left to pre-process) the calibration models are ranked by their leave-one-out error.

On a terminal, progress bars on stderr follow the loops, combinations or models; stdout carries only the result.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rgse_daemon import robots
from rgse_daemon.analysis.calibration import load_campaign, points_from_raw
from rgse_daemon.commands import add_json
from rgse_daemon.kinematics import G_PAPER_M_S2
from rgse_daemon.manifest import load_points_csv
from rgse_daemon.pipeline.study import StudyGrid, rank_models, run_study
from rgse_daemon.progress import stage_progress

TOP_ROWS = 20


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse study``."""
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--campaign", type=Path, metavar="DIR")
    src.add_argument("--points", type=Path, metavar="CSV")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    if args.points is not None:
        points = load_points_csv(args.points)
        with stage_progress() as progress:
            # the paper's g (site figure) and the active robot's Δr (its measurement pose)
            evs = rank_models(points, G_PAPER_M_S2, robots.active().lever_difference_m, progress)
        rows = [{"method": e.method, "n_params": e.n_params, "in_sample_mean_abs_err_pct": e.in_sample_mean_abs_err_pct,
                 "loo_mean_abs_err_pct": e.loo_mean_abs_err_pct, "loo_max_abs_err_kg": e.loo_max_abs_err_kg}
                for e in evs]
        if args.json:
            print(json.dumps({"kind": "models", "rows": rows}))
        else:
            print(f"{'rank':>4s} {'method':18s} {'params':>6s} {'in-sample %':>12s} {'LOO %':>8s} {'LOO max kg':>11s}")
            for i, r in enumerate(rows, 1):
                print(f"{i:4d} {r['method']:18s} {r['n_params']:6d} {r['in_sample_mean_abs_err_pct']:12.4f} "
                      f"{r['loo_mean_abs_err_pct']:8.4f} {r['loo_max_abs_err_kg']:11.3f}")
        return 0
    data = load_campaign(args.campaign)
    setup = data.manifest.setup
    grid = StudyGrid()
    with stage_progress() as progress:
        result = run_study(data.loops, lambda r3, r5: points_from_raw(data.manifest, r3, r5)[0], grid,
                           "paper", setup.g_m_s2, setup.lever_difference_m, progress)
    if args.json:
        print(json.dumps({"kind": "preprocessing", "method": "paper", "combinations": grid.size,
                          "rows": [r.to_dict() for r in result]}))
    else:
        print(f"{grid.size} combinations, ranked by mass error of the paper's calibration (top {TOP_ROWS}):")
        print(f"{'rank':>4s} {'crop':>5s} {'filter':15s} {'window':>6s} {'order':9s} {'mass err %':>10s} "
              f"{'R2 A3':>7s} {'R2 A5':>7s}")
        for i, r in enumerate(result[:TOP_ROWS], 1):
            crop = "none" if r.crop_sigma is None else f"{r.crop_sigma:g}σ"
            print(f"{i:4d} {crop:>5s} {r.filter:15s} {r.window:6d} {r.order:9s} {r.mass_err_pct:10.4f} "
                  f"{r.r2_a3:7.4f} {r.r2_a5:7.4f}")
        if result:
            # ranked on the campaign's own points: in-sample, so optimistic (check with the LOO of rgse calibrate)
            print(f"use the best: rgse calibrate --campaign {args.campaign} --preprocessing {result[0].spec} ...")
    return 0
