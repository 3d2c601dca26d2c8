"""When more loops no longer change U: the stop rule of a run's (and a campaign point's) loops.

The loop term of the U budget (:func:`~rgse_daemon.pipeline.uncertainty.loop_spread_kg`, the standard error of the
eq. 16 mean over the loops) shrinks as ``1/√n``; every other term (the calibration's reproducibility, curve, g, ...)
does not move with more loops of the same mounting. With the loop term a share ``r`` of u, infinitely many loops
more could shrink U by at most ``1 − √(1 − r²)`` (2 % at r = 0.2). So a run stops when

* it has ``max_loops`` (the configured ``loops``): ``max loops``; else, once it has at least ``min_loops``
  (:data:`MIN_LOOPS`: the loop-to-loop consistency check needs three) loops **kept** (the loops the integrity check
  of :mod:`rgse_daemon.pipeline.integrity` set aside do not count),
* U predicted for the loops measured is at most ``target_U_kg``: ``target U met``, or
* the predicted loop term is at most ``loop_share`` of the predicted u: ``loop term below share``.

Loops set aside are replaced: a run that has measured its ``max_loops`` but kept fewer than it needs
(``min_loops``, or ``max_loops`` if that is smaller) goes on with replacement loops, at most ``replacements`` of them
(the config's ``measurement.replacement_loops``); then it stops (``replacements spent``) and the mass is computed
from what was kept, or refused if too few were.

A campaign point stops by the same rule (:func:`point_prediction`): its loop term (the standard error of its mean
torque) against the scatter a new mounting adds, the reproducibility of the calibration in use.

The prediction (:func:`predict`): the loops measured are ``n``, the loops analysed ``n_a ≤ n`` (the newest loop's
files may still be on their way while the next loop is decided): the loop term for ``n`` loops is the analysed
one × ``√(n_a/n)``; the other terms are what the analysed loops gave. The result that is stored is computed from all
loops, and records the rule's decision beside its own U.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc

#: The fewest loops the rule stops at: the loop-to-loop consistency check (disturbed loops) needs three.
MIN_LOOPS = 3

MAX_LOOPS = "max loops"
TARGET_MET = "target U met"
LOOP_SHARE = "loop term below share"
REPLACEMENTS_SPENT = "replacements spent"
CONTINUE = ""


@dataclass(frozen=True)
class StopRule:
    """``max_loops``: the configured loops; ``min_loops`` ≥ :data:`MIN_LOOPS` unless ``max_loops`` is smaller;
    ``loop_share``: 0 switches the share test off; ``target_U_kg``: None switches the target test off (both off:
    always ``max_loops`` loops, the former fixed count); ``replacements``: loops the run may measure beyond
    ``max_loops`` to replace loops set aside."""

    max_loops: int
    min_loops: int = MIN_LOOPS
    loop_share: float = 0.2
    target_U_kg: float | None = None
    k: float = 2.0
    replacements: int = 0

    def __post_init__(self) -> None:
        if self.max_loops < 1:
            raise ValueError(f"stop rule: max_loops {self.max_loops} must be >= 1")
        if self.min_loops < MIN_LOOPS:
            raise ValueError(f"stop rule: min_loops {self.min_loops} must be >= {MIN_LOOPS} (the loop-to-loop check)")
        if not 0.0 <= self.loop_share < 1.0:
            raise ValueError(f"stop rule: loop_share {self.loop_share} must be in [0, 1)")
        if self.target_U_kg is not None and not self.target_U_kg > 0.0:
            raise ValueError(f"stop rule: target_U_kg {self.target_U_kg} must be > 0")
        if self.replacements < 0:
            raise ValueError(f"stop rule: replacements {self.replacements} must be >= 0")

    @property
    def needed(self) -> int:
        """The loops a run must keep before it may stop at ``max_loops``: ``min_loops``, or ``max_loops`` if fewer
        were asked for."""
        return min(self.min_loops, self.max_loops)

    @property
    def fixed(self) -> bool:
        """Neither test is on: the run always takes ``max_loops``."""
        return self.loop_share == 0.0 and self.target_U_kg is None


@dataclass(frozen=True)
class Prediction:
    """U's loop term and u for ``loops`` loops, predicted from ``analysed`` of them (kg for a mass; a campaign
    point's are in Nm (:func:`point_prediction`), where only the share test applies)."""

    loops: int
    analysed: int
    u_loops_kg: float
    u_kg: float
    k: float = 2.0

    @property
    def U_kg(self) -> float:
        return self.k * self.u_kg

    @property
    def loop_share(self) -> float:
        return self.u_loops_kg / self.u_kg if self.u_kg > 0 else math.inf


@dataclass(frozen=True)
class StopDecision:
    stop: bool
    reason: str
    """One of :data:`MAX_LOOPS`, :data:`TARGET_MET`, :data:`LOOP_SHARE`, :data:`REPLACEMENTS_SPENT`; empty while the
    run goes on."""
    prediction: Prediction | None = None
    kept: int | None = None
    """The loops kept when it was decided (None: not screened)."""

    def to_json(self) -> dict[str, object]:
        p = self.prediction
        return {"stop_reason": self.reason or None, "loops_kept": self.kept, "loops": None if p is None else p.loops,
                "loops_analysed": None if p is None else p.analysed,
                "predicted_U_kg": None if p is None else p.U_kg,
                "predicted_loop_share": None if p is None else p.loop_share}


def predict(loops: int, analysed: int, u_kg: float, u_loops_kg: float, k: float = 2.0) -> Prediction:
    """The budget for ``loops`` loops from the one of the first ``analysed`` (u and its loop term, kg)."""
    if not 1 <= analysed <= loops:
        raise ValueError(f"predict: {analysed} loops analysed of {loops}")
    if not (math.isfinite(u_kg) and math.isfinite(u_loops_kg)) or u_loops_kg < 0 or u_kg < u_loops_kg:
        raise ValueError(f"predict: u {u_kg} kg with a loop term of {u_loops_kg} kg")
    other_sq = u_kg**2 - u_loops_kg**2
    u_loops_n = u_loops_kg * math.sqrt(analysed / loops)
    return Prediction(loops, analysed, u_loops_n, math.sqrt(other_sq + u_loops_n**2), k)


def decide(rule: StopRule, loops: int, prediction: Prediction | None, kept: int | None = None) -> StopDecision:
    """Stop after ``loops`` loops measured, ``kept`` of them kept by the integrity check (None: all)?
    ``prediction``: the budget for the kept loops (None: nothing analysed yet)."""
    n = loops if kept is None else kept
    if loops >= rule.max_loops + rule.replacements and (n < rule.needed and rule.replacements > 0):
        return StopDecision(True, REPLACEMENTS_SPENT, prediction, kept)
    if loops >= rule.max_loops and (n >= rule.needed or rule.replacements == 0):
        return StopDecision(True, MAX_LOOPS, prediction, kept)
    if n < rule.min_loops or prediction is None or rule.fixed:
        return StopDecision(False, CONTINUE, prediction, kept)
    if rule.target_U_kg is not None and prediction.U_kg <= rule.target_U_kg:
        return StopDecision(True, TARGET_MET, prediction, kept)
    if rule.loop_share > 0.0 and prediction.loop_share <= rule.loop_share:
        return StopDecision(True, LOOP_SHARE, prediction, kept)
    return StopDecision(False, CONTINUE, prediction, kept)


def point_loop_term_nm(loops: Sequence[tuple[np.ndarray, np.ndarray, float]],
                       pre: pp.Preprocessing = pp.PAPER) -> tuple[float, float]:
    """A campaign point's loop term per axis (A3, A5; Nm): the standard error of its eq. 16 mean torque over the
    loops (A3 samples, A5 samples, sample period s), as :func:`~rgse_daemon.pipeline.uncertainty.loop_spread_kg`
    takes it for the mass (the larger of the between-loop and the pooled within-loop error)."""
    out = []
    for axis in (0, 1):
        means = np.array([pp.process_loop(lp[axis], lp[2], pre).torque_nm for lp in loops])
        se = np.array([unc.batch_means_se(pp.kept_samples(lp[axis], lp[2], pre)) for lp in loops])
        out.append(unc.loop_spread_kg(means, se))
    return out[0], out[1]


def point_prediction(loops: int, analysed: int, loop_term_nm: tuple[float, float],
                     reproducibility_nm: tuple[float, float]) -> Prediction:
    """A campaign point's budget (Nm, so only the share test applies): per axis its loop term against the scatter a
    new mounting adds (the reproducibility of the calibration in use), the axis with the larger share."""
    preds = [predict(loops, analysed, math.hypot(rep, lt), lt)
             for lt, rep in zip(loop_term_nm, reproducibility_nm, strict=True)]
    return max(preds, key=lambda p: p.loop_share)
