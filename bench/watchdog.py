"""Benchmark of the controller-side watchdog (docs/security.md): how long a motion outlives its heartbeat.

The simulated KR C4 runs in its own process (5x real time). The rendered warm-up (40 cycles: minutes of motion) is
pushed and started while the daemon's own :class:`~rgse_daemon.services.heartbeat.Heartbeat` beats; once the axes
move, the heartbeat task is cancelled (its connection closes, no stop is sent: as a SIGKILL). An independent
connection reads ``$AXIS_ACT`` every 20 ms. Per trial:

* ``after_last_beat_s``: from the last good beat to the last axis change (the bound plus the braking ramp);
* ``after_loss_s``: from the loss of the heartbeat to the last axis change (what an observer of the host sees).

Prints ONE JSON object: both figures per trial, their mean and max, the bound, and the goal of issue 31
(``after_loss_s`` ≤ 2 s).

Usage: ``.venv/bin/python bench/watchdog.py [--trials 5] [--bound-s 0.75]``
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from rgse_daemon.commands.krl import template_defaults
from rgse_daemon.config import Config, ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.krl.render import default_params, globals_dat_text, render
from rgse_daemon.link.connection import Connection
from rgse_daemon.services.heartbeat import Heartbeat
from rgse_daemon.services.signals import Alarms, StackLight
from simulators.krc4.process import SimProcess

PROGRAM = "KRC:\\R1\\PROGRAM\\RGSE_WARMUP.SRC"
GOAL_S = 2.0
OBSERVE_S = 5.0


async def _axes(conn: Connection) -> str:
    return await conn.read_var("$AXIS_ACT")


async def trial(sim: SimProcess, cfg: ControllerConfig) -> dict[str, float]:
    params = default_params("rgse_warmup", template_defaults(Config())).model_copy(update={"cycles": 40})
    program = render("rgse_warmup", params)
    observer = Connection("127.0.0.1", sim.port, name="observer")
    heartbeat = Heartbeat(cfg, Alarms(lambda _: None, StackLight(None)), link_up=lambda: True)
    stop = asyncio.Event()
    async with Controller.connect(cfg) as krc:
        await krc.put_file(PROGRAM, program.src_text.replace("\n", "\r\n").encode("latin-1"))
        with_beats = asyncio.create_task(heartbeat.run(stop))
        try:
            await krc.select_program(PROGRAM)
            await krc.start_program()
            last = await _axes(observer)
            async with asyncio.timeout(60.0):
                while (now := await _axes(observer)) == last:
                    last = now
                    await asyncio.sleep(0.05)
            with_beats.cancel()  # the host is gone: no stop of the timer, the connection closes
            await asyncio.wait({with_beats})
            t_loss = time.monotonic()
            assert heartbeat.last_beat_s is not None
            t_last_change = t_loss
            while time.monotonic() - t_loss < OBSERVE_S:
                now = await _axes(observer)
                if now != last:
                    t_last_change, last = time.monotonic(), now
                await asyncio.sleep(0.02)
            state = (await krc.read_raw("$PRO_STATE1")).strip()
            await krc.reset_program()
            await krc.cancel_program()
        finally:
            with_beats.cancel()
            await observer.close()
    return {"after_last_beat_s": t_last_change - heartbeat.last_beat_s, "after_loss_s": t_last_change - t_loss,
            "halted": state == "#P_STOP"}  # type: ignore[dict-item]


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--bound-s", type=float, default=ControllerConfig().watchdog_bound_s)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        sim = SimProcess(Path(tmp) / "share", seed=3, time_scale=5.0, latency_s=0.0, globals_dat=globals_dat_text())
        await asyncio.to_thread(sim.start)
        try:
            cfg = ControllerConfig(host="127.0.0.1", port=sim.port, protocol="c3bridge", pool_size=2,
                                   watchdog_bound_s=args.bound_s)
            trials = [await trial(sim, cfg) for _ in range(args.trials)]
        finally:
            await asyncio.to_thread(sim.stop)
    out: dict[str, object] = {"bound_s": args.bound_s, "period_s": ControllerConfig().watchdog_period_s,
                              "trials": trials, "goal_after_loss_s": GOAL_S}
    for key in ("after_last_beat_s", "after_loss_s"):
        values = [t[key] for t in trials]
        out[key] = {"mean": statistics.fmean(values), "max": max(values),
                    "sd": statistics.stdev(values) if len(values) > 1 else 0.0}
    out["all_halted"] = all(t["halted"] for t in trials)
    out["goal_met"] = max(t["after_loss_s"] for t in trials) <= GOAL_S and out["all_halted"]
    json.dump(out, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    asyncio.run(main())
