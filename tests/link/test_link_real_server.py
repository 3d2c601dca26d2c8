"""The client copes with the real C3 Bridge server's behaviour (docs/protocol.md §3), over a real socket:
slow, blocking file work; buffers lost with the connection; request-text echoes; unknown path and listing forms."""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.errors import LinkTimeout, ProtocolError
from rgse_daemon.filelayout import FileLayout, load_layout, save_layout
from rgse_daemon.link import frames as fr
from rgse_daemon.link.krlvalue import KrlEnum
from simulators.krc4.server import KrcServer, ServerConfig

RATE = 100_000.0  # the simulator's default file rate (bytes/s)
SHORT_S = 0.3  # the variable-read deadline in these tests


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[KrcServer]:
    share = tmp_path / "roboter"
    (share / "TRACE").mkdir(parents=True)
    async with KrcServer(ServerConfig(latency_s=0.0, file_rate_bytes_s=RATE), share) as srv:
        yield srv


def cfg_for(srv: KrcServer, **kw: object) -> ControllerConfig:
    base: dict[str, object] = {"host": "127.0.0.1", "port": srv.port, "request_timeout_s": SHORT_S,
                               "reconnect_min_s": 0.01, "reconnect_max_s": 0.05, "keepalive_s": 0.05}
    return ControllerConfig(**{**base, **kw})


def _put(srv: KrcServer, name: str, size: int) -> bytes:
    data = os.urandom(size)
    (srv.files.root / "TRACE" / name).write_bytes(data)
    return data


async def test_a_file_read_gets_a_deadline_sized_by_its_bytes_a_variable_read_keeps_the_short_one(
        sim: KrcServer) -> None:
    data = _put(sim, "big.r64", 150_000)  # the server loads it for 1.5 s, five times the read deadline
    async with Controller.connect(cfg_for(sim)) as krc:
        assert await krc.get_file("C:\\KRC\\ROBOTER\\TRACE\\big.r64") == data
        sim.faults.extra_latency_s = 2 * SHORT_S
        with pytest.raises(LinkTimeout):
            await krc.read_raw("$MODE_OP")


async def test_status_reads_and_keepalives_behind_a_long_pull_are_late_not_lost(sim: KrcServer) -> None:
    _put(sim, "big.r64", 150_000)
    async with Controller.connect(cfg_for(sim, pool_size=4)) as krc:
        pull = asyncio.create_task(krc.get_file("C:\\KRC\\ROBOTER\\TRACE\\big.r64"))
        await asyncio.sleep(0.2)  # the Begin is being served: everything else waits 1.3 s more
        snap = await krc.snapshot()  # deadline SHORT_S + the pull's remaining deadline
        assert snap.complete
        await pull
        health = krc.health()
        assert health["timeouts"] == 0 and health["reconnects"] == 0, health  # no keep-alive was killed
        assert health["keepalives"] > 0


async def test_a_read_interrupted_by_a_lost_link_starts_again_from_begin(sim: KrcServer) -> None:
    data = _put(sim, "t_NextGenDrive#3.r64", 200_000)  # four chunks
    async with Controller.connect(cfg_for(sim, keepalive_s=20.0)) as krc:  # no PING among the counted requests
        await krc.trace_layout()  # the path form is known (probed) before the fault is armed
        sim.faults.drop_after_requests = 2  # properties, Begin, then the first chunk request closes the link
        begins = sim.counters.by_type[30]
        assert await krc.get_file("C:\\KRC\\ROBOTER\\TRACE\\t_NextGenDrive#3.r64") == data
        assert sim.counters.faults_fired["drop_after_requests"] == 1
        assert sim.counters.by_type[30] - begins >= 2 + 5  # Begin, then Begin + 4 chunks + End again


async def test_a_read_whose_size_is_not_the_expected_one_is_refused(sim: KrcServer) -> None:
    _put(sim, "x.dat", 1000)
    async with Controller.connect(cfg_for(sim)) as krc:
        with pytest.raises(ProtocolError, match="1000 bytes"):
            await krc.get_file("C:\\KRC\\ROBOTER\\TRACE\\x.dat", size_bytes=999)


async def test_nothing_relies_on_a_normalised_echo(sim: KrcServer) -> None:
    async with Controller.connect(cfg_for(sim)) as krc:
        assert await krc.write("$TRACE.MODE", KrlEnum("t_start")) == KrlEnum("t_start")
        assert await krc.write_raw("$OV_PRO", " 35 ") == " 35 "  # the server's echo: the request text
        assert await krc.read("$TRACE.MODE") == KrlEnum("T_START")  # the controller's form comes from a read
        assert await krc.read("$OV_PRO") == 35


@pytest.mark.parametrize("listing", ["fields", "bare", "text"])
@pytest.mark.parametrize("forms", ["any", "disk", "krc"])
async def test_file_round_trip_on_every_listing_and_path_variant(tmp_path: Path, listing: str, forms: str) -> None:
    share = tmp_path / "roboter"
    (share / "TRACE").mkdir(parents=True)
    async with KrcServer(ServerConfig(latency_s=0.0, listing=listing, path_forms=forms), share) as srv:
        async with Controller.connect(cfg_for(srv)) as krc:
            name = "C:\\KRC\\ROBOTER\\TRACE\\rt_KRCIpo.dat"  # the daemon's own form; rewritten where needed
            await krc.put_file(name, b"header\r\n")
            entries = [e for e in await krc.list_dir("C:\\KRC\\ROBOTER\\TRACE\\") if not e.is_dir]
            assert [e.base_name for e in entries] == ["rt_KRCIpo.dat"]
            assert entries[0].size_bytes == (8 if listing == "fields" else None)  # never guessed from free text
            assert await krc.get_file(name) == b"header\r\n"
            await krc.delete_file(name)
            assert not (share / "TRACE" / "rt_KRCIpo.dat").exists()
            layout = await krc.trace_layout()
            assert layout is not None and layout.trace_dir == ("KRC:\\TRACE\\" if forms == "krc"
                                                               else "C:\\KRC\\ROBOTER\\TRACE\\")


async def test_a_recorded_layout_is_used_without_probing(tmp_path: Path) -> None:
    save_layout(tmp_path, FileLayout("KRC:\\TRACE\\", False, "fields", 123456.0))
    layout = load_layout(tmp_path)
    assert layout == FileLayout("KRC:\\TRACE\\", False, "fields", 123456.0)
    async with KrcServer(ServerConfig(latency_s=0.0, path_forms="krc"), tmp_path / "roboter") as sim, \
            Controller.connect(cfg_for(sim), layout=layout) as krc:
        lists = sim.counters.by_type[fr.MsgType.NAME_LIST]
        await krc.put_file("C:\\KRC\\ROBOTER\\TRACE\\a.xml", b"<Trace/>")
        assert sim.counters.by_type[fr.MsgType.NAME_LIST] == lists  # no probe
        assert (sim.files.root / "TRACE" / "a.xml").read_bytes() == b"<Trace/>"
