"""``rgse inertia``: offline inertia tensor of a DuT from a run directory with DuT and tare motion traces
(interfaces: ``inertia.toml``)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rgse_daemon.analysis.inertia import ECSS_REL, compute_inertia_dir
from rgse_daemon.commands import add_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse inertia``."""
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, metavar="CAL.json",
                   help="take the readings through its torsional gain curves of A4..A6 (default: 1:1)")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    result = compute_inertia_dir(Path(args.traces), args.calibration)
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    np.set_printoptions(precision=3, suppress=True)
    print("inertia tensor about the CoG, DuT frame (kg·m²):")
    for row, urow in zip(result.inertia_cog_dut_kgm2, result.U_inertia_cog_dut_kgm2, strict=True):
        print("  " + "  ".join(f"{v:9.3f} ± {u:6.3f}" for v, u in zip(row, urow, strict=True)))
    for k, (m, u) in enumerate(zip(result.principal_moments_kgm2, result.U_principal_moments_kgm2, strict=True)):
        axis = result.principal_axes_dut[:, k]
        ok = "within" if u <= ECSS_REL * m else "NOT within"
        print(f"I{k + 1} = {m:.3f} ± {u:.3f} kg·m² (k = 2, {100 * u / m:.1f} %: U {ok} ECSS ±3 %), axis "
              f"({axis[0]:+.3f}, {axis[1]:+.3f}, {axis[2]:+.3f}) ± {result.U_principal_axes_deg[k]:.1f}°")
    print(f"{result.n_strokes} strokes, {result.n_samples} samples, condition {result.condition_number:.1f}")
    for w in result.warnings:
        print(f"warning: {w}")
    return 0
