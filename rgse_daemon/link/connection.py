"""One TCP connection to a KR C4 variable server (C3 Bridge or KUKAVARPROXY), with one request in flight.

Why one request in flight: C3 Bridge *discards* bytes that arrive while it is still sending a reply, and
KUKAVARPROXY serves requests one at a time (``docs/protocol.md`` §3, ``docs/controller.md`` §3). Concurrency comes
from several connections (:mod:`rgse_daemon.link.pool`) and from multi-read (#6).

Failure handling: every exchange has a deadline (``request_timeout_s``). After a timeout, a protocol error, a
tag or type mismatch, a peer close, or a caller cancelled mid-request, the socket is dropped — a late reply
would otherwise be matched to the next request — and the next request (or the background maintainer) opens a
new one. Failed connects back off exponentially with jitter between ``reconnect_min_s`` and
``reconnect_max_s``. While idle the maintainer reads ``PING`` every ``keepalive_s`` (< 30 s, KVP's idle drop).

Public API::

    conn = Connection(host, port, connect_timeout_s=3, request_timeout_s=2, keepalive_s=10)  # or .from_config(cfg)
    await conn.start()                  # first connect (raises LinkClosed/LinkTimeout), starts the keep-alive
    rsp = await conn.request(ReadMulti(("$OV_PRO",)))   # any frames.Request -> frames.Reply, footer unchecked
    value = await conn.read_var("$OV_PRO")              # #0; VariableError on failure or an empty value
    echoed = await conn.write_var("$OV_PRO", "35")      # #1; VariableError on failure
    conn.state, conn.stats.as_dict()
    await conn.close()
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import random
import socket
import time
from bisect import bisect_left
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from rgse_daemon.config import ControllerConfig
from rgse_daemon.errors import LinkClosed, LinkError, LinkTimeout, ProtocolError, VariableError
from rgse_daemon.link.frames import (
    FailureReply,
    ReadVarAscii,
    ReadVarAsciiReply,
    Reply,
    Request,
    WriteVarAscii,
    WriteVarAsciiReply,
    decode_response,
    encode_request,
    read_frame,
)

log = logging.getLogger(__name__)

#: Upper edges of the latency histogram buckets in milliseconds; the last bucket is everything above.
LATENCY_BUCKETS_MS: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0)


class ServerLoad:
    """File work in flight on one controller. The real C3 Bridge server does file work on its one thread, so every
    other request, on every connection, waits behind it (docs/protocol.md §3). Each file operation registers
    the end of its own deadline here; a request sent meanwhile gets that much more time (:meth:`busy_until`), so a
    keep-alive or a status read queued behind a long pull is late, not lost."""

    def __init__(self) -> None:
        self._ends: dict[int, float] = {}
        self._ids = itertools.count()

    @contextlib.contextmanager
    def file_work(self, deadline_s: float) -> Iterator[None]:
        """Mark a file operation in flight whose deadline is ``deadline_s`` from now."""
        key = next(self._ids)
        self._ends[key] = time.monotonic() + deadline_s
        try:
            yield
        finally:
            del self._ends[key]

    def busy_until(self) -> float:
        """Monotonic time by which the file work in flight must have ended (its deadlines); 0.0 if none."""
        return max(self._ends.values(), default=0.0)

    def pending_s(self) -> float:
        """Seconds a request sent now may have to wait behind file work in flight."""
        return max(0.0, self.busy_until() - time.monotonic())


class ConnectionState(Enum):
    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    CONNECTED = "connected"
    BACKOFF = "backoff"  # the last connect failed; the next attempt waits
    CLOSED = "closed"  # close() was called; final


@dataclass
class LinkStats:
    """Counters of one connection (or the sum over a pool): published as link health, never reset silently."""

    requests: int = 0
    replies: int = 0
    timeouts: int = 0
    errors: int = 0  # protocol errors, peer closes, socket errors, cancelled exchanges
    connects: int = 0
    connect_failures: int = 0
    reconnects: int = 0  # successful connects after the first
    keepalives: int = 0
    latency_counts: list[int] = field(default_factory=lambda: [0] * (len(LATENCY_BUCKETS_MS) + 1))

    def observe_latency(self, latency_s: float) -> None:
        self.latency_counts[bisect_left(LATENCY_BUCKETS_MS, latency_s * 1000.0)] += 1

    def add(self, other: LinkStats) -> None:
        for name in ("requests", "replies", "timeouts", "errors", "connects", "connect_failures", "reconnects"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.keepalives += other.keepalives
        self.latency_counts = [a + b for a, b in zip(self.latency_counts, other.latency_counts, strict=True)]

    def as_dict(self) -> dict[str, Any]:
        edges = [f"le_{b:g}ms" for b in LATENCY_BUCKETS_MS] + ["gt_2000ms"]
        return {
            "requests": self.requests,
            "replies": self.replies,
            "timeouts": self.timeouts,
            "errors": self.errors,
            "connects": self.connects,
            "connect_failures": self.connect_failures,
            "reconnects": self.reconnects,
            "keepalives": self.keepalives,
            "latency_histogram": dict(zip(edges, self.latency_counts, strict=True)),
        }


class Connection:
    """One long-lived TCP connection with exactly one request in flight; see the module docstring."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        connect_timeout_s: float = 3.0,
        request_timeout_s: float = 2.0,
        keepalive_s: float = 10.0,
        reconnect_min_s: float = 0.2,
        reconnect_max_s: float = 10.0,
        name: str = "link",
        seed: int | None = None,
        load: ServerLoad | None = None,
    ) -> None:
        if not (0 < reconnect_min_s <= reconnect_max_s):
            raise ValueError("need 0 < reconnect_min_s <= reconnect_max_s")
        self.host = host
        self.port = port
        self.connect_timeout_s = connect_timeout_s
        self.request_timeout_s = request_timeout_s
        self.keepalive_s = keepalive_s
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.name = name
        self.load = load if load is not None else ServerLoad()
        self.stats = LinkStats()
        self._state = ConnectionState.DISCONNECTED
        self._rng = random.Random(seed)
        self._tags = itertools.cycle(range(0x10000))
        for _ in range(self._rng.randrange(0x10000)):
            next(self._tags)
        self._lock = asyncio.Lock()
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._failures = 0  # consecutive failed connects
        self._next_attempt = 0.0  # monotonic time before which no connect is tried
        self._last_used = time.monotonic()
        self._last_error: str | None = None
        self._maintainer: asyncio.Task[None] | None = None
        self._wake = asyncio.Event()  # set on a drop, so the maintainer reconnects at once

    @classmethod
    def from_config(
        cls, cfg: ControllerConfig, *, name: str = "link", seed: int | None = None, load: ServerLoad | None = None
    ) -> Connection:
        return cls(
            cfg.host,
            cfg.port,
            connect_timeout_s=cfg.connect_timeout_s,
            request_timeout_s=cfg.request_timeout_s,
            keepalive_s=cfg.keepalive_s,
            reconnect_min_s=cfg.reconnect_min_s,
            reconnect_max_s=cfg.reconnect_max_s,
            name=name,
            seed=seed,
            load=load,
        )

    # --- lifecycle ----------------------------------------------------------------------------------------------
    @property
    def state(self) -> ConnectionState:
        return self._state

    @property
    def last_error(self) -> str | None:
        """The reason of the last drop or failed connect, for health reports."""
        return self._last_error

    async def start(self) -> None:
        """Connect now (errors propagate) and start the keep-alive/reconnect maintainer."""
        async with self._lock:
            await self._ensure_connected()
        if self._maintainer is None:
            self._maintainer = asyncio.create_task(self._maintain(), name=f"{self.name}-maintainer")

    async def close(self) -> None:
        """Stop the maintainer and close the socket; every later request raises ``LinkClosed``, and so does one still
        connecting (close() does not wait for the lock): its new socket is closed, not kept."""
        self._state = ConnectionState.CLOSED
        task, self._maintainer = self._maintainer, None
        if task is not None:
            task.cancel()
            await asyncio.wait({task})  # not `await task`: a cancel of close() itself must still propagate
            if not task.cancelled() and task.exception() is not None:
                log.warning("%s: keep-alive task had failed: %r", self.name, task.exception())
        self._drop_socket()

    async def __aenter__(self) -> Connection:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- requests -----------------------------------------------------------------------------------------------
    async def request(self, req: Request, *, timeout_s: float | None = None, file_work: bool = False) -> Reply:
        """Send ``req``, wait for its reply (same tag, same type) and return it; the footer is not judged here.

        ``timeout_s`` (default ``request_timeout_s``) is the request's own deadline; file work already in flight on
        the server (:class:`ServerLoad`) adds its remaining time. ``file_work`` marks ``req`` itself as file work
        (a #30 Begin, a #29 End: the caller sizes ``timeout_s`` by the bytes), so that others wait for it.

        Raises ``LinkTimeout`` (no whole reply within the deadline), ``LinkClosed`` (no connection, peer
        closed), ``ProtocolError`` (malformed reply, tag or type mismatch). On each of these, and on
        cancellation, the socket is dropped.
        """
        async with self._lock:
            own_s = self.request_timeout_s if timeout_s is None else timeout_s
            deadline_s = own_s + self.load.pending_s()
            if not file_work:
                return await self._exchange(req, deadline_s)
            with self.load.file_work(deadline_s):
                return await self._exchange(req, deadline_s)

    async def read_var(self, name: str, *, timeout_s: float | None = None) -> str:
        """Read one variable with #0 (understood by KVP and C3 Bridge); returns the raw KRL value text."""
        rsp = await self.request(ReadVarAscii(name), timeout_s=timeout_s)
        assert isinstance(rsp, ReadVarAsciiReply | FailureReply)
        value = getattr(rsp, "value", "")
        if not rsp.success:
            raise VariableError(name, f"read refused (code {rsp.code})", rsp.code)
        if value == "":  # KVP may answer an unknown name with an empty value and success 1 (docs/controller.md §3)
            raise VariableError(name, "read returned an empty value", rsp.code)
        return value

    async def write_var(self, name: str, value: str, *, timeout_s: float | None = None) -> str:
        """Write one variable with #1; returns the value the server echoes."""
        rsp = await self.request(WriteVarAscii(name, value), timeout_s=timeout_s)
        assert isinstance(rsp, WriteVarAsciiReply | FailureReply)
        echoed = getattr(rsp, "value", "")
        if not rsp.success:
            raise VariableError(name, f"write of {value[:60]!r} refused (code {rsp.code})", rsp.code)
        if echoed == "":
            raise VariableError(name, f"write of {value[:60]!r} answered with an empty value", rsp.code)
        return echoed

    async def _exchange(self, req: Request, timeout_s: float) -> Reply:
        await self._ensure_connected(wait_limit_s=timeout_s)
        if self._reader is not None and self._reader.at_eof():
            # The peer closed while we were idle; nothing was sent yet, so reconnecting is safe for any request.
            self._drop("peer closed the idle connection")
            await self._ensure_connected(wait_limit_s=timeout_s)
        reader, writer = self._reader, self._writer
        assert reader is not None and writer is not None
        tag = next(self._tags)
        frame = encode_request(tag, req)
        self.stats.requests += 1
        t0 = time.monotonic()
        received = _Received(reader)
        try:
            async with asyncio.timeout(timeout_s):
                writer.write(frame)
                await writer.drain()
                raw = await read_frame(received, responses=True)  # type: ignore[arg-type]
            got_tag, rsp = decode_response(raw)
            if got_tag != tag:
                raise ProtocolError(f"reply tag {got_tag:#06x} does not match request tag {tag:#06x}")
            got_type = rsp.msg_type if isinstance(rsp, FailureReply) else rsp.TYPE
            if got_type != req.TYPE:
                raise ProtocolError(f"reply type {got_type} to a request of type {int(req.TYPE)}")
        except TimeoutError as exc:
            self.stats.timeouts += 1
            if received.count:  # bytes came, but no whole frame: the cause is what came, not silence
                self.stats.errors += 1
                problem = (f"{received.count} bytes received in reply to message type {int(req.TYPE)} "
                           f"({received.head()}) do not form a complete frame within {timeout_s} s: garbage on the "
                           "line, or not a C3 Bridge/KUKAVARPROXY server")
                self._drop(problem)
                raise ProtocolError(f"{self.name}: {problem}") from exc
            self._drop(f"no reply to type {int(req.TYPE)} within {timeout_s} s")
            raise LinkTimeout(f"{self.name}: no reply to message type {int(req.TYPE)} within {timeout_s} s") from exc
        except ProtocolError as exc:
            self.stats.errors += 1
            self._drop(f"protocol error: {exc}")
            raise
        except LinkClosed as exc:
            self.stats.errors += 1
            self._drop(str(exc))
            raise LinkClosed(f"{self.name}: {exc}") from exc
        except OSError as exc:
            self.stats.errors += 1
            self._drop(f"socket error: {exc}")
            raise LinkClosed(f"{self.name}: socket error: {exc}") from exc
        except BaseException:
            # Cancelled mid-request: the reply may still arrive and would desynchronise the stream.
            self.stats.errors += 1
            self._drop("request cancelled mid-exchange")
            raise
        latency_s = time.monotonic() - t0
        self.stats.replies += 1
        self.stats.observe_latency(latency_s)
        self._last_used = time.monotonic()
        return rsp

    # --- connecting ---------------------------------------------------------------------------------------------
    def _backoff_s(self) -> float:
        base = min(self.reconnect_max_s, self.reconnect_min_s * 2 ** max(0, self._failures - 1))
        return base * self._rng.uniform(0.5, 1.0)

    async def _ensure_connected(self, wait_limit_s: float | None = None) -> None:
        """Connect if needed; called with the lock held. Honours the backoff after failed attempts.

        A caller waits for the backoff only if it ends within ``wait_limit_s``; otherwise ``LinkClosed``.
        """
        if self._state is ConnectionState.CLOSED:
            raise LinkClosed(f"{self.name}: connection closed")
        if self._state is ConnectionState.CONNECTED:
            return
        wait_s = self._next_attempt - time.monotonic()
        if wait_s > 0:
            if wait_limit_s is not None and wait_s > wait_limit_s:
                raise LinkClosed(f"{self.name}: not connected ({self._last_error}); next attempt in {wait_s:.2f} s")
            await asyncio.sleep(wait_s)
            if self._state is ConnectionState.CLOSED:  # closed while this caller waited out the backoff
                raise LinkClosed(f"{self.name}: connection closed")
        self._state = ConnectionState.CONNECTING
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                reader, writer = await self._open()
        except (TimeoutError, OSError) as exc:
            self._failures += 1
            self.stats.connect_failures += 1
            self._next_attempt = time.monotonic() + self._backoff_s()
            if self._state is not ConnectionState.CLOSED:
                self._state = ConnectionState.BACKOFF
            what = "timed out" if isinstance(exc, TimeoutError) else str(exc)
            self._last_error = f"connect to {self.host}:{self.port} failed: {what}"
            if isinstance(exc, TimeoutError):
                raise LinkTimeout(f"{self.name}: {self._last_error}") from exc
            raise LinkClosed(f"{self.name}: {self._last_error}") from exc
        except BaseException:
            if self._state is not ConnectionState.CLOSED:
                self._state = ConnectionState.DISCONNECTED
            raise
        if self._state is ConnectionState.CLOSED:
            # close() does not wait for the lock, so it can run while this connect is in flight. Keeping the new
            # socket would bring the closed connection back to life with a socket that nobody ever closes: it stays
            # open until the garbage collector finds its writer (a ResourceWarning "unclosed <StreamWriter>").
            writer.close()
            raise LinkClosed(f"{self.name}: connection closed while it was connecting")
        sock = writer.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._reader, self._writer = reader, writer
        self._state = ConnectionState.CONNECTED
        if self.stats.connects > 0:
            self.stats.reconnects += 1
        self.stats.connects += 1
        self._failures = 0
        self._next_attempt = 0.0
        self._last_used = time.monotonic()
        log.debug("%s: connected to %s:%s", self.name, self.host, self.port)

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """The byte stream to the server: a TCP connection to ``host``:``port`` (the tests' in-process link to the
        simulated KR C4 replaces only this, ``simulators/krc4/inprocess.py``)."""
        return await asyncio.open_connection(self.host, self.port)

    def _drop(self, reason: str) -> None:
        if self._last_error != reason:
            log.warning("%s: dropping connection: %s", self.name, reason)
        self._last_error = reason
        self._drop_socket()
        if self._state is not ConnectionState.CLOSED:
            self._state = ConnectionState.DISCONNECTED
        self._wake.set()

    def _drop_socket(self) -> None:
        writer, self._writer, self._reader = self._writer, None, None
        if writer is not None:
            writer.close()

    # --- keep-alive and healing ---------------------------------------------------------------------------------
    async def _maintain(self) -> None:
        """Ping while idle; reconnect (with backoff) while disconnected. Errors are counted, never raised."""
        while self._state is not ConnectionState.CLOSED:
            if self._state is ConnectionState.CONNECTED:
                idle_s = time.monotonic() - self._last_used
                if idle_s < self.keepalive_s:
                    self._wake.clear()
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(self.keepalive_s - idle_s):
                            await self._wake.wait()
                    continue
                try:
                    async with self._lock:
                        if self._state is ConnectionState.CONNECTED and (
                            time.monotonic() - self._last_used >= self.keepalive_s
                        ):
                            self.stats.keepalives += 1  # behind file work in flight: late, not lost
                            await self._exchange(ReadVarAscii("PING"), self.request_timeout_s + self.load.pending_s())
                except LinkError:
                    pass  # counted and dropped in _exchange; the next loop reconnects
            else:
                wait_s = max(self._next_attempt - time.monotonic(), 0.0)
                await asyncio.sleep(max(wait_s, self.reconnect_min_s))
                try:
                    async with self._lock:
                        if self._state in (ConnectionState.DISCONNECTED, ConnectionState.BACKOFF):
                            await self._ensure_connected()
                except LinkError:
                    pass  # counted in stats.connect_failures; backoff grows


class _Received:
    """The reply's stream, counting what arrived (also the part of a frame still awaited), so that a deadline
    reached after garbage names the garbage instead of "no reply"."""

    def __init__(self, reader: asyncio.StreamReader) -> None:
        self._reader = reader
        self._seen = bytearray()

    async def readexactly(self, n: int) -> bytes:
        data = await self._reader.readexactly(n)
        self._seen += data
        return data

    def _waiting(self) -> bytes:
        return bytes(getattr(self._reader, "_buffer", b""))  # bytes of an unfinished readexactly (CPython)

    @property
    def count(self) -> int:
        return len(self._seen) + len(self._waiting())

    def head(self) -> str:
        first = (bytes(self._seen) + self._waiting())[:16]
        return "first bytes " + first.hex(" ") + (" …" if self.count > 16 else "")
