"""The in-line mass of a DuT from its measurement loops (paper §2.4.7): pre-process every loop, eq. 16 double
average, bias normalisation with the calibration's M_0, the operating-point check of
:mod:`rgse_daemon.pipeline.envelope`, eq. 21, and the uncertainty budget of :mod:`rgse_daemon.pipeline.uncertainty`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import envelope as env_mod
from rgse_daemon.pipeline import integrity
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.calibration import Calibration
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K, ThermalDrift, combine_axes

#: Fewer valid samples per loop than this draws a warning.
MIN_SAMPLES_PER_LOOP = 100
#: An uncorrected thermal offset of the DuT beyond this (K) draws a warning.
THERMAL_NOTE_K = 1.0

#: One loop: (A3 torque samples Nm, A5 torque samples Nm, sample period s, name for messages).
LoopSamples = tuple[np.ndarray, np.ndarray, float, str]


@dataclass(frozen=True)
class InlineMass:
    gross_mass_kg: float
    mass_kg: float
    uncertainty: unc.MassUncertainty
    loop_mass_kg: np.ndarray
    torque_a3_nm: float
    torque_a5_nm: float
    samples_used: int
    samples_total: int
    warnings: list[str] = field(default_factory=list)
    method: str = ""
    """The model the mass comes from (another admissible one if the calibration's own is unusable at this DuT)."""
    operating_point: str = "inside"
    """``inside`` or ``outside`` the calibrated envelope (far outside is refused)."""
    loops_used: list[str] = field(default_factory=list)
    """The loops the mass rests on, by name."""
    loops_set_aside: list[integrity.SetAside] = field(default_factory=list)
    """The loops left out, each with its reason (:mod:`rgse_daemon.pipeline.integrity`)."""
    thermal_applied: dict[str, bool] = field(default_factory=dict)
    """Per axis, whether the campaign's thermal drift β was applied (empty: no temperatures or no β)."""
    thermal_notes: dict[str, str] = field(default_factory=dict)
    """Per axis, how the drift was treated, for the operator: β (± u, the span it was fitted on) applied over the
    DuT's offset, or why not and the bound U carries over it (empty: no temperatures or no β)."""


def slope_kg_per_nm(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float, h_nm: float = 1.0
                    ) -> tuple[float, float]:
    """∂m/∂M_A3 and ∂m/∂M_A5 of eq. 21 with this calibration at the working point (central differences)."""
    d3 = float(cal.mass_kg(torque_a3_nm + h_nm, torque_a5_nm) - cal.mass_kg(torque_a3_nm - h_nm, torque_a5_nm))
    d5 = float(cal.mass_kg(torque_a3_nm, torque_a5_nm + h_nm) - cal.mass_kg(torque_a3_nm, torque_a5_nm - h_nm))
    return d3 / (2 * h_nm), d5 / (2 * h_nm)


@dataclass(frozen=True)
class MassCalibration:
    """What eq. 21 and the U budget take from a calibration (CAL.json, read as
    :meth:`rgse_daemon.calfile.CalFile.mass_calibration`): the model, the bias M_0 per axis, and the campaign's
    records for U. ``alternatives``: the other admissible models (same points), for the model-form spread, with their
    own ``alternative_uncertainty`` (same order; None where a file has none). ``uncertainty``: the calibration's
    :class:`~rgse_daemon.pipeline.uncertainty.CalibrationUncertainty`; None (an older calibration file) gives the
    former budget with ``model_rms_rel``. ``envelope``: what the campaign covered. ``thermal``: the campaign's drift
    of the torque estimate with motor temperature. ``g_u_m_s2``: the standard uncertainty of the calibration's g."""

    cal: Calibration
    bias_a3_nm: float
    bias_a5_nm: float
    model_rms_rel: float = 0.0
    g_u_m_s2: float = 0.0
    alternatives: Sequence[Calibration] = ()
    uncertainty: unc.CalibrationUncertainty | None = None
    alternative_uncertainty: Sequence[unc.CalibrationUncertainty | None] = ()
    envelope: env_mod.Envelope | None = None
    thermal: ThermalDrift | None = None
    extrapolation_kg: float | None = None
    """How the calibration's held-out error grows with the distance to its configurations
    (:func:`extrapolation_slope_kg`, kg per unit distance); a DuT outside the envelope gets U widened by it times its
    distance (None or NaN: by the spread of the admissible models there)."""


def in_line_mass(loops: Sequence[LoopSamples], calibration: MassCalibration, pre: pp.Preprocessing, *,
                 fixture_mass_kg: float = 0.0, g_measurement_m_s2: float | None = None,
                 g_u_measurement_m_s2: float = 0.0, envelope_limit: float = env_mod.DEFAULT_LIMIT,
                 loop_temps_k: Sequence[tuple[float | None, float | None]] | None = None,
                 drift_prior_per_k: float = DRIFT_PRIOR_PER_K,
                 set_aside: Sequence[integrity.SetAside] = ()) -> InlineMass:
    """Mass of the DuT and its uncertainty from its loops (interfaces §1 ``rgse mass``) with ``calibration``
    (:class:`MassCalibration`).

    Far outside the calibration's envelope (beyond ``envelope_limit``) raises
    :class:`~rgse_daemon.pipeline.envelope.OperatingPointError`. With the calibration's ``thermal`` drift and
    ``loop_temps_k`` (A3, A5 per loop, K) every loop is brought to the campaign's temperature
    (:mod:`rgse_daemon.pipeline.thermal`) and U gets its ``thermal`` term; where β is not applied the loops stay
    uncorrected and the term bounds their drift (:meth:`ThermalDrift.drift_bound_per_k`, ``drift_prior_per_k`` its
    outer bound, 1/K). ``set_aside``: loops the caller left out before (a frozen torque channel,
    :func:`~rgse_daemon.pipeline.integrity.frozen_reason`), not among ``loops``; they count with the set-aside ones in
    the refusal and the result. An ``uncertainty`` (or an alternative's)
    from a file written before ``refit_basis`` whose model has a ``sat`` term draws a warning
    (:func:`stale_refits_warning`): its refits are in another basis.
    """
    c = calibration
    cal, bias_a3_nm, bias_a5_nm, thermal, envelope = c.cal, c.bias_a3_nm, c.bias_a5_nm, c.thermal, c.envelope
    uncertainty, alternatives, alternative_uncertainty = c.uncertainty, c.alternatives, c.alternative_uncertainty
    extrapolation_kg = c.extrapolation_kg
    warnings: list[str] = []
    temps = None
    if thermal is not None and loop_temps_k is not None and len(loop_temps_k) == len(loops) and all(
            t is not None and np.isfinite(t) for pair in loop_temps_k for t in pair):
        temps = np.asarray(loop_temps_k, float)
    elif thermal is not None:  # the calibration has β, but not every loop recorded its motor temperatures
        lacking = [name for j, (_, _, _, name) in enumerate(loops)
                   if loop_temps_k is None or j >= len(loop_temps_k)
                   or not all(t is not None and np.isfinite(t) for t in loop_temps_k[j])]
        warnings.append(f"thermal drift neither corrected nor bounded: loop(s) {', '.join(lacking)} recorded no A3/A5 "
                        f"motor temperature (Motortemperatur), so the campaign's β (A3 "
                        f"{100 * thermal.coeff_per_k['A3']:+.3f}, A5 {100 * thermal.coeff_per_k['A5']:+.3f} %/K) can "
                        f"be applied to none, and U does not carry the drift; record the motor temperatures with the "
                        f"torques")
    # missing samples: a sample lacking in either torque channel is missing in both; too big a gap sets the loop aside
    gapped: list[integrity.SetAside] = list(set_aside)
    kept: list[int] = []
    clean: list[tuple[np.ndarray, np.ndarray, float, str]] = []
    for j, (a3, a5, period_s, name) in enumerate(loops):
        a3, a5 = np.asarray(a3, float), np.asarray(a5, float)
        ok = integrity.valid_mask(a3, a5)
        reason = integrity.gap_reason(ok, round(pre.settle_s / period_s))
        if reason is not None:
            gapped.append(integrity.SetAside(name, reason))
            continue
        kept.append(j)
        clean.append((np.where(ok, a3, np.nan), np.where(ok, a5, np.nan), period_s, name))
    loop_temps = None if temps is None else temps[kept]
    if not clean or (gapped and len(clean) < integrity.MIN_LOOPS):
        raise integrity.TooFewLoops(too_few(len(clean), gapped), [c[3] for c in clean], gapped)
    thermal_notes: dict[str, str] = {}
    drift_used = _drift_applied(thermal, loop_temps, warnings, drift_prior_per_k, thermal_notes)
    first = _loop_readings(clean, pre, thermal, loop_temps, drift_used, bias_a3_nm, bias_a5_nm)
    s3, s5 = slope_kg_per_nm(cal, first.m3, first.m5)
    allowance = None if loop_temps is None else combine_axes([
        (s3 * _loop_allowance_nm(thermal, "A3", first.raw3, loop_temps[:, 0], drift_used["A3"], drift_prior_per_k),
         drift_used["A3"]),
        (s5 * _loop_allowance_nm(thermal, "A5", first.raw5, loop_temps[:, 1], drift_used["A5"], drift_prior_per_k),
         drift_used["A5"])])
    skip = [round(pre.settle_s / p) for _, _, p, _ in clean]
    series = [(s3 * a3 + s5 * a5)[k:] for (a3, a5, _, _), k in zip(clean, skip, strict=True)]
    loop_mass0 = np.asarray(cal.mass_kg(first.n3, first.n5), float)
    se0 = np.hypot(s3 * first.se3, s5 * first.se5)
    screening = integrity.screen([c[3] for c in clean], series, loop_mass0, se0, allowance, integrity.MIN_LOOPS,
                                 "kg", gapped)
    if not screening.enough:
        raise integrity.TooFewLoops(too_few(len(screening.used), screening.set_aside),
                                    [clean[i][3] for i in screening.used], screening.set_aside)
    clean = [clean[i] for i in screening.used]
    if loop_temps is not None:
        loop_temps = loop_temps[screening.used]
    for s in screening.set_aside:
        warnings.append(f"loop {s.loop} set aside: {s.reason}")
    r = _loop_readings(clean, pre, thermal, loop_temps, drift_used, bias_a3_nm, bias_a5_nm)
    warnings += r.warnings
    n3, n5, m3, m5, se3, se5, raw3, raw5, used, total = (r.n3, r.n5, r.m3, r.m5, r.se3, r.se5, r.raw3, r.raw5,
                                                          r.used, r.total)
    temps = loop_temps
    where = "inside"
    if envelope is not None:
        check = env_mod.check(envelope, m3, m5, envelope_limit)
        if check.status == "refused":
            raise env_mod.OperatingPointError(f"measurement refused: the DuT lies far outside the calibrated "
                                              f"envelope: {check.detail}; calibrate with loads that cover it")
        if check.status == "outside":
            where = "outside"
            how = ("the spread of the admissible models there" if not _resolved(extrapolation_kg, envelope) else
                   f"what the calibration's own held-out configurations erred at that distance "
                   f"({extrapolation_kg * envelope.nearest(m3, m5):.3g} kg)")
            warnings.append(f"operating point outside the calibrated envelope ({check.detail}): U widened by {how}")
    if uncertainty is not None:
        stale = [c.method for c, u in [(cal, uncertainty), *zip(alternatives, alternative_uncertainty, strict=False)]
                 if unc.stale_refits(c, u)]
        if stale:
            warnings.append(stale_refits_warning(stale))
        cal, uncertainty, alternatives, note = _usable_model(cal, uncertainty, alternatives, alternative_uncertainty,
                                                             m3, m5)
        if note:
            warnings.append(note)
    loop_mass = np.asarray(cal.mass_kg(n3, n5), float)
    gross = float(cal.mass_kg(m3, m5))
    s3, s5 = slope_kg_per_nm(cal, m3, m5)
    loop_se = np.hypot(s3 * np.array(se3), s5 * np.array(se5))  # A3 and A5 noise independent
    if envelope is None:
        warnings += cal.out_of_range(m3, m5)
    if unc.loops_disagree(loop_mass, loop_se):
        warnings.append("loops disagree beyond their own spread (drift or a disturbed loop)")
    g_meas = cal.g_m_s2 if g_measurement_m_s2 is None else g_measurement_m_s2
    alt_mass = np.array([float(a.mass_kg(m3, m5)) for a in alternatives])
    u_loops = unc.loop_spread_kg(loop_mass, loop_se)
    u_g = unc.g_kg(gross, cal.g_m_s2, c.g_u_m_s2, g_meas, g_u_measurement_m_s2)
    u_thermal = None if temps is None else float(combine_axes([
        (s3 * _u_thermal_nm(thermal, "A3", raw3, temps[:, 0], drift_used["A3"], drift_prior_per_k), drift_used["A3"]),
        (s5 * _u_thermal_nm(thermal, "A5", raw5, temps[:, 1], drift_used["A5"], drift_prior_per_k), drift_used["A5"])],
        [_drift_direction(thermal, "A3", s3, raw3, temps[:, 0]),
         _drift_direction(thermal, "A5", s5, raw5, temps[:, 1])]))
    if uncertainty is None:  # a calibration file without held-out residuals: the former budget
        u = unc.MassUncertainty(
            u_loops_kg=u_loops,
            u_calibration_kg=unc.calibration_mc_kg(cal, m3, m5),
            u_model_kg=unc.model_kg(gross, c.model_rms_rel, alt_mass),
            u_reference_kg=unc.reference_mc_kg(cal, m3, m5),
            u_g_kg=u_g,
            u_thermal_kg=u_thermal,
        )
    else:
        if where == "outside" and _resolved(extrapolation_kg, envelope):
            assert envelope is not None and extrapolation_kg is not None
            spread = extrapolation_kg * envelope.nearest(m3, m5)  # out of sample: the held-out error at this distance
        elif where == "outside":
            spread = unc.model_spread_kg(gross, alt_mass)
        else:  # the alternatives' lack of fit at calibration-like points is in the reproducibility already
            spread = unc.excess_kg(unc.model_form_kg(gross, alt_mass), uncertainty.at_interior(
                lambda a3, a5: unc.model_form_kg(float(cal.mass_kg(a3, a5)),
                                                 np.array([float(a.mass_kg(a3, a5)) for a in alternatives]))))
        u = unc.MassUncertainty(
            u_loops_kg=u_loops,
            u_calibration_kg=uncertainty.u_calibration_kg(cal, m3, m5),
            u_model_kg=spread,
            u_reference_kg=uncertainty.u_reference_kg(cal, m3, m5),
            u_g_kg=u_g,
            u_reproducibility_kg=uncertainty.reproducibility.u_kg(cal.g_m_s2, cal.lever_difference_m),
            u_thermal_kg=u_thermal,
        )
    if gross - fixture_mass_kg < -u.expanded_kg:
        raise DataError(f"the DuT's mass comes out at {gross - fixture_mass_kg:.3f} ± {u.expanded_kg:.3f} kg, below "
                        f"zero: the gross load ({gross:.3f} kg) is less than the fixture's {fixture_mass_kg:.3f} kg "
                        f"(is the DuT mounted, the fixture mass right, each torque channel's sign as calibrated?)")
    return InlineMass(gross, gross - fixture_mass_kg, u, loop_mass, m3, m5, used, total, warnings, cal.method,
                      where, [c[3] for c in clean], list(screening.set_aside),
                      {} if temps is None else {ax: bool(v) for ax, v in drift_used.items()}, thermal_notes)


def extrapolation_slope_kg(envelope: env_mod.Envelope | None, heldout_residual_nm: np.ndarray | None,
                           g_m_s2: float, lever_difference_m: float) -> float | None:
    """:func:`~rgse_daemon.pipeline.uncertainty.extrapolation_kg_per_distance` of a calibration: its held-out per-axis
    residuals (n, 2; Nm, CAL.json ``fit.validation.heldout_residual_nm``) in kg by eq. 21 (∂m/∂(K·M)_A3 = 1/(g·Δr),
    A5 −1/(g·Δr)), the loaded configurations' distances to their nearest other one (``envelope.points_nm``, same
    order), the interior ones as the reproducibility's. None without points or residuals, or if they do not match."""
    if envelope is None or not envelope.points_nm or heldout_residual_nm is None:
        return None
    r = np.asarray(heldout_residual_nm, float)
    p = np.abs(np.asarray(envelope.points_nm, float))
    if r.ndim != 2 or r.shape != p.shape:
        return None
    loaded = p[:, 0] > 0
    interior = loaded & (p[:, 0] < p[:, 0].max()) & (p[:, 1] < p[:, 1].max())
    r_kg = (r[:, 0] - r[:, 1]) / abs(g_m_s2 * lever_difference_m)
    c = unc.extrapolation_kg_per_distance(np.where(loaded, r_kg, np.nan), envelope.neighbour_distances(), interior)
    return c if np.isfinite(c) else None


def _resolved(extrapolation_kg: float | None, envelope: env_mod.Envelope | None) -> bool:
    return envelope is not None and extrapolation_kg is not None and bool(np.isfinite(extrapolation_kg))


@dataclass(frozen=True)
class _Readings:
    raw3: np.ndarray
    raw5: np.ndarray
    n3: np.ndarray
    n5: np.ndarray
    m3: float
    m5: float
    se3: np.ndarray
    se5: np.ndarray
    used: int
    total: int
    warnings: list[str]


def _loop_readings(clean: Sequence[tuple[np.ndarray, np.ndarray, float, str]], pre: pp.Preprocessing,
                   thermal: ThermalDrift | None, temps: np.ndarray | None, drift_used: dict[str, bool],
                   bias_a3_nm: float, bias_a5_nm: float) -> _Readings:
    """Pre-process the loops (missing samples left out), bring each to the campaign's temperature where β is
    applied, normalise with M_0 and average (eq. 16)."""
    raw3, raw5, t3, t5, se3, se5, used, total, warnings = [], [], [], [], [], [], 0, 0, []
    for j, (a3, a5, period_s, name) in enumerate(clean):
        r3, r5 = pp.process_loop(a3, period_s, pre), pp.process_loop(a5, period_s, pre)
        raw3.append(r3.torque_nm)
        raw5.append(r5.torque_nm)
        t3.append(thermal.correct_nm("A3", r3.torque_nm, temps[j, 0]) if temps is not None and drift_used["A3"]
                  else r3.torque_nm)
        t5.append(thermal.correct_nm("A5", r5.torque_nm, temps[j, 1]) if temps is not None and drift_used["A5"]
                  else r5.torque_nm)
        se3.append(unc.batch_means_se(pp.kept_samples(a3, period_s, pre)))
        se5.append(unc.batch_means_se(pp.kept_samples(a5, period_s, pre)))
        n_used = min(r3.n_used, r5.n_used)
        used += n_used
        total += r3.n_total
        if n_used < MIN_SAMPLES_PER_LOOP:
            warnings.append(f"loop {name}: only {n_used} valid samples")
        missing = int(np.sum(~np.isfinite(a3)))
        if missing:
            warnings.append(f"loop {name}: {missing} of {a3.size} samples missing (no value, NaN or inf), the rest "
                            f"used")
    n3, n5 = pp.normalise(np.array(t3), bias_a3_nm), pp.normalise(np.array(t5), bias_a5_nm)
    return _Readings(np.array(raw3), np.array(raw5), n3, n5, pp.double_average_nm(n3), pp.double_average_nm(n5),
                     np.array(se3), np.array(se5), used, total, warnings)


def _drift_applied(thermal: ThermalDrift | None, temps: np.ndarray | None, warnings: list[str],
                   drift_prior_per_k: float, notes: dict[str, str] | None = None) -> dict[str, bool]:
    """Per axis, whether the campaign's β is applied to these loops (:meth:`ThermalDrift.not_applicable`); a
    warning for an axis left uncorrected over more than :data:`THERMAL_NOTE_K`. ``notes`` gets, per axis, how the
    drift was treated (:attr:`InlineMass.thermal_notes`)."""
    if thermal is None or temps is None:
        return {"A3": False, "A5": False}
    out = {}
    for i, ax in enumerate(("A3", "A5")):
        offset = float(np.mean(temps[:, i]) - thermal.reference_k[ax])
        why = thermal.not_applicable(ax, offset)
        out[ax] = why is None
        bound = thermal.drift_bound_per_k(ax, drift_prior_per_k)
        source = (f"the prior {100 * drift_prior_per_k:.3g} %/K" if bound >= drift_prior_per_k else
                  "the campaign's |β| + 2 u(β)")
        if notes is not None:
            notes[ax] = (f"campaign's β = {100 * thermal.coeff_per_k[ax]:+.3f} ± {100 * thermal.u_coeff_per_k[ax]:.3f}"
                         f" %/K (fitted over a {thermal.span_k[ax]:.2g} K span) applied over {offset:+.1f} K"
                         if why is None else
                         f"not corrected ({why}); U carries a drift of up to {100 * bound:.3g} %/K ({source}) over "
                         f"{offset:+.1f} K")
        if why is not None and abs(offset) > THERMAL_NOTE_K:
            warnings.append(f"thermal drift of {ax} not corrected: β = {100 * thermal.coeff_per_k[ax]:+.3f} ± "
                            f"{100 * thermal.u_coeff_per_k[ax]:.3f} %/K is not applied to this DuT ({why}); U "
                            f"carries a drift of up to {100 * bound:.3g} %/K ({source}) over the {offset:+.1f} K "
                            f"offset. Measure the DuT at the campaign's motor temperature "
                            f"({thermal.reference_k[ax]:.1f} K), or calibrate over a temperature span that covers it")
    return out


def _u_thermal_nm(thermal: ThermalDrift, axis: str, raw_nm: np.ndarray, temp_k: np.ndarray, applied: bool,
                  drift_prior_per_k: float) -> float:
    """The thermal term of one axis (Nm): β's uncertainty over the correction where applied, else the bound on the
    uncorrected drift (:meth:`ThermalDrift.drift_bound_per_k`, rectangular: standard uncertainty bound/√3); the axes
    combine by :func:`~rgse_daemon.pipeline.thermal.combine_axes`."""
    if applied:
        return thermal.u_correction_nm(axis, raw_nm, temp_k)
    lever = np.mean(np.asarray(raw_nm, float) * (np.asarray(temp_k, float) - thermal.reference_k[axis]))
    return float(abs(lever) * thermal.drift_bound_per_k(axis, drift_prior_per_k) / np.sqrt(3.0))


def _drift_direction(thermal: ThermalDrift, axis: str, slope_kg_per_nm: float, raw_nm: np.ndarray,
                     temp_k: np.ndarray) -> int:
    """The sign of ``axis``'s uncorrected drift in the mass (eq. 21's slope × β × the loops' mean M·(T − T_ref)) where
    the campaign resolves β's sign (:meth:`ThermalDrift.unresolved`), else 0 (either sign): for
    :func:`~rgse_daemon.pipeline.thermal.combine_axes`."""
    if thermal.unresolved(axis) is not None:
        return 0
    lever = np.mean(np.asarray(raw_nm, float) * (np.asarray(temp_k, float) - thermal.reference_k[axis]))
    return int(np.sign(slope_kg_per_nm * thermal.coeff_per_k[axis] * lever))


def _loop_allowance_nm(thermal: ThermalDrift, axis: str, raw_nm: np.ndarray, temp_k: np.ndarray, applied: bool,
                       drift_prior_per_k: float) -> np.ndarray:
    """Per loop, the standard deviation the thermal model leaves about the loops' mean temperature (Nm)."""
    dt = np.asarray(temp_k, float) - np.mean(temp_k)
    bound = thermal.drift_bound_per_k(axis, drift_prior_per_k)
    beta_u = thermal.u_coeff_per_k[axis] if applied else bound / np.sqrt(3.0)
    return np.abs(np.asarray(raw_nm, float) * dt) * beta_u


def too_few(n_left: int, aside: Sequence[integrity.SetAside]) -> str:
    text = "; ".join(f"loop {s.loop}: {s.reason}" for s in aside)
    return (f"measurement refused: {n_left} loop(s) left, fewer than the {integrity.MIN_LOOPS} a mass needs, after "
            f"setting aside {text}; re-mount the DuT and measure again")


def stale_refits_warning(methods: Sequence[str]) -> str:
    """The warning of a calibration file whose refits of ``methods`` (each with a ``sat`` term) were stored before
    ``fit.uncertainty.refit_basis`` (:func:`rgse_daemon.pipeline.uncertainty.stale_refits`)."""
    return (f"CAL.json fit.uncertainty was written before refit_basis: the refits of {', '.join(methods)} "
            f"(a sat term) are in another basis, so U's calibration term may be much too wide and the chosen model's "
            f"curve may have been replaced by an alternative's; run rgse calibrate on the campaign again to fix it")


def _usable_model(cal: Calibration, cu: unc.CalibrationUncertainty, alternatives: Sequence[Calibration],
                  alternative_cu: Sequence[unc.CalibrationUncertainty | None], torque_a3_nm: float,
                  torque_a5_nm: float) -> tuple[Calibration, unc.CalibrationUncertainty, list[Calibration], str]:
    """The calibration's own model if its curve uncertainty at the DuT is usable, else the first admissible
    alternative whose is (the others stay alternatives); with a note for the result's warnings."""
    candidates = [(cal, cu)] + [(a, c) for a, c in zip(alternatives, alternative_cu, strict=False) if c is not None]
    for i, (c, u) in enumerate(candidates):
        u_cal = u.curve_spread_kg(c, torque_a3_nm, torque_a5_nm)
        if not unc.unusable(u_cal, u.reproducibility.u_kg(c.g_m_s2, c.lever_difference_m)):
            if i == 0:
                return cal, cu, list(alternatives), ""
            rest = [a for a in [cal, *alternatives] if a is not c]
            return c, u, rest, (f"model {cal.method}'s prediction uncertainty at this DuT is unusable; "
                                f"the admissible model {c.method} gives the mass")
    return cal, cu, list(alternatives), (f"no calibration model has a usable prediction uncertainty at this DuT "
                                         f"({cal.method} kept, its U is wide)")
