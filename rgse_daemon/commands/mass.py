"""``rgse mass``: offline in-line mass of a DuT from a measurement directory and a CAL.json (interfaces §1)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rgse_daemon.analysis.mass import compute
from rgse_daemon.commands import add_drift_prior, add_json, finite
from rgse_daemon.errors import EXIT_OK, EXIT_WARNINGS
from rgse_daemon.pipeline.envelope import DEFAULT_LIMIT
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.verdict import OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse mass``."""
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, required=True, metavar="CAL.json")
    p.add_argument("--fixture-mass", type=finite, metavar="KG")
    p.add_argument("--envelope-limit", type=finite, default=DEFAULT_LIMIT, metavar="FRACTION",
                   help="refuse a DuT further outside the calibrated loads than this fraction of their span "
                        "(default 0.5)")
    add_drift_prior(p, "what U carries where β is not applied: alone where the campaign's span does not resolve "
                       "β, else over its |β| + 2 u(β)")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    """Exit 0 for a result without warnings, 4 (EXIT_WARNINGS) for one with warnings; a refusal raises (exit 2, and
    with ``--json`` the refusal's JSON object, see :func:`rgse_daemon.cli.main`)."""
    prior = getattr(args, "drift_prior", DRIFT_PRIOR_PER_K)
    result = compute(Path(args.traces), Path(args.calibration), args.fixture_mass,
                     getattr(args, "envelope_limit", DEFAULT_LIMIT), prior)
    doc = result.to_json()
    if args.json:
        print(json.dumps(doc))
    else:
        print(f"status: {doc['status']}" + (f" ({len(result.warnings)} warning(s), read them below)"
                                             if result.warnings else ""))
        print(f"mass {result.mass_kg:.3f} kg ± {result.U_kg:.3f} kg (k = 2)  gross {result.gross_mass_kg:.3f} kg, "
              f"fixture {result.fixture_mass_kg:.3f} kg, {result.loops} loops, "
              f"{result.samples_used}/{result.samples_total} samples, calibration {result.calibration_id} "
              f"({result.method})")
        print(f"loops used: {', '.join(result.loops_used)}")
        for a in result.loops_set_aside:
            print(f"set aside: loop {a['loop']}: {a['reason']}")
        for w in result.warnings:
            print(f"warning: {w}")
    return EXIT_OK if doc["status"] == OK else EXIT_WARNINGS
