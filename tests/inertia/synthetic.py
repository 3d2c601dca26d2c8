"""Synthetic runs from the identification's own model (not the simulator): the planned profile of each move sampled
at the trace period, torques of the payload plus a stand-in for the robot's wrist (a body on the flange and rotor
inertias), Coulomb and viscous friction that grows with the load, a mounting offset, noise on torques and positions.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.pipeline import inertia as inr

ROTOR_KGM2 = np.array([0.0, 0.0, 0.0, 9.0, 8.0, 4.0])
COULOMB_NM = np.array([0.0, 0.0, 0.0, 40.0, 35.0, 20.0])
VISCOUS_NM_S_RAD = np.array([0.0, 0.0, 0.0, 60.0, 50.0, 30.0])
WRIST_BODY = inr.body_params(45.0, [0.0, 0.0, 0.05], np.diag([0.6, 0.6, 0.4]))


def run(design: ex.Excitation, payload_pi: np.ndarray | None, *, period_s: float, seed: int,
        noise_nm: float = 2.0, rest_s: float = 0.15) -> list[inr.Stroke]:
    """The strokes of one run of ``design`` (``payload_pi`` None: the tare run)."""
    rng = np.random.default_rng(seed)
    load = 0.0 if payload_pi is None else float(payload_pi[0])
    offset = rng.normal(0.0, 3.0, 6)
    strokes = []
    here = np.asarray(design.start_deg, float)
    t0 = 0.0
    for m in design.moves:
        target = np.asarray(m.target_deg, float)
        q, qd, qdd, _ = ex._plan(here, target, m.vel_axis_pct, m.acc_axis_pct, period_s)
        n_rest = int(rest_s / period_s)
        q = np.vstack([np.repeat(q[:1], n_rest, 0), q, np.repeat(q[-1:], n_rest, 0)])
        qd = np.vstack([np.zeros((n_rest, 6)), qd, np.zeros((n_rest, 6))])
        qdd = np.vstack([np.zeros((n_rest, 6)), qdd, np.zeros((n_rest, 6))])
        tau = inr.payload_torques_nm(q, qd, qdd, WRIST_BODY) + ROTOR_KGM2 * np.deg2rad(qdd)
        if payload_pi is not None:
            tau += inr.payload_torques_nm(q, qd, qdd, payload_pi)
        fc = COULOMB_NM * (1.0 + load / 200.0)
        tau += fc * np.tanh(qd / 0.2) + VISCOUS_NM_S_RAD * (1.0 + load / 400.0) * np.deg2rad(qd)
        tau += offset + rng.normal(0.0, noise_nm, tau.shape)
        q_meas = q + rng.normal(0.0, 0.0005, q.shape)
        t = t0 + np.arange(len(q)) * period_s
        strokes.append(inr.Stroke(t, q_meas, tau, q))
        t0 = t[-1] + 1.0 + rng.uniform(0, period_s)
        here = target
    return strokes


def differenced(design: ex.Excitation, payload_pi: np.ndarray, *, period_s: float, seed: int,
                noise_nm: float = 2.0) -> list[inr.Stroke]:
    dut = run(design, payload_pi, period_s=period_s, seed=seed, noise_nm=noise_nm)
    tare = run(design, None, period_s=period_s, seed=seed + 10_000, noise_nm=noise_nm)
    return [inr.difference(d, t) for d, t in zip(dut, tare, strict=True)]


def body(mass_kg: float, cog: Sequence[float], principal_kgm2: Sequence[float], abc_deg: Sequence[float]) -> np.ndarray:
    r = inr.dut_rotation(abc_deg)
    return inr.body_params(mass_kg, cog, r @ np.diag(principal_kgm2) @ r.T)
