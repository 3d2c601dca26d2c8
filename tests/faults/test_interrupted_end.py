"""Issue 31 6a: a run that its daemon's crash ended is seen as ended.

``rgse run measure`` (a subprocess, as a script runs it) follows a run; the daemon (its own process) is SIGKILLed
while loop 1 records and a new daemon starts on the same store, controller and broker. Its recovery publishes the
run's final ``interrupted`` result and a ``run_interrupted`` alarm: the command must end on them, with a hint that
says what happened, instead of waiting out its timeout and then telling the operator to abort a run that no longer
exists."""

from __future__ import annotations

import asyncio
import json
import os
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from simulators.krc4.sim import SimulatedKrc4
from tests.support.configfile import write_config
from tests.support.daemon import PREFIX, daemon_config, running_daemon, seed_calibration
from tests.support.faults import WAIT_S, DaemonProcess, swept
from tests.support.mqtt import MosquittoProcess, retained
from tests.support.polling import wait_until

#: The command's own timeout: long beside the recovery (seconds), so that only a command that ignores the
#: ``interrupted`` end reaches it (and then says "not within", which the test refuses).
RUN_TIMEOUT_S = 150


async def ready(port: int) -> bool:
    """The daemon's retained state says it is connected and idle: its sweep is done, a run may start."""
    got = await retained("127.0.0.1", port, f"{PREFIX}/state")
    return any((s := json.loads(m.payload)).get("engine") == "idle" and s.get("connected") is True for m in got)


async def wait_until_async(check: Callable[[], Awaitable[bool]], what: str, timeout_s: float) -> None:
    for _ in range(int(timeout_s / 0.1)):
        if await check():
            return
        await asyncio.sleep(0.1)
    raise AssertionError(f"{what}: not within {timeout_s:g} s")


@pytest.mark.timeout(4 * RUN_TIMEOUT_S)
async def test_rgse_run_ends_on_an_interrupted_result_with_the_right_hint(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port)
    await seed_calibration(cfg, calibration_doc)
    config = write_config(cfg, tmp_path / "rgse.toml")
    child = DaemonProcess(cfg, "idle")
    await child.start()
    await child.until(lambda x: x.get("kind") == "started", "the daemon up", WAIT_S)
    await wait_until_async(lambda: ready(private_broker.port), "the daemon ready", WAIT_S)
    env = {k: v for k, v in os.environ.items() if not k.startswith("RGSE_")}
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "rgse_daemon.cli", "run", "measure", "--config", str(config), "--loops", "10",
        "--timeout", str(RUN_TIMEOUT_S), stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE, env=env)
    assert proc.stderr is not None and proc.stdout is not None
    err: list[str] = []

    async def read_err() -> None:
        assert proc.stderr is not None
        while line := (await proc.stderr.readline()).decode():
            err.append(line)

    reading = asyncio.create_task(read_err())
    try:
        await wait_until(lambda: any(" run " in line and " started" in line for line in err) or
                         proc.returncode is not None, "rgse run following its run", WAIT_S)
        assert proc.returncode is None, "".join(err)
        await child.kill()
        async with running_daemon(cfg) as rd:
            await swept(rd.daemon)
            async with asyncio.timeout(2 * RUN_TIMEOUT_S):  # a hang guard, not a timing check
                rc = await proc.wait()
                await reading
    finally:
        await child.kill()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    text = "".join(err)
    assert rc == 1, text
    assert "interrupted" in text and "not within" not in text, text
    assert "abort it with rgse abort" not in text and "no run in progress" not in text, text
    assert "daemon" in text.split("interrupted", 1)[1], text  # the hint names what ended it: the daemon stopped
