"""The daemon in a process of its own for the crash tests: ``daemon_child.py CONFIG_JSON
measurement|calibration|idle [--no-confirm]``. Starts the daemon, starts one run (none with ``idle``: a client starts
it), prints every engine event as a JSON line, confirms the operator prompts (unless ``--no-confirm``), and runs until
it is killed."""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from rgse_daemon.app import Daemon
from rgse_daemon.config import config_from_mapping
from rgse_daemon.procedures.calibration import table1_points
from rgse_daemon.procedures.events import Event
from rgse_daemon.systemd import Notifier

#: The smallest campaign the pre-check admits (``check_points_support``): two loaded points, fitted with "auto" (the
#: paper's models need at least 4 loaded points; a campaign they cannot fit is refused before its first prompt).
CAMPAIGN = table1_points(n_bodies=(0, 2, 4), torque_levers_a5_m=())
METHOD = "auto"


async def main() -> None:
    cfg = config_from_mapping(json.loads(sys.argv[1]), "<fault child>")
    kind = sys.argv[2]
    confirm = "--no-confirm" not in sys.argv
    daemon: Daemon | None = None

    def on_event(ev: Event) -> None:
        print(json.dumps({"kind": ev.kind, "step": ev.step, "message": ev.message, "run_id": ev.run_id}), flush=True)
        if ev.kind == "confirm" and confirm and daemon is not None and daemon.engine is not None:
            asyncio.get_running_loop().call_soon(daemon.engine.confirm, "mounted (fault test)")

    daemon = Daemon(cfg, notifier=Notifier({}), on_event=on_event)
    stop = asyncio.Event()
    task = asyncio.create_task(daemon.run(stop))
    await daemon.connected.wait()
    if kind == "measurement":
        await daemon.start_measurement()
    elif kind != "idle":  # "idle": the daemon alone, no run
        await daemon.start_calibration(points=CAMPAIGN, method=METHOD)
    print(json.dumps({"kind": "started"}), flush=True)
    await task


if __name__ == "__main__":
    asyncio.run(main())
