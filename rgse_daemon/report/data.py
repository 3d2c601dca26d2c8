"""What a report shows, gathered from the store and the archived raw files, and checked before anything is drawn.

Every number on a report page is either a value stored in the store (run, loops, trace files, result, calibration
document, reference weighings) or a quantity recomputed from the archived raw files with the same pipeline code
that produced the stored result. Recomputations are *checked*: the archived files must match their recorded
SHA-256 and size, and the recomputed mass, uncertainty, sample counts (measurement) or bias and K parameters
(calibration) must equal the stored ones. Any difference is a :class:`ReportConsistencyError` — a report that
disagrees with its own record is never written.

Store conventions the report relies on (what the daemon and ``tests/report/storefill.py`` write):

* measurement run: ``loops`` with their ``trace_name``; each loop's ``.dat``/``.r64`` files indexed as trace files
  with that ``loop_index`` (all files of a loop in one archive directory); one or more ``results`` (the newest is
  reported), whose ``calibration_id`` is a stored calibration.
* calibration run (``calibrations.run_id``): ``points`` whose ``spec`` holds ``kind``, ``mass_kg``,
  ``lever_a3_m``, ``lever_a5_m`` (manifest ``[[point]]``); ``loops`` with ``point_index``; trace files as above.
  A calibration without a run (fitted from a points CSV) is reported from its document alone.
* reference weighings: events of kind :data:`~rgse_daemon.analysis.reference.EVENT_KIND`
  (see :mod:`rgse_daemon.analysis.reference`).
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from rgse_daemon import __version__, calfile
from rgse_daemon.analysis import cog as cog_analysis
from rgse_daemon.analysis import inertia as inertia_analysis
from rgse_daemon.analysis import multipose as multipose_analysis
from rgse_daemon.analysis import reference as ref
from rgse_daemon.errors import DataError, RgseError
from rgse_daemon.manifest import TORSIONAL_KIND, Loop, read_loop
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import integrity
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.calibration import Calibration, CalibrationPoints
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.store import (
    CalibrationRecord,
    LoopRecord,
    NotFound,
    Repository,
    ResultRecord,
    RunKind,
    RunRecord,
    TraceFileRecord,
    archive_root,
    verify_file,
)

#: Stored and recomputed floats must agree to this relative tolerance (same code, same inputs: bit-identical in
#: practice; the tolerance only absorbs a JSON round trip).
REL_TOL = 1e-9

#: ECSS-E-10-03C mass accuracy requirement, relative (±0.05 %).
ECSS_MASS_REL = 0.0005

#: ECSS-E-10-03C centre-of-gravity accuracy (m): along the launch axis (the DuT frame's z) and across it (x, y).
ECSS_COG_ALONG_M = 0.0025
ECSS_COG_ACROSS_M = 0.001
ECSS_COG_LIMITS_M = (ECSS_COG_ACROSS_M, ECSS_COG_ACROSS_M, ECSS_COG_ALONG_M)

#: Coverage factor of the error corridors drawn from a parameter covariance.
BAND_K = 2.0


class ReportConsistencyError(RgseError):
    """A quantity recomputed from the archived raw files differs from the value the store holds."""


# ------------------------------------------------------------------------------------------------------------
# records
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AxisProcessing:
    """Fig. 22 of one loop and one axis: raw samples, what survived the settle cut and the crop, the filtered
    series, and the loop mean (inner average of eq. 16)."""

    time_s: np.ndarray
    raw_nm: np.ndarray
    kept_time_s: np.ndarray
    kept_nm: np.ndarray
    filtered_time_s: np.ndarray
    filtered_nm: np.ndarray
    loop_mean_nm: float
    n_used: int
    n_total: int


@dataclass(frozen=True)
class LoopView:
    index: int
    record: LoopRecord
    period_s: float
    a3: AxisProcessing
    a5: AxisProcessing
    gross_mass_kg: float | None
    """Mass of this loop alone (eq. 21 on its normalised loop means, fixture included); measurement runs only."""


@dataclass(frozen=True)
class PointView:
    """One calibration point recomputed from its archived loops."""

    index: int
    spec: dict[str, Any]
    loop_indices: tuple[int, ...]
    measured_a3_nm: float
    measured_a5_nm: float
    """Bias-normalised double averages (eq. 16 minus M_0)."""
    expected_a3_nm: float
    expected_a5_nm: float
    mass_calc_kg: float
    """Mass of the point by eq. 21 with the stored calibration."""
    u_mass_cal_kg: float
    """Standard uncertainty of that mass from the calibration's parameter covariance (linearised)."""


@dataclass(frozen=True)
class CalibrationView:
    record: CalibrationRecord
    document: dict[str, Any]
    """The CAL.json document exactly as stored (what a reproduction writes)."""
    cal_file: calfile.CalFile
    calibration: Calibration
    preprocessing: pp.Preprocessing
    run: RunRecord | None
    points: list[PointView] = field(default_factory=list)
    files: list[TraceFileRecord] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)
    result: ResultRecord | None = None
    """The campaign run's (newest) result: its status and warnings (None: fitted offline, or none stored)."""


@dataclass(frozen=True)
class MeasurementView:
    run: RunRecord
    result: ResultRecord
    all_results: list[ResultRecord]
    loops: list[LoopView]
    files: list[TraceFileRecord]
    calibration: CalibrationView
    references: list[ref.ReferenceRecord]
    working_a3_nm: float
    working_a5_nm: float
    """Normalised double averages of the run (eq. 16 minus M_0): the calibration's working point."""
    checks: list[str]
    events: list[Any]
    cog: dict[str, Any] | None = None
    """A properties run: its CoG result (``analysis.cog.CogResult.to_json``), recomputed and checked."""
    inertia: dict[str, Any] | None = None
    """A properties run with the inertia: the identification (``analysis.inertia``), recomputed and checked."""


@dataclass(frozen=True)
class ReportMeta:
    software_version: str
    generated_utc: datetime
    store: str


# ------------------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------------------
def calibration_from_document(doc: dict[str, Any], what: str) -> calfile.CalFile:
    """Validate a stored CAL.json document exactly as ``rgse mass`` reads the file (:func:`calfile.load`)."""
    try:
        return calfile.load(doc, what)
    except DataError as exc:
        raise DataError(f"{what}: stored calibration document is invalid: {str(exc).split(': ', 1)[-1]}") from exc


def _same(a: float, b: float) -> bool:
    return math.isclose(float(a), float(b), rel_tol=REL_TOL, abs_tol=1e-12)


def _check(checks: list[str], what: str, stored: Any, recomputed: Any) -> None:
    if isinstance(stored, float | int) and not isinstance(stored, bool) and isinstance(recomputed, float | int):
        ok = _same(stored, recomputed)
    else:
        ok = stored == recomputed
    if not ok:
        raise ReportConsistencyError(f"{what}: the store holds {stored!r}, the archived raw files give {recomputed!r}")
    checks.append(what)


def _verify_files(root: Path, files: list[TraceFileRecord], checks: list[str], owner: str) -> None:
    for f in files:
        verify_file(root / f.path, f.sha256, f.size_bytes)  # ArchiveError names the file and the difference
    checks.append(f"{owner}: {len(files)} archived file(s) match their recorded SHA-256 and size")


def _loop_directory(root: Path, loop: LoopRecord, files: list[TraceFileRecord]) -> Path:
    mine = [f for f in files if f.loop_index == loop.index]
    if not mine:
        raise DataError(f"run {loop.run_id} loop {loop.index} ({loop.trace_name}): no archived trace files")
    dirs = {PurePosixPath(f.path).parent for f in mine}
    if len(dirs) != 1:
        raise DataError(f"run {loop.run_id} loop {loop.index}: trace files lie in several directories {sorted(dirs)}")
    return root / str(dirs.pop())


def axis_processing(values: np.ndarray, period_s: float, cfg: pp.Preprocessing) -> AxisProcessing:
    """The stages of :func:`~rgse_daemon.pipeline.preprocess.filtered_rows` kept apart for plotting (Fig. 22)."""
    x = np.asarray(values, float)
    t = np.arange(x.size) * period_s
    skip = round(cfg.settle_s / period_s)
    xs, ts = x[skip:], t[skip:]
    present = np.isfinite(xs)  # missing samples (no value) are left out, as the pipeline does
    xs, ts = xs[present], ts[present]
    rows = pp.filtered_rows(x, period_s, cfg, np.array([cfg.window]))
    if cfg.order == "backward":
        kept = pp.crop_outliers(xs, cfg.crop_sigma)[0]
        mask = np.isfinite(kept)
        kept_t, kept_x = ts[mask], xs[mask]
        filt_t, filt_x = kept_t, rows[0]
    else:
        mask = np.isfinite(rows[0])
        kept_t, kept_x = ts[mask], xs[mask]
        filt_t, filt_x = ts[mask], rows[0][mask]
    loop = pp.process_loop(x, period_s, cfg)
    return AxisProcessing(t, x, kept_t, kept_x, filt_t, filt_x, loop.torque_nm, loop.n_used, loop.n_total)


def band_of_k(axis_k: cal_mod.AxisK, cov: np.ndarray, torque_nm: np.ndarray) -> np.ndarray:
    """Standard deviation of K(M) from the axis's parameter covariance, linearised (central differences)."""
    p0 = np.asarray(axis_k.params, float)
    jac = np.empty((np.size(torque_nm), p0.size))
    for j in range(p0.size):
        h = 1e-6 * max(abs(p0[j]), 1e-6)
        up, dn = p0.copy(), p0.copy()
        up[j] += h
        dn[j] -= h
        jac[:, j] = (cal_mod._replace_params(axis_k, up).k(torque_nm) - cal_mod._replace_params(axis_k, dn).k(torque_nm)
                     ) / (2 * h)
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    return np.sqrt(np.maximum(var, 0.0))


def mass_sigma_cal_kg(cal: Calibration, torque_a3_nm: float, torque_a5_nm: float) -> float:
    """Standard uncertainty of eq. 21 from the full parameter covariance, linearised."""
    p0 = cal.params
    grad = np.empty(p0.size)
    for j in range(p0.size):
        h = 1e-6 * max(abs(p0[j]), 1e-6)
        up, dn = p0.copy(), p0.copy()
        up[j] += h
        dn[j] -= h
        grad[j] = (float(cal.with_params(up).mass_kg(torque_a3_nm, torque_a5_nm))
                   - float(cal.with_params(dn).mass_kg(torque_a3_nm, torque_a5_nm))) / (2 * h)
    return float(math.sqrt(max(float(grad @ np.asarray(cal.covariance) @ grad), 0.0)))


# ------------------------------------------------------------------------------------------------------------
# calibration
# ------------------------------------------------------------------------------------------------------------
def load_calibration(repo: Repository, data_dir: Path, calibration_id: str) -> CalibrationView:
    """A stored calibration; with its campaign run, the points recomputed from the archive and checked."""
    try:
        rec = repo.get_calibration(calibration_id)
    except NotFound as exc:
        raise DataError(str(exc)) from exc
    doc = rec.document
    calf = calibration_from_document(doc, f"calibration {calibration_id}")
    cal, cfg = calf.calibration, calf.preprocessing or pp.PAPER
    checks: list[str] = [f"calibration {calibration_id}: document valid (schema {calf.schema})"]
    if rec.run_id is None:
        return CalibrationView(rec, doc, calf, cal, cfg, None, [], [], checks)
    run = repo.get_run(rec.run_id)
    results = repo.results(run.id)
    result = results[-1] if results else None
    # the torsional points (CoG, measured in several poses) are not mass points: the mass calibration ignores them
    # (as analysis.calibration does), and so does this recomputation; CAL.json's torsional section is shown as stored
    specs = [p for p in repo.points(run.id) if p.spec.get("kind") != TORSIONAL_KIND]
    loops = repo.loops(run.id)
    files = repo.trace_files(run.id)
    if not specs:
        return CalibrationView(rec, doc, calf, cal, cfg, run, [], files, checks, result)
    root = archive_root(data_dir)
    _verify_files(root, files, checks, f"calibration run {run.id}")
    raw3, raw5, loop_idx = [], [], []
    # the loops the campaign set aside (fit.set_aside: a gap, a step, a loop far from its point's others) are not
    # in its points; their files stay archived and are verified above
    aside = {a.loop for a in calf.fit.set_aside or ()}  # (a trace's name is unique in its run)
    for p in specs:
        mine = [lp for lp in loops if lp.point_index == p.index and lp.trace_name not in aside]
        if not mine:
            raise DataError(f"calibration run {run.id} point {p.index}: no loops recorded")
        l3, l5 = [], []
        for lp in mine:
            loop = read_loop(_loop_directory(root, lp, files), lp.trace_name)
            ok = integrity.valid_mask(loop.torque_a3_nm, loop.torque_a5_nm)  # missing in one channel: in both
            l3.append(pp.process_loop(np.where(ok, loop.torque_a3_nm, np.nan), loop.period_s, cfg).torque_nm)
            l5.append(pp.process_loop(np.where(ok, loop.torque_a5_nm, np.nan), loop.period_s, cfg).torque_nm)
        raw3.append(pp.double_average_nm(l3))
        raw5.append(pp.double_average_nm(l5))
        loop_idx.append(tuple(lp.index for lp in mine))
    kinds = np.array([str(p.spec.get("kind")) for p in specs])
    zero = kinds == "zero"
    if not zero.any():
        raise DataError(f"calibration run {run.id}: no 'zero' point, so no bias M_0")
    bias3, bias5 = float(np.array(raw3)[zero].mean()), float(np.array(raw5)[zero].mean())
    _check(checks, "bias M_0 of A3 (Nm)", calf.bias.a3_nm, bias3)
    _check(checks, "bias M_0 of A5 (Nm)", calf.bias.a5_nm, bias5)
    mass = np.array([float(p.spec["mass_kg"]) for p in specs])
    e3 = cal.g_m_s2 * mass * np.array([float(p.spec["lever_a3_m"]) for p in specs])
    e5 = cal.g_m_s2 * mass * np.array([float(p.spec["lever_a5_m"]) for p in specs])
    n3, n5 = pp.normalise(np.array(raw3), bias3), pp.normalise(np.array(raw5), bias5)
    points = CalibrationPoints(kinds, mass, n3, n5, e3, e5)
    refit = cal_mod.fit(points, cal.method, cal.g_m_s2, cal.lever_difference_m)
    for name, stored, again in (("A3", cal.k_a3.params, refit.k_a3.params), ("A5", cal.k_a5.params, refit.k_a5.params)):
        if stored.shape != again.shape or not np.allclose(stored, again, rtol=1e-7, atol=1e-12):
            raise ReportConsistencyError(f"calibration {calibration_id}: K parameters of {name} refitted from the "
                                         f"archived campaign are {again.tolist()}, the store holds {stored.tolist()}")
    checks.append(f"K of A3 and A5 ({cal.method}) refitted from the archived campaign equals the stored parameters")
    calc = np.asarray(cal.points_mass_kg(points), float)  # each point in its own geometry (its Δr)
    views = [PointView(p.index, p.spec, loop_idx[i], float(n3[i]), float(n5[i]), float(e3[i]), float(e5[i]),
                       float(calc[i]), mass_sigma_cal_kg(cal, float(n3[i]), float(n5[i])))
             for i, p in enumerate(specs)]
    return CalibrationView(rec, doc, calf, cal, cfg, run, views, files, checks, result)


# ------------------------------------------------------------------------------------------------------------
# measurement
# ------------------------------------------------------------------------------------------------------------
def load_measurement(repo: Repository, data_dir: Path, run_id: str) -> MeasurementView:
    """A measurement run with its newest result, recomputed from the archived loops and checked against it."""
    try:
        run = repo.get_run(run_id)
    except NotFound as exc:
        raise DataError(str(exc)) from exc
    if run.kind not in (RunKind.MEASUREMENT, RunKind.PROPERTIES):
        raise DataError(f"run {run_id} is a {run.kind.value} run; report its calibration with --calibration ID")
    results = repo.results(run_id)
    if not results:
        raise DataError(f"run {run_id}: no result stored (state {run.state.value}); nothing to report")
    result = results[-1]
    res = result.result
    cal_id = res.get("calibration_id")
    if not isinstance(cal_id, str):
        raise DataError(f"run {run_id} result {result.id}: names no calibration_id")
    calv = load_calibration(repo, data_dir, cal_id)
    cal, cfg, doc = calv.calibration, calv.preprocessing, calv.document
    loops = repo.loops(run_id)
    files = repo.trace_files(run_id)
    if not loops:
        raise DataError(f"run {run_id}: no loops recorded")
    root = archive_root(data_dir)
    checks: list[str] = []
    _verify_files(root, files, checks, f"run {run_id}")
    stored_inputs = set(result.trace_sha256)
    loop_shas = {f.sha256 for f in files if f.loop_index is not None}
    if not loop_shas <= stored_inputs:
        raise ReportConsistencyError(f"run {run_id} result {result.id}: loop trace files not among its inputs")
    all_loops = loops
    if isinstance(res.get("mass_traces"), list):  # a properties run: the mass loops, then the CoG poses' loops
        loops = [lp for lp in loops if lp.trace_name in res["mass_traces"]]
        if len(loops) != len(res["mass_traces"]):
            raise ReportConsistencyError(f"run {run_id} result {result.id}: mass loops {res['mass_traces']} are not "
                                         f"all recorded")
    raw: list[Loop] = [read_loop(_loop_directory(root, lp, files), lp.trace_name) for lp in loops]
    fixture = float(res.get("fixture_mass_kg", 0.0))
    bias3, bias5 = calv.cal_file.bias.a3_nm, calv.cal_file.bias.a5_nm
    # the campaign's thermal drift (CAL.json fit.thermal): every loop brought to the campaign's temperature, as
    # pipeline.inline does when each loop recorded its A3/A5 motor temperatures
    thermal = calv.cal_file.fit.thermal
    temps = [(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in raw]
    if thermal is None or not all(t is not None for pair in temps for t in pair):
        thermal = None
    # β per axis only where the result applied it, and only the loops it used (issue 33; older results: all, β on)
    applied = res.get("thermal_applied") if isinstance(res.get("thermal_applied"), dict) else None
    in_use = set(res["loops_used"]) if isinstance(res.get("loops_used"), list) else None
    views, t3, t5, used, total = [], [], [], 0, 0
    for j, (lp, loop) in enumerate(zip(loops, raw, strict=True)):
        ok = integrity.valid_mask(loop.torque_a3_nm, loop.torque_a5_nm)  # missing in one channel: in both
        a3 = axis_processing(np.where(ok, loop.torque_a3_nm, np.nan), loop.period_s, cfg)
        a5 = axis_processing(np.where(ok, loop.torque_a5_nm, np.nan), loop.period_s, cfg)
        m3, m5 = a3.loop_mean_nm, a5.loop_mean_nm
        if thermal is not None and (applied is None or applied.get("A3")):
            m3 = float(thermal.correct_nm("A3", m3, float(temps[j][0])))
        if thermal is not None and (applied is None or applied.get("A5")):
            m5 = float(thermal.correct_nm("A5", m5, float(temps[j][1])))
        gross = float(cal.mass_kg(pp.normalise(m3, bias3), pp.normalise(m5, bias5)))
        views.append(LoopView(lp.index, lp, loop.period_s, a3, a5, gross))
        if in_use is not None and loop.trace not in in_use:
            continue
        t3.append(m3)
        t5.append(m5)
        used += min(a3.n_used, a5.n_used)
        total += a3.n_total
    # eq. 16 over the loops of the normalised loop means, then eq. 21: exactly as the pipeline computes the mass
    w3 = pp.double_average_nm(pp.normalise(np.array(t3), bias3))
    w5 = pp.double_average_nm(pp.normalise(np.array(t5), bias5))
    gross = float(cal.mass_kg(w3, w5))
    # The uncertainty budget (u, U) depends on inputs beyond the raw files (g of the site, alternative models):
    # it is shown as stored, not recomputed. Everything that follows from raw files and calibration is checked.
    again = {"gross_mass_kg": gross, "mass_kg": gross - fixture, "loops": len(t3), "samples_used": used,
             "samples_total": total, "calibration_id": cal_id, "method": cal.method}
    multipose = res.get("mass_method") == "multipose"
    single = (res.get("mass_methods") or {}).get("single") if multipose else None
    for key, value in again.items():
        if multipose and key in ("gross_mass_kg", "mass_kg"):  # the result's mass is the multi-pose one (below)
            if key == "mass_kg" and isinstance(single, dict) and "mass_kg" in single:
                _check(checks, "result mass_methods.single.mass_kg", single["mass_kg"], value)
            continue
        if key in res:
            _check(checks, f"result {key}", res[key], value)
    cog = None
    if isinstance(res.get("cog_poses"), list):
        cog = _recompute_cog(root, run, all_loops, files, res, doc, checks)
    inertia = None
    if "principal_moments_kgm2" in res:
        inertia = _recompute_inertia(root, run, all_loops, files, res, doc, checks)
    refs = ref.references(repo, run_id)
    return MeasurementView(run, result, results, views, files, calv, refs, w3, w5, checks,
                           repo.events(run_id=run_id), cog, inertia)


def _recompute_inertia(root: Path, run: RunRecord, loops: list[LoopRecord], files: list[TraceFileRecord],
                       res: dict[str, Any], cal_doc: dict[str, Any], checks: list[str]) -> dict[str, Any]:
    """The inertia of a properties run recomputed from its archived excitation traces with
    :func:`analysis.inertia.compute_inertia_dir` (mass, CoG, fixture and DuT frame as the result states them) and
    checked against the stored one; returns the stored identification (``inertia``)."""
    stored = res.get("inertia")
    traces = res.get("inertia_traces")
    if not isinstance(stored, dict) or not isinstance(traces, dict):
        raise DataError(f"run {run.id}: result with principal moments but without its 'inertia' and "
                        "'inertia_traces' objects")
    by_trace = {lp.trace_name: lp for lp in loops}
    setup = run.config.get("settings", {})
    props = _fixture_of(run.config.get("properties", {}))
    with tempfile.TemporaryDirectory(prefix="rgse-report-inertia-") as tmp:
        directory = Path(tmp)
        for trace in [*traces.get("dut", []), *traces.get("tare", [])]:
            if trace not in by_trace:
                raise ReportConsistencyError(f"run {run.id}: inertia excitation trace {trace} not recorded")
            for f in files:
                if f.loop_index == by_trace[trace].index:
                    (directory / PurePosixPath(f.path).name).write_bytes((root / f.path).read_bytes())
        man = inertia_analysis.InertiaManifest(
            tuple(traces["dut"]), tuple(traces["tare"]), tuple(setup.get("meas_pose_deg", [])),
            float(stored["mass_kg"]), tuple(stored["cog_flange_m"]), tuple(stored["U_cog_flange_m"]),
            tuple(stored["dut_abc_deg"]), float(res.get("fixture_mass_kg", 0.0)),
            tuple(props["cog_flange_m"]))
        (directory / inertia_analysis.MANIFEST).write_text(man.to_toml(), encoding="utf-8")
        cal_path = directory / "CAL.json"
        cal_path.write_text(json.dumps(cal_doc), encoding="utf-8")
        again = inertia_analysis.compute_inertia_dir(directory, cal_path).to_json()
    for key in ("principal_moments_kgm2", "U_principal_moments_kgm2"):
        for k, (a, b) in enumerate(zip(res[key], again[key], strict=True)):
            _check(checks, f"result {key}[{k}]", a, b)
    return stored


def _recompute_cog(root: Path, run: RunRecord, loops: list[LoopRecord], files: list[TraceFileRecord],
                   res: dict[str, Any], cal_doc: dict[str, Any], checks: list[str]) -> dict[str, Any]:
    """The CoG of a properties run recomputed from its archived pose loops with :func:`analysis.cog.compute_cog`
    (the fixture frame and the scheme's poses as the result states them, the mass as stored), checked against the
    stored one; returns the stored CoG result (``cog``)."""
    stored = res.get("cog")
    if not isinstance(stored, dict):
        raise DataError(f"run {run.id}: properties result without its 'cog' object")
    by_trace = {lp.trace_name: lp for lp in loops}
    setup = run.config.get("settings", {})
    fixture = cog_analysis.FixtureFrame.from_json(
        {"mass_kg": res.get("fixture_mass_kg", 0.0), **_fixture_of(run.config.get("properties", {}))},
        f"run {run.id} properties fixture")
    with tempfile.TemporaryDirectory(prefix="rgse-report-cog-") as tmp:
        directory = Path(tmp)
        poses = []
        for pose in res["cog_poses"]:
            for trace in pose["traces"]:
                if trace not in by_trace:
                    raise ReportConsistencyError(f"run {run.id}: CoG pose {pose['name']} loop {trace} not recorded")
                _loop_directory(root, by_trace[trace], files)  # its files lie in one archive directory
                for f in files:
                    if f.loop_index == by_trace[trace].index:
                        (directory / PurePosixPath(f.path).name).write_bytes((root / f.path).read_bytes())
            poses.append((pose["name"], pose["q_deg"], pose["traces"]))
        (directory / "manifest.toml").write_text(
            f'[setup]\nrobot = "{run.robot}"\ng = {float(setup.get("g_m_s2", 9.81))!r}\n'
            f'lever_difference_m = {float(setup.get("lever_difference_m", 0.0))!r}\n\n'
            + cog_analysis.properties_manifest_toml(str(stored.get("scheme", "custom")), fixture, poses,
                                                    mass_kg=float(res["mass_kg"]), u_mass_kg=float(res["u_kg"])),
            encoding="utf-8")
        cal_path = directory / "CAL.json"
        cal_path.write_text(json.dumps(cal_doc), encoding="utf-8")
        again = cog_analysis.compute_cog_dir(directory, cal_path).to_json()
        if res.get("mass_method") == "multipose":  # the mass from the lever poses' torque differences (MP1-MP3)
            mp = multipose_analysis.compute_multipose_dir(directory, cal_path,
                                                          float(res.get("fixture_mass_kg", 0.0)),
                                                          multipose_drift_prior_per_k(res)).to_json()
            for key in ("mass_kg", "gross_mass_kg", "U_kg"):
                if key in res:
                    _check(checks, f"result {key} (multi-pose)", res[key], mp[key])
    for key in ("cog_flange_m", "U_cog_flange_m", "cog_dut_m", "U_cog_dut_m"):
        for axis, (a, b) in enumerate(zip(stored[key], again[key], strict=True)):
            _check(checks, f"result cog {key}[{axis}]", a, b)
    return stored


def multipose_drift_prior_per_k(res: dict[str, Any]) -> float:
    """The drift prior (1/K) the result's multi-pose mass was computed with (its U carries it where β is not
    applied): ``mass_methods.multipose.drift_prior_per_k``; the default for results that do not state it."""
    prior = ((res.get("mass_methods") or {}).get("multipose") or {}).get("drift_prior_per_k")
    return DRIFT_PRIOR_PER_K if prior is None else float(prior)


def _fixture_of(props: dict[str, Any]) -> dict[str, Any]:
    return {"cog_flange_m": props.get("fixture_cog_flange_m") or [0.0, 0.0, 0.0],
            "dut_origin_flange_m": props.get("dut_origin_flange_m", [0.0, 0.0, 0.0]),
            "dut_abc_deg": props.get("dut_abc_deg", [0.0, 0.0, 0.0])}


def meta(repo: Repository) -> ReportMeta:
    return ReportMeta(__version__, datetime.now(UTC), repo.description)
