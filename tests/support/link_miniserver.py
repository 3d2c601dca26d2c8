"""A tiny C3 Bridge / KVP server for the link's fault tests, built on the real codec over a real socket.

It serves #0/#1/#6/#14 from a dict and can misbehave on purpose: stall, drop the connection, send garbage,
answer with the wrong tag, or behave like plain KUKAVARPROXY (no @PROXY_TYPE, empty value with success 1).
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass, field

from rgse_daemon.errors import LinkClosed, ProtocolError
from rgse_daemon.link import frames as f


@dataclass
class MiniServer:
    variables: dict[str, str] = field(default_factory=lambda: {"$OV_PRO": "100", "$MODE_OP": "#T1"})
    kvp: bool = False
    fault: str | None = None  # None | "stall" | "drop" | "garbage" | "wrong_tag" | "wrong_type"
    fault_once: bool = True
    requests: list[f.Request] = field(default_factory=list)
    connections: int = 0
    port: int = 0
    _server: asyncio.Server | None = None
    _handlers: set[asyncio.Task] = field(default_factory=set)
    _writers: set[asyncio.StreamWriter] = field(default_factory=set)

    async def __aenter__(self) -> MiniServer:
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def stop(self) -> None:
        assert self._server is not None
        self._server.close()
        for w in list(self._writers):
            w.close()
        for t in list(self._handlers):
            t.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)
        await self._server.wait_closed()

    @property
    def open_connections(self) -> int:
        """Client connections the server still holds open (a handler ends when its client closes)."""
        return len(self._writers)

    def drop_all(self) -> None:
        for w in list(self._writers):
            w.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        self._writers.add(writer)
        self.connections += 1
        try:
            while True:
                raw = await f.read_frame(reader, responses=False)
                tag, req = f.decode_request(raw)
                self.requests.append(req)
                fault = self.fault
                if fault is not None and self.fault_once:
                    self.fault = None
                if fault == "stall":
                    await asyncio.sleep(3600)
                if fault == "drop":
                    return
                if fault == "garbage":
                    writer.write(b"\x00\x01\x00\x00\x06garbage")
                    await writer.drain()
                    continue
                rsp = self.answer(req)
                if fault == "wrong_tag":
                    tag ^= 0x5555
                if fault == "wrong_type":
                    rsp = f.ConfirmAllReply()
                writer.write(f.encode_response(tag, rsp))
                await writer.drain()
        except (LinkClosed, ProtocolError, ConnectionError):
            pass
        finally:
            self._writers.discard(writer)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
            self._handlers.discard(task)

    def _value(self, name: str) -> str | None:
        if name == "PING":
            return "PONG"
        if name == "@PROXY_TYPE" and not self.kvp:
            return "C3 BRIDGE INTERFACE"
        return self.variables.get(name)

    def answer(self, req: f.Request) -> f.Reply:
        match req:
            case f.ReadVarAscii(name=name):
                v = self._value(name)
                if v is None:  # KVP: empty value, success 1; C3: empty value, code 0, success 0
                    return f.ReadVarAsciiReply("", code=1, success=self.kvp)
                return f.ReadVarAsciiReply(v)
            case f.WriteVarAscii(name=name, value=value):
                if name not in self.variables:
                    return f.WriteVarAsciiReply("", code=0, success=False)
                self.variables[name] = value
                return f.WriteVarAsciiReply(value)
            case f.ReadMulti(names=names) if not self.kvp:
                entries = []
                for n in names:
                    v = self._value(n)
                    entries.append(f.MultiEntry(1, v) if v is not None else f.MultiEntry(0, ""))
                ok = all(e.ok for e in entries)
                return f.ReadMultiReply(tuple(entries), code=1 if ok else 0, success=ok)
            case f.ProxyFeatures() if not self.kvp:
                return f.ProxyFeaturesReply(frozenset({0, 1, 4, 5, 6, 7, 10, 13, 14}))
        return f.FailureReply(int(req.TYPE), b"", code=7, success=False)
