"""How large is the inertial torque at T1 speeds? The signal an inertia identification works with, on the simulator.

For a DuT (default: the wing box) in the measurement pose, each wrist axis A4, A5, A6 alone swings back and forth
(0 → +a → −a → 0) at 100 % $ACC_AXIS and the largest axis speed that keeps every corner of the DuT's envelope box
(and the flange) at or below the Cartesian limit: 250 mm/s (T1) and 500 mm/s (2× T1, simulation only, never on the
robot). The drive's torque estimate is simulated along the planned profile at 4 ms (simulators.krc4.dynamics) and the
moving axis' terms are compared:

* ``inert_pay`` peak |payload inertial torque| (Nm): τ_pay(q, q̇, q̈) − τ_pay(q, 0, 0), what the identification wants;
* ``inert_all`` the same with arm and reflected rotor (what must be known or identified besides);
* ``Fc`` Coulomb friction; ``F_var`` the friction's spread on the constant-speed stretches (ripple, load share,
  std); ``sigma`` white noise of the estimate;
* ``SNR_n`` = inert_pay / sigma, ``SNR_f`` = inert_pay / Fc; ``SNR_e`` = √(Σ inert_pay²) / sigma over the move: for
  white noise alone the relative standard deviation of a least-squares inertia from this one swing is ≈ 1/SNR_e
  (``noise %``); ``acc_s`` the time spent accelerating; ``t_s`` the move.

At 100 % $ACC_AXIS the peak inertial torque does not depend on the speed limit (T1 limits speed, not acceleration):
the limit sets how long the axis accelerates, i.e. how many samples carry the signal.

Run: ``python bench/dynamics_t1.py [--dut wing|cube] [--seed N] [--friction-scale X]``. Prints one table; takes a
few seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rgse_daemon import kinematics as kin
from simulators.krc4 import physics as ph
from simulators.krc4.dynamics import RobotDynamics, sample_motion_trace
from simulators.krc4.motion import T1_LIMIT_MM_S, MotionHistory, MotionSettings, plan_joint_move

PERIOD_S = 0.004
SWING_DEG = {4: 30.0, 5: 30.0, 6: 40.0}


def allowed_speed_deg_s(q0: np.ndarray, axis: int, swing_deg: float, corners: np.ndarray, limit_mm_s: float) -> float:
    """Largest speed of ``axis`` (deg/s) keeping every corner and the flange ≤ limit over the swing."""
    lo, hi = q0.copy(), q0.copy()
    lo[axis - 1] -= swing_deg
    hi[axis - 1] += swing_deg
    unit = np.zeros(6)
    unit[axis - 1] = 1.0
    per_deg_s = kin.max_point_speed_mm_s(lo, hi, unit, corners, synchronous=False).sampled_max_mm_s
    return min(limit_mm_s / per_deg_s, kin.MAX_AXIS_SPEED_DEG_S[axis - 1])


def swing_history(q0: np.ndarray, axis: int, swing_deg: float, speed_deg_s: float) -> tuple[MotionHistory, float]:
    pct = [100.0] * 6
    pct[axis - 1] = 100.0 * speed_deg_s / kin.MAX_AXIS_SPEED_DEG_S[axis - 1]
    settings = MotionSettings(vel_axis_pct=tuple(pct))
    hist = MotionHistory()
    t, q = 0.2, q0.copy()
    for target in (swing_deg, -swing_deg, 0.0):
        q1 = q0.copy()
        q1[axis - 1] += target
        move = plan_joint_move("PTP", q, q1, settings)
        hist.add(t, move)
        t += move.duration_s
        q = q1
    return hist, t + 0.2


def measure(dut: ph.AsymmetricDut, axis: int, limit_mm_s: float, seed: int,
            friction_scale: float = 1.0) -> dict[str, float]:
    model = ph.RobotModel(seed=seed)
    dyn = RobotDynamics(model.scenario, friction_scale=friction_scale, robot=model.robot)
    payload = dut.payload()
    q0 = kin.measurement_pose()
    corners = np.vstack([dut.box_corners_flange_m(), np.zeros((1, 3))])
    speed = allowed_speed_deg_s(q0, axis, SWING_DEG[axis], corners, limit_mm_s)
    hist, t_end = swing_history(q0, axis, SWING_DEG[axis], speed)
    t = np.arange(round(t_end / PERIOD_S)) * PERIOD_S
    motion = hist.sample(t)
    sample_motion_trace(model, dyn, payload, motion, PERIOD_S, t_since_release_s=100.0,
                        motor_temp_k=np.full(6, model.ambient_k), last_approach_sign=np.ones(6))
    truth = model.last_truth
    assert truth is not None
    i = axis - 1
    zero = np.zeros_like(motion.qd_deg_s)
    pay_static = dyn.payload_torques_nm(motion.q_deg, zero, zero, payload)[:, i]
    all_static = dyn.torques_nm(motion.q_deg, zero, zero, payload)[:, i]
    inert_pay = truth.payload_torque_nm[i] - pay_static
    inert_all = truth.true_torque_nm[i] - all_static
    qd = motion.qd_deg_s[:, i]
    cruise = (np.abs(qd) > 0.99 * speed) & (np.abs(motion.qdd_deg_s2[:, i]) < 1e-9)
    friction = truth.terms["friction"][i]
    legs = [cruise & (np.sign(qd) == s) for s in (1, -1)]
    spreads = [np.std(friction[leg]) for leg in legs if leg.sum() > 1]
    f_var = float(np.mean(spreads)) if spreads else float("nan")  # nan: the swing never cruises
    fc = dyn.friction[i].coulomb_nm
    sigma = model.scenario.axis(axis).noise_nm
    peak = float(np.abs(inert_pay).max())
    return {
        "speed": speed,
        "inert_pay": peak,
        "inert_all": float(np.abs(inert_all).max()),
        "Fc": fc,
        "F_var": f_var,
        "sigma": sigma,
        "SNR_n": peak / sigma,
        "SNR_f": peak / fc,
        "SNR_e": float(np.sqrt(np.sum(inert_pay**2))) / sigma,
        "noise %": 100.0 * sigma / float(np.sqrt(np.sum(inert_pay**2))),
        "acc_s": float(np.sum(np.abs(motion.qdd_deg_s2[:, i]) > 1e-9) * PERIOD_S),
        "t_s": float(t_end),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dut", choices=("wing", "cube"), default="wing")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--friction-scale", type=float, default=1.0, help="multiply the friction levels (default 1)")
    args = ap.parse_args()
    dut = ph.refex_wing_box() if args.dut == "wing" else ph.compact_cube()
    print(f"DuT {dut.name}: {dut.mass_kg} kg, principal moments {np.round(dut.principal_moments_kgm2, 2).tolist()} "
          f"kg·m²; swing 0 → +a → −a → 0 at 100 % $ACC_AXIS, 4 ms samples")
    cols = ("speed", "inert_pay", "inert_all", "Fc", "F_var", "sigma", "SNR_n", "SNR_f", "SNR_e", "noise %", "acc_s",
            "t_s")
    header = f"{'axis':>4} {'limit':>9} " + " ".join(f"{c:>9}" for c in cols)
    print(header)
    print("-" * len(header))
    for axis in (4, 5, 6):
        for factor, label in ((1.0, "T1"), (2.0, "2xT1")):
            r = measure(dut, axis, factor * T1_LIMIT_MM_S, args.seed, args.friction_scale)
            print(f"  A{axis} {label:>9} " + " ".join(f"{r[c]:9.2f}" for c in cols))
    print("units: speed deg/s; torques Nm; acc_s, t_s s. SNR_n: peak payload inertial torque / noise σ; "
          "SNR_f: / Coulomb friction; SNR_e: its root sum of squares / σ; noise %: 1/SNR_e.")


if __name__ == "__main__":
    main()
