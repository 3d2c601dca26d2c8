"""The whole daemon path over several simulated robots (issues #14, #15, #18): ``rgse demo --inertia --json --seed N``
for each seed, one after the other, and the coverage of ±U (k = 2) of what it measures.

Each demo is the full story through the daemon on a simulated KR C4 drawn from its seed (gains, offsets, noise): the
calibration campaign with its torsional points, then the wing box's properties run (mass, CoG, inertia with its
tare). ``bench/accuracy.py``, ``cog.py`` and ``inertia.py`` measure the same quantities offline over many more seeds;
this bench checks that the daemon's path (its programs, traces pulled from the controller, CAL.json, the cube-bound
excitation) holds what they claim. Rows: mass, CoG per flange coordinate, principal moments. Columns: mean and max
|error|, mean U, coverage of ±U with its Clopper-Pearson 95 % interval.

Run: ``.venv/bin/python bench/demo_repeat.py [--seeds N] [--first S] [--json]`` (about 3 min per seed on the shared
2-core machine; 6 seeds by default).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np
from scipy import stats

DEMO_TIMEOUT_S = 900


def one_demo(seed: int) -> dict:
    proc = subprocess.run([sys.executable, "-m", "rgse_daemon.cli", "demo", "--inertia", "--json", "--seed", str(seed)],
                          capture_output=True, text=True, timeout=DEMO_TIMEOUT_S, check=False)
    if proc.returncode != 0:
        return {"seed": seed, "failed": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no output"}
    return json.loads(proc.stdout)


def rows(runs: list[dict]) -> dict[str, list[tuple[float, float]]]:
    """Per quantity the (error, U) of each finished demo."""
    out: dict[str, list[tuple[float, float]]] = {"mass kg": []}
    for r in runs:
        if "failed" in r:
            continue
        out["mass kg"].append((r["mass_kg"] - r["true_mass_kg"], r["U_kg"]))
        for k, c in enumerate("xyz"):
            out.setdefault(f"CoG {c} mm", []).append((1000 * (r["cog_m"][k] - r["true_cog_m"][k]),
                                                       1000 * r["U_cog_m"][k]))
        for k in range(3):
            truth = r["true_principal_moments_kgm2"][k]
            out.setdefault(f"I{k + 1} % ({truth:.1f} kg·m²)", []).append(
                (100 * (r["principal_moments_kgm2"][k] - truth) / truth,
                 100 * r["U_principal_moments_kgm2"][k] / truth))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--first", type=int, default=2024)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    runs = []
    for seed in range(args.first, args.first + args.seeds):
        runs.append(one_demo(seed))
        print(f"seed {seed}: {'failed: ' + runs[-1]['failed'] if 'failed' in runs[-1] else 'done'} "
              f"({time.monotonic() - t0:.0f} s)", file=sys.stderr)
    table = {}
    for name, pairs in rows(runs).items():
        err = np.array([e for e, _ in pairs])
        big_u = np.array([u for _, u in pairs])
        k = int(np.sum(np.abs(err) <= big_u))
        ci = stats.binomtest(k, len(pairs)).proportion_ci(0.95, method="exact") if pairs else None
        table[name] = {"n": len(pairs), "mean_err": float(err.mean()), "max_abs_err": float(np.abs(err).max()),
                       "mean_U": float(big_u.mean()), "covered": k,
                       "coverage_ci95": (float(ci.low), float(ci.high)) if ci else None}
    failed = [r for r in runs if "failed" in r]
    if args.json:
        print(json.dumps({"bench": "demo_repeat", "seeds": [r["seed"] for r in runs], "failed": failed,
                          "table": table, "seconds": round(time.monotonic() - t0, 1)}))
        return 0
    print("| quantity | n | mean err | max \\|err\\| | mean U | covered by ±U (95 % CI) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, s in table.items():
        lo, hi = s["coverage_ci95"]
        print(f"| {name} | {s['n']} | {s['mean_err']:+.2f} | {s['max_abs_err']:.2f} | {s['mean_U']:.2f} | "
              f"{s['covered']}/{s['n']} ({100 * lo:.0f}–{100 * hi:.0f} %) |")
    print(f"seeds {args.first}..{args.first + args.seeds - 1}; {len(failed)} failed; "
          f"{time.monotonic() - t0:.0f} s")
    for r in failed:
        print(f"seed {r['seed']} failed: {r['failed']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
