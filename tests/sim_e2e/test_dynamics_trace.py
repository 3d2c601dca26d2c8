"""KUKA Trace during a KRL motion, end to end: a program swings A6 back and forth with the wing box mounted, in T1;
the trace pulled over the link and read with the daemon's reader shows the motion and A6's inertial torque."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon.controller import Controller
from rgse_daemon.trace.diadem import read_trace_set
from simulators.krc4 import physics as ph
from simulators.krc4.dynamics import SERVO_LAG_S, MotionTruth, dynamic_reading_nm
from simulators.krc4.motion import T1_LIMIT_MM_S, MotionSettings, plan_joint_move
from simulators.krc4.scenario import ServerBehaviour, default_scenario
from simulators.krc4.sim import SimulatedKrc4

from .conftest import TIME_SCALE, poll, pull_trace, put_config, put_program, run_to_end, save, trace_config_xml

#: Long enough for the whole program: the simulator's clock runs on while the interpreter plans a T1 motion (the
#: robot stands meanwhile), so the moves may lie seconds apart in simulated time; #T_STOP ends the trace.
TRACE_S = 150.0


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    """The default scenario with a fast file transfer: a 4 ms trace of all drives is a few MB to pull."""
    scenario = default_scenario().model_copy(update={"server": ServerBehaviour(file_rate_bytes_s=1e8)})
    async with SimulatedKrc4(tmp_path / "roboter", scenario, seed=7, time_scale=TIME_SCALE, latency_s=0.0) as s:
        yield s

SWING_SRC = """DEF swing( )
  DECL INT i
  BAS(#INITMOV, 0)
  PTP {A1 0, A2 -90, A3 90, A4 0, A5 0, A6 0}
  $VEL_AXIS[6] = 12
  $ACC_AXIS[6] = 100
  $TRACE.CONFIG[] = "dyn.xml"
  $TRACE.NAME[] = "swing"
  $TRACE.MODE = #T_START
  WAIT SEC 0.5
  FOR i = 1 TO 2
    PTP {A6 40}
    PTP {A6 -40}
  ENDFOR
  PTP {A6 0}
  WAIT SEC 0.5
  $TRACE.MODE = #T_STOP
  WAIT FOR $TRACE.STATE == #T_END
END
"""

WRIST_SRC = """DEF wrist( )
  BAS(#INITMOV, 0)
  $TRACE.CONFIG[] = "dyn.xml"
  $TRACE.NAME[] = "wrist"
  $TRACE.MODE = #T_START
  PTP {A4 30, A5 -60}
  PTP {A4 0, A5 0}
  $TRACE.MODE = #T_STOP
  WAIT FOR $TRACE.STATE == #T_END
END
"""


async def test_a6_swing_trace_shows_motion_and_inertial_torque(
    sim: SimulatedKrc4, krc: Controller, tmp_path: Path
) -> None:
    wing = ph.refex_wing_box()
    sim.mount(wing.payload())
    sim.set_mode("T1")
    await put_config(krc, "dyn.xml", trace_config_xml(TRACE_S, rate_us=4000))
    await run_to_end(krc, await put_program(krc, "SWING", SWING_SRC))
    trace = read_trace_set(save(await pull_trace(krc, "swing"), tmp_path / "swing"), "swing")
    a6 = trace.files["NextGenDrive#6"]
    assert a6.period_s == pytest.approx(0.004)
    soll = a6.channel("Sollposition").values
    ist = a6.channel("Istposition").values
    torque = a6.channel("Istmoment").values
    # the motion as asked for: ±40° at 12 % of A6's 122 deg/s, four reversals, at rest at both ends
    assert soll.max() == pytest.approx(40.0, abs=1e-6) and soll.min() == pytest.approx(-40.0, abs=1e-6)
    assert soll[0] == pytest.approx(0.0, abs=1e-9) and soll[-1] == pytest.approx(0.0, abs=1e-9)
    speed = np.gradient(soll, a6.period_s)
    assert np.abs(speed).max() == pytest.approx(0.12 * kin.MAX_AXIS_SPEED_DEG_S[5], rel=0.01)
    assert np.abs(ist - soll).max() < 0.1
    for axis in range(1, 6):  # the other axes stand still
        other = trace.files[f"NextGenDrive#{axis}"].channel("Sollposition").values
        assert np.ptp(other) < 1e-9
    # the inertial torque on A6: Istmoment against [q̈, sign q̇, q̇, cos q, sin q, 1] (inertia, friction, the
    # off-axis CoG's gravity) over the moving samples; the q̈ coefficient is the joint-space inertia of A6 (arm,
    # rotor, wing box about the flange axis), the payload part seen through the drive's gain (A6: 4..8 % high).
    # The arm follows the command SERVO_LAG_S late: the motion behind the torques is Sollposition delayed.
    t = np.arange(len(soll)) * a6.period_s
    soll = np.interp(t - SERVO_LAG_S, t, soll)
    speed = np.gradient(soll, a6.period_s)
    accel = np.gradient(speed, a6.period_s)
    moving = np.abs(speed) > 0.5
    q6 = np.deg2rad(soll)
    regressors = np.column_stack(
        [np.deg2rad(accel), np.sign(speed), np.deg2rad(speed), np.cos(q6), np.sin(q6), np.ones_like(speed)]
    )[moving]
    coef, *_ = np.linalg.lstsq(regressors, torque[moving], rcond=None)
    m66 = sim.dynamics.mass_matrix_kgm2(kin.measurement_pose(), wing.payload())[5, 5]
    # the drive reads the payload's part high (above), so the estimate lies above m66, not about it: 1.085-1.088 x
    # m66 in three runs alone, 1.1006 once under make test's load (it failed the former ±10 % about m66)
    assert 1.0 <= coef[0] / m66 <= 1.15, (coef[0], m66)
    assert coef[1] > 0  # friction opposes the motion: the drive supplies it in the direction of travel
    inertial_peak = m66 * np.deg2rad(np.abs(accel).max())
    assert inertial_peak > 20 * ph.RobotModel().scenario.axis(6).noise_nm
    # the truth kept for tests is the moving one, and the reading is its sum
    truth = sim.truths["swing"]
    assert isinstance(truth, MotionTruth)
    np.testing.assert_allclose(sum(truth.terms.values())[5], torque, atol=1e-9)


async def test_t1_slows_a_recorded_wrist_motion(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    """At 100 % the flange would exceed 250 mm/s; in T1 the recorded motion keeps to it, in AUT it does not."""
    sim.set_mode("T1")
    await put_config(krc, "dyn.xml", trace_config_xml(TRACE_S, rate_us=12000))
    await run_to_end(krc, await put_program(krc, "WRIST", WRIST_SRC))
    trace = read_trace_set(save(await pull_trace(krc, "wrist"), tmp_path / "t1"), "wrist")
    q = np.column_stack([trace.channel(f"NextGenDrive#{i}", "Sollposition").values for i in range(1, 7)])
    qd = np.gradient(q, 0.012, axis=0)
    flange = np.array([np.linalg.norm(kin.point_velocity_mm_s(qk, vk)) for qk, vk in zip(q, qd, strict=True)])
    assert 0.8 * T1_LIMIT_MM_S < flange.max() <= T1_LIMIT_MM_S * 1.01
    assert np.ptp(q[:, 4]) == pytest.approx(60.0)
    sim.set_mode("AUT")
    await run_to_end(krc, await put_program(krc, "WRIST", WRIST_SRC.replace('"wrist"', '"fast"')))
    fast = read_trace_set(save(await pull_trace(krc, "fast"), tmp_path / "aut"), "fast")
    q = np.column_stack([fast.channel(f"NextGenDrive#{i}", "Sollposition").values for i in range(1, 7)])
    qd = np.gradient(q, 0.012, axis=0)
    flange = np.array([np.linalg.norm(kin.point_velocity_mm_s(qk, vk)) for qk, vk in zip(q, qd, strict=True)])
    assert flange.max() > 1.5 * T1_LIMIT_MM_S


LONG_SRC = """DEF longa6( )
  BAS(#INITMOV, 0)
  $VEL_AXIS[6] = 4
  $TRACE.CONFIG[] = "dyn.xml"
  $TRACE.NAME[] = "braked"
  $TRACE.MODE = #T_START
  WAIT SEC 0.3
  PTP {A6 340}
END
"""


async def test_stop2_during_a_traced_motion_brakes_on_the_path(
    sim: SimulatedKrc4, krc: Controller, tmp_path: Path
) -> None:
    """Releasing the enabling switch mid-motion: the trace shows the ramp down on the path to where the robot
    stands, with A6's inertial torque reversed while it brakes."""
    sim.mount(ph.refex_wing_box().payload())
    sim.set_mode("T1")
    await put_config(krc, "dyn.xml", trace_config_xml(TRACE_S, rate_us=4000, modules=("NextGenDrive#6",)))
    program = await put_program(krc, "LONGA6", LONG_SRC)
    await krc.select_program(program)
    await krc.start_program()
    await poll(krc, "$AXIS_ACT", lambda v: sim.interpreter.axes_deg[5] > 60.0)
    sim.set_enabling_switch(False)
    assert await poll(krc, "$PRO_STATE1", lambda v: v in ("#P_STOP", "#P_END")) == "#P_STOP"
    q_stop = float(sim.interpreter.axes_deg[5])
    await krc.write_raw("$TRACE.MODE", "#T_STOP")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    a6 = read_trace_set(save(await pull_trace(krc, "braked"), tmp_path / "braked"), "braked").files["NextGenDrive#6"]
    soll = a6.channel("Sollposition").values
    torque = a6.channel("Istmoment").values
    assert 60.0 < q_stop < 340.0
    assert soll[-1] == pytest.approx(q_stop, abs=1e-6)  # the trace ends where the robot stands
    assert np.all(np.diff(soll) >= -1e-9)  # never back: braking stays on the path
    speed = np.gradient(soll, a6.period_s)
    accel = np.gradient(speed, a6.period_s)
    braking = accel < -50.0
    assert braking.any() and np.abs(speed).max() == pytest.approx(0.04 * kin.MAX_AXIS_SPEED_DEG_S[5], rel=0.01)
    cruise = (np.abs(accel) < 1.0) & (speed > 4.0)
    assert torque[braking].mean() < torque[cruise].mean() - 50.0  # decelerating the wing box takes torque


async def test_torque_axis_act_during_a_motion_is_the_dynamic_reading(tmp_path: Path) -> None:
    sim = SimulatedKrc4(tmp_path / "roboter", seed=3, time_scale=1.0, latency_s=0.0)
    wing = ph.refex_wing_box()
    sim.mount(wing.payload())
    sim.store.update("$PERI_RDY", "TRUE")  # drives on
    q0 = kin.measurement_pose()
    still = np.array([float(sim.store.read(f"$TORQUE_AXIS_ACT[{i}]")) for i in range(1, 7)])
    np.testing.assert_allclose(still, sim.model.static_reading_nm(q0, wing.payload()), atol=1e-3)
    move = plan_joint_move("PTP", q0, q0 + np.array([0, 0, 0, 0, 0, 40.0]), MotionSettings(vel_axis_pct=(12.0,) * 6))
    now = sim.clock.now_s()
    sim.clock.now_s = lambda: now  # type: ignore[method-assign]  # the clock stands: reading and truth at one time
    sim.history.add(now - 1.0, move)  # started a second ago: A6 cruises at 14.6 deg/s
    moving = float(sim.store.read("$TORQUE_AXIS_ACT[6]"))
    m = sim.history.sample(np.array([now - SERVO_LAG_S]))
    expected = dynamic_reading_nm(sim.model, sim.dynamics, m.q_deg[0], m.qd_deg_s[0], m.qdd_deg_s2[0], wing.payload())
    assert moving == pytest.approx(expected[5], abs=1e-3)
    assert m.qd_deg_s[0, 5] == pytest.approx(0.12 * kin.MAX_AXIS_SPEED_DEG_S[5])
    static_there = sim.model.static_reading_nm(m.q_deg[0], wing.payload())[5]
    assert moving - static_there > 0.5 * sim.dynamics.friction[5].coulomb_nm  # the drive supplies the friction
