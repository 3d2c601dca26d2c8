"""The campaign planner (pipeline/planning.py): its points cover the asked DuT range, bad input is refused naming the
argument, and the time prediction is the sum of its stated parts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon import robots
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import envelope as env_mod
from rgse_daemon.pipeline import planning as pl

G = 9.81
DR = 1.025
#: The paper's equipment, typed in from Table 1 / Table A1 (not imported: the planner must agree with the paper).
EQ = pl.Equipment(cb_mass_kg=20.93, zero_lever_a5_m=0.265, stack_lever_a5_m=0.275, stack_step_m=0.0075,
                  ta_mass_kg=19.20, ta_torque_a5_nm=217.95)


@pytest.fixture(scope="module")
def plan_50_250() -> pl.Plan:
    m, lv = pl.grid((50.0, 250.0), (0.40, 0.90), EQ)
    return pl.plan(m, lv, EQ)


def fine_grid(mass: tuple[float, float], lever: tuple[float, float], n: int = 41) -> tuple[np.ndarray, np.ndarray]:
    mm, ll = np.meshgrid(np.linspace(*mass, n), np.linspace(*lever, n), indexing="ij")
    return mm.ravel(), ll.ravel()


def test_every_dut_of_the_range_lies_inside_the_envelope_of_the_planned_points(plan_50_250):
    cal3 = np.array([G * p.mass_kg * p.lever_a3_m for p in plan_50_250.points])
    cal5 = np.array([G * p.mass_kg * p.lever_a5_m for p in plan_50_250.points])
    env = env_mod.Envelope.from_torques(cal3, cal5)
    m, lv = fine_grid((50.0, 250.0), (0.40, 0.90))  # 41 x 41, finer than the planner's own grid
    a3, a5 = G * m * (lv + DR), G * m * lv
    statuses = {env_mod.check(env, x3, x5).status for x3, x5 in zip(a3, a5, strict=True)}
    assert statuses == {"inside"}
    # calibrated points on both sides of every DuT, in M_A3 and in M_A5
    assert (cal3.min() <= a3.min()) and (cal3.max() >= a3.max())
    assert (cal5.min() <= a5.min()) and (cal5.max() >= a5.max())
    # and a calibrated point near each: within the bound on the planner's grid, within 1.1x between its nodes
    scale = np.array([a3.max(), a5.max()])
    cal = np.column_stack([cal3, cal5])
    dist = np.sqrt((((np.column_stack([a3, a5])[:, None] - cal[None]) / scale) ** 2).sum(axis=2)).min(axis=1)
    assert dist.max() <= 1.1 * pl.DEFAULT_MAX_DISTANCE
    assert plan_50_250.coverage.covered.all() and plan_50_250.uncovered == []
    assert plan_50_250.coverage.distance.max() <= pl.DEFAULT_MAX_DISTANCE
    # the envelope's own nearest-point distance: at the planned-for nodes held NODE_MARGIN below its inside bound,
    # on the finer grid between them still inside
    assert plan_50_250.coverage.gap.max() <= env_mod.POINT_INSIDE - pl.NODE_MARGIN
    assert max(env.nearest(x3, x5) for x3, x5 in zip(a3, a5, strict=True)) <= env_mod.POINT_INSIDE


def test_the_points_are_loads_the_equipment_can_mount(plan_50_250):
    pts = plan_50_250.points
    assert pts[0].kind == "zero" and sum(p.kind == "zero" for p in pts) == 1
    assert plan_50_250.loaded >= pl.DEFAULT_MIN_LOADED
    for p in pts:
        assert 0 <= p.n_cb <= 10
        assert p.lever_a3_m == pytest.approx(p.lever_a5_m + DR)
        if p.kind == "mass":  # a stack: n bodies at 0.275 + 0.0075 n (Table 1's printed levers - 0.020 m)
            assert p.mass_kg == pytest.approx(20.93 * p.n_cb)
            assert p.lever_a5_m == pytest.approx(0.275 + 0.0075 * p.n_cb)
        if p.kind == "torque":  # the adapter (217.95 Nm on A5) plus the bodies at their rail position
            assert 0.60 <= p.cb_lever_a5_m <= 1.50
            assert p.mass_kg == pytest.approx(19.20 + 20.93 * p.n_cb)
            assert G * p.mass_kg * p.lever_a5_m == pytest.approx(217.95 + G * 20.93 * p.n_cb * p.cb_lever_a5_m)
            assert G * p.mass_kg * p.lever_a5_m <= EQ.max_a5_torque_nm == 3330.0
    # the paper's first torque point: 10 bodies at 0.761 m, as examples/rehearsal-points.toml has it
    tp = pl.adapter_point(EQ, 10, 0.761, 3)
    assert tp.mass_kg == pytest.approx(228.5, abs=0.01) and tp.lever_a5_m == pytest.approx(0.7943, abs=1e-3)


def test_a_lever_range_the_equipment_cannot_reach_is_reported_not_hidden():
    # CoG 0.05-0.15 m from A5: below any load the MPA can carry (the empty MPA is at 0.265 m): A5/A3 ratio too low
    m, lv = pl.grid((50.0, 100.0), (0.05, 0.15), EQ)
    p = pl.plan(m, lv, EQ)
    assert not p.coverage.covered.all()
    assert p.uncovered and all("envelope" in u for u in p.uncovered)
    assert np.isnan(p.U_kg[~p.coverage.covered]).all()


def test_a_list_of_duts_is_planned_for_those_duts():
    p = pl.plan(np.array([107.3, 180.0]), np.array([0.625, 0.5]), EQ)
    assert p.coverage.covered.all() and p.coverage.mass_kg.tolist() == [107.3, 180.0]


@pytest.mark.parametrize(("mass", "lever", "words"), [
    ((250.0, 50.0), (0.4, 0.9), ["--mass", "minimum is above the maximum"]),
    ((50.0, 250.0), (0.9, 0.4), ["--lever-a5", "minimum is above the maximum"]),
    ((-10.0, 250.0), (0.4, 0.9), ["--mass", "negative"]),
    ((50.0, 250.0), (-0.1, 0.9), ["--lever-a5", "negative"]),
    ((50.0, 700.0), (0.4, 0.5), ["--mass", "700 kg", "611"]),
    ((50.0, 500.0), (0.4, 0.9), ["--mass/--lever-a5", "3330"]),  # 500 kg at 0.9 m: 4415 Nm on A5
    ((0.0, 100.0), (0.4, 0.9), ["--mass", "> 0 kg"]),
    ((50.0, float("nan")), (0.4, 0.9), ["--mass", "finite"]),
])
def test_bad_input_is_refused_naming_the_argument(mass, lever, words):
    with pytest.raises(DataError) as exc:
        pl.grid(mass, lever, EQ)
    for w in words:
        assert w in str(exc.value)


def test_the_time_prediction_is_the_sum_of_its_stated_parts():
    tm = pl.TimeModel(loop_motion_s=50.0, settle_s=4.0, record_s=12.0, warmup_initial_s=1000.0,
                      warmup_initial_min_s=200.0, rewarm_s=300.0, load_change_s=600.0)
    pts = [pl.zero_point(EQ, 3), pl.stack_point(EQ, 5, 4), pl.adapter_point(EQ, 10, 1.0, 5)]
    t = pl.campaign_time(pts, tm)
    assert t.loop_s == 66.0 and t.loops == 12
    assert t.loops_s == 12 * 66.0
    assert t.rewarm_s == 2 * 300.0  # after the two later load changes
    assert t.robot_s == 12 * 66.0 + 1000.0 + 600.0
    assert t.robot_min_s == 12 * 66.0 + 200.0 + 600.0
    assert t.campaign_s == t.robot_s + 3 * 600.0
    # the default loop is the measured 69 s (issue 35: 11.4-11.6 min for a 10-loop mass run)
    assert pl.TimeModel().loop_s == pytest.approx(69.0)


def test_the_50_250_kg_plan_predicts_time_and_U_from_its_parts(plan_50_250):
    t = plan_50_250.time
    n = len(plan_50_250.points)
    assert t.loops == 3 * n and t.loops_s == pytest.approx(3 * n * 69.0)
    assert t.robot_s == pytest.approx(t.loops_s + 2400.0 + (n - 1) * 300.0)
    # U: 2 * sqrt(1.06^2 (1 + 3/N) + 0.065^2 + 0.28^2), the same in kg over the covered range
    n_loaded = plan_50_250.loaded
    want = 2.0 * math.sqrt(1.06**2 * (1.0 + 3.0 / n_loaded) + 0.065**2 + 0.28**2)
    assert np.allclose(plan_50_250.U_kg, want)
    # on the demo's 10 loaded points it gives back issue 35's U with 3 loops (2.488 kg) to 1 %
    assert pl.predicted_U_kg(10) == pytest.approx(2.488, rel=0.01)
    assert pl.predicted_U_kg(20) < pl.predicted_U_kg(10)  # more points: a better-known curve


def test_points_toml_holds_every_point():
    pts = [pl.zero_point(EQ, 3), pl.stack_point(EQ, 2, 3), pl.adapter_point(EQ, 10, 1.261, 3)]
    text = pl.points_toml(pts, EQ, ["a header"])
    assert text.startswith("# a header\n") and text.count("[[point]]") == 3
    assert 'kind = "torque"' in text and "bodies = 10" in text and "mass_kg = 41.86" in text


def test_a_torque_point_at_the_rail_end_keeps_its_bodies_on_the_rail_in_the_file():
    for cb_lever, n in ((0.60, 10), (0.60, 1), (1.50, 10), (1.50, 3)):
        p = pl.adapter_point(EQ, n, cb_lever, 3)
        lever = pl.file_lever_a5_m(p, EQ)
        back = (p.mass_kg * lever - 217.95 / G) / (20.93 * n)  # the rail position the daemon derives from the file
        assert 0.60 <= back <= 1.50 and back == pytest.approx(cb_lever, abs=1e-3)


def test_a_tighter_configured_load_diagram_is_kept_to():
    eq = pl.Equipment(**{**EQ.__dict__, "max_payload_kg": 200.0, "max_a5_torque_nm": 2000.0})
    with pytest.raises(DataError, match=r"--mass: 250 kg is beyond the robot's load diagram \(200 kg payload\)"):
        pl.grid((50.0, 250.0), (0.4, 0.9), eq)
    m, lv = pl.grid((50.0, 180.0), (0.4, 0.8), eq)
    p = pl.plan(m, lv, eq)
    assert all(q.mass_kg <= 200.0 and G * q.mass_kg * q.lever_a5_m <= 2000.0 for q in p.points)


def test_the_equipment_keeps_to_the_active_robot_s_load_diagram():
    # the load diagram and lever difference are the RobotModel's (rgse_daemon.robots), not figures of the planner
    kr500 = robots.active()
    assert (EQ.max_payload_kg, EQ.max_a5_torque_nm, EQ.lever_difference_m) == (
        kr500.max_payload_kg, kr500.max_a5_torque_nm, kr500.lever_difference_m)
    kr10 = robots.get("kr10r1440")
    previous = robots.activate(kr10)
    try:
        eq = pl.Equipment(20.93, 0.265, 0.275, 0.0075, 19.20, 217.95)
        assert (eq.max_payload_kg, eq.max_a5_torque_nm) == (kr10.max_payload_kg, kr10.max_a5_torque_nm)
        with pytest.raises(DataError, match="load diagram"):
            pl.grid((5.0, 50.0), (0.05, 0.1), eq)
    finally:
        robots.activate(previous)
