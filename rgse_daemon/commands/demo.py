"""``rgse demo``: the whole story on the built-in simulated KR C4, through the daemon's real code paths.

A simulated KR 500 R2830 (C3 Bridge server on a loopback port, KRL interpreter, physics with the paper's error
sources, KUKA Trace) runs in scaled time. The daemon (:class:`rgse_daemon.app.Daemon`: network link, KRL rendering and
the interlock's static check, program push/select/start, runtime monitor, trace start and pull over the link's file
operations, archive, pipeline, store, outbox) then

1. runs a calibration campaign (the zero point, stacks of calibration bodies, torque points with the test adapter);
   the simulated operator mounts each load when the daemon asks for it and confirms;
2. measures a DuT in line: the paper's ReFEx wing-box segment (net 107.3 kg by crane scale; on a 10.288 kg fixture).

It prints true vs measured mass, the expanded uncertainty U (k = 2), and timings: robot time (what the robot needs:
motion, settling, recording — converted to real time) and daemon overhead (pulling, archiving, computing).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from rgse_daemon.app import Daemon
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.errors import ConfigError, RgseError
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.procedures.calibration import table1_points
from rgse_daemon.procedures.common import RunSettings
from rgse_daemon.procedures.events import Event
from simulators.krc4.physics import dut_payload, mass_calibration_payload, torque_calibration_payload
from simulators.krc4.process import SimProcess

log = logging.getLogger(__name__)

ROBOT = "KR500R2830-SIM"
SEED = 2024
#: Simulated seconds per wall second: a ~20 simulated minutes campaign + run in well under two minutes.
TIME_SCALE = 200.0
#: The paper's in-line run (Table 2): ReFEx wing-box segment on its fixture.
DUT_MASS_KG = 107.3
FIXTURE_MASS_KG = 10.288
DUT_COG_M = (0.0, 0.04, 0.30)
#: A shortened Table 1 campaign: zero, five stacks, two torque-based points.
CAMPAIGN = table1_points(n_bodies=(0, 1, 3, 5, 7, 10), torque_levers_a5_m=(0.761, 1.261))
CAMPAIGN_LOOPS = 5
SETTLE_S = 4.0
MEASUREMENT_LOOPS = 10
DEADLINE_S = 600.0


def demo_config(sim: SimProcess, data_dir: Path, mqtt_url: str | None) -> Config:
    mqtt: dict[str, Any] = {"enabled": False}
    if mqtt_url is not None:
        u = urlsplit(mqtt_url)
        if u.scheme not in ("mqtt", "tcp") or not u.hostname:
            raise ConfigError(f"--mqtt {mqtt_url}: expected mqtt://HOST[:PORT]")
        mqtt = {"enabled": True, "host": u.hostname, "port": u.port or 1883}
    return config_from_mapping(
        {
            "robot": {"name": ROBOT},
            "controller": {"host": "127.0.0.1", "port": sim.port, "protocol": "c3bridge",
                           "share_dir": str(sim.share_dir)},
            "paths": {"data_dir": str(data_dir)},
            # the demo shares a 2-core machine with its simulated controller (and, under `make test`, with the test
            # run): a scheduling hiccup of the daemon's event loop > 0.1 s is a stale snapshot and trips the
            # interlock. A dedicated measurement PC keeps the 0.1 s default; the simulated robot moves in T1.
            "limits": {"snapshot_stale_s": 0.5},
            # the daemon waits in wall time; the simulated controller's clock runs TIME_SCALE times faster, so the
            # paper's 2 x 2 s of settling after each brake-release move is 4 s / TIME_SCALE here
            "measurement": {"loops": MEASUREMENT_LOOPS, "settle_s": SETTLE_S / TIME_SCALE, "trace_period_s": 0.012,
                            "trace_samples": 1000, "warmup_cycles": 2, "fixture_mass_kg": FIXTURE_MASS_KG,
                            "payload_lever_max_m": 1.0, "warmup_until_steady": True,
                            "warmup_steady_window_s": 300.0 / TIME_SCALE, "warmup_max_s": 2400.0 / TIME_SCALE},
            "mqtt": mqtt,
        },
        "<demo>",
    )


class Operator:
    """The simulated lab operator: mounts the load the daemon asks for, then confirms; prints progress."""

    def __init__(self, sim: SimProcess, daemon_ref: list[Daemon], quiet: bool) -> None:
        self.sim = sim
        self.daemon_ref = daemon_ref
        self.quiet = quiet
        self._tasks: set[asyncio.Task[None]] = set()

    def __call__(self, ev: Event) -> None:
        if ev.kind == "confirm":
            task = asyncio.get_running_loop().create_task(self._mount_and_confirm(dict(ev.data)))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        if not self.quiet and ev.kind in ("confirm", "loop", "alarm", "result"):
            print(f"  [{ev.kind}] {ev.message}", file=sys.stderr, flush=True)

    async def _mount_and_confirm(self, d: dict[str, Any]) -> None:
        if d.get("kind") == "torque":
            payload = torque_calibration_payload(d["n_cb"], d["cb_lever_a5_m"])
        else:
            payload = mass_calibration_payload(d["n_cb"])
        await self.sim.mount(payload)
        engine = self.daemon_ref[0].engine
        assert engine is not None
        engine.confirm(f"operator mounted point {d['point_index']}")


async def _wait(task: asyncio.Task[Any], what: str) -> Any:
    try:
        async with asyncio.timeout(DEADLINE_S):
            return await task
    except TimeoutError as exc:
        raise RgseError(f"demo: {what} did not finish within {DEADLINE_S:.0f} s") from exc


async def run_demo(*, quiet: bool, report_dir: Path | None, mqtt_url: str | None) -> dict[str, Any]:
    t_start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="rgse-demo-") as tmp:
        root = Path(tmp)
        # the simulated controller in its own process, as a real KR C4 is its own machine: its CPU work must not
        # stall the daemon's event loop and its 20 Hz interlock monitor
        sim = SimProcess(root / "share", seed=SEED, time_scale=TIME_SCALE, globals_dat=globals_dat_text())
        await asyncio.to_thread(sim.start)
        try:
            cfg = demo_config(sim, root / "data", mqtt_url)
            ref: list[Daemon] = []
            daemon = Daemon(cfg, on_event=Operator(sim, ref, quiet))
            ref.append(daemon)
            stop = asyncio.Event()
            service = asyncio.create_task(daemon.run(stop), name="rgse-demo-daemon")
            try:
                async with asyncio.timeout(30):
                    await daemon.connected.wait()
                if not quiet:
                    print(f"calibration campaign: {len(CAMPAIGN)} points x {CAMPAIGN_LOOPS} loops", file=sys.stderr)
                t0 = time.monotonic()
                cal_settings = RunSettings.from_config(cfg, loops=CAMPAIGN_LOOPS, warmup_cycles=1)
                calibration = await _wait(
                    await daemon.start_calibration(points=CAMPAIGN, method="auto", settings=cal_settings),
                    "the calibration campaign",
                )
                t_cal = time.monotonic() - t0
                dut = dut_payload(DUT_MASS_KG, DUT_COG_M, fixture_mass_kg=FIXTURE_MASS_KG)
                await sim.mount(dut)
                if not quiet:
                    print(f"in-line measurement: {MEASUREMENT_LOOPS} loops", file=sys.stderr)
                t0 = time.monotonic()
                result = await _wait(await daemon.start_measurement(), "the measurement run")
                t_meas = time.monotonic() - t0
                report_path = None
                if report_dir is not None:
                    report_path = await _write_report(cfg, result["run_id"], report_dir)
            finally:
                stop.set()
                async with asyncio.timeout(60):
                    await service
        finally:
            await asyncio.to_thread(sim.stop)
    timing = result["timing"]
    robot_wall_s = float(timing["robot_time_s"])
    overhead_s = float(timing["overhead_s"])
    return {
        "mass_kg": result["mass_kg"],
        "true_mass_kg": DUT_MASS_KG,
        "error_kg": result["mass_kg"] - DUT_MASS_KG,
        "U_kg": result["U_kg"],
        "within_U": abs(result["mass_kg"] - DUT_MASS_KG) <= result["U_kg"],
        "loops": result["loops"],
        "robot_time_s": robot_wall_s * TIME_SCALE,
        "overhead_s": overhead_s,
        "overhead_pct_of_robot_time": 100.0 * overhead_s / (robot_wall_s * TIME_SCALE),
        # per loop: robot time as the real robot would need it (simulated time), daemon overhead in wall time (pull,
        # archive, store), plus the run's one-off computation of the mass
        "per_loop": [{"robot_s": float(lp["robot_s"]) * TIME_SCALE, "overhead_s": float(lp["overhead_s"]),
                      "pull_s": float(lp["pull_s"]), "store_s": float(lp["store_s"])} for lp in timing["per_loop"]],
        "compute_s": float(timing["compute_s"]),
        "time_scale": TIME_SCALE,
        "run_id": result["run_id"],
        "calibration": {
            "calibration_id": calibration["calibration_id"],
            "method": calibration["method"],
            "points": calibration["points"],
            "in_sample_mean_abs_err_pct": calibration["in_sample_mean_abs_err_pct"],
            "loo_mean_abs_err_pct": calibration["loo_mean_abs_err_pct"],
        },
        "wall_s": {"calibration": t_cal, "measurement": t_meas, "total": time.monotonic() - t_start},
        "warnings": result.get("warnings", []),
        "report": str(report_path) if report_path is not None else None,
    }


async def _write_report(cfg: Config, run_id: str, out: Path) -> Path:
    from rgse_daemon.commands import report  # optional part: the HTML report

    return await asyncio.to_thread(report.write, cfg, run_id=run_id, out_dir=out)


def run(args: argparse.Namespace) -> int:
    summary = asyncio.run(run_demo(quiet=args.json, report_dir=args.report, mqtt_url=args.mqtt))
    if args.json:
        print(json.dumps(summary))
        return 0
    c = summary["calibration"]
    print(f"calibration {c['calibration_id']} ({c['method']}, {c['points']} points): "
          f"in-sample {c['in_sample_mean_abs_err_pct']:.3f} %, leave-one-out {c['loo_mean_abs_err_pct']:.3f} %")
    print(f"true mass      {summary['true_mass_kg']:9.3f} kg")
    print(f"measured mass  {summary['mass_kg']:9.3f} kg ± {summary['U_kg']:.3f} kg (U, k = 2)   "
          f"error {summary['error_kg']:+.3f} kg  {'within' if summary['within_U'] else 'OUTSIDE'} U")
    print(f"{summary['loops']} loops: robot time {summary['robot_time_s'] / 60:.1f} min (real-time equivalent), "
          f"daemon overhead {summary['overhead_s']:.2f} s ({summary['overhead_pct_of_robot_time']:.2f} %)")
    w = summary["wall_s"]
    print(f"wall time: campaign {w['calibration']:.1f} s, measurement {w['measurement']:.1f} s, "
          f"total {w['total']:.1f} s (simulator at {summary['time_scale']:g}x)")
    if summary["report"] is not None:
        print(f"report: {summary['report']}")
    for warning in summary["warnings"]:
        print(f"warning: {warning}")
    return 0
