"""Kinematics of the KR 500 R2830: forward kinematics, speeds, worst-case bound, gravity torques."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgse_daemon import kinematics as kin

G = kin.G_PAPER_M_S2


def _rot(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rodrigues rotation matrix (independent of the module under test)."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * kx + (1 - np.cos(angle_rad)) * kx @ kx


def urdf_flange(q_deg) -> np.ndarray:
    """Flange pose from the ROS-Industrial URDF description of this robot family (joint origins and axes), as an
    independent check of the DH table: origins (m) and axes per joint, then tool0 = link_6 · Ry(90°)."""
    joints = [
        ((0, 0, 1.045), (0, 0, -1)),
        ((0.5, 0, 0), (0, 1, 0)),
        ((1.3, 0, 0), (0, 1, 0)),
        ((1.025, 0, -0.055), (-1, 0, 0)),
        ((0, 0, 0), (0, 1, 0)),
        ((0.290, 0, 0), (-1, 0, 0)),
    ]
    t = np.eye(4)
    for (xyz, axis), q in zip(joints, np.deg2rad(q_deg), strict=True):
        step = np.eye(4)
        step[:3, 3] = xyz
        step[:3, :3] = _rot(np.array(axis, float), q)
        t = t @ step
    tool0 = np.eye(4)
    tool0[:3, :3] = _rot(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    return t @ tool0


def test_home_pose_flange_is_in_front_at_published_position():
    pose = kin.flange_pose_xyzabc(kin.HOME_DEG)
    np.testing.assert_allclose(pose[:3], [1815.0, 0.0, 2290.0], atol=1e-6)
    np.testing.assert_allclose(pose[3:], [0.0, 90.0, 0.0], atol=1e-6)  # KUKA A, B, C: flange z forward


def test_candle_and_stretched_reach():
    np.testing.assert_allclose(kin.flange_pose_xyzabc(kin.CANDLE_DEG)[:3], [555.0, 0.0, 3660.0], atol=1e-6)
    # published reach 2826 mm: A1 axis to wrist centre, arm stretched (A2 = 0, A3 sweeping through the stretch)
    reach = max(np.hypot(*kin.joint_frames([0, 0, a3, 0, 0, 0])[4, :2, 3]) for a3 in np.linspace(-10, 10, 2001))
    assert reach == pytest.approx(0.5 + 1.3 + np.hypot(1.025, 0.055), abs=1e-5)
    assert round(reach * 1000) == 2826


def test_kuka_axis_directions():
    # A1 positive turns clockwise seen from above: the flange moves to −y
    assert kin.flange_pose_xyzabc([30, -90, 90, 0, 0, 0])[1] < -900
    # A5 positive tilts the flange down; A3 positive lowers the forearm
    assert kin.flange_pose_xyzabc([0, -90, 90, 0, 90, 0])[2] == pytest.approx(2000.0)
    assert kin.flange_pose_xyzabc([0, -90, 100, 0, 0, 0])[2] < 2290.0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-170, 170), min_size=6, max_size=6))
def test_dh_matches_urdf_chain(q):
    np.testing.assert_allclose(kin.flange_frame(q), urdf_flange(q), atol=1e-9)


def test_point_mass_lever_in_measurement_pose():
    q = kin.measurement_pose()
    m, z = 50.0, 0.5  # 50 kg, 0.5 m out from the flange along its axis
    tau = kin.gravity_torques_nm(q, [(m, (0.0, 0.0, z))])
    np.testing.assert_allclose(tau[4], -G * m * (kin.D6_M + z))
    np.testing.assert_allclose(tau[2], -G * m * (kin.D4_M + kin.D6_M + z))
    np.testing.assert_allclose(tau[1], tau[2])  # upper arm vertical: A2 straight below A3
    np.testing.assert_allclose(tau[[0, 3, 5]], 0.0, atol=1e-9)
    # a CoG offset sideways (flange y) loads the torsional axes A4 and A6 with g·m·offset
    tau_side = kin.gravity_torques_nm(q, [(m, (0.0, 0.1, 0.0))])
    np.testing.assert_allclose(np.abs(tau_side[[3, 5]]), G * m * 0.1)


@settings(max_examples=50, deadline=None)
@given(
    st.floats(1.0, 600.0),
    st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.2, 1.5)),
    st.floats(-120.0, 0.0),
)
def test_eq3_lever_difference_is_d4_whatever_the_cog(mass_kg, cog, a2_deg):
    q = kin.measurement_pose(a2_deg=a2_deg)
    tau = kin.gravity_torques_nm(q, [(mass_kg, cog)])
    # eq. 3: M_A3 − M_A5 = m·g·(r_A3 − r_A5) = m·g·d4 (holding torques are negative for a load in front)
    assert tau[2] - tau[4] == pytest.approx(-G * mass_kg * kin.D4_M, rel=1e-9)
    assert kin.horizontal_lever_m(q, 3, cog) - kin.horizontal_lever_m(q, 5, cog) == pytest.approx(kin.D4_M)


def _potential(q, bodies=None, links=None):
    v = 0.0
    if bodies:
        for m, c in bodies:
            v += m * G * kin.flange_point_m(q, c)[2]
    if links:
        frames = kin.joint_frames(q)
        for link, m, c in links:
            v += m * G * (frames[link - 1, :3, :3] @ np.array(c) + frames[link - 1, :3, 3])[2]
    return v


@pytest.mark.parametrize("q", [[10, -70, 80, 30, -40, 60], [0, -90, 90, 0, 0, 0], [-30, -20, 120, -90, 70, 200]])
def test_holding_torque_is_gradient_of_potential_energy(q):
    """τ_i = ∂V/∂A_i (V = Σ m g z): an independent check of the regressor and of the link torques."""
    bodies = [(80.0, (0.05, -0.1, 0.4)), (20.0, (0.0, 0.2, 0.1))]
    links = [(2, 400.0, (0.6, 0.0, 0.0)), (3, 250.0, (0.05, 0.1, 0.02)), (5, 60.0, (0.0, -0.1, 0.01))]
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        dv_b = (_potential(np.add(q, dq), bodies=bodies) - _potential(np.subtract(q, dq), bodies=bodies)) / (2 * h)
        dv_l = (_potential(np.add(q, dq), links=links) - _potential(np.subtract(q, dq), links=links)) / (2 * h)
        per_rad = 180.0 / np.pi
        assert kin.gravity_torques_nm(q, bodies)[i] == pytest.approx(dv_b * per_rad, abs=1e-4)
        assert kin.link_gravity_torques_nm(q, links)[i] == pytest.approx(dv_l * per_rad, abs=1e-4)


def test_single_axis_speed_is_omega_times_radius():
    q = kin.HOME_DEG
    w_deg_s = 10.0
    # A1 alone: the flange circles the vertical A1 axis at radius 1.815 m
    v = kin.point_velocity_mm_s(q, [w_deg_s, 0, 0, 0, 0, 0])
    assert np.linalg.norm(v) == pytest.approx(np.deg2rad(w_deg_s) * 1815.0)
    # A6 alone: a point 0.3 m off the flange axis moves at ω·0.3 m
    v6 = kin.point_velocity_mm_s(q, [0, 0, 0, 0, 0, w_deg_s], (0.3, 0.0, 0.5))
    assert np.linalg.norm(v6) == pytest.approx(np.deg2rad(w_deg_s) * 300.0)


def test_jacobian_matches_finite_differences():
    q = np.array([5.0, -60.0, 70.0, 20.0, -30.0, 45.0])
    p = (0.1, -0.05, 0.6)
    jac = kin.point_jacobian(q, p)
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = 1e-5
        num = (kin.flange_point_m(q + dq, p) - kin.flange_point_m(q - dq, p)) / (2e-5 * np.pi / 180.0)
        np.testing.assert_allclose(jac[:, i], num, atol=1e-6)


def test_ptp_synchronous_speeds():
    qdot = kin.ptp_joint_speeds_deg_s(kin.HOME_DEG, [10, -90, 80, 0, 40, 0], [10, 10, 10, 10, 5, 10])
    # A5 (40° at 5°/s) is the slowest: 8 s; every axis arrives together
    np.testing.assert_allclose(qdot, [1.25, 0, -1.25, 0, 5.0, 0])


@pytest.mark.parametrize(
    ("q0", "q1"),
    [
        ([0, -90, 90, 0, 0, 0], [30, -60, 100, 90, 40, 180]),
        ([-40, -100, 120, -50, -60, 0], [40, -30, 30, 50, 60, 90]),
        ([0, -90, 90, 0, 0, 0], [0, -90, 90, 0, 0, 0]),
    ],
)
def test_worst_case_bound_covers_the_sampled_maximum(q0, q1):
    payload_corners = [(x, y, z) for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.0, 0.8)]
    res = kin.max_point_speed_mm_s(q0, q1, 5.0, payload_corners)
    assert res.bound_mm_s >= res.sampled_max_mm_s
    # an independent dense check of the flange speed along the same path
    qdot = kin.ptp_joint_speeds_deg_s(q0, q1, 5.0)
    dense = [
        np.linalg.norm(kin.point_velocity_mm_s(np.add(q0, s * np.subtract(q1, q0)), qdot, c))
        for s in np.linspace(0, 1, 301)
        for c in payload_corners
    ]
    assert max(dense) <= res.bound_mm_s + 1e-9
    assert max(dense) == pytest.approx(res.sampled_max_mm_s, rel=0.01, abs=1e-9)
    unsync = kin.max_point_speed_mm_s(q0, q1, 5.0, payload_corners, synchronous=False)
    assert unsync.bound_mm_s >= res.bound_mm_s - 1e-9


def test_bound_flags_a_program_faster_than_200_mm_s():
    slow = kin.max_point_speed_mm_s(kin.HOME_DEG, [0, -90, 90, 0, 35, 0], 5.0, [(0.0, 0.0, 1.0)])
    fast = kin.max_point_speed_mm_s(kin.HOME_DEG, [45, -90, 90, 0, 35, 0], 30.0, [(0.0, 0.0, 1.0)])
    assert slow.bound_mm_s < 200.0 < fast.sampled_max_mm_s


def test_limits_and_input_checks():
    assert kin.within_limits(kin.HOME_DEG)
    assert not kin.within_limits([0, -90, 150, 0, 0, 0])
    with pytest.raises(ValueError):
        kin.measurement_pose(a2_deg=-135.0)
    with pytest.raises(ValueError):
        kin.joint_frames([0, 0, 0])
    with pytest.raises(ValueError):
        kin.joint_frames([0, 0, 0, 0, 0, np.nan])


@pytest.mark.parametrize("robot_key", ["kr500r2830", "kr10r1440"])
def test_a_path_at_once_gives_each_sample_s_frames_and_speeds(robot_key):
    """The interlock's sampled path in one numpy pass (joint_frames_path, path_speeds) gives exactly the frames of
    one pose at a time, and per sample and point the speed of the point's own Jacobian."""
    from rgse_daemon import robots

    robot = robots.get(robot_key)
    rng = np.random.default_rng(5)
    q0, q1 = rng.uniform(-120, 120, 6), rng.uniform(-120, 120, 6)
    path = q0[None, :] + np.linspace(0.0, 1.0, 41)[:, None] * (q1 - q0)[None, :]
    frames = kin.joint_frames_path(path, robot)
    assert frames.shape == (41, 6, 4, 4)
    for k in (0, 17, 40):
        np.testing.assert_array_equal(frames[k], kin.joint_frames(path[k], robot))
    qdot = kin.ptp_joint_speeds_deg_s(q0, q1, 20.0)
    corners = [(0.2, -0.1, 0.6), (-0.3, 0.2, 0.1)]
    res = kin.path_speeds(path, qdot, corners, robot)
    per_sample = np.array([[np.linalg.norm(kin.point_velocity_mm_s(q, qdot, c, robot)) for c in corners]
                           for q in path])
    np.testing.assert_allclose(res.per_point_max_mm_s[3:], per_sample.max(axis=0), rtol=1e-12)
    flange = max(np.linalg.norm(kin.point_velocity_mm_s(q, qdot, (0.0, 0.0, 0.0), robot)) for q in path)
    assert res.per_point_max_mm_s[2] == pytest.approx(flange, rel=1e-12)
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        kin.joint_frames_path(path[:, :5], robot)
    with pytest.raises(ValueError, match="finite"):
        kin.joint_frames_path(np.where(np.arange(6) == 2, np.inf, path), robot)
