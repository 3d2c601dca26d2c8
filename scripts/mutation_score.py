#!/usr/bin/env python3
"""Per-file mutation score of the last ``make mutation`` run, from mutmut's ``mutants/**/*.py.meta`` files.

Prints one line per mutated file: killed / checked (%), survivors, and mutants not checked yet (a run narrowed
with MUTATE= leaves the other files unchecked). A mutant counts as killed when a test failed or timed out on it;
"no tests" (no fast pipeline test reaches the function) counts against the score.

Usage: scripts/mutation_score.py [file-substring ...]   (e.g. mass uncertainty)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

KILLED = {1, 3, 36, 24, -24, 152, 255, 37}
SURVIVED = {0}
NO_TESTS = {5, 33}


def main(argv: list[str]) -> int:
    metas = sorted(Path("mutants").rglob("*.py.meta"))
    if not metas:
        print("no mutants/ directory: run `make mutation` first", file=sys.stderr)
        return 1
    print(f"{'file':45s} {'killed':>7s} {'checked':>7s} {'score':>7s} {'survived':>8s} {'no tests':>8s} "
          f"{'unchecked':>9s}")
    for meta in metas:
        name = str(meta.relative_to("mutants")).removesuffix(".meta")
        if argv and not any(a in name for a in argv):
            continue
        codes = list(json.loads(meta.read_text())["exit_code_by_key"].values())
        if not codes:
            continue
        checked = [c for c in codes if c is not None]
        killed = sum(c in KILLED for c in checked)
        survived = sum(c in SURVIVED for c in checked)
        no_tests = sum(c in NO_TESTS for c in checked)
        score = f"{100.0 * killed / len(checked):6.1f}%" if checked else "      -"
        print(f"{name:45s} {killed:7d} {len(checked):7d} {score:>7s} {survived:8d} {no_tests:8d} "
              f"{len(codes) - len(checked):9d}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
