"""The assembled simulated KR C4 over the link: live torques from the physics, motions feeding the physics, the T1
operator (enabling switch, STOP 2), operating mode, construction and ``serve_forever``."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.errors import ConfigError
from rgse_daemon.kinematics import flange_pose_xyzabc
from rgse_daemon.link.errors import CommandError
from rgse_daemon.link.krlvalue import KrlStruct
from simulators.krc4.physics import Payload, RobotModel, dut_payload, mass_calibration_payload
from simulators.krc4.scenario import default_scenario
from simulators.krc4.sim import SimulatedKrc4

from .conftest import DEADLINE_S, poll, put_config, put_program, run_to_end, trace_config_xml

SCENARIO = default_scenario()


async def axes_deg(krc: Controller) -> np.ndarray:
    value = await krc.read("$AXIS_ACT")
    assert isinstance(value, KrlStruct)
    return np.array([float(value[f"A{i}"]) for i in range(1, 7)])  # type: ignore[arg-type]


async def test_mount_changes_torques_as_the_physics_says(sim: SimulatedKrc4, krc: Controller) -> None:
    sim.set_enabling_switch(True)  # T1: drives on while the switch is held
    assert await krc.read("$PERI_RDY") is True and await krc.read_raw("$BRAKE_SIG") == "B111111"
    reference = RobotModel(SCENARIO, seed=7)  # the fixture's simulated robot: the same arm as built
    kt_ratio = np.array([SCENARIO.axis(i).torque_constant_nm_a * SCENARIO.axis(i).gear_ratio for i in range(1, 7)])
    snapshots = {}
    for label, payload in (
        ("bare", Payload()),
        ("mpa_3cb", mass_calibration_payload(3)),
        ("dut", dut_payload(250.0, (0.05, 0.0, 0.40))),
    ):
        sim.mount(payload)
        # the same mounting in the reference: every mounting seats the load a little differently
        reference.mount_offset_nm, reference.mount_cog_shift_m = sim.model.mount_offset_nm, sim.model.mount_cog_shift_m
        snap = await krc.snapshot()
        assert snap.axes_deg is not None and snap.pos_act is not None
        q = np.array(snap.axes_deg)
        expected = reference.static_reading_nm(q, payload)
        np.testing.assert_allclose(np.array(snap.torques_nm, dtype=float), expected, atol=1e-3)
        currents = np.array([float(await krc.read_raw(f"$CURR_ACT[{i}]")) for i in range(1, 7)])
        np.testing.assert_allclose(currents, expected / kt_ratio, atol=1e-4)
        pose = snap.pos_act
        np.testing.assert_allclose([pose.x_mm, pose.y_mm, pose.z_mm], flange_pose_xyzabc(q)[:3], atol=1e-3)
        snapshots[label] = np.array(snap.torques_nm, dtype=float)
    # more load in front of the wrist: A3 and A5 hold more (holding torque is negative in front)
    assert snapshots["dut"][2] < snapshots["mpa_3cb"][2] < snapshots["bare"][2]
    assert snapshots["dut"][4] < snapshots["mpa_3cb"][4] < snapshots["bare"][4]

    sim.set_enabling_switch(False)  # drives off: the brakes hold the load, the motors carry nothing
    snap = await krc.snapshot()
    assert snap.torques_nm == (0.0,) * 6 and snap.brake_sig == "000000" and snap.peri_rdy is False


WARM_SRC = """DEF warm( )
  DECL INT i
  BAS(#INITMOV, 0)
  FOR i = 1 TO 3
    PTP_REL {A3 30.0, A5 30.0}
    PTP_REL {A3 -30.0, A5 -30.0}
  ENDFOR
  PTP_REL {A3 -10.0, A5 10.0}
  $TRACE.CONFIG[] = "t2.xml"
  $TRACE.NAME[] = "right_after"
  $TRACE.MODE = #T_START
  WAIT FOR $TRACE.STATE == #T_END
  WAIT SEC 30.0
  $TRACE.NAME[] = "later"
  $TRACE.MODE = #T_START
  WAIT FOR $TRACE.STATE == #T_END
END
"""


async def test_motions_heat_the_motors_and_restart_the_settling_clock(sim: SimulatedKrc4, krc: Controller) -> None:
    cold_k = float(await krc.read_raw("$MOT_TEMP[3]"))
    assert cold_k == round(SCENARIO.thermal.ambient_k)
    await put_config(krc, "t2.xml", trace_config_xml(2.0, modules=("NextGenDrive#3", "NextGenDrive#5")))
    await run_to_end(krc, await put_program(krc, "WARM", WARM_SRC))
    assert float(await krc.read_raw("$MOT_TEMP[3]")) > cold_k
    after, later = sim.truths["right_after"], sim.truths["later"]
    assert after.t_since_release_s < 30.0 <= later.t_since_release_s - after.t_since_release_s
    assert after.last_approach_sign[2] == -1.0 and after.last_approach_sign[4] == 1.0  # the last move's direction
    assert after.motor_temp_k[2, 0] > SCENARIO.thermal.ambient_k + 1.0
    # the settling oscillation after the last move has decayed by the later trace
    assert np.abs(later.terms["settle"][2]).max() < np.abs(after.terms["settle"][2]).max()


LONG_MOVE_SRC = """DEF longmove( )
  BAS(#INITMOV, 0)
  PTP {A1 40.0}
END
"""


async def test_releasing_the_enabling_switch_is_a_stop_2(sim: SimulatedKrc4, krc: Controller) -> None:
    await krc.write("$OV_PRO", 10)  # slow: the move lasts long enough to be caught moving
    program = await put_program(krc, "LONGMOVE", LONG_MOVE_SRC)
    await krc.select_program(program)
    await krc.start_program()
    await poll(krc, "$ROB_STOPPED", lambda v: v == "FALSE")
    sim.set_enabling_switch(False)
    await poll(krc, "$PRO_STATE1", lambda v: v == "#P_STOP")
    assert await krc.read("$STOPMESS") is True
    await poll(krc, "$ROB_STOPPED", lambda v: v == "TRUE")
    stopped_at = await axes_deg(krc)
    assert 0.0 < stopped_at[0] < 40.0
    await asyncio.sleep(0.05)  # 5 simulated seconds: a stopped robot stays where it is
    np.testing.assert_array_equal(await axes_deg(krc), stopped_at)

    sim.set_enabling_switch(True)
    with pytest.raises(CommandError):  # the stop message must be acknowledged first
        await krc.start_program()
    await krc.confirm_all()
    assert await krc.read("$STOPMESS") is False
    await krc.start_program()
    await poll(krc, "$PRO_STATE1", lambda v: v == "#P_END")
    assert (await axes_deg(krc))[0] == pytest.approx(40.0)


async def test_operating_mode(sim: SimulatedKrc4, krc: Controller) -> None:
    sim.set_mode("AUT")
    assert await krc.read_raw("$MODE_OP") == "#AUT"
    sim.set_mode("#t1")
    assert (await krc.snapshot()).mode_op == "T1"
    with pytest.raises(ValueError, match="mode"):
        sim.set_mode("T3")


async def test_serve_forever_until_cancelled(tmp_path: Path) -> None:
    scenario = tmp_path / "bremen.toml"
    scenario.write_text("g_m_s2 = 9.8134\n")
    sim = SimulatedKrc4(tmp_path / "roboter", scenario=scenario, time_scale=50.0, latency_s=0.0)
    assert sim.model.g_m_s2 == 9.8134
    task = asyncio.create_task(sim.serve_forever())
    try:
        async with asyncio.timeout(DEADLINE_S):
            while sim.port == 0:  # noqa: ASYNC110 - nothing signals the bind
                await asyncio.sleep(0.001)
        cfg = ControllerConfig(host="127.0.0.1", port=sim.port, request_timeout_s=2.0, pool_size=1)
        async with Controller.connect(cfg) as krc:
            assert (await krc.snapshot()).trace_state == "T_END"
    finally:
        task.cancel()
        async with asyncio.timeout(DEADLINE_S):
            with contextlib.suppress(asyncio.CancelledError):
                await task
    with pytest.raises(OSError):
        async with asyncio.timeout(DEADLINE_S):
            await asyncio.open_connection("127.0.0.1", sim.port)


def test_bad_construction_is_a_config_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[axes.A3]\nnoise_nm = -1.0\n")
    with pytest.raises(ConfigError, match="noise_nm"):
        SimulatedKrc4(tmp_path / "r1", scenario=bad)
    with pytest.raises(ConfigError, match="cannot read"):
        SimulatedKrc4(tmp_path / "r2", scenario=tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="time_scale"):
        SimulatedKrc4(tmp_path / "r3", time_scale=0.0)


async def test_installed_globals_are_read_and_written_over_the_link(sim: SimulatedKrc4, krc: Controller) -> None:
    from rgse_daemon.krl.render import globals_dat_text

    names = sim.install_globals(globals_dat_text())
    assert "RGSE_CMD" in names and "RGSE_DONE" in names
    assert sim.install_globals(globals_dat_text()) == names  # installing twice keeps the values
    await krc.write("RGSE_CMD", 3)
    assert await krc.read("RGSE_CMD") == 3
    assert await krc.read("RGSE_DONE") is False
    with pytest.raises(ConfigError, match="not supported"):
        sim.install_globals("DEFDAT bad PUBLIC\nDECL GLOBAL E6AXIS RGSE_POSE\nENDDAT\n")
