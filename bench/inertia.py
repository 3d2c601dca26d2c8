"""Inertia identification at T1 speeds on the simulator (issue #15): error per principal moment, coverage of ±U and
robot time, over seeds and two DuTs, and the ablation at twice the speed limit.

Per DuT the excitation is designed once (``rgse_daemon.pipeline.excitation``, the T1 speed at every corner of the
DuT's envelope box; the 2× variant with twice the limit, which the interlock refuses — it is computed here in
simulation only and never rendered for a robot). Per seed a new simulated robot (``RobotModel(seed)``: noise,
mounting offsets, CoG shift of the mounting, spikes) runs the program twice, as the daemon's run does: the tare
(MPA and fixture) and the DuT on them. The drive channels are simulated along the simulator's own planned profiles
(``simulators.krc4.motion.plan_joint_move``, T1 slowing) with its rigid-body dynamics, friction and torque error
model (``simulators.krc4.dynamics.sample_motion_trace``) at 4 ms, and the identification
(``rgse_daemon.pipeline.inertia.identify``) gets what the traces show: Sollposition, Istposition and Istmoment of
A4–A6, the DuT's mass and CoG as the static measurement gives them (the truth here: the CoG's own error is the CoG
bench's business; the simulator's per-mounting CoG shift stays unknown to it).

Run: ``python bench/inertia.py [--seeds N] [--workers 2]``. Prints one table (T1 and 2xT1, ``excitation.REPEATS``
= 2 swings of each axis per orientation).

``--repeats 1,2,4,8`` adds a second table at T1 only: one row per number of swings per axis and orientation
(``excitation.design(repeats=n)``; the daemon's ``[properties] inertia_repeats``), and per DuT and principal moment
a fit of the RMS error against n — the robot time is T0 + dT·n, the repositioning and the moves to and from the
swings being T0 — with the robot time each fit needs for 3 % RMS: the power law RMS = c·n^p (p = −0.5 for white
torque noise alone) and noise plus a floor RMS² = A/n + B². ``--no-main`` skips the first table (the repeats table's
n = 2 rows are the first table's T1 rows). ``--off noise,spikes,thermal,mount`` switches those error terms of the
simulated reading off in every row (``scenario_without``): what is left is the floor the others leave.
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.pipeline import inertia as inr
from simulators.krc4 import physics as ph
from simulators.krc4.dynamics import SERVO_LAG_S, RobotDynamics, sample_motion_trace
from simulators.krc4.motion import T1_LIMIT_MM_S, MotionHistory, MotionSettings, plan_joint_move
from simulators.krc4.scenario import AXIS_KEYS, Scenario, default_scenario

PERIOD_S = 0.004
REST_S = 0.3
#: The interlock's limit the excitation is designed for (config limits.t1_speed_mm_s default, paper §2.2).
LIMIT_MM_S = 200.0
#: U (k = 2) of the static CoG measurement the identification is given (bench/cog.py's order of magnitude).
U_COG_M = 0.002
DUTS = {"wing": ph.refex_wing_box, "cube": ph.compact_cube}
#: Error terms of the simulated reading ``--off`` can switch off (the diagnosis of a floor): their scenario keys.
OFF_TERMS = ("noise", "spikes", "thermal", "mount")


def scenario_without(off: tuple[str, ...]) -> Scenario:
    """The default scenario with the error terms ``off`` (of OFF_TERMS) switched off: ``noise`` the white noise,
    ``spikes`` the spikes, ``thermal`` the reading's drift with motor temperature, ``mount`` the per-mounting reading
    offsets and CoG shift."""
    sc = default_scenario()
    zero: dict[str, float] = {}
    if "noise" in off:
        zero["noise_nm"] = 0.0
    if "spikes" in off:
        sc = sc.model_copy(update={"spikes": sc.spikes.model_copy(update={"rate_per_sample": 0.0})})
    if "thermal" in off:
        zero["thermal_coeff_per_k"] = 0.0
    if "mount" in off:
        zero["mount_offset_nm"] = 0.0
        sc = sc.model_copy(update={"mounting": sc.mounting.model_copy(update={"cog_shift_m": 0.0})})
    axes = {k: sc.axis(i).model_copy(update=zero) for i, k in enumerate(AXIS_KEYS, 1)}
    return sc.model_copy(update={"axes": axes})


@functools.lru_cache(maxsize=16)
def design_of(dut_name: str, factor: float, repeats: int) -> ex.Excitation:
    """The excitation of a DuT (deterministic: designed once per worker, not per seed)."""
    return ex.design(payload_of(DUTS[dut_name]()), limit_mm_s=LIMIT_MM_S * factor, optimise=False, repeats=repeats)


def payload_of(dut: ph.AsymmetricDut) -> ex.Payload:
    """What the daemon knows of the DuT for the design: mass, CoG, envelope box (and the fixture's corners)."""
    corners = [tuple(map(float, c)) for c in dut.box_corners_flange_m()]
    return ex.Payload(dut.mass_kg, tuple(map(float, dut.cog_flange_m)), tuple(corners))


def simulate(design: ex.Excitation, payload: ph.Payload, model: ph.RobotModel, dyn: RobotDynamics,
             t1_limit_mm_s: float) -> list[inr.Stroke]:
    """Run ``design``'s moves on the simulated robot and trace A1..A6 at PERIOD_S; one Stroke per move."""
    model.new_mounting()
    hist = MotionHistory()
    q = np.asarray(design.start_deg, float)
    t = REST_S
    spans = []
    for m in design.moves:
        settings = MotionSettings(vel_axis_pct=tuple(m.vel_axis_pct), acc_axis_pct=tuple(m.acc_axis_pct))
        move = plan_joint_move("PTP", q, m.target_deg, settings, t1_limit_mm_s=t1_limit_mm_s)
        hist.add(t, move)
        spans.append((t - REST_S / 2, t + move.duration_s + REST_S / 2))
        t += move.duration_s + REST_S
        q = np.asarray(m.target_deg, float)
    times = np.arange(round(t / PERIOD_S)) * PERIOD_S
    motion = hist.sample(times, design.start_deg)
    actual = hist.sample(times - SERVO_LAG_S, design.start_deg)  # the arm follows the command, as the server's
    trace = sample_motion_trace(model, dyn, payload, motion, PERIOD_S, t_since_release_s=100.0,
                                motor_temp_k=model.state.motor_temp_k, last_approach_sign=np.ones(6), actual=actual)
    soll = np.stack([trace[a]["Sollposition"] for a in range(1, 7)], axis=1)
    ist = np.stack([trace[a]["Istposition"] for a in range(1, 7)], axis=1)
    tau = np.stack([trace[a]["Istmoment"] for a in range(1, 7)], axis=1)
    temp = np.stack([trace[a]["Motortemperatur"] for a in range(1, 7)], axis=1)
    strokes = []
    for t0, t1 in spans:
        sel = (times >= t0) & (times < t1)
        strokes.append(inr.Stroke(times[sel], ist[sel], tau[sel], soll[sel], temp_k=temp[sel]))
    return strokes


class SimulatorGain:
    """The simulator's own gain curve of one axis as a calibration would find it: reading G(|x|)·x (an *ideal*
    torque calibration; the bench's "ideal gain" rows, against "no gain" where the reading is taken 1:1)."""

    def __init__(self, model: ph.RobotModel, axis: int) -> None:
        self.model, self.i = model, axis - 1

    def reading_nm(self, x_nm: np.ndarray) -> np.ndarray:
        x = np.asarray(x_nm, float)
        xs = np.zeros((6, x.size))
        xs[self.i] = x.ravel()
        return (self.model.gains(xs)[self.i] * x.ravel()).reshape(x.shape)

    def slope(self, x_nm: np.ndarray) -> np.ndarray:
        h = 0.5
        return (self.reading_nm(np.asarray(x_nm) + h) - self.reading_nm(np.asarray(x_nm) - h)) / (2 * h)


def fixture_pi() -> tuple[float, float, float, float]:
    p = ph.dut_payload(0.0, (0.0, 0.0, 0.0))
    return tuple(float(v) for v in p.theta)  # type: ignore[return-value]


def one(dut_name: str, seed: int, factor: float, repeats: int = ex.REPEATS, off: tuple[str, ...] = (),
        gain: str = "ideal") -> dict[str, object]:
    dut = DUTS[dut_name]()
    design = design_of(dut_name, factor, repeats)
    model = ph.RobotModel(scenario_without(off) if off else None, seed=seed)
    dyn = RobotDynamics(model.scenario, robot=model.robot)
    t1 = T1_LIMIT_MM_S * factor
    tare = simulate(design, ph.dut_payload(0.0, (0.0, 0.0, 0.0)), model, dyn, t1)
    loaded = simulate(design, dut.payload(), model, dyn, t1)
    strokes = [inr.difference(d, t) for d, t in zip(loaded, tare, strict=True)]
    cal = None
    if gain == "ideal":
        cal = inr.TorqueCalibration({a: SimulatorGain(model, a) for a in inr.WRIST_AXES}, fixture_pi(),
                                    calibration_temp_k=(model.ambient_k,) * 6)
    # the static CoG measurement of this mounting (the simulator shifts the mounted load along the flange axis)
    cog = np.asarray(dut.cog_flange_m) + np.array([0.0, 0.0, model.mount_cog_shift_m])
    res = inr.identify(strokes, PERIOD_S, dut.mass_kg, cog, dut_abc_deg=dut.dut_abc_deg, seed=seed,
                       calibration=cal, u_cog_flange_m=(U_COG_M / 2,) * 3)
    truth = dut.principal_moments_kgm2
    return {"dut": dut_name, "seed": seed, "factor": factor, "repeats": repeats, "est": res.principal_moments_kgm2,
            "U": res.U_principal_moments_kgm2, "truth": truth, "robot_s": 2 * design.robot_time_s,
            "friction": res.friction, "rms": res.residual_rms_nm}


HEADER = (f"{'DuT':>5} {'limit':>6} {'moment':>6} {'truth kg·m²':>11} {'mean err %':>10} {'rms err %':>9} "
          f"{'max |err| %':>11} {'mean U %':>8} {'coverage':>8} {'in ±3 %':>7} {'robot s':>7}")


def summary(rs: list[dict]) -> tuple[np.ndarray, np.ndarray, float]:
    """Per principal moment of a row's seeds: mean err %, RMS err %, max |err| %, mean U %, coverage, share within
    ±3 % (rows of a (6, 3) array), the truth, and the robot time."""
    est = np.array([r["est"] for r in rs])
    u = np.array([r["U"] for r in rs])
    truth = np.asarray(rs[0]["truth"])
    err = 100.0 * (est - truth) / truth
    stats = np.array([err.mean(axis=0), np.sqrt(np.mean(err**2, axis=0)), np.abs(err).max(axis=0),
                      100 * np.mean(u / truth, axis=0), np.mean(np.abs(est - truth) <= u, axis=0),
                      np.mean(np.abs(err) <= 3.0, axis=0)])
    return stats, truth, float(rs[0]["robot_s"])  # type: ignore[arg-type]


def row_lines(label: str, d: str, rs: list[dict]) -> list[str]:
    st, truth, robot_s = summary(rs)
    return [f"{d:>5} {label:>6} {k + 1:>6} {truth[k]:11.3f} {st[0, k]:10.2f} {st[1, k]:9.2f} {st[2, k]:11.2f} "
            f"{st[3, k]:8.2f} {st[4, k]:8.2f} {st[5, k]:7.2f} {robot_s:7.0f}" for k in range(3)]


def fit_lines(d: str, rows: list[tuple[int, float, np.ndarray]], goal: float = 3.0) -> list[str]:
    """Per principal moment, from (repeats n, robot s, RMS err % per moment) of the repeats rows: the robot time is
    linear in n (T = T0 + dT·n, the repositioning and the moves to and from the swings being T0), the noise averages
    over the swings, so RMS is fitted against n: the log-log slope p (−0.5: white torque noise alone, 0: a floor) and
    two extrapolations to RMS = ``goal`` %, the power law RMS = c·n^p and noise plus a floor RMS² = A/n + B² (least
    squares in 1/n weighted by 1/RMS²; B ≥ goal: never), each as the robot time T0 + dT·n it needs."""
    n = np.array([r[0] for r in rows], float)
    dt, t0 = np.polyfit(n, [r[1] for r in rows], 1)
    out = []
    for k in range(3):
        y = np.array([r[2][k] for r in rows])
        p, logc = np.polyfit(np.log(n), np.log(y), 1)
        n_pow = (goal / np.exp(logc)) ** (1.0 / p) if p < 0 else np.inf
        a, b2 = np.polyfit(1.0 / n, y**2, 1, w=1.0 / y**2)  # the RMS of a row is uncertain in proportion to it
        b = float(np.sqrt(max(b2, 0.0)))
        n_nf = a / (goal**2 - max(b2, 0.0)) if b < goal and a > 0 else np.inf
        fmt = lambda v: f"{t0 + dt * v:8.0f}" if np.isfinite(v) and v < 1e6 else "   never"  # noqa: E731
        out.append(f"{d:>5} {k + 1:>6} {p:8.2f} {fmt(n_pow)} {np.sqrt(max(a, 0.0) / n.max()):9.2f} {b:8.2f} "
                   f"{fmt(n_nf)}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dut", choices=(*DUTS, "all"), default="all")
    ap.add_argument("--repeats", default="",
                    help="comma list of swings per axis and orientation (e.g. 1,2,4,8): a second table at T1 only, "
                         f"one row per value, and the extrapolation to ±3 %% (default {ex.REPEATS})")
    ap.add_argument("--main", action=argparse.BooleanOptionalAction, default=True,
                    help="the T1 / 2xT1 table (--no-main: the repeats table alone)")
    ap.add_argument("--off", default="", help=f"comma list of the simulator's error terms to switch off in every "
                                              f"row ({', '.join(OFF_TERMS)}): the diagnosis of a floor")
    args = ap.parse_args()
    workers = min(max(args.workers, 1), 2)
    duts = list(DUTS) if args.dut == "all" else [args.dut]
    repeats = [int(v) for v in args.repeats.split(",") if v.strip()]
    if any(r < 1 for r in repeats):
        ap.error("--repeats: every value must be ≥ 1")
    off = tuple(v.strip() for v in args.off.split(",") if v.strip())
    if set(off) - set(OFF_TERMS):
        ap.error(f"--off: one of {', '.join(OFF_TERMS)}")
    keys = []  # (dut, seed, factor, repeats): the T1 rows of the main table are the repeats table's default row
    if args.main:
        keys += [(d, s, f, ex.REPEATS) for d in duts for f in (1.0, 2.0) for s in range(args.seeds)]
    keys += [(d, s, 1.0, r) for d in duts for r in repeats for s in range(args.seeds)]
    keys = list(dict.fromkeys(keys))
    t0 = time.time()
    with ProcessPoolExecutor(workers) as pool:
        results = list(pool.map(one, *zip(*keys, strict=True), [off] * len(keys)))
    by = {k: [r for r in results if (r["dut"], r["factor"], r["repeats"]) == k]
          for k in {(d, f, r) for d, _, f, r in keys}}
    note = f"; simulator terms off: {', '.join(off)}" if off else ""
    if args.main:
        print(HEADER)
        for d in duts:
            for f in (1.0, 2.0):
                print("\n".join(row_lines("T1" if f == 1 else "2xT1", d, by[(d, f, ex.REPEATS)])))
        print(f"{args.seeds} seeds per row; limit: the interlock's Cartesian limit on the envelope box ({LIMIT_MM_S:g} "
              f"mm/s, 2xT1 simulation only); robot s: tare + DuT run; U with k = 2{note}")
    if repeats:
        print(f"\nT1, swings per axis and orientation ({ex.N_BLOCKS} orientations; default {ex.REPEATS}):")
        print(HEADER.replace(" limit", "reps  ", 1))
        for d in duts:
            for r in repeats:
                print("\n".join(row_lines(f"{r}", d, by[(d, 1.0, r)])))
        print(f"{args.seeds} seeds per row; robot s: tare + DuT run (rests excluded){note}")
        if len(repeats) >= 2:
            print("\nfit of RMS err % against the repeats n, and the robot time (tare + DuT) for 3 % RMS:")
            print(f"{'DuT':>5} {'moment':>6} {'slope p':>8} {'T3% pw':>8} {'noise %':>9} {'floor %':>8} "
                  f"{'T3% nf':>8}")
            for d in duts:
                rows = [(r, summary(by[(d, 1.0, r)])[2], summary(by[(d, 1.0, r)])[0][1]) for r in sorted(repeats)]
                print("\n".join(fit_lines(d, rows)))
            print(f"slope p: log-log slope of RMS against n (-0.5: torque noise alone, 0: a floor); T3% pw: the power "
                  f"law RMS = c·n^p; noise %, floor %: RMS² = A/n + B² fitted, sqrt(A/n) at the largest n and B; "
                  f"T3% nf: that model's; both as the robot time T0 + dT·n (linear in n). The RMS of {args.seeds} "
                  f"seeds is itself uncertain by ~{100 / np.sqrt(2 * args.seeds):.0f} % (1 s.e.).")
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
