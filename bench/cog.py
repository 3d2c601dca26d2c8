"""Accuracy of the centre of gravity over seeds (issue #14): error per coordinate, coverage of ±U, robot time, and
U against the number of poses.

Each repetition is a whole story on the simulated KR 500 (``simulators.krc4.physics``, default scenario: Table 1's
A3/A5 gains, A4/A6 errors of the same kinds, thermal drift, settling, noise, spikes, per-mounting offsets and CoG
shifts): warm-up, the torsional points of the campaign (the bare MPA and six loads on the bracket, every point a new
mounting, measured in every pose of the scheme), then an asymmetric DuT (the ReFEx-like wing box, 80-130 kg, its CoG
moved by up to ±30 mm per coordinate from the nominal one) on the fixture, a new mounting, its properties run. The
DuT's mass is the true one plus a draw of the mass run's error (u = 1.2 kg, k = 1: ``bench/accuracy.py``'s mean
|error| of about 1 kg today), and its U enters the CoG's. Same code as ``rgse cog`` after reading the trace files
(``analysis.cog.compute_cog``). The DuT frame's z is the flange axis: the launch axis (ECSS-E-10-03C: ±2.5 mm along
it, ±1 mm across).

Rows:
``full`` / ``paper``: the two schemes. ``mass known``: the DuT's true mass given (no mass error: what the CoG itself
costs; along the flange axis A4-A6 only see the first moment m·(d6 + c_z) about the wrist, so a mass error δm moves
c_z by −(d6 + c_z)·δm/m, ~6 mm per 1 % of mass). ``no-shift``: the scenario without the per-mounting CoG shift
(8 mm σ along the flange axis, the simulator's stand-in for Table 1's per-mounting scatter, which also blurs where
the calibration loads sit). ``full 12 pts``: twelve torsional points (each load mounted twice). ``full robots``: a
new robot per seed, the gain curves of A3..A6 drawn from ``bench/accuracy.py``'s ``ROBOT_FAMILY`` (robots the
torsional catalogue was not set up on; ``mass known`` as above). ``poses N``: the full calibration, the DuT measured
in only the first N poses of the full scheme (what each extra pose buys).
Columns: RMS and max |error| per DuT-frame coordinate (mm), coverage of ±U (k = 2) per coordinate, mean U (mm),
the share of seeds within the ECSS limits, the DuT's robot time (s) in the poses.

Run: ``.venv/bin/python bench/cog.py [--seeds N] [--json]`` (40 seeds: measured 2.5 min of CPU on one core, 3.7 min
of wall time on a shared 2-core machine).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' simulated campaigns

from bench.accuracy import robot_axis
from rgse_daemon import calfile
from rgse_daemon.analysis import cog as acog
from simulators.krc4 import physics as ph
from simulators.krc4.scenario import default_scenario
from tests.support import cogcampaign as cc

U_MASS_KG = 1.2
ALONG_MM, ACROSS_MM = 2.5, 1.0
N_LOOPS = 2
ROWS = ("full", "full mass known", "full no-shift", "full no-shift mass known", "full 12 pts", "full robots",
        "full robots mass known", "paper", "poses 2", "poses 4", "poses 6", "poses 8")


def robot_time_s(n_poses: int, loops: int = N_LOOPS) -> float:
    """Robot time of the DuT's poses: per pose the approach and the move into it, then the loops (brake-release
    move, settle, trace, brakes), as the plan runs them (tests/support/cogcampaign.py's timing)."""
    return n_poses * (cc.MOVE_S + 1.0 + loops * cc.LOOP_S)


def _torsional(campaign: cc.TorsionalCampaign) -> calfile.Torsional:
    fit = campaign.fit()
    poses = [calfile.TorsionalPose(t.name, t.q_deg, t.reading().torque_nm, t.reading().sigma_nm)
             for t in campaign.bias]
    return calfile.Torsional(campaign.scheme, {p.name: p for p in poses}, dict(fit.gains), dict(fit.evaluations),
                             len(campaign.points))


def repetition(seed: int) -> dict[str, dict]:
    rng = np.random.default_rng(50_000 + seed)
    nominal = ph.refex_wing_box()
    dut = replace(nominal, mass_kg=float(rng.uniform(80.0, 130.0)),
                  cog_dut_m=tuple(float(c + rng.uniform(-0.03, 0.03)) for c in nominal.cog_dut_m))
    mass_kg = dut.mass_kg + float(rng.normal(0.0, U_MASS_KG))
    out = {}
    configs = {
        "full": ("full", default_scenario(), cc.TORSIONAL_POINTS),
        "full no-shift": ("full", _no_shift(), cc.TORSIONAL_POINTS),
        "full 12 pts": ("full", default_scenario(), cc.TORSIONAL_POINTS * 2),
        "paper": ("paper", default_scenario(), cc.TORSIONAL_POINTS),
        "full robots": ("full", _robot(seed), cc.TORSIONAL_POINTS),
    }
    for name, (scheme, scenario, points) in configs.items():
        model = ph.RobotModel(scenario, seed=seed)
        cc.warm_up(model)
        campaign = cc.simulate_torsional(model, scheme, n_loops=N_LOOPS, points=points, seed=seed)
        tors = _torsional(campaign)
        run = cc.simulate_properties(model, dut, scheme, n_loops=N_LOOPS)
        readings = [t.reading() for t in run.poses]
        subsets = {name: (readings, mass_kg, U_MASS_KG)}
        if name in ("full", "full no-shift", "full robots"):  # the mass known exactly: what the CoG itself costs
            subsets[f"{name} mass known"] = (readings, dut.mass_kg, 0.0)
        if name == "full":
            subsets.update({f"poses {n}": (readings[:n], mass_kg, U_MASS_KG) for n in (2, 4, 6, 8)})
        true_dut = dut.rotation.T @ (run.true_cog_flange_m - np.asarray(dut.dut_origin_flange_m))
        for row, (rd, m, u_m) in subsets.items():
            res = acog.compute_cog(rd, tors, g_m_s2=9.81, calibration_id="bench", mass_kg=m, u_mass_kg=u_m,
                                   fixture=run.fixture)
            out[row] = {"err_mm": ((np.array(res.cog_dut_m) - true_dut) * 1000.0).tolist(),
                        "U_mm": (np.array(res.U_cog_dut_m) * 1000.0).tolist(), "n_poses": len(rd)}
    return out


def _robot(seed: int):
    """A new robot per repetition: the drive gain curves of A3..A6 drawn from ``bench/accuracy.py``'s
    ``ROBOT_FAMILY`` (what the mass bench's ``robots`` row draws for A3 and A5), the rest the default scenario."""
    sc = default_scenario()
    rng = np.random.default_rng(80_000 + seed)
    return sc.model_copy(update={"axes": {**sc.axes, **{f"A{i}": robot_axis(sc.axis(i), rng) for i in (3, 4, 5, 6)}}})


def _no_shift():
    sc = default_scenario()
    return sc.model_copy(update={"mounting": sc.mounting.model_copy(update={"cog_shift_m": 0.0})})


def summarise(reps: list[dict[str, dict]]) -> dict[str, dict]:
    table = {}
    for row in ROWS:
        err = np.array([r[row]["err_mm"] for r in reps])
        u = np.array([r[row]["U_mm"] for r in reps])
        limit = np.array([ACROSS_MM, ACROSS_MM, ALONG_MM])
        table[row] = {"rms_mm": np.sqrt(np.mean(err**2, axis=0)).tolist(),
                      "max_mm": np.max(np.abs(err), axis=0).tolist(),
                      "coverage": np.mean(np.abs(err) <= u, axis=0).tolist(),
                      "mean_U_mm": np.mean(u, axis=0).tolist(),
                      "within_ecss": float(np.mean(np.all(np.abs(err) <= limit, axis=1))),
                      "robot_s": robot_time_s(reps[0][row]["n_poses"]), "n_poses": reps[0][row]["n_poses"]}
    return table


def print_table(table: dict[str, dict], seeds: int, took_s: float) -> None:
    def f3(v: list[float], fmt: str = "{:.2f}") -> str:
        return "/".join(fmt.format(x) for x in v)

    print(f"CoG on the simulated KR 500, {seeds} seeds, DuT frame x/y across, z along the launch axis "
          f"(ECSS ±{ACROSS_MM:g}/±{ACROSS_MM:g}/±{ALONG_MM:g} mm); {took_s:.0f} s\n")
    for scheme, n in (("full", 8), ("paper", 2)):
        points = 1 + len(cc.TORSIONAL_POINTS)
        print(f"torsional calibration, {scheme} scheme: {points} mountings x {n} poses, robot time "
              f"{points * robot_time_s(n) / 60:.0f} min (plus mounting each load)")
    print()
    print("| row | poses | robot s | RMS err x/y/z mm | max err x/y/z mm | mean U x/y/z mm | coverage x/y/z | "
          "within ECSS |")
    print("|---|---|---|---|---|---|---|---|")
    for row, t in table.items():
        print(f"| {row} | {t['n_poses']} | {t['robot_s']:.0f} | {f3(t['rms_mm'])} | {f3(t['max_mm'])} | "
              f"{f3(t['mean_U_mm'])} | {f3(t['coverage'], '{:.0%}')} | {t['within_ecss']:.0%} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    t0 = time.monotonic()
    reps = [repetition(seed) for seed in range(args.seeds)]
    table = summarise(reps)
    if args.json:
        print(json.dumps({"seeds": args.seeds, "rows": table}))
    else:
        print_table(table, args.seeds, time.monotonic() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
