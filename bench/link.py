"""Benchmark of the KR C4 link against the simulated controller with a realistic per-request latency.

Measures, and prints as ONE JSON object on stdout:

* single-read latency of this client (#0, one connection): median and p95 in ms;
* snapshot rate (all ``SNAPSHOT_VARIABLES``) of this client with C3 Bridge (one #6 multi-read) and in forced
  KUKAVARPROXY mode (#0 reads spread over the pool);
* the same snapshot read variable by variable with py-openshowvar (PyPI 1.1.7, blocking, one connection);
* the ratio of this client's C3 snapshot rate to py-openshowvar's (goal ≥ 10).

The simulator serialises requests across all clients, like the real single-threaded server, and each request
takes ``--latency-ms`` (≈ 2 ms measured on real controllers: github.com/ivareri/KUKAVARPROXY_tests, listed in
``docs/protocol.md``, Sources).

Usage: ``.venv/bin/python bench/link.py [--latency-ms 2] [--reads 300] [--snapshots 60]``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time

from py_openshowvar import openshowvar

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import SNAPSHOT_VARIABLES, Controller
from rgse_daemon.link.connection import Connection
from simulators.krc4.server import KrcServer, ServerConfig


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    idx = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[idx]


async def _single_reads(port: int, n: int) -> list[float]:
    latencies_ms = []
    async with Connection("127.0.0.1", port, request_timeout_s=2.0) as conn:
        for _ in range(n):
            t0 = time.perf_counter()
            await conn.read_var("$OV_PRO")
            latencies_ms.append((time.perf_counter() - t0) * 1000.0)
    return latencies_ms


async def _snapshot_rate(cfg: ControllerConfig, n: int) -> tuple[float, bool]:
    async with Controller.connect(cfg) as krc:
        await krc.snapshot()  # warm-up: opens connections
        complete = True
        t0 = time.perf_counter()
        for _ in range(n):
            complete &= (await krc.snapshot()).complete
        return n / (time.perf_counter() - t0), complete


def _openshowvar_rate(port: int, n: int) -> tuple[float, bool]:
    client = openshowvar("127.0.0.1", port)
    try:
        complete = True
        for name in SNAPSHOT_VARIABLES:  # warm-up
            client.read(name, debug=False)
        t0 = time.perf_counter()
        for _ in range(n):
            for name in SNAPSHOT_VARIABLES:
                complete &= bool(client.read(name, debug=False))
        return n / (time.perf_counter() - t0), complete
    finally:
        client.sock.close()


async def main(argv: list[str]) -> dict[str, object]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--latency-ms", type=float, default=2.0)
    ap.add_argument("--reads", type=int, default=300)
    ap.add_argument("--snapshots", type=int, default=60)
    args = ap.parse_args(argv)
    async with KrcServer(ServerConfig(latency_s=args.latency_ms / 1000.0, idle_timeout_s=None)) as srv:
        cfg = ControllerConfig(host="127.0.0.1", port=srv.port, pool_size=4)
        lat = await _single_reads(srv.port, args.reads)
        c3_rate, c3_ok = await _snapshot_rate(cfg, args.snapshots)
        kvp_rate, kvp_ok = await _snapshot_rate(
            ControllerConfig(host="127.0.0.1", port=srv.port, pool_size=4, protocol="kvp"), max(5, args.snapshots // 4)
        )
        osv_rate, osv_ok = await asyncio.to_thread(_openshowvar_rate, srv.port, max(5, args.snapshots // 4))
    return {
        "bench": "link",
        "sim_latency_ms": args.latency_ms,
        "snapshot_variables": len(SNAPSHOT_VARIABLES),
        "single_read_ms": {
            "n": len(lat),
            "median": round(statistics.median(lat), 3),
            "p95": round(_percentile(lat, 0.95), 3),
        },
        "snapshot_per_s": {
            "rgse_c3bridge_multiread": round(c3_rate, 2),
            "rgse_kvp_pooled_single_reads": round(kvp_rate, 2),
            "py_openshowvar_one_by_one": round(osv_rate, 2),
        },
        "snapshots_complete": {"rgse_c3bridge": c3_ok, "rgse_kvp": kvp_ok, "py_openshowvar": osv_ok},
        "ratio_rgse_c3_vs_openshowvar": round(c3_rate / osv_rate, 2),
        "goal_ratio": 10.0,
    }


if __name__ == "__main__":
    result = asyncio.run(main(sys.argv[1:]))
    print(json.dumps(result))
