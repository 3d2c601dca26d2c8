"""Loop integrity (issue 33): which loops of a point or a DuT measurement are fit to be averaged (eq. 16).

A loop is set aside, with its reason, when

* **a torque channel is frozen**: it holds one value for :data:`FROZEN_FRACTION` of its samples after the settle
  cut or more, in one run (:func:`frozen_reason`): a stuck sensor or a stale trace buffer, not a measurement of the
  load. No drive's torque estimate repeats itself sample for sample; an exactly repeated reading is no sample, and
  neither the step check (whose scatter it zeroes) nor the loop-to-loop check (whose scatter it hides when every
  loop is frozen) would say so. Set aside on its own: the loops after it were measured as before;
* **it repeats an earlier loop** sample for sample in both torque channels (:class:`Repeats`): a trace file copied
  under another name, no new measurement; counted twice it would narrow the loop spread of U on no evidence;
* **samples are missing**: fewer than :data:`MIN_VALID_FRACTION` of its samples after the settle cut are valid (a
  sample is missing in a loop when any of its torque channels lacks it: DIAdem's no-value marker or NaN/inf, read as
  NaN by :mod:`rgse_daemon.trace.diadem`); a loop with a smaller gap is used with what remains;
* **it holds a step or a ramp**: at some split its later part differs from its earlier part by more than
  :data:`STEP_Z` standard errors (:func:`step_profile`: batch medians, so a spike moves nothing), after the trend
  every loop shares (the release transient, the warming within a trace) is taken out as the median of that
  difference over the loops (at least :data:`MIN_LOOPS_TO_SCREEN`). A step means the load moved during the
  measurement (a knock, a settling fixture): the loops after it are in another state, so they are set aside too
  ("after the step in loop ...");
* **it disagrees with the others** (three or more loops): its value lies more than :data:`LOOP_Z` scales from the
  median of the loops, the scale being its own and the median's standard error and what the thermal model allows for
  its temperature (``allowance``). Only a minority is set aside this way: when half the loops or more disagree, the
  loops drift or scatter as a whole, nothing marks one as disturbed, and the loop spread widens U instead (with the
  "loops disagree" warning).

Medians throughout: one disturbed loop or one spike moves none of them. The false-alarm rate of the two thresholds
on undisturbed simulated measurements is in docs/accuracy.md (bench/accuracy.py counts every set-aside).
If fewer than the configured minimum of loops remain (:data:`MIN_LOOPS`, :data:`MIN_LOOPS_PER_POINT`), the
caller refuses with the reasons, or (the daemon) may measure replacement loops: :attr:`Screening.enough` is that
decision. The raw files of a set-aside loop stay archived as they are; only the average leaves it out.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rgse_daemon.errors import DataError

#: A loop keeps at least this fraction of its samples (after the settle cut), else it is set aside.
MIN_VALID_FRACTION = 0.5
#: ... and at least this many valid samples.
MIN_VALID_SAMPLES = 20
#: A torque channel that holds one value over this fraction of a loop's samples (after the settle cut), in one run, is
#: frozen (:func:`frozen_reason`) ...
FROZEN_FRACTION = 0.25
#: ... if that run is at least this many samples long.
FROZEN_MIN_SAMPLES = 10
#: Fewest loops a DuT measurement's mass rests on (the loop-to-loop check and the loop spread need two); fewer left
#: after setting loops aside refuses the measurement. The stop-when-U-is-reached rule must not stop below it.
MIN_LOOPS = 2
#: Fewest loops a calibration point keeps (the thermal drift's fit needs two per point).
MIN_LOOPS_PER_POINT = 2
#: Fewest loops the step and loop-to-loop checks need: the trend every loop shares (release transient, warming) and
#: the loops' centre are their median, which two loops do not give. With fewer, only missing samples set a loop
#: aside, and the loop spread (with its "loops disagree" warning) is all that guards the mean.
MIN_LOOPS_TO_SCREEN = 3
#: Batches a loop is cut into for the step statistic (:func:`step_profile`).
N_BATCHES = 10
#: Step statistic beyond which a loop holds a step (standard errors of the difference across the split where it is
#: largest; for independent batches each split's is a Student t with 8 degrees of freedom, 3·10⁻⁴ beyond 6 two-sided,
#: and the largest of the 7 correlated splits at most 7 times that per loop and axis).
STEP_Z = 6.0
#: Loop-to-loop statistic beyond which a loop disagrees with the others (scales from the median).
LOOP_Z = 6.0
#: σ of a median of n normal values is 1.2533·σ/√n.
MEDIAN_SE_FACTOR = 1.2533


class TooFewLoops(DataError):
    """Fewer loops than the configured minimum remain after setting the disturbed ones aside: refused.
    ``used``: the loops that remained (names); ``set_aside``: those left out, with their reasons."""

    def __init__(self, message: str, used: Sequence[str] = (), set_aside: Sequence[SetAside] = ()) -> None:
        super().__init__(message)
        self.used = list(used)
        self.set_aside = list(set_aside)


@dataclass(frozen=True)
class SetAside:
    """A loop left out of the average, and why."""

    loop: str
    reason: str

    def to_dict(self) -> dict[str, str]:
        return {"loop": self.loop, "reason": self.reason}


@dataclass(frozen=True)
class Screening:
    """The loops kept (indices into the input, in order) and those set aside with their reasons."""

    used: list[int]
    set_aside: list[SetAside] = field(default_factory=list)
    minimum: int = MIN_LOOPS

    @property
    def enough(self) -> bool:
        """At least ``minimum`` loops remain, or every loop measured (fewer were asked for and none set aside);
        otherwise refuse, or (the daemon) measure replacement loops."""
        return len(self.used) >= self.minimum or (bool(self.used) and not self.set_aside)

    def reasons(self) -> str:
        return "; ".join(f"loop {s.loop}: {s.reason}" for s in self.set_aside)


def valid_mask(*channels: np.ndarray) -> np.ndarray:
    """Samples valid in every channel of a loop (a sample missing in one torque channel is missing in all)."""
    return np.logical_and.reduce([np.isfinite(np.asarray(c, float)) for c in channels])


def gap_reason(valid: np.ndarray, skip: int) -> str | None:
    """Why a loop with these valid samples (after ``skip`` settle samples) cannot be used; None if it can."""
    v = np.asarray(valid, bool)[skip:]
    n, k = v.size, int(v.sum())
    if n - k == 0:
        return None
    if k < max(MIN_VALID_FRACTION * n, MIN_VALID_SAMPLES):
        return (f"{n - k} of {n} samples missing (no value, NaN or inf in the trace): fewer than "
                f"{MIN_VALID_FRACTION:.0%} left")
    return None


def longest_run(x: np.ndarray) -> tuple[int, float]:
    """The longest run of exactly equal consecutive values in ``x`` (NaN, a missing sample, is left out first):
    its length and its value (0 and NaN for an empty ``x``)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0, float("nan")
    edges = np.flatnonzero(np.diff(x) != 0.0) + 1  # where a new value begins
    starts = np.r_[0, edges]
    lengths = np.diff(np.r_[starts, x.size])
    k = int(lengths.argmax())
    return int(lengths[k]), float(x[starts[k]])


def frozen_reason(channels: Sequence[tuple[str, np.ndarray]], skip: int) -> str | None:
    """Why a loop cannot be used because a torque channel is frozen (``channels``: (name, samples) of each torque
    channel; ``skip``: the settle cut in samples): one value repeated for at least :data:`FROZEN_FRACTION` of the
    samples after the cut, and at least :data:`FROZEN_MIN_SAMPLES`; None if none is."""
    for name, x in channels:
        v = np.asarray(x, float)[skip:]
        n = int(np.isfinite(v).sum())
        run, value = longest_run(v)
        if n and run >= max(FROZEN_FRACTION * n, FROZEN_MIN_SAMPLES):
            return (f"{name} torque frozen: {value:.6g} Nm for {run} of {n} samples in a row (a stuck sensor or a "
                    f"stale trace buffer, not a measurement of the load; limit {FROZEN_FRACTION:.0%})")
    return None


class Repeats:
    """Remembers the torque samples of the loops seen so far (by digest) and names the loop a later one repeats
    sample for sample: real drive torques never repeat a loop exactly."""

    def __init__(self) -> None:
        self._seen: dict[str, str] = {}

    def reason(self, name: str, *channels: np.ndarray) -> str | None:
        """Why loop ``name`` (its torque ``channels``) cannot be used: it repeats an earlier loop; None if it does
        not (it is then remembered)."""
        digest = hashlib.sha256()
        for c in channels:
            digest.update(np.ascontiguousarray(c, dtype=float).tobytes())
        first = self._seen.setdefault(digest.hexdigest(), name)
        if first == name:
            return None
        return (f"repeats loop {first} sample for sample in both torque channels (a copy of its trace file, not a "
                f"new measurement)")


def step_profile(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The step of a loop at every split: its valid samples cut into :data:`N_BATCHES` batches, for each split k
    (2 ≤ k ≤ N_BATCHES − 2 batches before it) the mean of the batch medians after it minus those before it, and its
    standard error from the batch medians' scatter within the two parts (Student t with N_BATCHES − 2 degrees of
    freedom for independent batches), never below what white noise of the loop's own sample scatter gives. A spike
    moves no batch median; a smooth trend within the parts widens the error instead of firing. NaN when the loop has
    too few samples."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    splits = np.arange(2, N_BATCHES - 1)
    size = x.size // N_BATCHES
    if size < 3:
        return np.full(splits.size, np.nan), np.full(splits.size, np.nan)
    b = np.median(x[: size * N_BATCHES].reshape(N_BATCHES, size), axis=1)
    # floor: the scatter a batch median of white noise has (σ from the MAD of the sample-to-sample differences,
    # which neither a step nor a trend inflates): a few batches that agree by chance do not make a step
    diffs = np.diff(x)
    sigma = 1.4826 * float(np.median(np.abs(diffs - np.median(diffs)))) / np.sqrt(2.0)
    floor = MEDIAN_SE_FACTOR * sigma / np.sqrt(size)
    d, se = [], []
    for k in splits:
        before, after = b[:k], b[k:]
        pooled = (before.var(ddof=1) * (k - 1) + after.var(ddof=1) * (N_BATCHES - k - 1)) / (N_BATCHES - 2)
        d.append(after.mean() - before.mean())
        se.append(np.sqrt(max(pooled, floor**2) * (1.0 / k + 1.0 / (N_BATCHES - k))))
    return np.array(d), np.array(se)


def screen(names: Sequence[str], series: Sequence[np.ndarray], values: np.ndarray, value_se: np.ndarray,
           allowance: np.ndarray | None = None, minimum: int = MIN_LOOPS, unit: str = "kg",
           already: Sequence[SetAside] = ()) -> Screening:
    """Screen loops for a step (``series``: each loop's valid samples after the settle cut, in the unit the decision
    matters in) and for loop-to-loop disagreement (``values``: the per-loop results, ``value_se`` their standard
    errors, ``allowance`` the standard deviation the thermal model leaves per loop). ``already``: loops set aside
    before (missing samples), not among ``names``."""
    n = len(names)
    aside = list(already)
    keep = np.ones(n, bool)
    if n >= MIN_LOOPS_TO_SCREEN:
        prof = [step_profile(x) for x in series]
        d = np.array([p[0] for p in prof])  # loops × splits
        se = np.array([p[1] for p in prof])
        ref = np.median(d, axis=0)  # the trend every loop shares, per split
        with np.errstate(invalid="ignore", divide="ignore"):
            z_all = np.abs(d - ref) / np.maximum(se, 1e-12)
        z_all = np.where(np.isfinite(z_all), z_all, 0.0)
        at = z_all.argmax(axis=1)
        z = z_all[np.arange(n), at]
        bad = np.flatnonzero(z > STEP_Z)
        if bad.size:
            first = int(bad[0])
            step = d[first, at[first]] - ref[at[first]]
            aside.append(SetAside(names[first], f"a step of {step:+.3g} {unit} inside the loop, "
                                                f"{(at[first] + 2) / N_BATCHES:.0%} into it ({z[first]:.1f} standard "
                                                f"errors, limit {STEP_Z:g}): the load moved during the measurement"))
            for j in range(first + 1, n):
                aside.append(SetAside(names[j], f"measured after the step in loop {names[first]} (the load may "
                                                f"no longer sit as before)"))
            keep[first:] = False
    idx = np.flatnonzero(keep)
    se_ok = np.all(np.isfinite(value_se)) and np.all(np.asarray(value_se, float) > 0)  # noiseless: nothing to judge
    if idx.size >= MIN_LOOPS_TO_SCREEN and se_ok:
        v = np.asarray(values, float)[idx]
        s = np.asarray(value_se, float)[idx]
        extra = np.zeros(idx.size) if allowance is None else np.asarray(allowance, float)[idx]
        med = float(np.median(v))
        s_med = MEDIAN_SE_FACTOR * float(np.sqrt(np.mean(s**2 + extra**2)) / np.sqrt(idx.size))
        scale = np.sqrt(s**2 + extra**2 + s_med**2)
        z = np.abs(v - med) / np.maximum(scale, 1e-12)
        out = np.flatnonzero(np.isfinite(z) & (z > LOOP_Z))
        if 2 * out.size >= idx.size:  # not a few outliers but loops spread or drifting: no majority to keep
            out = out[:0]
        for j in out:
            keep[idx[j]] = False
            aside.append(SetAside(names[idx[j]], f"disagrees with the other loops by {v[j] - med:+.3g} {unit} "
                                                 f"({z[j]:.1f} times what the loop scatter and the thermal model "
                                                 f"explain, limit {LOOP_Z:g})"))
    return Screening([int(i) for i in np.flatnonzero(keep)], aside, minimum)
