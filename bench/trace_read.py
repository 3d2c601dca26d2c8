"""Benchmark: read a ~100 MB KUKA trace set with rgse_daemon.trace vs bare numpy.fromfile of the same .r64 files.

Writes 6 drive modules x 7 channels x N samples (BLOCK, as KUKA) into a temporary directory, then times
(best of --runs):
  * ``fromfile``: ``np.fromfile`` of every ``.r64`` (no header, no checks, no hashing), each array dropped at
    once so the allocator hands back the same, already mapped pages - the floor;
  * ``fromfile_kept``: the same, keeping all arrays alive as any real consumer (and the reader) does;
  * ``reader``: ``read_trace_set`` (header parsing, layout checks, finiteness check, SHA-256 of every raw file);
  * ``reader_scaled``: the same set written with factor/offset != identity, so every channel is computed.
The OS page cache cannot be dropped without root, so both read from warm cache: the figures are CPU/memory
bound, not disk bound. Prints one JSON object; ``ratio`` = reader MB/s / fromfile MB/s (goal >= 0.5).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rgse_daemon.trace import read_trace_set
from simulators.krc4.tracefiles import write_trace_set

CHANNELS = {
    "Sollposition": "deg",
    "Istposition": "deg",
    "Positionsschleppfehler": "deg",
    "Geschwindigkeitsdifferenz": "deg/s",
    "Motortemperatur": "K",
    "Istmoment": "Nm",
    "Iststrom": "A",
}


def _best_s(fn: Callable[[], object], runs: int) -> float:
    best = float("inf")
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=100.0, help="approximate size of the .r64 files in MB")
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()

    n_modules, n_channels = 6, len(CHANNELS)
    n_samples = int(args.mb * 1e6 / (8 * n_modules * n_channels))
    rng = np.random.default_rng(0)
    modules = {
        f"NextGenDrive#{k}": {name: (rng.standard_normal(n_samples), unit) for name, unit in CHANNELS.items()}
        for k in range(1, n_modules + 1)
    }
    with tempfile.TemporaryDirectory(prefix="rgse-bench-") as tmp:
        directory = Path(tmp)
        start = time.perf_counter()
        write_trace_set(directory, "bench", 0.004, modules)
        write_s = time.perf_counter() - start
        write_trace_set(directory, "scaled", 0.004, modules, factor=0.001, offset=1.5)
        r64 = sorted(directory.glob("bench_*.r64"))
        total_mb = sum(p.stat().st_size for p in r64) / 1e6

        def fromfile() -> None:
            for p in r64:
                np.fromfile(p, dtype="<f8")

        def fromfile_kept() -> list[np.ndarray]:
            return [np.fromfile(p, dtype="<f8") for p in r64]

        fromfile()  # warm the page cache for both contenders
        fromfile_s = _best_s(fromfile, args.runs)
        kept_s = _best_s(fromfile_kept, args.runs)
        reader_s = _best_s(lambda: read_trace_set(directory, "bench"), args.runs)
        reader_1t_s = _best_s(lambda: read_trace_set(directory, "bench", max_workers=1), args.runs)
        scaled_s = _best_s(lambda: read_trace_set(directory, "scaled"), args.runs)
        nohash_s = _best_s(lambda: read_trace_set(directory, "bench", with_sha256=False), args.runs)
        sha_s = _best_s(lambda: [hashlib.sha256(p.read_bytes()).hexdigest() for p in r64], args.runs)

    print(
        json.dumps(
            {
                "bench": "trace_read",
                "size_mb": round(total_mb, 1),
                "modules": n_modules,
                "channels_per_module": n_channels,
                "samples": n_samples,
                "runs": args.runs,
                "cache": "warm (page cache cannot be dropped without root)",
                "write_mb_s": round(total_mb / write_s, 1),
                "fromfile_mb_s": round(total_mb / fromfile_s, 1),
                "fromfile_kept_mb_s": round(total_mb / kept_s, 1),
                "reader_mb_s": round(total_mb / reader_s, 1),
                "reader_1thread_mb_s": round(total_mb / reader_1t_s, 1),
                "reader_scaled_mb_s": round(total_mb / scaled_s, 1),
                "reader_no_sha256_mb_s": round(total_mb / nohash_s, 1),
                "sha256_alone_1thread_mb_s": round(total_mb / sha_s, 1),
                "ratio": round(fromfile_s / reader_s, 3),
                "ratio_1thread": round(fromfile_s / reader_1t_s, 3),
                "ratio_no_sha256": round(fromfile_s / nohash_s, 3),
                "ratio_vs_kept": round(kept_s / reader_s, 3),
                "ratio_no_sha256_vs_kept": round(kept_s / nohash_s, 3),
                "goal_ratio": 0.5,
            }
        )
    )


if __name__ == "__main__":
    main()
