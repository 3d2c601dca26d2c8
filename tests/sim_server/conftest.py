"""Fixtures for the simulated KR C4 server: a running server on port 0 and a raw-socket client."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.link import frames as fr
from simulators.krc4.server import KrcServer, ServerConfig

DEADLINE_S = 5.0


class RawClient:
    """A bare TCP client: sends bytes or encoded requests, reads exactly one reply frame."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer

    @classmethod
    async def open(cls, port: int) -> RawClient:
        async with asyncio.timeout(DEADLINE_S):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        return cls(reader, writer)

    async def send(self, data: bytes) -> None:
        self.writer.write(data)
        async with asyncio.timeout(DEADLINE_S):
            await self.writer.drain()

    async def frame(self) -> bytes:
        async with asyncio.timeout(DEADLINE_S):
            return await fr.read_frame(self.reader, responses=True)

    async def raw(self, data: bytes) -> bytes:
        await self.send(data)
        return await self.frame()

    async def call(self, req: fr.Request, tag: int = 7) -> fr.Reply:
        got_tag, rsp = fr.decode_response(await self.raw(fr.encode_request(tag, req)))
        assert got_tag == tag
        return rsp

    async def at_eof(self) -> bool:
        """True when the server closed the connection (without sending anything first)."""
        async with asyncio.timeout(DEADLINE_S):
            rest = await self.reader.read()
        return rest == b""

    async def close(self) -> None:
        self.writer.close()
        try:
            async with asyncio.timeout(DEADLINE_S):
                await self.writer.wait_closed()
        except (ConnectionError, OSError):
            pass


@pytest.fixture
def share(tmp_path: Path) -> Path:
    (tmp_path / "R1" / "PROGRAM").mkdir(parents=True)
    (tmp_path / "TRACE").mkdir()
    return tmp_path


@pytest.fixture
async def server(share: Path) -> AsyncIterator[KrcServer]:
    async with KrcServer(ServerConfig(latency_s=0.0), share) as srv:
        yield srv


@pytest.fixture
async def client(server: KrcServer) -> AsyncIterator[RawClient]:
    c = await RawClient.open(server.port)
    yield c
    await c.close()


@pytest.fixture(autouse=True)
def _default_server_variant(monkeypatch: pytest.MonkeyPatch) -> None:
    """These tests pin the simulated server's own behaviour: its default listing and path forms (a suite run with
    RGSE_SIM_LISTING / RGSE_SIM_PATHS set exercises the clients on a variant; tests here set variants explicitly)."""
    monkeypatch.delenv("RGSE_SIM_LISTING", raising=False)
    monkeypatch.delenv("RGSE_SIM_PATHS", raising=False)
