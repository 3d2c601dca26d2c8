"""``rgse cog``: offline centre of gravity of a DuT from a properties run directory and a CAL.json (interfaces §1)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rgse_daemon.analysis.cog import compute_cog_dir
from rgse_daemon.commands import add_json
from rgse_daemon.errors import EXIT_OK, EXIT_WARNINGS


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse cog``."""
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, required=True, metavar="CAL.json")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    result = compute_cog_dir(Path(args.traces), Path(args.calibration))
    doc = result.to_json()
    code = EXIT_WARNINGS if result.warnings else EXIT_OK
    if args.json:
        print(json.dumps(doc))
        return code
    print(f"status: {doc['status']}" + (f" ({len(result.warnings)} warning(s), read them below)"
                                         if result.warnings else ""))
    mm = [v * 1000.0 for v in result.cog_flange_m]
    umm = [v * 1000.0 for v in result.U_cog_flange_m]
    dmm = [v * 1000.0 for v in result.cog_dut_m]
    dumm = [v * 1000.0 for v in result.U_cog_dut_m]
    print(f"CoG (flange) x {mm[0]:.2f} ± {umm[0]:.2f} mm, y {mm[1]:.2f} ± {umm[1]:.2f} mm, "
          f"z {mm[2]:.2f} ± {umm[2]:.2f} mm (k = 2)")
    print(f"CoG (DuT)    x {dmm[0]:.2f} ± {dumm[0]:.2f} mm, y {dmm[1]:.2f} ± {dumm[1]:.2f} mm, "
          f"z {dmm[2]:.2f} ± {dumm[2]:.2f} mm (k = 2)")
    print(f"mass {result.mass_kg:.3f} kg ± {result.U_mass_kg:.3f} kg, scheme {result.scheme}, {result.n_poses} poses, "
          f"calibration {result.budget.get('calibration_id')}")
    for w in result.warnings:
        print(f"warning: {w}")
    return code
