"""KUKA Trace on the simulated KR C4, over the link: state sequence, triggers, early stop, refusals, atomic files."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from rgse_daemon.controller import Controller
from rgse_daemon.errors import VariableError
from rgse_daemon.trace.config import buffer_limit_s
from rgse_daemon.trace.diadem import read_trace_set
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.trace import TRIGGER_MOTION_START, TRIGGER_PROGRAM_START, TraceState

from .conftest import (
    DEADLINE_S,
    TRACE_DIR,
    base_name,
    poll,
    pull_trace,
    put_config,
    put_program,
    run_to_end,
    save,
    start_trace,
    states_until_end,
    trace_config_xml,
)

SHORT_SRC = """DEF short( )
  WAIT SEC 1.0
END
"""
MOVE_SRC = """DEF mover( )
  BAS(#INITMOV, 0)
  PTP_REL {A1 5.0}
END
"""
ORDER = [TraceState.WAIT.value, TraceState.TRIGGERED.value, TraceState.WRITING.value, TraceState.END.value]


def history(sim: SimulatedKrc4, name: str) -> list[str]:
    return [state.value for trace, state in sim.trace.transitions if trace == name]


async def test_state_sequence_with_program_start_trigger(sim: SimulatedKrc4, krc: Controller) -> None:
    sim.trace.write_rate_bytes_s = 10e3  # a slow disk: #T_WRITING lasts long enough to be seen over the link
    await put_config(krc, "on_start.xml", trace_config_xml(20.0, trigger=TRIGGER_PROGRAM_START))
    program = await put_program(krc, "SHORT", SHORT_SRC)
    await krc.select_program(program)
    await start_trace(krc, "on_start.xml", "seq")
    assert await krc.read_raw("$TRACE.STATE") == "#T_WAIT"
    for _ in range(20):  # armed and waiting: nothing triggers it but a program start
        assert await krc.read_raw("$TRACE.STATE") == "#T_WAIT"
        await asyncio.sleep(0.005)
    await krc.start_program()
    seen = await states_until_end(krc)
    assert ["#T_WAIT", *seen[seen[0] == "#T_WAIT" :]] == ORDER
    assert history(sim, "seq") == ORDER


async def test_motion_start_trigger_and_krl_started_trace(sim: SimulatedKrc4, krc: Controller) -> None:
    await put_config(krc, "on_move.xml", trace_config_xml(2.0, trigger=TRIGGER_MOTION_START))
    await start_trace(krc, "on_move.xml", "moved")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_WAIT")
    await run_to_end(krc, await put_program(krc, "MOVER", MOVE_SRC))
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    assert history(sim, "moved") == ORDER

    # a KRL program starts a trace itself and waits for its end, as the daemon's measurement program does
    await put_config(krc, "plain.xml", trace_config_xml(3.0))
    krl_traced = """DEF krltrace( )
  $TRACE.CONFIG[] = "plain.xml"
  $TRACE.NAME[] = "from_krl"
  $TRACE.MODE = #T_START
  WAIT FOR $TRACE.STATE == #T_END
END
"""
    await run_to_end(krc, await put_program(krc, "KRLTRACE", krl_traced))
    assert history(sim, "from_krl") == ORDER
    files = await pull_trace(krc, "from_krl")
    assert files["from_krl_PROG.TXT"].decode("latin-1").replace("\r\n", "\n") == krl_traced


async def test_stop_ends_early_with_a_shorter_file(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    full_s, period_s = 2.0, 0.012
    await put_config(krc, "short.xml", trace_config_xml(full_s))
    await start_trace(krc, "short.xml", "full")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    long_s = buffer_limit_s(period_s)  # 600 s at 12 ms: the longest the buffer holds, accepted
    await put_config(krc, "long.xml", trace_config_xml(long_s))
    await start_trace(krc, "long.xml", "stopped")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#TRIGGERED")
    await krc.write_raw("$TRACE.MODE", "#T_STOP")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    assert history(sim, "stopped") == ORDER

    for name in ("full", "stopped"):
        save(await pull_trace(krc, name), tmp_path / name)
    full = read_trace_set(tmp_path / "full", "full").channel("NextGenDrive#3", "Istmoment").values
    stopped_set = read_trace_set(tmp_path / "stopped", "stopped")
    stopped = stopped_set.channel("NextGenDrive#3", "Istmoment").values
    assert full.size == round(full_s / period_s)
    assert 1 <= stopped.size < round(long_s / period_s)
    assert stopped_set.files["NextGenDrive#3"].period_s == period_s


async def test_stop_while_waiting_writes_nothing(sim: SimulatedKrc4, krc: Controller) -> None:
    await put_config(krc, "on_start.xml", trace_config_xml(5.0, trigger=TRIGGER_PROGRAM_START))
    await start_trace(krc, "on_start.xml", "never")
    await krc.write_raw("$TRACE.MODE", "#T_STOP")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    assert history(sim, "never") == ["#T_WAIT", "#T_END"]
    assert await pull_trace(krc, "never") == {}


@pytest.mark.parametrize(
    ("rate_us", "time_s"),
    [(12000, buffer_limit_s(0.012) + 1.0), (4000, buffer_limit_s(0.004) + 0.5), (1000, buffer_limit_s(0.001) + 1.0)],
)
async def test_time_beyond_the_buffer_is_refused(
    sim: SimulatedKrc4, krc: Controller, rate_us: int, time_s: float
) -> None:
    await put_config(krc, "too_long.xml", trace_config_xml(time_s, rate_us=rate_us))
    await krc.write("$TRACE.CONFIG[]", "too_long.xml")
    await krc.write("$TRACE.NAME[]", "too_long")
    with pytest.raises(VariableError):
        await krc.write_raw("$TRACE.MODE", "#T_START")
    assert await krc.read_raw("$TRACE.STATE") == "#T_END"
    assert sim.trace.last_error is not None and "buffer" in sim.trace.last_error
    assert history(sim, "too_long") == []


@pytest.mark.parametrize(
    ("file_name", "xml", "why"),
    [
        ("absent.xml", None, "not found"),
        ("broken.xml", "<Trace><Time>5</Time>", "not well-formed"),
        ("rate.xml", trace_config_xml(5.0, rate_us=2000), "not offered"),
        ("module.xml", trace_config_xml(5.0, modules=("NextGenDrive#7",)), "not on this controller"),
        ("trigger.xml", trace_config_xml(5.0, trigger=("KRCIpo", 99)), "not simulated"),
    ],
)
async def test_missing_or_bad_config_is_refused(
    sim: SimulatedKrc4, krc: Controller, file_name: str, xml: str | None, why: str
) -> None:
    if xml is not None:
        await put_config(krc, file_name, xml)
    with pytest.raises(VariableError) as err:
        await start_trace(krc, file_name, "refused")
    assert "$TRACE.MODE" in str(err.value)
    assert sim.trace.last_error is not None and why in sim.trace.last_error
    assert await krc.read_raw("$TRACE.STATE") == "#T_END"
    assert await pull_trace(krc, "refused") == {}


async def test_start_while_active_is_refused(sim: SimulatedKrc4, krc: Controller) -> None:
    await put_config(krc, "long.xml", trace_config_xml(300.0))
    await start_trace(krc, "long.xml", "first")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#TRIGGERED")
    with pytest.raises(VariableError):
        await krc.write_raw("$TRACE.MODE", "#T_START")
    assert sim.trace.last_error is not None and "a trace is active" in sim.trace.last_error
    assert history(sim, "first") == ["#T_WAIT", "#TRIGGERED"]
    await krc.write_raw("$TRACE.MODE", "#T_STOP")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")


async def test_files_appear_atomically_while_writing(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    """Every file visible by its final name during #T_WRITING is already complete; a .dat never before its .r64."""
    sim.trace.write_rate_bytes_s = 5e3  # a slow disk: the set appears module by module over many polls
    await put_config(krc, "meas.xml", trace_config_xml(12.0))
    await start_trace(krc, "meas.xml", "atomic")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_WRITING")
    snapshots: list[dict[str, bytes]] = []
    async with asyncio.timeout(DEADLINE_S):
        while await krc.read_raw("$TRACE.STATE") == "#T_WRITING":
            listed = [base_name(e.name) for e in await krc.list_dir(TRACE_DIR)]
            assert not [n for n in listed if n.startswith(".")], f"temporary names visible: {listed}"
            snapshots.append({n: await krc.get_file(TRACE_DIR + n) for n in listed if n.startswith("atomic_")})
    final = await pull_trace(krc, "atomic")
    assert len(final) == 7 * 3  # no program selected: no N_PROG.TXT
    partial = [s for s in snapshots if 0 < len(s) < len(final)]
    assert partial, "no listing caught the set half-written: the test saw nothing"
    for snap in snapshots:
        for file_name, content in snap.items():
            assert content == final[file_name], f"{file_name} was visible before it was complete"
            if file_name.endswith(".dat"):
                assert file_name[:-4] + ".r64" in snap
    entries = [base_name(e.name) for e in await krc.list_dir(TRACE_DIR)]
    assert not [n for n in entries if n.startswith(".")], "temporary files left behind"
    assert not list(sim.share_dir.parent.glob(".krc4-trace-staging-*")), "staging folder left behind"
    read_trace_set(save(final, tmp_path / "atomic"), "atomic")


async def test_pretrigger_part_is_what_was_available(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    """Time 6 s with PreTrigger 2 s: armed long enough, the file holds all 6 s; triggered at once, only 4 s."""
    period_s = 0.012
    await put_config(krc, "pre_start.xml", trace_config_xml(6.0, pretrigger_s=2.0, trigger=TRIGGER_PROGRAM_START))
    await put_config(krc, "pre_now.xml", trace_config_xml(6.0, pretrigger_s=2.0))
    program = await put_program(krc, "SHORT", SHORT_SRC)
    await start_trace(krc, "pre_start.xml", "armed")
    armed_s = sim.clock.now_s()
    async with asyncio.timeout(DEADLINE_S):
        while sim.clock.now_s() < armed_s + 3.0:  # noqa: ASYNC110 - simulated time passing is the point
            await asyncio.sleep(0.005)
    await run_to_end(krc, program)
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    await start_trace(krc, "pre_now.xml", "at_once")
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    for name, expected_s in (("armed", 6.0), ("at_once", 4.0)):
        ts = read_trace_set(save(await pull_trace(krc, name), tmp_path / name), name)
        assert ts.channel("NextGenDrive#5", "Istmoment").values.size == round(expected_s / period_s)


async def test_trace_name_defaults_to_basename_and_must_be_a_file_name(sim: SimulatedKrc4, krc: Controller) -> None:
    await put_config(krc, "named.xml", trace_config_xml(1.0, modules=("NextGenDrive#3",), basename="base_run"))
    with pytest.raises(VariableError):
        await start_trace(krc, "named.xml", "bad/name")
    assert sim.trace.last_error is not None and "file name" in sim.trace.last_error
    await start_trace(krc, "named", "")  # no ".xml" and no name: the config file and its Basename
    await poll(krc, "$TRACE.STATE", lambda v: v == "#T_END")
    assert sorted(await pull_trace(krc, "base_run")) == [
        f"base_run_NextGenDrive#3.{ext}" for ext in ("dat", "r64", "trc")
    ]
