"""Benchmark: pulling a realistic trace set from the simulated KR C4 at the real server's file behaviour, with the
interlock watching.

The simulated C3 Bridge server loads a whole file before it answers a #30 Begin, at ``file_rate_bytes_s`` (default
100 kB/s, conservative), on its single thread: every status read waits behind it. The daemon pulls under the
monitor's file-window rule (rgse_daemon/safety/monitor.py). Measured, per trace set:

* pull time (list, read, verify, archive, delete) and the bytes pulled;
* status-poll latency of the interlock monitor during the pull (median, p95, max of its snapshots) against the
  same without a pull, the polls that were late (beyond the normal 100 ms limit: doubt cleared at the window's
  close) and whether the interlock tripped.

Trace sets: the paper's 1 kS per loop on A1–A6 (``NextGenDrive#1..6`` + ``KRCIpo``, 7 channels each, 12 ms) and a
ten-times-larger one (10 kS). Prints a table and ONE JSON object (last line).

Usage: ``.venv/bin/python bench/pull.py [--rate 100000] [--samples 1000 10000]``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller, Snapshot
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.safety.monitor import Monitor
from simulators.krc4.physics import CHANNEL_UNITS, CHANNELS
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.tracefiles import write_trace_set

MODULES = ("KRCIpo", *(f"NextGenDrive#{i}" for i in range(1, 7)))
PERIOD_S = 0.012


def _write_set(trace_dir: Path, name: str, samples: int) -> int:
    rng = np.random.default_rng(1)
    modules = {mod: {ch: (rng.normal(0.0, 100.0, samples), CHANNEL_UNITS[ch]) for ch in CHANNELS} for mod in MODULES}
    paths = write_trace_set(trace_dir, name, PERIOD_S, modules, prog_text="DEF RGSE_BRAKE_RELEASE()\r\nEND\r\n")
    return sum(p.stat().st_size for p in paths)


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))] if ordered else float("nan")


def _stats_ms(values: list[float]) -> dict[str, float]:
    return {"n": len(values), "median_ms": 1e3 * statistics.median(values) if values else float("nan"),
            "p95_ms": 1e3 * _pct(values, 0.95), "max_ms": 1e3 * max(values, default=float("nan"))}


def _pull_plan(trace: str, dest: Path) -> m.Plan:
    return (yield m.Pull(trace, dest, 30.0))


async def _one(sim: SimulatedKrc4, samples: int, out: Path) -> dict[str, Any]:
    name = f"bench{samples}"
    total_bytes = _write_set(sim.share_dir / "TRACE", name, samples)
    cfg = ControllerConfig(host="127.0.0.1", port=sim.port, protocol="c3bridge")
    async with Controller.connect(cfg) as krc:
        polls: list[tuple[float, float]] = []  # (start, duration) of every monitor snapshot
        original = krc.snapshot

        async def timed_snapshot() -> Snapshot:
            t0 = time.monotonic()
            try:
                return await original()
            finally:
                polls.append((t0, time.monotonic() - t0))

        krc.snapshot = timed_snapshot  # type: ignore[method-assign]
        monitor = Monitor(krc)  # the daemon's defaults: 20 Hz, stale after 2 periods (100 ms)
        engine = RunEngine(krc, checker=lambda program, snap: None, monitor=monitor)

        def idle_plan() -> m.Plan:
            yield m.Sleep(1.0)

        await engine.run(idle_plan())  # baseline: the same monitor, no file work
        baseline = [d for _, d in polls]
        polls.clear()
        t0 = time.monotonic()
        tripped = None
        try:
            pulled = await engine.run(_pull_plan(name, out / name))
        except Exception as exc:  # a trip (or any failure) is a result to report
            pulled, tripped = None, f"{type(exc).__name__}: {exc}"
        pull_s = time.monotonic() - t0
        during = [d for _, d in polls]
        return {
            "samples_per_channel": samples,
            "files": len(pulled.files) if pulled else None,
            "bytes": total_bytes,
            "pull_s": pull_s,
            "pull_rate_kB_s": total_bytes / pull_s / 1000.0,
            "poll_without_pull": _stats_ms(baseline),
            "poll_during_pull": _stats_ms(during),
            "window_polls": monitor.stats.window_polls,
            "window_late_polls": monitor.stats.window_late_polls,
            "tripped": tripped,
        }


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=None, help="simulated file rate in bytes/s (default: scenario)")
    ap.add_argument("--samples", type=int, nargs="+", default=[1000, 10000])
    args = ap.parse_args()
    scenario = {"server": {"file_rate_bytes_s": args.rate}} if args.rate else None
    results = []
    with tempfile.TemporaryDirectory(prefix="rgse-bench-pull-") as tmp:
        async with SimulatedKrc4(Path(tmp) / "share", scenario=scenario) as sim:  # default latency: 2 ms
            rate = sim.server.config.file_rate_bytes_s
            for samples in args.samples:
                results.append(await _one(sim, samples, Path(tmp) / "archive"))
    print(f"file rate {rate / 1000:.0f} kB/s, request latency 2 ms, monitor 20 Hz (stale after 100 ms)")
    print(f"{'set':>10} {'bytes':>10} {'pull s':>8} {'poll ms (no pull) med/p95/max':>31} "
          f"{'poll ms (pull) med/p95/max':>28} {'late':>5} {'trip':>5}")
    for r in results:
        a, b = r["poll_without_pull"], r["poll_during_pull"]
        print(f"{r['samples_per_channel']:>8}S {r['bytes']:>10} {r['pull_s']:>8.1f} "
              f"{a['median_ms']:>9.1f}/{a['p95_ms']:>6.1f}/{a['max_ms']:>7.1f}      "
              f"{b['median_ms']:>9.1f}/{b['p95_ms']:>6.1f}/{b['max_ms']:>7.1f} "
              f"{r['window_late_polls']:>5} {'yes' if r['tripped'] else 'no':>5}")
    print(json.dumps({"file_rate_bytes_s": rate, "results": results}))


if __name__ == "__main__":
    asyncio.run(main())
