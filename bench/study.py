"""Benchmark of ``rgse study``'s kernel at the paper's size: 14 points × ~30 kS per point, ≥ 300 combinations.

Synthetic Table-1-like torque traces (levels + noise + thermal drift + spikes) are written as raw float64 files
and timed in the same run: ``numpy.fromfile`` of all of them (the I/O floor), the pre-processing grid as it was
(``point_torques_before``: every combination filtered on its own, direct Gaussian sums) and as it is (shared crop
statistics and forward filters, FFT Gaussian), and the whole study (grid plus one calibration fit per
combination). Both grids must give the same torques. Prints one JSON object.

    .venv/bin/python bench/study.py
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.calibration import CalibrationPoints
from rgse_daemon.pipeline.study import StudyGrid, filter_windows, point_torques, run_study

G, DR = 9.81, 1.025
MASS_KG = np.r_[0.0, 20.93 * np.arange(1, 11), 228.51, 228.51, 228.51]
LEVER_A3_M = np.r_[1.29 + 0.0075 * np.arange(11), 1.80, 2.05, 2.30]
LOOPS, SAMPLES = 3, 10_000  # 30 kS per point
PERIOD_S = 0.004


def synth(rng: np.random.Generator, true_nm: float, gain: float, bias_nm: float) -> np.ndarray:
    t = np.arange(SAMPLES) * PERIOD_S
    x = true_nm / gain + bias_nm + 20.0 * np.exp(-t / 0.5) + 0.05 * t + rng.normal(0, 8.0, SAMPLES)
    spikes = rng.random(SAMPLES) < 0.005
    x[spikes] += 200.0
    return x


def point_torques_before(points_loops, grid: StudyGrid) -> dict:
    """The grid kernel before this optimisation (kept here for the side-by-side timing)."""

    def smooth(x, filt, windows):
        if filt == "gaussian":
            return np.stack([ndimage.gaussian_filter1d(x, sigma=max(w / 5.0, 1e-3), mode="nearest") for w in windows])
        return pp.smooth(x, filt, windows)

    def rows_of(x, crop, filt, order, windows):
        if order == "backward":
            kept = pp.crop_outliers(x, crop)[0]
            return smooth(kept[np.isfinite(kept)], filt, windows)
        return pp.crop_outliers(smooth(x, filt, windows), crop)

    out = {}
    for crop in grid.crop_sigmas:
        for filt in grid.filters:
            windows = np.asarray(filter_windows(grid, filt), int)
            for order in grid.orders:
                shape = (windows.size, len(points_loops))
                acc = {loc: (np.zeros(shape), np.zeros(shape)) for loc in grid.locations}
                for j, loops in enumerate(points_loops):
                    per_loop = {loc: ([], []) for loc in grid.locations}
                    for a3, a5, _dt in loops:
                        r3 = rows_of(a3, crop, filt, order, windows)
                        r5 = rows_of(a5, crop, filt, order, windows)
                        for loc in grid.locations:
                            per_loop[loc][0].append(pp.location_rows(r3, loc))
                            per_loop[loc][1].append(pp.location_rows(r5, loc))
                    for loc in grid.locations:
                        acc[loc][0][:, j] = np.mean(per_loop[loc][0], axis=0)
                        acc[loc][1][:, j] = np.mean(per_loop[loc][1], axis=0)
                for loc in grid.locations:
                    out[(crop, filt, order, loc)] = acc[loc]
    return out


def main() -> None:
    rng = np.random.default_rng(0)
    grid = StudyGrid(crop_sigmas=(1.0, 2.0, 3.0), filters=("moving_average", "gaussian", "median"),
                     windows=(5, 25, 50, 100, 150, 200, 300, 500, 1000, 5000), orders=("backward", "forward"),
                     locations=("mean", "huber"))
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for j, (m, l3) in enumerate(zip(MASS_KG, LEVER_A3_M, strict=True)):
            for k in range(LOOPS):
                for axis, lever, gain, bias in (("a3", l3, 1.095, 1320.46), ("a5", l3 - DR, 0.87, 315.96)):
                    p = Path(tmp) / f"p{j:02d}_l{k}_{axis}.r64"
                    synth(rng, G * m * lever, gain, bias).astype("<f8").tofile(p)
                    files.append(p)
        t0 = time.perf_counter()
        arrays = [np.fromfile(p, "<f8") for p in files]
        t_read = time.perf_counter() - t0
    loops = [[(arrays[(j * LOOPS + k) * 2], arrays[(j * LOOPS + k) * 2 + 1], PERIOD_S) for k in range(LOOPS)]
             for j in range(len(MASS_KG))]

    def to_points(raw3: np.ndarray, raw5: np.ndarray) -> CalibrationPoints:
        n3, n5 = raw3 - raw3[0], raw5 - raw5[0]
        return CalibrationPoints(np.array(["mass"] * len(MASS_KG)), MASS_KG, n3, n5, G * MASS_KG * LEVER_A3_M,
                                 G * MASS_KG * (LEVER_A3_M - DR))

    t0 = time.perf_counter()
    before = point_torques_before(loops, grid)
    t_before = time.perf_counter() - t0
    t0 = time.perf_counter()
    after = point_torques(loops, grid)
    t_pre = time.perf_counter() - t0
    max_diff = max(float(np.max(np.abs(after[k][i] - before[k][i]))) for k in before for i in (0, 1))
    t0 = time.perf_counter()
    rows = run_study(loops, to_points, grid, "gain-linear", G, DR)
    t_study = time.perf_counter() - t0
    best = rows[0]
    print(json.dumps({
        "points": len(MASS_KG), "samples_per_point": LOOPS * SAMPLES, "combinations": grid.size,
        "rows": len(rows), "fromfile_s": round(t_read, 4), "preprocess_grid_before_s": round(t_before, 3),
        "preprocess_grid_s": round(t_pre, 3), "speedup": round(t_before / t_pre, 1),
        "max_abs_torque_diff_nm": max_diff, "study_total_s": round(t_study, 3),
        "study_over_fromfile": round(t_study / t_read, 1),
        "best": best.to_dict(),
    }))


if __name__ == "__main__":
    main()
