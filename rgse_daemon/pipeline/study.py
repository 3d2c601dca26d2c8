"""The pre-processing parameter study (paper §2.4.6, Fig. 26, Table A2): crop σ × filter × window × order
(× location), each combination ranked by the mass error of the calibration it leads to.

Per loop and per (crop, filter, order) all windows are processed at once (:func:`preprocess.filtered_rows`);
the calibration is then fitted once per combination. With pre-averaged points (nothing left to pre-process) the
calibration models are ranked instead (:func:`rank_models`). An optional ``progress(stage, done, total)`` hears of
every loop, combination or model finished.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import robots
from rgse_daemon.kinematics import G_PAPER_M_S2
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import selection
from rgse_daemon.progress import ProgressFn

#: Largest running-median window the study tries: its cost grows with the window (the paper's study found the
#: moving average best; the median is a robust comparison, not worth seconds per loop at 5000 samples).
MEDIAN_MAX_WINDOW = 501

#: One loop: (A3 torque samples, A5 torque samples, sample period in s).
LoopData = tuple[np.ndarray, np.ndarray, float]

#: Progress stages (the bars' descriptions).
STAGE_LOOPS = "pre-processing loops"
STAGE_COMBINATIONS = "fitting combinations"
STAGE_MODELS = "fitting models (LOO)"


@dataclass(frozen=True)
class StudyGrid:
    crop_sigmas: tuple[float | None, ...] = (1.0, 2.0, 3.0)
    filters: tuple[str, ...] = ("moving_average", "gaussian", "median")
    windows: tuple[int, ...] = (5, 50, 100, 150, 200, 500, 1000, 5000)
    orders: tuple[str, ...] = ("backward", "forward")
    locations: tuple[str, ...] = ("mean",)

    @property
    def size(self) -> int:
        """Number of combinations actually run."""
        per_filter = sum(len(filter_windows(self, f)) for f in self.filters)
        return len(self.crop_sigmas) * per_filter * len(self.orders) * len(self.locations)


@dataclass(frozen=True)
class StudyRow:
    crop_sigma: float | None
    filter: str
    window: int
    order: str
    location: str
    mass_err_pct: float
    r2_a3: float
    r2_a5: float

    def to_dict(self) -> dict:
        """JSON-ready (NaN, e.g. R² of a model fitted to masses, becomes None), with its ``preprocessing`` spec."""
        d = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}
        return {**d, "preprocessing": self.spec}

    @property
    def spec(self) -> str:
        """This row as ``rgse calibrate --campaign DIR --preprocessing SPEC``."""
        crop = "none" if self.crop_sigma is None else f"{self.crop_sigma:g}"
        return (f"crop_sigma={crop},filter={self.filter},window={self.window},order={self.order},"
                f"location={self.location}")


def filter_windows(grid: StudyGrid, filt: str) -> tuple[int, ...]:
    """The windows tried with filter ``filt`` (the running median is capped at :data:`MEDIAN_MAX_WINDOW`)."""
    if filt == "median":
        return tuple(w for w in grid.windows if w <= MEDIAN_MAX_WINDOW)
    if filt == "none":
        return (1,)
    return grid.windows


def loop_grid_rows(values: np.ndarray, period_s: float, grid: StudyGrid, settle_s: float = 0.0
                   ) -> dict[tuple, np.ndarray]:
    """Every (crop σ, filter, order) of the grid on one loop: ``{(crop, filter, order): rows}``, one row per window,
    NaN marking cropped samples (same as :func:`preprocess.filtered_rows` per combination).

    Shared work: the crop statistics (mean, σ) once per crop σ; the forward order filters the raw loop once per
    filter and window, whatever the crop σ; the moving average of all windows comes from one cumulative sum.
    """
    base = pp.Preprocessing(crop_sigma=None, filter="none", window=1, settle_s=settle_s)
    x = pp.filtered_rows(values, period_s, base, np.array([1]))[0]  # validation and settle cut
    out: dict[tuple, np.ndarray] = {}
    kept = {crop: (x if crop is None else x[np.isfinite(pp.crop_outliers(x, crop)[0])]) for crop in grid.crop_sigmas}
    for filt in grid.filters:
        windows = np.asarray(filter_windows(grid, filt), int)
        forward = pp.smooth(x, filt, windows) if "forward" in grid.orders else None
        for crop in grid.crop_sigmas:
            if "backward" in grid.orders:
                out[(crop, filt, "backward")] = pp.smooth(kept[crop], filt, windows)
            if forward is not None:
                out[(crop, filt, "forward")] = pp.crop_outliers(forward, crop)
    return out


def point_torques(points_loops: Sequence[Sequence[LoopData]], grid: StudyGrid, progress: ProgressFn | None = None
                  ) -> dict[tuple, tuple[np.ndarray, np.ndarray]]:
    """Eq. 16 point torques (raw, not yet bias-normalised) for every combination of the grid.

    Returns ``{(crop, filter, order, location): (raw_a3, raw_a5)}`` with arrays of shape (n_windows, n_points).
    """
    n_points = len(points_loops)
    n_loops, done = sum(len(loops) for loops in points_loops), 0
    out: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
    for crop in grid.crop_sigmas:
        for filt in grid.filters:
            shape = (len(filter_windows(grid, filt)), n_points)
            for order in grid.orders:
                for loc in grid.locations:
                    out[(crop, filt, order, loc)] = (np.zeros(shape), np.zeros(shape))
    for j, loops in enumerate(points_loops):
        for a3, a5, dt in loops:
            for axis, values in ((0, a3), (1, a5)):
                for (crop, filt, order), rows in loop_grid_rows(values, dt, grid).items():
                    for loc in grid.locations:  # eq. 16: the outer average over the point's loops
                        out[(crop, filt, order, loc)][axis][:, j] += pp.location_rows(rows, loc) / len(loops)
            done += 1
            if progress is not None:
                progress(STAGE_LOOPS, done, n_loops)
    return out


def run_study(points_loops: Sequence[Sequence[LoopData]],
              to_points: Callable[[np.ndarray, np.ndarray], cal_mod.CalibrationPoints],
              grid: StudyGrid = StudyGrid(), method: str = "paper", g_m_s2: float = G_PAPER_M_S2,
              lever_difference_m: float | None = None, progress: ProgressFn | None = None) -> list[StudyRow]:
    """Every grid combination, ranked by the in-sample mean absolute mass error of ``method`` (as Table A2).

    ``to_points(raw_a3, raw_a5)`` turns eq. 16 point torques into bias-normalised calibration points.
    ``lever_difference_m``: Δr of eq. 3–4; ``None``: the active robot's measurement pose's.
    """
    if lever_difference_m is None:
        lever_difference_m = robots.active().lever_difference_m
    rows = []
    done = 0
    for (crop, filt, order, loc), (raw3, raw5) in point_torques(points_loops, grid, progress).items():
        for i, window in enumerate(filter_windows(grid, filt)):
            points = to_points(raw3[i], raw5[i])
            try:
                cal = cal_mod.fit(points, method, g_m_s2, lever_difference_m)
            except cal_mod.CalibrationError:
                cal = None  # not fittable with this pre-processing: not ranked
            if cal is not None:
                err = cal_mod.mean_abs_pct(points.mass_kg, cal.mass_kg(points.torque_a3_nm, points.torque_a5_nm))
                rows.append(StudyRow(crop, filt, int(window), order, loc, err, cal.r2.get("A3", float("nan")),
                                     cal.r2.get("A5", float("nan"))))
            done += 1
            if progress is not None:
                progress(STAGE_COMBINATIONS, done, grid.size)
    rows.sort(key=lambda r: r.mass_err_pct)
    return rows


def rank_models(points: cal_mod.CalibrationPoints, g_m_s2: float = G_PAPER_M_S2,
                lever_difference_m: float | None = None,
                progress: ProgressFn | None = None) -> list[selection.Evaluation]:
    """:func:`selection.evaluate_all`, ranked by the leave-one-out mean absolute mass error (``lever_difference_m``
    ``None``: the active robot's Δr)."""
    if lever_difference_m is None:
        lever_difference_m = robots.active().lever_difference_m
    report = None if progress is None else (lambda done, total: progress(STAGE_MODELS, done, total))
    evaluations = selection.evaluate_all(points, g_m_s2, lever_difference_m, report)
    return sorted(evaluations, key=lambda e: e.loo_mean_abs_err_pct)
