"""``rgse mass``: offline in-line mass of a DuT from a measurement directory and a CAL.json (interfaces §1)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rgse_daemon.analysis.mass import compute
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline.envelope import DEFAULT_LIMIT
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K


def run(args: argparse.Namespace) -> int:
    prior = getattr(args, "drift_prior", DRIFT_PRIOR_PER_K)
    if not 0.0 <= prior <= 0.1:
        raise DataError(f"--drift-prior {prior}: a bound on |β| must lie within 0..0.1 per K")
    result = compute(Path(args.traces), Path(args.calibration), args.fixture_mass,
                     getattr(args, "envelope_limit", DEFAULT_LIMIT), prior)
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(f"mass {result.mass_kg:.3f} kg ± {result.U_kg:.3f} kg (k = 2)  gross {result.gross_mass_kg:.3f} kg, "
              f"fixture {result.fixture_mass_kg:.3f} kg, {result.loops} loops, "
              f"{result.samples_used}/{result.samples_total} samples, calibration {result.calibration_id} "
              f"({result.method})")
        print(f"loops used: {', '.join(result.loops_used)}")
        for a in result.loops_set_aside:
            print(f"set aside: loop {a['loop']}: {a['reason']}")
        for w in result.warnings:
            print(f"warning: {w}")
    return 0
