"""The warm-up until the A3/A5 motor temperatures are steady (paper §2.4.4 A): on the simulated KR C4, whose torque
estimate drifts with motor temperature, and on the pure steadiness rule."""

from __future__ import annotations

import numpy as np

from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.calibration import run_calibration, table1_points
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.procedures.warmup import ThermalHistory, warm_up
from simulators.krc4.physics import mass_calibration_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.plans import short

from .conftest import TIME_SCALE, make_engine

#: The simulator's default equilibrium motor temperature rise while the drives hold (K, scenario thermal model).
HOLD_RISE_K = 40.0
AMBIENT_K = 293.15


def steady_settings(cfg, **kw) -> RunSettings:
    """Windows in wall time: the simulator's clock runs TIME_SCALE times faster (300 s of motion → 3 s)."""
    base = {"warmup_until_steady": True, "warmup_steady_window_s": 300.0 / TIME_SCALE,
            "warmup_max_s": 2400.0 / TIME_SCALE}
    return short(cfg, **{**base, **kw})


def warm_up_plan(s: RunSettings) -> m.Plan:
    snap = yield m.ReadState()
    _, warnings = yield from warm_up(s, snap)
    return warnings


def steps(events: list[Event], step: str) -> list[Event]:
    return [e for e in events if e.kind == "step" and e.step == step]


# --- the rule ------------------------------------------------------------------------------------------------------
def test_steady_needs_a_full_window_of_motion() -> None:
    h = ThermalHistory()
    h.add(0.0, (313.0, 313.0))
    h.add(100.0, (313.0, 313.0))
    assert not h.steady(300.0, 1.0)  # flat, but only 100 s observed
    h.add(300.0, (313.0, 313.0))
    assert h.steady(300.0, 1.0)


def test_steady_judges_every_reading_in_the_window_and_the_one_before_it() -> None:
    h = ThermalHistory()
    for t, temp in ((0.0, 300.0), (200.0, 308.0), (400.0, 311.0), (600.0, 312.0), (800.0, 312.0)):
        h.add(t, (temp, 293.0))
    # the last 300 s hold 312, 312, and the last reading before the window 311: all within 1 K of 312
    assert h.steady(300.0, 1.0)
    assert not h.steady(500.0, 1.0)  # reaches back to 308 K
    h.add(1000.0, (312.0, 295.0))  # A5 moved by 2 K
    assert not h.steady(300.0, 1.0)
    assert "A3 300 -> 312 K" in h.describe() and "A5 293 -> 295 K" in h.describe()


# --- on the simulator ------------------------------------------------------------------------------------------------
async def test_cold_robot_warms_until_steady(sim: SimulatedKrc4, cfg, engine: RunEngine) -> None:
    assert np.allclose(sim.model.state.motor_temp_k, AMBIENT_K)
    events: list[Event] = []
    engine.subscribe(events.append)
    warnings = await engine.run(warm_up_plan(steady_settings(cfg)))
    assert warnings == []
    runs = steps(events, "warm-up")
    assert len(runs) > 3, "a cold robot needs several warm-up runs"
    temps = sim.model.state.motor_temp_k
    # within a few K of the equilibrium (the rule stops at ≤ 1 K per 300 s of motion; heating τ = 240 s)
    assert np.all(temps[[2, 4]] > AMBIENT_K + HOLD_RISE_K - 3.0), temps
    # the rule sees what the controller reports: $MOT_TEMP of the last readings agree within 1 K
    assert abs(float(sim.store.read("$MOT_TEMP[3]")) - temps[2]) <= 1.0


async def test_one_run_when_not_asked_for_steadiness(sim: SimulatedKrc4, cfg, engine: RunEngine) -> None:
    events: list[Event] = []
    engine.subscribe(events.append)
    assert await engine.run(warm_up_plan(short(cfg, warmup_until_steady=False))) == []
    assert len(steps(events, "warm-up")) == 1


async def test_not_steady_within_the_limit_gives_a_warning(sim: SimulatedKrc4, cfg, engine: RunEngine) -> None:
    warnings = await engine.run(warm_up_plan(steady_settings(cfg, warmup_max_s=0.5)))
    assert len(warnings) == 1 and warnings[0].startswith("warm-up: motor temperatures not steady"), warnings


async def test_dry_run_warms_up_once(sim: SimulatedKrc4, krc, cfg) -> None:
    engine = make_engine(krc, cfg, dry_run=True)
    events: list[Event] = []
    engine.subscribe(events.append)
    assert await engine.run(warm_up_plan(steady_settings(cfg))) == []
    assert len(steps(events, "warm-up")) == 1 and sim.moves == 0


async def test_campaign_warms_up_again_after_the_motors_cooled(sim: SimulatedKrc4, cfg, krc, store,
                                                               engine: RunEngine) -> None:
    """The operator takes 15 minutes to mount point 2 with the brakes applied: the campaign warms up again before
    measuring it; the later points are mounted at once and measured without another warm-up."""
    events: list[Event] = []

    def operator(ev: Event) -> None:
        events.append(ev)
        if ev.kind != "confirm":
            return
        i = ev.data["point_index"]
        sim.mount(mass_calibration_payload(ev.data["n_cb"]))
        if i == 1:
            sim.model.apply_brakes(900.0)
        engine.confirm(f"mounted point {i}")

    engine.subscribe(operator)
    points = table1_points(n_bodies=(0, 2, 4, 6, 8), torque_levers_a5_m=())
    summary = await run_calibration(engine, store, cfg, points=points, settings=steady_settings(cfg),
                                    method="gain-linear")
    assert summary is not None and summary["warnings"] == []
    # which point each warm-up run belonged to
    point = -1
    warmups_per_point = dict.fromkeys(range(len(points)), 0)
    for e in events:
        if e.kind == "step" and e.step == "point":
            point = e.data["point_index"]
        elif e.kind == "step" and e.step == "warm-up":
            warmups_per_point[point] += 1
    w = warmups_per_point
    assert w[0] > 1 and w[1] > 1 and w[2] == w[3] == w[4] == 0, w
