"""The multi-pose mass beside the paper's single pose, on one mounting of the demo's wing box (issue #35, item 4).

Each seed is a whole story on the simulated KR 500 (``simulators.krc4.physics``, default scenario: Table 1's gains,
per-mounting offsets and CoG shift, thermal drift, release transient, hysteresis, settling, noise, spikes):

* the paper's Table-1-like campaign (every point a new mounting) and its calibration (``auto``, as ``rgse calibrate``);
* the multi-pose section of the calibration: the bare MPA visiting the lever poses (``bias_visits`` each, one
  mounting) and K_A3 from stacks of 2..10 bodies, each a new mounting visiting the lever poses once
  (``tests/support/simmultipose.py``);
* the ReFEx-like wing box (107.3 kg, CoG off the flange axis) mounted once; on that mounting the single pose's loops
  (``inline.in_line_mass``, as ``rgse mass``) and the multi-pose visits (``pipeline.multipose``).

Out of sample: the DuT's mounting, noise and temperatures are drawn after the calibration and never enter it.
Columns: U (k = 2) in % of the mass, coverage of the truth by ±U with its Clopper-Pearson 95 % interval, mean |err| %,
robot minutes per result, and the U budget (mean standard uncertainty per source, kg).

Robot minutes: a loop is the daemon's measured loop (``LOOP_ROBOT_S``: the demo's 10 mass loops took 11.4–11.6 min of
robot time, issue #35); a pose change is a PTP of A3 and A5 at the T1 limit on the payload box's corners (computed
from the kinematics, :func:`pose_change_s`). The campaign's extra minutes for the multi-pose section are printed too.

``--path files`` runs the daemon's path instead: the torsional campaign in scheme ``lever`` and the wing box's
properties run written as trace files, CAL.json fitted as ``rgse calibrate`` does, the masses by ``analysis``
(:func:`repetition_files`).

Run: ``nice .venv/bin/python bench/multipose.py [--seeds 40] [--first-seed 0] [--workers 1|2] [--path memory|files]
[--json]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' simulated campaigns

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.analysis.calibration import campaign_points
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import inline, selection
from rgse_daemon.pipeline import multipose as mp
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.envelope import Envelope
from simulators.krc4 import physics as ph
from tests.support import simmultipose as sm
from tests.support.simcampaign import CHANGE_BODIES_S, SETTLE_S, G

#: Robot seconds of one daemon loop: the demo's 10 mass loops took 11.4-11.6 min (issue #35, `rgse demo --json`).
LOOP_ROBOT_S = 69.0
#: T1's speed limit on every point of the payload (mm/s).
T1_MM_S = 250.0
SINGLE_LOOPS = (3, 10)
VISITS = (1, 2)
BIAS_VISITS = 4


def pose_change_s(q_from_deg, q_to_deg) -> float:
    """A PTP between two lever poses at the T1 limit: the synchronous PTP's time at full axis speed, stretched so that
    no corner of the payload box moves faster than :data:`T1_MM_S`."""
    r = robots.active()
    dq = np.abs(np.asarray(q_to_deg, float) - np.asarray(q_from_deg, float))
    t_full = float(np.max(dq / np.asarray(r.max_axis_speed_deg_s, float)))
    lo, hi = np.asarray(r.cell.payload_box_min_m), np.asarray(r.cell.payload_box_max_m)
    corners = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    speed = kin.max_point_speed_mm_s(q_from_deg, q_to_deg, r.max_axis_speed_deg_s, corners).bound_mm_s
    return t_full * max(1.0, speed / T1_MM_S)


def multipose_robot_s(poses: list[mp.LeverPose], visits: int) -> float:
    order = mp.visit_order(poses, visits)
    moves = sum(pose_change_s(a.q_deg, b.q_deg) for a, b in itertools.pairwise(order)
                if a.q_deg != b.q_deg)
    back = pose_change_s(order[-1].q_deg, poses[0].q_deg) if order[-1].q_deg != poses[0].q_deg else 0.0
    return len(order) * LOOP_ROBOT_S + moves + back


def repetition(seed: int) -> dict:
    c = sm.simulate_multipose_campaign(seed, bias_visits=BIAS_VISITS)
    points, bias3, bias5 = campaign_points(c.data, pp.PAPER)
    evaluations = selection.evaluate_all(points, G, c.campaign.manifest.setup.lever_difference_m)
    chosen = selection.choose_auto(points, evaluations)
    dr = c.campaign.manifest.setup.lever_difference_m
    cal = cal_mod.fit(points, chosen.method, G, dr)
    cu = unc.calibration_uncertainty(points, chosen.method, G, dr, chosen.heldout_residual_nm)
    env = Envelope.from_torques(points.torque_a3_nm, points.torque_a5_nm)
    wing = ph.refex_wing_box()
    truth = wing.mass_kg
    payload = ph.dut_payload(truth, wing.cog_flange_m)
    model, q0 = c.model, kin.measurement_pose()
    model.apply_brakes(CHANGE_BODIES_S)
    model.new_mounting()
    loops, temps = [], []
    for k in range(max(SINGLE_LOOPS)):
        model.brake_release_move(q0)
        model.hold(SETTLE_S)
        tr = model.sample_trace(q0, payload, 250, 0.012)
        model.apply_brakes(150.0 - SETTLE_S - 3.0)
        loops.append((tr[3]["Istmoment"], tr[5]["Istmoment"], 0.012, f"dut_l{k + 1:02d}"))
        temps.append((float(np.mean(tr[3]["Motortemperatur"])), float(np.mean(tr[5]["Motortemperatur"]))))
    out: dict = {"seed": seed, "truth_kg": truth}
    for n in SINGLE_LOOPS:
        r = inline.in_line_mass(loops[:n], inline.MassCalibration(cal, bias3, bias5, uncertainty=cu, envelope=env,
                                                                  thermal=c.thermal),
                                pp.PAPER, fixture_mass_kg=ph.FIXTURE_MASS_KG, loop_temps_k=temps[:n])
        out[f"single pose, {n} loops"] = {"err_kg": r.mass_kg - truth, "U_kg": r.uncertainty.expanded_kg,
                                          "budget_kg": r.uncertainty.components(),
                                          "robot_min": n * LOOP_ROBOT_S / 60.0}
    poses = list(c.calibration.poses)
    for v in VISITS:
        got = sm.visit_poses(model, poses, v, payload, c.thermal, c.beta_applied)
        r = mp.multipose_mass(got, c.calibration, ph.FIXTURE_MASS_KG)
        out[f"multi-pose, {v} visit(s) per pose"] = {
            "err_kg": r.mass_kg - truth, "U_kg": r.uncertainty.expanded_kg, "budget_kg": r.uncertainty.components(),
            "robot_min": multipose_robot_s(poses, v) / 60.0, "warnings": r.warnings}
    return out


def repetition_files(seed: int) -> dict:
    """The daemon's path (``--path files``): the paper's campaign and a torsional campaign in scheme ``lever``
    written as trace files and fitted as ``rgse calibrate --campaign`` does (K_A3 from the six torsional points in
    every pose, each with its own offset), then the wing box's properties run in scheme ``lever`` (2 loops per pose)
    as files, its mass by ``analysis.multipose`` and ``analysis.mass`` (the measurement pose's loops)."""
    import tempfile

    from rgse_daemon.analysis import mass as mass_analysis
    from rgse_daemon.analysis.calibration import fit_campaign
    from rgse_daemon.analysis.multipose import compute_multipose_dir
    from tests.support import cogcampaign as cc
    from tests.support import simcampaign as sc

    wing = ph.refex_wing_box()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        campaign, model = sc.simulate_campaign(seed, n_loops=2)
        sc.write_dirs(campaign, sc.simulate_measurement(model, 50.0, n_loops=1), d / "campaign", d / "dut")
        cc.warm_up(model)
        lines = cc.torsional_manifest_lines(d / "campaign", cc.simulate_torsional(model, "lever", seed=seed))
        with (d / "campaign" / "manifest.toml").open("a", encoding="utf-8") as f:
            f.write("\n" + "\n".join(lines))
        doc, _ = fit_campaign(d / "campaign", "auto")
        (d / "CAL.json").write_text(json.dumps(doc.to_dict()), encoding="utf-8")
        run = cc.simulate_properties(model, wing, "lever")
        cc.write_properties_dir(d / "prop", run, robot=sc.ROBOT, scheme="lever", measurement_pose_traces=True)
        multi = compute_multipose_dir(d / "prop", d / "CAL.json")
        single = mass_analysis.compute(d / "prop", d / "CAL.json")
    poses = mp.lever_poses(kin.measurement_pose())
    return {"seed": seed, "truth_kg": wing.mass_kg,
            "single pose, 2 loops (files)": {"err_kg": single.mass_kg - wing.mass_kg, "U_kg": single.U_kg,
                                             "budget_kg": single.u_components_kg,
                                             "robot_min": 2 * LOOP_ROBOT_S / 60.0},
            "multi-pose, 2 loops per pose (files)": {
                "err_kg": multi.mass_kg - wing.mass_kg, "U_kg": multi.uncertainty.expanded_kg,
                "budget_kg": multi.uncertainty.components(), "warnings": multi.warnings,
                "robot_min": (4 * LOOP_ROBOT_S + 2 * pose_change_s(poses[0].q_deg, poses[1].q_deg)) / 60.0}}


def summarise(runs: list[dict], row: str) -> dict:
    rs = [r[row] for r in runs]
    err = np.array([x["err_kg"] for x in rs])
    big_u = np.array([x["U_kg"] for x in rs])
    truth = runs[0]["truth_kg"]
    k = int(np.sum(np.abs(err) <= big_u))
    ci = stats.binomtest(k, len(rs)).proportion_ci(0.95, method="exact")
    keys = rs[0]["budget_kg"].keys()
    return {"n": len(rs), "U_pct": float(100 * np.mean(big_u) / truth), "U_pct_max": float(100 * big_u.max() / truth),
            "coverage": k / len(rs), "coverage_ci95": (float(ci.low), float(ci.high)),
            "mean_abs_err_pct": float(100 * np.mean(np.abs(err)) / truth), "mean_err_kg": float(err.mean()),
            "robot_min": float(np.mean([x["robot_min"] for x in rs])),
            "budget_kg": {key: float(np.mean([x["budget_kg"][key] for x in rs])) for key in keys},
            "warned": int(sum(bool(x.get("warnings")) for x in rs))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1, choices=(1, 2))
    ap.add_argument("--path", choices=("memory", "files"), default="memory",
                    help="memory: the scheme's own lever calibration in memory; files: the daemon's path through "
                         "trace files and CAL.json's torsional section in scheme lever (about 30 s per seed)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    with ProcessPoolExecutor(args.workers) as pool:
        runs = list(pool.map(repetition if args.path == "memory" else repetition_files, seeds))
    rows = [k for k in runs[0] if k not in ("seed", "truth_kg")]
    table = {row: summarise(runs, row) for row in rows}
    poses = mp.lever_poses(kin.measurement_pose())
    n_lever = len(sm.LEVER_POINT_BODIES)
    campaign_extra_min = (multipose_robot_s(poses, BIAS_VISITS) + n_lever * multipose_robot_s(poses, 1)) / 60.0
    if args.json:
        print(json.dumps({"bench": "multipose", "seeds": args.seeds, "first_seed": args.first_seed, "table": table,
                          "campaign_extra_robot_min": campaign_extra_min,
                          "seconds": round(time.monotonic() - t0, 1)}))
        return 0
    print("| method | n | U % (mean, max) | coverage ±U (95 % CI) | mean \\|err\\| % | mean err kg | robot min | "
          "U budget: mean u per source, kg |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for row, s in table.items():
        lo, hi = s["coverage_ci95"]
        budget = ", ".join(f"{k} {v:.3f}" for k, v in s["budget_kg"].items() if v > 0)
        print(f"| {row} | {s['n']} | {s['U_pct']:.2f}, {s['U_pct_max']:.2f} | {100 * s['coverage']:.0f} % "
              f"({100 * lo:.0f}–{100 * hi:.0f}) | {s['mean_abs_err_pct']:.2f} | {s['mean_err_kg']:+.3f} | "
              f"{s['robot_min']:.1f} | {budget} |")
    if args.path == "memory":
        print(f"multi-pose section of the campaign: +{campaign_extra_min:.0f} robot min (bare MPA {BIAS_VISITS} "
              f"visits per pose, {n_lever} stacks 1 visit per pose; body changes not counted)")
    else:
        print("files: the single pose's U carries the thermal bound of a DuT measured warm after a cold mass "
              "campaign (its beta is not extrapolated); the multi-pose mass is brought to the torsional campaign's "
              "temperature")
    print(f"{args.seeds} seeds (from {args.first_seed}), wing box {ph.refex_wing_box().mass_kg} kg, "
          f"{time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
