"""The stop rule of a run's loops (pipeline/stopping.py): its choices, pure."""

from __future__ import annotations

import math

import pytest

from rgse_daemon.pipeline import stopping as st
from rgse_daemon.pipeline.stopping import StopRule, decide, predict

#: Issue 35's campaign: u's other terms about 1.24 kg; the loop term 0.065 kg with 3 loops.
U_OTHER_KG = 1.242


def budget(n: int, u_loops_1_kg: float = 0.113) -> tuple[float, float]:
    """(u, loop term) of ``n`` loops whose loop term is ``u_loops_1_kg`` for one loop."""
    lt = u_loops_1_kg / math.sqrt(n)
    return math.hypot(U_OTHER_KG, lt), lt


def test_prediction_scales_the_loop_term_only():
    u, lt = budget(2)
    p = predict(4, 2, u, lt)
    assert p.u_loops_kg == pytest.approx(lt * math.sqrt(2 / 4))
    assert p.u_kg == pytest.approx(math.hypot(U_OTHER_KG, lt / math.sqrt(2)))
    assert p.U_kg == pytest.approx(2 * p.u_kg)
    same = predict(3, 3, u, lt)
    assert same.u_kg == pytest.approx(u) and same.u_loops_kg == lt


@pytest.mark.parametrize(("loops", "analysed", "u", "lt"), [
    (3, 0, 1.0, 0.1), (3, 4, 1.0, 0.1), (3, 2, 0.1, 0.2), (3, 2, float("nan"), 0.1), (3, 2, 1.0, -0.1)])
def test_prediction_refuses_impossible_budgets(loops, analysed, u, lt):
    with pytest.raises(ValueError, match="predict"):
        predict(loops, analysed, u, lt)


def test_below_the_minimum_the_run_goes_on_whatever_u_says():
    rule = StopRule(max_loops=10, loop_share=0.5, target_U_kg=100.0)
    for n in (1, 2):
        d = decide(rule, n, predict(n, n, *budget(n)))
        assert not d.stop and d.reason == st.CONTINUE


def test_loop_term_below_share_stops_at_the_minimum():
    rule = StopRule(max_loops=10, loop_share=0.2)
    d = decide(rule, 3, predict(3, 2, *budget(2)))
    assert d.stop and d.reason == st.LOOP_SHARE
    assert d.prediction is not None and d.prediction.loop_share < 0.2
    assert d.to_json()["stop_reason"] == st.LOOP_SHARE and d.to_json()["loops_analysed"] == 2


def test_a_loop_term_above_share_goes_on_until_it_is_below():
    # a noisy DuT: the loop term is 40 % of u with 3 loops; it drops below 20 % only after more loops
    rule = StopRule(max_loops=20, loop_share=0.2)
    noisy = 0.9  # kg for one loop
    stops = [n for n in range(3, 21) if decide(rule, n, predict(n, n - 1, *budget(n - 1, noisy))).stop]
    first = stops[0]
    assert 3 < first < 20
    p = predict(first, first - 1, *budget(first - 1, noisy))
    assert p.loop_share <= 0.2
    before = predict(first - 1, first - 2, *budget(first - 2, noisy))
    assert before.loop_share > 0.2


def test_target_u_met_before_the_share():
    rule = StopRule(max_loops=10, loop_share=0.01, target_U_kg=2.6)
    d = decide(rule, 3, predict(3, 3, *budget(3)))
    assert d.stop and d.reason == st.TARGET_MET
    # a target U the calibration cannot reach: the loops go on to the maximum
    rule = StopRule(max_loops=5, loop_share=0.0, target_U_kg=1.0)
    reasons = [decide(rule, n, predict(n, n, *budget(n))).reason for n in range(3, 6)]
    assert reasons == [st.CONTINUE, st.CONTINUE, st.MAX_LOOPS]


def test_max_loops_always_stops_and_a_small_max_wins_over_the_minimum():
    assert decide(StopRule(max_loops=10, loop_share=0.2), 10, None).reason == st.MAX_LOOPS
    assert decide(StopRule(max_loops=2), 2, None).reason == st.MAX_LOOPS  # loops = 2 configured: 2 loops
    assert not decide(StopRule(max_loops=2), 1, None).stop


def test_no_prediction_or_both_tests_off_keeps_the_fixed_count():
    assert not decide(StopRule(max_loops=10), 5, None).stop  # nothing analysed (a dry run, no calibration)
    fixed = StopRule(max_loops=10, loop_share=0.0, target_U_kg=None)
    assert fixed.fixed
    assert [decide(fixed, n, predict(n, n, *budget(n))).stop for n in range(1, 11)] == [False] * 9 + [True]


@pytest.mark.parametrize("kw", [{"max_loops": 0}, {"max_loops": 5, "min_loops": 2},
                                {"max_loops": 5, "loop_share": 1.0}, {"max_loops": 5, "loop_share": -0.1},
                                {"max_loops": 5, "target_U_kg": 0.0}])
def test_a_rule_that_cannot_hold_is_refused(kw):
    with pytest.raises(ValueError, match="stop rule"):
        StopRule(**kw)


def test_min_loops_is_the_consistency_checks_three():
    assert st.MIN_LOOPS == 3 and StopRule(max_loops=10).min_loops == 3


def test_a_campaign_point_weighs_each_axis_against_its_reproducibility():
    # A5's loop term is the larger share of its own scatter: it decides
    p = st.point_prediction(3, 2, (2.0, 3.0), (40.0, 10.0))
    assert p.u_loops_kg == pytest.approx(3.0 * math.sqrt(2 / 3))
    assert p.loop_share == pytest.approx(p.u_loops_kg / math.hypot(10.0, p.u_loops_kg))
    rule = StopRule(max_loops=10, loop_share=0.2)
    assert decide(rule, 3, p).stop is False  # 0.24 of A5's scatter: more loops still matter there
    quiet = st.point_prediction(3, 2, (2.0, 0.5), (40.0, 10.0))
    assert decide(rule, 3, quiet).reason == st.LOOP_SHARE


def test_point_loop_term_is_the_standard_error_of_the_mean_torque():
    import numpy as np

    from rgse_daemon.pipeline import preprocess as pp
    from rgse_daemon.pipeline import uncertainty as unc

    rng = np.random.default_rng(5)
    offsets = (0.0, 3.0, -3.0)  # Nm between loops, far above the within-loop noise
    loops = [(100.0 + o + 0.1 * rng.standard_normal(1000), 50.0 + 0.1 * rng.standard_normal(1000), 0.012)
             for o in offsets]
    lt3, lt5 = st.point_loop_term_nm(loops)
    means3 = np.array([pp.process_loop(a, 0.012).torque_nm for a, _, _ in loops])
    assert lt3 == pytest.approx(unc.loop_spread_kg(means3, np.array(
        [unc.batch_means_se(pp.kept_samples(a, 0.012)) for a, _, _ in loops])))
    assert lt3 == pytest.approx(means3.std(ddof=1) / math.sqrt(3), rel=1e-6)  # the between-loop error wins
    assert 0 < lt5 < 0.1 * lt3


def test_the_rule_counts_only_kept_loops_and_replaces_those_set_aside():
    """Issue 33: loops the integrity check set aside do not count towards ``min_loops``; at ``max_loops`` with too
    few kept, replacement loops follow within the budget, then the rule stops ("replacements spent")."""
    rule = StopRule(10, 3, loop_share=0.2, replacements=2)
    met = predict(3, 3, *budget(3, 0.001))  # a loop term far below the share
    assert decide(rule, 3, met).reason == st.LOOP_SHARE
    assert not decide(rule, 3, met, kept=2).stop  # one of three set aside: 2 kept, below min_loops
    assert decide(rule, 4, met, kept=3).reason == st.LOOP_SHARE
    short = StopRule(3, 3, loop_share=0.0, replacements=2)
    assert decide(short, 3, None, kept=3).reason == st.MAX_LOOPS
    assert not decide(short, 3, None, kept=2).stop  # a replacement loop
    assert decide(short, 4, None, kept=3).reason == st.MAX_LOOPS
    spent = decide(short, 5, None, kept=1)
    assert spent.stop and spent.reason == st.REPLACEMENTS_SPENT and spent.to_json()["loops_kept"] == 1
    none = StopRule(3, 3, loop_share=0.0)  # no budget: the configured loops, whatever was kept
    assert decide(none, 3, None, kept=1).reason == st.MAX_LOOPS
    with pytest.raises(ValueError, match="replacements"):
        StopRule(3, replacements=-1)
