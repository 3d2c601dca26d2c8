"""The simulated KR C4 running KRL: program states, motion, control flow, handshakes, T1 rules (scaled time)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import numpy as np
import pytest

from simulators.krc4.krl import KrlInterpreter, MotionEvent, parse_axes
from simulators.krc4.variables import ProgramControlError, ProState, VariableStore, module_name
from tests.support.polling import wait_until

TIME_SCALE = 200.0
HOME = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)


class Programs:
    """An in-memory program folder: name → (.src, .dat)."""

    def __init__(self) -> None:
        self.files: dict[str, tuple[str, str | None]] = {}

    def add(self, name: str, src: str, dat: str | None = None) -> None:
        self.files[name.upper()] = (src, dat)

    def __call__(self, name: str) -> tuple[str, str, str | None]:
        mod = module_name(name)
        if mod not in self.files:
            raise ProgramControlError(f"{name} not found", 3)
        src, dat = self.files[mod]
        return mod, src, dat


@pytest.fixture
def store() -> VariableStore:
    return VariableStore()


@pytest.fixture
def programs() -> Programs:
    return Programs()


@pytest.fixture
async def interp(store: VariableStore, programs: Programs) -> AsyncIterator[KrlInterpreter]:
    interpreter = KrlInterpreter(store, programs, time_scale=TIME_SCALE)
    yield interpreter
    await interpreter.aclose()


def axes(store: VariableStore) -> np.ndarray:
    return np.array(parse_axes(store.read("$AXIS_ACT")))




async def run_to_end(interp: KrlInterpreter, name: str) -> None:
    interp.run(name, "", False)
    state = await interp.wait_state(ProState.END, ProState.STOP, timeout_s=20.0)
    assert state is ProState.END, interp.last_error


WARMUP_SRC = """DEF warm()
  DECL INT i
  BAS(#INITMOV, 0)
  FOR i = 1 TO 6
    $VEL_AXIS[i] = 20
    $ACC_AXIS[i] = 50
  ENDFOR
  FOR i = 1 TO loops
    PTP {A3 100, A5 -20} C_PTP
    PTP_REL {A3 -20, A5 40}
    loop_no = i
  ENDFOR
  PTP xhome
  done = TRUE
END
"""
WARMUP_DAT = """DEFDAT warm PUBLIC
  DECL GLOBAL INT loops = 2
  DECL GLOBAL INT loop_no = 0
  DECL GLOBAL BOOL done = FALSE
  DECL E6AXIS xhome = {A1 5.0, A2 -90.0, A3 90.0, A4 0.0, A5 10.0, A6 0.0}
ENDDAT
"""


async def test_program_runs_through_its_states_and_moves(interp: KrlInterpreter, store, programs) -> None:
    programs.add("WARM", WARMUP_SRC, WARMUP_DAT)
    events: list[MotionEvent] = []
    interp.add_motion_listener(events.append)
    assert store.read("$PRO_STATE1") == "#P_FREE"
    interp.select("KRC:\\R1\\PROGRAM\\WARM.SRC", "", False)
    assert store.read("$PRO_STATE1") == "#P_RESET" and store.read("$PRO_NAME1[]") == '"WARM"'
    assert store.read("LOOPS") == "2" and store.read("DONE") == "FALSE"  # GLOBALs of the .dat are in the store
    store.write("LOOPS", "3")  # the daemon may set a parameter before starting
    interp.start(1)
    assert store.read("$PRO_STATE1") == "#P_ACTIVE"
    assert await interp.wait_state(ProState.END, ProState.STOP, timeout_s=20.0) is ProState.END, interp.last_error
    assert store.read("LOOP_NO") == "3" and store.read("DONE") == "TRUE"
    np.testing.assert_allclose(axes(store), (5.0, -90.0, 90.0, 0.0, 10.0, 0.0), atol=1e-6)
    ends = [e for e in events if e.kind == "end"]
    assert len(ends) == 7 and not any(e.stopped for e in ends)
    assert ends[0].directions == (0, 0, 1, 0, -1, 0)  # A3 came up from 90, A5 down from 0
    assert ends[1].q_deg[2] == pytest.approx(80.0) and ends[1].q_deg[4] == pytest.approx(20.0)
    assert store.read("$ROB_STOPPED") == "TRUE" and "X 1" in store.read("$POS_ACT")
    with pytest.raises(ProgramControlError, match="reset"):
        interp.start(1)
    interp.reset(1)
    assert store.read("$PRO_STATE1") == "#P_RESET"
    interp.cancel(1)
    assert store.read("$PRO_STATE1") == "#P_FREE" and store.read("$PRO_NAME1[]") == '""'


FLOW_SRC = """DEF flow()
  DECL INT i, n, arr[5]
  DECL REAL x
  n = 0
  FOR i = 10 TO 1 STEP -3
    n = n + i
  ENDFOR
  r_for = n
  r_after = i
  n = 0
  LOOP
    n = n + 1
    IF n >= 4 THEN
      EXIT
    ENDIF
  ENDLOOP
  r_loop = n
  WHILE n > 0
    n = n - 1
    arr[n + 1] = n * n
  ENDWHILE
  r_arr = arr[4]
  REPEAT
    n = n + 5
  UNTIL n > 12
  r_repeat = n
  x = 7 / 2
  r_int_div = x
  r_real = 7.0 / 2 + ABS(-1)
  IF (r_real > 4) AND NOT (r_for == 0) THEN
    r_if = 1
  ELSE
    r_if = 2
  ENDIF
  r_fct = twice(21)
  bump(n)
  r_out = n
  r_str[] = "done"
END

DEFFCT INT twice(v:IN)
  DECL INT v
  RETURN v * 2
ENDFCT

DEF bump(p:OUT)
  DECL INT p
  p = p + 100
END
"""
FLOW_DAT = """DEFDAT flow
  DECL GLOBAL INT r_for = 0
  DECL GLOBAL INT r_after = 0
  DECL GLOBAL INT r_loop = 0
  DECL GLOBAL INT r_arr = 0
  DECL GLOBAL INT r_repeat = 0
  DECL GLOBAL REAL r_int_div = 0.0
  DECL GLOBAL REAL r_real = 0.0
  DECL GLOBAL INT r_if = 0
  DECL GLOBAL INT r_fct = 0
  DECL GLOBAL INT r_out = 0
  DECL GLOBAL CHAR r_str[16]
ENDDAT
"""


async def test_control_flow_semantics(interp: KrlInterpreter, store, programs) -> None:
    programs.add("FLOW", FLOW_SRC, FLOW_DAT)
    await run_to_end(interp, "FLOW")
    got = {n: store.read(n) for n in ("R_FOR", "R_AFTER", "R_LOOP", "R_ARR", "R_REPEAT", "R_IF", "R_FCT", "R_OUT")}
    assert got == {
        "R_FOR": "22",  # 10 + 7 + 4 + 1
        "R_AFTER": "-2",  # the counter ends one step past the bound
        "R_LOOP": "4",
        "R_ARR": "9",  # arr[4] = 3 * 3
        "R_REPEAT": "15",  # 0 → 5 → 10 → 15
        "R_IF": "1",
        "R_FCT": "42",
        "R_OUT": "115",  # OUT parameter written back
    }
    assert float(store.read("R_INT_DIV")) == 3.0  # INT / INT cuts the decimals off
    assert float(store.read("R_REAL")) == 4.5
    assert store.read("R_STR[]") == '"done"'


HANDSHAKE_SRC = """DEF hs()
  $TRACE.NAME[] = "dut_l01"
  ready = TRUE
  WAIT FOR go
  $TRACE.MODE = #T_START
  WAIT SEC 2.0
  $TRACE.MODE = #T_STOP
  WAIT FOR $TRACE.STATE == #T_END
  ready = FALSE
END
"""
HANDSHAKE_DAT = """DEFDAT hs
  DECL GLOBAL BOOL ready = FALSE
  DECL GLOBAL BOOL go = FALSE
ENDDAT
"""


async def test_wait_for_handshake_and_trace_setters(interp: KrlInterpreter, store, programs) -> None:
    programs.add("HS", HANDSHAKE_SRC, HANDSHAKE_DAT)
    seen: list[tuple[str, str]] = []
    store.register_setter("$TRACE.MODE", lambda v: seen.append(("mode", v)))
    store.register_setter("$TRACE.NAME[]", lambda v: seen.append(("name", v)))
    interp.run("HS", "", False)
    await wait_until(lambda: store.read("READY") == "TRUE")
    await asyncio.sleep(0.02)  # 4 simulated seconds: the program must still be waiting
    assert store.read("$PRO_STATE1") == "#P_ACTIVE" and seen == [("name", '"dut_l01"')]
    store.write("GO", "TRUE")  # the daemon's write over the link
    await wait_until(lambda: len(seen) >= 3)
    assert seen[1:] == [("mode", "#T_START"), ("mode", "#T_STOP")]
    assert await interp.wait_state(ProState.END, ProState.STOP) is ProState.END, interp.last_error
    assert store.read("READY") == "FALSE"


LONG_MOVE_SRC = """DEF longmv()
  BAS(#INITMOV, 0)
  BAS(#VEL_PTP, 100)
  PTP {A1 40, A2 -60, A3 60, A5 30}
  reached = TRUE
END
"""
LONG_MOVE_DAT = """DEFDAT longmv
  DECL GLOBAL BOOL reached = FALSE
ENDDAT
"""


async def test_t1_clamps_the_flange_speed(interp: KrlInterpreter, store, programs) -> None:
    programs.add("LONGMV", LONG_MOVE_SRC, LONG_MOVE_DAT)
    speeds: list[float] = []
    interp.run("LONGMV", "", False)
    async with asyncio.timeout(20.0):
        while store.read("$PRO_STATE1") == "#P_ACTIVE":
            speeds.append(float(store.read("$VEL_ACT")))
            await asyncio.sleep(0.001)
    assert interp.state is ProState.END, interp.last_error
    assert 0.2 < max(speeds) <= 0.250001  # m/s: slowed to the T1 limit, not refused
    np.testing.assert_allclose(axes(store), (40.0, -60.0, 60.0, 0.0, 30.0, 0.0), atol=1e-6)


async def test_enabling_switch_release_is_stop2(interp: KrlInterpreter, store, programs) -> None:
    programs.add("LONGMV", LONG_MOVE_SRC, LONG_MOVE_DAT)
    events: list[MotionEvent] = []
    interp.add_motion_listener(events.append)
    interp.run("LONGMV", "", False)
    await wait_until(lambda: abs(axes(store)[0]) >= 5.0)
    interp.set_enabling_switch(False)
    assert store.read("$STOPMESS") == "TRUE" and store.read("$PERI_RDY") == "FALSE"
    assert await interp.wait_state(ProState.STOP, ProState.END) is ProState.STOP
    q_stop = axes(store)
    assert 5.0 < q_stop[0] < 40.0 and store.read("REACHED") == "FALSE"
    moving = [0, 1, 2, 4]
    delta = np.array([40.0, -60.0, 60.0, 0.0, 30.0, 0.0]) - np.array(HOME)
    frac = (q_stop - np.array(HOME))[moving] / delta[moving]
    np.testing.assert_allclose(frac, frac[0], atol=1e-6)  # it stopped on the path
    np.testing.assert_allclose(q_stop[[3, 5]], 0.0)
    assert events[-1].kind == "end" and events[-1].stopped
    with pytest.raises(ProgramControlError, match="enabling switch"):
        interp.start(1)
    interp.set_enabling_switch(True)
    with pytest.raises(ProgramControlError, match="acknowledge"):
        interp.start(1)
    interp.acknowledge()
    interp.start(1)
    assert await interp.wait_state(ProState.END, timeout_s=20.0) is ProState.END
    assert store.read("REACHED") == "TRUE"
    np.testing.assert_allclose(axes(store), (40.0, -60.0, 60.0, 0.0, 30.0, 0.0), atol=1e-6)
    assert events[-1].kind == "end" and not events[-1].stopped


async def test_start_key_not_pressed_means_no_start_in_t1(interp: KrlInterpreter, store, programs) -> None:
    programs.add("LONGMV", LONG_MOVE_SRC, LONG_MOVE_DAT)
    interp.set_start_key(False)
    interp.select("LONGMV", "", False)
    with pytest.raises(ProgramControlError, match="start key"):
        interp.start(1)
    assert store.read("$PRO_STATE1") == "#P_RESET"
    np.testing.assert_allclose(axes(store), HOME)
    store.update("$MODE_OP", "#AUT")  # automatic mode needs no operator at the robot
    interp.start(1)
    assert await interp.wait_state(ProState.END, timeout_s=20.0) is ProState.END


async def test_stop_halt_and_resume(interp: KrlInterpreter, store, programs) -> None:
    programs.add(
        "PAUSE",
        "DEF pause()\n  WAIT SEC 50\n  stage = 1\n  HALT\n  stage = 2\nEND\n",
        "DEFDAT pause\n  DECL GLOBAL INT stage = 0\nENDDAT\n",
    )
    interp.run("PAUSE", "", False)
    interp.stop(1)
    assert await interp.wait_state(ProState.STOP) is ProState.STOP
    interp.start(1)
    assert await interp.wait_state(ProState.STOP, timeout_s=10.0) is ProState.STOP  # the HALT
    assert store.read("STAGE") == "1" and interp.last_error is None
    interp.start(1)
    assert await interp.wait_state(ProState.END) is ProState.END
    assert store.read("STAGE") == "2"


async def test_runtime_error_stops_the_program(interp: KrlInterpreter, store, programs) -> None:
    programs.add("BAD", "DEF bad()\n  x = nowhere + 1\nEND\n")
    programs.add("CART", "DEF cart()\n  LIN {X 1000, Y 0, Z 1500}\nEND\n")
    programs.add("SYNTAX", "DEF syntax()\n  IF THEN\nEND\n")
    interp.run("BAD", "", False)
    assert await interp.wait_state(ProState.STOP, ProState.END) is ProState.STOP
    assert "unknown variable" in (interp.last_error or "") and "BAD.SRC:2:" in (interp.last_error or "")
    with pytest.raises(ProgramControlError, match="reset"):
        interp.start(1)
    interp.reset(1)
    interp.cancel(1)
    interp.run("CART", "", False)
    assert await interp.wait_state(ProState.STOP, ProState.END) is ProState.STOP
    assert "inverse kinematics" in (interp.last_error or "")
    interp.reset(1)
    with pytest.raises(ProgramControlError, match="does not compile"):
        interp.select("SYNTAX", "", False)
    with pytest.raises(ProgramControlError, match="not found"):
        interp.select("MISSING", "", False)


async def test_programs_load_from_the_share(tmp_path, store) -> None:
    from simulators.krc4.files import ShareFiles
    from simulators.krc4.krl import share_loader

    folder = tmp_path / "R1" / "PROGRAM"
    folder.mkdir(parents=True)
    (folder / "SHARED.SRC").write_bytes(b"DEF shared()\n  flag = TRUE ; \xe4 latin-1 comment\nEND\n")
    (folder / "SHARED.DAT").write_bytes(b"DEFDAT shared\n  DECL GLOBAL BOOL flag = FALSE\nENDDAT\n")
    interp = KrlInterpreter(store, share_loader(ShareFiles(tmp_path)), time_scale=TIME_SCALE)
    try:
        await run_to_end(interp, "KRC:\\R1\\PROGRAM\\SHARED.SRC")
        assert store.read("FLAG") == "TRUE"
        with pytest.raises(ProgramControlError, match="not found"):
            interp.select("/R1/NOPE", "", False)
    finally:
        await interp.aclose()


PERSIST_SRC = """DEF persist()
  runs = runs + 1
  r_runs = runs
END
"""
PERSIST_DAT = """DEFDAT persist
  DECL INT runs = 0
  DECL GLOBAL INT r_runs = 0
ENDDAT
"""


async def test_data_list_values_persist_across_reset_and_select(interp: KrlInterpreter, store, programs) -> None:
    """As on the KR C4, a run leaves its data-list values behind: the next run starts from them (the interlock must
    not take the pushed initial value of a data-list variable the program writes)."""
    programs.add("PERSIST", PERSIST_SRC, PERSIST_DAT)
    await run_to_end(interp, "PERSIST")
    assert store.read("R_RUNS") == "1"
    interp.reset(1)
    interp.start(1)
    assert await interp.wait_state(ProState.END, ProState.STOP) is ProState.END, interp.last_error
    assert store.read("R_RUNS") == "2"
    interp.cancel(1)
    await run_to_end(interp, "PERSIST")  # selected again, same .dat
    assert store.read("R_RUNS") == "3"
    interp.cancel(1)
    programs.add("PERSIST", PERSIST_SRC, PERSIST_DAT.replace("runs = 0", "runs = 10", 1))  # a new .dat pushed
    await run_to_end(interp, "PERSIST")
    assert store.read("R_RUNS") == "11"
