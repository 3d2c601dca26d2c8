"""The centre of gravity of a DuT from a mass-properties run (issue #14): bias-corrected torques in the poses of a
scheme, the per-axis K of CAL.json's ``torsional`` section, the mass from the mass run, the fixture frame.

One code path for ``rgse cog`` and the daemon's properties run, so a stored CoG is always reproducible from its
raw files (``compute_cog_dir``). The numbers are computed in :mod:`rgse_daemon.pipeline.cog`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon import kinematics as kin
from rgse_daemon.analysis import mass as mass_analysis
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import (
    TORQUE_CHANNEL,
    Manifest,
    TorsionalPointSpec,
    check_keys,
    check_one_period,
    check_scheme,
    load_manifest,
    mean_temperature_k,
    plausible_period_s,
    read_toml,
)
from rgse_daemon.pipeline import cog as cog_mod
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import torsion
from rgse_daemon.pipeline.cog import CogPose, cog_poses
from rgse_daemon.pipeline.uncertainty import COVERAGE_K
from rgse_daemon.trace.diadem import read_trace_set
from rgse_daemon.trace.names import plain_name
from rgse_daemon.verdict import status_of

#: Largest difference (deg) between a reading's pose and the calibration's pose of the same name.
POSE_TOLERANCE_DEG = 0.5
__all__ = ["CogPose", "CogResult", "FixtureFrame", "PoseReading", "cog_poses", "compute_cog", "compute_cog_dir",
           "properties_manifest_toml", "read_properties_dir", "torsional_calibration"]
DRIVE_MODULE = "NextGenDrive#{}"


@dataclass(frozen=True)
class PoseReading:
    """Mean torques of one pose of a properties run: A1..A6 in deg (as commanded or measured), the mean
    ``Istmoment`` A1..A6 over its traces (Nm, NaN where not traced) and the standard error of each mean."""

    pose: str
    q_deg: tuple[float, ...]
    torque_nm: tuple[float, ...]
    sigma_nm: tuple[float, ...]
    motor_temp_k: tuple[float, ...] | None = None
    """Mean ``Motortemperatur`` A1..A6 over the traces (K, NaN where not recorded); None when unknown."""


@dataclass(frozen=True)
class FixtureFrame:
    """The fixture between MPA and DuT, and where the DuT's own frame sits: fixture mass (kg) and CoG in the
    flange frame (m), the DuT frame's origin in the flange frame (m) and its KUKA A, B, C (Z-Y-X, deg)."""

    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    dut_origin_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dut_abc_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        values = [self.mass_kg, *self.cog_flange_m, *self.dut_origin_flange_m, *self.dut_abc_deg]
        if (len(self.cog_flange_m), len(self.dut_origin_flange_m), len(self.dut_abc_deg)) != (3, 3, 3) or not all(
                isinstance(v, int | float) and math.isfinite(v) for v in values):
            raise DataError(f"fixture frame: mass, CoG, DuT origin and A, B, C must be finite numbers (three each), "
                            f"got {self!r}")
        if self.mass_kg < 0:
            raise DataError(f"fixture frame: mass must be >= 0 kg, got {self.mass_kg}")

    def to_json(self) -> dict[str, Any]:
        return {"mass_kg": self.mass_kg, "cog_flange_m": list(self.cog_flange_m),
                "dut_origin_flange_m": list(self.dut_origin_flange_m), "dut_abc_deg": list(self.dut_abc_deg)}

    @staticmethod
    def from_json(d: dict[str, Any], where: str = "fixture") -> FixtureFrame:
        if not isinstance(d, dict):
            raise DataError(f"{where}: must be a table/object")
        try:
            return FixtureFrame(float(d["mass_kg"]), tuple(float(v) for v in d["cog_flange_m"]),
                                tuple(float(v) for v in d.get("dut_origin_flange_m", (0.0, 0.0, 0.0))),
                                tuple(float(v) for v in d.get("dut_abc_deg", (0.0, 0.0, 0.0))))
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{where}: needs mass_kg and cog_flange_m [x, y, z] (and optionally dut_origin_flange_m,"
                            f" dut_abc_deg): {exc!r}") from None


@dataclass(frozen=True)
class CogResult:
    """The DuT's CoG in the flange and DuT frames (m) with U (k = 2) per coordinate, the mass it used, warnings and
    the uncertainty budget (standard uncertainties per source, the fit's diagnostics)."""

    cog_flange_m: tuple[float, float, float]
    U_cog_flange_m: tuple[float, float, float]
    cog_dut_m: tuple[float, float, float]
    U_cog_dut_m: tuple[float, float, float]
    mass_kg: float
    U_mass_kg: float
    scheme: str
    n_poses: int
    warnings: tuple[str, ...]
    budget: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"cog_flange_m": list(self.cog_flange_m), "U_cog_flange_m": list(self.U_cog_flange_m),
                "cog_dut_m": list(self.cog_dut_m), "U_cog_dut_m": list(self.U_cog_dut_m), "k": int(COVERAGE_K),
                "mass_kg": self.mass_kg, "U_mass_kg": self.U_mass_kg, "scheme": self.scheme,
                "n_poses": self.n_poses, "warnings": list(self.warnings), "budget": self.budget,
                "status": status_of({"warnings": self.warnings})}


def _three(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def compute_cog(readings: Sequence[PoseReading], tors: calfile.Torsional | None, *, g_m_s2: float,
                calibration_id: str | None, mass_kg: float, u_mass_kg: float, fixture: FixtureFrame) -> CogResult:
    """The DuT's CoG from its pose readings and a calibration's torsional section (CAL.json ``torsional``).

    ``mass_kg``: the DuT's mass from the mass run (fixture excluded), ``u_mass_kg`` its *standard* uncertainty
    (the mass result's ``u_kg``). Each reading is bias-corrected with the calibration's bare reading of the pose of
    the same name (the MPA stays on; fixture and DuT are what the torques carry beyond it), converted to payload
    torque with the axis' K, and fitted by :func:`rgse_daemon.pipeline.cog.estimate_cog_gls`.
    DataError naming CAL.json when the calibration has no torsional section or lacks a pose's bias.
    """
    where = "CAL.json"
    if tors is None:
        raise DataError(f"{where}: the calibration has no 'torsional' section (no CoG calibration: run a campaign "
                        f"with torsional points, then rgse calibrate); the CoG cannot be computed")
    if not readings:
        raise DataError("CoG: no pose readings")
    if not (math.isfinite(mass_kg) and mass_kg > 0):
        raise DataError(f"CoG: DuT mass must be a finite mass > 0 kg, got {mass_kg}")
    if not (math.isfinite(u_mass_kg) and u_mass_kg >= 0):
        raise DataError(f"CoG: u_mass_kg must be finite and >= 0, got {u_mass_kg}")
    g = g_m_s2
    warnings: list[str] = []
    poses = []
    names = [r.pose for r in readings]
    if len(set(names)) != len(names):
        raise DataError(f"CoG: pose names repeat: {names}")
    for r in readings:
        cal_pose = tors.poses.get(r.pose)
        if cal_pose is None:
            raise DataError(f"{where}: torsional section has no bias for pose {r.pose!r} "
                            f"(it has {', '.join(tors.poses)})")
        q = np.asarray(r.q_deg, dtype=float)
        if q.shape != (6,) or len(r.torque_nm) != 6 or len(r.sigma_nm) != 6:
            raise DataError(f"CoG: pose {r.pose}: q_deg, torque_nm and sigma_nm need six entries (A1..A6)")
        dq = float(np.max(np.abs(q - np.asarray(cal_pose.q_deg))))
        if dq > POSE_TOLERANCE_DEG:
            raise DataError(f"CoG: pose {r.pose} at {q.tolist()} deg differs from the calibration's "
                            f"{list(cal_pose.q_deg)} by {dq:.2f} deg (limit {POSE_TOLERANCE_DEG} deg)")
        tau, sig = np.asarray(r.torque_nm, float), np.asarray(r.sigma_nm, float)
        bias, u_bias = np.asarray(cal_pose.bias_nm), np.asarray(cal_pose.u_bias_nm)
        usable = [ax for ax in tors.gains if np.isfinite(tau[ax - 1]) and np.isfinite(bias[ax - 1])]
        if not usable:
            raise DataError(f"CoG: pose {r.pose}: no calibrated axis (A{', A'.join(map(str, tors.gains))}) has both "
                            f"a torque and a bias")
        poses.append(cog_mod.PoseTorques(r.pose, tuple(q.tolist()), tuple((tau - bias).tolist()),
                                         tuple(np.where(np.isfinite(sig), sig, 0.0).tolist()),
                                         tuple(np.where(np.isfinite(u_bias), u_bias, 0.0).tolist())))
    fit = cog_mod.estimate_cog_gls(poses, tors.gains, dut_mass_kg=mass_kg, u_dut_mass_kg=u_mass_kg,
                                   fixture_mass_kg=fixture.mass_kg, fixture_cog_m=fixture.cog_flange_m, g_m_s2=g)
    for ax in fit.outside_range:
        warnings.append(f"{ax}: payload torques outside what the torsional calibration covered; U does not cover "
                        f"the extrapolation")
    if np.isfinite(fit.chi2_red) and fit.chi2_red > 4.0:
        warnings.append(f"the poses disagree more than their noise explains (reduced chi2 {fit.chi2_red:.1f}); "
                        f"U is scaled by it")
    mismatch = thermal_mismatch(thermal_state_k(readings), tors.thermal_state_k)
    if mismatch is not None:
        warnings.append(mismatch)
    c_dut, cov_dut = cog_mod.to_dut_frame(fit.cog_m, fit.cov_m2, fixture.dut_origin_flange_m, fixture.dut_abc_deg)
    u_flange = np.sqrt(np.diag(fit.cov_m2))
    budget: dict[str, Any] = {
        "u_flange_m": {k: np.sqrt(np.diag(v)).tolist() for k, v in fit.cov_parts_m2.items()},
        "covariance_flange_m2": fit.cov_m2.tolist(),
        "covariance_dut_m2": cov_dut.tolist(),
        "chi2_red": None if not np.isfinite(fit.chi2_red) else fit.chi2_red,
        "n_equations": fit.n_equations,
        "fitted_offsets_nm": fit.offsets_nm,
        "axes": [f"A{ax}" for ax in sorted(tors.gains)],
        "calibration_id": calibration_id,
    }
    if tors.scheme != "?" and {r.pose for r in readings} - set(tors.poses):
        warnings.append("poses outside the calibration's scheme")
    paper = _eq5_7(readings, tors, mass_kg + fixture.mass_kg)
    if paper is not None:
        budget["eq5_7_levers_m"] = paper
    scheme = _scheme_of(names)
    return CogResult(_three(fit.cog_m), _three(COVERAGE_K * u_flange), _three(c_dut),
                     _three(COVERAGE_K * np.sqrt(np.diag(cov_dut))), float(mass_kg), COVERAGE_K * float(u_mass_kg),
                     scheme, len(readings), tuple(warnings), budget)


def _scheme_of(names: Sequence[str]) -> str:
    for scheme in ("full", "paper"):
        if set(names) == {p.name for p in cog_mod.cog_poses(kin.measurement_pose(), scheme)}:
            return scheme
    return "custom"


def _eq5_7(readings: Sequence[PoseReading], tors: calfile.Torsional, total_mass_kg: float) -> dict | None:
    """The paper's levers a, b, c (eq. 5–7) of fixture + DuT, from A5 at 0° and A6 at 0°/90° (K applied), for
    comparison with the least-squares estimate; None without those poses."""
    by_name = {r.pose: r for r in readings}
    if "meas" not in by_name or "A6+90" not in by_name or 5 not in tors.gains or 6 not in tors.gains:
        return None

    def x(pose: str, ax: int) -> float:
        r = by_name[pose].torque_nm[ax - 1] - tors.poses[pose].bias_nm[ax - 1]
        return float(tors.gains[ax].payload_torque_nm(np.array([r]))[0])

    try:
        a, b, c = cog_mod.cog_paper(total_mass_kg, -x("meas", 5), x("meas", 6), x("A6+90", 6))
    except DataError:
        return None
    return {"a": float(a), "b": float(b), "c": float(c)}


# ---------------------------------------------------------------------------------------------------------------------
# The run directory of a properties run (interfaces §2)
# ---------------------------------------------------------------------------------------------------------------------
def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _toml_list(values: Sequence[float]) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def properties_manifest_toml(scheme: str, fixture: FixtureFrame,
                             poses: Sequence[tuple[str, Sequence[float], Sequence[str]]], *,
                             mass_kg: float | None = None, u_mass_kg: float | None = None,
                             shared_pose: str | None = None) -> str:
    """The ``[properties]`` tables of a properties run's ``manifest.toml`` (after ``[setup]`` and, usually, the
    ``[measurement]`` of the mass loops): the scheme, the fixture frame and one ``[[properties.pose]]`` per pose
    (name, A1..A6 in deg, its trace names). ``mass_kg``/``u_mass_kg`` (standard uncertainty): the DuT's mass when it
    does not come from the directory's own ``[measurement]`` loops. ``shared_pose``: the pose whose loops include
    ``[measurement]`` loops, recorded in that very pose (``shares_measurement_loops = true``)."""
    for name, q, traces in poses:
        if len(q) != 6 or not traces:
            raise DataError(f"properties manifest: pose {name!r} needs six angles and at least one trace")
        for t in traces:
            plain_name(t, f"properties manifest: pose {name!r}")
    lines = ["[properties]", f"scheme = {_toml_str(scheme)}"]
    if mass_kg is not None:
        lines += [f"mass_kg = {float(mass_kg)!r}", f"u_mass_kg = {float(u_mass_kg or 0.0)!r}"]
    lines += ["", "[properties.fixture]", f"mass_kg = {float(fixture.mass_kg)!r}",
              f"cog_flange_m = {_toml_list(fixture.cog_flange_m)}",
              f"dut_origin_flange_m = {_toml_list(fixture.dut_origin_flange_m)}",
              f"dut_abc_deg = {_toml_list(fixture.dut_abc_deg)}"]
    for name, q, traces in poses:
        lines += ["", "[[properties.pose]]", f"name = {_toml_str(name)}", f"q_deg = {_toml_list(q)}",
                  "traces = [" + ", ".join(_toml_str(t) for t in traces) + "]"]
        if name == shared_pose:
            lines.append("shares_measurement_loops = true")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class PropertiesRun:
    """A properties run directory, read: robot, g, scheme, the mass (kg) and its standard uncertainty stated in
    ``[properties]`` (None: from the directory's ``[measurement]`` loops), the fixture frame, one reading per pose."""

    robot: str
    g_m_s2: float
    scheme: str
    mass_kg: float | None
    u_mass_kg: float | None
    fixture: FixtureFrame
    readings: list[PoseReading]
    period_s: float | None = None
    """The pose loops' one KUKA Trace sample period (s)."""


def _pose_reading(directory: Path, name: str, q: tuple[float, ...], traces: Sequence[str],
                  pre: pp.Preprocessing, periods: list[tuple[str, float]]) -> PoseReading:
    """Mean torque per axis over the pose's loops (eq. 16's double average), its standard error: the loops'
    scatter with two or more loops, else the within-loop standard error of the kept samples. Each trace file's
    sample period is appended to ``periods`` (checked by the caller: one period for the whole run)."""
    per_axis: dict[int, list[tuple[float, float]]] = {}
    temps: dict[int, list[float]] = {}
    for t in traces:
        ts = read_trace_set(directory, t)
        for ax in range(1, 7):
            module = DRIVE_MODULE.format(ax)
            if module not in ts.files:
                continue
            tf = ts.files[module]
            periods.append((f"trace {t!r} ({module})", plausible_period_s(tf.period_s, tf.dat_path)))
            values = np.asarray(ts.channel(module, TORQUE_CHANNEL).values, float)
            if values.size < 3 or not np.all(np.isfinite(values)):
                raise DataError(f"{tf.dat_path}: torque channel {TORQUE_CHANNEL!r} is too short or not finite")
            loop = pp.process_loop(values, float(tf.period_s), pre)
            kept = pp.kept_samples(values, float(tf.period_s), pre)
            per_axis.setdefault(ax, []).append((loop.torque_nm, float(np.std(kept) / np.sqrt(max(kept.size, 1)))))
            temp = mean_temperature_k(tf)
            temps.setdefault(ax, []).append(np.nan if temp is None else temp)
    torque = np.full(6, np.nan)
    sigma = np.full(6, np.nan)
    for ax, loops in per_axis.items():
        if len(loops) != len(traces):
            raise DataError(f"{directory}: pose {name!r}: A{ax} is traced in only {len(loops)} of {len(traces)} "
                            f"loops")
        means = np.array([m for m, _ in loops])
        torque[ax - 1] = pp.double_average_nm(means)
        within = float(np.sqrt(np.sum(np.array([s for _, s in loops]) ** 2))) / len(loops)
        between = float(np.std(means, ddof=1) / np.sqrt(len(means))) if len(means) > 1 else 0.0
        sigma[ax - 1] = max(within, between)
    temp_k = tuple(float(np.mean(temps[ax])) if ax in temps else float("nan") for ax in range(1, 7))
    return PoseReading(name, q, tuple(torque.tolist()), tuple(sigma.tolist()), temp_k)


def thermal_state_k(readings: Sequence[PoseReading]) -> dict[str, float] | None:
    """Mean motor temperature of A3..A6 over the readings (K), None when any of them lacks it."""
    out = {}
    for ax in torsion.COG_AXES:
        values = [r.motor_temp_k[ax - 1] for r in readings if r.motor_temp_k is not None]
        if len(values) != len(readings) or not values or not np.all(np.isfinite(values)):
            return None
        out[f"A{ax}"] = float(np.mean(values))
    return out


def thermal_mismatch(measured_k: dict[str, float] | None, calibration_k: Any) -> str | None:
    """A warning when the A3..A6 motor temperatures of the poses differ from the torsional campaign's by more than
    ``THERMAL_MISMATCH_K`` (every torque reading drifts with its motor's temperature; U does not model it)."""
    if measured_k is None or not isinstance(calibration_k, dict):
        return None
    off = {ax: measured_k[ax] - float(calibration_k[ax]) for ax in measured_k if ax in calibration_k}
    off = {ax: d for ax, d in off.items() if abs(d) > mass_analysis.THERMAL_MISMATCH_K}
    if not off:
        return None
    text = ", ".join(f"{ax} {d:+.1f} K" for ax, d in off.items())
    return (f"motor temperatures in the CoG poses differ from the torsional campaign's ({text}; limit "
            f"{mass_analysis.THERMAL_MISMATCH_K:g} K): warm up until steady, or re-calibrate")


#: The keys of ``[properties]``, ``[properties.fixture]`` and ``[[properties.pose]]``; others are refused.
PROPERTIES_KEYS = ("scheme", "mass_kg", "u_mass_kg", "fixture", "pose")
FIXTURE_KEYS = ("mass_kg", "cog_flange_m", "dut_origin_flange_m", "dut_abc_deg")
#: A ``[[properties.pose]]`` key: the pose's traces may include the ``[measurement]`` loops, which were recorded in
#: this very pose (same axes, same approach, same load, the A3..A6 trace); at most one pose has it.
SHARES_MEASUREMENT_LOOPS = "shares_measurement_loops"
PROPERTIES_POSE_KEYS = ("name", "q_deg", "traces", SHARES_MEASUREMENT_LOOPS)


def read_properties_dir(directory: Path | str, pre: pp.Preprocessing = pp.PAPER) -> PropertiesRun:
    """Read a properties run directory (``manifest.toml`` with ``[properties]``, trace files)."""
    directory = Path(directory)
    man = load_manifest(directory)
    doc = read_toml(man.path)
    where = f"{man.path} [properties]"
    props = doc.get("properties")
    if not isinstance(props, dict):
        raise DataError(f"{man.path}: no [properties] table (is this a properties run?)")
    check_keys(props, PROPERTIES_KEYS, where)
    scheme = check_scheme(props.get("scheme", "custom"), where)
    if isinstance(props.get("fixture"), dict):
        check_keys(props["fixture"], FIXTURE_KEYS, f"{where} fixture")
    mass = u_mass = None
    if "mass_kg" in props:
        try:
            mass = float(props["mass_kg"])
            u_mass = float(props.get("u_mass_kg", 0.0))
        except (TypeError, ValueError):
            raise DataError(f"{where}: mass_kg and u_mass_kg must be numbers") from None
        if not (math.isfinite(mass) and mass > 0 and math.isfinite(u_mass) and u_mass >= 0):
            raise DataError(f"{where}: mass_kg must be > 0 and u_mass_kg >= 0, got {mass}, {u_mass}")
    elif not man.measurement_traces:
        raise DataError(f"{where}: no mass_kg and no [measurement] loops to measure the mass from")
    fixture = FixtureFrame.from_json(props.get("fixture", {}), f"{where} fixture")
    poses = props.get("pose")
    if not isinstance(poses, list) or not poses:
        raise DataError(f"{where}: needs [[properties.pose]] entries")
    specs = []
    sharing: int | None = None
    for i, p in enumerate(poses):
        pw = f"{where} pose #{i + 1}"
        if not isinstance(p, dict) or not isinstance(p.get("name"), str):
            raise DataError(f"{pw}: needs a name")
        check_keys(p, PROPERTIES_POSE_KEYS, pw)
        q = p.get("q_deg")
        if not isinstance(q, list) or len(q) != 6 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in q):
            raise DataError(f"{pw}: q_deg must be six finite angles (deg)")
        traces = p.get("traces")
        if not isinstance(traces, list) or not traces or not all(isinstance(t, str) for t in traces):
            raise DataError(f"{pw}: traces must be a non-empty list of trace names")
        for t in traces:
            plain_name(t, f"{pw}: traces")
        shares = p.get(SHARES_MEASUREMENT_LOOPS, False)
        if not isinstance(shares, bool):
            raise DataError(f"{pw}: {SHARES_MEASUREMENT_LOOPS} must be true or false, got {shares!r}")
        if shares:
            if sharing is not None:
                raise DataError(f"{pw}: {SHARES_MEASUREMENT_LOOPS} already holds for pose #{sharing}; the mass "
                                f"loops were recorded in one pose")
            sharing = i + 1
        # the mass loops recorded in this very pose serve as its loops too: such a pose may list a [measurement]
        # trace (once); every other trace appears once in the manifest
        for t in traces:
            if shares and man.trace_places.get(t) == "[measurement]":
                man.trace_places[t] = f"[measurement] and [[properties.pose]] #{i + 1}"
            else:
                man.claim_traces([t], f"[[properties.pose]] #{i + 1}")
        specs.append((p["name"], tuple(float(v) for v in q), traces))
    periods: list[tuple[str, float]] = []
    readings = [_pose_reading(directory, name, q, traces, pre, periods) for name, q, traces in specs]
    check_one_period(periods, man.path)
    return PropertiesRun(man.setup.robot, man.setup.g_m_s2, scheme, mass, u_mass,
                         fixture, readings, periods[0][1] if periods else None)


def compute_cog_dir(directory: Path | str, calibration_path: Path | str, *, mass_kg: float | None = None,
                    u_mass_kg: float | None = None) -> CogResult:
    """The CoG of a properties run directory with a calibration file: what ``rgse cog`` prints and what the daemon
    stores — one code path, so a stored CoG is always reproducible from its raw files.

    The DuT's mass (and its standard uncertainty): ``mass_kg``/``u_mass_kg`` when given, else ``[properties]
    mass_kg``/``u_mass_kg``, else the in-line mass of the directory's ``[measurement]`` loops (as ``rgse mass``)."""
    calf = calfile.read(calibration_path)
    pre = calf.preprocessing
    run = read_properties_dir(directory, pre or pp.PAPER)
    calfile.check_robot(calibration_path, calf, run.robot)
    mass_warnings: list[str] = []
    if mass_kg is None:
        if run.mass_kg is not None:
            mass_kg, u_mass_kg = run.mass_kg, run.u_mass_kg
        else:
            mass = mass_analysis.compute(Path(directory), Path(calibration_path))
            mass_kg, u_mass_kg = mass.mass_kg, mass.u_kg
            mass_warnings = [f"mass: {w}" for w in mass.warnings]  # the mass the CoG rests on: its warnings hold
    try:
        result = compute_cog(run.readings, calf.torsional, calibration_id=calf.calibration_id, mass_kg=mass_kg,
                             u_mass_kg=u_mass_kg or 0.0, fixture=run.fixture,
                             g_m_s2=calf.calibration.g_m_s2 if run.g_m_s2 is None else run.g_m_s2)
    except DataError as exc:
        raise DataError(str(exc).replace("CAL.json", str(calibration_path))) from None
    cal_period_s = calf.fit.sample_period_s
    rate = None if run.period_s is None else mass_analysis.period_mismatch(run.period_s, cal_period_s, pre or pp.PAPER)
    warnings = [*mass_warnings, *result.warnings, *([rate] if rate is not None else [])]
    # (a trace-period warning is the mass loops' and the poses' alike: said once)
    warnings = list(dict.fromkeys(w for w in warnings if rate is None or w != f"mass: {rate}"))
    return dataclasses.replace(result, warnings=tuple(warnings))


# ---------------------------------------------------------------------------------------------------------------------
# The torsional calibration of a campaign directory (CAL.json ``torsional``)
# ---------------------------------------------------------------------------------------------------------------------
def torsional_calibration(directory: Path, man: Manifest, pre: pp.Preprocessing = pp.PAPER, *,
                          periods: Sequence[tuple[str, float]] = ()) -> calfile.Torsional:
    """The ``torsional`` section of CAL.json from a campaign's ``kind = "torsional"`` points: the bare MPA's mean
    torques per pose (the bias, with its standard error) and K per axis A3..A6 (:func:`pipeline.torsion.fit_torsional`,
    leave-one-point-out validation). ``periods``: the sample period of the campaign's mass loops (every loop of a
    campaign has one period)."""
    seen = list(periods)
    poses = [cog_mod.CogPose(p.name, p.q_deg) for p in man.torsional_poses]
    bias_specs = [pt for pt in man.torsional_points if pt.mass_kg == 0.0]
    if len(bias_specs) != 1:
        raise DataError(f"{man.path}: exactly one torsional point with mass_kg = 0 (the bias), found "
                        f"{len(bias_specs)}")

    every: list[PoseReading] = []

    def means(spec: TorsionalPointSpec) -> dict[str, torsion.PoseMean]:
        out = {}
        for p in poses:
            r = _pose_reading(directory, p.name, p.q_deg, spec.traces[p.name], pre, seen)
            every.append(r)
            out[p.name] = torsion.PoseMean(r.torque_nm, r.sigma_nm)
        return out

    bias = means(bias_specs[0])
    loaded = [torsion.TorsionalPoint(pt.mass_kg, pt.cog_flange_m, means(pt))
              for pt in man.torsional_points if pt.mass_kg > 0]
    check_one_period(seen, man.path)
    try:
        fit = torsion.fit_torsional(poses, bias, loaded, g_m_s2=man.setup.g_m_s2)
    except DataError as exc:
        raise DataError(f"{man.path}: {exc}") from None
    cal_poses = [calfile.TorsionalPose(p.name, p.q_deg, bias[p.name].torque_nm, bias[p.name].sigma_nm)
                 for p in poses]
    return calfile.Torsional(man.torsional_scheme or "custom", {p.name: p for p in cal_poses}, dict(fit.gains),
                             dict(fit.evaluations), len(loaded), thermal_state_k(every))
