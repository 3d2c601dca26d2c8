"""Interop: the third-party py-openshowvar client (PyPI 1.1.7, blocking, one recv(256) per reply), unchanged.

It sends KUKAVARPROXY #0/#1 frames with a random tag and accepts a reply only if the tag matches and the footer
ends in 01; a reply that does not arrive in one recv(256) breaks it. Run in a thread: it is blocking.
"""

from __future__ import annotations

import asyncio

from py_openshowvar import openshowvar

from simulators.krc4.server import KrcServer, ServerConfig
from simulators.krc4.variables import Kind, e6axis


def _session(port: int) -> dict[str, bytes | None]:
    client = openshowvar("127.0.0.1", port)
    client.sock.settimeout(5.0)  # never hang the test thread on a silent server
    try:
        return {
            "axis": client.read("$AXIS_ACT", debug=False),
            "ping": client.read("PING", debug=False),
            "written": client.write("RGSE_LOOPS", "42", debug=False),
            "read_back": client.read("RGSE_LOOPS", debug=False),
            "unknown": client.read("RGSE_NOT_DECLARED", debug=False),
            "string": client.write("$TRACE.NAME[]", '"m_0001"', debug=False),
        }
    finally:
        client.close()


async def test_py_openshowvar_reads_axes_and_writes_a_global(share) -> None:
    async with KrcServer(ServerConfig(), share) as srv:  # default latency, as a real KR C4
        srv.store.declare_global("RGSE_LOOPS", Kind.INT, "0")
        async with asyncio.timeout(30):
            got = await asyncio.to_thread(_session, srv.port)
    assert got["axis"] == e6axis((0.0, -90.0, 90.0, 0.0, 0.0, 0.0)).encode()
    assert got["axis"].startswith(b"{E6AXIS: A1 0.0, A2 -90.0, A3 90.0")
    assert got["ping"] == b"PONG"
    assert got["written"] == b"42" and got["read_back"] == b"42"
    assert got["unknown"] is None  # success 0: py-openshowvar returns None
    assert got["string"] == b'"m_0001"'
    assert srv.store.read("RGSE_LOOPS") == "42"
    assert srv.counters.by_type == {0: 4, 1: 2}
