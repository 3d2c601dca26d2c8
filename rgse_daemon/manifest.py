"""Campaign and measurement directories (interfaces §2): ``manifest.toml`` plus KUKA trace file sets → arrays.

This is the I/O side of the pipeline: it reads and validates, the numbers are computed in
:mod:`rgse_daemon.pipeline`. Every problem is a :class:`~rgse_daemon.errors.DataError` naming the file.
"""

from __future__ import annotations

import csv
import difflib
import hashlib
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon.errors import DataError
from rgse_daemon.pipeline.calibration import CalibrationPoints, reference_mass_covariance
from rgse_daemon.pipeline.cog import SCHEMES
from rgse_daemon.trace.config import PERIOD_MAX_S, PERIOD_MIN_S
from rgse_daemon.trace.diadem import read_trace_set
from rgse_daemon.trace.names import inside, plain_name

MODULE_A3 = "NextGenDrive#3"
MODULE_A5 = "NextGenDrive#5"
TORQUE_CHANNEL = "Istmoment"
TEMPERATURE_CHANNEL = "Motortemperatur"
#: The drive's actual axis position (deg): where the loop was recorded (:func:`pose_deg`).
POSITION_CHANNEL = "Istposition"
KINDS = ("zero", "mass", "torque")
#: Point kind of the CoG (torsional) calibration: a load of known mass and position measured in every pose of a
#: scheme (interfaces §2); kept apart from the mass calibration's points.
TORSIONAL_KIND = "torsional"
#: Standard uncertainty of one weighed calibration body, kg, when the manifest states none (optional field).
DEFAULT_BODY_MASS_U_KG = 0.01
REFERENCE_CORRELATIONS = ("nested", "independent")
#: Scheme names of ``[torsional]``/``[properties]``: the poses of :func:`rgse_daemon.pipeline.cog.cog_poses`, or
#: ``custom`` (poses of their own).
MANIFEST_SCHEMES = (*SCHEMES, "custom")
#: The keys each table of a manifest may hold; any other key is refused (a misspelt optional key would otherwise
#: silently take its default).
TOP_KEYS = ("setup", "point", "measurement", "torsional", "properties")
SETUP_KEYS = ("robot", "g", "lever_difference_m", "body_mass_u_kg", "reference_correlation", "g_u_m_s2")
POINT_KEYS = ("kind", "mass_kg", "lever_a3_m", "lever_a5_m", "traces", "bodies", "mass_u_kg")
TORSIONAL_POINT_KEYS = ("kind", "mass_kg", "cog_flange_m", "poses", "bodies", "mass_u_kg")
MEASUREMENT_KEYS = ("traces", "fixture_mass_kg")
TORSIONAL_KEYS = ("scheme", "pose")
POSE_KEYS = ("name", "q_deg")


@dataclass(frozen=True)
class Setup:
    """``[setup]``; the last three are optional manifest fields (defaults in brackets).

    ``body_mass_u_kg`` [0.01]: standard uncertainty of each weighed calibration body. ``reference_correlation``
    ["nested"]: the loads of the campaign contain each other (the paper's stack: point n holds the bodies of
    point n−1), so their mass errors are correlated; "independent" for separate loads. ``g_u_m_s2`` [0]: standard
    uncertainty of ``g`` (local g vs the value used, docs/controller.md §7).
    """

    robot: str
    g_m_s2: float
    lever_difference_m: float
    body_mass_u_kg: float = DEFAULT_BODY_MASS_U_KG
    reference_correlation: str = "nested"
    g_u_m_s2: float = 0.0


@dataclass(frozen=True)
class PointSpec:
    kind: str
    mass_kg: float
    lever_a3_m: float
    lever_a5_m: float
    traces: tuple[str, ...]
    bodies: int | None = None  # optional: weighed bodies in the load (default 1 for a loaded point)
    mass_u_kg: float | None = None  # optional: standard uncertainty of mass_kg (overrides bodies)

    def mass_var_kg2(self, body_mass_u_kg: float) -> float:
        """Variance of the reference mass of this point."""
        if self.mass_kg == 0.0:
            return 0.0
        if self.mass_u_kg is not None:
            return self.mass_u_kg**2
        return (1 if self.bodies is None else self.bodies) * body_mass_u_kg**2


@dataclass(frozen=True)
class Loop:
    """The A3 and A5 torque of one measurement loop (one trace), Nm, and its sample period."""

    trace: str
    torque_a3_nm: np.ndarray
    torque_a5_nm: np.ndarray
    period_s: float
    motor_temp_a3_k: float | None = None
    """Mean ``Motortemperatur`` of A3 over the trace (K); None when the trace did not record it."""
    motor_temp_a5_k: float | None = None
    axes_deg: tuple[float, float] | None = None
    """Median ``Istposition`` of A3 and A5 over the trace (deg): the pose the loop was recorded in; None when either
    drive module did not record it."""


@dataclass(frozen=True)
class TorsionalPointSpec:
    """A ``kind = "torsional"`` point: the load beyond the MPA (mass kg, 0 = the bare MPA, i.e. the bias of every
    pose; CoG in the flange frame m; its standard uncertainty in mass) and its traces per pose name."""

    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    traces: dict[str, tuple[str, ...]]
    mass_u_kg: float = 0.0


@dataclass(frozen=True)
class TorsionalPose:
    """A pose of the torsional points' scheme (``[[torsional.pose]]``): name and A1..A6 in deg."""

    name: str
    q_deg: tuple[float, ...]


@dataclass
class Manifest:
    path: Path
    setup: Setup
    points: list[PointSpec] = field(default_factory=list)
    measurement_traces: tuple[str, ...] = ()
    fixture_mass_kg: float | None = None
    torsional_points: list[TorsionalPointSpec] = field(default_factory=list)
    torsional_poses: list[TorsionalPose] = field(default_factory=list)
    torsional_scheme: str | None = None
    trace_places: dict[str, str] = field(default_factory=dict)
    """Where each trace name appears in the manifest (e.g. ``[[point]] #3``)."""

    def claim_traces(self, traces: Sequence[str], where: str) -> None:
        """Record that ``traces`` appear at ``where``; DataError when one of them already appears in the manifest
        (a loop counted twice, or one load's loop taken for another's)."""
        for t in traces:
            first = self.trace_places.get(t)
            if first is not None:
                place = f"twice in {where}" if first == where else f"in {first} and in {where}"
                raise DataError(f"{self.path}: trace {t!r} appears {place}; a trace may appear once in a manifest")
            self.trace_places[t] = where


def check_keys(table: dict[str, Any], known: Sequence[str], where: str) -> None:
    """DataError naming the first key of ``table`` that is not one of ``known``, with a close match if any."""
    for key in table:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DataError(f"{where}: unknown key {key!r}{hint}; known keys: {', '.join(known)}")


def check_scheme(value: Any, where: str) -> str:
    """A scheme name of ``MANIFEST_SCHEMES``."""
    if value not in MANIFEST_SCHEMES:
        raise DataError(f"{where}: scheme must be one of {', '.join(MANIFEST_SCHEMES)}, got {value!r}")
    return str(value)


def _num(d: dict[str, Any], key: str, where: str, *, minimum: float | None = None, positive: bool = False) -> float:
    if key not in d:
        raise DataError(f"{where}: missing {key!r}")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise DataError(f"{where}: {key!r} must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise DataError(f"{where}: {key!r} must be > 0, got {v}")
    if minimum is not None and v < minimum:
        raise DataError(f"{where}: {key!r} must be >= {minimum}, got {v}")
    return float(v)


def _opt_num(d: dict[str, Any], key: str, where: str, default: float | None) -> float | None:
    """An optional number >= 0."""
    return _num(d, key, where, minimum=0.0) if key in d else default


def _traces(d: dict[str, Any], where: str) -> tuple[str, ...]:
    t = d.get("traces")
    if not isinstance(t, list) or not t or not all(isinstance(x, str) and x for x in t):
        raise DataError(f"{where}: 'traces' must be a non-empty list of trace names")
    return tuple(plain_name(x, f"{where}: traces[{i}]") for i, x in enumerate(t))


def read_toml(path: Path) -> dict[str, Any]:
    """The TOML document of ``path`` (a UTF-8 byte order mark is allowed); DataError naming the file otherwise.
    Like a trace file, a manifest symbolically linked out of its own directory is refused."""
    inside(path.parent, path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{path}: manifest not found") from None
    except IsADirectoryError:
        raise DataError(f"{path}: is a directory, not a manifest file") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        return tomllib.loads(raw.decode("utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not valid TOML: {exc}") from exc
    except RecursionError:  # tomllib's answer to arrays nested thousands deep
        raise DataError(f"{path}: not valid TOML: nested too deeply") from None


def _tables(doc: dict[str, Any], key: str, where: str) -> list[Any]:
    """``[[key]]``: an array of tables (absent: none); DataError for any other type."""
    value = doc.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise DataError(f"{where}: {key!r} must be [[{key}]] tables, got {value!r}")
    return value


def load_manifest(directory: Path | str) -> Manifest:
    """Read and validate ``DIR/manifest.toml``."""
    directory = Path(directory)
    path = directory / "manifest.toml"
    if not directory.is_dir():
        raise DataError(f"{directory}: directory not found")
    doc = read_toml(path)
    check_keys(doc, TOP_KEYS, str(path))
    setup = doc.get("setup")
    if not isinstance(setup, dict):
        raise DataError(f"{path}: missing [setup] table")
    check_keys(setup, SETUP_KEYS, f"{path} [setup]")
    robot = setup.get("robot")
    if not isinstance(robot, str) or not robot:
        raise DataError(f"{path}: [setup] robot must be a non-empty string")
    where = f"{path} [setup]"
    corr = setup.get("reference_correlation", "nested")
    if corr not in REFERENCE_CORRELATIONS:
        raise DataError(f"{where}: reference_correlation must be one of {', '.join(REFERENCE_CORRELATIONS)}, "
                        f"got {corr!r}")
    man = Manifest(path, Setup(robot, _num(setup, "g", where, positive=True),
                               _num(setup, "lever_difference_m", where, positive=True),
                               _opt_num(setup, "body_mass_u_kg", where, DEFAULT_BODY_MASS_U_KG), corr,
                               _opt_num(setup, "g_u_m_s2", where, 0.0)))
    for i, p in enumerate(_tables(doc, "point", str(path))):
        where = f"{path} [[point]] #{i + 1}"
        kind = p.get("kind")
        check_keys(p, TORSIONAL_POINT_KEYS if kind == TORSIONAL_KIND else POINT_KEYS, where)
        if kind == TORSIONAL_KIND:
            man.torsional_points.append(_torsional_point(p, where))
            for pose, traces in man.torsional_points[-1].traces.items():
                man.claim_traces(traces, f"[[point]] #{i + 1} poses.{pose}")
            continue
        if kind not in KINDS:
            raise DataError(f"{where}: kind must be one of {', '.join(KINDS)}, got {kind!r}")
        bodies = p.get("bodies")
        if bodies is not None and (isinstance(bodies, bool) or not isinstance(bodies, int) or bodies < 0):
            raise DataError(f"{where}: 'bodies' must be an integer >= 0, got {bodies!r}")
        mass_u = _opt_num(p, "mass_u_kg", where, None)
        spec = PointSpec(kind, _num(p, "mass_kg", where, minimum=0.0), _num(p, "lever_a3_m", where),
                         _num(p, "lever_a5_m", where), _traces(p, where), bodies, mass_u)
        if (kind == "zero") != (spec.mass_kg == 0.0):
            raise DataError(f"{where}: a 'zero' point has mass_kg = 0 and only a 'zero' point has")
        man.claim_traces(spec.traces, f"[[point]] #{i + 1}")
        man.points.append(spec)
    _torsional_poses(man, doc.get("torsional"), f"{path} [torsional]")
    meas = doc.get("measurement")
    if meas is not None:
        if not isinstance(meas, dict):
            raise DataError(f"{path}: [measurement] must be a table")
        check_keys(meas, MEASUREMENT_KEYS, f"{path} [measurement]")
        man.measurement_traces = _traces(meas, f"{path} [measurement]")
        man.claim_traces(man.measurement_traces, "[measurement]")
        if "fixture_mass_kg" in meas:
            man.fixture_mass_kg = _num(meas, "fixture_mass_kg", f"{path} [measurement]", minimum=0.0)
    return man


def _torsional_point(p: dict[str, Any], where: str) -> TorsionalPointSpec:
    cog = p.get("cog_flange_m")
    if not isinstance(cog, list) or len(cog) != 3 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in cog):
        raise DataError(f"{where}: a torsional point needs cog_flange_m = [x, y, z] (m, flange frame)")
    traces = p.get("poses")
    if not isinstance(traces, dict) or not traces:
        raise DataError(f"{where}: a torsional point needs [point.poses] with its trace names per pose")
    by_pose = {str(name): _traces({"traces": t}, f"{where} poses.{name}") for name, t in traces.items()}
    return TorsionalPointSpec(_num(p, "mass_kg", where, minimum=0.0), (float(cog[0]), float(cog[1]), float(cog[2])),
                              by_pose, _opt_num(p, "mass_u_kg", where, 0.0) or 0.0)


def _torsional_poses(man: Manifest, table: Any, where: str) -> None:
    """``[torsional]``: the scheme's name and its ``[[torsional.pose]]`` list; needed when torsional points exist."""
    if table is None:
        if man.torsional_points:
            raise DataError(f"{where}: torsional points need a [torsional] table with their [[torsional.pose]]s")
        return
    if not isinstance(table, dict) or not isinstance(table.get("pose"), list) or not table["pose"]:
        raise DataError(f"{where}: needs [[torsional.pose]] entries (name, q_deg)")
    check_keys(table, TORSIONAL_KEYS, where)
    man.torsional_scheme = check_scheme(table.get("scheme", "custom"), where)
    for i, p in enumerate(table["pose"]):
        pw = f"{where} pose #{i + 1}"
        if isinstance(p, dict):
            check_keys(p, POSE_KEYS, pw)
        q = p.get("q_deg") if isinstance(p, dict) else None
        if not isinstance(p, dict) or not isinstance(p.get("name"), str) or not isinstance(q, list) or len(q) != 6 \
                or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in q):
            raise DataError(f"{pw}: needs a name and q_deg = six finite angles (deg)")
        man.torsional_poses.append(TorsionalPose(p["name"], tuple(float(v) for v in q)))
    names = [p.name for p in man.torsional_poses]
    for k, pt in enumerate(man.torsional_points):
        missing = sorted(set(names) - set(pt.traces))
        extra = sorted(set(pt.traces) - set(names))
        if missing or extra:
            raise DataError(f"{where}: torsional point #{k + 1} must have traces for exactly the poses "
                            f"{', '.join(names)} (missing {missing}, unknown {extra})")
    if man.torsional_points and not any(pt.mass_kg == 0.0 for pt in man.torsional_points):
        raise DataError(f"{where}: the torsional points need one with mass_kg = 0 (the bare MPA: the bias)")


def plausible_period_s(period_s: float, source: Path | str) -> float:
    """``period_s`` if it is a plausible KUKA Trace sample period; DataError naming ``source`` otherwise."""
    if not (math.isfinite(period_s) and PERIOD_MIN_S <= period_s <= PERIOD_MAX_S):
        raise DataError(f"{source}: sample period (code 241) {period_s:g} s is outside the {PERIOD_MIN_S:g} to "
                        f"{PERIOD_MAX_S:g} s of a KUKA trace")
    return period_s


def check_one_period(periods: Sequence[tuple[str, float]], where: Path | str) -> None:
    """DataError unless every ``(what, sample period in s)`` has the period of the first: the loops of one
    measurement or one campaign are pre-processed alike, and the pre-processing counts its filter window in samples."""
    if not periods:
        return
    first, p0 = periods[0]
    for what, p in periods[1:]:
        if not math.isclose(p, p0, rel_tol=1e-6):
            raise DataError(f"{where}: {what} has sample period {p:g} s, {first} {p0:g} s; the loops of one "
                            f"measurement or campaign need one sample period (the filter window counts samples)")


def read_loop(directory: Path | str, trace: str) -> Loop:
    """The A3 and A5 ``Istmoment`` of one trace; DataError (naming the file) if absent, truncated or not finite."""
    ts = read_trace_set(directory, trace, (MODULE_A3, MODULE_A5))
    a3 = np.asarray(ts.channel(MODULE_A3, TORQUE_CHANNEL).values, float)
    a5 = np.asarray(ts.channel(MODULE_A5, TORQUE_CHANNEL).values, float)
    f3, f5 = ts.files[MODULE_A3], ts.files[MODULE_A5]
    for values, tf in ((a3, f3), (a5, f5)):  # missing samples (NaN) are the pipeline's to judge (integrity.py)
        if values.size < 3:
            raise DataError(f"{tf.dat_path}: only {values.size} torque samples")
    for tf in (f3, f5):
        plausible_period_s(tf.period_s, tf.dat_path)
    if f3.period_s != f5.period_s or a3.size != a5.size:
        raise DataError(f"{f5.dat_path}: sample period or length differs from {f3.dat_path.name}")
    p3, p5 = _median_position_deg(f3), _median_position_deg(f5)
    return Loop(trace, a3, a5, float(f3.period_s), _mean_temperature_k(f3), _mean_temperature_k(f5),
                None if p3 is None or p5 is None else (p3, p5))


def _median_position_deg(tf: Any) -> float | None:
    """Median of the drive's ``Istposition`` channel (deg) over its valid samples; None if absent or every sample is
    missing."""
    ch = tf.channels.get(POSITION_CHANNEL)
    if ch is None:
        return None
    values = np.asarray(ch.values, float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else None


def _mean_temperature_k(tf: Any) -> float | None:
    """Mean of the drive's ``Motortemperatur`` channel (K) over its valid samples (a missing sample, NaN, is left
    out), None if absent or every sample is missing; implausible values are a DataError."""
    ch = tf.channels.get(TEMPERATURE_CHANNEL)
    if ch is None:
        return None
    values = np.asarray(ch.values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    if values.min() < 200.0 or values.max() > 450.0:
        raise DataError(f"{tf.dat_path}: channel {TEMPERATURE_CHANNEL!r} is not a motor temperature in K "
                        f"(expected values within 200..450 K)")
    return float(values.mean())


#: The mean ``Motortemperatur`` of one trace file (K, None if absent): also the CoG's thermal check (analysis.cog).
mean_temperature_k = _mean_temperature_k


def thermal_state_k(loops: list[Loop]) -> dict[str, float] | None:
    """Mean A3 and A5 motor temperature over ``loops`` (K): the thermal state the torques were measured in; None
    when any loop lacks the channel."""
    t3 = [lp.motor_temp_a3_k for lp in loops]
    t5 = [lp.motor_temp_a5_k for lp in loops]
    if not loops or any(t is None for t in t3 + t5):
        return None
    return {"A3": float(np.mean(t3)), "A5": float(np.mean(t5))}


def pose_deg(loops: Sequence[Loop]) -> dict[str, float] | None:
    """The A3 and A5 positions (deg) ``loops`` were recorded in, the median over the loops: the calibration's
    measurement pose (CAL.json ``measurement_axes_deg``); None when any loop lacks its positions."""
    if not loops or any(lp.axes_deg is None for lp in loops):
        return None
    axes = np.array([lp.axes_deg for lp in loops], float)
    return {"A3": float(np.median(axes[:, 0])), "A5": float(np.median(axes[:, 1]))}


def read_loops(directory: Path | str, traces: tuple[str, ...]) -> list[Loop]:
    """The loops of ``traces``; DataError unless they share one sample period."""
    loops = [read_loop(directory, t) for t in traces]
    check_one_period(loop_periods(loops), directory)
    return loops


def loop_periods(loops: Sequence[Loop]) -> list[tuple[str, float]]:
    """``(trace 'name', sample period)`` of each loop, for :func:`check_one_period`."""
    return [(f"trace {lp.trace!r}", lp.period_s) for lp in loops]


def source_sha256(paths: list[Path]) -> dict[str, str]:
    """SHA-256 of input files by name (recorded in CAL.json, so a calibration names exactly what it came from)."""
    out = {}
    for p in paths:
        out[p.name] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


# ------------------------------------------------------------------------------------------------------------
# Table-1 style CSV of pre-averaged points
# ------------------------------------------------------------------------------------------------------------
POINTS_COLUMNS = ("calibration_type", "mass_kg", "m_a3_expected_nm", "m_a5_expected_nm", "m_a3_measured_nm",
                  "m_a5_measured_nm")
#: Largest magnitude a points CSV value may have: a torque in Nm (columns ``*_nm``), else a mass in kg. Far beyond
#: any KUKA axis or payload; a typo such as 1e300 would otherwise reach the fit.
POINTS_MAX_NM = 1e6
POINTS_MAX_KG = 1e5


def _count(text: str | None, where: str) -> int:
    """A CSV cell holding a count: an integer >= 0 (``3`` or ``3.0``)."""
    try:
        v = float(text or "")
    except (TypeError, ValueError):
        raise DataError(f"{where} is not a number: {text!r}") from None
    if not (math.isfinite(v) and v >= 0 and v == int(v)):
        raise DataError(f"{where} must be a whole number of bodies >= 0, got {text!r}")
    return int(v)


def load_points_csv(path: Path | str) -> CalibrationPoints:
    """Read calibration points in the format of ``paper/table1_calibration.csv`` (``#`` lines are comments)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    header = list(reader.fieldnames or [])
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise DataError(f"{path}: column(s) given twice in the header: {', '.join(twice)}")
    rows = list(reader)
    if not rows:
        raise DataError(f"{path}: no data rows")
    missing = [c for c in POINTS_COLUMNS if c not in header]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)}")
    cols: dict[str, list] = {c: [] for c in POINTS_COLUMNS}
    for lineno, row in enumerate(rows, start=2):
        kind = (row["calibration_type"] or "").strip()
        if kind not in KINDS:
            raise DataError(f"{path}: data row {lineno - 1}: calibration_type must be one of {', '.join(KINDS)}, "
                            f"got {kind!r}")
        cols["calibration_type"].append(kind)
        for c in POINTS_COLUMNS[1:]:
            try:
                v = float(row[c])
            except (TypeError, ValueError):
                raise DataError(f"{path}: data row {lineno - 1}: column {c} is not a number: {row[c]!r}") from None
            if not math.isfinite(v):
                raise DataError(f"{path}: data row {lineno - 1}: column {c} is {v}")
            limit, unit = (POINTS_MAX_NM, "Nm") if c.endswith("_nm") else (POINTS_MAX_KG, "kg")
            if abs(v) > limit:
                raise DataError(f"{path}: data row {lineno - 1}: column {c} is {v:g}, beyond the plausible "
                                f"{limit:g} {unit}")
            cols[c].append(v)
    cov = None
    if "n_cb" in header:  # Table 1: n_cb bodies, the torque rows on the test adapter (one more weighed body)
        n_cb = np.array([_count(r["n_cb"], f"{path}: data row {i}: column n_cb") for i, r in enumerate(rows, 1)])
        bodies = n_cb + (np.array(cols["calibration_type"]) == "torque")
        var = np.where(np.array(cols["mass_kg"]) > 0, bodies * DEFAULT_BODY_MASS_U_KG**2, 0.0)
        cov = reference_mass_covariance(var, nested=True)
    try:
        return CalibrationPoints(np.array(cols["calibration_type"]), np.array(cols["mass_kg"]),
                                 np.array(cols["m_a3_measured_nm"]), np.array(cols["m_a5_measured_nm"]),
                                 np.array(cols["m_a3_expected_nm"]), np.array(cols["m_a5_expected_nm"]), cov)
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc
