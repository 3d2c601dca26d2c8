"""The Controller facade and the link against the REAL simulated KR C4 server (simulators.krc4.server) over TCP."""

from __future__ import annotations

import asyncio
import os
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import ControllerConfig, Protocol
from rgse_daemon.controller import SNAPSHOT_VARIABLES, Controller, LoadData, share_path
from rgse_daemon.errors import ConfigError, LinkClosed, LinkTimeout, NotAllowedError, ProtocolError, VariableError
from rgse_daemon.link import frames as fr
from rgse_daemon.link.errors import CommandError, NotSupportedError
from rgse_daemon.link.krlvalue import KrlEnum
from rgse_daemon.safety.allowlist import writable
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


@pytest.mark.parametrize("op", ["get", "put", "list", "size", "delete", "copy", "move"])
async def test_a_hung_share_is_a_link_timeout_not_a_hang(sim: KrcServer, monkeypatch: pytest.MonkeyPatch,
                                                        op: str) -> None:
    """A network mount that stops answering (a dead SMB server) must not block a run forever: every file operation
    on the share has the same deadline as it would have over the wire."""
    cfg = cfg_for(sim, protocol="kvp", share_dir=sim.files.root)
    name = "KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC"
    async with Controller.connect(cfg) as krc:
        await krc.put_file(name, b"DEF RGSE_MEAS()\r\nEND\r\n")
        release = threading.Event()

        def hung(*_: object) -> None:
            release.wait(10.0)

        for fn in ("_share_read", "_share_write", "_share_list", "_share_delete", "_share_copy"):
            monkeypatch.setattr(f"rgse_daemon.controller.{fn}", hung)
        monkeypatch.setattr(Path, "stat", lambda self, **kw: hung() if self.name == "RGSE_MEAS.SRC" else
                            os.stat(self, **kw))
        calls = {"get": lambda: krc.get_file(name, size_bytes=22), "put": lambda: krc.put_file(name, b"x"),
                 "list": lambda: krc.list_dir("KRC:\\R1\\PROGRAM"), "size": lambda: krc.file_size(name),
                 "delete": lambda: krc.delete_file(name), "copy": lambda: krc.copy_file(name, name + "2"),
                 "move": lambda: krc.move_file(name, name + "2")}
        t0 = time.monotonic()
        try:
            with pytest.raises(LinkTimeout, match="on the share: no answer within"):
                await calls[op]()
        finally:
            release.set()
        assert time.monotonic() - t0 < 5.0  # the deadline (0.5 s, two for copy/move with their size), not 10 s


async def test_delete_copy_move_create_attributes_over_c3(sim: KrcServer) -> None:
    root = sim.files.root
    trace = "C:\\KRC\\ROBOTER\\TRACE\\"
    async with Controller.connect(cfg_for(sim)) as krc:
        await krc.put_file(trace + "t1_KRCIpo.dat", b"samples")
        before = sim.counters.by_type[23]
        await krc.delete_file(trace + "t1_KRCIpo.dat")
        assert not (root / "TRACE" / "t1_KRCIpo.dat").exists() and sim.counters.by_type[23] - before == 1
        with pytest.raises(CommandError) as missing:
            await krc.delete_file(trace + "t1_KRCIpo.dat")
        assert missing.value.code == fr.ErrorCode.ARGUMENT

        await krc.put_file("KRC:\\R1\\PROGRAM\\A.SRC", b"DEF A()\r\nEND\r\n")
        await krc.copy_file("/R1/A.SRC", "/R1/B.SRC")
        assert (root / "R1" / "PROGRAM" / "B.SRC").read_bytes() == b"DEF A()\r\nEND\r\n"
        await krc.put_file("/R1/A.SRC", b"DEF A()\r\n;v2\r\nEND\r\n")
        with pytest.raises(CommandError) as exists:
            await krc.copy_file("/R1/A.SRC", "/R1/B.SRC")
        assert exists.value.code == fr.ErrorCode.ACCESS
        assert (root / "R1" / "PROGRAM" / "B.SRC").read_bytes() == b"DEF A()\r\nEND\r\n"
        await krc.copy_file("/R1/A.SRC", "/R1/B.SRC", overwrite=True)
        assert await krc.get_file("/R1/B.SRC") == b"DEF A()\r\n;v2\r\nEND\r\n"

        await krc.move_file("/R1/B.SRC", trace + "B.SRC")
        assert not (root / "R1" / "PROGRAM" / "B.SRC").exists() and (root / "TRACE" / "B.SRC").exists()
        with pytest.raises(CommandError) as exists:
            await krc.move_file("/R1/A.SRC", trace + "B.SRC")
        assert exists.value.code == fr.ErrorCode.ACCESS and (root / "R1" / "PROGRAM" / "A.SRC").exists()
        await krc.move_file("/R1/A.SRC", trace + "B.SRC", overwrite=True)
        assert not (root / "R1" / "PROGRAM" / "A.SRC").exists()

        await krc.create_file("KRC:\\R1\\PROGRAM\\NEW.SRC")
        await krc.create_file("KRC:\\R1\\PROGRAM\\SUB", fr.ItemType.DIR)
        assert (root / "R1" / "PROGRAM" / "NEW.SRC").read_bytes() == b"" and (root / "R1" / "PROGRAM" / "SUB").is_dir()
        with pytest.raises(CommandError):
            await krc.create_file("KRC:\\R1\\PROGRAM\\NEW.SRC")
        await krc.set_attribute("/R1/NEW.SRC", fr.Attribute.READ_ONLY, fr.Attribute.READ_ONLY)
        with pytest.raises(CommandError) as read_only:
            await krc.delete_file("/R1/NEW.SRC")
        assert read_only.value.code == fr.ErrorCode.ACCESS
        await krc.delete_file("/R1/NEW.SRC", always=True)
        await krc.delete_file("KRC:\\R1\\PROGRAM\\SUB")
        assert sorted(p.name for p in (root / "R1" / "PROGRAM").iterdir()) == []


async def test_file_commands_refuse_paths_leaving_the_share(sim: KrcServer) -> None:
    victim = sim.files.root.parent / "victim.txt"
    victim.write_text("keep")
    escapes = ("KRC:\\R1\\..\\..\\victim.txt", "/TRACE/../../victim.txt", "C:\\Windows\\victim.txt")
    async with Controller.connect(cfg_for(sim)) as krc:
        await krc.put_file("/TRACE/in.txt", b"in")
        for name in escapes:
            for call in (
                lambda name=name: krc.delete_file(name, always=True),
                lambda name=name: krc.copy_file("/TRACE/in.txt", name, overwrite=True),
                lambda name=name: krc.move_file(name, "/TRACE/out.txt", overwrite=True),
                lambda name=name: krc.create_file(name, fr.ItemType.TEXT, always=True),
                lambda name=name: krc.get_krc_name(name),
            ):
                with pytest.raises(CommandError) as refused:
                    await call()
                assert refused.value.code == fr.ErrorCode.ARGUMENT
    assert victim.read_text() == "keep" and not (sim.files.root / "TRACE" / "out.txt").exists()


async def test_krc_name_and_full_name_round_trip(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as krc:
        full = await krc.get_full_name("/R1/TEST.SRC")
        assert full == "KRC:\\R1\\PROGRAM\\TEST.SRC"
        assert await krc.get_krc_name(full) == "/R1/TEST.SRC"
        trace = "C:\\KRC\\ROBOTER\\TRACE\\t1_KRCIpo.r64"
        assert await krc.get_full_name(await krc.get_krc_name(trace)) == trace


async def test_delete_copy_move_over_kvp_use_the_mounted_share(sim: KrcServer) -> None:
    root = sim.files.root
    (root / "TRACE").mkdir(exist_ok=True)
    (root / "TRACE" / "t1_KRCIpo.dat").write_bytes(b"samples")
    async with Controller.connect(cfg_for(sim, protocol="kvp", share_dir=root)) as krc:
        before = sim.counters.requests
        await krc.copy_file("C:\\KRC\\ROBOTER\\TRACE\\t1_KRCIpo.dat", "/TRACE/copy.dat")
        with pytest.raises(CommandError):
            await krc.copy_file("/TRACE/t1_KRCIpo.dat", "/TRACE/copy.dat")
        await krc.move_file("/TRACE/copy.dat", "/TRACE/moved.dat")
        assert (root / "TRACE" / "moved.dat").read_bytes() == b"samples" and not (root / "TRACE" / "copy.dat").exists()
        await krc.delete_file("C:\\KRC\\ROBOTER\\TRACE\\t1_KRCIpo.dat")
        await krc.delete_file("/TRACE/moved.dat")
        assert list((root / "TRACE").iterdir()) == []
        with pytest.raises(CommandError):
            await krc.delete_file("/TRACE/moved.dat")
        with pytest.raises(NotAllowedError):
            await krc.delete_file("KRC:\\R1\\..\\..\\etc\\passwd")
        for call in (
            lambda: krc.create_file("/R1/NEW.SRC"),
            lambda: krc.set_attribute("/R1/NEW.SRC", fr.Attribute.READ_ONLY, fr.Attribute.READ_ONLY),
            lambda: krc.get_krc_name("KRC:\\R1\\PROGRAM\\TEST.SRC"),
            lambda: krc.get_full_name("/R1/TEST.SRC"),
        ):
            with pytest.raises(NotSupportedError):
                await call()
        assert sim.counters.requests == before  # nothing of this went over the link
    async with Controller.connect(cfg_for(sim, protocol="kvp")) as krc:
        with pytest.raises(ConfigError, match="share_dir"):
            await krc.delete_file("/TRACE/x.dat")


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
