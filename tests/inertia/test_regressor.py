"""The payload regressor against the statics, an analytic rotation, energy conservation and the simulator's own
Newton–Euler with a full inertia tensor."""

from __future__ import annotations

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon.pipeline import inertia as inr
from simulators.krc4 import physics as ph
from simulators.krc4.dynamics import RobotDynamics, true_inertia_dut_kgm2

RNG = np.random.default_rng(7)


def _body() -> tuple[float, np.ndarray, np.ndarray]:
    mass = 80.0
    cog = np.array([0.05, -0.03, 0.45])
    a = RNG.normal(size=(3, 3))
    i_c = a @ a.T + np.diag([6.0, 9.0, 4.0])
    return mass, cog, i_c


def test_static_part_is_the_gravity_regressor() -> None:
    q = np.array([[10.0, -80.0, 95.0, 20.0, 35.0, -40.0]])
    y = inr.payload_regressor(q, np.zeros((1, 6)), np.zeros((1, 6)))
    assert np.allclose(y[0, :, :4], kin.gravity_regressor(q[0]), atol=1e-9)
    assert np.allclose(y[0, :, 4:], 0.0)


def test_pure_rotation_about_a6_is_izz_times_acceleration() -> None:
    # CoG on the A6 axis, A6 axis vertical (no gravity moment about it): τ6 = Izz·q̈6 about the flange
    mass, _, i_c = _body()
    pi = inr.body_params(mass, [0.0, 0.0, 0.3], i_c)
    q = np.array([[0.0, -90.0, 90.0, 0.0, 90.0, 30.0]])
    qdd = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 57.29577951308232]])  # 1 rad/s²
    tau = inr.payload_torques_nm(q, np.zeros((1, 6)), qdd, pi)
    izz_flange = inr.tensor(pi[4:])[2, 2]
    assert abs(kin.axis_lines(q[0])[1][5] @ np.array([0, 0, -1.0])) > 1 - 1e-9  # A6 points down: vertical
    assert np.isclose(tau[0, 5], izz_flange, rtol=1e-9)


def _trajectory(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    base = np.array([5.0, -85.0, 92.0, 10.0, 30.0, -20.0])
    amp = np.array([3.0, 4.0, -5.0, 40.0, 25.0, 60.0])
    f = np.array([0.3, 0.25, 0.2, 0.5, 0.4, 0.6])
    ph = 2 * np.pi * f * t[:, None]
    return base + amp * np.sin(ph), amp * 2 * np.pi * f * np.cos(ph), -amp * (2 * np.pi * f) ** 2 * np.sin(ph)


def _energy(q: np.ndarray, qd: np.ndarray, mass: float, cog: np.ndarray, i_c: np.ndarray) -> np.ndarray:
    """Kinetic plus potential energy of the body, from positions and joint speeds (independent of the regressor)."""
    out = []
    for qk, qdk in zip(q, qd, strict=True):
        f = kin.flange_frame(qk)
        p = f[:3, :3] @ cog + f[:3, 3]
        origins, dirs = kin.axis_lines(qk)
        w = dirs.T @ np.deg2rad(qdk)
        v = np.cross(dirs, p - origins).T @ np.deg2rad(qdk)
        i_base = f[:3, :3] @ i_c @ f[:3, :3].T
        out.append(0.5 * mass * v @ v + 0.5 * w @ i_base @ w + mass * kin.G_PAPER_M_S2 * p[2])
    return np.array(out)


def test_power_equals_the_rate_of_energy_on_a_random_motion() -> None:
    mass, cog, i_c = _body()
    pi = inr.body_params(mass, cog, i_c)
    t = np.linspace(0.0, 2.0, 2001)
    q, qd, qdd = _trajectory(t)
    tau = inr.payload_torques_nm(q, qd, qdd, pi)
    power = np.einsum("ij,ij->i", tau, np.deg2rad(qd))
    energy = _energy(q, qd, mass, cog, i_c)
    de_dt = np.gradient(energy, t)
    inner = slice(5, -5)
    scale = np.abs(power[inner]).max()
    assert scale > 50.0  # the motion is not trivial
    assert np.abs(power[inner] - de_dt[inner]).max() < 1e-3 * scale


def test_regressor_is_linear_in_the_parameters() -> None:
    t = np.linspace(0.0, 1.0, 11)
    q, qd, qdd = _trajectory(t)
    m1, c1, i1 = _body()
    m2, c2, i2 = _body()
    p1, p2 = inr.body_params(m1, c1, i1), inr.body_params(m2, c2 * 2, i2)
    lhs = inr.payload_torques_nm(q, qd, qdd, p1 + p2)
    rhs = inr.payload_torques_nm(q, qd, qdd, p1) + inr.payload_torques_nm(q, qd, qdd, p2)
    assert np.allclose(lhs, rhs)


def test_a_turned_dut_with_products_reads_as_the_simulator_moves_it() -> None:
    # the frame and sign conventions of the products of inertia: the simulator's wing box (its principal axes turned
    # against the DuT frame, the DuT turned 90° on the flange: R · I_dut · Rᵀ, KUKA A, B, C = Rz·Ry·Rx) through the
    # simulator's own Newton–Euler against the identification's regressor with the tensor the daemon would report
    # (``dut_rotation`` of the DuT's A, B, C), at random states of all six axes
    dut = ph.refex_wing_box()
    i_dut = true_inertia_dut_kgm2(dut)
    assert np.min(np.abs(i_dut[np.triu_indices(3, 1)])) > 0.3
    r_fd = inr.dut_rotation(dut.dut_abc_deg)
    pi = inr.body_params(dut.mass_kg, dut.cog_flange_m, r_fd @ i_dut @ r_fd.T)
    dyn = RobotDynamics(ph.RobotModel(seed=0).scenario)
    body = ph.dut_payload(dut.mass_kg, dut.cog_flange_m, dut.inertia_flange_kgm2, fixture_mass_kg=0.0, with_mpa=False)
    q = RNG.uniform(-120.0, 120.0, (40, 6))
    qd = RNG.uniform(-40.0, 40.0, (40, 6))
    qdd = RNG.uniform(-150.0, 150.0, (40, 6))
    sim = dyn.payload_torques_nm(q, qd, qdd, body)
    ours = inr.payload_torques_nm(q, qd, qdd, pi, g_m_s2=dyn.g_m_s2)
    assert np.allclose(ours, sim, atol=1e-6 * np.abs(sim).max())
    # the products matter here: with their signs flipped the torques differ by far more than rounding
    flipped = inr.body_params(dut.mass_kg, dut.cog_flange_m, r_fd @ (2 * np.diag(np.diag(i_dut)) - i_dut) @ r_fd.T)
    assert np.abs(inr.payload_torques_nm(q, qd, qdd, flipped, g_m_s2=dyn.g_m_s2) - sim).max() > 1.0
