"""The typed model of ``CAL.json`` (interfaces §3): the schema's single source.

Every section of the file is a frozen dataclass here; :func:`parse` validates a document into a :class:`CalFile`
(errors name the field and the problem), and :meth:`CalFile.to_dict` writes it back in the same key order, so a file
written by the project reads back equal. Sections added over time are optional (None: the file predates them), so
every file the project has written still reads. A schema change is made here and nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rgse_daemon.config import MAX_DRIFT_PRIOR_PER_K
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline.axis_gain import AxisGain
from rgse_daemon.pipeline.calibration import AxisK, Calibration
from rgse_daemon.pipeline.envelope import Envelope
from rgse_daemon.pipeline.inline import MassCalibration, extrapolation_slope_kg
from rgse_daemon.pipeline.preprocess import Preprocessing
from rgse_daemon.pipeline.thermal import ThermalDrift
from rgse_daemon.pipeline.uncertainty import CalibrationUncertainty
from rgse_daemon.trace.config import PERIOD_MAX_S, PERIOD_MIN_S
from rgse_daemon.trace.names import plain_name

SCHEMA = 1
#: The payload axes of the mass calibration, in the file's order.
AXES = ("A3", "A5")
#: Plausible ranges of a calibration's g (m/s², anywhere on Earth: 9.78 at the equator, 9.83 at the poles) and of
#: the lever difference Δr between the A3 and A5 axes (m, any industrial robot's measurement pose).
G_RANGE_M_S2 = (9.7, 9.9)
LEVER_DIFFERENCE_RANGE_M = (0.05, 5.0)
TORSIONAL_VALIDATION = "leave-one-point-out (all poses of a point held out together)"


# ---------------------------------------------------------------------------------------------------------------------
# the sections
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Bias:
    """``bias_nm``: M_0 of A3 and A5 (Nm), the unloaded reading every torque is normalised with (eq. 13–14)."""

    a3_nm: float
    a5_nm: float


@dataclass(frozen=True)
class Validation:
    """``fit.validation``: the held-out scheme, the chosen model's per-axis held-out residuals, the nested figure."""

    scheme: str | dict[str, str]
    """The validation scheme, in words (per part of the selection in files since f14872f)."""
    heldout_axis_rms_nm: dict[str, float]
    heldout_residual_nm: dict[str, list[float]]
    lever_group_mean_abs_err_pct: float | None = None
    nested_mean_abs_err_pct: float | None = None


@dataclass(frozen=True)
class Alternative:
    """One entry of ``fit.alternatives``: another admissible model fitted on the same points (the model-form term of
    U, and the fallback where the chosen model's U is unusable), as a calibration over the chosen one's range."""

    calibration: Calibration
    loo_mean_abs_err_pct: float | None = None
    uncertainty: CalibrationUncertainty | None = None


@dataclass(frozen=True)
class SetAsideLoop:
    """One entry of ``fit.set_aside``: a campaign loop left out of its point (the file stays archived)."""

    point: int
    loop: str
    reason: str


@dataclass(frozen=True)
class Fit:
    """``fit``: the chosen model's figures and everything the measurement's U budget takes from the campaign.
    (``r2``, ``covariance`` and ``covariance_reference_mass`` are the :class:`Calibration`'s.)"""

    in_sample_mean_abs_err_pct: float
    loo_mean_abs_err_pct: float
    loo_max_abs_err_kg: float
    sample_period_s: float | None = None
    """The campaign's one KUKA Trace sample period (s); None for a points CSV and in files before it existed."""
    n_points: int | None = None
    loo_residual_rms_rel: float | None = None
    validation: Validation | None = None
    uncertainty: CalibrationUncertainty | None = None
    envelope: Envelope | None = None
    """The loads the campaign covered, with the nearest-calibrated-point check's points."""
    alternatives: tuple[Alternative, ...] | None = None
    thermal: ThermalDrift | None = None
    """The campaign's thermal drift β per axis (with u, span, whether it resolves)."""
    set_aside: tuple[SetAsideLoop, ...] | None = None
    """The integrity screen's loops left out of the campaign's points."""
    screening_drift_prior_per_k: float | None = None
    """The bound on the thermal drift |β| (1/K) the screen allowed a point's loops before its loop-to-loop check set
    one aside (``rgse calibrate --drift-prior``, the daemon's ``measurement.drift_prior_per_k``); None for a points
    CSV (nothing screened) and in files written before it was recorded (their screen allowed the default 0.3 %/K,
    or, from c85e141 on, whatever ``--drift-prior`` said)."""


@dataclass(frozen=True)
class Provenance:
    """Where a calibration comes from: the raw files' SHA-256 (``source_sha256``), the thermal state they were
    recorded in (``thermal_state_k``: mean A3/A5 motor temperature, K; None if the traces had none) and the pose."""

    source_sha256: dict[str, str] = field(default_factory=dict)
    thermal_state_k: dict[str, float] | None = None
    axes_deg: dict[str, float] | None = None
    """The A3 and A5 positions (deg, ``Istposition``) the campaign's loops were recorded in
    (``measurement_axes_deg``): the measurement pose eq. 21's levers hold for; None if the traces had none."""


@dataclass(frozen=True)
class TorsionalPose:
    """The bare reading (MPA only, eq. 13–14's bias idea) of one pose of the CoG scheme: A1..A6 in deg, the
    bias per axis and its standard uncertainty (Nm, NaN where the campaign did not trace the axis)."""

    name: str
    q_deg: tuple[float, ...]
    bias_nm: tuple[float, ...]
    u_bias_nm: tuple[float, ...]


@dataclass(frozen=True)
class Torsional:
    """``torsional``: the CoG calibration: the scheme, the bias per pose and the per-axis gain K (A3..A6)."""

    scheme: str
    poses: dict[str, TorsionalPose]
    gains: dict[int, AxisGain]
    evaluations: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Per axis, the candidate models' held-out record (``axes.A<n>.evaluation``, for the report)."""
    n_points: int | None = None
    thermal_state_k: dict[str, float] | None = None
    """Mean motor temperature per axis of the torsional points' traces (K)."""


@dataclass(frozen=True)
class CalFile:
    """One ``CAL.json``. ``calibration`` holds the method, the A3/A5 models, their covariance, the torque ranges,
    g and Δr; the rest are the file's sections. ``calibration_id`` is a hash of the content (:func:`content_id`)."""

    robot: str
    calibration: Calibration
    bias: Bias
    fit: Fit
    provenance: Provenance = field(default_factory=Provenance)
    preprocessing: Preprocessing | None = None
    g_u_m_s2: float | None = None
    """Standard uncertainty of g (m/s²); None in files before it existed (taken as 0)."""
    torsional: Torsional | None = None
    calibration_id: str = ""
    created_utc: str = ""
    schema: int = SCHEMA

    @property
    def method(self) -> str:
        return self.calibration.method

    def alternatives(self) -> list[Calibration]:
        return [a.calibration for a in self.fit.alternatives or ()]

    def mass_calibration(self) -> MassCalibration:
        """What :func:`rgse_daemon.pipeline.inline.in_line_mass` takes from this file."""
        alts = self.fit.alternatives or ()
        return MassCalibration(self.calibration, self.bias.a3_nm, self.bias.a5_nm,
                               model_rms_rel=self.fit.loo_residual_rms_rel or 0.0, g_u_m_s2=self.g_u_m_s2 or 0.0,
                               alternatives=tuple(a.calibration for a in alts), uncertainty=self.fit.uncertainty,
                               alternative_uncertainty=tuple(a.uncertainty for a in alts),
                               envelope=self.fit.envelope, thermal=self.fit.thermal,
                               extrapolation_kg=extrapolation_slope_kg(self.fit.envelope, self.heldout_residual_nm(),
                                                                       self.calibration.g_m_s2,
                                                                       self.calibration.lever_difference_m))

    def heldout_residual_nm(self) -> np.ndarray | None:
        """``fit.validation.heldout_residual_nm`` as (n, 2) A3/A5 (Nm); None if the file has none (U outside the
        envelope then falls back to the models' spread)."""
        v = self.fit.validation
        if v is None or not v.heldout_residual_nm.get("A3") or not v.heldout_residual_nm.get("A5"):
            return None
        r = np.array([v.heldout_residual_nm["A3"], v.heldout_residual_nm["A5"]], float)
        return r.T if r.ndim == 2 else None

    def to_dict(self) -> dict[str, Any]:
        """The JSON document, keys in the order the project has always written them."""
        cal = self.calibration
        doc: dict[str, Any] = {
            "schema": self.schema,
            "calibration_id": self.calibration_id,
            "created_utc": self.created_utc,
            "robot": self.robot,
            "method": cal.method,
            "preprocessing": None if self.preprocessing is None else self.preprocessing.to_dict(),
            "bias_nm": {"A3": float(self.bias.a3_nm), "A5": float(self.bias.a5_nm)},
            "models": cal.models_dict(),
            "lever_difference_m": cal.lever_difference_m,
            "g": cal.g_m_s2,
            **({} if self.g_u_m_s2 is None else {"g_u_m_s2": float(self.g_u_m_s2)}),
            "torque_range_nm": {"A3": list(cal.torque_range_a3_nm), "A5": list(cal.torque_range_a5_nm)},
            "fit": _fit_dict(self.fit, cal),
            "source_sha256": dict(self.provenance.source_sha256),
        }
        if self.provenance.thermal_state_k is not None:
            doc["thermal_state_k"] = {k: float(v) for k, v in self.provenance.thermal_state_k.items()}
        if self.provenance.axes_deg is not None:
            doc["measurement_axes_deg"] = {k: float(v) for k, v in self.provenance.axes_deg.items()}
        if self.torsional is not None:
            doc["torsional"] = torsional_dict(self.torsional)
        return doc


def _fit_dict(fit: Fit, cal: Calibration) -> dict[str, Any]:
    out: dict[str, Any] = {
        "in_sample_mean_abs_err_pct": fit.in_sample_mean_abs_err_pct,
        "loo_mean_abs_err_pct": fit.loo_mean_abs_err_pct,
        "loo_max_abs_err_kg": fit.loo_max_abs_err_kg,
        "r2": cal.r2,
        "covariance": np.asarray(cal.covariance, float).tolist(),
    }
    if cal.covariance_reference is not None:
        out["covariance_reference_mass"] = np.asarray(cal.covariance_reference, float).tolist()
    if fit.sample_period_s is not None:
        out["sample_period_s"] = float(fit.sample_period_s)
    if fit.n_points is not None:
        out["n_points"] = fit.n_points
    if fit.loo_residual_rms_rel is not None:
        out["loo_residual_rms_rel"] = fit.loo_residual_rms_rel
    if fit.validation is not None:
        v = fit.validation
        out["validation"] = {"scheme": v.scheme if isinstance(v.scheme, str) else dict(v.scheme),
                             "heldout_axis_rms_nm": dict(v.heldout_axis_rms_nm),
                             "heldout_residual_nm": {k: list(r) for k, r in v.heldout_residual_nm.items()},
                             "lever_group_mean_abs_err_pct": v.lever_group_mean_abs_err_pct,
                             "nested_mean_abs_err_pct": v.nested_mean_abs_err_pct}
    if fit.uncertainty is not None:
        out["uncertainty"] = fit.uncertainty.to_dict()
    if fit.envelope is not None:
        out["envelope"] = fit.envelope.to_dict()
    if fit.alternatives is not None:
        out["alternatives"] = [{"method": a.calibration.method,
                                **({} if a.loo_mean_abs_err_pct is None else
                                   {"loo_mean_abs_err_pct": a.loo_mean_abs_err_pct}),
                                "models": a.calibration.models_dict(),
                                **({} if a.uncertainty is None else {"uncertainty": a.uncertainty.to_dict()})}
                               for a in fit.alternatives]
    if fit.thermal is not None:
        out["thermal"] = fit.thermal.to_dict()
    if fit.set_aside is not None:
        out["set_aside"] = [{"point": s.point, "loop": s.loop, "reason": s.reason} for s in fit.set_aside]
    if fit.screening_drift_prior_per_k is not None:
        out["screening_drift_prior_per_k"] = float(fit.screening_drift_prior_per_k)
    return out


def torsional_dict(t: Torsional) -> dict[str, Any]:
    """The ``torsional`` section (JSON null for an axis the campaign did not trace)."""
    def js(values: tuple[float, ...]) -> list[float | None]:
        return [float(v) if math.isfinite(v) else None for v in values]
    out: dict[str, Any] = {
        "scheme": t.scheme,
        "poses": {p.name: {"q_deg": list(p.q_deg), "bias_nm": js(p.bias_nm), "u_bias_nm": js(p.u_bias_nm)}
                  for p in t.poses.values()},
        "axes": {f"A{ax}": {**g.to_dict(), "evaluation": t.evaluations.get(ax, {})} for ax, g in t.gains.items()},
        "validation": {"scheme": TORSIONAL_VALIDATION, "u_point_nm": {f"A{ax}": g.u_point_nm
                                                                      for ax, g in t.gains.items()}},
    }
    if t.n_points is not None:
        out["n_points"] = t.n_points
    if t.thermal_state_k is not None:
        out["thermal_state_k"] = dict(t.thermal_state_k)
    return out


# ---------------------------------------------------------------------------------------------------------------------
# reading: every field validated, every error naming it
# ---------------------------------------------------------------------------------------------------------------------
def _obj(v: Any, where: str) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise DataError(f"{where} must be a JSON object, got {type(v).__name__}")
    return v


def _need(d: dict[str, Any], key: str, where: str) -> Any:
    if key not in d:
        raise DataError(f"{where} lacks {key!r}")
    return d[key]


def _finite(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise DataError(f"{where} must be a finite number, got {v!r}")
    return float(v)


def _opt_finite(v: Any, where: str) -> float | None:
    return None if v is None else _finite(v, where)


def _int(v: Any, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise DataError(f"{where} must be a whole number, got {v!r}")
    return v


def _within(v: float, bounds: tuple[float, float], where: str, unit: str = "", shown: Any = None) -> float:
    """``v`` if within ``bounds``; else a DataError showing ``shown`` (the value as the file has it) or ``v``."""
    if not bounds[0] <= v <= bounds[1]:
        raise DataError(f"{where} = {v if shown is None else shown!r}{unit} is outside the plausible "
                        f"{bounds[0]:g}..{bounds[1]:g}{unit}")
    return v


def plausible_g(g_m_s2: float, what: str) -> float:
    """``g_m_s2`` if it is a gravity found on Earth (:data:`G_RANGE_M_S2`), else a DataError naming ``what``."""
    if not (math.isfinite(g_m_s2) and G_RANGE_M_S2[0] <= g_m_s2 <= G_RANGE_M_S2[1]):
        raise DataError(f"{what} = {g_m_s2!r} m/s² is outside the plausible {G_RANGE_M_S2[0]:g}..{G_RANGE_M_S2[1]:g}")
    return g_m_s2


def _axis_pair(d: Any, key: str, p: str) -> dict[str, Any]:
    v = _obj(d, f"{p}{key}")
    if not all(ax in v for ax in AXES):
        raise DataError(f"{p}{key} needs entries A3 and A5")
    return v


def _axis_model(d: Any, where: str) -> AxisK:
    if not isinstance(d, dict):
        raise DataError(f"{where} must be a JSON object, got {type(d).__name__}")
    try:
        k = AxisK.from_dict(d)
    except DataError as exc:
        raise DataError(f"{where}: {exc}") from None
    if np.ndim(k.params) != 1 or not k.params.size:
        raise DataError(f"{where}: its parameters must be a list of numbers")
    if not np.all(np.isfinite(k.params)):
        raise DataError(f"{where} has non-finite parameters")
    return k


def _matrix(v: Any, n: int, where: str) -> np.ndarray:
    try:
        m = np.asarray(v, float)
    except (TypeError, ValueError):
        raise DataError(f"{where} must be a finite {n}x{n} matrix") from None
    if m.shape != (n, n) or not np.all(np.isfinite(m)):
        raise DataError(f"{where} must be a finite {n}x{n} matrix")
    return m


def _from(parse_fn: Any, where: str, *args: Any) -> Any:
    """A section's own ``from_dict``; its error is prefixed with the file (a section of the wrong shape can fail in
    it with any of these: each is a DataError here)."""
    try:
        return parse_fn(*args)
    except DataError as exc:
        raise DataError(f"{where}: {exc}") from None
    except (TypeError, AttributeError, KeyError, ValueError) as exc:
        raise DataError(f"{where}: {getattr(parse_fn, '__qualname__', 'section')}: malformed: {exc!r}") from None


def parse(doc: Any, path: str = "CAL.json") -> CalFile:
    """Validate a CAL.json document into a :class:`CalFile`; a :class:`DataError` names ``path``, the field and the
    problem. The content's ``calibration_id`` is checked by :func:`rgse_daemon.calfile.read`, not here."""
    p = f"{path}: "
    if not isinstance(doc, dict):
        raise DataError(f"{path}: calibration file must hold a JSON object")
    if doc.get("schema") != SCHEMA:
        raise DataError(f"{path}: unsupported calibration schema {doc.get('schema')!r} (expected {SCHEMA})")
    if not isinstance(doc.get("robot"), str):
        raise DataError(f"{path}: calibration file lacks the robot it belongs to")
    for key in ("models", "fit", "bias_nm", "torque_range_nm", "method", "g", "lever_difference_m"):
        if key not in doc:
            raise DataError(f"{path}: calibration file lacks {key!r}")
    models = _axis_pair(doc["models"], "models", p)
    bias = _axis_pair(doc["bias_nm"], "bias_nm", p)
    ranges = _axis_pair(doc["torque_range_nm"], "torque_range_nm", p)
    fit = _obj(doc["fit"], f"{p}fit")
    k3, k5 = _axis_model(models["A3"], f"{p}models.A3"), _axis_model(models["A5"], f"{p}models.A5")
    n = len(k3.params) + len(k5.params)
    cov = _matrix(fit.get("covariance", []), n, f"{p}fit.covariance")
    cov_ref = (None if fit.get("covariance_reference_mass") is None else
               _matrix(fit["covariance_reference_mass"], n, f"{p}fit.covariance_reference_mass"))
    rng = []
    for axis in AXES:
        r = ranges[axis]
        if not (isinstance(r, list) and len(r) == 2):
            raise DataError(f"{p}torque_range_nm.{axis} must be [min, max]")
        rng.append((_finite(r[0], f"{p}torque_range_nm.{axis}"), _finite(r[1], f"{p}torque_range_nm.{axis}")))
    r2 = fit.get("r2") or {}
    if not isinstance(r2, dict):
        raise DataError(f"{p}fit.r2 must be an object of axis -> R²")
    g = plausible_g(_finite(doc["g"], f"{p}g"), f"{p}g")
    dr = _within(_finite(doc["lever_difference_m"], f"{p}lever_difference_m"), LEVER_DIFFERENCE_RANGE_M,
                 f"{p}lever_difference_m", shown=doc["lever_difference_m"])
    cal = Calibration(str(doc["method"]), k3, k5, cov, rng[0], rng[1], g, dr, dict(r2), cov_ref)
    pre = None if doc.get("preprocessing") is None else _from(Preprocessing.from_dict, path, doc["preprocessing"])
    sources = doc.get("source_sha256", {})
    if not isinstance(sources, dict):
        raise DataError(f"{path}: source_sha256 must be an object of file name -> SHA-256")
    for name in sources:
        plain_name(name, f"{path}: source_sha256")
    return CalFile(
        robot=doc["robot"], calibration=cal,
        bias=Bias(_finite(bias["A3"], f"{p}bias_nm.A3"), _finite(bias["A5"], f"{p}bias_nm.A5")),
        fit=_parse_fit(fit, cal, p),
        provenance=Provenance(dict(sources), _temps(doc.get("thermal_state_k"), f"{p}thermal_state_k"),
                              _axes(doc.get("measurement_axes_deg"), f"{p}measurement_axes_deg")),
        preprocessing=pre, g_u_m_s2=_opt_finite(doc.get("g_u_m_s2"), f"{p}g_u_m_s2"),
        torsional=parse_torsional(doc.get("torsional"), path),
        calibration_id=str(doc.get("calibration_id", "")), created_utc=str(doc.get("created_utc", "")),
        schema=SCHEMA)


def _temps(v: Any, where: str) -> dict[str, float] | None:
    if v is None:
        return None
    return {str(k): _finite(x, f"{where}.{k}") for k, x in _obj(v, where).items()}


def _axes(v: Any, where: str) -> dict[str, float] | None:
    """``measurement_axes_deg``: A3 and A5 in deg, each finite and within ±360."""
    if v is None:
        return None
    d = _obj(v, where)
    if set(d) != {"A3", "A5"}:
        raise DataError(f"{where} must hold exactly A3 and A5 (deg), got {sorted(d)}")
    out = {ax: _finite(d[ax], f"{where}.{ax}") for ax in ("A3", "A5")}
    for ax, deg in out.items():
        if abs(deg) > 360.0:
            raise DataError(f"{where}.{ax} = {deg!r} is not an axis position in deg (|q| <= 360)")
    return out


def _parse_fit(fit: dict[str, Any], cal: Calibration, p: str) -> Fit:
    w = f"{p}fit"
    period = _opt_finite(fit.get("sample_period_s"), f"{w}.sample_period_s")
    if period is not None:
        _within(period, (PERIOD_MIN_S, PERIOD_MAX_S), f"{w}.sample_period_s", " s", fit["sample_period_s"])
    unc = fit.get("uncertainty")
    return Fit(
        in_sample_mean_abs_err_pct=_finite(_need(fit, "in_sample_mean_abs_err_pct", w),
                                           f"{w}.in_sample_mean_abs_err_pct"),
        loo_mean_abs_err_pct=_finite(_need(fit, "loo_mean_abs_err_pct", w), f"{w}.loo_mean_abs_err_pct"),
        loo_max_abs_err_kg=_finite(_need(fit, "loo_max_abs_err_kg", w), f"{w}.loo_max_abs_err_kg"),
        sample_period_s=period,
        n_points=None if fit.get("n_points") is None else _int(fit["n_points"], f"{w}.n_points"),
        loo_residual_rms_rel=_opt_finite(fit.get("loo_residual_rms_rel"), f"{w}.loo_residual_rms_rel"),
        validation=None if fit.get("validation") is None else _validation(fit["validation"], f"{w}.validation"),
        uncertainty=None if unc is None else _from(CalibrationUncertainty.from_dict, p.rstrip(": "), unc,
                                                   len(cal.params), "fit.uncertainty"),
        envelope=None if fit.get("envelope") is None else _from(Envelope.from_dict, p.rstrip(": "), fit["envelope"]),
        alternatives=None if fit.get("alternatives") is None else _alternatives(fit["alternatives"], cal, p),
        thermal=None if fit.get("thermal") is None else _from(ThermalDrift.from_dict, p.rstrip(": "), fit["thermal"]),
        set_aside=None if fit.get("set_aside") is None else _set_aside(fit["set_aside"], f"{w}.set_aside"),
        screening_drift_prior_per_k=_drift_prior(fit.get("screening_drift_prior_per_k"),
                                                 f"{w}.screening_drift_prior_per_k"),
    )


def _drift_prior(v: Any, where: str) -> float | None:
    """A bound on |β| (1/K) as ``measurement.drift_prior_per_k`` takes it: in (0, MAX_DRIFT_PRIOR_PER_K]."""
    prior = _opt_finite(v, where)
    if prior is not None and not 0.0 < prior <= MAX_DRIFT_PRIOR_PER_K:
        raise DataError(f"{where} = {v!r} per K is not a bound on |β|: it must lie in (0, {MAX_DRIFT_PRIOR_PER_K:g}]")
    return prior


def _validation(v: Any, where: str) -> Validation:
    d = _obj(v, where)
    rms = _axis_pair(_need(d, "heldout_axis_rms_nm", where), "heldout_axis_rms_nm", f"{where}.")
    res = _axis_pair(d.get("heldout_residual_nm") or {ax: [] for ax in AXES}, "heldout_residual_nm", f"{where}.")
    residuals = {}
    for ax in AXES:
        if not isinstance(res[ax], list):
            raise DataError(f"{where}.heldout_residual_nm.{ax} must be a list of numbers")
        residuals[ax] = [_finite(x, f"{where}.heldout_residual_nm.{ax}") for x in res[ax]]
    scheme = d.get("scheme", "?")
    if not (isinstance(scheme, str) or (isinstance(scheme, dict) and all(isinstance(v, str)
                                                                          for v in scheme.values()))):
        raise DataError(f"{where}.scheme must be text or an object of texts, got {scheme!r}")
    return Validation(scheme if isinstance(scheme, str) else dict(scheme),
                      {ax: _finite(rms[ax], f"{where}.heldout_axis_rms_nm.{ax}") for ax in AXES}, residuals,
                      _opt_finite(d.get("lever_group_mean_abs_err_pct"), f"{where}.lever_group_mean_abs_err_pct"),
                      _opt_finite(d.get("nested_mean_abs_err_pct"), f"{where}.nested_mean_abs_err_pct"))


def _alternatives(v: Any, cal: Calibration, p: str) -> tuple[Alternative, ...]:
    if not isinstance(v, list):
        raise DataError(f"{p}fit.alternatives must be a list, got {type(v).__name__}")
    out = []
    for i, entry in enumerate(v):
        w = f"{p}fit.alternatives[{i}]"
        d = _obj(entry, w)
        models = _axis_pair(_need(d, "models", w), "models", f"{w}.")
        k3, k5 = _axis_model(models["A3"], f"{w}.models.A3"), _axis_model(models["A5"], f"{w}.models.A5")
        alt = Calibration(str(d.get("method", "?")), k3, k5, np.zeros((0, 0)), cal.torque_range_a3_nm,
                          cal.torque_range_a5_nm, cal.g_m_s2, cal.lever_difference_m)
        u = d.get("uncertainty")
        out.append(Alternative(alt, _opt_finite(d.get("loo_mean_abs_err_pct"), f"{w}.loo_mean_abs_err_pct"),
                               None if u is None else _from(CalibrationUncertainty.from_dict, p.rstrip(": "), u,
                                                            len(alt.params), f"fit.alternatives[{i}].uncertainty")))
    return tuple(out)


def _set_aside(v: Any, where: str) -> tuple[SetAsideLoop, ...]:
    if not isinstance(v, list):
        raise DataError(f"{where} must be a list, got {type(v).__name__}")
    out = []
    for i, entry in enumerate(v):
        d = _obj(entry, f"{where}[{i}]")
        loop, reason = _need(d, "loop", f"{where}[{i}]"), _need(d, "reason", f"{where}[{i}]")
        if not isinstance(loop, str) or not isinstance(reason, str):
            raise DataError(f"{where}[{i}]: loop and reason must be text")
        out.append(SetAsideLoop(_int(_need(d, "point", f"{where}[{i}]"), f"{where}[{i}].point"), loop, reason))
    return tuple(out)


def _six(v: Any, what: str, where: str) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) != 6:
        raise DataError(f"{where}: {what} must be a list of six numbers (A1..A6; null where not traced)")
    out = []
    for x in v:
        if x is None:
            out.append(float("nan"))
        elif isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise DataError(f"{where}: {what} holds {x!r}, not a finite number or null")
        else:
            out.append(float(x))
    return tuple(out)


def parse_torsional(sec: Any, where: str = "CAL.json") -> Torsional | None:
    """The ``torsional`` section, validated; None when the file has none (written before it existed, or from a
    campaign without torsional points)."""
    if sec is None:
        return None
    w = f"{where}: torsional"
    if not isinstance(sec, dict) or not isinstance(sec.get("poses"), dict) or not isinstance(sec.get("axes"), dict):
        raise DataError(f"{w}: must be an object with 'poses' and 'axes'")
    poses = {}
    for name, p in sec["poses"].items():
        if not isinstance(p, dict):
            raise DataError(f"{w}.poses.{name}: must be an object")
        q = _six(p.get("q_deg"), "q_deg", f"{w}.poses.{name}")
        if not all(math.isfinite(v) for v in q):
            raise DataError(f"{w}.poses.{name}: q_deg must be six finite angles")
        bias = _six(p.get("bias_nm"), "bias_nm", f"{w}.poses.{name}")
        u = _six(p.get("u_bias_nm"), "u_bias_nm", f"{w}.poses.{name}")
        poses[name] = TorsionalPose(name, q, bias, u)
    gains, evaluations = {}, {}
    for key, d in sec["axes"].items():
        if key not in ("A1", "A2", "A3", "A4", "A5", "A6") or not isinstance(d, dict):
            raise DataError(f"{w}.axes: {key!r} is not an axis A1..A6 with an object")
        try:
            gains[int(key[1])] = AxisGain.from_dict(int(key[1]), d)
        except DataError as exc:
            raise DataError(f"{where}: {exc}") from None
        if d.get("evaluation") is not None:
            evaluations[int(key[1])] = _obj(d["evaluation"], f"{w}.axes.{key}.evaluation")
    if not poses or not gains:
        raise DataError(f"{w}: no poses or no axis gains")
    n_points = sec.get("n_points")
    return Torsional(str(sec.get("scheme", "?")), poses, gains, evaluations,
                     None if n_points is None else _int(n_points, f"{w}.n_points"),
                     _temps(sec.get("thermal_state_k"), f"{w}.thermal_state_k"))

