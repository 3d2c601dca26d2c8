"""The simulated KR C4's network face: a C3 Bridge Interface server on TCP that a KUKAVARPROXY client can use unchanged.

It speaks the frames of ``rgse_daemon.link.frames`` (docs/protocol.md) over the :class:`VariableStore`, the
:class:`ProgramHost` and the share directory (:mod:`simulators.krc4.files`), and reproduces the behaviour of the
real servers that a client has to live with (docs/controller.md §3, docs/protocol.md §3):

* requests are **serialised across all clients** (one lock: the real server is single-threaded) and each one
  takes ``latency_s`` (≈ 2 ms on a real KR C4);
* **file work takes time in proportion to its bytes** and blocks every other request meanwhile: a #30 Begin loads
  the whole file (``CopyFile2Mem``) before it answers, a #29 End writes the whole buffer (``CopyMem2File``), a
  #24/#25 copy or move reads and writes the file, all at ``file_rate_bytes_s`` (default
  :data:`DEFAULT_FILE_RATE_BYTES_S`, a conservative guess: the real rate is unknown and measured by ``rgse doctor``);
* requests pipelined on one connection are **queued and answered in order**; input is discarded only while a
  reply's send is incomplete (the transport still holds unsent reply bytes), as the real ``client.cpp`` does
  (``discard_while_busy`` restores the stricter old model, where everything arriving while busy is dropped);
* writes (#1, #5, #7) echo **the value text of the request**, not a read-back; ``PING`` and ``@PROXY_*`` are matched
  **exact-case**; the version is **1.4**; #11 (motion) and #12 (KCP keys) are answered (refused with code 7: this
  simulator never moves the robot on a protocol command), not closed;
* an unknown message type or a length of 0 closes the connection without a reply; #0/#1 with a malformed body
  fail with code 0 and an empty value, other malformed requests get code 9; trailing bytes after a well-formed
  body are ignored;
* the variants that the public source does not settle (docs/protocol.md §3: listing info text, accepted path
  forms) are switched by ``listing`` and ``path_forms`` (see :data:`LISTING_VARIANTS`, :data:`PATH_FORM_VARIANTS`;
  defaults from the environment variables ``RGSE_SIM_LISTING`` / ``RGSE_SIM_PATHS``, so a whole test suite can be
  run against each variant);
* UDP discovery in standard mode (``udp_port``: reply to the sender's port) and legacy mode (``legacy_udp_port``,
  KUKAVARPROXY's 6999: reply to the sender's address on ``legacy_reply_port``, 7000);
* connections are not limited by default and never dropped for idleness (C3 Bridge's ``settings.h``); the
  KUKAVARPROXY limits (``max_clients`` 10, ``idle_timeout_s`` ~30 s) can be switched on.

Faults for tests are set at runtime on ``server.faults`` (see :class:`Faults`); what happened is counted in
``server.counters`` (see :class:`Counters`).

Usage::

    async with KrcServer(ServerConfig(latency_s=0.0), share_dir, store=store) as srv:
        ...  # connect to ("127.0.0.1", srv.port)
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import logging
import os
import re
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Coroutine, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rgse_daemon.errors import ConfigError, ProtocolError, VariableError
from rgse_daemon.link import frames as fr
from simulators.krc4.files import (
    LISTING_VARIANTS,
    MAX_BUFFER_BYTES,
    PATH_FORM_VARIANTS,
    FileOpError,
    FileSession,
    ShareFiles,
)
from simulators.krc4.variables import (
    ProgramControlError,
    ProgramHost,
    StateOnlyProgramHost,
    VariableStore,
    normalize_name,
)

log = logging.getLogger(__name__)

PROXY_TYPE = "C3 BRIDGE INTERFACE"
_BUILD_NAMES = {0: "OPEN SOURCE", 1: "PROPRIETARY", 2: "FREEWARE", 3: "INTERNAL BUILD"}
#: Message types this server answers; every other type closes the connection (as the real server does for types
#: it has no handler for). #11/#12 (motion, KCP keys) are answered with code 7 and move nothing.
HANDLED_TYPES: frozenset[int] = frozenset({0, 1, 4, 5, 6, 7, 10, 11, 12, 13, 14, 17, *range(20, 31), 63})
#: Motion (#11) and KCP keys (#12): answered with the echoed subtype byte and code 7, never executed here.
MSG_MOTION = 11
MSG_KCP_KEYS = 12
#: Bytes per second of the controller's file work (Cross3 ``CopyFile2Mem``/``CopyMem2File``) unless configured: a
#: conservative guess (no measurement of a real KR C4 is public); ``rgse doctor`` measures the real one.
DEFAULT_FILE_RATE_BYTES_S = 100_000.0
#: Time of one NameList / GetProperties / Delete / Create on the controller's file system (s), besides latency_s.
FILE_META_S = 0.005
#: Where a legacy-mode discovery answer goes (KUKAVARPROXY's clients listen there).
LEGACY_REPLY_PORT = 7000
#: [src] a response payload is at most 65531 bytes; longer multi-variable replies get code 10.
MAX_REPLY_PAYLOAD = 65531
#: A deterministic reply that is no frame at all (type 0xFF, length 0), sent by the ``garbage_next`` fault.
GARBAGE_REPLY = b"\xde\xad\x00\x00\xffGARBAGE!"
_ERR = fr.ErrorCode


@dataclass
class ServerConfig:
    """How the simulated server behaves. Times in seconds; ``None`` disables a timeout.

    Attributes
    ----------
    host, port:
        Where to listen; port 0 picks a free port (read it back from ``KrcServer.port``).
    max_clients:
        Connections beyond this many are closed at once (``None``: no limit, as C3 Bridge; KUKAVARPROXY: 10).
    idle_timeout_s:
        A connection that sends nothing for this long is dropped (``None``: never, as C3 Bridge; KUKAVARPROXY ~30 s).
    latency_s:
        Service time of every request; requests of all clients are served one at a time.
    discard_while_busy:
        Drop every byte that arrives on a connection while its request is being served (an older, stricter model).
        When false (the real server), such requests are queued and answered in order; only input that arrives
        while a reply's send is incomplete is dropped.
    file_rate_bytes_s:
        Speed of the controller's file work: a #30 Begin takes size / rate before it answers, and so on.
    listing:
        #21's answer format, one of :data:`LISTING_VARIANTS`.
    path_forms:
        Which path forms the file messages accept, one of :data:`PATH_FORM_VARIANTS`.
    version:
        (major, minor, build type) as reported by #13 and ``@PROXY_VERSION``; build type 0 = open source.
    hostname:
        Computer name reported by #13 and ``@PROXY_HOSTNAME``.
    benchmark_max_count, benchmark_max_iterations:
        #17 caps: the real server lowers the name count to 10; the iteration cap keeps a simulated benchmark
        (which blocks every client, as on the real server) from running for hours.
    udp_port:
        Answer ``WHEREAREYOU?`` and ``@PROXY_*`` datagrams on this UDP port (0 = any free port; ``None`` = off).
    legacy_udp_port, legacy_reply_port:
        Legacy discovery: listen on ``legacy_udp_port`` (6999 on a real one; 0 = any, ``None`` = off) and answer
        to the sender's address on ``legacy_reply_port``.
    max_file_buffer_bytes:
        Largest #29 buffer; a bigger Begin fails with code 4 (out of memory).
    """

    host: str = "127.0.0.1"
    port: int = 0
    max_clients: int | None = None
    idle_timeout_s: float | None = None
    latency_s: float = 0.002
    discard_while_busy: bool = False
    file_rate_bytes_s: float = DEFAULT_FILE_RATE_BYTES_S
    listing: str = field(default_factory=lambda: os.environ.get("RGSE_SIM_LISTING", "fields"))
    path_forms: str = field(default_factory=lambda: os.environ.get("RGSE_SIM_PATHS", "any"))
    version: tuple[int, int, int] = (1, 4, 0)
    hostname: str = "KRC4-SIM"
    benchmark_max_count: int = 10
    benchmark_max_iterations: int = 100_000
    udp_port: int | None = None
    legacy_udp_port: int | None = None
    legacy_reply_port: int = LEGACY_REPLY_PORT
    max_file_buffer_bytes: int = MAX_BUFFER_BYTES

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"sim server port {self.port} is not 0..65535")
        for key in ("udp_port", "legacy_udp_port"):
            value = getattr(self, key)
            if value is not None and not 0 <= value <= 65535:
                raise ConfigError(f"sim server {key} {value} is not 0..65535")
        if not 1 <= self.legacy_reply_port <= 65535:
            raise ConfigError(f"sim server legacy_reply_port {self.legacy_reply_port} is not 1..65535")
        if not self.file_rate_bytes_s > 0:
            raise ConfigError(f"sim server file_rate_bytes_s {self.file_rate_bytes_s} must be positive")
        if self.listing not in LISTING_VARIANTS:
            raise ConfigError(f"sim server listing {self.listing!r} is not one of {', '.join(LISTING_VARIANTS)}"
                              " (RGSE_SIM_LISTING)")
        if self.path_forms not in PATH_FORM_VARIANTS:
            raise ConfigError(f"sim server path_forms {self.path_forms!r} is not one of "
                              f"{', '.join(PATH_FORM_VARIANTS)} (RGSE_SIM_PATHS)")
        if self.max_clients is not None and self.max_clients < 1:
            raise ConfigError(f"sim server max_clients {self.max_clients} must be at least 1")
        if self.idle_timeout_s is not None and self.idle_timeout_s <= 0:
            raise ConfigError(f"sim server idle_timeout_s {self.idle_timeout_s} must be positive or None")
        if not 0 <= self.latency_s <= 10:
            raise ConfigError(f"sim server latency_s {self.latency_s} is not 0..10 s")
        if self.version[2] not in _BUILD_NAMES:
            raise ConfigError(f"sim server build type {self.version[2]} is not one of {sorted(_BUILD_NAMES)}")


@dataclass
class Faults:
    """Faults to inject, settable at runtime (e.g. ``srv.faults.stall_next = True``). ``*_next`` fire once.

    Attributes
    ----------
    drop_after_requests:
        Answer this many more requests, then close the connection that sends the next one, without reply.
    drop_on_variable:
        Close, without reply, any connection whose request names this variable (stays set until cleared).
    stall_next:
        The connection that sends the next request never answers again (it stays open, input is ignored).
    garbage_next:
        Answer the next request with :data:`GARBAGE_REPLY` instead of a frame.
    wrong_tag_next:
        Answer the next request with a tag that is not the request's.
    extra_latency_s:
        Added to every request's service time.
    refuse_types:
        Message type → error code: every well-formed request of such a type is refused with that code (its
        failure layout, nothing done) until cleared; e.g. ``{23: 2}`` makes every #23 Delete fail with Access.
    """

    drop_after_requests: int | None = None
    drop_on_variable: str | None = None
    stall_next: bool = False
    garbage_next: bool = False
    wrong_tag_next: bool = False
    extra_latency_s: float = 0.0
    refuse_types: dict[int, int] = field(default_factory=dict)


@dataclass
class Counters:
    """What the server did, for tests and benchmarks."""

    requests: int = 0
    by_type: Counter[int] = field(default_factory=Counter)
    connections_accepted: int = 0
    connections_refused: int = 0
    idle_drops: int = 0
    bytes_discarded: int = 0
    bad_frame_closes: int = 0
    malformed_requests: int = 0
    file_work_s: float = 0.0
    faults_fired: Counter[str] = field(default_factory=Counter)


def _tick_ms() -> int:
    """Like Win32 ``GetTickCount``: milliseconds on a monotonic clock, wrapping at 2**32."""
    return int(time.monotonic() * 1000) & 0xFFFFFFFF


class _Connection(asyncio.Protocol):
    """One client connection: splits frames, hands them to the server one at a time, discards input while busy."""

    def __init__(self, server: KrcServer) -> None:
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.reader = fr.FrameReader(responses=False)
        self.busy = False
        self.muted = False
        self.closed = False
        self.queue: list[bytes] = []
        self.files: FileSession | None = None
        self._idle: asyncio.TimerHandle | None = None
        self.peer = "?"

    # asyncio callbacks ---------------------------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.peer = str(transport.get_extra_info("peername"))
        if not self.server._admit(self):
            self.closed = True
            transport.close()
            return
        self.files = FileSession(self.server.files, self.server.config.max_file_buffer_bytes)
        self._arm_idle()

    def data_received(self, data: bytes) -> None:
        if self.closed:
            return
        self._arm_idle()
        sending = self.transport is not None and self.transport.get_write_buffer_size() > 0
        if self.muted or sending or (self.busy and self.server.config.discard_while_busy):
            # [src] client.cpp: input is dropped while a reply's send is incomplete
            self.server.counters.bytes_discarded += len(data)
            return
        try:
            frames = self.reader.feed(data)
        except ProtocolError as exc:  # a length of 0: the real server drops the connection
            log.info("closing %s: %s", self.peer, exc)
            self.server.counters.bad_frame_closes += 1
            self.close()
            return
        if not frames:
            return
        if self.server.config.discard_while_busy and not self.busy:
            # Anything behind the first frame arrived while that request is about to be served: dropped.
            dropped = sum(len(f) for f in frames[1:]) + self.reader.pending
            if dropped:
                self.server.counters.bytes_discarded += dropped
                self.reader = fr.FrameReader(responses=False)
            frames = frames[:1]
        self.queue.extend(frames)
        if not self.busy:
            self._next()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        if self._idle is not None:
            self._idle.cancel()
        if self.files is not None:
            self.files.close()
        self.server._forget(self)

    # helpers --------------------------------------------------------------------------------------------------------
    def _next(self) -> None:
        if self.closed or not self.queue:
            self.busy = False
            return
        self.busy = True
        self.server._spawn(self._serve(self.queue.pop(0)), f"krc-serve-{self.peer}")

    async def _serve(self, frame: bytes) -> None:
        try:
            await self.server._handle(self, frame)
        except Exception:
            log.exception("serving a request from %s failed; closing the connection", self.peer)
            self.close()
        self._next()

    def _arm_idle(self) -> None:
        timeout = self.server.config.idle_timeout_s
        if timeout is None or self.transport is None:
            return
        if self._idle is not None:
            self._idle.cancel()
        self._idle = asyncio.get_running_loop().call_later(timeout, self._idle_expired)

    def _idle_expired(self) -> None:
        if not self.closed:
            log.info("dropping %s: idle for %.1f s", self.peer, self.server.config.idle_timeout_s)
            self.server.counters.idle_drops += 1
            self.close()

    def send(self, data: bytes) -> None:
        if not self.closed and self.transport is not None:
            self.transport.write(data)

    def close(self) -> None:
        self.closed = True
        self.queue.clear()
        if self.transport is not None:
            self.transport.close()


class _Discovery(asyncio.DatagramProtocol):
    """UDP discovery (docs/protocol.md §2, discovery). Standard mode answers the sender's address and port; legacy mode
    (``reply_port`` set: KUKAVARPROXY's 6999 → 7000) answers the sender's address on ``reply_port``."""

    def __init__(self, server: KrcServer, reply_port: int | None = None) -> None:
        self.server = server
        self.reply_port = reply_port
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        text = data[:32].decode("latin-1")
        if text == "WHEREAREYOU?":
            store = self.server.store
            try:
                answer = f"KUKA|{store.read('$MODEL_NAME[]')}|{store.read('$KR_SERIALNO')}"
            except VariableError:
                answer = "KUKA||"
        else:
            answer = self.server._internal(text) if text.startswith("@") else None
        if answer is not None and self.transport is not None:
            to = addr if self.reply_port is None else (addr[0], self.reply_port)
            self.transport.sendto(answer.encode("latin-1"), to)


class KrcServer:
    """The simulated KR C4's C3 Bridge / KUKAVARPROXY server.

    Parameters
    ----------
    config:
        Behaviour (:class:`ServerConfig`); defaults are a real controller's.
    share_dir:
        The directory standing for the controller's ``roboter`` share; a temporary one if ``None``.
    store:
        The variable store; a freshly seeded :class:`VariableStore` if ``None``.
    program_host:
        What #10 drives; a :class:`StateOnlyProgramHost` over ``store`` if ``None``.
    on_confirm_all:
        Called by #63 (acknowledge all messages); the default clears ``$STOPMESS``.
    """

    def __init__(
        self,
        config: ServerConfig | None = None,
        share_dir: Path | None = None,
        *,
        store: VariableStore | None = None,
        program_host: ProgramHost | None = None,
        on_confirm_all: Callable[[], None] | None = None,
    ) -> None:
        self.config = config or ServerConfig()
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if share_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="krc4-share-")
            share_dir = Path(self._tmp.name)
        self.files = ShareFiles(share_dir, listing=self.config.listing, path_forms=self.config.path_forms)
        for folder in ("TRACE", "R1/PROGRAM"):  # every KR C4 has them
            (self.files.root / folder).mkdir(parents=True, exist_ok=True)
        self.store = store if store is not None else VariableStore()
        self.program_host: ProgramHost = program_host or StateOnlyProgramHost(self.store, exists=self.files.exists)
        self.on_confirm_all = on_confirm_all or (lambda: self.store.update("$STOPMESS", "FALSE"))
        self.faults = Faults()
        self.counters = Counters()
        self.port = 0
        self.udp_port: int | None = None
        self._lock = asyncio.Lock()
        self._connections: set[_Connection] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self._server: asyncio.Server | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._legacy_udp: asyncio.DatagramTransport | None = None
        self.legacy_udp_port: int | None = None
        self._stopped = asyncio.Event()

    # --- lifecycle ---------------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Bind and listen (TCP, and UDP discovery if configured)."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Connection(self), self.config.host, self.config.port)
        self.port = self._server.sockets[0].getsockname()[1]
        if self.config.udp_port is not None:
            self._udp, _ = await loop.create_datagram_endpoint(
                lambda: _Discovery(self), local_addr=(self.config.host, self.config.udp_port)
            )
            self.udp_port = self._udp.get_extra_info("sockname")[1]
        if self.config.legacy_udp_port is not None:
            reply_port = self.config.legacy_reply_port
            self._legacy_udp, _ = await loop.create_datagram_endpoint(
                lambda: _Discovery(self, reply_port), local_addr=(self.config.host, self.config.legacy_udp_port)
            )
            self.legacy_udp_port = self._legacy_udp.get_extra_info("sockname")[1]
        log.info("simulated KR C4 listening on %s:%d (share %s)", self.config.host, self.port, self.files.root)

    async def close(self) -> None:
        """Stop listening, drop every client, end every task (bounded: 5 s), free the temporary share."""
        if self._server is not None:
            self._server.close()
        for udp in (self._udp, self._legacy_udp):
            if udp is not None:
                udp.close()
        for conn in list(self._connections):
            if conn.transport is not None:
                conn.transport.abort()
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            async with asyncio.timeout(5.0):
                await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            async with asyncio.timeout(5.0):
                await self._server.wait_closed()
            self._server = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self._stopped.set()

    async def serve_forever(self) -> None:
        """Serve until :meth:`close` is called or the awaiting task is cancelled (then close)."""
        if self._server is None:
            await self.start()
        try:
            await self._stopped.wait()
        finally:
            if not self._stopped.is_set():
                await asyncio.shield(self.close())

    async def __aenter__(self) -> KrcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def closed(self) -> bool:
        """:meth:`close` has run: no connection, TCP or in-process (:mod:`simulators.krc4.inprocess`), is served."""
        return self._stopped.is_set()

    @property
    def client_count(self) -> int:
        """Connections currently open and admitted."""
        return len(self._connections)

    # --- connection bookkeeping --------------------------------------------------------------------------------------
    def _admit(self, conn: _Connection) -> bool:
        if self.config.max_clients is not None and len(self._connections) >= self.config.max_clients:
            self.counters.connections_refused += 1
            log.info("refusing %s: %d clients already connected", conn.peer, len(self._connections))
            return False
        self._connections.add(conn)
        self.counters.connections_accepted += 1
        return True

    def _forget(self, conn: _Connection) -> None:
        self._connections.discard(conn)

    def _spawn(self, coro: Coroutine[Any, Any, None], name: str) -> None:
        task = asyncio.get_running_loop().create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # --- one request -------------------------------------------------------------------------------------------------
    async def _handle(self, conn: _Connection, frame: bytes) -> None:
        async with self._lock:  # the real server is single-threaded: one request at a time, all clients
            await asyncio.sleep(self.config.latency_s + self.faults.extra_latency_s)
            if conn.closed:
                return
            msg_type = frame[4]
            if msg_type not in HANDLED_TYPES:
                log.info("closing %s: message type %d is not handled", conn.peer, msg_type)
                self.counters.bad_frame_closes += 1
                conn.close()
                return
            self.counters.requests += 1
            self.counters.by_type[msg_type] += 1
            if self._fire_drop_after():
                conn.close()
                return
            tag = (frame[0] << 8) | frame[1]
            if msg_type in (MSG_MOTION, MSG_KCP_KEYS):
                self._send(conn, tag, msg_type, _motion_or_key(msg_type, frame))
                return
            try:
                req = _decode_lenient(frame)
            except ProtocolError as exc:
                log.info("malformed request type %d from %s: %s", msg_type, conn.peer, exc)
                self.counters.malformed_requests += 1
                # [src] #0/#1 never map a code: a malformed body fails with code 0 and an empty value; the wide
                # messages (#4/#5 ...) answer code 9
                ascii_types = (fr.MsgType.READ_VAR_ASCII, fr.MsgType.WRITE_VAR_ASCII)
                code = _ERR.GENERAL if msg_type in ascii_types else _ERR.PROTOCOL
                reply: fr.Reply = _failure(msg_type, code)
            else:
                if self._names_trip_drop(req):
                    self.counters.faults_fired["drop_on_variable"] += 1
                    conn.close()
                    return
                refused = self.faults.refuse_types.get(msg_type)
                if refused is not None:
                    self.counters.faults_fired["refuse_types"] += 1
                    reply = _file_failure(req, refused)
                    if isinstance(reply, fr.FailureReply):  # not a file operation: the generic failure layout
                        reply = _failure(msg_type, refused)
                else:
                    work_s = self._file_work_s(conn, req)
                    if work_s > 0.0:
                        self.counters.file_work_s += work_s
                        await asyncio.sleep(work_s)  # every other request, on every connection, waits behind it
                        if conn.closed:  # the client gave up meanwhile: its buffers are gone with it
                            return
                    reply = self._dispatch(conn, req)
            self._send(conn, tag, msg_type, reply)

    def _file_work_s(self, conn: _Connection, req: fr.Request) -> float:
        """How long the controller's file system works on ``req`` (s): bytes moved / ``file_rate_bytes_s``."""
        rate = self.config.file_rate_bytes_s
        match req:
            case fr.ReadContentBegin(file_name=name) | fr.Copy(source=name) | fr.Move(source=name):
                return FILE_META_S + self.files.size_or_zero(name) / rate
            case fr.WriteContentEnd():
                assert conn.files is not None
                return FILE_META_S + conn.files.write_size() / rate
            case fr.NameList() | fr.GetProperties() | fr.Delete() | fr.Create() | fr.SetAttribute():
                return FILE_META_S
        return 0.0

    def _send(self, conn: _Connection, tag: int, msg_type: int, reply: fr.Reply) -> None:
        faults = self.faults
        if faults.stall_next:
            faults.stall_next = False
            self.counters.faults_fired["stall"] += 1
            conn.muted = True
            return
        if faults.garbage_next:
            faults.garbage_next = False
            self.counters.faults_fired["garbage"] += 1
            conn.send(GARBAGE_REPLY)
            return
        if faults.wrong_tag_next:
            faults.wrong_tag_next = False
            self.counters.faults_fired["wrong_tag"] += 1
            tag = (tag + 1) & 0xFFFF
        try:
            data = fr.encode_response(tag, reply)
        except ProtocolError as exc:  # e.g. a value that is not ISO-8859-1 in an ASCII reply, or too long
            log.info("reply to type %d does not fit the wire: %s", msg_type, exc)
            data = fr.encode_response(tag, _failure(msg_type, _ERR.LONG_ANSWER))
        conn.send(data)

    def _fire_drop_after(self) -> bool:
        remaining = self.faults.drop_after_requests
        if remaining is None:
            return False
        if remaining > 0:
            self.faults.drop_after_requests = remaining - 1
            return False
        self.faults.drop_after_requests = None
        self.counters.faults_fired["drop_after_requests"] += 1
        return True

    def _names_trip_drop(self, req: fr.Request) -> bool:
        target = self.faults.drop_on_variable
        if target is None:
            return False
        return normalize_name(target) in {normalize_name(n) for n in _names_of(req)}

    # --- dispatch ----------------------------------------------------------------------------------------------------
    def _dispatch(self, conn: _Connection, req: fr.Request) -> fr.Reply:
        assert conn.files is not None
        match req:
            case fr.ReadVarAscii(name=name):
                try:
                    return fr.ReadVarAsciiReply(self.read_variable(name))
                except VariableError:
                    return fr.ReadVarAsciiReply("", code=_ERR.GENERAL, success=False)  # [src] #0 never maps
            case fr.WriteVarAscii(name=name, value=value):
                try:
                    self.store.write(name, value)
                    return fr.WriteVarAsciiReply(value)  # [src] the request's text, not a read-back
                except VariableError:
                    return fr.WriteVarAsciiReply("", code=_ERR.GENERAL, success=False)
            case fr.ReadVar(name=name):
                try:
                    return fr.ReadVarReply(self.read_variable(name))
                except VariableError as exc:
                    return fr.ReadVarReply("", code=_code(exc), success=False)
            case fr.WriteVar(name=name, value=value):
                try:
                    self.store.write(name, value)
                    return fr.WriteVarReply(value)
                except VariableError as exc:
                    return fr.WriteVarReply("", code=_code(exc), success=False)
            case fr.ReadMulti(names=names):
                return self._multi(fr.ReadMultiReply, [self._entry(lambda n=n: self.read_variable(n)) for n in names])
            case fr.WriteMulti(items=items):
                entries = []
                for name, value in items:
                    try:
                        self.store.write(name, value)
                        entries.append(fr.MultiEntry(_ERR.SUCCESS, value))
                    except VariableError as exc:
                        entries.append(fr.MultiEntry(_code(exc), value))  # [src] the requested value, own code
                return self._multi(fr.WriteMultiReply, entries)
            case fr.ProgramControl():
                return self._program_control(req)
            case fr.ProxyInfo():
                now = dt.datetime.now(dt.UTC)
                utc = (now.year, now.month, (now.weekday() + 1) % 7, now.day, now.hour, now.minute, now.second,
                       now.microsecond // 1000)  # fmt: skip
                major, minor, build = self.config.version
                return fr.ProxyInfoReply(major, minor, build, utc, self.config.hostname)
            case fr.ProxyFeatures():
                return fr.ProxyFeaturesReply(HANDLED_TYPES)
            case fr.Benchmark():
                return self._benchmark(req)
            case fr.ConfirmAll():
                self.on_confirm_all()
                return fr.ConfirmAllReply()
        return self._file_op(conn.files, req)

    def read_variable(self, name: str) -> str:
        """What #0/#4/#6 answer: a KRL variable, else an internal ``PING``/``@PROXY_*`` variable."""
        try:
            return self.store.read(name)
        except VariableError:
            internal = self._internal(name)
            if internal is None:
                raise
            return internal

    def _internal(self, name: str) -> str | None:
        key = name  # [src] client_variables.cpp / proxy.cpp compare exact-case: "ping" is a KRL name, not PING
        major, minor, build = self.config.version
        if key == "PING":
            return "PONG"
        if key == "@PROXY_TYPE":
            return PROXY_TYPE
        if key == "@PROXY_VERSION":
            return f"{major}.{minor} ({_BUILD_NAMES[build]})"
        if key == "@PROXY_FEATURES":
            bits = "".join("1" if t in HANDLED_TYPES else "0" for t in range(255, -1, -1)).lstrip("0")
            return bits.rjust(8, "0")
        if key == "@PROXY_HOSTNAME":
            return self.config.hostname
        if key == "@PROXY_TIME":
            return dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        if key == "@PROXY_ADDRESS":
            return self.config.host
        if key == "@PROXY_PORT":
            return str(self.port)
        if key == "@PROXY_ENABLED":
            return "TRUE"
        return None

    @staticmethod
    def _entry(read: Callable[[], str]) -> fr.MultiEntry:
        try:
            return fr.MultiEntry(_ERR.SUCCESS, read())
        except VariableError as exc:
            return fr.MultiEntry(_code(exc), "")

    @staticmethod
    def _multi(cls: type[fr.ReadMultiReply] | type[fr.WriteMultiReply], entries: list[fr.MultiEntry]) -> fr.Reply:
        size = 1 + sum(3 + len(e.value.encode("utf-16-le")) for e in entries)
        if size > MAX_REPLY_PAYLOAD:
            return cls((), code=_ERR.LONG_ANSWER, success=False)
        if all(e.code == _ERR.SUCCESS for e in entries):
            return cls(tuple(entries))
        return cls(tuple(entries), code=_ERR.GENERAL, success=False)  # [src] all entries still returned

    def _program_control(self, req: fr.ProgramControl) -> fr.Reply:
        host = self.program_host
        cmd = req.cmd
        try:
            if cmd in (fr.ProgCmd.RESET, fr.ProgCmd.START, fr.ProgCmd.STOP, fr.ProgCmd.CANCEL):
                if req.name is not None:
                    return fr.ProgramControlReply(cmd, code=_ERR.PROTOCOL, success=False)
                action = {1: host.reset, 2: host.start, 3: host.stop, 4: host.cancel}[cmd]
                action(req.interpreter)
            elif cmd in (fr.ProgCmd.SELECT, fr.ProgCmd.RUN):
                if req.name is None:
                    return fr.ProgramControlReply(cmd, code=_ERR.PROTOCOL, success=False)
                (host.select if cmd == fr.ProgCmd.SELECT else host.run)(req.name, req.params, req.force)
            else:
                return fr.ProgramControlReply(cmd, code=_ERR.NOT_IMPLEMENTED, success=False)
        except ProgramControlError as exc:
            log.info("program control %d refused: %s", cmd, exc)
            return fr.ProgramControlReply(cmd, code=exc.code, success=False)
        return fr.ProgramControlReply(cmd)

    def _benchmark(self, req: fr.Benchmark) -> fr.Reply:
        """#17: time repeated reads or writes. Blocks every client meanwhile, like the real server."""
        count = min(len(req.names), self.config.benchmark_max_count)
        iterations = min(req.iterations, self.config.benchmark_max_iterations)
        names = req.names[:count]
        values = req.values[:count]
        start_ms = _tick_ms()
        for _ in range(iterations):
            for i, name in enumerate(names):
                with contextlib.suppress(VariableError):  # [src] errors on single variables are ignored
                    if req.write:
                        self.store.write(name, values[i])
                    else:
                        self.read_variable(name)
        stop_ms = _tick_ms()
        return fr.BenchmarkReply(req.write, count, iterations, start_ms, stop_ms, (stop_ms - start_ms) & 0xFFFFFFFF)

    def _file_op(self, session: FileSession, req: fr.Request) -> fr.Reply:
        try:
            for name, folder in _file_names_of(req):
                self.files.check_form(name, folder=folder)
            return self._file_op_unchecked(session, req)
        except FileOpError as exc:
            log.info("file operation %s refused: %s", type(req).__name__, exc)
            return _file_failure(req, exc.code)

    def _file_op_unchecked(self, session: FileSession, req: fr.Request) -> fr.Reply:
        files = self.files
        match req:
            case fr.NameList(item_type=item_type, list_flags=flags, path=path):
                items, infos = files.name_list(path, item_type, flags)
                return fr.NameListReply(tuple(items), tuple(infos))
            case fr.GetProperties(name=name):
                p = files.properties(name)
                return fr.GetPropertiesReply(
                    p.item_type, p.size_bytes, p.attributes, p.creation_ft, p.bias_min, p.access_ft, p.bias_min,
                    p.modified_ft, p.bias_min, p.edit_mode, files.full_name(name),
                )  # fmt: skip
            case fr.GetFullName(path=path):
                return fr.GetFullNameReply(files.full_name(path))
            case fr.GetKrcName(path=path):
                return fr.GetKrcNameReply(files.krc_name(path))
            case fr.SetAttribute(attributes=attributes, mask=mask, name=name):
                files.set_attribute(name, attributes, mask)
                return fr.SetAttributeReply()
            case fr.Create(item_type=item_type, always=always, name=name):
                files.create(name, item_type, always)
                return fr.CreateReply()
            case fr.Delete(always=always, name=name):
                files.delete(name, always)
                return fr.DeleteReply()
            case fr.Copy(copy_flags=flags, source=source, destination=destination):
                files.copy(source, destination, flags)
                return fr.CopyReply()
            case fr.Move(copy_flags=flags, source=source, destination=destination):
                files.copy(source, destination, flags, move=True)
                return fr.MoveReply()
            case fr.WriteContentBegin(total_size=size):
                return fr.WriteContentBeginReply(session.write_begin(size))
            case fr.WriteContentData(offset=offset, data=data):
                return fr.WriteContentDataReply(offset, session.write_data(offset, data))
            case fr.WriteContentGetSize():
                return fr.WriteContentGetSizeReply(session.write_size())
            case fr.WriteContentEnd(file_name=name):
                session.write_end(name)
                return fr.WriteContentEndReply()
            case fr.ReadContentBegin(file_name=name):
                return fr.ReadContentBeginReply(session.read_begin(name))
            case fr.ReadContentData(offset=offset, max_chunk=max_chunk):
                return fr.ReadContentDataReply(offset, session.read_data(offset, max_chunk))
            case fr.ReadContentGetSize():
                return fr.ReadContentGetSizeReply(session.read_size())
            case fr.ReadContentEnd():
                session.read_end()
                return fr.ReadContentEndReply()
        return fr.FailureReply(req.TYPE, code=_ERR.NOT_IMPLEMENTED)


_TRAILING = re.compile(r"(\d+) unexpected trailing byte")


def _decode_lenient(frame: bytes) -> fr.Request:
    """Decode a request as the real server does: bytes after a well-formed body are ignored, not refused."""
    try:
        return fr.decode_request(frame)[1]
    except ProtocolError as exc:
        m = _TRAILING.search(str(exc))
        if m is None or not 0 < int(m.group(1)) < len(frame) - 4:
            raise
        body = bytearray(frame[: len(frame) - int(m.group(1))])
        body[2:4] = (len(body) - 4).to_bytes(2, "big")
        return fr.decode_request(bytes(body))[1]


def _motion_or_key(msg_type: int, frame: bytes) -> fr.Reply:
    """#11 / #12: the reply echoes the subtype byte. This simulator moves nothing on a protocol command: code 7
    (NotImplemented) for every subtype; a body too short for the subtype byte gets code 9."""
    if len(frame) < 6:
        return fr.FailureReply(msg_type, b"\x00", code=_ERR.PROTOCOL)
    return fr.FailureReply(msg_type, frame[5:6], code=_ERR.NOT_IMPLEMENTED)


def _code(exc: VariableError) -> int:
    return exc.code if exc.code is not None else int(_ERR.GENERAL)


def _file_names_of(req: fr.Request) -> list[tuple[str, bool]]:
    """The controller names a file request carries, each with whether it designates a folder to list."""
    match req:
        case fr.NameList(path=path):
            return [(path, True)]
        case fr.Copy(source=a, destination=b) | fr.Move(source=a, destination=b):
            return [(a, False), (b, False)]
        case (fr.SetAttribute(name=n) | fr.Create(name=n) | fr.Delete(name=n) | fr.GetProperties(name=n)
              | fr.GetFullName(path=n) | fr.GetKrcName(path=n) | fr.WriteContentEnd(file_name=n)
              | fr.ReadContentBegin(file_name=n)):
            return [(n, False)]
    return []


def _names_of(req: fr.Request) -> Iterable[str]:
    match req:
        case fr.ReadVarAscii(name=n) | fr.WriteVarAscii(name=n) | fr.ReadVar(name=n) | fr.WriteVar(name=n):
            return (n,)
        case fr.ReadMulti(names=names) | fr.Benchmark(names=names):
            return names
        case fr.WriteMulti(items=items):
            return (n for n, _ in items)
    return ()


def _failure(msg_type: int, code: int) -> fr.Reply:
    """A failed reply for a request that could not be decoded: empty value / zero counts, as the real server."""
    empty_payload = {
        fr.MsgType.READ_VAR_ASCII: b"\x00\x00",
        fr.MsgType.WRITE_VAR_ASCII: b"\x00\x00",
        fr.MsgType.READ_VAR: b"\x00\x00",
        fr.MsgType.WRITE_VAR: b"\x00\x00",
        fr.MsgType.READ_MULTI: b"\x00",
        fr.MsgType.WRITE_MULTI: b"\x00",
        fr.MsgType.NAME_LIST: b"\x00\x00\x00\x00",
        fr.MsgType.GET_PROPERTIES: b"\x00" * 58,
        fr.MsgType.GET_FULL_NAME: b"\x00\x00",
        fr.MsgType.GET_KRC_NAME: b"\x00\x00",
    }.get(msg_type, b"")
    return fr.FailureReply(msg_type, empty_payload, code=code)


def _file_failure(req: fr.Request, code: int) -> fr.Reply:
    """The reply layout of a refused file operation: the fixed fields zero, the footer carrying the code."""
    bad = {"code": code, "success": False}
    match req:
        case fr.NameList():
            return fr.NameListReply((), (), **bad)
        case fr.GetProperties():
            return fr.GetPropertiesReply(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, "", **bad)
        case fr.GetFullName():
            return fr.GetFullNameReply("", **bad)
        case fr.GetKrcName():
            return fr.GetKrcNameReply("", **bad)
        case fr.SetAttribute():
            return fr.SetAttributeReply(**bad)
        case fr.Create():
            return fr.CreateReply(**bad)
        case fr.Delete():
            return fr.DeleteReply(**bad)
        case fr.Copy():
            return fr.CopyReply(**bad)
        case fr.Move():
            return fr.MoveReply(**bad)
        case fr.WriteContentBegin():
            return fr.WriteContentBeginReply(0, **bad)
        case fr.WriteContentData(offset=offset):
            return fr.WriteContentDataReply(offset, 0, **bad)
        case fr.WriteContentEnd():
            return fr.WriteContentEndReply(**bad)
        case fr.ReadContentBegin():
            return fr.ReadContentBeginReply(0, **bad)
        case fr.ReadContentData(offset=offset):
            return fr.ReadContentDataReply(offset, b"", **bad)
    return fr.FailureReply(req.TYPE, code=code)
