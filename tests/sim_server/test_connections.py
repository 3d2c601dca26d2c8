"""Connection behaviour of the simulated server: client limit, idle drop, discarding, faults, UDP discovery."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from rgse_daemon.errors import ConfigError, ProtocolError
from rgse_daemon.link import frames as fr
from simulators.krc4.server import GARBAGE_REPLY, KrcServer, ServerConfig
from tests.support.polling import wait_until

from .conftest import DEADLINE_S, RawClient

PING = fr.encode_request(1, fr.ReadVarAscii("PING"))




async def test_kvp_client_limit_when_configured_closes_the_eleventh(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0, max_clients=10), share) as srv:
        clients = [await RawClient.open(srv.port) for _ in range(10)]
        try:
            for c in clients:
                assert await c.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
            eleventh = await RawClient.open(srv.port)
            assert await eleventh.at_eof()
            await eleventh.close()
            assert srv.counters.connections_refused == 1
            await clients.pop().close()
            await wait_until(lambda: srv.client_count == 9, "server notices the closed client")
            replacement = await RawClient.open(srv.port)
            clients.append(replacement)
            assert await replacement.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
        finally:
            for c in clients:
                await c.close()


async def test_idle_client_is_dropped(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0, idle_timeout_s=0.5), share) as srv:
        c = await RawClient.open(srv.port)
        assert await c.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
        assert await c.at_eof()
        await c.close()
        assert srv.counters.idle_drops == 1


async def test_strict_model_discards_bytes_arriving_while_busy(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.3, discard_while_busy=True), share) as srv:
        c = await RawClient.open(srv.port)
        try:
            second = fr.encode_request(2, fr.ReadVarAscii("$MODE_OP"))
            await c.send(PING + second)  # a pipelined second request: lost in the strict model
            tag, rsp = fr.decode_response(await c.frame())
            assert (tag, rsp) == (1, fr.ReadVarAsciiReply("PONG"))
            assert srv.counters.bytes_discarded == len(second)
            assert srv.counters.requests == 1
            # once the reply is out, the connection serves again
            assert await c.call(fr.ReadVarAscii("$MODE_OP"), tag=3) == fr.ReadVarAsciiReply("#T1")
        finally:
            await c.close()


async def test_pipelined_requests_are_queued_and_answered_in_order(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.05), share) as srv:  # the real server's default
        c = await RawClient.open(srv.port)
        try:
            await c.send(PING + fr.encode_request(2, fr.ReadVarAscii("$MODE_OP")))
            assert fr.decode_response(await c.frame()) == (1, fr.ReadVarAsciiReply("PONG"))
            assert fr.decode_response(await c.frame()) == (2, fr.ReadVarAsciiReply("#T1"))
            assert srv.counters.bytes_discarded == 0
        finally:
            await c.close()


async def test_requests_of_all_clients_are_served_one_at_a_time(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.01), share) as srv:
        clients = [await RawClient.open(srv.port) for _ in range(5)]
        in_service = 0
        peak = 0
        original = srv.store.read

        def watched_read(name: str) -> str:
            nonlocal in_service, peak
            in_service += 1
            peak = max(peak, in_service)
            try:
                return original(name)
            finally:
                in_service -= 1

        srv.store.read = watched_read  # type: ignore[method-assign]
        try:
            replies = await asyncio.gather(*(c.call(fr.ReadVarAscii("$MODE_OP")) for c in clients for _ in range(1)))
            assert all(r == fr.ReadVarAsciiReply("#T1") for r in replies)
            assert peak == 1 and srv.counters.requests == 5
        finally:
            for c in clients:
                await c.close()


async def test_fault_drop_after_requests(server: KrcServer, client: RawClient) -> None:
    server.faults.drop_after_requests = 1
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    await client.send(PING)
    assert await client.at_eof()
    assert server.faults.drop_after_requests is None and server.counters.faults_fired["drop_after_requests"] == 1
    again = await RawClient.open(server.port)
    assert await again.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    await again.close()


async def test_fault_drop_on_variable(server: KrcServer, client: RawClient) -> None:
    server.faults.drop_on_variable = "$axis_act"
    other = await RawClient.open(server.port)
    try:
        await client.send(fr.encode_request(1, fr.ReadMulti(("$MODE_OP", "$AXIS_ACT"))))
        assert await client.at_eof()
        assert await other.call(fr.ReadVarAscii("$MODE_OP")) == fr.ReadVarAsciiReply("#T1")
    finally:
        await other.close()


async def test_fault_stall_silences_one_connection(server: KrcServer, client: RawClient) -> None:
    server.faults.stall_next = True
    await client.send(PING)
    other = await RawClient.open(server.port)
    try:
        # served after the stalled request (one lock, FIFO): once this reply is here, the stalled one would be too
        assert await other.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
        await client.send(PING)
        assert await other.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
        with pytest.raises(TimeoutError):
            async with asyncio.timeout(0.2):
                await client.reader.read(1)
        assert server.counters.faults_fired["stall"] == 1 and not server.faults.stall_next
    finally:
        await other.close()


async def test_fault_garbage_reply(server: KrcServer, client: RawClient) -> None:
    server.faults.garbage_next = True
    await client.send(PING)
    async with asyncio.timeout(DEADLINE_S):
        got = await client.reader.readexactly(len(GARBAGE_REPLY))
    assert got == GARBAGE_REPLY
    with pytest.raises(ProtocolError):
        fr.FrameReader(responses=True).feed(got)
    assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")  # fires once


async def test_fault_wrong_tag(server: KrcServer, client: RawClient) -> None:
    server.faults.wrong_tag_next = True
    tag, rsp = fr.decode_response(await client.raw(fr.encode_request(41, fr.ReadVarAscii("PING"))))
    assert tag != 41 and rsp == fr.ReadVarAsciiReply("PONG")
    tag, _ = fr.decode_response(await client.raw(fr.encode_request(42, fr.ReadVarAscii("PING"))))
    assert tag == 42


async def test_udp_discovery(share: Path) -> None:
    async with KrcServer(ServerConfig(latency_s=0.0, udp_port=0), share) as srv:
        loop = asyncio.get_running_loop()
        answers: asyncio.Queue[bytes] = asyncio.Queue()

        class Probe(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                answers.put_nowait(data)

        transport, _ = await loop.create_datagram_endpoint(Probe, remote_addr=("127.0.0.1", srv.udp_port))
        try:
            transport.sendto(b"WHEREAREYOU?")
            async with asyncio.timeout(DEADLINE_S):
                assert await answers.get() == b'KUKA|"#KR500R2830 C4"|1234567'
            transport.sendto(b"@PROXY_TYPE")
            async with asyncio.timeout(DEADLINE_S):
                assert await answers.get() == b"C3 BRIDGE INTERFACE"
        finally:
            transport.close()


@pytest.mark.parametrize(
    "kwargs",
    [{"port": 70000}, {"max_clients": 0}, {"idle_timeout_s": 0.0}, {"latency_s": -1.0}, {"version": (1, 5, 9)}],
)
def test_bad_server_config_is_a_config_error(kwargs) -> None:
    with pytest.raises(ConfigError):
        ServerConfig(**kwargs)


async def test_serve_forever_until_cancelled_then_closed(share: Path) -> None:
    srv = KrcServer(ServerConfig(latency_s=0.0), share)
    task = asyncio.create_task(srv.serve_forever())
    try:
        await wait_until(lambda: srv.port != 0, "the server listens")
        c = await RawClient.open(srv.port)
        assert await c.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
    assert await c.at_eof()  # the server dropped its clients on the way out
    await c.close()
    with pytest.raises(OSError):
        await RawClient.open(srv.port)
