"""``rgse daemon`` says that it runs (issue #34: without ``-v`` it printed nothing at start): what it serves when it
starts, when the controller first answers, and that it stopped, on stderr, as a separate process."""

from __future__ import annotations

import asyncio
import signal
import sys
from pathlib import Path

from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config

DEADLINE_S = 60.0


async def test_daemon_says_what_it_serves_and_when_the_controller_answers(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir)
    config = tmp_path / "rgse.toml"
    config.write_text(f'[robot]\nname = "{cfg.robot.name}"\n[controller]\nhost = "127.0.0.1"\nport = {sim.port}\n'
                      f'protocol = "c3bridge"\nwatchdog_bound_s = 1.0\n[paths]\ndata_dir = "{tmp_path / "data"}"\n'
                      f'[limits]\nsnapshot_stale_s = 1.0\n')
    proc = await asyncio.create_subprocess_exec(sys.executable, "-m", "rgse_daemon", "daemon", "--config",
                                                str(config), stdout=asyncio.subprocess.DEVNULL,
                                                stderr=asyncio.subprocess.PIPE)
    lines: list[str] = []
    try:
        async with asyncio.timeout(DEADLINE_S):
            while not lines or "controller connected" not in lines[-1]:
                lines.append((await proc.stderr.readline()).decode())
                assert lines[-1], lines  # ended before saying it was connected
        assert lines[0].startswith(f"rgse daemon: robot {cfg.robot.name}, controller 127.0.0.1:{sim.port}, ")
        assert "mqtt off, console off; waiting for the controller" in lines[0]
        assert lines[-1] == "rgse daemon: controller connected; runs can start\n"
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(DEADLINE_S):
            rest = (await proc.stderr.read()).decode()
            await proc.wait()
        assert proc.returncode == 0 and rest.endswith("rgse daemon: stopped\n"), rest
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
