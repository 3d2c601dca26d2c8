"""The calibration of a campaign: read its loops, pre-process and average them (eq. 16), fit and describe K.

One code path for ``rgse calibrate`` and the daemon's calibration campaign, so a stored calibration is always
reproducible from its campaign directory."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon.analysis import cog as cog_analysis
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import (
    Manifest,
    Setup,
    check_one_period,
    load_manifest,
    loop_periods,
    pose_deg,
    read_loops,
    source_sha256,
    thermal_state_k,
)
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import integrity, selection
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import thermal as thermal_mod
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.calibration import CalibrationPoints
from rgse_daemon.pipeline.envelope import Envelope
from rgse_daemon.pipeline.thermal import ThermalDrift

#: Robot named in a calibration fitted from a bare points CSV (the paper's robot type; the CSV names none).
POINTS_ROBOT = "KR500R2830"


@dataclass(frozen=True)
class CampaignData:
    """A campaign's loops, read once: per point a list of (A3 loop, A5 loop, period) triples."""

    manifest: Manifest
    loops: list[list[tuple[np.ndarray, np.ndarray, float]]]
    files: list[Path]
    thermal_state_k: dict[str, float] | None = None
    """Mean A3/A5 motor temperature over every loop (K), when the traces recorded it."""
    loop_temps_k: list[list[tuple[float, float]]] | None = None
    """Per point, per loop: the A3 and A5 motor temperature (K); None when a trace did not record it."""
    period: list[tuple[str, float]] = dataclasses.field(default_factory=list)
    """The campaign's one sample period, as ``(trace 'name', s)`` of its first loop (:func:`check_one_period`)."""
    set_aside: list[tuple[int, integrity.SetAside]] = dataclasses.field(default_factory=list)
    """Loops left out by :func:`screen_campaign`: (1-based point, loop and reason); their files stay as they are."""
    axes_deg: dict[str, float] | None = None
    """The A3 and A5 positions the loops were recorded in (deg, :func:`~rgse_daemon.manifest.pose_deg`)."""


def load_campaign(directory: Path) -> CampaignData:
    man = load_manifest(directory)
    if not man.points:
        raise DataError(f"{man.path}: a calibration campaign needs [[point]] entries")
    if not any(p.kind == "zero" for p in man.points):
        raise DataError(f"{man.path}: a calibration campaign needs a 'zero' point (the M_0 bias)")
    loops = []
    every_loop = []
    temps = []
    for spec in man.points:
        point_loops = read_loops(directory, spec.traces)
        every_loop += point_loops
        loops.append([(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point_loops])
        temps.append([(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in point_loops])
    check_one_period(loop_periods(every_loop), man.path)
    files = [man.path, *sorted(p for p in Path(directory).iterdir() if p.suffix in (".dat", ".r64"))]
    state = thermal_state_k(every_loop)
    return CampaignData(man, loops, files, state, temps if state is not None else None,
                        loop_periods(every_loop[:1]), axes_deg=pose_deg(every_loop))


def screen_campaign(data: CampaignData, cfg: pp.Preprocessing,
                    minimum: int = integrity.MIN_LOOPS_PER_POINT,
                    drift_prior_per_k: float = thermal_mod.DRIFT_PRIOR_PER_K) -> CampaignData:
    """Set aside the loops of each point that miss too many samples, have a frozen torque channel, repeat a loop of
    the campaign, hold a step, or disagree with the point's other loops (:mod:`rgse_daemon.pipeline.integrity`, per
    axis in Nm; the thermal allowance is the prior bound on β, ``drift_prior_per_k`` (``measurement.drift_prior_per_k``,
    ``rgse calibrate --drift-prior``), over each loop's temperature difference, since β is fitted from these very
    loops); a sample missing in one torque channel is missing in both. DataError naming the point if it keeps fewer
    than ``minimum`` loops (or, when it had fewer, not all of them): one bad loop never fails the campaign while its
    point keeps enough."""
    loops, temps, aside = [], [], []
    names = [spec.traces for spec in data.manifest.points]
    repeats = integrity.Repeats()  # a loop repeating another, of any point
    for i, point_loops in enumerate(data.loops):
        point_temps = None if data.loop_temps_k is None else data.loop_temps_k[i]
        gapped, clean, kept = [], [], []
        for j, (a3, a5, dt) in enumerate(point_loops):
            ok = integrity.valid_mask(a3, a5)
            skip = round(cfg.settle_s / dt)
            reason = (integrity.gap_reason(ok, skip) or integrity.frozen_reason((("A3", a3), ("A5", a5)), skip)
                      or repeats.reason(names[i][j], a3, a5))
            if reason is not None:
                gapped.append(integrity.SetAside(names[i][j], reason))
                continue
            kept.append(j)
            clean.append((np.where(ok, a3, np.nan), np.where(ok, a5, np.nan), dt))
        used = list(range(len(clean)))
        found = list(gapped)
        for ax in (0, 1):
            if len(used) < 1:
                break
            series = [clean[k][ax][round(cfg.settle_s / clean[k][2]):] for k in used]
            values = np.array([pp.process_loop(clean[k][ax], clean[k][2], cfg).torque_nm for k in used])
            se = np.array([unc.batch_means_se(pp.kept_samples(clean[k][ax], clean[k][2], cfg)) for k in used])
            allowance = None
            if point_temps is not None:
                t = np.array([point_temps[kept[k]][ax] for k in used], float)
                allowance = np.abs(values * (t - t.mean())) * drift_prior_per_k / np.sqrt(3.0)
            sc = integrity.screen([names[i][kept[k]] for k in used], series, values, se, allowance, minimum,
                                  f"Nm ({'A3' if ax == 0 else 'A5'})")
            found += sc.set_aside
            used = [used[k] for k in sc.used]
        need = min(minimum, len(point_loops))
        if len(used) < need:
            reasons = "; ".join(f"loop {a.loop}: {a.reason}" for a in found)
            raise DataError(f"{data.manifest.path}: calibration point {i + 1} keeps {len(used)} of "
                            f"{len(point_loops)} loops, fewer than the {need} it needs, after setting aside {reasons}; "
                            f"measure the point again")
        aside += [(i + 1, a) for a in found]
        loops.append([clean[k] for k in used])
        if point_temps is not None:
            temps.append([point_temps[kept[k]] for k in used])
    return dataclasses.replace(data, loops=loops, loop_temps_k=temps if data.loop_temps_k is not None else None,
                               set_aside=aside)


def campaign_period_s(data: CampaignData) -> float | None:
    """The campaign's one sample period (s; :func:`check_one_period` made it one); None without loops."""
    return data.period[0][1] if data.period else None


def campaign_thermal(data: CampaignData, cfg: pp.Preprocessing) -> ThermalDrift | None:
    """The thermal drift of the torque estimate from the campaign's loops (:mod:`rgse_daemon.pipeline.thermal`);
    None when the traces carry no motor temperature or it does not vary within the points."""
    if data.loop_temps_k is None:
        return None
    readings = {"A3": [], "A5": []}
    temps = {"A3": [], "A5": []}
    for point_loops, point_temps in zip(data.loops, data.loop_temps_k, strict=True):
        readings["A3"].append(np.array([pp.process_loop(a3, dt, cfg).torque_nm for a3, _, dt in point_loops]))
        readings["A5"].append(np.array([pp.process_loop(a5, dt, cfg).torque_nm for _, a5, dt in point_loops]))
        temps["A3"].append(np.array([t3 for t3, _ in point_temps], float))
        temps["A5"].append(np.array([t5 for _, t5 in point_temps], float))
    try:
        return thermal_mod.fit(readings, temps)
    except DataError:
        return None


def campaign_points(data: CampaignData, cfg: pp.Preprocessing) -> tuple[CalibrationPoints, float, float]:
    """Pre-process every loop, average (eq. 16), remove the zero-load bias M_0; returns points and biases."""
    raw3, raw5 = [], []
    for point_loops in data.loops:
        raw3.append(pp.double_average_nm([pp.process_loop(a3, dt, cfg).torque_nm for a3, _, dt in point_loops]))
        raw5.append(pp.double_average_nm([pp.process_loop(a5, dt, cfg).torque_nm for _, a5, dt in point_loops]))
    return points_from_raw(data.manifest, np.array(raw3), np.array(raw5))


def points_from_raw(man: Manifest, raw3: np.ndarray, raw5: np.ndarray) -> tuple[CalibrationPoints, float, float]:
    kinds = np.array([p.kind for p in man.points])
    zero = kinds == "zero"
    bias3, bias5 = float(raw3[zero].mean()), float(raw5[zero].mean())
    g = man.setup.g_m_s2
    mass = np.array([p.mass_kg for p in man.points])
    e3 = g * mass * np.array([p.lever_a3_m for p in man.points])  # expected normalised torque g·m·lever
    e5 = g * mass * np.array([p.lever_a5_m for p in man.points])
    # the measured torque carries the sign of the axis direction; K (negative then) absorbs it
    n3, n5 = pp.normalise(raw3, bias3), pp.normalise(raw5, bias5)
    var = np.array([p.mass_var_kg2(man.setup.body_mass_u_kg) for p in man.points])
    cov = cal_mod.reference_mass_covariance(var, nested=man.setup.reference_correlation == "nested")
    try:
        return CalibrationPoints(kinds, mass, n3, n5, e3, e5, cov), bias3, bias5
    except DataError as exc:  # a point's declared mass or levers: name the manifest they are in
        raise DataError(f"{man.path}: {exc}") from exc


def fit_and_describe(points: CalibrationPoints, method: str, g: float, dr: float):
    """Evaluate every model (in-sample and LOO), pick ``method`` (or the auto choice) and fit it on all points."""
    evaluations = selection.evaluate_all(points, g, dr)
    if method == "auto":
        chosen = selection.choose_auto(points, evaluations)
    else:
        if not cal_mod.known_method(method):
            raise DataError(f"unknown calibration method {method!r}; use auto or one of {', '.join(cal_mod.MODELS)}")
        found = [e for e in evaluations if e.method == method]
        chosen = found[0] if found else selection.evaluate(points, method, g, dr)
    cal = cal_mod.fit(points, chosen.method, g, dr)
    cov_ref = cal_mod.reference_mass_param_covariance(points, chosen.method, g, dr)
    cal.covariance = cal.covariance + cov_ref
    cal.covariance_reference = cov_ref
    return cal, chosen, evaluations


#: The stand-in torques of :func:`check_planned`: the expected torques through a smooth gain of a few per cent
#: (K = 1 + 0.03 exp(-|M| / 1500 Nm), Table 1's K lies within 0.93..1.05), with a ±0.2 % alternating scatter so that
#: no fit is exact. Only the number, kinds and spread of the planned points then decide whether a method can be fitted.
STAND_IN_GAIN_AMPLITUDE = 0.03
STAND_IN_GAIN_SCALE_NM = 1500.0
STAND_IN_SCATTER = 0.002
#: A campaign whose loaded points' measured torques span less than this fraction of their expected torques' span, on
#: both axes, did not measure its loads (an empty flange, the wrong drive's channel): refused with that reason.
MIN_TORQUE_SPAN_FRACTION = 0.5


def check_planned(kinds: list[str], mass_kg: list[float], lever_a3_m: list[float], lever_a5_m: list[float],
                  method: str, g: float, dr: float) -> None:
    """Before a campaign moves the robot: can its planned points (``kind`` zero/mass/torque, mass, levers) be
    fitted with ``method`` at all? The same selection and fit as at its end (:func:`fit_and_describe`), on stand-in
    torques; a :class:`~rgse_daemon.errors.DataError` says why not (e.g. the model needs more loaded points)."""
    m = np.asarray(mass_kg, dtype=float)
    e3 = g * m * np.asarray(lever_a3_m, dtype=float)
    e5 = g * m * np.asarray(lever_a5_m, dtype=float)
    sign = np.where(np.arange(len(m)) % 2 == 0, 1.0, -1.0)

    def measured(expected: np.ndarray) -> np.ndarray:
        k = 1.0 + STAND_IN_GAIN_AMPLITUDE * np.exp(-np.abs(expected) / STAND_IN_GAIN_SCALE_NM)
        return expected / k * (1.0 + STAND_IN_SCATTER * sign)

    points = CalibrationPoints(np.asarray(kinds), m, measured(e3), measured(e5), e3, e5)
    fit_and_describe(points, method, g, dr)


def check_torques_follow_loads(points: CalibrationPoints) -> None:
    """Refuse a campaign whose measured torques do not rise with its loads (see :data:`MIN_TORQUE_SPAN_FRACTION`):
    every model would fail on it with a message that names a symptom of the fit, not the cause."""
    loaded = points.mass_kg > 0
    if loaded.sum() < 2:
        return
    spans = []
    for axis, measured, expected in (("A3", points.torque_a3_nm, points.expected_a3_nm),
                                     ("A5", points.torque_a5_nm, points.expected_a5_nm)):
        want = float(np.ptp(np.abs(expected[loaded])))
        got = float(np.ptp(np.abs(measured[loaded])))
        if want <= 0.0 or got >= MIN_TORQUE_SPAN_FRACTION * want:
            return
        spans.append(f"{axis} {got:.1f} Nm where the loads' expected torques span {want:.1f} Nm")
    raise cal_mod.CalibrationError(
        "the measured torques do not follow the calibration loads (" + "; ".join(spans) + "): were the loads "
        "mounted when each point was confirmed, and are these the payload axes' drives?")


def check_declared_masses(points: CalibrationPoints, evaluations: list[selection.Evaluation], g: float,
                          dr: float) -> None:
    """Refuse a campaign with a point whose declared mass the others do not bear out
    (:func:`~rgse_daemon.pipeline.selection.declared_mass_outliers`): fitted as it is, the typo became a calibration
    whose reproducibility term made every U tens of kg wide (a +100 kg typo: U 70 kg, status ok) or that no
    measurement could use (10×: its alternatives' uncertainty not finite), and either said nothing of the cause."""
    out = selection.declared_mass_outliers(points, evaluations, g, dr)
    if out:
        raise cal_mod.CalibrationError(
            "calibration refused: " + "; ".join(o.describe() for o in out) + ": is its mass_kg a typo, or are these "
            "another load's traces? Correct the manifest (or the points CSV) or measure the point again")


def plausible_alternatives(points: CalibrationPoints, chosen: selection.Evaluation,
                           evaluations: list[selection.Evaluation], g: float, dr: float
                           ) -> tuple[calfile.Alternative, ...]:
    """The other admissible models whose held-out error is within ``PLAUSIBLE_LOO_FACTOR`` of the chosen one's,
    fitted on all points, each with its own uncertainty data (CAL.json ``fit.alternatives``: the model-form term,
    and the fallback where the chosen model's U is unusable)."""
    limit = unc.PLAUSIBLE_LOO_FACTOR * chosen.loo_mean_abs_err_pct
    return tuple(calfile.Alternative(_as_alternative(cal_mod.fit(points, e.method, g, dr)), e.loo_mean_abs_err_pct,
                                     unc.calibration_uncertainty(points, e.method, g, dr, e.heldout_residual_nm))
                 for e in evaluations
                 if e.method != chosen.method and e.admissible and e.loo_mean_abs_err_pct <= limit)


def _as_alternative(fitted: cal_mod.Calibration) -> cal_mod.Calibration:
    """An alternative as CAL.json records it: its models only (no covariance of its own)."""
    return dataclasses.replace(fitted, covariance=np.zeros((0, 0)), r2={}, covariance_reference=None)


def validation_record(points: CalibrationPoints, chosen: selection.Evaluation, nested_pct: float | None
                      ) -> calfile.Validation:
    """CAL.json ``fit.validation``: the scheme, the chosen model's held-out per-axis residuals, the nested figure."""
    rms = chosen.axis_rms_nm
    return calfile.Validation(
        selection.VALIDATION_SCHEME, {"A3": float(rms[0]), "A5": float(rms[1])},
        {"A3": chosen.heldout_residual_nm[:, 0].tolist(), "A5": chosen.heldout_residual_nm[:, 1].tolist()},
        None if not np.isfinite(chosen.lever_mean_abs_err_pct) else chosen.lever_mean_abs_err_pct, nested_pct)


@dataclass(frozen=True)
class CampaignRecords:
    """What a campaign's loops tell beside its points, recorded in CAL.json: ``drift`` (``fit.thermal``, removed
    from the DuT's loops at measurement), ``sample_period_s`` (``fit.sample_period_s``, compared with the DuT's; None
    for a points CSV), ``set_aside`` (``fit.set_aside``: (1-based point, loop and reason)) and the drift prior the
    screen that set them aside allowed (``fit.screening_drift_prior_per_k``, 1/K; None: nothing screened)."""

    drift: ThermalDrift | None = None
    sample_period_s: float | None = None
    set_aside: Sequence[tuple[int, integrity.SetAside]] = ()
    screening_drift_prior_per_k: float | None = None


def calibrate(points: CalibrationPoints, method: str, setup: Setup, *, pre: pp.Preprocessing | None,
              bias: calfile.Bias, provenance: calfile.Provenance, where: Path,
              records: CampaignRecords = CampaignRecords(), nested: bool = True
              ) -> tuple[calfile.CalFile, dict[str, Any]]:
    """Fit and describe a calibration: (CAL.json, the ``--json`` summary). One code path for the CLI and the
    daemon's campaign, so a stored calibration is always reproducible from its campaign directory. ``setup``: the
    robot, g (and its u) and Δr. ``nested``: also the nested held-out figure of ``auto`` (selection repeated inside
    every fold; seconds)."""
    g, dr, drift, set_aside = setup.g_m_s2, setup.lever_difference_m, records.drift, records.set_aside
    check_torques_follow_loads(points)
    try:
        cal, chosen, evaluations = fit_and_describe(points, method, g, dr)
        check_declared_masses(points, evaluations, g, dr)
        nested_pct = (cal_mod.mean_abs_pct(points.mass_kg, selection.nested_loo_auto_mass_kg(points, g, dr))
                      if nested else None)
        cu = unc.calibration_uncertainty(points, chosen.method, g, dr, chosen.heldout_residual_nm)
    except DataError as exc:
        raise DataError(f"{where}: {exc}") from exc
    validation = validation_record(points, chosen, nested_pct)
    doc = calfile.sealed(calfile.CalFile(
        robot=setup.robot, calibration=cal, bias=bias, provenance=provenance, preprocessing=pre,
        g_u_m_s2=float(setup.g_u_m_s2),
        fit=calfile.Fit(in_sample_mean_abs_err_pct=chosen.in_sample_mean_abs_err_pct,
                        loo_mean_abs_err_pct=chosen.loo_mean_abs_err_pct, loo_max_abs_err_kg=chosen.loo_max_abs_err_kg,
                        sample_period_s=records.sample_period_s, n_points=len(points),
                        loo_residual_rms_rel=loo_rms_rel(points, chosen), validation=validation, uncertainty=cu,
                        envelope=Envelope.from_torques(points.torque_a3_nm, points.torque_a5_nm),
                        alternatives=plausible_alternatives(points, chosen, evaluations, g, dr), thermal=drift,
                        set_aside=tuple(calfile.SetAsideLoop(p, a.loop, a.reason) for p, a in set_aside),
                        screening_drift_prior_per_k=records.screening_drift_prior_per_k)))
    summary = {
        "calibration_id": doc.calibration_id,
        "method": cal.method,
        "in_sample_mean_abs_err_pct": chosen.in_sample_mean_abs_err_pct,
        "loo_mean_abs_err_pct": chosen.loo_mean_abs_err_pct,
        "loo_max_abs_err_kg": chosen.loo_max_abs_err_kg,
        "nested_mean_abs_err_pct": nested_pct,
        "heldout_axis_rms_nm": dict(validation.heldout_axis_rms_nm),
        "u_reproducibility_kg": cu.reproducibility.u_kg(g, dr),
        "points": len(points),
        "r2": cal.r2,
        "set_aside": [{"point": p, **a.to_dict()} for p, a in set_aside],
        "screening_drift_prior_per_k": records.screening_drift_prior_per_k,
        "thermal": None if drift is None else {
            ax: {"beta_per_k": drift.coeff_per_k[ax], "u_beta_per_k": drift.u_coeff_per_k[ax],
                 "span_k": drift.span_k[ax], "resolved": drift.unresolved(ax) is None,
                 "description": drift.describe(ax)} for ax in thermal_mod.AXES},
        "models": [{"method": e.method, "in_sample_mean_abs_err_pct": e.in_sample_mean_abs_err_pct,
                    "loo_mean_abs_err_pct": e.loo_mean_abs_err_pct, "loo_max_abs_err_kg": e.loo_max_abs_err_kg,
                    "lever_group_mean_abs_err_pct": (e.lever_mean_abs_err_pct
                                                     if np.isfinite(e.lever_mean_abs_err_pct) else None),
                    "joint": e.joint, "admissible": e.admissible, "note": e.note,
                    "n_params": e.n_params}
                   for e in evaluations + ([] if any(e.method == chosen.method for e in evaluations) else [chosen])],
    }
    return doc, summary


def parse_preprocessing(spec: str | None) -> pp.Preprocessing:
    """``--preprocessing``: ``paper`` (method F, the default) or ``key=value,...`` over the fields of
    :class:`~rgse_daemon.pipeline.preprocess.Preprocessing` (e.g. a row of ``rgse study --campaign``:
    ``crop_sigma=2,filter=gaussian,window=100,order=forward,location=huber``); unnamed fields keep method F's value.
    ``crop_sigma=none`` keeps every sample."""
    if spec is None or spec.strip().lower() == "paper":
        return pp.PAPER
    fields = {f.name: f.type for f in dataclasses.fields(pp.Preprocessing)}
    values: dict[str, Any] = {}
    for item in spec.split(","):
        key, sep, text = (part.strip() for part in item.partition("="))
        if not sep or key not in fields:
            raise DataError(f"--preprocessing {spec!r}: {item.strip()!r} is not KEY=VALUE with KEY one of "
                            f"{', '.join(fields)}")
        if key in values:
            raise DataError(f"--preprocessing {spec!r}: {key} given twice")
        try:
            if key == "crop_sigma":
                values[key] = None if text.lower() == "none" else float(text)
            elif key == "window":
                values[key] = int(text)
            elif key == "settle_s":
                values[key] = float(text)
            else:
                values[key] = text
        except ValueError:
            raise DataError(f"--preprocessing {spec!r}: {key}={text!r} is not a number") from None
    try:
        return dataclasses.replace(pp.PAPER, **values)
    except pp.PreprocessError as exc:
        raise DataError(f"--preprocessing {spec!r}: {exc}") from None


def fit_campaign(directory: Path, method: str, pre: pp.Preprocessing = pp.PAPER,
                 drift_prior_per_k: float = thermal_mod.DRIFT_PRIOR_PER_K) -> tuple[calfile.CalFile, dict[str, Any]]:
    """``rgse calibrate --campaign DIR [--preprocessing SPEC] [--drift-prior PER_K]`` without writing: (CAL.json,
    summary). ``drift_prior_per_k``: the screening's thermal allowance (:func:`screen_campaign`)."""
    data = screen_campaign(load_campaign(directory), pre, drift_prior_per_k=drift_prior_per_k)
    points, bias3, bias5 = campaign_points(data, pre)
    doc, summary = calibrate(points, method, data.manifest.setup, pre=pre, bias=calfile.Bias(bias3, bias5),
                             provenance=calfile.Provenance(source_sha256(data.files), data.thermal_state_k,
                                                           data.axes_deg),
                             where=directory, records=CampaignRecords(campaign_thermal(data, pre),
                                                                      campaign_period_s(data), data.set_aside,
                                                                      drift_prior_per_k))
    if data.manifest.torsional_points:
        # the CoG calibration (issue #14): bias per pose and K for A3..A6 from the torsional points
        tors = cog_analysis.torsional_calibration(Path(directory), data.manifest, pre, periods=data.period)
        doc = calfile.sealed(dataclasses.replace(doc, torsional=tors))
        summary["calibration_id"] = doc.calibration_id
        summary["torsional"] = {f"A{ax}": {"model": g.model, "u_point_nm": g.u_point_nm,
                                           "heldout_rms_nm": tors.evaluations[ax]["models"][g.model]["heldout_rms_nm"]}
                                for ax, g in tors.gains.items()}
    return doc, summary


def loo_rms_rel(points: CalibrationPoints, ev: selection.Evaluation) -> float:
    """RMS of the relative LOO mass errors over the loaded points (the model term of the uncertainty)."""
    loaded = points.mass_kg > 0
    rel = (ev.loo_mass_kg[loaded] - points.mass_kg[loaded]) / points.mass_kg[loaded]
    return float(np.sqrt(np.mean(rel**2))) if rel.size else 0.0
