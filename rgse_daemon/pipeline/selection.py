"""Model selection by held-out configurations (issue #18): which calibration model ``--method auto`` uses.

Every model of :data:`~rgse_daemon.pipeline.calibration.MODELS` is validated by holding out whole load
configurations (every loop of a point together) and then the lever group (the torque-based points together).
Joint models are admitted only where their A3/A5 split holds on held-out configurations (:func:`admissibility`);
``auto`` averages the near-best admissible per-axis gain models (:func:`average_of`), and
:func:`nested_loo_auto_mass_kg` repeats the whole choice without each configuration: the honest out-of-sample figure
that ``rgse calibrate`` prints.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from rgse_daemon.pipeline.calibration import (
    AVERAGE_PREFIX,
    AVERAGEABLE,
    GAIN_TERMS,
    JOINT_MODELS,
    MODELS,
    Calibration,
    CalibrationError,
    CalibrationPoints,
    fit,
    mean_abs_pct,
)

#: Members of the average: admissible per-axis gain models whose selection score is within this factor of the best.
AVERAGE_FACTOR = 1.5
#: How the models are validated (recorded in CAL.json): every load configuration (all loops of a calibration point
#: together) held out in turn, then the lever group of the torque-based points held out together.
VALIDATION_SCHEME = {"configurations": "leave-one-configuration-out (all loops of a point together)",
                     "lever_group": "leave-lever-group-out (the torque-based points together)",
                     "selection": "lowest score = configuration mean |error| % + 0.01 x lever-group mean |error| % "
                                  "among admissible models; per-axis models preferred"}
#: A joint model is admissible only if, on every axis, its held-out corrected torques scatter around the expected
#: torques (eq. 17/18) by at most this factor times the best per-axis model's.
JOINT_AXIS_FACTOR = 1.5
#: ... with this floor, as a fraction of the campaign's gain scale (:meth:`CalibrationPoints.gain_scale_nm`): a split
#: error below it is immaterial (on Table 1 1.0 Nm, 0.1 kg at Δr = 1.025 m), on any robot's torque scale.
JOINT_AXIS_FLOOR_FRACTION = 1e-3
#: A joint model replaces the best per-axis model only if its selection score is lower by more than this (%).
PREFER_AXIS_MARGIN_PCT = 0.02
#: Weight of the lever-group (extrapolation to other levers) error in the selection score.
LEVER_WEIGHT = 0.01


@dataclass(frozen=True)
class Evaluation:
    """In-sample and held-out mass errors of one method on one set of calibration points.

    ``loo_*``: every configuration (point) predicted by the fit on all others. ``heldout_residual_nm`` (n, 2): the
    held-out corrected torque ``K(M)·M`` minus the expected torque, A3 and A5 (the identifiability check of a
    joint model, and the reproducibility of the uncertainty). ``lever_*``: the torque-based points predicted by
    the fit on the others (NaN where there are none or the rest cannot carry the model): the selection's
    extrapolation check.
    """

    method: str
    in_sample_mass_kg: np.ndarray
    loo_mass_kg: np.ndarray
    in_sample_mean_abs_err_pct: float
    loo_mean_abs_err_pct: float
    loo_max_abs_err_kg: float
    n_params: int
    heldout_residual_nm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    lever_mass_kg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lever_mean_abs_err_pct: float = np.nan
    admissible: bool = True
    note: str = ""

    @property
    def joint(self) -> bool:
        return self.method in JOINT_MODELS

    @property
    def axis_rms_nm(self) -> np.ndarray:
        """RMS of the held-out per-axis residuals (A3, A5), Nm."""
        r = np.asarray(self.heldout_residual_nm, float)
        return np.sqrt(np.mean(r**2, axis=0)) if r.size else np.full(2, np.nan)


def _axis_residual_nm(cal: Calibration, points: CalibrationPoints, index: np.ndarray) -> np.ndarray:
    c3 = cal.k_a3.corrected_torque_nm(points.torque_a3_nm[index])
    c5 = cal.k_a5.corrected_torque_nm(points.torque_a5_nm[index])
    return np.stack([c3 - points.expected_a3_nm[index], c5 - points.expected_a5_nm[index]], axis=-1)


def leave_one_out_mass_kg(points: CalibrationPoints, method: str, g_m_s2: float,
                          lever_difference_m: float) -> np.ndarray:
    """Mass of each point (configuration) predicted by the method fitted on all other points."""
    return _held_out(points, method, g_m_s2, lever_difference_m)[0]


def _held_out(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float
              ) -> tuple[np.ndarray, np.ndarray]:
    n = len(points)
    mass, resid = np.empty(n), np.empty((n, 2))
    for i in range(n):
        keep = np.arange(n) != i
        cal = fit(points.subset(keep), method, g_m_s2, lever_difference_m)
        mass[i] = float(cal.points_mass_kg(points, np.array([i]))[0])
        resid[i] = _axis_residual_nm(cal, points, np.array([i]))[0]
    return mass, resid


def _lever_group_out(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float
                     ) -> np.ndarray:
    """The torque-based points predicted together by the fit on the other points (NaN elsewhere / if unfittable)."""
    mass = np.full(len(points), np.nan)
    group = np.asarray(points.kind) == "torque"
    if not group.any() or group.all():
        return mass
    try:
        cal = fit(points.subset(~group), method, g_m_s2, lever_difference_m)
    except CalibrationError:
        return mass
    idx = np.flatnonzero(group)
    mass[idx] = cal.points_mass_kg(points, idx)
    return mass


def evaluate(points: CalibrationPoints, method: str, g_m_s2: float, lever_difference_m: float) -> Evaluation:
    cal = fit(points, method, g_m_s2, lever_difference_m)
    ins = cal.points_mass_kg(points)
    loo, resid = _held_out(points, method, g_m_s2, lever_difference_m)
    lever = _lever_group_out(points, method, g_m_s2, lever_difference_m)
    held = np.isfinite(lever)
    lever_pct = mean_abs_pct(points.mass_kg[held], lever[held]) if held.any() else np.nan
    return Evaluation(method, ins, loo, mean_abs_pct(points.mass_kg, ins), mean_abs_pct(points.mass_kg, loo),
                      float(np.max(np.abs(loo - points.mass_kg))), len(cal.params), resid, lever, lever_pct)


def evaluate_all(points: CalibrationPoints, g_m_s2: float, lever_difference_m: float,
                 progress: Callable[[int, int], None] | None = None) -> list[Evaluation]:
    """Every model of the catalogue that can be fitted to these points, in catalogue order, with its admissibility
    (:func:`admissibility`); ``progress(done, total)`` after each model (the held-out fits take seconds)."""
    out = []
    for done, name in enumerate(MODELS, 1):
        try:
            out.append(evaluate(points, name, g_m_s2, lever_difference_m))
        except CalibrationError:
            pass  # this model needs more points than there are: the others are still ranked
        if progress is not None:
            progress(done, len(MODELS))
    if not out:
        raise CalibrationError("no calibration model can be fitted to these points (too few loaded points)")
    return admissibility(out, JOINT_AXIS_FLOOR_FRACTION * points.gain_scale_nm())


def admissibility(evaluations: list[Evaluation], floor_nm: float) -> list[Evaluation]:
    """Mark the joint models whose A3/A5 split is not borne out by held-out configurations as inadmissible
    (``floor_nm``: a per-axis held-out RMS below it counts as this much, :data:`JOINT_AXIS_FLOOR_FRACTION`).

    On points where M_A3 and M_A5 rise together (a mass stack) a joint fit can move any part of the correction
    from one axis to the other without changing eq. 21's mass there; the wrong split shows as soon as a DuT's A3/A5
    torque ratio differs. It also shows in the held-out corrected torques per axis, which then miss the expected
    torques (eq. 17/18) by much more than a per-axis model's do.
    """
    axis = [e for e in evaluations if not e.joint]
    if not axis:
        return [replace(e, admissible=False, note="no per-axis model to check the A3/A5 split against")
                if e.joint else e for e in evaluations]
    best = np.min([e.axis_rms_nm for e in axis], axis=0)
    out = []
    for e in evaluations:
        if not e.joint:
            out.append(e)
            continue
        # (the lever-group fold cannot judge the split: without the torque points no joint fit can find it)
        bad = [f"{ax} held-out {v:.1f} Nm vs per-axis {b:.1f} Nm" for ax, v, b in
               zip(("A3", "A5"), e.axis_rms_nm, best, strict=True)
               if v > JOINT_AXIS_FACTOR * max(b, floor_nm)]
        out.append(replace(e, admissible=not bad, note="; ".join(bad)))
    return out


def selection_score(evaluations: list[Evaluation]) -> dict[str, float]:
    """Per method: held-out configuration mean |error| % + :data:`LEVER_WEIGHT` × lever-group mean |error| % (a
    model that cannot be validated on the lever group gets the worst lever figure of the others)."""
    levers = [e.lever_mean_abs_err_pct for e in evaluations if np.isfinite(e.lever_mean_abs_err_pct)]
    worst = max(levers, default=0.0)
    return {e.method: e.loo_mean_abs_err_pct + LEVER_WEIGHT * (e.lever_mean_abs_err_pct if np.isfinite(
        e.lever_mean_abs_err_pct) else worst) for e in evaluations}


def select_auto(evaluations: list[Evaluation]) -> Evaluation:
    """The admissible model with the lowest :func:`selection_score`. A joint model must beat the best per-axis model
    by more than :data:`PREFER_AXIS_MARGIN_PCT`; near-ties (< 0.01 %) go to fewer parameters."""
    score = selection_score(evaluations)
    pool = [e for e in evaluations if e.admissible] or list(evaluations)
    axis = [e for e in pool if not e.joint]
    joint = [e for e in pool if e.joint]
    best_axis = min((score[e.method] for e in axis), default=np.inf)
    best_joint = min((score[e.method] for e in joint), default=np.inf)
    group = joint if best_joint < best_axis - PREFER_AXIS_MARGIN_PCT else (axis or joint)
    best = min(score[e.method] for e in group)
    close = [e for e in group if score[e.method] <= best + 0.01]
    return min(close, key=lambda e: (e.n_params, score[e.method]))


def average_of(points: CalibrationPoints, evaluations: list[Evaluation]) -> Evaluation | None:
    """The equal-weight average of the admissible per-axis gain models whose selection score is within
    :data:`AVERAGE_FACTOR` of the best admissible per-axis model (averageable or not), as an :class:`Evaluation` (its
    held-out masses and residuals are the members' means: eq. 21 is linear in the corrected torques); None if fewer
    than two qualify. A model that is not a gain curve (``paper``, ``ratio-linear``) and clearly better than every
    gain curve leaves no members: the average is for near-equal models, not for outvoting a better one."""
    score = selection_score(evaluations)
    pool = [e for e in evaluations if e.method in AVERAGEABLE and e.admissible]
    if len(pool) < 2:
        return None
    best = min(score[e.method] for e in evaluations if e.admissible and not e.joint)
    members = [e for e in pool if score[e.method] <= AVERAGE_FACTOR * best]
    if len(members) < 2:
        return None
    method = AVERAGE_PREFIX + "+".join(e.method for e in members)
    ins = np.mean([e.in_sample_mass_kg for e in members], axis=0)
    loo = np.mean([e.loo_mass_kg for e in members], axis=0)
    lever = np.mean([e.lever_mass_kg for e in members], axis=0)
    held = np.isfinite(lever)
    k3 = {t for e in members for t in GAIN_TERMS[e.method][0]}
    k5 = {t for e in members for t in GAIN_TERMS[e.method][1]}
    return Evaluation(method, ins, loo, mean_abs_pct(points.mass_kg, ins), mean_abs_pct(points.mass_kg, loo),
                      float(np.max(np.abs(loo - points.mass_kg))), len(k3) + len(k5),
                      np.mean([e.heldout_residual_nm for e in members], axis=0), lever,
                      mean_abs_pct(points.mass_kg[held], lever[held]) if held.any() else np.nan)


def choose_auto(points: CalibrationPoints, evaluations: list[Evaluation]) -> Evaluation:
    """What ``--method auto`` uses: a joint model where :func:`select_auto` admits and prefers one, otherwise the
    average of the best per-axis gain models (:func:`average_of`), or the single best model if there is no average."""
    single = select_auto(evaluations)
    if single.joint:
        return single
    return average_of(points, evaluations) or single


def nested_loo_auto_mass_kg(points: CalibrationPoints, g_m_s2: float, lever_difference_m: float,
                            progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Honest out-of-sample figure of ``--method auto``: in each fold (one configuration held out) the model is
    *selected* on the remaining points only, then fitted there and used to predict the held-out configuration."""
    n = len(points)
    out = np.empty(n)
    for i in range(n):
        keep = np.arange(n) != i
        sub = points.subset(keep)
        chosen = choose_auto(sub, evaluate_all(sub, g_m_s2, lever_difference_m))
        cal = fit(sub, chosen.method, g_m_s2, lever_difference_m)
        out[i] = float(cal.points_mass_kg(points, np.array([i]))[0])
        if progress is not None:
            progress(i + 1, n)
    return out


#: A calibration point whose declared mass the fit on the other points misses by more than this many times the
#: other points' robust held-out scatter is out of line (:func:`declared_mass_outliers`). On 50 undisturbed simulated
#: campaigns (16 seeds of Table 1's, 12 other robots, 6 with six torque rows, 6 without mounting scatter, 4 warm) the
#: largest is 6.9 (another robot's farthest torque row), on the paper's own Table 1 3.9. Typos at 104.65 kg (seed 3):
#: +36 kg 27, +100 kg 76, 10x 700; 228.5 -> 282.5 kg at a torque row 47. +10 kg (7.5) stays below it and in the
#: reproducibility term of U instead (u from 1.4 to 3.7 kg, the DuT still inside U).
DECLARED_MASS_Z = 12.0
#: The check needs at least this many loaded points (their scatter is a median).
MIN_POINTS_TO_CHECK_MASS = 5
#: The fits without the worst point are made only if its error exceeds this many times the scatter of all points'
#: (which the wrong mass widens; the -21 kg of two points of one load: 7.7 there, 16 judged without it).
PRESCREEN_MASS_Z = 4.0
#: Robust σ of normal values from their median absolute value.
MAD_TO_SIGMA = 1.4826
#: The scale is at least this fraction of the point's held-out mass: without per-mounting scatter the others agree to
#: 0.2 kg and a model's form error of 1 kg at a torque row would otherwise count 6 times that (simulated, no-mount).
MASS_SCALE_FLOOR_REL = 0.005


@dataclass(frozen=True)
class MassOutlier:
    """A point whose declared mass (kg) the others' fit does not bear out: ``heldout_kg`` is its held-out mass (the
    median over the admissible per-axis models fitted without it), ``z`` the miss in units of ``scale_kg``, the other
    points' held-out scatter without it."""

    index: int
    declared_kg: float
    heldout_kg: float
    z: float
    scale_kg: float

    def describe(self) -> str:
        return (f"point {self.index + 1} (mass_kg {self.declared_kg:g} kg): the fit on the other points weighs its "
                f"torques at {self.heldout_kg:.2f} kg ({self.heldout_kg - self.declared_kg:+.2f} kg, {self.z:.0f} "
                f"times their own held-out scatter of {self.scale_kg:.2f} kg, limit {DECLARED_MASS_Z:g})")


def _heldout_error_kg(points: CalibrationPoints, evaluations: Sequence[Evaluation]) -> np.ndarray | None:
    """Each point's held-out mass error (kg), the median over the admissible per-axis models (none: None)."""
    axis = [e for e in evaluations if not e.joint and e.admissible]
    if not axis:
        return None
    with np.errstate(invalid="ignore"):
        return np.nanmedian(np.array([np.where(np.isfinite(e.loo_mass_kg), e.loo_mass_kg, np.nan) - points.mass_kg
                                      for e in axis]), axis=0)


def declared_mass_outliers(points: CalibrationPoints, evaluations: Sequence[Evaluation], g_m_s2: float,
                           lever_difference_m: float) -> list[MassOutlier]:
    """The loaded point whose declared mass is out of line with the rest of the campaign, if any: a typo in a
    manifest's ``mass_kg`` (10×, +100 kg), or two points of one load under different masses.

    Its held-out error (eq. 21 with K fitted on the other configurations, as the selection validates) is the median
    over the admissible per-axis models, so that no one model's extrapolation at the campaign's edge counts. The
    point with the largest is then judged against the others' held-out errors from fits *without it* (the same
    models' leave-one-out on the other points): a wrong mass moves every fit it is in, and in the first evaluation
    widens the scale it would be judged by. Scale: the robust σ (median) of those errors over the loaded points,
    at least :data:`MASS_SCALE_FLOOR_REL` of the point's held-out mass.
    Empty with fewer than :data:`MIN_POINTS_TO_CHECK_MASS` loaded points besides it."""
    loaded = np.asarray(points.mass_kg) > 0
    err = _heldout_error_kg(points, evaluations)
    if err is None or int(loaded.sum()) <= MIN_POINTS_TO_CHECK_MASS:
        return []
    score = np.where(loaded & np.isfinite(err), np.abs(err), -1.0)
    worst = int(score.argmax())
    if score[worst] < 0 or score[worst] <= PRESCREEN_MASS_Z * MAD_TO_SIGMA * float(np.nanmedian(score[loaded])):
        return []
    keep = np.arange(len(points)) != worst
    others = points.subset(keep)
    try:  # the same models' held-out masses, on the other points only
        with np.errstate(invalid="ignore"):
            rest = np.nanmedian(np.array([leave_one_out_mass_kg(others, e.method, g_m_s2, lever_difference_m)
                                          - others.mass_kg for e in evaluations if not e.joint and e.admissible]),
                                axis=0)
    except CalibrationError:
        return []
    heldout_kg = float(points.mass_kg[worst] + err[worst])
    scale = max(MAD_TO_SIGMA * float(np.nanmedian(np.abs(rest[loaded[keep]]))), MASS_SCALE_FLOOR_REL * abs(heldout_kg))
    if not np.isfinite(scale) or scale <= 0.0:
        return []
    z = abs(float(err[worst])) / scale
    if z <= DECLARED_MASS_Z:
        return []
    return [MassOutlier(worst, float(points.mass_kg[worst]), heldout_kg, z, scale)]
