"""The calibration file ``CAL.json`` (interfaces §3): write, read back into a :class:`Calibration`, robot check."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import inline
from rgse_daemon.pipeline.calibration import AxisK, Calibration
from rgse_daemon.pipeline.cog import AxisGain
from rgse_daemon.pipeline.envelope import Envelope
from rgse_daemon.pipeline.preprocess import Preprocessing
from rgse_daemon.pipeline.thermal import ThermalDrift
from rgse_daemon.pipeline.uncertainty import CalibrationUncertainty
from rgse_daemon.trace.config import PERIOD_MAX_S, PERIOD_MIN_S
from rgse_daemon.trace.names import plain_name

SCHEMA = 1


def build(cal: Calibration, *, robot: str, preprocessing: Preprocessing | None, bias_a3_nm: float,
          bias_a5_nm: float, in_sample_pct: float, loo_pct: float, loo_max_kg: float,
          source_sha256: dict[str, str], extra_fit: dict[str, Any] | None = None,
          g_u_m_s2: float = 0.0, thermal_state_k: dict[str, float] | None = None,
          sample_period_s: float | None = None) -> dict[str, Any]:
    """The CAL.json document of a fitted calibration; ``calibration_id`` is a hash of its content.
    ``thermal_state_k``: mean A3/A5 motor temperature of the campaign's traces (K), if they recorded it.
    ``sample_period_s``: the campaign's one KUKA Trace sample period (``fit.sample_period_s``); None for points that
    come averaged (a points CSV)."""
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "calibration_id": "",
        "created_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "robot": robot,
        "method": cal.method,
        "preprocessing": preprocessing.to_dict() if preprocessing else None,
        "bias_nm": {"A3": float(bias_a3_nm), "A5": float(bias_a5_nm)},
        "models": cal.models_dict(),
        "lever_difference_m": cal.lever_difference_m,
        "g": cal.g_m_s2,
        "g_u_m_s2": float(g_u_m_s2),
        "torque_range_nm": {"A3": list(cal.torque_range_a3_nm), "A5": list(cal.torque_range_a5_nm)},
        "fit": {
            "in_sample_mean_abs_err_pct": in_sample_pct,
            "loo_mean_abs_err_pct": loo_pct,
            "loo_max_abs_err_kg": loo_max_kg,
            "r2": cal.r2,
            "covariance": np.asarray(cal.covariance, float).tolist(),
            **({} if cal.covariance_reference is None else
               {"covariance_reference_mass": np.asarray(cal.covariance_reference, float).tolist()}),
            **({} if sample_period_s is None else {"sample_period_s": float(sample_period_s)}),
            **(extra_fit or {}),
        },
        "source_sha256": source_sha256,
    }
    if thermal_state_k is not None:
        doc["thermal_state_k"] = {k: float(v) for k, v in thermal_state_k.items()}
    return seal(doc)


def content_id(doc: dict[str, Any]) -> str:
    """A hash of the document's content: everything but the id and the creation time."""
    body = json.dumps({k: v for k, v in doc.items() if k not in ("calibration_id", "created_utc")}, sort_keys=True)
    return hashlib.sha256(body.encode()).hexdigest()[:16]


def seal(doc: dict[str, Any]) -> dict[str, Any]:
    """Set ``calibration_id`` to :func:`content_id`."""
    doc["calibration_id"] = content_id(doc)
    return doc


#: Plausible ranges of a calibration's g (m/s², anywhere on Earth: 9.78 at the equator, 9.83 at the poles) and of
#: the lever difference Δr between the A3 and A5 axes (m, any industrial robot's measurement pose).
G_RANGE_M_S2 = (9.7, 9.9)
LEVER_DIFFERENCE_RANGE_M = (0.05, 5.0)


def _within(v: float, bounds: tuple[float, float], what: str, path: Path) -> float:
    if not bounds[0] <= v <= bounds[1]:
        raise DataError(f"{path}: {what} = {v!r} is outside the plausible {bounds[0]:g}..{bounds[1]:g}")
    return v


def plausible_g(g_m_s2: float, what: str) -> float:
    """``g_m_s2`` if it is a gravity found on Earth (:data:`G_RANGE_M_S2`), else a DataError naming ``what``."""
    if not (math.isfinite(g_m_s2) and G_RANGE_M_S2[0] <= g_m_s2 <= G_RANGE_M_S2[1]):
        raise DataError(f"{what} = {g_m_s2!r} m/s² is outside the plausible {G_RANGE_M_S2[0]:g}..{G_RANGE_M_S2[1]:g}")
    return g_m_s2


def write(path: Path | str, doc: dict[str, Any]) -> None:
    path = Path(path)
    try:
        write_atomic(path, json.dumps(doc, indent=2) + "\n")
    except OSError as exc:
        raise DataError(f"{path}: cannot write calibration: {exc}") from exc


def _need(doc: dict[str, Any], key: str, path: Path) -> Any:
    if key not in doc:
        raise DataError(f"{path}: calibration file lacks {key!r}")
    return doc[key]


def _finite(v: Any, what: str, path: Path) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise DataError(f"{path}: {what} must be a finite number, got {v!r}")
    return float(v)


def read(path: Path | str) -> tuple[dict[str, Any], Calibration, Preprocessing | None]:
    """Read and validate CAL.json; returns the document, the calibration and its pre-processing."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: calibration file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable JSON calibration file: {exc}") from exc
    except RecursionError:  # the json module's answer to arrays nested thousands deep
        raise DataError(f"{path}: not a readable JSON calibration file: nested too deeply") from None
    if not isinstance(doc, dict):
        raise DataError(f"{path}: calibration file must hold a JSON object")
    if doc.get("schema") != SCHEMA:
        raise DataError(f"{path}: unsupported calibration schema {doc.get('schema')!r} (expected {SCHEMA})")
    if doc.get("calibration_id") != content_id(doc):
        raise DataError(f"{path}: the content does not match its calibration_id {doc.get('calibration_id')!r} "
                        f"(edited after it was fitted, or damaged): refit it with rgse calibrate")
    models = _need(doc, "models", path)
    fit = _need(doc, "fit", path)
    bias = _need(doc, "bias_nm", path)
    ranges = _need(doc, "torque_range_nm", path)
    if not all(isinstance(x, dict) and "A3" in x and "A5" in x for x in (models, bias, ranges)):
        raise DataError(f"{path}: models, bias_nm and torque_range_nm need entries A3 and A5")
    try:
        k3 = AxisK.from_dict(models["A3"])
        k5 = AxisK.from_dict(models["A5"])
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc
    n = len(k3.params) + len(k5.params)
    cov = np.asarray(fit.get("covariance", []), float) if isinstance(fit, dict) else np.empty(0)
    if cov.shape != (n, n) or not np.all(np.isfinite(cov)):
        raise DataError(f"{path}: fit.covariance must be a finite {n}x{n} matrix")
    cov_ref = None
    if fit.get("covariance_reference_mass") is not None:
        cov_ref = np.asarray(fit["covariance_reference_mass"], float)
        if cov_ref.shape != (n, n) or not np.all(np.isfinite(cov_ref)):
            raise DataError(f"{path}: fit.covariance_reference_mass must be a finite {n}x{n} matrix")
    for name, p in (("A3", k3.params), ("A5", k5.params)):
        if not np.all(np.isfinite(p)):
            raise DataError(f"{path}: model {name} has non-finite parameters")
    rng = []
    for axis in ("A3", "A5"):
        r = ranges[axis]
        if not (isinstance(r, list) and len(r) == 2):
            raise DataError(f"{path}: torque_range_nm.{axis} must be [min, max]")
        rng.append((_finite(r[0], f"torque_range_nm.{axis}", path), _finite(r[1], f"torque_range_nm.{axis}", path)))
        _finite(bias[axis], f"bias_nm.{axis}", path)
    cal = Calibration(str(_need(doc, "method", path)), k3, k5, cov, rng[0], rng[1],
                      plausible_g(_finite(_need(doc, "g", path), "g", path), f"{path}: g"),
                      _within(_finite(_need(doc, "lever_difference_m", path), "lever_difference_m", path),
                              LEVER_DIFFERENCE_RANGE_M, "lever_difference_m", path),
                      dict(fit.get("r2") or {}), cov_ref)
    pre = None
    if doc.get("preprocessing") is not None:
        try:
            pre = Preprocessing.from_dict(doc["preprocessing"])
        except (DataError, TypeError) as exc:
            raise DataError(f"{path}: {exc}") from exc
    if not isinstance(doc.get("robot"), str):
        raise DataError(f"{path}: calibration file lacks the robot it belongs to")
    sources = doc.get("source_sha256", {})
    if not isinstance(sources, dict):
        raise DataError(f"{path}: source_sha256 must be an object of file name -> SHA-256")
    for name in sources:
        plain_name(name, f"{path}: source_sha256")
    sample_period_s(path, doc)
    return doc, cal, pre


def sample_period_s(path: Path | str, doc: dict[str, Any]) -> float | None:
    """``fit.sample_period_s``: the KUKA Trace sample period the campaign was recorded at (s), validated; None in
    files written before it existed and in calibrations fitted from a points CSV (nothing to compare with)."""
    v = (doc.get("fit") or {}).get("sample_period_s")
    if v is None:
        return None
    period_s = _finite(v, "fit.sample_period_s", path)
    if not PERIOD_MIN_S <= period_s <= PERIOD_MAX_S:
        raise DataError(f"{path}: fit.sample_period_s = {v!r} s is outside the plausible {PERIOD_MIN_S:g}.."
                        f"{PERIOD_MAX_S:g} s of a KUKA trace")
    return period_s


def alternatives(path: Path | str, doc: dict[str, Any], cal: Calibration) -> list[Calibration]:
    """The plausible alternative models recorded in ``fit.alternatives`` (optional), as calibrations."""
    out = []
    for alt in (doc.get("fit") or {}).get("alternatives") or []:
        try:
            k3, k5 = AxisK.from_dict(alt["models"]["A3"]), AxisK.from_dict(alt["models"]["A5"])
        except (DataError, KeyError, TypeError) as exc:
            raise DataError(f"{path}: fit.alternatives: malformed entry: {exc}") from exc
        if not (np.all(np.isfinite(k3.params)) and np.all(np.isfinite(k5.params))):
            raise DataError(f"{path}: fit.alternatives: model {alt.get('method')!r} has non-finite parameters")
        out.append(Calibration(str(alt.get("method", "?")), k3, k5, np.zeros((0, 0)), cal.torque_range_a3_nm,
                               cal.torque_range_a5_nm, cal.g_m_s2, cal.lever_difference_m))
    return out


def uncertainty(path: Path | str, doc: dict[str, Any], cal: Calibration, where: str = "fit.uncertainty"
                ) -> CalibrationUncertainty | None:
    """``fit.uncertainty`` (held-out reproducibility, bootstrap refits); None in files written before it existed.
    ``where``: the record's place in the file, for the messages."""
    d = (doc.get("fit") or {}).get("uncertainty")
    if d is None:
        return None
    try:
        return CalibrationUncertainty.from_dict(d, len(cal.params), where)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc


def alternative_uncertainties(path: Path | str, doc: dict[str, Any], alts: list[Calibration]
                              ) -> list[CalibrationUncertainty | None]:
    """The ``uncertainty`` of every ``fit.alternatives`` entry, in the order of :func:`alternatives`."""
    out = []
    for i, (entry, alt) in enumerate(zip((doc.get("fit") or {}).get("alternatives") or [], alts, strict=True)):
        out.append(uncertainty(path, {"fit": {"uncertainty": entry.get("uncertainty")}}, alt,
                               f"fit.alternatives[{i}].uncertainty"))
    return out


def envelope(path: Path | str, doc: dict[str, Any]) -> Envelope | None:
    """``fit.envelope``: the loads the campaign covered; None in files written before it existed."""
    d = (doc.get("fit") or {}).get("envelope")
    if d is None:
        return None
    try:
        return Envelope.from_dict(d)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc


def thermal(path: Path | str, doc: dict[str, Any]) -> ThermalDrift | None:
    """``fit.thermal``: the campaign's thermal drift of the torque estimate; None in files without it."""
    d = (doc.get("fit") or {}).get("thermal")
    if d is None:
        return None
    try:
        return ThermalDrift.from_dict(d)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc


def uncertainty_inputs(path: Path | str, doc: dict[str, Any], cal: Calibration, alts: list[Calibration]
                       ) -> dict[str, Any]:
    """The keyword arguments of :func:`rgse_daemon.pipeline.inline.in_line_mass` that come from a calibration file:
    ``uncertainty``, ``alternative_uncertainty``, ``envelope``, ``thermal`` and ``extrapolation_kg`` (None / empty in
    older files)."""
    env = envelope(path, doc)
    return {"uncertainty": uncertainty(path, doc, cal),
            "alternative_uncertainty": alternative_uncertainties(path, doc, list(alts)),
            "envelope": env, "thermal": thermal(path, doc),
            "extrapolation_kg": inline.extrapolation_slope_kg(env, heldout_residual_nm(doc), cal.g_m_s2,
                                                              cal.lever_difference_m)}


def heldout_residual_nm(doc: dict[str, Any]) -> np.ndarray | None:
    """``fit.validation.heldout_residual_nm`` as (n, 2) A3/A5 (Nm); None if the file has none (or it is malformed:
    then U outside the envelope falls back to the models' spread)."""
    v = ((doc.get("fit") or {}).get("validation") or {}).get("heldout_residual_nm")
    try:
        r = np.array([v["A3"], v["A5"]], float).T
    except (KeyError, TypeError, ValueError):
        return None
    return r if r.ndim == 2 and r.shape[1] == 2 else None


def check_robot(path: Path | str, doc: dict[str, Any], robot: str) -> None:
    """A calibration is only ever used for the robot it names (interfaces §3)."""
    if doc.get("robot") != robot:
        raise DataError(f"{path}: calibration belongs to robot {doc.get('robot')!r}, the measurement to {robot!r}")


# ---------------------------------------------------------------------------------------------------------------------
# The optional torsional section: the CoG calibration (interfaces §3)
# ---------------------------------------------------------------------------------------------------------------------
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
    """CAL.json ``torsional``: the scheme, the bias per pose and the per-axis gain K (A3..A6)."""

    scheme: str
    poses: dict[str, TorsionalPose]
    gains: dict[int, AxisGain]


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


def torsional_section(scheme: str, poses: list[TorsionalPose], gains: dict[int, AxisGain],
                      evaluations: dict[int, dict], n_points: int) -> dict[str, Any]:
    """The ``torsional`` section of CAL.json (JSON null for an axis the campaign did not trace)."""
    def js(values: tuple[float, ...]) -> list[float | None]:
        return [float(v) if math.isfinite(v) else None for v in values]
    return {"scheme": scheme,
            "poses": {p.name: {"q_deg": list(p.q_deg), "bias_nm": js(p.bias_nm), "u_bias_nm": js(p.u_bias_nm)}
                      for p in poses},
            "axes": {f"A{ax}": {**g.to_dict(), "evaluation": evaluations.get(ax, {})} for ax, g in gains.items()},
            "validation": {"scheme": "leave-one-point-out (all poses of a point held out together)",
                           "u_point_nm": {f"A{ax}": g.u_point_nm for ax, g in gains.items()}},
            "n_points": n_points}


def torsional(doc: dict[str, Any], where: Path | str = "CAL.json") -> Torsional | None:
    """The CoG calibration of a CAL.json document, validated; None when the file has none (written before it
    existed, or from a campaign without torsional points)."""
    sec = doc.get("torsional")
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
    gains = {}
    for key, d in sec["axes"].items():
        if key not in ("A1", "A2", "A3", "A4", "A5", "A6") or not isinstance(d, dict):
            raise DataError(f"{w}.axes: {key!r} is not an axis A1..A6 with an object")
        try:
            gains[int(key[1])] = AxisGain.from_dict(int(key[1]), d)
        except DataError as exc:
            raise DataError(f"{where}: {exc}") from None
    if not poses or not gains:
        raise DataError(f"{w}: no poses or no axis gains")
    return Torsional(str(sec.get("scheme", "?")), poses, gains)
