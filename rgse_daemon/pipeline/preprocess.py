"""Pre-processing of torque traces (paper §2.4.4–2.4.6, Fig. 23/26): settle cut, xσ outlier cropping,
smoothing filter, order of the two, per-loop location and the double arithmetic average of eq. 16.

Everything is vectorised (cumulative sums, scipy.ndimage filters, NaN-masked row operations); functions that
take a 2-D array work on many signals at once (one row per filter window in the parameter study).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import ndimage, signal

from rgse_daemon.errors import DataError

FILTERS = ("none", "moving_average", "gaussian", "median")
ORDERS = ("backward", "forward")
LOCATIONS = ("mean", "trimmed", "huber", "median")

#: Fraction cut from each tail by the ``trimmed`` location.
TRIM_FRACTION = 0.1
#: Huber tuning constant (in robust standard deviations): 95 % efficiency for Gaussian noise.
HUBER_C = 1.345
#: Bounds of the parameters a CAL.json or ``--preprocessing`` may set: a filter window (samples; a trace holds at most
#: some ten thousand) and the settle cut (s; a loop's trace lasts seconds to minutes).
MAX_WINDOW = 100_000
MAX_SETTLE_S = 3600.0


class PreprocessError(DataError):
    """A trace cannot be pre-processed (too short, nothing left after cropping, bad parameters)."""


@dataclass(frozen=True)
class Preprocessing:
    """Pre-processing parameters (paper Table A2 columns, plus the robust location options).

    Attributes
    ----------
    crop_sigma
        Remove samples deviating from the loop mean by more than ``crop_sigma`` standard deviations;
        ``None`` keeps all.
    filter, window
        Centred smoothing filter and its window in samples (Gaussian: window ≈ 5 σ, as MATLAB's smoothdata).
    order
        ``"backward"``: crop, then filter (the paper's choice); ``"forward"``: filter, then crop.
    location
        Per-loop location estimate: ``mean`` (eq. 16, the paper), ``trimmed``, ``huber`` or ``median``.
    settle_s
        Seconds cut from the start of every loop (settling transient after the brake-release move).
    """

    crop_sigma: float | None = 1.0
    filter: str = "moving_average"
    window: int = 150
    order: str = "backward"
    location: str = "mean"
    settle_s: float = 0.0

    def __post_init__(self) -> None:
        if self.filter not in FILTERS:
            raise PreprocessError(f"pre-processing: unknown filter {self.filter!r} (one of {', '.join(FILTERS)})")
        if self.order not in ORDERS:
            raise PreprocessError(f"pre-processing: unknown order {self.order!r} (one of {', '.join(ORDERS)})")
        if self.location not in LOCATIONS:
            raise PreprocessError(f"pre-processing: unknown location {self.location!r}")
        if isinstance(self.window, bool) or not isinstance(self.window, int) or not 1 <= self.window <= MAX_WINDOW:
            raise PreprocessError(f"pre-processing: window must be a whole number of samples 1..{MAX_WINDOW}, "
                                  f"got {self.window!r}")
        if self.crop_sigma is not None and not (_number(self.crop_sigma) and 0 < self.crop_sigma < math.inf):
            raise PreprocessError(f"pre-processing: crop_sigma must be a finite number > 0, got {self.crop_sigma!r}")
        if not (_number(self.settle_s) and 0 <= self.settle_s <= MAX_SETTLE_S):
            raise PreprocessError(f"pre-processing: settle_s must be a number 0..{MAX_SETTLE_S:g} s, "
                                  f"got {self.settle_s!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> Preprocessing:
        try:
            return Preprocessing(**d)
        except TypeError as exc:
            raise PreprocessError(f"pre-processing: bad parameters {d!r}: {exc}") from exc


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


#: The paper's chosen method F (Table A2/A3): 1σ crop, then centred moving average of 150 samples.
PAPER = Preprocessing()


# ------------------------------------------------------------------------------------------------------------
# building blocks on 2-D arrays (rows = signals, NaN = removed sample)
# ------------------------------------------------------------------------------------------------------------
def crop_outliers(x: np.ndarray, crop_sigma: float | None) -> np.ndarray:
    """Replace samples beyond ``crop_sigma``·σ of their row mean by NaN (one pass, as the paper's xσ crop)."""
    x = np.atleast_2d(np.asarray(x, float))
    if crop_sigma is None:
        return x
    mu = np.nanmean(x, axis=1, keepdims=True)
    sd = np.nanstd(x, axis=1, keepdims=True)
    dev = np.abs(x - mu)
    # for crop_sigma >= 1 some sample always lies within 1σ; the floor keeps that true under rounding too
    threshold = np.maximum(crop_sigma * sd, np.nanmin(dev, axis=1, keepdims=True))
    return np.where(dev <= threshold, x, np.nan)


def moving_average(x: np.ndarray, windows: np.ndarray | int) -> np.ndarray:
    """Centred moving average with shrinking windows at the ends (MATLAB ``movmean``), via cumulative sums.

    ``x`` is 1-D (no NaN); returns one row per window.
    """
    x = np.asarray(x, float)
    w = np.atleast_1d(np.asarray(windows, int))[:, None]
    n = x.size
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(n)[None, :]
    lo = np.maximum(i - w // 2, 0)
    hi = np.minimum(i + (w - 1) // 2 + 1, n)
    return (c[hi] - c[lo]) / (hi - lo)


#: Above this kernel radius (samples) the Gaussian is applied by FFT convolution (same result, O(n log n)).
GAUSSIAN_FFT_RADIUS = 64


def gaussian(x: np.ndarray, window: int) -> np.ndarray:
    """Centred Gaussian smoothing of a 1-D signal, σ = window/5 samples (MATLAB ``smoothdata``), ends ``nearest``.

    Identical to ``scipy.ndimage.gaussian_filter1d(x, σ, mode="nearest")`` (kernel truncated at 4σ); long kernels
    go through an FFT convolution of the edge-padded signal instead of the direct sum.
    """
    sigma = max(window / 5.0, 1e-3)
    radius = int(4.0 * sigma + 0.5)
    if radius <= GAUSSIAN_FFT_RADIUS:
        return ndimage.gaussian_filter1d(x, sigma=sigma, mode="nearest")
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    return signal.fftconvolve(np.pad(x, radius, mode="edge"), k / k.sum(), mode="valid")


def smooth(x: np.ndarray, filter_name: str, windows: np.ndarray | int) -> np.ndarray:
    """Apply a centred filter to the 1-D signal ``x`` for each window; returns one row per window."""
    x = np.asarray(x, float)
    windows = np.atleast_1d(np.asarray(windows, int))
    if filter_name == "none":
        return np.broadcast_to(x, (windows.size, x.size)).copy()
    if filter_name == "moving_average":
        return moving_average(x, windows)
    if filter_name == "gaussian":
        return np.stack([gaussian(x, w) for w in windows])
    if filter_name == "median":
        return np.stack([ndimage.median_filter(x, size=int(w), mode="nearest") for w in windows])
    raise PreprocessError(f"pre-processing: unknown filter {filter_name!r}")


def _row_median(x: np.ndarray, n_valid: np.ndarray) -> np.ndarray:
    """Median of each row ignoring NaN (sorted to the end), vectorised over rows (``np.nanmedian`` loops)."""
    s = np.sort(x, axis=1)
    lo = np.take_along_axis(s, np.maximum((n_valid - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(s, np.maximum(n_valid // 2, 0)[:, None], axis=1)[:, 0]
    return 0.5 * (lo + hi)  # a row without valid samples reads its first (NaN) element twice: NaN


def location_rows(x: np.ndarray, kind: str) -> np.ndarray:
    """Location estimate of each row of ``x`` ignoring NaN: mean, trimmed mean, Huber M-estimate or median."""
    x = np.atleast_2d(np.asarray(x, float))
    valid = np.isfinite(x)
    if kind == "mean":
        return np.nanmean(x, axis=1)
    if kind == "median":
        return np.nanmedian(x, axis=1)
    if kind == "trimmed":
        s = np.sort(x, axis=1)  # NaN sort to the end
        n = valid.sum(axis=1)
        cut = np.floor(TRIM_FRACTION * n).astype(int)
        j = np.arange(x.shape[1])[None, :]
        keep = (j >= cut[:, None]) & (j < (n - cut)[:, None])
        return np.where(keep, s, 0.0).sum(axis=1) / keep.sum(axis=1)
    if kind == "huber":
        n = valid.sum(axis=1)
        mu = _row_median(x, n)[:, None]
        scale = 1.4826 * _row_median(np.abs(x - mu), n)[:, None]
        scale = np.where(scale > 0, scale, np.nanstd(x, axis=1, keepdims=True) + 1e-12)
        xv = np.where(valid, x, 0.0)
        cs = HUBER_C * scale
        for _ in range(30):  # iteratively reweighted mean; converges in a handful of steps
            w = np.where(valid, np.minimum(1.0, cs / np.maximum(np.abs(xv - mu), 1e-300)), 0.0)
            new = (xv * w).sum(axis=1, keepdims=True) / w.sum(axis=1, keepdims=True)
            done = np.allclose(new, mu, rtol=0, atol=1e-9 * (1 + np.abs(mu).max()))
            mu = new
            if done:
                break
        return mu[:, 0]
    raise PreprocessError(f"pre-processing: unknown location {kind!r}")


# ------------------------------------------------------------------------------------------------------------
# one loop, one point
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopTorque:
    """Result of pre-processing one loop (trace) of one axis.

    Attributes
    ----------
    torque_nm : float
        Location of the pre-processed samples (inner average of eq. 16).
    spread_nm : float
        Standard deviation of the samples used.
    n_used, n_total : int
        Samples surviving settle cut and cropping, and samples in the loop.
    """

    torque_nm: float
    spread_nm: float
    n_used: int
    n_total: int


def valid_samples(x: np.ndarray) -> np.ndarray:
    """The loop's samples without the missing ones (NaN: DIAdem's no-value marker or a non-finite value, issue 33),
    in time order. Whether enough remain is :mod:`rgse_daemon.pipeline.integrity`'s decision."""
    return x[np.isfinite(x)]


def filtered_rows(values: np.ndarray, period_s: float, cfg: Preprocessing, windows: np.ndarray) -> np.ndarray:
    """Settle cut, crop and filter (in ``cfg.order``) of one loop for several windows; NaN marks cropped samples.

    Returns one row per window (the parameter study's inner kernel).
    """
    x = np.asarray(values, float)
    if x.ndim != 1:
        raise PreprocessError(f"pre-processing: a loop must be 1-D, got shape {x.shape}")
    if period_s <= 0:
        raise PreprocessError(f"pre-processing: sample period must be > 0, got {period_s}")
    skip = round(cfg.settle_s / period_s)
    x = valid_samples(x[skip:])
    if x.size < 3:
        raise PreprocessError(f"pre-processing: only {x.size} samples left after the {cfg.settle_s} s settle cut")
    windows = np.atleast_1d(np.asarray(windows, int))
    if cfg.order == "backward":  # crop, then filter the remaining samples
        kept = crop_outliers(x, cfg.crop_sigma)[0]
        rows = smooth(kept[np.isfinite(kept)], cfg.filter, windows)
    else:  # forward: filter, then crop
        rows = crop_outliers(smooth(x, cfg.filter, windows), cfg.crop_sigma)
    if np.any(np.isfinite(rows).sum(axis=1) < 1):
        raise PreprocessError("pre-processing: no samples left after cropping")
    return rows


def process_loop_windows(values: np.ndarray, period_s: float, cfg: Preprocessing, windows: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pre-process one loop for several filter windows at once.

    Returns per window: location (Nm), standard deviation of the used samples (Nm), samples used.
    """
    rows = filtered_rows(values, period_s, cfg, windows)
    return location_rows(rows, cfg.location), np.nanstd(rows, axis=1), np.isfinite(rows).sum(axis=1)


def process_loop(values: np.ndarray, period_s: float, cfg: Preprocessing = PAPER) -> LoopTorque:
    """Pre-process one loop of one axis with ``cfg``."""
    loc, sd, used = process_loop_windows(values, period_s, cfg, np.array([cfg.window]))
    return LoopTorque(float(loc[0]), float(sd[0]), int(used[0]), int(np.asarray(values).size))


def kept_samples(values: np.ndarray, period_s: float, cfg: Preprocessing = PAPER) -> np.ndarray:
    """The raw samples the pre-processing keeps (after the settle cut and the crop), unfiltered, in time order:
    what the within-loop standard error is estimated from (a centred smoothing filter hardly moves the mean but
    correlates neighbours)."""
    x = valid_samples(np.asarray(values, float)[round(cfg.settle_s / period_s):])
    if cfg.order == "backward":
        return x[np.isfinite(crop_outliers(x, cfg.crop_sigma)[0])]
    return x[np.isfinite(filtered_rows(values, period_s, cfg, np.array([cfg.window]))[0])]


def double_average_nm(loop_torques_nm: np.ndarray) -> float:
    """Eq. 16: the mean over the m loops of the per-loop (inner) averages."""
    a = np.asarray(loop_torques_nm, float)
    if a.size == 0:
        raise PreprocessError("pre-processing: a point needs at least one loop")
    return float(a.mean())


def normalise(torque_nm: np.ndarray | float, bias_nm: float) -> np.ndarray:
    """Zero-load bias normalisation ``M_norm = M − M_0`` (paper §2.4.5: all calculations use normalised values)."""
    return np.asarray(torque_nm, float) - bias_nm
