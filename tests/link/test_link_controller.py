"""The Controller facade and the link against the REAL simulated KR C4 server (simulators.krc4.server) over TCP."""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import ControllerConfig, Protocol
from rgse_daemon.controller import SNAPSHOT_VARIABLES, Controller, LoadData, share_path, writable
from rgse_daemon.errors import LinkClosed, LinkTimeout, NotAllowedError, ProtocolError, VariableError
from rgse_daemon.link.errors import CommandError, NotSupportedError
from rgse_daemon.link.krlvalue import KrlEnum
from simulators.krc4.server import KrcServer, ServerConfig
from simulators.krc4.variables import Kind


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[KrcServer]:
    share = tmp_path / "roboter"
    async with KrcServer(ServerConfig(latency_s=0.0), share) as srv:
        srv.store.declare_global("RGSE_STEP", Kind.INT, "0")
        srv.store.declare_global("RGSE_NOTE", Kind.CHAR, '""')
        yield srv


def cfg_for(srv: KrcServer, **kw) -> ControllerConfig:
    base = {
        "host": "127.0.0.1",
        "port": srv.port,
        "request_timeout_s": 0.5,
        "reconnect_min_s": 0.01,
        "reconnect_max_s": 0.05,
        "pool_size": 4,
    }
    base.update(kw)
    return ControllerConfig(**base)


async def test_snapshot_is_one_multi_read_with_c3(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as krc:
        assert krc.protocol is Protocol.C3BRIDGE
        before = sim.counters.requests
        multi_before = sim.counters.by_type[6]
        snap = await krc.snapshot()
        assert sim.counters.requests - before == 1 and sim.counters.by_type[6] - multi_before == 1
    assert snap.complete, snap.errors
    assert len(SNAPSHOT_VARIABLES) >= 24 and set(snap.raw) == set(SNAPSHOT_VARIABLES)
    assert snap.mode_op == "T1" and snap.pro_state1 == "P_FREE" and snap.trace_state == "T_END"
    assert snap.axes_deg is not None and len(snap.axes_deg) == 6
    assert snap.pos_act is not None and snap.pos_act.x_mm == pytest.approx(1339.90503) and snap.pos_act.status == 6
    assert snap.torques_nm == (0.0,) * 6 and snap.motor_temps_k == (298.0,) * 6
    assert snap.load == LoadData(-1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert snap.ov_pro_pct == 100 and snap.user_saf is True and snap.stopmess is False
    assert snap.brake_sig == "000000" and snap.rob_stopped is True and snap.vel_act_m_s == 0.0


async def test_snapshot_over_kvp_uses_single_reads_and_matches(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as c3, Controller.connect(cfg_for(sim, protocol="kvp")) as kvp:
        assert kvp.protocol is Protocol.KVP
        reads_before = sim.counters.by_type[0]
        snap_kvp = await kvp.snapshot()
        assert sim.counters.by_type[0] - reads_before == len(SNAPSHOT_VARIABLES)
        snap_c3 = await c3.snapshot()
    assert snap_kvp.complete and snap_kvp.raw == snap_c3.raw


async def test_unreadable_variable_leaves_field_none(sim: KrcServer) -> None:
    sim.store.update("$MOT_TEMP[3]", "hot")  # not a KRL value
    sim.store._vars.pop("$STOPMESS")
    async with Controller.connect(cfg_for(sim)) as krc:
        snap = await krc.snapshot()
    assert snap.motor_temps_k[2] is None and snap.stopmess is None
    assert set(snap.errors) == {"$MOT_TEMP[3]", "$STOPMESS"}
    assert snap.mode_op == "T1"


async def test_read_write_and_allow_list(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as krc:
        assert await krc.write("$OV_PRO", 30) == 30
        assert await krc.read("$OV_PRO") == 30
        assert await krc.write("RGSE_STEP", 4) == 4
        assert await krc.write("rgse_note", "ok 1") == "ok 1"
        assert await krc.write("$TRACE.NAME[]", "run_01") == "run_01"
        assert await krc.write_raw("$TRACE.MODE", "#T_START") == "#T_START"
        assert await krc.read("$TRACE.MODE") == KrlEnum("T_START")
        with pytest.raises(VariableError) as ei:
            await krc.write("$OV_PRO", 150)  # the controller refuses out-of-range values
        assert ei.value.name == "$OV_PRO"
        before = sim.counters.requests
        for name in ("$MODE_OP", "$OUT[1]", "$LOAD", "RGSE_X; $OUT[1]", "$ov_pro2", "XRGSE_A", ""):
            with pytest.raises(NotAllowedError):
                await krc.write(name, 1)
        with pytest.raises(NotAllowedError):
            await krc.write_raw("$AXIS_ACT", "{A1 0}")
        assert sim.counters.requests == before  # refused locally: nothing reached the wire
    assert writable("$trace.mode") and writable("RGSE_ARR[3]") and not writable("RGSE_")


async def test_put_and_get_200k_file_and_list(sim: KrcServer) -> None:
    data = os.urandom(200_000)
    name = "C:\\KRC\\ROBOTER\\TRACE\\blob.r64"
    async with Controller.connect(cfg_for(sim)) as krc:
        await krc.put_file(name, data)
        assert (sim.files.root / "TRACE" / "blob.r64").read_bytes() == data
        assert await krc.get_file(name) == data
        entries = await krc.list_dir("C:\\KRC\\ROBOTER\\TRACE")
        assert any(e.name.upper().endswith("BLOB.R64") for e in entries)
        with pytest.raises(CommandError):
            await krc.get_file("C:\\KRC\\ROBOTER\\TRACE\\missing.dat")
        await krc.put_file("KRC:\\R1\\PROGRAM\\EMPTY.SRC", b"")
        assert await krc.get_file("/R1/EMPTY.SRC") == b""


async def test_files_over_kvp_use_the_mounted_share(sim: KrcServer) -> None:
    cfg = cfg_for(sim, protocol="kvp", share_dir=sim.files.root)
    async with Controller.connect(cfg) as krc:
        before = sim.counters.requests
        await krc.put_file("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC", b"DEF RGSE_MEAS()\r\nEND\r\n")
        assert (sim.files.root / "R1" / "PROGRAM" / "RGSE_MEAS.SRC").exists()
        assert await krc.get_file("/R1/RGSE_MEAS.SRC") == b"DEF RGSE_MEAS()\r\nEND\r\n"
        assert [e.name for e in await krc.list_dir("KRC:\\R1\\PROGRAM")] == ["KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC"]
        assert sim.counters.requests == before
        with pytest.raises(NotAllowedError):
            await krc.get_file("KRC:\\R1\\..\\..\\etc\\passwd")
        with pytest.raises(NotSupportedError):
            await krc.select_program("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC")
    assert share_path(Path("/s"), "C:\\KRC\\ROBOTER\\TRACE\\a.dat") == Path("/s/TRACE/a.dat")


async def test_program_control(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as krc:
        with pytest.raises(CommandError):
            await krc.start_program()  # nothing selected
        with pytest.raises(CommandError):
            await krc.select_program("KRC:\\R1\\PROGRAM\\NOPE.SRC")
        await krc.put_file("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC", b"DEF RGSE_MEAS()\r\nEND\r\n")
        await krc.select_program("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC")
        snap = await krc.snapshot()
        assert snap.pro_state1 == "P_RESET" and snap.pro_name1 == "RGSE_MEAS"
        await krc.start_program()
        assert (await krc.snapshot()).pro_state1 == "P_ACTIVE"
        await krc.stop_program()
        assert (await krc.snapshot()).pro_state1 == "P_STOP"
        await krc.reset_program()
        await krc.cancel_program()
        assert (await krc.snapshot()).pro_state1 == "P_FREE"
        sim.store.update("$STOPMESS", "TRUE")
        await krc.confirm_all()
        assert (await krc.snapshot()).stopmess is False


async def test_stall_times_out_then_reconnects(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim, pool_size=1)) as krc:
        sim.faults.stall_next = True
        with pytest.raises(LinkTimeout):
            await krc.read("$OV_PRO")
        assert await krc.read("$MODE_OP") == KrlEnum("T1")
        h = krc.health()
        assert h["timeouts"] == 1 and h["reconnects"] == 1


async def test_dropped_connection_reconnect_is_counted(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim, pool_size=1)) as krc:
        sim.faults.drop_after_requests = 0
        with pytest.raises(LinkClosed):
            await krc.write("$OV_PRO", 50)  # writes are not retried: the first may have arrived
        sim.faults.drop_after_requests = 0
        assert await krc.read("$OV_PRO") == 100  # reads retry once on a fresh connection
        assert krc.health()["reconnects"] == 2


@pytest.mark.parametrize("fault", ["garbage_next", "wrong_tag_next"])
async def test_garbage_and_wrong_tag_are_protocol_errors(sim: KrcServer, fault: str) -> None:
    async with Controller.connect(cfg_for(sim, pool_size=1)) as krc:
        setattr(sim.faults, fault, True)
        with pytest.raises(ProtocolError):
            await krc.snapshot()
        assert (await krc.snapshot()).complete
        assert krc.health()["errors"] == 1


async def test_connect_to_nothing_is_a_link_error(sim: KrcServer) -> None:
    port = sim.port
    await sim.close()
    with pytest.raises(LinkClosed):
        async with Controller.connect(ControllerConfig(port=port, connect_timeout_s=1.0)):
            pass


async def test_concurrent_snapshots_share_the_pool(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim, protocol="kvp")) as krc:
        snaps = await asyncio.gather(*(krc.snapshot() for _ in range(5)))
    assert all(s.complete for s in snaps)
    assert sim.counters.connections_accepted >= 4
