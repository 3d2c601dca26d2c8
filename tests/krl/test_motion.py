"""Joint motion profiles of the simulated KR C4: synchronised PTP, override, T1 flange-speed clamp, STOP 2 ramp."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simulators.krc4.motion import (
    MAX_AXIS_SPEED_DEG_S,
    MotionError,
    MotionSettings,
    Profile,
    flange_speed_mm_s,
    plan_joint_move,
)

HOME = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)


def sample(move, n: int = 400) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.linspace(0.0, move.duration_s, n)
    states = [move.state(ti) for ti in t]
    return t, np.array([q for q, _ in states]), np.array([v for _, v in states])


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 10.0), st.floats(0.01, 20.0))
def test_trapezoid_goes_from_zero_to_one_within_its_limits(v_max: float, a_max: float) -> None:
    profile = Profile.trapezoid(v_max, a_max)
    assert profile.at(0.0) == (0.0, 0.0)
    s_end, v_end = profile.at(profile.duration_s)
    assert s_end == pytest.approx(1.0) and v_end == pytest.approx(0.0, abs=1e-9)
    ts = np.linspace(0.0, profile.duration_s, 200)
    speeds = np.array([profile.at(t)[1] for t in ts])
    positions = np.array([profile.at(t)[0] for t in ts])
    assert speeds.max() <= v_max * (1 + 1e-9) and speeds.min() >= -1e-9
    assert np.all(np.diff(positions) >= -1e-12)


def test_ptp_is_synchronised_and_the_leading_axis_runs_at_its_limit() -> None:
    target = (30.0, -80.0, 100.0, 10.0, -20.0, 5.0)
    move = plan_joint_move("PTP", HOME, target, MotionSettings(vel_axis_pct=(20.0,) * 6))
    _, q, qd = sample(move)
    np.testing.assert_allclose(q[0], HOME)
    np.testing.assert_allclose(q[-1], target)
    limits = 0.2 * np.array(MAX_AXIS_SPEED_DEG_S)
    peak = np.abs(qd).max(axis=0)
    assert np.all(peak <= limits + 1e-9)
    assert np.isclose(peak / limits, 1.0).any()  # A1 leads: 30 deg at 16 deg/s
    # every axis is the same fraction of the way at every instant: one straight joint-space line
    frac = (q - np.array(HOME)) / (np.array(target) - np.array(HOME))
    np.testing.assert_allclose(frac, frac[:, :1].repeat(6, axis=1), atol=1e-9)
    assert move.directions() == (1, 1, 1, 1, -1, 1)


def test_override_slows_the_motion() -> None:
    target = (20.0, -90.0, 90.0, 0.0, 0.0, 0.0)
    full = plan_joint_move("PTP", HOME, target, MotionSettings(vel_axis_pct=(10.0,) * 6))
    half = plan_joint_move("PTP", HOME, target, MotionSettings(vel_axis_pct=(10.0,) * 6, override_pct=50.0))
    assert half.duration_s == pytest.approx(2.0 * full.duration_s)


def test_target_outside_the_software_limits_is_refused() -> None:
    with pytest.raises(MotionError, match="A2 target"):
        plan_joint_move("PTP", HOME, (0.0, 30.0, 90.0, 0.0, 0.0, 0.0), MotionSettings())
    with pytest.raises(MotionError, match="above 0 %"):
        plan_joint_move("PTP", HOME, (10.0, -90.0, 90.0, 0.0, 0.0, 0.0), MotionSettings(override_pct=0.0))


def test_t1_clamps_the_flange_speed_instead_of_refusing() -> None:
    target = (45.0, -60.0, 60.0, 0.0, 30.0, 0.0)
    fast = MotionSettings()  # 100 % axis speeds: the flange would move well above 1 m/s
    free = plan_joint_move("PTP", HOME, target, fast)
    t1 = plan_joint_move("PTP", HOME, target, fast, t1_limit_mm_s=250.0)
    speeds_free = [flange_speed_mm_s(q, v) for q, v in zip(*sample(free)[1:], strict=True)]
    speeds_t1 = [flange_speed_mm_s(q, v) for q, v in zip(*sample(t1)[1:], strict=True)]
    assert max(speeds_free) > 1000.0 and not free.t1_clamped
    assert t1.t1_clamped and max(speeds_t1) <= 250.0 + 1e-6 and max(speeds_t1) > 240.0
    assert t1.duration_s > free.duration_s
    np.testing.assert_allclose(t1.state(t1.duration_s)[0], target)


def test_lin_keeps_the_flange_at_vel_cp() -> None:
    target = (10.0, -85.0, 95.0, 0.0, 0.0, 0.0)
    move = plan_joint_move("LIN", HOME, target, MotionSettings(vel_cp_m_s=0.05))
    speeds = [flange_speed_mm_s(q, v) for q, v in zip(*sample(move)[1:], strict=True)]
    assert max(speeds) <= 50.0 + 1e-6 and max(speeds) > 45.0
    assert not move.t1_clamped


def test_stop2_ramps_down_on_the_path_and_short_of_the_target() -> None:
    target = (40.0, -90.0, 90.0, 0.0, 0.0, 0.0)
    move = plan_joint_move("PTP", HOME, target, MotionSettings(vel_axis_pct=(10.0,) * 6))
    t_stop = move.duration_s / 2
    q_at, v_at = move.state(t_stop)
    braking = move.stopped_at(t_stop)
    np.testing.assert_allclose(braking.q_start_deg, q_at)
    q_rest, v_rest = braking.state(braking.duration_s)
    np.testing.assert_allclose(v_rest, 0.0, atol=1e-9)
    assert q_at[0] < q_rest[0] < target[0]  # it travelled on, but stopped short
    np.testing.assert_allclose(q_rest[1:], HOME[1:])  # the other axes stay on the (straight) path
    _, _, qd = sample(braking)
    assert np.abs(qd[:, 0]).max() <= abs(v_at[0]) + 1e-9
    # braking takes v / decel: the profile's own deceleration
    assert braking.duration_s == pytest.approx(abs(v_at[0]) / (move.profile.decel * 40.0))
    at_rest = move.stopped_at(move.duration_s)
    assert at_rest.duration_s == 0.0 and at_rest.q_end_deg == pytest.approx(target)
