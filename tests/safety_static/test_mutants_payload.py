"""The load diagram's A5 torque and the axis speeds a refused write leaves (issue #31's survivors of mutmut on
``safety/static.py`` that no test killed): worked out independently here and compared exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon import robots
from rgse_daemon.kinematics import G_PAPER_M_S2, gravity_torques_nm
from rgse_daemon.safety.static import TORQUE_STEP_DEG, CheckContext, _Checker, check_program

MEAS = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
SLOW = "\n".join(f"  $VEL_AXIS[{i}] = 2\n  $ACC_AXIS[{i}] = 20" for i in range(1, 7))


def test_a_payload_under_a_kilogram_still_loads_a5() -> None:
    """0.5 kg at 0.2 m from the flange: far below the limit, so the bound is the answer: m·g·|c + d6·z|."""
    ctx = CheckContext(start_axes_deg=MEAS, payload_mass_kg=0.5, payload_cog_flange_m=(0.0, 0.0, 0.2))
    d6 = ctx.robot.dh[5].d_m
    assert _Checker(ctx).max_a5_torque_nm(MEAS, MEAS) == pytest.approx(0.5 * G_PAPER_M_S2 * (0.2 + d6), rel=1e-12)
    none = CheckContext(start_axes_deg=MEAS, payload_mass_kg=0.0, payload_cog_flange_m=(0.0, 0.0, 0.2))
    assert _Checker(none).max_a5_torque_nm(MEAS, MEAS) == 0.0


def test_the_a5_torque_is_the_checked_robots() -> None:
    """The KR 10 with 9 kg 0.3 m out: its bound (9·g·(0.3 + d6)) is above its 19.6 Nm limit, so the path is sampled
    on the KR 10's own geometry (the KR 500's would give another torque): the largest sampled |A5| plus the margin
    for the unsampled path, 2·m·g·(d6 + |c|)·step."""
    kr10 = robots.get("kr10r1440")
    start, target = MEAS, (0.0, -90.0, 90.0, 0.0, 40.0, 0.0)
    ctx = CheckContext(start_axes_deg=start, payload_mass_kg=9.0, payload_cog_flange_m=(0.0, 0.0, 0.3), robot=kr10)
    d6 = kr10.dh[5].d_m
    assert 9.0 * G_PAPER_M_S2 * (0.3 + d6) > kr10.max_a5_torque_nm
    n = math.ceil(40.0 / TORQUE_STEP_DEG) + 1
    body = [(9.0, (0.0, 0.0, 0.3))]
    worst = max(abs(float(gravity_torques_nm(np.array(start) + s * (np.array(target) - np.array(start)), body,
                                             robot=kr10)[4])) for s in np.linspace(0.0, 1.0, n))
    expected = worst + 2.0 * 9.0 * G_PAPER_M_S2 * (d6 + 0.3) * math.radians(40.0 / (n - 1))
    got = _Checker(ctx).max_a5_torque_nm(start, target)
    assert got == pytest.approx(expected, rel=1e-12)
    kr500 = max(abs(float(gravity_torques_nm(np.array(start) + s * (np.array(target) - np.array(start)), body)[4]))
                for s in np.linspace(0.0, 1.0, n))
    assert abs(kr500 - worst) > 0.1  # the two arms differ here: the test tells them apart


def test_a_speed_written_to_an_unknown_axis_counts_as_full_speed_on_every_axis() -> None:
    """``$VEL_AXIS[i]`` with i not a constant: refused, and every axis is then taken at 100 % (the worst the write
    could have done); the motion after it is checked, and refused, at 100 % on all six."""
    src = (f"&ACCESS RVP\n&REL 1\nDEF world( )\n  DECL INT i\n{SLOW}\n  i = $IN[1]\n  $VEL_AXIS[i] = 2\n"
           "  PTP {A1 10}\nEND\n")
    v = check_program(src, None, CheckContext(start_axes_deg=MEAS), "world.src")
    rules = [(x.rule, x.message) for x in v]
    assert ("VELOCITY", "$VEL_AXIS must be set per axis with a constant index 1..6") in rules, rules
    speed = [m for r, m in rules if r == "SPEED"]
    assert len(speed) == 1 and speed[0].endswith("($VEL_AXIS 100/100/100/100/100/100 %, override 100 %)"), speed
