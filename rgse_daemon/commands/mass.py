"""``rgse mass``: offline in-line mass of a DuT from a measurement directory and a CAL.json (interfaces §1)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rgse_daemon.analysis.mass import compute
from rgse_daemon.pipeline.envelope import DEFAULT_LIMIT


def run(args: argparse.Namespace) -> int:
    result = compute(Path(args.traces), Path(args.calibration), args.fixture_mass,
                     getattr(args, "envelope_limit", DEFAULT_LIMIT))
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
