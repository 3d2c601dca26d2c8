"""The parameter study kernel: grid size, ranking, and that cropping beats no cropping on spiky data."""

from __future__ import annotations

import numpy as np

from rgse_daemon.pipeline.calibration import CalibrationPoints
from rgse_daemon.pipeline.study import MEDIAN_MAX_WINDOW, StudyGrid, run_study

MASS = np.r_[0.0, 20.93 * np.arange(1, 11), 228.51, 228.51]
L3 = np.r_[1.29 + 0.0075 * np.arange(11), 1.8, 2.3]


def make_loops(seed: int):
    rng = np.random.default_rng(seed)
    loops = []
    for m, l3 in zip(MASS, L3, strict=True):
        point = []
        for _ in range(2):
            a3 = 9.81 * m * l3 / 1.09 + 1320.0 + rng.normal(0, 5, 800)
            a5 = 9.81 * m * (l3 - 1.025) / 0.87 + 316.0 + rng.normal(0, 5, 800)
            a3[rng.random(800) < 0.05] += 400.0  # one-sided spikes bias an uncropped mean
            point.append((a3, a5, 0.004))
        loops.append(point)
    return loops


def to_points(r3, r5):
    return CalibrationPoints(np.array(["mass"] * MASS.size), MASS, r3 - r3[0], r5 - r5[0], 9.81 * MASS * L3,
                             9.81 * MASS * (L3 - 1.025))


def test_study_ranks_cropping_first():
    grid = StudyGrid(crop_sigmas=(None, 2.0), filters=("moving_average", "median"), windows=(5, 150, 1000),
                     orders=("backward", "forward"))
    rows = run_study(make_loops(0), to_points, grid, "gain-linear")
    assert len(rows) == grid.size == 2 * (3 + 2) * 2
    assert all(r.window <= MEDIAN_MAX_WINDOW for r in rows if r.filter == "median")
    errs = [r.mass_err_pct for r in rows]
    assert errs == sorted(errs)
    best_uncropped = min(r.mass_err_pct for r in rows if r.crop_sigma is None and r.filter == "moving_average")
    best_cropped = min(r.mass_err_pct for r in rows if r.crop_sigma == 2.0 and r.filter == "moving_average")
    assert best_cropped < best_uncropped
    assert rows[0].to_dict()["r2_a3"] is None  # gain models have no per-axis R²


def test_study_with_paper_method_reports_r2():
    grid = StudyGrid(crop_sigmas=(1.0,), filters=("moving_average",), windows=(150,), orders=("backward",))
    rows = run_study(make_loops(1), to_points, grid, "paper")
    assert len(rows) == 1 and 0.0 <= rows[0].r2_a3 <= 1.0


def test_shared_grid_kernel_equals_each_combination_on_its_own():
    """The shared crop statistics / forward filters / FFT Gaussian give exactly the per-combination torques."""
    from rgse_daemon.pipeline import preprocess as pp
    from rgse_daemon.pipeline.study import filter_windows, point_torques

    loops = make_loops(2)[:3]
    grid = StudyGrid(crop_sigmas=(None, 1.0, 3.0), filters=("moving_average", "gaussian", "median"),
                     windows=(5, 400, 2000), orders=("backward", "forward"), locations=("mean", "huber"))
    got = point_torques(loops, grid)
    for (crop, filt, order, loc), (raw3, raw5) in got.items():
        cfg = pp.Preprocessing(crop_sigma=crop, filter=filt, window=1, order=order, location=loc)
        windows = np.asarray(filter_windows(grid, filt))
        for j, point in enumerate(loops):
            want3 = np.mean([pp.location_rows(pp.filtered_rows(a3, dt, cfg, windows), loc) for a3, _, dt in point], 0)
            want5 = np.mean([pp.location_rows(pp.filtered_rows(a5, dt, cfg, windows), loc) for _, a5, dt in point], 0)
            np.testing.assert_allclose(raw3[:, j], want3, rtol=0, atol=1e-9)
            np.testing.assert_allclose(raw5[:, j], want5, rtol=0, atol=1e-9)


def test_fft_gaussian_equals_direct_filter():
    from scipy import ndimage

    from rgse_daemon.pipeline import preprocess as pp

    x = np.random.default_rng(4).normal(size=3000).cumsum()
    for w in (3, 200, 1500, 9000):
        np.testing.assert_allclose(pp.gaussian(x, w), ndimage.gaussian_filter1d(x, max(w / 5, 1e-3), mode="nearest"),
                                   rtol=0, atol=1e-9)
