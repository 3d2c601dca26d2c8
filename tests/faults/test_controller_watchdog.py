"""Issue 31 item 1: a motion does not outlive the daemon that watches it.

The simulated KR C4 runs in its own process (5x real time); the daemon runs in its own process and starts a
measurement, whose warm-up moves A3 and A5 for many cycles. An independent client, on its own TCP connection to the
simulated controller, reads ``$PRO_STATE1`` and ``$AXIS_ACT`` every 0.1 s (wall clock).

* The daemon is SIGKILLed mid-motion and not restarted: the controller-side watchdog (the interrupt every daemon
  program arms on ``$TIMER[16]``, fed by the daemon's heartbeat) brakes the motion on its path and halts the program.
* The daemon's link is cut (a proxy between daemon and controller stops passing bytes, no socket closed) while the
  daemon and the simulated robot keep running: the same.
* A trip while the daemon lives is an alarm (``watchdog_tripped``).

Each test prints the measured time from the fault to the last axis change (the Done-when bound of issue 31 is
2 s, with a watchdog bound of ``controller.watchdog_bound_s``).
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from rgse_daemon.commands.krl import template_defaults
from rgse_daemon.config import Config, ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.krl.render import default_params, render
from rgse_daemon.link.connection import Connection
from rgse_daemon.link.krlvalue import parse_value
from rgse_daemon.services.heartbeat import Heartbeat
from rgse_daemon.services.signals import Alarms, StackLight
from simulators.krc4.process import SimProcess
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import daemon_config, seed_calibration
from tests.support.faults import DaemonProcess
from tests.support.polling import wait_until
from tests.support.tcpproxy import CutProxy

#: The Done-when bound of issue 31 (wall clock, from the fault to the end of the motion).
DONE_WHEN_S = 2.0
#: How long the observer keeps watching after the fault (the issue's trial: 8 s).
OBSERVE_S = 8.0
PERIOD_S = 0.1


class Observer:
    """An independent client of the simulated controller: its own connection, reads only."""

    def __init__(self, port: int) -> None:
        self.conn = Connection("127.0.0.1", port, name="observer", request_timeout_s=2.0)

    async def read(self) -> tuple[str, str, tuple[float, ...]]:
        state = (await self.conn.read_var("$PRO_STATE1")).strip().upper()
        name = (await self.conn.read_var("$PRO_NAME1[]")).strip().strip('"').upper()
        axes = parse_value(await self.conn.read_var("$AXIS_ACT"))
        return state, name, tuple(float(axes[f"A{i}"]) for i in range(1, 7))  # type: ignore[index, arg-type]

    async def until_moving(self, timeout_s: float = 120.0) -> None:
        """Until one of our programs is active and its axes change between two reads."""
        deadline = time.monotonic() + timeout_s
        last: tuple[float, ...] | None = None
        while True:
            state, name, axes = await self.read()
            if state == "#P_ACTIVE" and name.startswith("RGSE_WARMUP") and last is not None and axes != last:
                return
            last = axes
            assert time.monotonic() < deadline, f"no warm-up motion within {timeout_s:g} s ({state} {name})"
            await asyncio.sleep(PERIOD_S)

    async def watch(self, t_fault: float) -> list[tuple[float, str, tuple[float, ...]]]:
        """(seconds since the fault, $PRO_STATE1, axes) every PERIOD_S for OBSERVE_S."""
        seen = []
        while (t := time.monotonic() - t_fault) < OBSERVE_S:
            state, _, axes = await self.read()
            seen.append((t, state, axes))
            await asyncio.sleep(PERIOD_S)
        return seen


def motion_end_s(seen: list[tuple[float, str, tuple[float, ...]]]) -> float:
    """The time of the first reading after which the axes never changed again and no program was active."""
    end = 0.0
    for (_, _, a0), (t1, state, a1) in itertools.pairwise(seen):
        if a1 != a0 or state == "#P_ACTIVE":
            end = t1
    return end


async def _fault_mid_warmup(sim: SimProcess, tmp_path: Path, calibration_doc: dict[str, Any], controller_port: int,
                            fault: Callable[[DaemonProcess], Awaitable[None]]) -> list[tuple[float, str, tuple]]:
    cfg = daemon_config(tmp_path / "data", controller_port=controller_port, share_dir=sim.share_dir,
                        warmup_cycles=40)  # a warm-up of minutes: it cannot end by itself while observed
    # the default bound (tests/support/daemon.py raises it to 1 s for the other tests)
    cfg = cfg.model_copy(update={"controller": cfg.controller.model_copy(
        update={"watchdog_bound_s": ControllerConfig().watchdog_bound_s}),
        # 40 cycles are bounded at about 30 min of motion: above the default limits.max_motion_s, as meant here
        "limits": cfg.limits.model_copy(update={"max_motion_s": 3600.0})})
    await seed_calibration(cfg, calibration_doc)
    observer = Observer(sim.port)
    child = DaemonProcess(cfg, "measurement")
    await child.start()
    try:
        await observer.until_moving()
        t_fault = time.monotonic()
        await fault(child)
        seen = await observer.watch(t_fault)
    finally:
        await child.kill()
        await observer.conn.close()
    return seen


def _judge(seen: list[tuple[float, str, tuple[float, ...]]], what: str) -> None:
    end_s = motion_end_s(seen)
    print(f"{what}: motion ended {end_s:.2f} s after the fault (bound {DONE_WHEN_S:g} s); "
          f"final state {seen[-1][1]}, axes {seen[-1][2]}")
    assert seen[-1][1] == "#P_STOP", seen[-1]  # halted by the watchdog's routine (not ended, not an error)
    assert end_s <= DONE_WHEN_S, f"{what}: the motion went on for {end_s:.2f} s after the fault: {seen}"


async def test_sigkill_of_the_daemon_mid_motion_ends_the_motion(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    async def sigkill(child: DaemonProcess) -> None:
        await child.kill()

    seen = await _fault_mid_warmup(sim_proc, tmp_path, calibration_doc, sim_proc.port, sigkill)
    _judge(seen, "SIGKILL")
    peek = await sim_proc.peek("RGSE_WD_TRIP", "RGSE_DONE")
    assert peek["RGSE_WD_TRIP"].strip() == "TRUE" and peek["RGSE_DONE"].strip() == "FALSE"


async def test_a_cut_link_ends_the_motion_while_the_daemon_runs_on(
        sim_proc: SimProcess, calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    async with CutProxy(sim_proc.port) as proxy:
        async def cut(child: DaemonProcess) -> None:
            proxy.cut()

        seen = await _fault_mid_warmup(sim_proc, tmp_path, calibration_doc, proxy.port, cut)
        assert proxy.is_cut
    _judge(seen, "link cut")
    assert (await sim_proc.peek("RGSE_WD_TRIP"))["RGSE_WD_TRIP"].strip() == "TRUE"


async def test_a_trip_while_the_daemon_lives_is_an_alarm(sim: SimulatedKrc4) -> None:
    """The daemon's heartbeat pauses longer than the bound (its link down): the watchdog halts the program; once the
    heartbeat beats again it reads RGSE_WD_TRIP and raises ``watchdog_tripped`` (a stop the daemon did not send is
    seen, with its cause)."""
    cfg = ControllerConfig(host="127.0.0.1", port=sim.port, protocol="c3bridge", pool_size=1)
    params = default_params("rgse_warmup", template_defaults(Config())).model_copy(update={"cycles": 40})
    src = render("rgse_warmup", params).src_text
    alarms: list[dict[str, object]] = []
    up = True
    heartbeat = Heartbeat(cfg, Alarms(alarms.append, StackLight(None)), link_up=lambda: up)
    stop = asyncio.Event()
    beats = asyncio.create_task(heartbeat.run(stop))
    try:
        async with Controller.connect(cfg) as krc:
            await krc.put_file("KRC:\\R1\\PROGRAM\\RGSE_WARMUP.SRC", src.replace("\n", "\r\n").encode("latin-1"))
            await krc.select_program("KRC:\\R1\\PROGRAM\\RGSE_WARMUP.SRC")
            await krc.start_program()
            await wait_until(lambda: sim.store.read("RGSE_STEP") == "3", "the warm-up cycles", 30.0)
            assert not [a for a in alarms if a["kind"] == "watchdog_tripped"]
            up = False  # no beats: the link is down as far as the heartbeat knows
            await wait_until(lambda: sim.store.read("$PRO_STATE1") == "#P_STOP", "the watchdog halts it", 10.0)
            assert sim.store.read("RGSE_WD_TRIP") == "TRUE"
            up = True
            await wait_until(lambda: any(a["kind"] == "watchdog_tripped" for a in alarms), "the alarm", 10.0)
    finally:
        stop.set()
        await asyncio.wait({beats}, timeout=10.0)
    assert sim.store.read("$TIMER_STOP[16]") == "TRUE"  # a clean stop of the heartbeat stops the timer
