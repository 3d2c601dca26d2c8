"""Finding 8 of #12 (last point): garbage bytes from the controller's port are reported naming them, not as
"no reply to message type 0". The peer is a real TCP server on loopback that answers like a broken or foreign
service would; the daemon's own Controller talks to it."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import pytest

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.errors import LinkError, LinkTimeout, ProtocolError
from rgse_daemon.link.connection import Connection

# A #0 reply header whose value-length field (0xfff0) promises 65 KB that never come, then some junk.
LOOKS_LIKE_A_READ_REPLY = b"\x00\x01\x00\x09\x00\xff\xf0junk"
LINE_NOISE = bytes([0x00, 0x00, 0x00])  # fewer bytes than a header


async def peer(answer: bytes | None) -> tuple[asyncio.Server, int]:
    """A server that reads whatever is sent and answers every chunk with ``answer`` (None: stays silent)."""

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while await reader.read(4096):
                if answer is not None:
                    writer.write(answer)
                    await writer.drain()
        finally:
            writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    return server, server.sockets[0].getsockname()[1]


@pytest.fixture
async def servers() -> AsyncIterator[list[asyncio.Server]]:
    started: list[asyncio.Server] = []
    yield started
    for s in started:
        s.close()
        await s.wait_closed()


@pytest.mark.parametrize("garbage", [LOOKS_LIKE_A_READ_REPLY, LINE_NOISE], ids=["partial-frame", "short-noise"])
async def test_garbage_reply_names_the_bytes(servers, garbage):
    server, port = await peer(garbage)
    servers.append(server)
    conn = Connection("127.0.0.1", port, name="krc", request_timeout_s=0.5, connect_timeout_s=2.0)
    try:
        with pytest.raises(ProtocolError) as info:
            await conn.read_var("$MODE_OP")
    finally:
        await conn.close()
    text = str(info.value)
    assert f"{len(garbage)} bytes received in reply to message type 0" in text, text
    assert garbage[:4].hex(" ") in text and "not a C3 Bridge/KUKAVARPROXY server" in text, text
    assert "no reply" not in text


async def test_silence_is_still_a_timeout(servers):
    server, port = await peer(None)
    servers.append(server)
    conn = Connection("127.0.0.1", port, name="krc", request_timeout_s=0.3, connect_timeout_s=2.0)
    try:
        with pytest.raises(LinkTimeout, match="no reply to message type 0"):
            await conn.read_var("$MODE_OP")
    finally:
        await conn.close()


async def test_controller_over_garbage_reports_the_cause(servers):
    """As the daemon sees it: Controller.connect to a port that answers garbage fails naming the garbage."""
    server, port = await peer(LOOKS_LIKE_A_READ_REPLY)
    servers.append(server)
    cfg = ControllerConfig(host="127.0.0.1", port=port, request_timeout_s=0.5, connect_timeout_s=2.0, pool_size=1)
    with pytest.raises(LinkError) as info:
        async with Controller.connect(cfg) as krc:
            await krc.read_raw("$MODE_OP")
    assert "do not form a complete frame" in str(info.value), str(info.value)
