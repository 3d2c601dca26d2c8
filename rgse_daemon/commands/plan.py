"""``rgse plan --mass KG KG --lever-a5 M M [--dut KG M ...] [--config FILE] [--loops-per-point N]
[--max-distance D] [--points-out FILE.toml] [--json]``: the calibration campaign for the DuTs a lab will measure.

From a DuT range (mass of what is mounted on the MPA, kg, and its CoG lever along the flange axis from A5, m) or a
list of DuTs (``--dut KG M``, repeated), the planner (:mod:`rgse_daemon.pipeline.planning`) proposes the calibration
points with their loops, checks that every DuT lies inside the calibration's envelope and near a calibrated point,
and predicts the campaign's robot time and the U it will give. ``--points-out`` writes the points as ``rgse run
calibrate --points`` reads them; the file is read back with the daemon's own schema (``load_points``) and the
campaign's pre-check (``check_points_support``, ``--method auto``) before the command says it is written.

Exit 0: every DuT covered; 4: some are not (listed); 2: bad input (the argument named).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon.app import campaign_point
from rgse_daemon.client import load_points
from rgse_daemon.commands import add_json, finite
from rgse_daemon.config import Config, load_config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import EXIT_OK, EXIT_WARNINGS, ConfigError, DataError, RgseError
from rgse_daemon.io.commands import CalibrationPoint
from rgse_daemon.pipeline import planning as pl
from rgse_daemon.procedures import calibration as cal
from rgse_daemon.procedures.preconditions import PreconditionError
from rgse_daemon.procedures.settings import RunSettings

METHOD = "auto"


def equipment(cfg: Config | None = None) -> pl.Equipment:
    """The paper's calibration equipment, as the campaign procedure mounts it, within the configured load diagram
    (``[limits] max_payload_kg``, ``max_a5_torque_nm``)."""
    lim = {} if cfg is None else {"max_payload_kg": cfg.limits.max_payload_kg,
                                  "max_a5_torque_nm": cfg.limits.max_a5_torque_nm}
    return pl.Equipment(cal.CB_MASS_KG, cal.ZERO_LEVER_A5_M, cal.STACK_LEVER_A5_M, cal.STACK_STEP_M, cal.TA_MASS_KG,
                        cal.TA_TORQUE_A5_NM, **lim)


def time_model(cfg: Config) -> pl.TimeModel:
    """The time model with the lab's settling, recording and warm-up settings (robot time, s)."""
    ms = cfg.measurement
    return pl.TimeModel(settle_s=ms.settle_s, record_s=ms.trace_samples * ms.trace_period_s,
                        warmup_initial_s=ms.warmup_max_s if ms.warmup_cycles > 0 else 0.0,
                        warmup_initial_min_s=(ms.warmup_steady_window_s if ms.warmup_until_steady else 0.0)
                        if ms.warmup_cycles > 0 else 0.0,
                        rewarm_s=ms.warmup_steady_window_s if ms.warmup_cycles > 0 and ms.warmup_until_steady
                        else 0.0)


def make_plan(args: argparse.Namespace, cfg: Config) -> pl.Plan:
    eq = equipment(cfg)
    if args.dut:
        if args.mass is not None or args.lever_a5 is not None:
            raise DataError("--dut: give either DuTs or --mass/--lever-a5, not both")
        mass = np.array([d[0] for d in args.dut], float)
        lever = np.array([d[1] for d in args.dut], float)
        pl.dut_targets(mass, lever, eq, names=("--dut", "--dut"))
    else:
        if args.mass is None or args.lever_a5 is None:
            raise DataError("give --mass KG KG and --lever-a5 M M (or --dut KG M, repeated)")
        mass, lever = pl.grid(tuple(args.mass), tuple(args.lever_a5), eq)
    return pl.plan(mass, lever, eq, loops=args.loops_per_point, max_distance=args.max_distance,
                   tm=time_model(cfg))


def check_file(path: Path, cfg: Config) -> int:
    """The points file read back as the daemon reads it, and the campaign's pre-check for ``auto``."""
    points = load_points(path)
    s = RunSettings.from_config(cfg)
    try:
        camp = [campaign_point(CalibrationPoint.model_validate(p.as_command()), s.g_m_s2) for p in points]
        cal.check_points_support(camp, METHOD, s)
    except (PreconditionError, RgseError) as exc:
        raise DataError(f"{path}: the planned campaign is refused by the daemon's pre-check: {exc}") from None
    lo, hi = equipment().rail_a5_m
    for i, c in enumerate(camp, 1):
        if c.cb_lever_a5_m is not None and not lo <= c.cb_lever_a5_m <= hi:
            raise DataError(f"{path} [[point]] #{i}: the bodies would sit at {c.cb_lever_a5_m:.5f} m from A5, off the "
                            f"test adapter's rail ({lo:g}..{hi:g} m)")
    return len(camp)


def to_json(p: pl.Plan, args: argparse.Namespace) -> dict[str, Any]:
    c, t = p.coverage, p.time
    finite_U = p.U_kg[np.isfinite(p.U_kg)]
    return {
        "points": [{"kind": q.kind, "bodies": q.n_cb, "mass_kg": q.mass_kg, "lever_a3_m": q.lever_a3_m,
                    "lever_a5_m": q.lever_a5_m, "cb_lever_a5_m": q.cb_lever_a5_m, "loops": q.loops,
                    "label": q.label} for q in p.points],
        "loaded_points": p.loaded,
        "duts": len(c.mass_kg), "covered": int(c.covered.sum()), "uncovered": p.uncovered,
        "max_distance": c.max_distance, "max_distance_found": float(c.distance.max()),
        "time": {"loops": t.loops, "loop_s": t.loop_s, "loops_s": t.loops_s,
                 "warmup_initial_s": t.warmup_initial_s, "warmup_initial_min_s": t.warmup_initial_min_s,
                 "rewarm_s": t.rewarm_s, "robot_s": t.robot_s, "robot_min_s": t.robot_min_s,
                 "load_changes_s": t.load_changes_s, "campaign_s": t.campaign_s},
        "paper_campaign_min": pl.PAPER_CAMPAIGN_MIN, "paper_campaign_points": pl.PAPER_CAMPAIGN_POINTS,
        "predicted_U_kg": [float(finite_U.min()), float(finite_U.max())] if finite_U.size else None,
        "predicted_U_rel_pct": ([float(np.nanmin(100 * p.U_kg / c.mass_kg)), float(np.nanmax(100 * p.U_kg / c.mass_kg))]
                                if finite_U.size else None),
        "prediction": True, "assumptions": p.assumptions,
        "points_out": None if args.points_out is None else str(args.points_out),
    }


def print_plan(out: dict[str, Any]) -> None:
    print(f"{'#':>2} {'load':<40} {'mass kg':>8} {'l_A3 m':>7} {'l_A5 m':>7} {'loops':>5}")
    for i, q in enumerate(out["points"], 1):
        print(f"{i:>2} {q['label']:<40} {q['mass_kg']:>8.2f} {q['lever_a3_m']:>7.4f} {q['lever_a5_m']:>7.4f} "
              f"{q['loops']:>5}")
    t = out["time"]
    print(f"{len(out['points'])} points ({out['loaded_points']} loaded), {t['loops']} loops; DuTs covered "
          f"{out['covered']}/{out['duts']} (nearest calibrated point at most {out['max_distance_found']:.2f} of the "
          f"range, bound {out['max_distance']:g})")
    print(f"predicted robot time: loops {t['loops_s'] / 60:.1f} min ({t['loops']} x {t['loop_s']:.0f} s; the "
          f"campaign result's robot_time_s) + first warm-up {t['warmup_initial_min_s'] / 60:.0f}-"
          f"{t['warmup_initial_s'] / 60:.0f} min + re-warm-ups {t['rewarm_s'] / 60:.0f} min = "
          f"{t['robot_min_s'] / 60:.1f}-{t['robot_s'] / 60:.1f} min (paper: {out['paper_campaign_min']:g} min for "
          f"{out['paper_campaign_points']} points); with load changes {t['campaign_s'] / 60:.0f} min")
    if out["predicted_U_kg"] is not None:
        lo, hi = out["predicted_U_kg"]
        rlo, rhi = out["predicted_U_rel_pct"]
        print(f"predicted U (k = 2) over the covered DuTs: {lo:.2f}-{hi:.2f} kg ({rlo:.1f}-{rhi:.1f} % of the mass): "
              f"a prediction from the stated model, not a result")
    for u in out["uncovered"]:
        print(f"not covered: {u}")
    print("assumptions:")
    for a in out["assumptions"]:
        print(f"  - {a}")
    if out["points_out"]:
        print(f"points file: {out['points_out']} (rgse run calibrate --points {out['points_out']})")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse plan``."""
    p.add_argument("--mass", type=finite, nargs=2, metavar=("KG", "KG"),
                   help="the DuTs' mass range (what is mounted on the MPA), kg")
    p.add_argument("--lever-a5", type=finite, nargs=2, metavar=("M", "M"),
                   help="the DuTs' CoG lever range along the flange axis from A5, m")
    p.add_argument("--dut", type=finite, nargs=2, action="append", metavar=("KG", "M"),
                   help="one DuT (mass, lever from A5), instead of a range; repeat for a list")
    p.add_argument("--loops-per-point", type=int, default=3, metavar="N", help="loops per point (default 3)")
    p.add_argument("--max-distance", type=finite, default=0.15, metavar="D",
                   help="a DuT is covered within D of a calibrated point (torque over the range's largest, per axis)")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (settling, warm-up)")
    p.add_argument("--points-out", type=Path, metavar="FILE.toml", help="write the points for rgse run calibrate")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    if args.loops_per_point < 1:
        raise ConfigError(f"--loops-per-point {args.loops_per_point}: must be >= 1")
    p = make_plan(args, cfg)
    out = to_json(p, args)
    if args.points_out is not None:
        t = p.time
        header = [f"rgse plan: {len(p.points)} calibration points for {len(p.coverage.mass_kg)} DuT operating points "
                  f"({out['covered']} covered)",
                  f"predicted robot time {t.robot_min_s / 60:.0f}-{t.robot_s / 60:.0f} min (loops "
                  f"{t.loops_s / 60:.1f} min), {p.points[0].loops} loops a point; run it with",
                  f"  rgse run calibrate --config FILE --points {args.points_out.name} --method auto",
                  "bodies: calibration bodies of 20.93 kg to mount (on the MPA, or on the test adapter for a torque "
                  "point)"]
        write_atomic(args.points_out, pl.points_toml(p.points, equipment(), header))
        out["points_checked"] = check_file(args.points_out, cfg)
    if args.json:
        print(json.dumps(out))
    else:
        print_plan(out)
    return EXIT_OK if not p.uncovered else EXIT_WARNINGS
