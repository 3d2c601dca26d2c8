"""The simulator behaves as the real C3 Bridge server does (docs/protocol.md §3): one test per behaviour."""

from __future__ import annotations

import asyncio
import struct
import time
from pathlib import Path

import pytest

from rgse_daemon.errors import ConfigError
from rgse_daemon.link import frames as fr
from simulators.krc4.scenario import scenario_from_mapping
from simulators.krc4.server import DEFAULT_FILE_RATE_BYTES_S, KrcServer, ServerConfig
from simulators.krc4.sim import SimulatedKrc4

from .conftest import DEADLINE_S, RawClient

PING = fr.encode_request(1, fr.ReadVarAscii("PING"))
RATE = 200_000.0  # bytes/s in these tests: a 100 kB file takes 0.5 s


def _trace_file(share: Path, name: str = "big.r64", size: int = 100_000) -> str:
    (share / "TRACE" / name).write_bytes(bytes(range(256)) * (size // 256) + b"\x00" * (size % 256))
    return "C:\\KRC\\ROBOTER\\TRACE\\" + name


async def test_read_begin_loads_the_whole_file_before_it_answers(share: Path) -> None:
    name = _trace_file(share)
    async with KrcServer(ServerConfig(latency_s=0.0, file_rate_bytes_s=RATE), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            t0 = time.monotonic()
            assert await c.call(fr.ReadContentBegin(0, name)) == fr.ReadContentBeginReply(100_000)
            assert time.monotonic() - t0 >= 100_000 / RATE  # a lower bound: the sleep guarantees it
            t0 = time.monotonic()
            rsp = await c.call(fr.ReadContentData(0, fr.MAX_READ_CHUNK))  # chunks come from the buffer: fast
            assert isinstance(rsp, fr.ReadContentDataReply) and len(rsp.data) == fr.MAX_READ_CHUNK
        finally:
            await c.close()


async def test_write_end_takes_time_in_proportion_to_the_buffer(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0, file_rate_bytes_s=RATE), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            await c.call(fr.WriteContentBegin(60_000))
            await c.call(fr.WriteContentData(0, b"x" * 60_000))
            t0 = time.monotonic()
            assert (await c.call(fr.WriteContentEnd(64, "C:\\KRC\\ROBOTER\\TRACE\\w.xml"))).ok
            assert time.monotonic() - t0 >= 60_000 / RATE
            assert (share / "TRACE" / "w.xml").stat().st_size == 60_000
        finally:
            await c.close()


def test_the_default_file_rate_is_the_conservative_one_and_a_scenario_key_sets_it(share: Path) -> None:
    assert ServerConfig().file_rate_bytes_s == DEFAULT_FILE_RATE_BYTES_S
    sim = SimulatedKrc4(share, scenario={"server": {"file_rate_bytes_s": 5e6, "listing": "bare", "path_forms": "krc"}})
    assert (sim.server.config.file_rate_bytes_s, sim.server.config.listing, sim.server.config.path_forms) == (
        5e6, "bare", "krc")
    with pytest.raises(ConfigError, match="listing"):
        scenario_from_mapping({"server": {"listing": "xml"}})


async def test_a_file_operation_blocks_every_other_connection(share: Path) -> None:
    name = _trace_file(share)
    async with KrcServer(ServerConfig(latency_s=0.0, file_rate_bytes_s=RATE), share) as srv:
        puller, pinger = await RawClient.open(srv.port), await RawClient.open(srv.port)
        try:
            begin = asyncio.create_task(puller.call(fr.ReadContentBegin(0, name)))
            await asyncio.sleep(0.1)  # the Begin is being served
            t0 = time.monotonic()
            assert await pinger.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
            waited_s = time.monotonic() - t0
            assert waited_s >= 100_000 / RATE - 0.15  # the PING was answered only after the file was loaded
            await begin
        finally:
            await puller.close()
            await pinger.close()


async def test_buffers_are_per_connection_and_lost_on_disconnect(share: Path) -> None:
    name = _trace_file(share, size=1000)
    async with KrcServer(ServerConfig(latency_s=0.0), share) as srv:
        first = await RawClient.open(srv.port)
        assert await first.call(fr.ReadContentBegin(0, name)) == fr.ReadContentBeginReply(1000)
        other = await RawClient.open(srv.port)
        try:
            assert await other.call(fr.ReadContentGetSize()) == fr.ReadContentGetSizeReply(0)  # not shared
            await first.close()
            again = await RawClient.open(srv.port)
            rsp = await again.call(fr.ReadContentData(0, 100))
            assert not rsp.ok  # the transfer is lost: start again from Begin
            assert await again.call(fr.ReadContentBegin(0, name)) == fr.ReadContentBeginReply(1000)
            await again.close()
        finally:
            await other.close()


async def test_writes_echo_the_request_text_not_a_read_back(server: KrcServer, client: RawClient) -> None:
    assert await client.call(fr.WriteVarAscii("$TRACE.MODE", "#t_start")) == fr.WriteVarAsciiReply("#t_start")
    assert server.store.read("$TRACE.MODE") == "#T_START"  # the controller holds the normalised form
    assert await client.call(fr.WriteVar("$OV_PRO", " 35")) == fr.WriteVarReply(" 35")
    load = "{M 12, CM {X 0, Y 0, Z 300, A 0, B 0, C 0}, J {X 0, Y 0, Z 0}}"
    assert await client.call(fr.WriteVar("$LOAD", load)) == fr.WriteVarReply(load)


async def test_ping_and_proxy_variables_are_exact_case(client: RawClient) -> None:
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    assert await client.call(fr.ReadVarAscii("ping")) == fr.ReadVarAsciiReply("", code=0, success=False)
    assert await client.call(fr.ReadVar("@proxy_type")) == fr.ReadVarReply("", code=0, success=False)
    # KRL names go to Cross3 unchanged, and KRL itself is case-insensitive
    assert await client.call(fr.ReadVarAscii("$mode_op")) == fr.ReadVarAsciiReply("#T1")


async def test_version_is_1_4(client: RawClient) -> None:
    info = await client.call(fr.ProxyInfo())
    assert isinstance(info, fr.ProxyInfoReply) and (info.major, info.minor) == (1, 4)
    assert await client.call(fr.ReadVarAscii("@PROXY_VERSION")) == fr.ReadVarAsciiReply("1.4 (OPEN SOURCE)")


async def test_pipelined_requests_are_answered_in_order(client: RawClient) -> None:
    frames = [fr.encode_request(tag, fr.ReadVarAscii(n)) for tag, n in ((1, "PING"), (2, "$MODE_OP"), (3, "PING"))]
    await client.send(b"".join(frames))
    got = [fr.decode_response(await client.frame()) for _ in range(3)]
    assert got == [(1, fr.ReadVarAsciiReply("PONG")), (2, fr.ReadVarAsciiReply("#T1")),
                   (3, fr.ReadVarAsciiReply("PONG"))]


async def test_trailing_bytes_after_a_well_formed_body_are_ignored(client: RawClient) -> None:
    frame = bytearray(fr.encode_request(9, fr.ReadVar("$MODE_OP")) + b"\x01\x02\x03")
    struct.pack_into(">H", frame, 2, len(frame) - 4)
    assert fr.decode_response(await client.raw(bytes(frame))) == (9, fr.ReadVarReply("#T1"))


async def test_unknown_variable_is_an_empty_value_with_code_0(client: RawClient) -> None:
    for req, reply in ((fr.ReadVarAscii("RGSE_NOPE"), fr.ReadVarAsciiReply("", code=0, success=False)),
                       (fr.ReadVar("RGSE_NOPE"), fr.ReadVarReply("", code=0, success=False))):
        assert await client.call(req) == reply


async def test_malformed_reads_code_0_on_ascii_code_9_on_wide(client: RawClient) -> None:
    raw = await client.raw(bytes.fromhex("0005 0003 00 0009"))  # #0 announcing 9 bytes it does not carry
    assert raw == bytes.fromhex("0005 0006 00 0000 0000 00")
    raw = await client.raw(bytes.fromhex("0006 0003 04 0009"))  # #4 announcing 9 units it does not carry
    assert raw == bytes.fromhex("0006 0006 04 0000 0009 00")


@pytest.mark.parametrize("msg_type, body", [(11, b"\x01\x00\x00"), (12, b"\x03" + bytes(10))])
async def test_motion_and_key_messages_are_answered_not_closed(client: RawClient, msg_type: int, body: bytes) -> None:
    raw = await client.raw(struct.pack(">HHB", 5, len(body) + 1, msg_type) + body)
    assert raw[:2] == b"\x00\x05" and raw[4] == msg_type and raw[5] == body[0]  # the subtype byte echoed
    assert raw[-3:] == b"\x00\x07\x00"  # code 7: this simulator never moves the robot on a protocol command
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")


async def test_legacy_discovery_answers_on_port_7000_of_the_sender(share: Path) -> None:
    loop = asyncio.get_running_loop()
    answers: asyncio.Queue[bytes] = asyncio.Queue()

    class Listener(asyncio.DatagramProtocol):  # stands for the client's port 7000
        def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
            answers.put_nowait(data)

    listen, _ = await loop.create_datagram_endpoint(Listener, local_addr=("127.0.0.1", 0))
    reply_port = listen.get_extra_info("sockname")[1]
    config = ServerConfig(latency_s=0.0, legacy_udp_port=0, legacy_reply_port=reply_port)
    try:
        async with KrcServer(config, share) as srv:
            send, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol,
                                                          remote_addr=("127.0.0.1", srv.legacy_udp_port))
            try:
                send.sendto(b"WHEREAREYOU?")
                async with asyncio.timeout(DEADLINE_S):
                    assert (await answers.get()).startswith(b"KUKA|")
            finally:
                send.close()
    finally:
        listen.close()


async def test_no_client_limit_and_no_idle_drop_by_default(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0), share) as srv:
        clients = [await RawClient.open(srv.port) for _ in range(12)]
        try:
            await asyncio.sleep(0.3)
            for c in clients:
                assert await c.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
            assert srv.counters.connections_refused == 0 and srv.counters.idle_drops == 0
        finally:
            for c in clients:
                await c.close()


@pytest.mark.parametrize("listing", ["fields", "bare", "text"])
async def test_listing_variants(share: Path, listing: str) -> None:
    _trace_file(share, "t_KRCIpo.dat", 300)
    async with KrcServer(ServerConfig(latency_s=0.0, listing=listing), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            rsp = await c.call(fr.NameList(0, 0, "C:\\KRC\\ROBOTER\\TRACE\\"))
        finally:
            await c.close()
    assert isinstance(rsp, fr.NameListReply) and rsp.ok
    if listing == "bare":
        assert rsp.items == ("t_KRCIpo.dat",) and rsp.infos == ()
    else:
        assert rsp.items == ("C:\\KRC\\ROBOTER\\TRACE\\t_KRCIpo.dat",)
        info = rsp.infos[0]
        assert info.split(";")[1] == "300" if listing == "fields" else (info.startswith("300 ") and ";" not in info)


@pytest.mark.parametrize("forms, ok, refused", [
    ("disk", ["C:\\KRC\\ROBOTER\\TRACE\\", "KRC:\\R1\\PROGRAM\\"], ["KRC:\\TRACE\\", "C:\\KRC\\ROBOTER\\TRACE"]),
    ("krc", ["KRC:\\TRACE", "KRC:\\R1\\PROGRAM"], ["C:\\KRC\\ROBOTER\\TRACE", "KRC:\\TRACE\\"]),
    ("any", ["KRC:\\TRACE", "KRC:\\TRACE\\", "C:\\KRC\\ROBOTER\\TRACE", "C:\\KRC\\ROBOTER\\TRACE\\"], []),
])
async def test_path_form_variants(share: Path, forms: str, ok: list[str], refused: list[str]) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0, path_forms=forms), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            for path in ok:
                assert (await c.call(fr.NameList(0, 0, path))).ok, path
            for path in refused:
                rsp = await c.call(fr.NameList(0, 0, path))
                assert not rsp.ok and rsp.code == 3, path
        finally:
            await c.close()


async def test_input_is_dropped_only_while_a_reply_is_still_being_sent(share: Path) -> None:
    import socket

    name = _trace_file(share, size=fr.MAX_READ_CHUNK)
    async with KrcServer(ServerConfig(latency_s=0.0), share) as srv:
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a client that reads slowly
        sock.setblocking(False)
        await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", srv.port))
        reader, writer = await asyncio.open_connection(sock=sock)
        c = RawClient(reader, writer)
        try:
            assert (await c.call(fr.ReadContentBegin(0, name))).ok
            chunks = 120  # ~7.7 MB of replies: more than the socket buffers hold, so the server's send backs up
            await c.send(b"".join(fr.encode_request(i, fr.ReadContentData(0, fr.MAX_READ_CHUNK))
                                  for i in range(chunks)))
            for _ in range(200):
                if srv.counters.by_type[30] >= 1 + chunks:
                    break
                await asyncio.sleep(0.01)
            await c.send(PING)  # arrives while replies are still queued for sending: dropped
            await asyncio.sleep(0.2)
            tags = [fr.decode_response(await c.frame())[0] for _ in range(chunks)]
            assert tags == list(range(chunks))  # every queued request answered, in order
            assert srv.counters.bytes_discarded == len(PING)
        finally:
            await c.close()
