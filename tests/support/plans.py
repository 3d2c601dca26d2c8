"""Plans for the tests: a long warm-up motion with a long trace recording (what a trip has to stop)."""

from __future__ import annotations

from dataclasses import replace

from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, render_program, run_checked, trace_config_xml
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from simulators.krc4.sim import SimulatedKrc4

LONG_TRACE = "long_trace"


def long_motion(s: RunSettings) -> m.Plan:
    """Start a long trace, then a warm-up of many cycles (minutes of simulated time)."""
    snap = yield m.ReadState()
    yield m.PutFile(TRACE_DIR + TRACE_CONFIG_NAME, trace_config_xml(replace(s, trace_samples=40_000)).encode())
    yield m.TraceStart(LONG_TRACE, TRACE_CONFIG_NAME)
    prog = yield from render_program("rgse_warmup", replace(s, warmup_cycles=60), snap)
    yield from run_checked(prog, s)




def moving(sim: SimulatedKrc4) -> bool:
    """The program runs and the robot moves (the warm-up cycles have begun)."""
    return (sim.store.read("$PRO_STATE1") == "#P_ACTIVE" and sim.store.read("$ROB_STOPPED") == "FALSE"
            and sim.store.read("$TRACE.STATE") == "#TRIGGERED")


def robot_still(sim: SimulatedKrc4) -> bool:
    return sim.store.read("$PRO_STATE1") != "#P_ACTIVE" and sim.store.read("$ROB_STOPPED") == "TRUE"


def trace_stopped(sim: SimulatedKrc4) -> bool:
    return sim.store.read("$TRACE.STATE") == "#T_END"


def short(cfg, **kw) -> RunSettings:
    base = {"loops": 1, "trace_samples": 400, "warmup_cycles": 1, "payload_lever_max_m": 1.0}
    return RunSettings.from_config(cfg, **{**base, **kw})
