"""The in-line mass of a measurement directory with a calibration file (eq. 16, 21 and the U budget).

One code path for ``rgse mass`` and the daemon's measurement run, so a stored result is always reproducible from
its raw files."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import Loop, load_manifest, read_loops, thermal_state_k
from rgse_daemon.pipeline import inline, integrity
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.calibration import Calibration
from rgse_daemon.verdict import status_of

#: Largest accepted difference between the measurement's and the calibration's mean A3/A5 motor temperature (K).
THERMAL_MISMATCH_K = 3.0


@dataclass
class MassResult:
    mass_kg: float
    u_kg: float
    U_kg: float
    gross_mass_kg: float
    fixture_mass_kg: float
    loops: int
    samples_used: int
    samples_total: int
    calibration_id: str
    method: str
    warnings: list[str] = field(default_factory=list)
    u_components_kg: dict[str, float] = field(default_factory=dict)
    motor_temp_k: dict[str, float] | None = None
    operating_point: str = "inside"
    loops_used: list[str] = field(default_factory=list)
    """The loops the mass rests on (trace names)."""
    loops_set_aside: list[dict[str, str]] = field(default_factory=list)
    """The loops left out, each ``{"loop", "reason"}`` (pipeline.integrity); their raw files stay archived."""
    thermal_applied: dict[str, bool] = field(default_factory=dict)
    """Per axis, whether the campaign's thermal drift β was applied (empty: no β or no temperatures)."""
    thermal_notes: dict[str, str] = field(default_factory=dict)
    """Per axis, how the drift was treated (:attr:`~rgse_daemon.pipeline.inline.InlineMass.thermal_notes`)."""

    def to_json(self) -> dict[str, Any]:
        return {"mass_kg": self.mass_kg, "u_kg": self.u_kg, "U_kg": self.U_kg, "k": int(unc.COVERAGE_K),
                "gross_mass_kg": self.gross_mass_kg, "fixture_mass_kg": self.fixture_mass_kg, "loops": self.loops,
                "samples_used": self.samples_used, "samples_total": self.samples_total,
                "calibration_id": self.calibration_id, "method": self.method, "cog_m": None,
                "warnings": self.warnings, "u_components_kg": self.u_components_kg,
                "motor_temp_k": self.motor_temp_k, "operating_point": self.operating_point,
                "loops_used": self.loops_used, "loops_set_aside": self.loops_set_aside,
                "thermal_applied": self.thermal_applied, "thermal_notes": self.thermal_notes,
                "status": status_of({"warnings": self.warnings})}


def measure(loops: list[Loop], cal: calfile.CalFile, pre: pp.Preprocessing, fixture_mass_kg: float,
            g_measurement_m_s2: float | None = None, g_u_measurement_m_s2: float = 0.0,
            envelope_limit: float = inline.env_mod.DEFAULT_LIMIT,
            drift_prior_per_k: float = inline.DRIFT_PRIOR_PER_K) -> MassResult:
    """Pre-process every loop, set the disturbed ones aside (a frozen torque channel or a repeated loop first, then
    what :func:`~rgse_daemon.pipeline.inline.in_line_mass` screens), average (eq. 16), normalise with the
    calibration's M_0, apply eq. 21, budget U."""
    unusable, loops = unusable_loops(loops, pre, cal.provenance.axes_deg)
    if not loops:
        raise integrity.TooFewLoops(inline.too_few(0, unusable), [], unusable)
    r = inline.in_line_mass([(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in loops],
                            cal.mass_calibration(), pre, fixture_mass_kg=fixture_mass_kg,
                            g_measurement_m_s2=g_measurement_m_s2, g_u_measurement_m_s2=g_u_measurement_m_s2,
                            envelope_limit=envelope_limit,
                            loop_temps_k=[(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in loops],
                            drift_prior_per_k=drift_prior_per_k, set_aside=unusable)
    return MassResult(r.mass_kg, r.uncertainty.u_kg, r.uncertainty.expanded_kg, r.gross_mass_kg, fixture_mass_kg,
                      len(r.loops_used), r.samples_used, r.samples_total, cal.calibration_id, r.method,
                      r.warnings, r.uncertainty.components(), operating_point=r.operating_point,
                      loops_used=r.loops_used, loops_set_aside=[a.to_dict() for a in r.loops_set_aside],
                      thermal_applied=r.thermal_applied, thermal_notes=r.thermal_notes)


#: How far (deg) a loop's A3 or A5 position may lie from the calibration's measurement pose (CAL.json
#: ``measurement_axes_deg``). A drive holds its position to well below 0.01° at standstill; in the KR 500's measurement
#: pose eq. 21's lever difference changes by about 0.5 % of the mass per degree of A3 (simulated: +10° gave −7 %), so
#: 0.1° stays below 0.1 % while a loop recorded in another pose is caught.
AXIS_TOLERANCE_DEG = 0.1


def pose_reason(axes_deg: tuple[float, float] | None, calibrated_deg: dict[str, float] | None) -> str | None:
    """Why a loop recorded at ``axes_deg`` (A3, A5; deg) cannot be weighed with a calibration made in
    ``calibrated_deg``: it lies more than :data:`AXIS_TOLERANCE_DEG` away on A3 or A5; None if it does not or either
    is unknown (a trace without ``Istposition``, a CAL.json that does not record the pose)."""
    if axes_deg is None or calibrated_deg is None:
        return None
    off = [(ax, q, calibrated_deg[ax]) for ax, q in zip(("A3", "A5"), axes_deg, strict=True)
           if abs(q - calibrated_deg[ax]) > AXIS_TOLERANCE_DEG]
    if not off:
        return None
    where = ", ".join(f"{ax} at {q:.3f}° instead of {c:.3f}°" for ax, q, c in off)
    return (f"recorded in another pose than the calibration's ({where}; limit {AXIS_TOLERANCE_DEG:g}°): eq. 21's "
            f"levers hold only in the pose the calibration was made in")


def unusable_loops(loops: list[Loop], pre: pp.Preprocessing, calibrated_deg: dict[str, float] | None = None
                   ) -> tuple[list[integrity.SetAside], list[Loop]]:
    """The loops recorded in another pose than the calibration's (:func:`pose_reason`; ``calibrated_deg``: CAL.json
    ``measurement_axes_deg``), whose A3 or A5 torque channel is frozen
    (:func:`~rgse_daemon.pipeline.integrity.frozen_reason`) or that repeat an earlier loop sample for sample
    (:class:`~rgse_daemon.pipeline.integrity.Repeats`), each with its reason, and the others. Checked on the trace
    files' samples: a synthetic noiseless loop handed to the pipeline directly is not a frozen sensor."""
    aside, rest = [], []
    repeats = integrity.Repeats()
    for lp in loops:
        reason = (pose_reason(lp.axes_deg, calibrated_deg)
                  or integrity.frozen_reason((("A3", lp.torque_a3_nm), ("A5", lp.torque_a5_nm)),
                                             round(pre.settle_s / lp.period_s))
                  or repeats.reason(lp.trace, lp.torque_a3_nm, lp.torque_a5_nm))
        if reason is None:
            rest.append(lp)
        else:
            aside.append(integrity.SetAside(lp.trace, reason))
    return aside, rest


#: How far the measurement's Δr (m) and g (m/s²) may differ from the calibration's: a calibration holds for its own
#: measurement pose and site (1 mm and 0.01 m/s² are 0.1 % of the mass). Smaller differences draw a warning.
POSE_TOLERANCE_M = 1e-3
G_TOLERANCE_M_S2 = 0.01


def check_pose(where: Path, lever_difference_m: float, g_m_s2: float, cal: Calibration) -> None:
    """Refuse a measurement whose pose (Δr) or g is not the calibration's (eq. 21 uses the calibration's)."""
    calfile.plausible_g(g_m_s2, f"{where}: g")
    if abs(lever_difference_m - cal.lever_difference_m) > POSE_TOLERANCE_M or abs(g_m_s2 - cal.g_m_s2) > \
            G_TOLERANCE_M_S2:
        raise DataError(f"{where}: the measurement's Δr = {lever_difference_m} m and g = {g_m_s2} m/s² are not the "
                        f"calibration's ({cal.lever_difference_m} m, {cal.g_m_s2} m/s²): a calibration holds for its "
                        f"own measurement pose and site")


def compute(directory: Path, calibration_path: Path, fixture_mass_kg: float | None = None,
            envelope_limit: float = inline.env_mod.DEFAULT_LIMIT,
            drift_prior_per_k: float = inline.DRIFT_PRIOR_PER_K):
    """The in-line mass of a measurement directory (interfaces §2) with a calibration file: what ``rgse mass`` prints,
    and what the daemon stores — one code path, so a stored result is always reproducible from its raw files."""
    man = load_manifest(directory)
    if not man.measurement_traces:
        raise DataError(f"{man.path}: no [measurement] table (is this a calibration campaign?)")
    calf = calfile.read(calibration_path)
    calfile.check_robot(calibration_path, calf, man.setup.robot)
    cal, pre = calf.calibration, calf.preprocessing
    check_pose(man.path, man.setup.lever_difference_m, man.setup.g_m_s2, cal)
    fixture = fixture_mass_kg if fixture_mass_kg is not None else (man.fixture_mass_kg or 0.0)
    if not np.isfinite(fixture) or fixture < 0:
        raise DataError(f"fixture mass must be a finite mass >= 0 kg, got {fixture}")
    loops = read_loops(directory, man.measurement_traces)
    result = measure(loops, calf, pre or pp.PAPER, fixture, man.setup.g_m_s2, man.setup.g_u_m_s2 or 0.0,
                     envelope_limit, drift_prior_per_k)
    rate = period_mismatch(loops[0].period_s, calf.fit.sample_period_s, pre or pp.PAPER)
    if rate is not None:
        result.warnings.append(rate)
    if abs(man.setup.lever_difference_m - cal.lever_difference_m) > 1e-6 or abs(man.setup.g_m_s2 - cal.g_m_s2) > 1e-6:
        result.warnings.append("measurement pose (lever_difference_m, g) differs from the calibration's")
    result.motor_temp_k = thermal_state_k(loops)
    mismatch = thermal_mismatch(result.motor_temp_k, calf.provenance.thermal_state_k,
                                corrected=any(result.thermal_applied.values()))
    if mismatch is not None:
        result.warnings.append(mismatch)
    return result


def budget(directory: Path, traces: Sequence[str], calibration_path: Path, fixture_mass_kg: float,
           g_m_s2: float | None = None, g_u_m_s2: float = 0.0,
           drift_prior_per_k: float = inline.DRIFT_PRIOR_PER_K) -> MassResult:
    """The mass and its U budget from the loops ``traces`` of ``directory`` so far, by the same :func:`measure` as
    :func:`compute` (no manifest needed): what the stop rule (pipeline/stopping.py) predicts from during a run."""
    calf = calfile.read(calibration_path)
    loops = read_loops(directory, tuple(traces))
    return measure(loops, calf, calf.preprocessing or pp.PAPER, fixture_mass_kg, g_m_s2, g_u_m_s2,
                   drift_prior_per_k=drift_prior_per_k)


def _ms(period_s: float) -> str:
    return f"{period_s * 1e3:g} ms"


def period_mismatch(trace_period_s: float, calibration_period_s: float | None, pre: pp.Preprocessing) -> str | None:
    """A warning when the measurement's trace sample period (s; one for all its loops) is not the calibration
    campaign's (CAL.json ``fit.sample_period_s``): the pre-processing counts its filter window in samples, so the
    window spans another time, and the calibration was not validated at this rate. None when they agree (to float
    tolerance) or the calibration file does not record its period (older files, a points CSV: nothing to compare)."""
    if calibration_period_s is None or math.isclose(trace_period_s, calibration_period_s, rel_tol=1e-6):
        return None
    window = ("" if pre.filter == "none" else
              f"the {pre.filter} window of {pre.window} samples spans {pre.window * trace_period_s:g} s instead of "
              f"{pre.window * calibration_period_s:g} s, and ")
    return (f"trace sample period {_ms(trace_period_s)} differs from the calibration campaign's "
            f"{_ms(calibration_period_s)}: {window}the calibration was not validated at this rate; record the DuT at "
            f"{_ms(calibration_period_s)} or calibrate at {_ms(trace_period_s)}")


def thermal_mismatch(measured_k: dict[str, float] | None, calibration_k: Any, corrected: bool = False) -> str | None:
    """A warning when the A3/A5 motor temperatures of the measurement differ from the calibration campaign's by more
    than :data:`THERMAL_MISMATCH_K` (the torque estimate drifts with motor temperature). ``corrected``: the loops
    were brought to the campaign's temperature with its drift coefficient (``fit.thermal``, its uncertainty in U),
    which rests on a few K of warming within the campaign's points: the warning says so."""
    if measured_k is None or not isinstance(calibration_k, dict):
        return None
    diffs = {ax: measured_k[ax] - float(calibration_k[ax]) for ax in ("A3", "A5") if ax in calibration_k}
    off = {ax: d for ax, d in diffs.items() if abs(d) > THERMAL_MISMATCH_K}
    if not off:
        return None
    text = ", ".join(f"{ax} {d:+.1f} K" for ax, d in off.items())
    if corrected:
        return (f"motor temperatures differ from the calibration campaign's ({text}; limit {THERMAL_MISMATCH_K:g} "
                f"K): corrected with the campaign's thermal drift (extrapolated, its uncertainty in U); warming "
                f"up until steady avoids the extrapolation")
    return (f"motor temperatures differ from the calibration campaign's ({text}; limit {THERMAL_MISMATCH_K:g} K): "
            f"warm up until steady, or re-calibrate")
