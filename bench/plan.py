"""The planned calibration campaign for a 50–250 kg DuT range (issue 35, goal: <= 120 min of robot time, against the
paper's 480 min), predicted by ``rgse plan`` and, with ``--run``, run on the simulated KR C4 as a lab would run it.

* ``predicted``: the planner's points for 50–250 kg at a CoG lever of 0.40–0.90 m from A5 (the demo's wing box on
  its fixture sits at about 0.63 m), its predicted robot time by part and its predicted U.
* ``run`` (``--run``): the planned points file read with ``load_points`` and turned into loads as the daemon does,
  the campaign run by the whole daemon on ``rgse demo``'s simulator (seed, scatter, drift and noise as rough as the
  demo's) with the planned loops a point, then an in-line mass run of the demo's wing box with that calibration.
  Robot time: the campaign result's ``robot_time_s`` (loops) and the warm-ups (the warm-up runs the events announce
  x the median duration of one run), both x the simulator's time scale. By default the simulated operator mounts a
  load at once: load changes cost no time, so the re-warm-ups the planner assumes after each one are not triggered.
  ``--load-change-s S``: the operator takes S s of robot time for each load change with the drives off (the brakes
  applied, as in T1 when the enabling switch is let go), so the simulated motors cool (the simulator's first-order
  model, ``[thermal]`` of its scenario) and the daemon warms up again when A3/A5 cooled by more than
  ``warmup_steady_k``; the A3/A5 temperatures before and after each change are reported.
* alarms: the engine's (an interlock trip, a refused program) and the daemon's warnings and errors (the heartbeat and
  the controller-side watchdog among them), by phase, so that a run under load says whether anything tripped.
* ``demo``: the demo's campaign (16 points, 42 loops: bench/robot_time.py measured 54.8 min of loops at x50) and
  the paper's (14 points, 480 min).

Run: ``.venv/bin/python bench/plan.py [--run] [--time-scale 100] [--seed 2024] [--load-change-s 0]``
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import logging
import statistics
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from demo_sim import demo_sim, finished, running_daemon

from rgse_daemon.app import Daemon, campaign_point
from rgse_daemon.client import load_points
from rgse_daemon.commands import demo
from rgse_daemon.commands import plan as plan_cmd
from rgse_daemon.config import load_config
from rgse_daemon.io.commands import CalibrationPoint
from rgse_daemon.pipeline import planning as pl
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.inertia import TARE_PROMPT
from rgse_daemon.procedures.settings import RunSettings

MASS_KG = (50.0, 250.0)
LEVER_A5_M = (0.40, 0.90)
#: bench/robot_time.py at x50 (commit c8ada2c): the demo's campaign, 42 loops.
DEMO_CAMPAIGN_LOOPS_MIN, DEMO_CAMPAIGN_LOOPS = 54.8, 42
GOAL_MIN = 120.0


def predicted(points_out: Path) -> dict[str, Any]:
    args = SimpleNamespace(mass=list(MASS_KG), lever_a5=list(LEVER_A5_M), dut=None, loops_per_point=3,
                           max_distance=pl.DEFAULT_MAX_DISTANCE, points_out=points_out)
    cfg = load_config(None)
    p = plan_cmd.make_plan(args, cfg)  # type: ignore[arg-type]
    points_out.write_text(pl.points_toml(p.points, plan_cmd.equipment()), encoding="utf-8")
    out = plan_cmd.to_json(p, args)  # type: ignore[arg-type]
    out["points_checked"] = plan_cmd.check_file(points_out, cfg)
    return out


class WarmupClock:
    """The engine's events, timed: warm-up runs (``step`` events of step ``warm-up``) and their wall spacing."""

    def __init__(self) -> None:
        self.events: list[tuple[float, Event]] = []

    def __call__(self, ev: Event) -> None:
        self.events.append((time.monotonic(), ev))

    def warmup_wall_s(self) -> tuple[int, int, float]:
        """(warm-ups, warm-up runs, their wall time): each run's duration is the median spacing of two runs of one
        warm-up; a warm-up starts with its run 1 (the first, then one after each load change that cooled A3/A5)."""
        runs = [(t, ev.data.get("run")) for t, ev in self.events if ev.kind == "step" and ev.step == "warm-up"]
        spacing = [t1 - t0 for (t0, _), (t1, r1) in itertools.pairwise(runs) if r1 and r1 > 1]
        if not runs:
            return 0, 0, 0.0
        starts = sum(1 for _, r in runs if r == 1)
        return starts, len(runs), len(runs) * (statistics.median(spacing) if spacing else 0.0)

    def loop_parts_s(self) -> dict[str, float]:
        """The median campaign loop's parts (s of wall time, as the loop events report them): the brake-release move,
        the settling and the recording (what ``robot_time_s`` counts), and the overrun (overhead, not counted)."""
        loops = [ev.data for _, ev in self.events if ev.kind == "loop" and "motion_s" in ev.data]
        return {k: statistics.median(float(d[k]) for d in loops) if loops else 0.0
                for k in ("motion_s", "settle_s", "record_s", "overrun_s")}


THERMAL_VARS = ("$MOT_TEMP[3]", "$MOT_TEMP[5]")


def slow_operator(load_change_s: float, scale: float,
                  changes: list[dict[str, Any]]) -> type[demo.Operator]:
    """The demo's operator, who takes ``load_change_s`` of robot time (``load_change_s / scale`` of wall time) for
    each load change of the campaign with the drives off; the A3/A5 motor temperatures (K, whole degrees as the
    simulator reports them) before and after each change go to ``changes``."""

    class SlowOperator(demo.Operator):
        async def _mount_and_confirm(self, d: dict[str, Any]) -> None:
            if int(d.get("point_index", 0)) > 0 and d.get(TARE_PROMPT) is not True:  # not the first load
                before = await self.sim.peek(*THERMAL_VARS)  # the physics brought up to now, drives as they were
                await self.sim.update("$PERI_RDY", "FALSE")  # drives off: the next program start turns them on
                await asyncio.sleep(load_change_s / scale)
                after = await self.sim.peek(*THERMAL_VARS)
                changes.append({"point_index": d["point_index"], "before_k": [float(before[v]) for v in THERMAL_VARS],
                                "after_k": [float(after[v]) for v in THERMAL_VARS]})
            await super()._mount_and_confirm(d)

    return SlowOperator


class LogCapture(logging.Handler):
    """The daemon's warnings and errors (its alarms are logged as errors), tagged with the bench's phase."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.phase = "start-up"
        self.records: list[dict[str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append({"phase": self.phase, "level": record.levelname, "logger": record.name,
                             "message": record.getMessage()})


async def run_campaign(points_file: Path, scale: float, seed: int, loops: int,
                       load_change_s: float = 0.0, rewarm: bool = True) -> dict[str, Any]:
    log = LogCapture()
    logging.getLogger("rgse_daemon").addHandler(log)
    try:
        return await _run_campaign(points_file, scale, seed, loops, load_change_s, log, rewarm)
    finally:
        logging.getLogger("rgse_daemon").removeHandler(log)


async def _run_campaign(points_file: Path, scale: float, seed: int, loops: int, load_change_s: float,
                        log: LogCapture, rewarm: bool = True) -> dict[str, Any]:
    changes: list[dict[str, Any]] = []
    operator = slow_operator(load_change_s, scale, changes) if load_change_s > 0.0 else demo.Operator
    async with demo_sim("rgse-bench-plan-", scale, seed) as (sim, cfg):
        # rewarm False: one warm-up run before the first point and none after a load change (the campaign's loops
        # then warm the motors and span the temperatures β is fitted on)
        s = RunSettings.from_config(cfg, loops=loops, **({} if rewarm else {"warmup_until_steady": False}))
        points = [campaign_point(CalibrationPoint.model_validate(p.as_command()), s.g_m_s2)
                  for p in load_points(points_file)]
        clock = WarmupClock()
        async with running_daemon(sim, cfg, clock, operator=operator) as daemon:
            log.phase = "campaign"
            t0 = time.monotonic()
            cal = await finished(await daemon.start_calibration(points=points, method="auto", settings=s))
            wall = time.monotonic() - t0
            warmups, warm_runs, warm_wall = clock.warmup_wall_s()
            loop_parts = clock.loop_parts_s()
            log.phase = "measurement"
            await sim.mount(demo.DUT.payload())
            res = await finished(await daemon.start_measurement())
            alarms = _alarms(clock, daemon)
            log.phase = "shut-down"
    return {"scale": scale, "seed": seed, "loops_per_point": loops, "points": len(points), "rewarm": rewarm,
            "thermal_applied": res.get("thermal_applied"), "calibration_thermal": cal.get("thermal"),
            "load_change_s": load_change_s, "load_changes": changes,
            "campaign_wall_s": wall, "loops_robot_min": float(cal["robot_time_s"]) * scale / 60.0,
            "loops": sum(int(p["loops"]) for p in cal.get("points_stop", [])),
            "loop_parts_robot_s": {k: v * scale for k, v in loop_parts.items()},
            "warmups": warmups, "warmup_runs": warm_runs, "warmup_robot_min": warm_wall * scale / 60.0,
            "alarms": alarms, "daemon_log": log.records,
            "method": cal.get("method"), "calibration_warnings": cal.get("warnings", []),
            "dut_true_kg": demo.DUT_MASS_KG, "dut_mass_kg": res["mass_kg"], "dut_U_kg": res["U_kg"],
            "dut_error_kg": res["mass_kg"] - demo.DUT_MASS_KG,
            "dut_within_U": abs(res["mass_kg"] - demo.DUT_MASS_KG) <= res["U_kg"],
            "dut_u_components_kg": res.get("u_components_kg"), "dut_warnings": res.get("warnings", [])}


def _alarms(clock: WarmupClock, daemon: Daemon) -> list[str]:
    """The engine's alarm events of both runs and the daemon-level alarms still active at their end."""
    return ([ev.message for _, ev in clock.events if ev.kind == "alarm"]
            + [f"daemon alarm active: {kind}" for kind in sorted(daemon.alarms.active)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", action="store_true", help="run the planned campaign on the simulator")
    ap.add_argument("--time-scale", type=float, default=100.0)
    ap.add_argument("--seed", type=int, default=demo.SEED)
    ap.add_argument("--load-change-s", type=float, default=0.0,
                    help="robot time (s) the operator takes for each load change, drives off (0: mounts at once)")
    ap.add_argument("--no-rewarm", action="store_true",
                    help="one warm-up run before the first point, no warm-up after a load change")
    args = ap.parse_args()
    if args.time_scale <= 0.0 or args.load_change_s < 0.0:
        ap.error("--time-scale must be > 0 and --load-change-s >= 0")
    with tempfile.TemporaryDirectory(prefix="rgse-plan-") as tmp:
        f = Path(tmp) / "plan.toml"
        out: dict[str, Any] = {"range": {"mass_kg": MASS_KG, "lever_a5_m": LEVER_A5_M}, "predicted": predicted(f)}
        if args.run:
            out["run"] = asyncio.run(run_campaign(f, args.time_scale, args.seed, 3, args.load_change_s,
                                                  not args.no_rewarm))
    _print(out)
    print(json.dumps(out))


def _print(out: dict[str, Any]) -> None:
    p, t = out["predicted"], out["predicted"]["time"]
    print(f"planned campaign for {out['range']['mass_kg'][0]:g}-{out['range']['mass_kg'][1]:g} kg at "
          f"{out['range']['lever_a5_m'][0]:g}-{out['range']['lever_a5_m'][1]:g} m from A5: {len(p['points'])} points "
          f"({p['loaded_points']} loaded), DuTs covered {p['covered']}/{p['duts']}, accepted by load_points and "
          f"check_points_support (auto): {p['points_checked']} points")
    print(f"{'campaign':<34} {'points':>6} {'loops':>5} {'loops min':>9} {'warm-up min':>11} {'robot min':>9} "
          f"{'goal':>6}")
    warm_lo, warm_hi = (t["warmup_initial_min_s"] + t["rewarm_s"]) / 60, (t["warmup_initial_s"] + t["rewarm_s"]) / 60
    verdict = "<=120" if t["robot_s"] / 60 <= GOAL_MIN else "OVER"
    print(f"{'planned, predicted':<34} {len(p['points']):>6} {t['loops']:>5} {t['loops_s'] / 60:>9.1f} "
          f"{warm_lo:>5.0f}-{warm_hi:<5.0f} {t['robot_min_s'] / 60:>4.0f}-{t['robot_s'] / 60:<4.0f} {verdict:>6}")
    if "run" in out:
        r = out["run"]
        total = r["loops_robot_min"] + r["warmup_robot_min"]
        print(f"{'planned, run (sim x' + format(r['scale'], 'g') + ', seed ' + str(r['seed']) + ')':<34} "
              f"{r['points']:>6} {r['loops']:>5} "
              f"{r['loops_robot_min']:>9.1f} {r['warmup_robot_min']:>11.1f} {total:>9.1f} "
              f"{'<=120' if total <= GOAL_MIN else 'OVER':>6}")
        lp = r["loop_parts_robot_s"]
        print(f"  the median loop: move {lp['motion_s']:.1f} s + settling {lp['settle_s']:.1f} s + recording "
              f"{lp['record_s']:.1f} s of robot time (overrun {lp['overrun_s']:.1f} s, overhead, not counted)")
        print(f"  warm-ups run: {r['warmups']} ({r['warmup_runs']} runs of the warm-up move); campaign wall time "
              f"{r['campaign_wall_s']:.1f} s")
        if r["load_change_s"] > 0.0:
            cooled = [max(b - a for b, a in zip(c["before_k"], c["after_k"], strict=True)) for c in r["load_changes"]]
            print(f"  load changes: {len(cooled)} of {r['load_change_s']:g} s with the drives off; A3/A5 cooled by "
                  f"{min(cooled, default=0):g}-{max(cooled, default=0):g} K (re-warm-up above 1 K)")
        else:
            print("  the simulated operator mounts at once, so the motors do not cool between points")
        print(f"  alarms: {len(r['alarms'])}" + (f" ({'; '.join(r['alarms'])})" if r["alarms"] else ""))
        for rec in r["daemon_log"]:
            print(f"  daemon {rec['level'].lower()} ({rec['phase']}): {rec['logger']}: {rec['message']}")
    print(f"{'demo campaign (robot_time.py x50)':<34} {16:>6} {DEMO_CAMPAIGN_LOOPS:>5} "
          f"{DEMO_CAMPAIGN_LOOPS_MIN:>9.1f} {'-':>11} {'-':>9} {'':>6}")
    print(f"{'paper (Table 1, §2.4.4)':<34} {pl.PAPER_CAMPAIGN_POINTS:>6} {'-':>5} {'-':>9} {'-':>11} "
          f"{pl.PAPER_CAMPAIGN_MIN:>9.0f} {'':>6}")
    lo, hi = p["predicted_U_kg"]
    print(f"predicted U (k = 2) inside the range: {lo:.2f}-{hi:.2f} kg")
    if "run" in out:
        r = out["run"]
        print(f"wing box with the planned calibration: {r['dut_mass_kg']:.2f} kg, U {r['dut_U_kg']:.2f} kg, true "
              f"{r['dut_true_kg']:.2f} kg ({'within' if r['dut_within_U'] else 'OUTSIDE'} U)"
              + (f"; warnings: {'; '.join(r['dut_warnings'])}" if r["dut_warnings"] else ""))


if __name__ == "__main__":
    main()
