"""The console's HTTP face (interfaces §4.4) as an unknown client meets it, over raw sockets against the daemon on
the simulated KR C4: bad bodies get a 4xx with a reason, never a 500."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import config_from_mapping
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import RunningDaemon, daemon_config, running_daemon

IO_S = 10.0  # a hang guard on each socket read, not a timing check


@pytest.fixture
async def console(sim: SimulatedKrc4, tmp_path: Path) -> AsyncIterator[RunningDaemon]:
    """The daemon with its console on a free port (tokens configured, no broker)."""
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    cfg = config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<console http test>")
    async with running_daemon(cfg) as rd:
        yield rd


async def exchange(port: int, request: bytes) -> tuple[int, bytes]:
    """Send ``request`` on a fresh connection; the response's status and body (the server closes)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        async with asyncio.timeout(IO_S):
            raw = await reader.read()
    finally:
        writer.close()
        await writer.wait_closed()
    head, _, body = raw.partition(b"\r\n\r\n")
    return int(head.split(b" ")[1]), body


def post(path: str, body: bytes) -> bytes:
    return (f"POST {path} HTTP/1.1\r\nHost: t\r\nConnection: close\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode() + body


async def test_a_body_nested_too_deeply_is_a_400_with_its_reason(console: RunningDaemon) -> None:
    port = console.daemon.console.port
    for path, body in (("/api/confirm", b"[" * 50000 + b"]" * 50000),
                       ("/api/abort", b'{"reason": "x", "a": ' + b"[" * 5000 + b"]" * 5000 + b"}")):
        status, text = await exchange(port, post(path, body))
        assert (status, json.loads(text)) == (400, {"ok": False, "error": "a JSON object expected: nested too deeply"})
    status, text = await exchange(port, post("/api/abort", b'{"reason": "x"}'))
    assert status == 409 and json.loads(text)["error"] == "unauthorised: missing or wrong token"
