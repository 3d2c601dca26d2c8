"""Pre-processing: crop, filters, order, robust locations, eq. 16, bias normalisation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import integrity
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.preprocess import PreprocessError


def test_moving_average_matches_direct_centred_mean():
    x = np.random.default_rng(0).normal(size=57)
    for w in (1, 2, 5, 10, 57, 100):
        got = pp.moving_average(x, w)[0]
        want = [x[max(0, i - w // 2): min(57, i + (w - 1) // 2 + 1)].mean() for i in range(57)]
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_crop_removes_spikes_and_order_matters():
    rng = np.random.default_rng(1)
    x = rng.normal(100.0, 1.0, 3000)
    x[::100] += 500.0
    back = pp.process_loop(x, 0.004, pp.Preprocessing(crop_sigma=2, window=150, order="backward"))
    fwd = pp.process_loop(x, 0.004, pp.Preprocessing(crop_sigma=2, window=150, order="forward"))
    plain = pp.process_loop(x, 0.004, pp.Preprocessing(crop_sigma=None, filter="none"))
    assert abs(back.torque_nm - 100.0) < 0.1
    assert back.n_used < back.n_total
    assert plain.torque_nm > 104.0  # spikes unremoved
    assert fwd.torque_nm != back.torque_nm


@pytest.mark.parametrize("location", pp.LOCATIONS)
def test_robust_locations_resist_one_sided_outliers(location):
    rng = np.random.default_rng(2)
    x = rng.normal(50.0, 1.0, 4000)
    x[:200] += 30.0
    loc = pp.location_rows(x, location)[0]
    if location == "mean":
        assert loc > 51.0
    else:
        assert abs(loc - 50.0) < 0.5


@given(st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=200), st.sampled_from(pp.FILTERS),
       st.integers(1, 300), st.sampled_from(pp.ORDERS), st.sampled_from(pp.LOCATIONS))
@settings(max_examples=60, deadline=None)
def test_loop_result_within_data_range(values, filt, window, order, location):
    x = np.array(values)
    r = pp.process_loop(x, 0.001, pp.Preprocessing(crop_sigma=2, filter=filt, window=window, order=order,
                                                   location=location))
    assert x.min() - 1e-6 <= r.torque_nm <= x.max() + 1e-6
    assert 1 <= r.n_used <= r.n_total


def test_settle_cut_uses_the_sample_period():
    x = np.r_[np.full(250, 999.0), np.full(1000, 10.0)]
    assert pp.process_loop(x, 0.004, pp.Preprocessing(crop_sigma=None, settle_s=1.0)).torque_nm == pytest.approx(10)
    assert pp.process_loop(x, 0.008, pp.Preprocessing(crop_sigma=None, settle_s=1.0)).torque_nm > 100.0


def test_double_average_and_bias():
    assert pp.double_average_nm([1.0, 2.0, 6.0]) == pytest.approx(3.0)
    np.testing.assert_allclose(pp.normalise(np.array([1320.46, 1568.61]), 1320.46), [0.0, 248.15])


def test_bad_input_is_typed():
    # NaN / inf (DIAdem's no-value marker reads as NaN) are missing samples (issue 33), not refused input: the loop
    # is the samples that are there, and n_total still counts the raw ones
    cfg = pp.Preprocessing(crop_sigma=None, window=1)
    for gap in (np.nan, np.inf, -np.inf):
        got = pp.process_loop(np.array([1.0, gap, 2.0, 6.0]), 0.004, cfg)
        assert (got.torque_nm, got.n_used, got.n_total) == (pytest.approx(3.0), 3, 4)
    # a loop with too few samples left is refused, naming what is left
    with pytest.raises(PreprocessError, match="only 2 samples left"):
        pp.process_loop(np.array([1.0, np.nan, np.nan, 3.0]), 0.004)
    # whether a loop has enough samples is integrity's call: under half left (or under 20), it is set aside with
    # its reason; a sample missing in one torque channel is missing in both
    a3, a5 = np.full(1000, 5.0), np.full(1000, 7.0)
    a3[100:400], a5[350:700] = np.nan, np.nan
    assert integrity.gap_reason(integrity.valid_mask(a3, a5), 0) == (
        "600 of 1000 samples missing (no value, NaN or inf in the trace): fewer than 50% left")
    a5[350:700] = 7.0
    assert integrity.gap_reason(integrity.valid_mask(a3, a5), 0) is None
    assert "samples missing" in integrity.gap_reason(np.r_[np.ones(19, bool), np.zeros(1, bool)], 0)
    with pytest.raises(DataError):
        pp.Preprocessing(filter="kalman")
    with pytest.raises(DataError):
        pp.double_average_nm([])
