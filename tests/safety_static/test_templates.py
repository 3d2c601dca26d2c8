"""The daemon's KRL templates: they render, parse, pass the static check and run on the simulated KR C4."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Callable, Sequence

import numpy as np
import pytest

from rgse_daemon.commands.krl import default_context, template_defaults
from rgse_daemon.config import Config
from rgse_daemon.errors import ConfigError
from rgse_daemon.kinematics import measurement_pose
from rgse_daemon.krl import parse_dat, parse_src
from rgse_daemon.krl.ast import Assign, BoolLit, IntLit, Motion, Name
from rgse_daemon.krl.render import (
    CAL_POSES_DEG,
    OPER_POSE_DEG,
    TEMPLATES,
    RenderedProgram,
    cube_corners,
    default_params,
    format_axes,
    format_int,
    format_real,
    globals_dat_text,
    render,
    safe_axis_velocity_pct,
)
from rgse_daemon.krl.walk import walk
from rgse_daemon.safety.allowlist import WATCHDOG_TIMER
from rgse_daemon.safety.static import check_program
from simulators.krc4.krl import KrlInterpreter, parse_axes
from simulators.krc4.variables import Kind, ProgramControlError, ProState, VariableStore, e6axis, module_name

TIME_SCALE = 5000.0
MEAS = tuple(float(v) for v in measurement_pose())
Sim = tuple[KrlInterpreter, VariableStore]


@pytest.fixture(scope="module")
def rendered() -> dict[str, RenderedProgram]:
    defaults = template_defaults(Config())
    return {name: render(name, default_params(name, defaults)) for name in TEMPLATES}


# --- rendering ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", TEMPLATES)
def test_template_renders_parses_and_passes_the_check(rendered: dict[str, RenderedProgram], name: str) -> None:
    program = rendered[name]
    assert "{{" not in program.src_text and "}}" not in program.src_text
    module = parse_src(program.src_text, f"{name}.src")
    assert module.headers[0] == "&ACCESS RVP" and module.main.name == name.upper() and not module.main.params
    assert check_program(program.src_text, program.dat_text, default_context(Config()), f"{name}.src") == []
    # every axis speed and acceleration is set explicitly before the first motion
    set_before: set[tuple[str, int]] = set()
    for visit in walk(module):
        if isinstance(visit.stmt, Motion):
            break
        s = visit.stmt
        if isinstance(s, Assign) and isinstance(s.target, Name) is False and hasattr(s.target, "indices"):
            base = s.target.base  # type: ignore[union-attr]
            index = s.target.indices[0]  # type: ignore[union-attr]
            if isinstance(base, Name) and isinstance(index, IntLit):
                set_before.add((base.name, index.value))
    assert set_before == {(v, i) for v in ("$VEL_AXIS", "$ACC_AXIS") for i in range(1, 7)}
    assert 0.0 < program.params.vel_axis_pct <= 100.0


def test_handshake_globals_are_global_and_allow_listed() -> None:
    data = parse_dat(globals_dat_text(), "rgse_globals.dat")
    names = {dn.name for d in data.globals for dn in d.names}
    assert data.public and len(data.globals) == len(data.decls)
    assert {"RGSE_CMD", "RGSE_ARG", "RGSE_ACK", "RGSE_BUSY", "RGSE_STEP", "RGSE_LOOP", "RGSE_DONE",
            "RGSE_WD_TRIP"} == names


def test_velocity_keeps_the_farthest_point_under_the_limit() -> None:
    corners = cube_corners(1.0)
    paths = [[MEAS, OPER_POSE_DEG]]
    fast = safe_axis_velocity_pct(paths, 200.0, ())
    slow = safe_axis_velocity_pct(paths, 200.0, corners)
    assert 0.0 < slow < fast <= 100.0  # a payload reaching 1 m needs a slower axis speed
    assert safe_axis_velocity_pct(paths, 100.0, corners) <= slow / 2 + 0.01  # linear in the limit
    assert safe_axis_velocity_pct([[MEAS, MEAS]], 200.0, corners) == 100.0  # nothing moves
    with pytest.raises(ValueError):
        safe_axis_velocity_pct(paths, 0.0, corners)


def test_render_rejects_bad_parameters() -> None:
    ok = {"vel_axis_pct": 2.0}
    render("rgse_meas_pose", ok)
    with pytest.raises(ConfigError, match="unknown KRL template"):
        render("rgse_nothing", ok)
    with pytest.raises(ConfigError, match="Extra inputs"):
        render("rgse_meas_pose", {**ok, "amplitude_deg": 3.0})  # supplied but not used by this template
    with pytest.raises(ConfigError, match="vel_axis_pct"):
        render("rgse_meas_pose", {})  # not supplied
    with pytest.raises(ConfigError, match="less than or equal to 100"):
        render("rgse_meas_pose", {"vel_axis_pct": 150.0})
    with pytest.raises(ConfigError, match="envelope"):
        render("rgse_oper_pose", {**ok, "oper_pose": (60.0, -45.0, 100.0, 0.0, -55.0, 0.0)})
    with pytest.raises(ConfigError, match="axis range"):
        render("rgse_cal_pose", {**ok, "cal_pose": (0.0, 30.0, 90.0, 0.0, 0.0, 0.0)})
    with pytest.raises(ConfigError, match="axis range"):  # 90 + 60 on A3 exceeds +144
        render("rgse_brake_release", {**ok, "angle_deg": 60.0})
    with pytest.raises(ConfigError, match="must not be 0"):
        render("rgse_brake_release", {**ok, "angle_deg": 0.0})
    with pytest.raises(ConfigError, match="cycles"):
        render("rgse_warmup", {**ok, "cycles": -1})


def test_krl_literals() -> None:
    assert format_real(2.0) == "2.0" and format_real(-0.0) == "0.0" and format_real(1.23456789) == "1.234568"
    assert format_real(-90) == "-90.0" and format_int(3) == "3"
    assert format_axes(MEAS) == "{E6AXIS: A1 0.0, A2 -90.0, A3 90.0, A4 0.0, A5 0.0, A6 0.0}"
    with pytest.raises(ValueError):
        format_real(math.nan)
    with pytest.raises(ValueError):
        format_int(2**31)


# --- on the simulator -------------------------------------------------------------------------------------------------
class Programs:
    def __init__(self, rendered: dict[str, RenderedProgram]) -> None:
        self.rendered = rendered

    def __call__(self, name: str) -> tuple[str, str, str | None]:
        mod = module_name(name)
        program = self.rendered.get(mod.lower())
        if program is None:
            raise ProgramControlError(f"{name} not found", 3)
        return mod, program.src_text, program.dat_text


@pytest.fixture
async def sim(rendered: dict[str, RenderedProgram]) -> AsyncIterator[Callable[[Sequence[float]], Sim]]:
    """A factory: a simulated KR C4 with the handshake globals installed, its robot standing at ``start``."""
    made: list[KrlInterpreter] = []

    def make(start: Sequence[float], time_scale: float = TIME_SCALE) -> Sim:
        store = VariableStore()
        kinds = {"INT": Kind.INT, "BOOL": Kind.BOOL}
        for decl in parse_dat(globals_dat_text()).globals:  # installed once on the controller (krl/README.md)
            init = decl.init
            text = ("TRUE" if init.value else "FALSE") if isinstance(init, BoolLit) else str(init.value)  # type: ignore[union-attr]
            store.declare_global(decl.names[0].name, kinds[decl.type_name], text)
        store.update("$AXIS_ACT", e6axis(start))
        # the daemon's heartbeat, set once for an hour: these tests are about the moves (the watchdog: below)
        store.write(f"$TIMER[{WATCHDOG_TIMER}]", "-3600000")
        store.write(f"$TIMER_STOP[{WATCHDOG_TIMER}]", "FALSE")
        interp = KrlInterpreter(store, Programs(rendered), time_scale=time_scale)
        made.append(interp)
        return interp, store

    yield make
    for interp in made:
        await interp.aclose()


def axes(store: VariableStore) -> np.ndarray:
    return np.array(parse_axes(store.read("$AXIS_ACT")))


END_POSE = {
    "rgse_meas_pose": MEAS,
    "rgse_oper_pose": OPER_POSE_DEG,
    "rgse_cal_pose": MEAS,
    "rgse_warmup": MEAS,
    "rgse_brake_release": MEAS,
}
END_STEP = {"rgse_meas_pose": 3, "rgse_oper_pose": 3, "rgse_cal_pose": 3, "rgse_warmup": 5, "rgse_brake_release": 5}


@pytest.mark.parametrize("name", list(END_POSE))
async def test_template_runs_on_the_simulator(sim, name: str) -> None:
    interp, store = sim(OPER_POSE_DEG if name != "rgse_oper_pose" else MEAS)  # start away from the end pose
    interp.run(name.upper(), "", False)
    state = await interp.wait_state(ProState.END, ProState.STOP, timeout_s=30.0)
    assert state is ProState.END, interp.last_error
    assert store.read("RGSE_DONE") == "TRUE" and store.read("RGSE_STEP") == str(END_STEP[name])
    np.testing.assert_allclose(axes(store), END_POSE[name], atol=1e-6)


async def test_resident_runs_commands_on_the_simulator(sim) -> None:
    interp, store = sim(MEAS)
    interp.run("RGSE_RESIDENT", "", False)

    async def command(cmd: int, arg: int = 0) -> str:
        store.write("RGSE_ARG", str(arg))
        store.write("RGSE_CMD", str(cmd))
        async with asyncio.timeout(30.0):
            while store.read("RGSE_CMD") != "0":  # noqa: ASYNC110 - the store has no change notification
                await asyncio.sleep(0.001)
        return store.read("RGSE_ACK")

    assert await command(4) == "4"
    np.testing.assert_allclose(axes(store), OPER_POSE_DEG, atol=1e-6)
    assert await command(3) == "3"  # brake release: ends in the measurement pose
    np.testing.assert_allclose(axes(store), MEAS, atol=1e-6)
    assert await command(5, 3) == "5"
    np.testing.assert_allclose(axes(store), CAL_POSES_DEG[2], atol=1e-6)
    assert await command(2) == "2" and store.read("RGSE_LOOP") == "0"
    np.testing.assert_allclose(axes(store), MEAS, atol=1e-6)
    assert await command(5, 7) == "-1" and await command(42) == "-1"  # unknown: nothing moves
    np.testing.assert_allclose(axes(store), MEAS, atol=1e-6)
    assert store.read("RGSE_DONE") == "TRUE" and store.read("RGSE_BUSY") == "FALSE"
    assert await command(99) == "99"
    assert await interp.wait_state(ProState.END, ProState.STOP, timeout_s=10.0) is ProState.END, interp.last_error


@pytest.mark.parametrize("name", ["rgse_warmup", "rgse_resident"])
async def test_template_without_heartbeat_does_not_move(sim, name: str) -> None:
    interp, store = sim(OPER_POSE_DEG)
    store.write(f"$TIMER_STOP[{WATCHDOG_TIMER}]", "TRUE")  # no daemon: the timer is not running
    interp.run(name.upper(), "", False)
    if name == "rgse_resident":
        store.write("RGSE_CMD", "2")
    await asyncio.sleep(0.5)
    assert interp.state is ProState.ACTIVE, interp.last_error  # waiting for a fresh heartbeat
    np.testing.assert_allclose(axes(store), OPER_POSE_DEG, atol=1e-9)


async def test_warmup_stops_on_its_path_when_the_heartbeat_lapses(sim) -> None:
    interp, store = sim(OPER_POSE_DEG, time_scale=10.0)  # the move lasts seconds of wall clock
    store.write(f"$TIMER[{WATCHDOG_TIMER}]", "-150")  # one beat, then the daemon is gone
    interp.run("RGSE_WARMUP", "", False)
    assert await interp.wait_state(ProState.END, ProState.STOP, timeout_s=30.0) is ProState.STOP
    assert interp.last_error is None  # HALT in the watchdog's routine, not a failure
    assert store.read("RGSE_WD_TRIP") == "TRUE" and store.read("RGSE_DONE") == "FALSE"
    assert store.read("$ROB_STOPPED") == "TRUE"
    held = axes(store)
    await asyncio.sleep(0.3)
    np.testing.assert_array_equal(axes(store), held)
