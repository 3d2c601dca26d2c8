"""``rgse reference --run RUN_ID``: weigh the DuT on the crane scale, record it next to the run's in-line result,
print the paper's Table 2 comparison (see :mod:`rgse_daemon.analysis.reference`)."""

from __future__ import annotations

import argparse
import asyncio
import json
from pathlib import Path
from typing import Any

from rgse_daemon.analysis import reference as ref
from rgse_daemon.commands import absent_store, add_json, positive
from rgse_daemon.config import load_config
from rgse_daemon.errors import ConfigError
from rgse_daemon.io.scale import CraneScale
from rgse_daemon.procedures.reference import run_and_result, take_reference
from rgse_daemon.store import Store


async def _reference(args: argparse.Namespace) -> dict[str, Any]:
    config_path = getattr(args, "config", None)
    cfg = load_config(config_path)
    if cfg.scale is None:
        raise ConfigError(f"{args.config or '<defaults>'}: no [scale] section; the crane scale is not configured")
    absent = absent_store(cfg, f"run {args.run!r}", config_path)  # no empty store created just to say so
    if absent is not None:
        raise absent
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        await run_and_result(store, args.run)  # before the scale is opened: fail fast on a wrong run
        async with CraneScale(cfg.scale) as scale:
            run, rec, cmp = await take_reference(
                store, scale, args.run, weighed=getattr(args, "weighed", "gross"),
                timeout_s=getattr(args, "timeout", None), operators=getattr(args, "operators", None),
                operation_min=getattr(args, "operation_min", None))
            counters = dict(vars(scale.counters))
    rows = ref.table2_rows(run, cmp, rec)
    return {
        "run_id": run.id,
        "robot": run.robot,
        "result_id": rec.result_id,
        "event_id": rec.event_id,
        "reference": {**rec.data(), "recorded_utc": rec.recorded_utc.isoformat().replace("+00:00", "Z")},
        "comparison": cmp.to_json(),
        "table2": [{"parameter": p, "reference_crane_scale": a, "inline_robot": b} for p, a, b in rows],
        "scale_counters": counters,
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse reference``."""
    p.add_argument("--run", required=True, metavar="RUN_ID")
    p.add_argument("--config", type=Path, metavar="FILE")
    p.add_argument("--weighed", choices=("gross", "net"), default="gross",
                   help="gross: DuT and fixture hang on the scale together (the paper's 117.6 kg)")
    p.add_argument("--timeout", type=positive, metavar="S", help="wait at most S s for a stable weighing")
    p.add_argument("--operators", type=int, metavar="N", help="operators of the crane-scale procedure (Table 2)")
    p.add_argument("--operation-min", type=positive, metavar="MIN", help="its total time of operation (Table 2)")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    out = asyncio.run(_reference(args))
    if getattr(args, "json", False):
        print(json.dumps(out))
        return 0
    refd, c = out["reference"], out["comparison"]
    print(f"run {out['run_id']} ({out['robot']}), result {out['result_id']}")
    print(f"crane scale {refd['device']}: {refd['mass_kg']:.3f} kg ({refd['weighed']}), raw line {refd['raw_line']!r}, "
          f"{refd['bad_frames']} bad frame(s) skipped, recorded as event {out['event_id']}")
    width = max(len(r["parameter"]) for r in out["table2"])
    print(f"{'parameter':{width}s}  {'crane scale':>16s}  {'in-line robot':>26s}")
    for r in out["table2"]:
        print(f"{r['parameter']:{width}s}  {r['reference_crane_scale']:>16s}  {r['inline_robot']:>26s}")
    print(f"{'agree' if c['agree'] else 'DISAGREE'}: |{c['difference_kg']:.3f}| kg "
          f"{'<=' if c['agree'] else '>'} {c['limit_kg']:.3f} kg")
    return 0
