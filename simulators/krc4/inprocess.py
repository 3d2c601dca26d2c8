"""The simulated KR C4 without TCP: the daemon's :class:`~rgse_daemon.controller.Controller` on an in-process link.

For unit tests of the engine, the interlock and recovery. Only the operating system's socket is replaced, by an
in-memory byte pipe between the daemon's :class:`~rgse_daemon.link.connection.Connection` and the simulated server's
connection handler. Everything else is what runs over TCP, so the fake is exactly as rough as the TCP simulator:

* the server side is :class:`~simulators.krc4.server.KrcServer`'s own per-connection handler: requests of all clients
  served one at a time (one lock), ``latency_s`` each, file work taking bytes / ``file_rate_bytes_s`` while every
  other request waits, input queued while a request is served, the file buffers per connection, and every fault of
  ``server.faults`` (drops, stalls, garbage, wrong tags, refusals, extra latency);
* the daemon side is the real link: the frames are encoded and decoded, the pool, the connections with their
  deadlines (a stalled request is a ``LinkTimeout`` after ``request_timeout_s``), reconnection after a drop, the
  keep-alive, protocol detection and the C3 Bridge/KUKAVARPROXY switch of :class:`Controller`;
* bytes reach the other end on the next turn of the event loop, as from a socket, never inside the write.

What is not exercised here, and is over TCP in the end-to-end tests (``tests/sim_e2e``, ``tests/app``,
``tests/link``, ``tests/sim_server``, ``tests/faults``): the kernel's socket (connect, refused and reset
connections, partial sends), UDP discovery and the client limit of a listening server.

Usage::

    sim = SimulatedKrc4(share_dir, seed=7, time_scale=100.0, latency_s=0.0)   # not started: nothing listens
    async with in_process_controller(sim.server, cfg.controller) as krc:     # a Controller (KrcController)
        snap = await krc.snapshot()
    await sim.close()
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Any

from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.filelayout import FileLayout
from rgse_daemon.link.connection import Connection
from rgse_daemon.link.pool import LinkPool
from simulators.krc4.server import KrcServer, _Connection

#: What ``peername`` says on both ends of an in-process link.
PEER = ("in-process", 0)


class _Pipe(asyncio.Transport):
    """One end's transport of an in-memory byte stream: :meth:`write` hands the bytes to the other end's protocol on
    the next loop turn (in order, as a socket would); closing either end tells both protocols, once."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._loop = loop
        self.protocol: asyncio.Protocol | None = None  # this end's own protocol
        self.other: _Pipe | None = None
        self._closing = False
        self._lost = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing or self.other is None:
            return
        self._loop.call_soon(self.other._receive, bytes(data))

    def _receive(self, data: bytes) -> None:
        if not self._lost and self.protocol is not None:
            self.protocol.data_received(data)

    def get_write_buffer_size(self) -> int:
        return 0  # delivered on the next loop turn: nothing is ever left unsent

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        for end in (self, self.other):
            if end is not None and not end._closing:
                end._closing = True
                self._loop.call_soon(end._connection_lost)  # after the bytes already on their way

    def abort(self) -> None:
        self.close()

    def _connection_lost(self) -> None:
        if not self._lost and self.protocol is not None:
            self._lost = True
            self.protocol.connection_lost(None)

    def can_write_eof(self) -> bool:
        return False

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return PEER if name == "peername" else default

    def is_reading(self) -> bool:
        return not self._closing

    def pause_reading(self) -> None:
        """Flow control is a no-op here: the pipe hands each reply over whole, and one reply stays far below the
        stream reader's buffer limit, so there is nothing to hold back."""

    def resume_reading(self) -> None:
        """The other half of :meth:`pause_reading`: nothing was held back, so nothing resumes."""


def open_pipe(server: KrcServer) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """A client's stream to ``server``'s connection handler, as :func:`asyncio.open_connection` gives one over TCP."""
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader(loop=loop)
    client = asyncio.StreamReaderProtocol(reader, loop=loop)
    client_end, server_end = _Pipe(loop), _Pipe(loop)
    client_end.other, server_end.other = server_end, client_end
    handler = _Connection(server)
    client_end.protocol, server_end.protocol = client, handler
    handler.connection_made(server_end)
    client.connection_made(client_end)
    return reader, asyncio.StreamWriter(client_end, client, reader, loop)


class InProcessConnection(Connection):
    """A link :class:`Connection` whose byte stream is :func:`open_pipe` to ``server`` instead of a TCP socket."""

    server: KrcServer

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self.server.closed:
            raise ConnectionRefusedError(f"the simulated KR C4 {PEER[0]} is closed")
        return open_pipe(self.server)

    @classmethod
    def to(cls, server: KrcServer, cfg: ControllerConfig, *, name: str = "link", **kw: Any) -> InProcessConnection:
        conn = cls.from_config(cfg, name=name, **kw)
        assert isinstance(conn, InProcessConnection)
        conn.server = server
        return conn


class InProcessPool(LinkPool):
    """The daemon's :class:`LinkPool` (``cfg.pool_size`` connections, protocol detection, multi-reads) over
    :class:`InProcessConnection`."""

    def __init__(self, cfg: ControllerConfig, server: KrcServer, *, seed: int | None = None) -> None:
        super().__init__(cfg, seed=seed)
        self._conns = [
            InProcessConnection.to(server, cfg, name=f"link{i}", seed=None if seed is None else seed + i,
                                   load=self.load)
            for i in range(cfg.pool_size)
        ]
        self._idle = asyncio.Queue()
        for c in self._conns:
            self._idle.put_nowait(c)


@contextlib.asynccontextmanager
async def in_process_controller(server: KrcServer, cfg: ControllerConfig, *, seed: int | None = None,
                                layout: FileLayout | None = None) -> AsyncIterator[Controller]:
    """:meth:`Controller.connect` without TCP: the controller on an :class:`InProcessPool` to ``server``
    (``cfg.host``/``port`` are not used; every other setting is)."""
    pool = InProcessPool(cfg, server, seed=seed)
    await pool.start()  # a closed server: LinkClosed, as a refused TCP connect
    try:
        yield Controller(cfg, pool, layout)
    finally:
        await pool.close()
