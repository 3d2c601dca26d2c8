"""Helpers of the fault suite (tests/faults): the simulator's ground truth, the daemon as a separate process to
SIGKILL (``daemon_child.py``), and "the daemon's connect-time sweep and recovery are done"."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rgse_daemon.config import Config
from simulators.krc4.process import SimProcess
from tests.support.polling import wait_until

PG_URL = os.environ.get("RGSE_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/test")
PROGRAM_VARS = ("$PRO_STATE1", "$PRO_NAME1[]", "$TRACE.STATE")
TRACE_ACTIVE = ("#T_WAIT", "#TRIGGERED", "#T_START")
WAIT_S = 90.0


async def truth(sim: SimProcess) -> dict[str, str]:
    """$PRO_STATE1, $PRO_NAME1[] and $TRACE.STATE as the simulated controller has them (not as the daemon reads)."""
    v = await sim.peek(*PROGRAM_VARS)
    return {k: x.strip().strip('"').upper() for k, x in v.items()}


def ours_active(v: dict[str, str], name: str | None = None) -> bool:
    return v["$PRO_STATE1"] == "#P_ACTIVE" and v["$PRO_NAME1[]"].startswith(name or "RGSE_")


def stopped(v: dict[str, str]) -> bool:
    """Nothing of ours can move: no program active, none of ours left selected where start would resume it, no
    trace recording."""
    return (v["$PRO_STATE1"] != "#P_ACTIVE"
            and not (v["$PRO_NAME1[]"].startswith("RGSE_") and v["$PRO_STATE1"] in ("#P_STOP", "#P_RESET"))
            and v["$TRACE.STATE"] not in TRACE_ACTIVE)


def halted(v: dict[str, str]) -> bool:
    """No program active, no trace recording (a stopped program may still be selected)."""
    return v["$PRO_STATE1"] != "#P_ACTIVE" and v["$TRACE.STATE"] not in TRACE_ACTIVE


async def until_truth(sim: SimProcess, predicate: Callable[[dict[str, str]], bool], what: str,
                      timeout_s: float = WAIT_S, period_s: float = 0.02) -> dict[str, str]:
    deadline = time.monotonic() + timeout_s
    while True:
        v = await truth(sim)
        if predicate(v):
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:g} s; the simulator shows {v}")
        await asyncio.sleep(period_s)


async def swept(daemon: Any, timeout_s: float = WAIT_S) -> None:
    """Wait until ``daemon`` (a connected :class:`~rgse_daemon.app.Daemon`) finished its connect-time sweep and
    recovery: it makes its run engine only then."""
    await wait_until(lambda: daemon.engine is not None, "the connect-time sweep and recovery done", timeout_s)


class DaemonProcess:
    """``tests/faults/daemon_child.py``: the daemon in its own process, with one run started; SIGKILL it."""

    def __init__(self, cfg: Config, kind: str, *, confirm: bool = True) -> None:
        self.cfg = cfg
        self.kind = kind
        self.confirm = confirm
        self.proc: asyncio.subprocess.Process | None = None
        self.lines: list[dict[str, Any]] = []
        self._reader: asyncio.Task[None] | None = None

    async def start(self) -> None:
        args = [sys.executable, str(Path(__file__).with_name("daemon_child.py")),
                json.dumps(self.cfg.model_dump(mode="json")), self.kind]
        if not self.confirm:
            args.append("--no-confirm")
        self.proc = await asyncio.create_subprocess_exec(*args, stdout=asyncio.subprocess.PIPE)
        self._reader = asyncio.create_task(self._read(), name="daemon-child-reader")

    async def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        async for line in self.proc.stdout:
            try:
                self.lines.append(json.loads(line))
            except ValueError:
                self.lines.append({"raw": line.decode(errors="replace")})

    async def until(self, predicate: Callable[[dict[str, Any]], bool], what: str, timeout_s: float = WAIT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while not any(predicate(x) for x in self.lines):
            assert self.proc is not None
            if self.proc.returncode is not None:
                raise AssertionError(f"{what}: the daemon process exited ({self.proc.returncode}): {self.lines[-5:]}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout_s:g} s: {self.lines[-5:]}")
            await asyncio.sleep(0.02)

    async def kill(self) -> None:
        """SIGKILL: no finaliser, no cleanup — as a crash or the OOM killer."""
        assert self.proc is not None
        if self.proc.returncode is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        await asyncio.wait_for(self.proc.wait(), 10)
        if self._reader is not None:
            await asyncio.gather(self._reader, return_exceptions=True)
