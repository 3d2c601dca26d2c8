"""``rgse mass``: offline in-line mass of a DuT from a measurement directory and a CAL.json (contracts §1)."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import Loop, load_manifest, read_loops
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.calibration import Calibration

#: Fewer valid samples per loop than this draws a warning.
MIN_SAMPLES_PER_LOOP = 100


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

    def to_json(self) -> dict[str, Any]:
        return {"mass_kg": self.mass_kg, "u_kg": self.u_kg, "U_kg": self.U_kg, "k": int(unc.COVERAGE_K),
                "gross_mass_kg": self.gross_mass_kg, "fixture_mass_kg": self.fixture_mass_kg, "loops": self.loops,
                "samples_used": self.samples_used, "samples_total": self.samples_total,
                "calibration_id": self.calibration_id, "method": self.method, "cog_m": None,
                "warnings": self.warnings}


def measure(loops: list[Loop], cal: Calibration, cal_doc: dict[str, Any], pre: pp.Preprocessing,
            fixture_mass_kg: float) -> MassResult:
    """Pre-process every loop, average (eq. 16), normalise with the calibration's M_0, apply eq. 21."""
    bias3, bias5 = float(cal_doc["bias_nm"]["A3"]), float(cal_doc["bias_nm"]["A5"])
    t3, t5, se_mass, used, total = [], [], [], 0, 0
    warnings: list[str] = []
    for lp in loops:
        r3 = pp.process_loop(lp.torque_a3_nm, lp.period_s, pre)
        r5 = pp.process_loop(lp.torque_a5_nm, lp.period_s, pre)
        t3.append(r3.torque_nm)
        t5.append(r5.torque_nm)
        n_used = min(r3.n_used, r5.n_used)
        used += n_used
        total += r3.n_total
        if n_used < MIN_SAMPLES_PER_LOOP:
            warnings.append(f"loop {lp.trace}: only {n_used} valid samples")
        # within-loop standard error of the loop mass, batch means (autocorrelated samples)
        dm = (lp.torque_a3_nm - lp.torque_a5_nm) / (cal.g_m_s2 * cal.lever_difference_m)
        se_mass.append(unc.batch_means_se(dm) * _local_gain(cal, r3.torque_nm - bias3, r5.torque_nm - bias5))
    n3, n5 = pp.normalise(np.array(t3), bias3), pp.normalise(np.array(t5), bias5)
    loop_mass = np.asarray(cal.mass_kg(n3, n5), float)
    m3, m5 = pp.double_average_nm(n3), pp.double_average_nm(n5)  # eq. 16 over loops
    gross = float(cal.mass_kg(m3, m5))
    warnings += cal.out_of_range(m3, m5)
    if unc.loops_disagree(loop_mass, np.array(se_mass)):
        warnings.append("loops disagree beyond their own spread (drift or a disturbed loop)")
    u = unc.MassUncertainty(
        u_loops_kg=unc.loop_spread_kg(loop_mass, se_mass[0] if se_mass else float("nan")),
        u_calibration_kg=unc.calibration_mc_kg(cal, m3, m5),
        u_model_kg=abs(gross) * float(cal_doc["fit"].get("loo_residual_rms_rel", 0.0)),
    )
    return MassResult(gross - fixture_mass_kg, u.u_kg, u.expanded_kg, gross, fixture_mass_kg, len(loops), used, total,
                      str(cal_doc["calibration_id"]), cal.method, warnings)


def _local_gain(cal: Calibration, m3: float, m5: float) -> float:
    """d(mass)/d(uncorrected mass): the calibration's slope at the working point (≈ K)."""
    h = 1.0
    dm_cal = float(cal.mass_kg(m3 + h, m5) - cal.mass_kg(m3, m5))
    return abs(dm_cal * cal.g_m_s2 * cal.lever_difference_m / h)


def run(args: argparse.Namespace) -> int:
    directory = Path(args.traces)
    man = load_manifest(directory)
    if not man.measurement_traces:
        raise DataError(f"{man.path}: no [measurement] table (is this a calibration campaign?)")
    doc, cal, pre = calfile.read(args.calibration)
    calfile.check_robot(args.calibration, doc, man.setup.robot)
    fixture = args.fixture_mass if args.fixture_mass is not None else (man.fixture_mass_kg or 0.0)
    if not np.isfinite(fixture) or fixture < 0:
        raise DataError(f"--fixture-mass must be a finite mass >= 0 kg, got {fixture}")
    loops = read_loops(directory, man.measurement_traces)
    result = measure(loops, cal, doc, pre or pp.PAPER, fixture)
    if abs(man.setup.lever_difference_m - cal.lever_difference_m) > 1e-6 or abs(man.setup.g_m_s2 - cal.g_m_s2) > 1e-6:
        result.warnings.append("measurement pose (lever_difference_m, g) differs from the calibration's")
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(f"mass {result.mass_kg:.3f} kg ± {result.U_kg:.3f} kg (k = 2)  gross {result.gross_mass_kg:.3f} kg, "
              f"fixture {result.fixture_mass_kg:.3f} kg, {result.loops} loops, "
              f"{result.samples_used}/{result.samples_total} samples, calibration {result.calibration_id} "
              f"({result.method})")
        for w in result.warnings:
            print(f"warning: {w}")
    return 0
