"""The assembled simulated KR C4 on port 0 and the daemon's own Controller connected to it over TCP.

Helpers drive the controller the way the daemon does: files through the link's file operations, programs through
#10, trace control through variable writes, and polling with a deadline (the link has no change notification).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from simulators.krc4.sim import SimulatedKrc4

#: Simulated seconds per wall second: a 12 s trace takes 0.12 s.
TIME_SCALE = 100.0
#: Longest wall time any single wait in these tests may take.
DEADLINE_S = 20.0
TRACE_DIR = "C:\\KRC\\ROBOTER\\TRACE\\"
PROGRAM_DIR = "KRC:\\R1\\PROGRAM\\"
ALL_MODULES = ("KRCIpo", *(f"NextGenDrive#{i}" for i in range(1, 7)))


def trace_config_xml(
    time_s: float,
    *,
    rate_us: int = 12000,
    modules: tuple[str, ...] = ALL_MODULES,
    pretrigger_s: float = 0.0,
    trigger: tuple[str, int] | None = None,
    basename: str = "meas",
) -> str:
    """A trace configuration as it lies in the controller's TRACE folder, written by hand (not validated here)."""
    mods = "".join(
        f"<Module><Name>{m}</Name><Rate>{rate_us}</Rate><Channel>1</Channel><Channel>202</Channel></Module>"
        for m in modules
    )
    trig = f"<Trigger><ModuleName>{trigger[0]}</ModuleName><ID>{trigger[1]}</ID></Trigger>" if trigger else ""
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        f"<Trace><Time>{time_s:g}</Time><PreTrigger>{pretrigger_s:g}</PreTrigger><Basename>{basename}</Basename><Modules>{mods}</Modules>{trig}</Trace>\n"
    )


async def poll(krc: Controller, name: str, done: Callable[[str], bool], timeout_s: float = DEADLINE_S) -> str:
    """Read ``name`` over the link until ``done(value)``; the value. TimeoutError after ``timeout_s`` wall."""
    async with asyncio.timeout(timeout_s):
        while True:
            value = await krc.read_raw(name)
            if done(value):
                return value
            await asyncio.sleep(0.002)


async def put_config(krc: Controller, file_name: str, xml: str) -> None:
    await krc.put_file(TRACE_DIR + file_name, xml.encode("utf-8"))


async def put_program(krc: Controller, module: str, src: str, dat: str | None = None) -> str:
    """Put ``module``.SRC (and .DAT) into R1\\PROGRAM; the name to select."""
    await krc.put_file(f"{PROGRAM_DIR}{module}.SRC", src.encode("latin-1"))
    if dat is not None:
        await krc.put_file(f"{PROGRAM_DIR}{module}.DAT", dat.encode("latin-1"))
    return f"{PROGRAM_DIR}{module}.SRC"


async def run_to_end(krc: Controller, program: str) -> None:
    """Select and start ``program`` and wait for ``#P_END`` (a ``#P_STOP`` instead fails the test)."""
    await krc.select_program(program)
    await krc.start_program()
    state = await poll(krc, "$PRO_STATE1", lambda v: v in ("#P_END", "#P_STOP"))
    assert state == "#P_END", "program stopped before its end"


async def start_trace(krc: Controller, config: str, name: str) -> None:
    """``$TRACE.CONFIG[]``, ``$TRACE.NAME[]``, then ``$TRACE.MODE = #T_START`` (what the daemon writes)."""
    await krc.write("$TRACE.CONFIG[]", config)
    await krc.write("$TRACE.NAME[]", name)
    await krc.write_raw("$TRACE.MODE", "#T_START")


async def states_until_end(krc: Controller) -> list[str]:
    """Poll ``$TRACE.STATE`` until it is back at ``#T_END``; every distinct state seen, in order."""
    seen: list[str] = []
    async with asyncio.timeout(DEADLINE_S):
        while True:
            state = await krc.read_raw("$TRACE.STATE")
            if not seen or seen[-1] != state:
                seen.append(state)
            if state == "#T_END":
                return seen
            await asyncio.sleep(0.001)


def base_name(full_name: str) -> str:
    """``C:\\KRC\\ROBOTER\\TRACE\\x.dat`` → ``x.dat``."""
    return full_name.rsplit("\\", 1)[-1]


async def pull_trace(krc: Controller, name: str) -> dict[str, bytes]:
    """List the TRACE folder over the link and fetch every file of trace ``name``: file name → content."""
    return {
        base_name(entry.name): await krc.get_file(entry.name)
        for entry in await krc.list_dir(TRACE_DIR)
        if not entry.is_dir and base_name(entry.name).startswith(f"{name}_")
    }


def save(files: dict[str, bytes], dest: Path) -> Path:
    """Write pulled files into ``dest`` (the daemon's archive stands in here); ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    for file_name, content in files.items():
        (dest / file_name).write_bytes(content)
    return dest


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    async with SimulatedKrc4(tmp_path / "roboter", seed=7, time_scale=TIME_SCALE, latency_s=0.0) as s:
        yield s


@pytest.fixture
async def krc(sim: SimulatedKrc4) -> AsyncIterator[Controller]:
    cfg = ControllerConfig(host="127.0.0.1", port=sim.port, request_timeout_s=2.0, pool_size=2)
    async with Controller.connect(cfg) as controller:
        yield controller
