"""The simulated KR C4's interrupts, system timers and BRAKE: what the daemon's controller-side watchdog rests on
(docs/security.md). Runs in scaled time; the timers count wall-clock ms (simulators/krc4/variables.py)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import numpy as np
import pytest

from simulators.krc4.krl import KrlInterpreter, MotionEvent, parse_axes
from simulators.krc4.variables import ProState, VariableStore
from tests.krl.test_interpreter import Programs
from tests.support.polling import wait_until

TIME_SCALE = 2.0  # slow enough that a motion outlives a 0.3 s wall-clock timer


def axes(store: VariableStore) -> np.ndarray:
    return np.array(parse_axes(store.read("$AXIS_ACT")))


@pytest.fixture
def store() -> VariableStore:
    return VariableStore()


@pytest.fixture
async def interp(store: VariableStore) -> AsyncIterator[tuple[KrlInterpreter, Programs]]:
    programs = Programs()
    interpreter = KrlInterpreter(store, programs, time_scale=TIME_SCALE)
    yield interpreter, programs
    await interpreter.aclose()


WATCHED = """DEF watched( )
  $VEL_AXIS[1] = 5
  $VEL_AXIS[2] = 5
  $VEL_AXIS[3] = 5
  $VEL_AXIS[4] = 5
  $VEL_AXIS[5] = 5
  $VEL_AXIS[6] = 5
  INTERRUPT DECL 3 WHEN $TIMER_FLAG[16] OR $TIMER_STOP[16] DO WD_STOP( )
  INTERRUPT ON 3
  WAIT FOR NOT ($TIMER_FLAG[16] OR $TIMER_STOP[16])
  PTP {A1 40}
  DONE = TRUE
END

DEF WD_STOP( )
  BRAKE
  TRIPPED = TRUE
  WHILE $TIMER_FLAG[16] OR $TIMER_STOP[16]
    HALT
  ENDWHILE
END
"""
DAT = """DEFDAT watched PUBLIC
  DECL GLOBAL BOOL DONE = FALSE
  DECL GLOBAL BOOL TRIPPED = FALSE
ENDDAT
"""


def test_timer_counts_up_and_flags_at_zero(store: VariableStore) -> None:
    assert store.read("$TIMER_STOP[16]") == "TRUE" and store.read("$TIMER[16]") == "0"
    assert store.read("$TIMER_FLAG[16]") == "TRUE"  # stopped at 0: >= 0
    store.write("$TIMER[16]", "-200")
    assert store.read("$TIMER_FLAG[16]") == "FALSE"
    time.sleep(0.05)
    assert store.read("$TIMER[16]") == "-200"  # stopped: does not count
    store.write("$TIMER_STOP[16]", "FALSE")
    time.sleep(0.3)
    assert int(store.read("$TIMER[16]")) >= 0 and store.read("$TIMER_FLAG[16]") == "TRUE"
    store.write("$TIMER_STOP[16]", "TRUE")
    frozen = store.read("$TIMER[16]")
    time.sleep(0.05)
    assert store.read("$TIMER[16]") == frozen


async def test_program_waits_for_a_running_timer_before_it_moves(interp, store: VariableStore) -> None:
    ip, programs = interp
    programs.add("watched", WATCHED, DAT)
    ip.run("watched", "", False)
    await asyncio.sleep(0.3)
    assert ip.state is ProState.ACTIVE and axes(store)[0] == 0.0  # no heartbeat yet: waits, nothing moves
    store.write("$TIMER[16]", "-100000")
    store.write("$TIMER_STOP[16]", "FALSE")
    await wait_until(lambda: axes(store)[0] > 0.0, "the motion starts once the timer runs", 10.0)


async def test_a_lapsed_timer_brakes_the_motion_on_its_path_and_halts(interp, store: VariableStore) -> None:
    ip, programs = interp
    programs.add("watched", WATCHED, DAT)
    events: list[MotionEvent] = []
    ip.add_motion_listener(events.append)
    store.write("$TIMER[16]", "-400")
    store.write("$TIMER_STOP[16]", "FALSE")
    ip.run("watched", "", False)
    await ip.wait_state(ProState.STOP, ProState.END, timeout_s=10.0)
    assert ip.state is ProState.STOP and ip.last_error is None  # HALT, not an error
    assert store.read("TRIPPED") == "TRUE" and store.read("DONE") == "FALSE"
    a1 = axes(store)[0]
    assert 0.0 < a1 < 40.0  # stopped part-way
    assert [e.kind for e in events] == ["start", "brake", "end"] and events[-1].stopped
    assert store.read("$ROB_STOPPED") == "TRUE"
    await asyncio.sleep(0.2)
    assert axes(store)[0] == a1
    # started again with the timer still lapsed: HALT again, nothing moves
    ip.start(1)
    await ip.wait_state(ProState.STOP, timeout_s=10.0)
    await asyncio.sleep(0.1)
    assert ip.state is ProState.STOP and axes(store)[0] == a1
    # a fresh heartbeat: the operator's start resumes the motion to its target
    store.write("$TIMER[16]", "-100000")
    ip.start(1)
    await ip.wait_state(ProState.END, timeout_s=60.0)
    assert axes(store)[0] == pytest.approx(40.0) and store.read("DONE") == "TRUE"


async def test_stopping_the_timer_trips_too(interp, store: VariableStore) -> None:
    ip, programs = interp
    programs.add("watched", WATCHED, DAT)
    store.write("$TIMER[16]", "-100000")
    store.write("$TIMER_STOP[16]", "FALSE")
    ip.run("watched", "", False)
    await wait_until(lambda: axes(store)[0] > 1.0, "moving", 10.0)
    store.write("$TIMER_STOP[16]", "TRUE")
    await ip.wait_state(ProState.STOP, timeout_s=10.0)
    assert store.read("TRIPPED") == "TRUE" and axes(store)[0] < 40.0


async def test_interrupt_is_edge_triggered_and_off_until_switched_on(interp, store: VariableStore) -> None:
    ip, programs = interp
    programs.add("edge", """DEF edge( )
  INTERRUPT DECL 5 WHEN FLAG DO COUNT_IT( )
  FLAG = TRUE
  WAIT SEC 0.05
  FLAG = FALSE
  INTERRUPT ON 5
  FLAG = TRUE
  WAIT SEC 0.05
  FLAG = TRUE
  WAIT SEC 0.05
  FLAG = FALSE
  WAIT SEC 0.05
  FLAG = TRUE
  WAIT SEC 0.05
  INTERRUPT OFF 5
  FLAG = FALSE
  WAIT SEC 0.05
  FLAG = TRUE
  WAIT SEC 0.05
END

DEF COUNT_IT( )
  N = N + 1
END
""", """DEFDAT edge PUBLIC
  DECL GLOBAL BOOL FLAG = FALSE
  DECL GLOBAL INT N = 0
ENDDAT
""")
    ip.run("edge", "", False)
    assert await ip.wait_state(ProState.END, ProState.STOP, timeout_s=10.0) is ProState.END, ip.last_error
    assert store.read("N") == "2"  # two rising edges while on; none while off, none for TRUE staying TRUE


async def test_brake_outside_an_interrupt_routine_is_a_runtime_error(interp, store: VariableStore) -> None:
    ip, programs = interp
    programs.add("bad", "DEF bad( )\n  BRAKE\nEND\n")
    ip.run("bad", "", False)
    await ip.wait_state(ProState.STOP, ProState.END, timeout_s=10.0)
    assert ip.state is ProState.STOP and "interrupt routine" in (ip.last_error or "")
