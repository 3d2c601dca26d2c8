"""A small pool of :class:`~rgse_daemon.link.connection.Connection` objects, plus protocol detection.

Why a pool: each connection carries one request at a time, so reading many variables concurrently needs
several connections (KUKAVARPROXY allows at most 10 clients, hence ``pool_size`` ≤ 10). With C3 Bridge a whole
snapshot is *one* multi-read (#6, ≤ 255 names) on one connection instead.

Protocol detection (``protocol = auto``): read ``@PROXY_TYPE`` with #0. C3 Bridge answers
``C3 BRIDGE INTERFACE``; KUKAVARPROXY has no such variable and answers with an empty value or a failure. With
C3 Bridge the feature bitmap (#14) then says which message types the server implements (#6 needs 1.2.0).

Public API::

    pool = LinkPool(cfg)                        # cfg: ControllerConfig
    await pool.start()                          # connects one connection, detects the protocol
    pool.protocol                               # Protocol.C3BRIDGE or Protocol.KVP
    await pool.read("$OV_PRO") -> str           # #0 on any free connection; VariableError / LinkError
    await pool.write("$OV_PRO", "35") -> str    # #1; returns the echoed value
    await pool.read_many(names) -> dict[str, str | VariableError]   # one #6 (C3) or #0s spread over the pool
    async with pool.connection() as conn: ...   # hold one connection for a sequence (file ops: per-connection buffers)
    await pool.request(req) -> Reply            # any frames.Request on a free connection
    pool.stats() -> LinkStats; pool.health() -> dict
    await pool.close()
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Sequence

from rgse_daemon.config import ControllerConfig, Protocol
from rgse_daemon.errors import LinkClosed, LinkError, LinkTimeout, ProtocolError, VariableError
from rgse_daemon.link.connection import Connection, ConnectionState, LinkStats, ServerLoad
from rgse_daemon.link.frames import (
    MAX_MULTI,
    ErrorCode,
    MsgType,
    ProxyFeatures,
    ProxyFeaturesReply,
    ReadMulti,
    ReadMultiReply,
    Reply,
    Request,
)

C3_PROXY_TYPE = "C3 BRIDGE INTERFACE"
#: Rough per-entry budget of a #6 reply: a reply may hold at most 65531 payload bytes ([src]); split the names
#: into chunks whose expected reply stays well below that. Long values (E6POS) are ~300 UTF-16 units.
_MULTI_REPLY_BUDGET_BYTES = 60000


class LinkPool:
    """Up to ``cfg.pool_size`` connections to one controller; see the module docstring."""

    def __init__(self, cfg: ControllerConfig, *, seed: int | None = None, load: ServerLoad | None = None) -> None:
        self.cfg = cfg
        # one controller, one single-threaded server: shared by every connection (``load``: also by connections
        # outside the pool, the heartbeat's)
        self.load = ServerLoad() if load is None else load
        self._conns = [
            Connection.from_config(cfg, name=f"link{i}", seed=None if seed is None else seed + i, load=self.load)
            for i in range(cfg.pool_size)
        ]
        self._idle: asyncio.Queue[Connection] = asyncio.Queue()
        for c in self._conns:
            self._idle.put_nowait(c)
        self.protocol: Protocol = Protocol(cfg.protocol)
        self.features: frozenset[int] = frozenset()
        self.proxy_type: str | None = None
        self._started = False
        self._closed = False

    # --- lifecycle ----------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Connect the first connection (errors propagate), detect the protocol, start the others' maintainers.

        The other connections open lazily on first use, or when their maintainer gets to them.
        """
        first = self._conns[0]
        await first.start()
        try:
            await self._detect(first)
            for c in self._conns[1:]:
                with contextlib.suppress(LinkError):
                    await c.start()
        except BaseException:
            await self.close()
            raise
        self._started = True

    async def close(self) -> None:
        self._closed = True
        for c in self._conns:
            await c.close()

    async def __aenter__(self) -> LinkPool:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _detect(self, conn: Connection) -> None:
        if Protocol(self.cfg.protocol) is Protocol.KVP:
            self.protocol = Protocol.KVP
            return
        try:
            self.proxy_type = await conn.read_var("@PROXY_TYPE")
        except VariableError:
            self.proxy_type = None
        is_c3 = self.proxy_type is not None and self.proxy_type.strip().strip('"') == C3_PROXY_TYPE
        if Protocol(self.cfg.protocol) is Protocol.C3BRIDGE and not is_c3:
            raise ProtocolError(f"configured for C3 Bridge, but @PROXY_TYPE reads {self.proxy_type!r}")
        if not is_c3:
            self.protocol = Protocol.KVP
            return
        self.protocol = Protocol.C3BRIDGE
        rsp = await conn.request(ProxyFeatures())
        if isinstance(rsp, ProxyFeaturesReply) and rsp.success:
            self.features = rsp.types
        else:  # a 1.0/1.1 server without #14: assume the base set it must have
            self.features = frozenset({MsgType.READ_VAR_ASCII, MsgType.WRITE_VAR_ASCII})

    # --- connection access --------------------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def connection(self) -> AsyncIterator[Connection]:
        """Hold one connection exclusively (a file transfer keeps its buffer on one connection)."""
        if self._closed:
            raise LinkClosed("link pool is closed")
        try:
            wait_s = self.cfg.connect_timeout_s + self.cfg.request_timeout_s * len(self._conns) + self.load.pending_s()
            async with asyncio.timeout(wait_s):
                conn = await self._idle.get()
        except TimeoutError as exc:
            raise LinkTimeout("no free connection in the link pool") from exc
        try:
            yield conn
        finally:
            self._idle.put_nowait(conn)

    def supports(self, msg_type: MsgType) -> bool:
        return self.protocol is Protocol.C3BRIDGE and int(msg_type) in self.features

    async def request(self, req: Request, *, timeout_s: float | None = None) -> Reply:
        async with self.connection() as conn:
            return await conn.request(req, timeout_s=timeout_s)

    async def read(self, name: str) -> str:
        """Read one variable (#0). One retry on a fresh connection if the peer had closed the old one."""
        async with self.connection() as conn:
            try:
                return await conn.read_var(name)
            except LinkClosed:
                if conn.state is ConnectionState.CLOSED:
                    raise
                return await conn.read_var(name)

    async def write(self, name: str, value: str) -> str:
        """Write one variable (#1), no retry (the first attempt may have reached the controller)."""
        async with self.connection() as conn:
            return await conn.write_var(name, value)

    async def read_many(self, names: Sequence[str]) -> dict[str, str | VariableError]:
        """Read many variables; each name maps to its value text or to the ``VariableError`` that refused it.

        Link failures (timeout, closed, protocol) raise. C3 Bridge: one #6 per ≤ 255 names (chunked further if
        the reply would be too long); KVP: concurrent #0 reads spread over the pool.
        """
        unique = list(dict.fromkeys(names))
        if not unique:
            return {}
        if self.supports(MsgType.READ_MULTI):
            return await self._read_multi(unique)
        results = await asyncio.gather(*(self._read_one_captured(n) for n in unique), return_exceptions=True)
        out: dict[str, str | VariableError] = {}
        for name, res in zip(unique, results, strict=True):
            if isinstance(res, BaseException):
                raise res
            out[name] = res
        return out

    async def _read_one_captured(self, name: str) -> str | VariableError:
        try:
            return await self.read(name)
        except VariableError as exc:
            return exc

    async def _read_multi(self, names: list[str]) -> dict[str, str | VariableError]:
        out: dict[str, str | VariableError] = {}
        for chunk in _chunks(names):
            await self._read_multi_chunk(chunk, out)
        return out

    async def _read_multi_chunk(self, chunk: list[str], out: dict[str, str | VariableError]) -> None:
        rsp = await self.request(ReadMulti(tuple(chunk)))
        if not isinstance(rsp, ReadMultiReply):
            raise ProtocolError(f"multi-read of {len(chunk)} names answered without entries (code {rsp.code})")
        if rsp.code == ErrorCode.LONG_ANSWER and not rsp.entries and len(chunk) > 1:
            half = len(chunk) // 2
            await self._read_multi_chunk(chunk[:half], out)
            await self._read_multi_chunk(chunk[half:], out)
            return
        if len(rsp.entries) != len(chunk):
            raise ProtocolError(
                f"multi-read of {len(chunk)} names answered with {len(rsp.entries)} entries (code {rsp.code})"
            )
        for name, entry in zip(chunk, rsp.entries, strict=True):
            if not entry.ok:
                out[name] = VariableError(name, f"read refused (code {entry.code})", entry.code)
            elif entry.value == "":
                out[name] = VariableError(name, "read returned an empty value", entry.code)
            else:
                out[name] = entry.value

    # --- health -------------------------------------------------------------------------------------------------
    def stats(self) -> LinkStats:
        total = LinkStats()
        for c in self._conns:
            total.add(c.stats)
        return total

    def health(self) -> dict[str, object]:
        return {
            "protocol": self.protocol.value,
            "proxy_type": self.proxy_type,
            "connections": {c.name: c.state.value for c in self._conns},
            "last_errors": {c.name: c.last_error for c in self._conns if c.last_error},
            **self.stats().as_dict(),
        }


def _chunks(names: list[str]) -> list[list[str]]:
    chunks: list[list[str]] = []
    cur: list[str] = []
    budget = 0
    for n in names:
        cost = 3 + 2 * 300  # entry code + length + a long value
        if cur and (len(cur) >= MAX_MULTI or budget + cost > _MULTI_REPLY_BUDGET_BYTES):
            chunks.append(cur)
            cur, budget = [], 0
        cur.append(n)
        budget += cost
    if cur:
        chunks.append(cur)
    return chunks
