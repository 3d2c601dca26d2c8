"""Robot time of a properties run alone (issue 35): the demo's wing box, measured by the whole daemon on the demo's
simulated KR C4 with the demo's run settings (stop rule, 1000 samples at 12 ms, 4 s settling, the demo's scheme
``lever`` at 2 loops a pose, the demo's mass method ``auto`` unless ``--mass-method``), the controller's file work at
40 kB/s. Unlike ``bench/robot_time.py`` it does not measure the
calibration campaign first: the calibration (with its torsional section) is fitted offline from a simulated campaign
(``tests/support/cogcal.py``), so the run needs only about a minute of real-time robot control and survives a loaded
machine. Robot time is counted as in ``bench/robot_time.py`` (the loops' motion + settling + recording, x the time
scale); U is not this bench's figure (the calibration is not the simulated robot's own).

Run: ``.venv/bin/python bench/properties_time.py [--time-scale 20] [--seed 2024] [--mass-method auto]``; run it on
two checkouts for a before/after.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from demo_sim import demo_sim, finished, running_daemon

from rgse_daemon import robots
from rgse_daemon.commands import demo
from rgse_daemon.procedures.properties import PropertiesSettings
from rgse_daemon.store import Store
from simulators.krc4 import physics as ph
from tests.support.cogcal import fit_sim_cog_calibration
from tests.support.simcampaign import ROBOT


async def properties_run(scale: float, seed: int, cal_doc: dict[str, Any], mass_method: str) -> dict[str, Any]:
    async with demo_sim("rgse-properties-time-", scale, seed) as (sim, cfg):
        cfg = cfg.model_copy(update={"robot": cfg.robot.model_copy(update={"name": ROBOT})})
        async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
            await store.add_calibration(cal_doc, activate=True)
        async with running_daemon(sim, cfg) as daemon:
            await sim.mount(demo.DUT.payload())
            props = await finished(await daemon.start_properties(props=PropertiesSettings(
                demo.COG_SCHEME, demo.PROPERTIES_LOOPS_PER_POSE, ph.fixture_cog_flange_m(),
                demo.DUT.dut_origin_flange_m, demo.DUT.dut_abc_deg, False, mass_method=mass_method)))
    t = props["timing"]
    per = t["per_loop"]
    mass = set(props.get("mass_traces", []))
    return {"time_scale": scale, "seed": seed, "status": props["status"],
            "robot_min": float(t["robot_time_s"]) * scale / 60.0,
            "mass_min": float(t["mass_robot_time_s"]) * scale / 60.0,
            "cog_min": float(t["cog_robot_time_s"]) * scale / 60.0,
            "mass_loops": len(mass), "cog_loops": len([lp for lp in per if lp["trace"] not in mass]),
            "loop_min": [round(lp["robot_s"] * scale / 60.0, 3) for lp in per],
            "poses": [(p["name"], len(p["traces"])) for p in props.get("cog_poses", [])],
            "U_kg": props.get("U_kg"), "U_cog_m": props.get("U_cog_m"), "stop_reason": props.get("stop_reason"),
            "mass_method": props.get("mass_method"), "mass_method_requested": props.get("mass_method_requested"),
            "mass_methods": {k: {"mass_kg": v["mass_kg"], "U_kg": v["U_kg"],
                                 "robot_min": float(v.get("robot_time_s") or 0.0) * scale / 60.0}
                             for k, v in (props.get("mass_methods") or {}).items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-scale", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=demo.SEED)
    ap.add_argument("--mass-method", choices=("single", "multipose", "auto"),
                    default=demo.mass_method(robots.get(robots.DEFAULT_KEY)),
                    help="the properties run's mass method (default: the KR 500 demo's)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="rgse-properties-time-cal-") as tmp:
        cal_doc = fit_sim_cog_calibration(Path(tmp), demo.COG_SCHEME, seed=args.seed)  # the demo's scheme, its arm
    out = asyncio.run(properties_run(args.time_scale, args.seed, cal_doc, args.mass_method))
    print(f"properties run: {out['robot_min']:.2f} min of robot time (mass {out['mass_min']:.2f} min, "
          f"{out['mass_loops']} loops; CoG {out['cog_min']:.2f} min, {out['cog_loops']} loops; poses "
          f"{out['poses']}; goal <= 8 min), status {out['status']}, mass method {out['mass_method']} "
          f"(asked {out['mass_method_requested']}), x{args.time_scale:g}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
