"""Bounded soak of the daemon: many short measurement runs back to back; does anything grow per run?

The real daemon (:class:`rgse_daemon.app.Daemon`) runs in this process against the simulated KR C4 in its own process
(loopback only), with a private SQLite store in a temporary directory and, with ``--mqtt``, a private Mosquitto on a
free loopback port. A short calibration campaign first (so measurements are admitted), then ``--runs`` measurement
runs, each as short as the settings allow (1 loop, 100 trace samples, no warm-up, simulator at high time scale).

After every run it records this process's RSS (``VmRSS`` of /proc/self/status), its open file descriptors
(/proc/self/fd), the number of asyncio tasks and the run's wall time; it prints a table every 50 runs and a summary at
the end: RSS at run 1, 50, 100, ..., the RSS growth per run (least-squares line over the second half of the runs,
after the start-up allocations settled), file descriptors and tasks first/last.

Bounded: it stops by itself after ``--runs`` runs or ``--max-minutes`` minutes, whichever comes first.

Run: ``.venv/bin/python bench/soak.py [--runs N] [--max-minutes M] [--mqtt]``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from rgse_daemon.app import Daemon
from rgse_daemon.commands.demo import CAMPAIGN, FIXTURE_MASS_KG, ROBOT, SEED, Operator, SilentView
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.procedures.settings import RunSettings
from simulators.krc4.physics import dut_payload
from simulators.krc4.process import SimProcess

#: Simulated seconds per wall second (the demo runs at 200).
TIME_SCALE = 500.0
TABLE_EVERY = 50
#: Deadline of one run, of the calibration campaign, of connecting and of stopping (s): a hang guard.
RUN_DEADLINE_S = 120.0
CAMPAIGN_DEADLINE_S = 600.0
CONNECT_DEADLINE_S = 30.0
STOP_DEADLINE_S = 60.0


@dataclass(frozen=True)
class Sample:
    run: int
    rss_kb: int
    fds: int
    tasks: int
    wall_s: float


def rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("/proc/self/status has no VmRSS line")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Mosquitto:
    """A private Mosquitto on a free loopback port (no persistence), stopped on exit."""

    def __init__(self, directory: Path) -> None:
        self.dir = directory
        self.port = free_loopback_port()
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        self.dir.mkdir(parents=True, exist_ok=True)
        conf = self.dir / "mosquitto.conf"
        conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
                        "log_dest stderr\n")
        with (self.dir / "mosquitto.log").open("wb") as log_file:  # the child keeps its own descriptor
            self.proc = subprocess.Popen([binary, "-c", str(conf)], stdin=subprocess.DEVNULL, stderr=log_file)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited with {self.proc.returncode}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError(f"mosquitto did not listen on 127.0.0.1:{self.port} within 10 s")

    def stop(self) -> None:
        if self.proc is None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)


def soak_config(sim: SimProcess, data_dir: Path, broker_port: int | None) -> Config:
    mqtt: dict[str, Any] = {"enabled": False}
    if broker_port is not None:  # a private broker on loopback: the bench's robot is its own simulator
        mqtt = {"enabled": True, "host": "127.0.0.1", "port": broker_port, "command_auth": "open_lab_bench"}
    return config_from_mapping(
        {
            "robot": {"name": ROBOT},
            "controller": {"host": "127.0.0.1", "port": sim.port, "protocol": "c3bridge",
                           "share_dir": str(sim.share_dir)},
            "paths": {"data_dir": str(data_dir)},
            "limits": {"snapshot_stale_s": 1.0},  # a loaded 2-core machine; the simulated robot moves in T1
            "measurement": {"loops": 1, "settle_s": 0.01, "trace_period_s": 0.012, "trace_samples": 100,
                            "warmup_cycles": 0, "warmup_until_steady": False, "fixture_mass_kg": FIXTURE_MASS_KG,
                            "payload_lever_max_m": 1.0, "program_timeout_s": 60.0, "trace_timeout_s": 30.0},
            "mqtt": mqtt,
        },
        "<soak>",
    )


def table(samples: list[Sample]) -> str:
    lines = [f"{'run':>5} {'RSS MB':>8} {'fds':>5} {'tasks':>6} {'wall s':>7}"]
    lines += [f"{s.run:>5} {s.rss_kb / 1024:>8.1f} {s.fds:>5} {s.tasks:>6} {s.wall_s:>7.2f}" for s in samples]
    return "\n".join(lines)


def milestones(samples: list[Sample]) -> list[Sample]:
    """Run 1, 50, 100, ... and the last run."""
    picked = [s for s in samples if s.run == 1 or s.run % TABLE_EVERY == 0]
    if samples and picked[-1] is not samples[-1]:
        picked.append(samples[-1])
    return picked


def summary(samples: list[Sample], elapsed_s: float, stopped_by: str) -> dict[str, Any]:
    second_half = samples[len(samples) // 2:]
    growth_kb = None
    if len(second_half) >= 2:
        growth_kb = statistics.linear_regression([s.run for s in second_half],
                                                 [s.rss_kb for s in second_half]).slope
    first, last = samples[0], samples[-1]
    walls = [s.wall_s for s in samples]
    return {
        "runs": len(samples), "stopped_by": stopped_by, "elapsed_min": elapsed_s / 60.0,
        "rss_mb_first": first.rss_kb / 1024, "rss_mb_last": last.rss_kb / 1024,
        "rss_mb_at": {s.run: round(s.rss_kb / 1024, 1) for s in milestones(samples)},
        "rss_growth_kb_per_run_second_half": growth_kb,
        "fds_first": first.fds, "fds_last": last.fds, "fds_max": max(s.fds for s in samples),
        "tasks_first": first.tasks, "tasks_last": last.tasks, "tasks_max": max(s.tasks for s in samples),
        "wall_s_median": statistics.median(walls), "wall_s_max": max(walls),
    }


async def soak(runs: int, max_minutes: float, use_mqtt: bool) -> tuple[list[Sample], str, float]:
    t_start = time.monotonic()
    deadline = t_start + 60.0 * max_minutes
    samples: list[Sample] = []
    stopped_by = "runs"
    with tempfile.TemporaryDirectory(prefix="rgse-soak-") as tmp:
        root = Path(tmp)
        broker = Mosquitto(root / "mosquitto") if use_mqtt else None
        sim = SimProcess(root / "share", seed=SEED, time_scale=TIME_SCALE, globals_dat=globals_dat_text())
        if broker is not None:
            await asyncio.to_thread(broker.start)
        await asyncio.to_thread(sim.start)
        try:
            cfg = soak_config(sim, root / "data", broker.port if broker is not None else None)
            ref: list[Daemon] = []
            daemon = Daemon(cfg, on_event=Operator(sim, ref, SilentView()))
            ref.append(daemon)
            stop = asyncio.Event()
            service = asyncio.create_task(daemon.run(stop), name="rgse-soak-daemon")
            try:
                async with asyncio.timeout(CONNECT_DEADLINE_S):
                    await daemon.connected.wait()
                settings = RunSettings.from_config(cfg, loops=2, warmup_cycles=0)
                t0 = time.monotonic()
                async with asyncio.timeout(CAMPAIGN_DEADLINE_S):
                    cal = await (await daemon.start_calibration(points=CAMPAIGN, method="auto", settings=settings))
                print(f"calibration {cal['calibration_id']}: {len(CAMPAIGN)} points x 2 loops in "
                      f"{time.monotonic() - t0:.1f} s", flush=True)
                await sim.mount(dut_payload(107.3, (0.0, 0.04, 0.30), fixture_mass_kg=FIXTURE_MASS_KG))
                for i in range(1, runs + 1):
                    if time.monotonic() >= deadline:
                        stopped_by = "max-minutes"
                        break
                    t0 = time.monotonic()
                    async with asyncio.timeout(RUN_DEADLINE_S):
                        await (await daemon.start_measurement())  # a failed run ends the soak
                    wall_s = time.monotonic() - t0
                    samples.append(Sample(i, rss_kb(), open_fds(), len(asyncio.all_tasks()), wall_s))
                    if i % TABLE_EVERY == 0:
                        print(table(milestones(samples)), flush=True)
            finally:
                stop.set()
                async with asyncio.timeout(STOP_DEADLINE_S):
                    await service
        finally:
            await asyncio.to_thread(sim.stop)
            if broker is not None:
                await asyncio.to_thread(broker.stop)
    return samples, stopped_by, time.monotonic() - t_start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=500, help="measurement runs (default 500)")
    ap.add_argument("--max-minutes", type=float, default=20.0, help="stop after this many minutes (default 20)")
    ap.add_argument("--mqtt", action="store_true", help="publish to a private Mosquitto on a free loopback port")
    args = ap.parse_args()
    if args.runs < 1 or args.max_minutes <= 0:
        ap.error("--runs must be ≥ 1 and --max-minutes > 0")
    samples, stopped_by, elapsed_s = asyncio.run(soak(args.runs, args.max_minutes, args.mqtt))
    if not samples:
        print("soak: no measurement run completed within the bound", file=sys.stderr)
        return 1
    print(table(milestones(samples)))
    print(json.dumps(summary(samples, elapsed_s, stopped_by)))
    print(json.dumps({"last": asdict(samples[-1])}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
