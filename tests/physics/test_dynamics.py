"""The simulator's dynamics against analytic cases: a swinging point mass, a pure rotation, the static torques,
power balance, friction, the motion history and the moving torque estimate."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from simulators.krc4 import dynamics as dy
from simulators.krc4 import physics as ph
from simulators.krc4.motion import (
    MotionHistory,
    MotionSettings,
    flange_speed_mm_s,
    flange_speeds_mm_s,
    plan_joint_move,
)

G = 9.81


@pytest.fixture(scope="module")
def dyn() -> dy.RobotDynamics:
    return dy.RobotDynamics()


def point_mass(mass_kg: float, z_m: float) -> ph.Payload:
    return ph.Payload((ph.RigidBody("point", mass_kg, (0.0, 0.0, z_m)),))


def test_single_axis_swinging_a_point_mass(dyn: dy.RobotDynamics) -> None:
    """A5 horizontal (measurement pose), only A5 moves: τ5 = m l² q̈ − m g l cos q (holding sign: a load in front
    pulls A5's positive direction, so the drive holds with a negative torque; A5 positive tilts the flange down)."""
    m, z = 40.0, 0.45
    lever = kin.D6_M + z
    rng = np.random.default_rng(3)
    q = np.tile(kin.measurement_pose(), (50, 1))
    q[:, 4] = rng.uniform(-80.0, 80.0, 50)
    qd = np.zeros((50, 6))
    qd[:, 4] = rng.uniform(-40.0, 40.0, 50)
    qdd = np.zeros((50, 6))
    qdd[:, 4] = rng.uniform(-200.0, 200.0, 50)
    tau = dyn.payload_torques_nm(q, qd, qdd, point_mass(m, z))[:, 4]
    q5 = np.deg2rad(q[:, 4])
    expected = m * lever**2 * np.deg2rad(qdd[:, 4]) - m * G * lever * np.cos(q5)
    np.testing.assert_allclose(tau, expected, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("products", [False, True])
def test_pure_rotation_about_the_flange_axis(dyn: dy.RobotDynamics, products: bool) -> None:
    """A body on the A6 axis (CoG on it) turned by A6 alone: τ6 = I_zz q̈ whatever the pose and speed; with products
    of inertia ω × I ω adds moments across the axis; A4 and A5 carry the projection of the body's moment (its
    CoG does not move: no force)."""
    inertia = np.diag([3.0, 5.0, 7.0])
    if products:
        inertia = inertia + np.array([[0.0, 0.4, 0.6], [0.4, 0.0, -0.5], [0.6, -0.5, 0.0]])
    body = ph.Payload((ph.RigidBody("rotor", 25.0, (0.0, 0.0, 0.3), inertia),))
    rng = np.random.default_rng(5)
    q = rng.uniform(-60.0, 60.0, (40, 6))
    qd = np.zeros((40, 6))
    qdd = np.zeros((40, 6))
    qd[:, 5] = rng.uniform(-60.0, 60.0, 40)
    qdd[:, 5] = rng.uniform(-300.0, 300.0, 40)
    tau = dyn.payload_torques_nm(q, qd, qdd, body)
    np.testing.assert_allclose(tau[:, 5], inertia[2, 2] * np.deg2rad(qdd[:, 5]), rtol=1e-10, atol=1e-9)
    # about the flange frame's z: ω = −q̇6 ẑ (A6 turns about −z of the flange); N = I ω̇ + ω × I ω
    w, wd = -np.deg2rad(qd[:, 5]), -np.deg2rad(qdd[:, 5])
    n_flange = np.outer(wd, inertia[:, 2]) + np.cross(np.outer(w, [0, 0, 1.0]), np.outer(w, inertia[:, 2]))
    no_gravity = dyn.payload_torques_nm(q, qd, qdd, body) - dyn.payload_torques_nm(q, 0 * qd, 0 * qdd, body)
    for k in range(40):
        # the moment the drives exert on the body, seen about A4's and A5's KUKA directions
        rot = kin.flange_frame(q[k])[:3, :3]
        _, dirs = kin.axis_lines(q[k])
        for j in (3, 4):
            assert no_gravity[k, j] == pytest.approx(dirs[j] @ rot @ n_flange[k], abs=1e-8)


def test_static_case_equals_the_gravity_torques() -> None:
    model = ph.RobotModel(seed=2)
    model.new_mounting()
    dyn = dy.RobotDynamics(model.scenario, robot=model.robot)  # both on the arm as built
    rng = np.random.default_rng(9)
    for payload in (ph.refex_wing_box().payload(), ph.mass_calibration_payload(7), ph.compact_cube().payload()):
        for _ in range(10):
            q = rng.uniform(kin.JOINT_LIMITS_DEG[:, 0], kin.JOINT_LIMITS_DEG[:, 1])
            tau = dyn.torques_nm(q, np.zeros(6), np.zeros(6), payload, shift_z_m=model.mount_cog_shift_m)
            np.testing.assert_allclose(tau, model.true_torques_nm(q, payload), rtol=0, atol=1e-9)


def test_power_equals_the_rate_of_kinetic_energy(dyn: dy.RobotDynamics) -> None:
    """Without gravity and friction, τ·q̇ = dT/dt with T = ½ q̇ᵀ M(q) q̇ (M from the same dynamics), on a random
    smooth motion of all six axes with the wing box."""
    payload = ph.refex_wing_box().payload()
    rng = np.random.default_rng(11)
    amp, freq, phase = rng.uniform(10, 40, 6), rng.uniform(0.2, 0.8, 6), rng.uniform(0, 2 * np.pi, 6)
    q0 = kin.measurement_pose()

    def state(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        arg = 2 * np.pi * freq * t + phase
        w = 2 * np.pi * freq
        return q0 + amp * np.sin(arg), amp * w * np.cos(arg), -amp * w**2 * np.sin(arg)

    def kinetic(t: float) -> float:
        q, qd, _ = state(t)
        v = np.deg2rad(qd)
        return 0.5 * v @ dyn.mass_matrix_kgm2(q, payload) @ v

    h = 1e-5
    for t in rng.uniform(0.0, 5.0, 8):
        q, qd, qdd = state(t)
        power = dyn.torques_nm(q, qd, qdd, payload, gravity=False) @ np.deg2rad(qd)
        d_kin = (kinetic(t + h) - kinetic(t - h)) / (2 * h)
        assert power == pytest.approx(d_kin, rel=1e-5, abs=1e-4)
    # gravity does work as the potential falls: τ_g · q̇ = dV/dt, V from the static model's CoG heights
    q, qd, qdd = state(1.3)
    tau_g = dyn.torques_nm(q, qd, qdd, payload) - dyn.torques_nm(q, qd, qdd, payload, gravity=False)

    def potential(qq: np.ndarray) -> float:
        frames = kin.joint_frames(qq)
        v = 0.0
        for link in range(6):
            lk = dyn.links[link]
            v += lk.mass_kg * G * (frames[link, :3, :3] @ lk.cog_m + frames[link, :3, 3])[2]
        return v + payload.mass_kg * G * kin.flange_point_m(qq, payload.cog_flange_m)[2]

    dv = (potential(q + qd * h) - potential(q - qd * h)) / (2 * h)
    assert tau_g @ np.deg2rad(qd) == pytest.approx(dv, rel=1e-5)


def test_mass_matrix_is_symmetric_positive_and_holds_the_payload_inertia(dyn: dy.RobotDynamics) -> None:
    wing = ph.refex_wing_box()
    q = kin.measurement_pose()
    m_with = dyn.mass_matrix_kgm2(q, wing.payload())
    assert np.allclose(m_with, m_with.T, atol=1e-9) and np.linalg.eigvalsh(m_with).min() > 0
    # A6 sees the payload's inertia about the flange axis through its CoG plus m r² (parallel axes), and its rotor
    bare = dyn.mass_matrix_kgm2(q)
    pay = wing.payload()
    c = pay.cog_flange_m
    expected = pay.inertia_cog_kgm2[2, 2] + pay.mass_kg * (c[0] ** 2 + c[1] ** 2)
    assert m_with[5, 5] - bare[5, 5] == pytest.approx(expected, rel=1e-9)
    assert bare[5, 5] > dyn.armature_kgm2[5] > 0


def test_dut_truth_and_inertia_checks() -> None:
    wing = ph.refex_wing_box()
    moments = dy.true_principal_moments_kgm2(wing)
    np.testing.assert_allclose(moments, ph.WING_BOX_PRINCIPAL_KGM2, rtol=1e-12)
    assert list(moments) == sorted(moments)
    tensor = dy.true_inertia_dut_kgm2(wing)
    assert abs(tensor[0, 1]) > 0.5  # a full tensor: products of inertia
    axes = dy.true_principal_axes_dut(wing)
    np.testing.assert_allclose(axes.T @ tensor @ axes, np.diag(moments), atol=1e-9)
    # the flange frame's tensor is the DuT's turned by the mounting
    np.testing.assert_allclose(np.linalg.eigvalsh(wing.inertia_flange_kgm2), moments, rtol=1e-12)
    cube = ph.compact_cube()
    assert 2.0 < cube.principal_moments_kgm2[0] < cube.principal_moments_kgm2[2] < 3.0
    with pytest.raises(ValueError, match=r"bad: inertia about the CoG.*not a rigid body"):
        ph.RigidBody("bad", 1.0, (0, 0, 0), (1.0, 1.0, 3.0))
    with pytest.raises(ValueError, match="not symmetric"):
        ph.AsymmetricDut("skew", 1.0, (0, 0, 0), (0, 0, 0), (0, 0, 0), [[1, 0.2, 0], [0, 1, 0], [0, 0, 1]])
    # box and plate formulas: the MPA and a body are plates, the cube a box
    assert ph.box_inertia_kgm2(60.0, 0.5, 0.5, 0.5) == pytest.approx((2.5, 2.5, 2.5))
    mpa = ph.mpa().inertia_tensor_kgm2
    assert mpa[2, 2] == pytest.approx(mpa[0, 0] + mpa[1, 1], rel=0.01)  # thin plate: I_z ≈ I_x + I_y


def test_friction_sign_direction_temperature_and_stribeck(dyn: dy.RobotDynamics) -> None:
    q = np.zeros((1, 6))
    cold, warm = np.full((1, 6), 293.15), np.full((1, 6), 323.15)

    def f(v: float, temp: np.ndarray = cold, load: float = 0.0) -> np.ndarray:
        return dyn.friction_nm(q, np.full((1, 6), v), temp, 293.15, np.full((1, 6), load))[0]

    pos, neg = f(5.0), f(-5.0)
    assert np.all(pos > 0) and np.all(neg < 0)  # the drive supplies friction in the direction of motion
    assert not np.allclose(pos, -neg)  # direction asymmetry
    assert np.all(np.abs(f(5.0, warm)) < np.abs(pos))  # warm gear oil: less friction
    assert np.all(np.abs(f(5.0, load=1000.0)) > np.abs(pos))  # load dependence
    assert np.all(np.abs(f(0.2)) > np.abs(f(3.0)))  # Stribeck hump at low speed
    np.testing.assert_allclose(f(0.0), 0.0)  # at rest the static model's hysteresis takes over
    # a rougher gear: every level scaled
    rough = dy.RobotDynamics(dyn.scenario, friction_scale=3.0)
    np.testing.assert_allclose(rough.friction_nm(q + 1.0, np.full((1, 6), -7.0), cold, 293.15, np.zeros((1, 6))),
                               3.0 * dyn.friction_nm(q + 1.0, np.full((1, 6), -7.0), cold, 293.15, np.zeros((1, 6))))
    # Coulomb level = hysteresis / κ (module docstring)
    sc = dyn.scenario
    for i, fr in enumerate(dyn.friction):
        assert fr.coulomb_nm == pytest.approx(sc.axis(i + 1).hysteresis_nm / dy.KAPPA_LOCKED)


def test_motion_history_follows_the_planned_profile() -> None:
    q0 = kin.measurement_pose()
    q1 = q0 + np.array([0, 0, 0, 10.0, -8.0, 40.0])
    move = plan_joint_move("PTP", q0, q1, MotionSettings(vel_axis_pct=(20.0,) * 6, acc_axis_pct=(30.0,) * 6))
    hist = MotionHistory()
    hist.add(10.0, move)
    t = np.arange(9.0, 10.0 + move.duration_s + 1.0, 0.001)
    m = hist.sample(t)
    np.testing.assert_allclose(m.q_deg[0], q0)
    np.testing.assert_allclose(m.q_deg[-1], q1)
    np.testing.assert_allclose(np.gradient(m.q_deg, t, axis=0)[5:-5], m.qd_deg_s[5:-5], atol=0.05)
    moving = m.moving
    assert moving.any() and not moving[0] and not moving[-1]
    assert hist.active(10.0 + move.duration_s / 2) is move and hist.active(9.0) is None
    after = t >= 10.0 + move.duration_s
    np.testing.assert_allclose(m.t_since_stop_s[after], t[after] - 10.0 - move.duration_s, atol=1e-12)
    np.testing.assert_allclose(m.approach[-1], [0, 0, 0, 1, -1, 1])
    peak = np.abs(m.qd_deg_s).max(axis=0)
    np.testing.assert_allclose(peak[5], 0.2 * kin.MAX_AXIS_SPEED_DEG_S[5], rtol=1e-9)  # A6 leads the PTP


def test_motion_trace_carries_inertial_torque_and_reads_static_at_rest() -> None:
    """The moving estimate: without noise the A6 reading follows I q̈ + friction; standing still it is the static
    model's reading."""
    scenario = ph.RobotModel().scenario
    model = ph.RobotModel(scenario, seed=4)
    dyn = dy.RobotDynamics(scenario, robot=model.robot)  # the arm as built, as the simulator's
    wing = ph.refex_wing_box()
    payload = wing.payload()
    q0 = kin.measurement_pose()
    hist = MotionHistory()
    out = plan_joint_move("PTP", q0, q0 + np.array([0, 0, 0, 0, 0, 30.0]), MotionSettings(acc_axis_pct=(100.0,) * 6))
    hist.add(0.5, out)
    period = 0.004
    t = np.arange(round((out.duration_s + 1.5) / period)) * period
    motion = hist.sample(t)
    chans = dy.sample_motion_trace(model, dyn, payload, motion, period, t_since_release_s=100.0,
                                   motor_temp_k=np.full(6, 293.15), last_approach_sign=np.ones(6))
    truth = model.last_truth
    assert isinstance(truth, dy.MotionTruth)
    reading = chans[6]["Istmoment"]
    np.testing.assert_allclose(reading, sum(truth.terms.values())[5])
    np.testing.assert_allclose(chans[6]["Sollposition"], motion.q_deg[:, 5])
    # the inertial part on A6: (payload I_zz about the flange axis + arm + rotor) · q̈ during the ramps
    accel = np.abs(motion.qdd_deg_s2[:, 5]) > 1.0
    inertial = truth.true_torque_nm[5] - dyn.torques_nm(motion.q_deg, 0 * motion.qd_deg_s, 0 * motion.qdd_deg_s2,
                                                        payload, shift_z_m=model.mount_cog_shift_m)[:, 5]
    m66 = dyn.mass_matrix_kgm2(q0, payload)[5, 5]
    np.testing.assert_allclose(inertial[accel], m66 * np.deg2rad(motion.qdd_deg_s2[accel, 5]), rtol=0.02, atol=1.0)
    assert np.abs(inertial).max() > 10 * scenario.axis(6).noise_nm  # it stands out of the noise at 100 % $ACC
    # friction only while moving, hysteresis only at rest
    moving = motion.moving
    assert np.all(truth.terms["friction"][5][~moving] == 0.0)
    assert np.all(np.sign(truth.terms["friction"][5][motion.qd_deg_s[:, 5] > 1.0]) > 0)
    before = t < 0.5
    np.testing.assert_allclose(truth.terms["hysteresis"][5][before], -scenario.axis(6).hysteresis_nm)
    # at rest before the motion, the static part equals the static model's noise-free reading (with δ)
    static_model = model.static_reading_nm(q0, payload)
    got = truth.terms["static"][:, 0] + truth.terms["mount"][:, 0]
    np.testing.assert_allclose(got, static_model, atol=1e-9)


def test_batched_flange_speeds_equal_the_kinematics_one_pose_at_a_time() -> None:
    rng = np.random.default_rng(21)
    q = rng.uniform(kin.JOINT_LIMITS_DEG[:, 0], kin.JOINT_LIMITS_DEG[:, 1], (30, 6))
    qdot = rng.uniform(-50.0, 50.0, 6)
    one_by_one = [flange_speed_mm_s(qk, qdot) for qk in q]
    np.testing.assert_allclose(flange_speeds_mm_s(q, qdot), one_by_one, rtol=1e-12, atol=1e-9)


def test_dut_envelope_corners() -> None:
    wing = ph.refex_wing_box()
    corners = wing.box_corners_flange_m()
    assert corners.shape == (8, 3)
    np.testing.assert_allclose(corners.mean(axis=0), wing.cog_flange_m, atol=1e-12)  # centred at the CoG
    spans = np.sort(np.ptp(corners @ wing.rotation, axis=0))  # back in the DuT frame
    np.testing.assert_allclose(spans, [0.3, 0.6, 1.6], atol=1e-12)
    cube = ph.compact_cube()
    np.testing.assert_allclose(cube.box_corners_flange_m()[:, 2].min(), ph.fixture_front_z_m(), atol=1e-12)
