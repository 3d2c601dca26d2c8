"""Benchmark of ``rgse study``'s kernel at the paper's size: 14 points × ~30 kS per point, ≥ 300 combinations.

Synthetic Table-1-like torque traces (levels + noise + thermal drift + spikes) are written as raw float64 files
and timed twice: ``numpy.fromfile`` of all of them (the I/O floor) and the full pre-processing grid plus one
calibration fit per combination. Prints one JSON object.

    .venv/bin/python bench/study.py
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from rgse_daemon.pipeline.calibration import CalibrationPoints
from rgse_daemon.pipeline.study import StudyGrid, point_torques, run_study

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
    point_torques(loops, grid)
    t_pre = time.perf_counter() - t0
    t0 = time.perf_counter()
    rows = run_study(loops, to_points, grid, "gain-linear", G, DR)
    t_study = time.perf_counter() - t0
    best = rows[0]
    print(json.dumps({
        "points": len(MASS_KG), "samples_per_point": LOOPS * SAMPLES, "combinations": grid.size,
        "rows": len(rows), "fromfile_s": round(t_read, 4), "preprocess_grid_s": round(t_pre, 3),
        "study_total_s": round(t_study, 3), "study_over_fromfile": round(t_study / t_read, 1),
        "best": best.to_dict(),
    }))


if __name__ == "__main__":
    main()
