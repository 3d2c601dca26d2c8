"""Helpers of the MQTT tests: a private Mosquitto process, a collecting subscriber, a recording handler, a raw TCP
listener standing in for a slow or silent broker."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import os
import signal
import socket
import subprocess
import uuid
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import aiomqtt
import pytest

from rgse_daemon import robots
from rgse_daemon.config import MqttConfig
from rgse_daemon.io.commands import AbortCommand, CalibrateCommand, ConfirmCommand, MeasureCommand
from rgse_daemon.store import ResultRecord, RunRecord, Store, archive_file_async, archive_root

MOSQUITTO = "/usr/sbin/mosquitto"
ROBOT = "KR500R2830-1234"

_FIXTURE_KG = robots.get(robots.DEFAULT_KEY).calibration.fixture_mass_kg


async def port_open(host: str, port: int, timeout_s: float = 2.0) -> bool:
    try:
        # not wait_for: on Python 3.11 it can return the connection and drop a cancellation of the caller
        async with asyncio.timeout(timeout_s):
            _, writer = await asyncio.open_connection(host, port)
    except (OSError, TimeoutError):
        return False
    writer.close()
    await writer.wait_closed()
    return True


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]




class MosquittoProcess:
    """A Mosquitto of the test's own on a free loopback port, with persistence (retained messages survive restarts)."""

    def __init__(self, directory: Path, extra_config: str = "") -> None:
        self.dir = directory
        self.dir.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.extra_config = extra_config
        self.proc: asyncio.subprocess.Process | None = None

    @property
    def log_text(self) -> str:
        path = self.dir / "mosquitto.log"
        return path.read_text(errors="replace") if path.exists() else ""

    async def start(self) -> None:
        conf = self.dir / "mosquitto.conf"
        conf.write_text(
            f"listener {self.port} 127.0.0.1\n"
            "user root\n"
            "persistence true\n"
            f"persistence_location {self.dir}/\n"
            f"log_dest file {self.dir}/mosquitto.log\n"
            "log_type all\n" + (self.extra_config or "allow_anonymous true\n")
        )
        self.proc = await asyncio.create_subprocess_exec(MOSQUITTO, "-c", str(conf), stdin=subprocess.DEVNULL)
        async with asyncio.timeout(10):
            while not await port_open("127.0.0.1", self.port):
                if self.proc.returncode is not None:
                    pytest.fail(f"mosquitto exited with {self.proc.returncode}: {self.log_text[-2000:]}")
                await asyncio.sleep(0.05)

    async def stop(self) -> None:
        """SIGTERM (mosquitto writes its persistence file on the way out) and wait; SIGKILL after 10 s."""
        proc, self.proc = self.proc, None
        if proc is None:
            return
        if proc.returncode is None:
            proc.send_signal(signal.SIGTERM)
        try:
            await asyncio.wait_for(proc.wait(), 10)
        except TimeoutError:
            proc.kill()
            await asyncio.wait_for(proc.wait(), 10)


def aiomqtt_tasks() -> list[str]:
    """The running tasks whose coroutine is aiomqtt's own (its client's ``_misc_loop``)."""
    names = []
    for task in asyncio.all_tasks():
        code = getattr(task.get_coro(), "cr_code", None)
        if not task.done() and code is not None and f"{os.sep}aiomqtt{os.sep}" in code.co_filename:
            names.append(task.get_coro().__qualname__)
    return names


class TcpPeer:
    """A raw TCP listener on a free loopback port that notes, per accepted connection, when the client closes it.

    ``forward_to``: each connection is forwarded to that broker (its end of the connection is passed on as a
    half-close); otherwise it is held and never answered (a hung broker, a firewall's half-open port).
    ``backlog_full``: the accept queue is filled (by a connection of the test itself) and nothing is accepted until
    :meth:`release` — a client's connect blocks in ``connect()``. ``hold_from``: an MQTT packet type (e.g.
    :data:`SUBSCRIBE`); from the client's first packet of that type on, nothing it sends is forwarded, so the broker
    never acknowledges it (counted in ``held``). ``client_ids``: the client id of each CONNECT seen, in order.
    ``backlog``: of the listening socket; more than 0 for clients that connect at once (with ``backlog_full``, 0).
    """

    def __init__(self, *, forward_to: tuple[str, int] | None = None, backlog_full: bool = False,
                 hold_from: int | None = None, backlog: int = 0) -> None:
        self._forward_to = forward_to
        self._hold_from = hold_from
        self._listener = socket.socket()
        self._listener.bind(("127.0.0.1", 0))
        # Linux, backlog 0: one completed connection fits in the accept queue, a further SYN is dropped
        self._listener.listen(backlog)
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self._filler: socket.socket | None = None
        if backlog_full:
            self._filler = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        self.accepted = 0
        self.closed_by_client = 0
        self.held = 0
        self.client_ids: list[str] = []
        self._released = asyncio.Event()
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: list[asyncio.StreamWriter] = []

    async def __aenter__(self) -> Self:
        self._spawn(self._accept())
        if self._filler is None:
            self.release()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    def release(self) -> None:
        """Start accepting (the connection filling the accept queue is accepted and closed first)."""
        self._released.set()

    async def close(self) -> None:
        """Close every connection from our side, then the listener."""
        for writer in self._writers:
            writer.close()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for writer in self._writers:
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()
        if self._filler is not None:
            self._filler.close()
        self._listener.close()

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        self._tasks.add(asyncio.create_task(coro))

    async def _accept(self) -> None:
        loop = asyncio.get_running_loop()
        await self._released.wait()
        filler = None if self._filler is None else self._filler.getsockname()
        while True:
            conn, peer = await loop.sock_accept(self._listener)
            if peer == filler:
                conn.close()
                continue
            self.accepted += 1
            reader, writer = await asyncio.open_connection(sock=conn)
            self._writers.append(writer)
            upstream: asyncio.StreamWriter | None = None
            if self._forward_to is not None:
                up_reader, upstream = await asyncio.open_connection(*self._forward_to)
                self._writers.append(upstream)
                self._spawn(self._pump(up_reader, writer))
            self._spawn(self._from_client(reader, upstream))

    async def _from_client(self, reader: asyncio.StreamReader, upstream: asyncio.StreamWriter | None) -> None:
        holding = False
        with contextlib.suppress(ConnectionError):
            while data := await reader.read(4096):
                # the CONNECT comes alone (nothing is sent before its CONNACK), and a packet sent after waiting for
                # the broker's answer starts a chunk: the chunk's first byte is that packet's
                if data[0] >> 4 == CONNECT:
                    self.client_ids.append(_connect_client_id(data))
                if data[0] >> 4 == self._hold_from and not holding:
                    holding = True
                    self.held += 1
                if upstream is not None and not holding:
                    upstream.write(data)
        self.closed_by_client += 1
        if upstream is not None:
            upstream.close()

    @staticmethod
    async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(ConnectionError):
            while data := await reader.read(4096):
                writer.write(data)
            if not writer.is_closing():
                writer.write_eof()  # the broker ended the connection (e.g. a takeover of its client id)


#: MQTT control packet types (the high nibble of a packet's first byte).
CONNECT = 1
SUBSCRIBE = 8


def _connect_client_id(packet: bytes) -> str:
    """The client id of an MQTT 3.1.1 CONNECT packet (after the fixed header: protocol name, level, flags, keepalive,
    then the client id as a length-prefixed string)."""
    i = 1
    while packet[i] & 0x80:  # the remaining length's bytes
        i += 1
    i += 1
    i += 2 + int.from_bytes(packet[i:i + 2], "big") + 1 + 1 + 2
    n = int.from_bytes(packet[i:i + 2], "big")
    return packet[i + 2:i + 2 + n].decode()


def _remaining_length(n: int) -> bytes:
    """MQTT's variable-length integer (1-4 bytes, 7 bits each, high bit: more follows)."""
    out = bytearray()
    while True:
        n, digit = divmod(n, 128)
        out.append(digit | (0x80 if n else 0))
        if not n:
            return bytes(out)


def connect_packet(client_id: str) -> bytes:
    """A minimal MQTT 3.1.1 CONNECT: clean session, no keepalive (the broker never drops it for idling), no will."""
    cid = client_id.encode()
    body = b"\x00\x04MQTT\x04\x02\x00\x00" + len(cid).to_bytes(2, "big") + cid
    return b"\x10" + _remaining_length(len(body)) + body


class SessionThief:
    """A tiny raw-socket MQTT client that keeps taking over the session of ``client_id``.

    It connects with that client id and holds the connection; when the broker closes it (another client connected
    with the same id: MQTT 3.1.1 §3.1.4, the older session is disconnected), it connects again at once — taking
    the session back. A client with the same id (the bridge under test) thus loses every session right after its
    CONNACK. ``takeovers`` counts how often the thief was pushed off, i.e. how many sessions the other one got.
    """

    def __init__(self, host: str, port: int, client_id: str) -> None:
        self._host, self._port, self._packet = host, port, connect_packet(client_id)
        self.takeovers = 0
        self._first = asyncio.Event()
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Self:
        self._task = asyncio.create_task(self._run(), name="session thief")
        try:
            async with asyncio.timeout(10):
                await self._first.wait()  # holds the id before the other client comes
        except BaseException:
            await self.__aexit__(None, None, None)
            raise
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._task is not None
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)

    async def _run(self) -> None:
        while True:
            reader, writer = await asyncio.open_connection(self._host, self._port)
            try:
                writer.write(self._packet)
                connack = await reader.readexactly(4)
                assert connack == b"\x20\x02\x00\x00", f"CONNACK refused: {connack.hex()}"
                self._first.set()
                with contextlib.suppress(ConnectionError):
                    while await reader.read(256):  # nothing is sent to us (no subscriptions): EOF ends the session
                        pass
                self.takeovers += 1
            finally:
                writer.close()
                with contextlib.suppress(ConnectionError):
                    await writer.wait_closed()


class Collector:
    """A real MQTT client subscribed to ``topics`` that keeps every message it receives, in order.

    :meth:`sync` makes "everything published before now has arrived" observable without sleeping: it publishes
    a sentinel to a topic of its own and waits for it to come back; the broker delivers in order.
    """

    def __init__(self, host: str, port: int, *topics: str, **client_kwargs: Any) -> None:
        self._client = aiomqtt.Client(
            host, port, identifier=f"collector-{uuid.uuid4().hex[:8]}", timeout=5, **client_kwargs
        )
        self._topics = topics
        self._sentinel_topic = f"rgse-test-sentinel/{uuid.uuid4().hex}"
        self._sentinels_seen: set[str] = set()
        self.messages: list[aiomqtt.Message] = []
        self._changed = asyncio.Event()
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Self:
        await self._client.__aenter__()
        try:
            for t in (*self._topics, self._sentinel_topic):
                await self._client.subscribe(t, qos=1)
        except BaseException:
            await self._client.__aexit__(None, None, None)
            raise
        self._task = asyncio.create_task(self._collect(), name="collector")
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._task is not None
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)
        await self._client.__aexit__(exc_type, exc, tb)

    async def _collect(self) -> None:
        async for m in self._client.messages:
            if m.topic.value == self._sentinel_topic:
                self._sentinels_seen.add(bytes(m.payload).decode())  # type: ignore[arg-type]
            else:
                self.messages.append(m)
            self._changed.set()

    async def wait_for(
        self, predicate: Callable[[list[aiomqtt.Message]], bool], what: str, timeout_s: float = 15.0
    ) -> None:
        async with asyncio.timeout(timeout_s):
            while not predicate(self.messages):
                self._changed.clear()
                await self._changed.wait()
        assert predicate(self.messages), what

    async def sync(self, timeout_s: float = 10.0) -> None:
        token = uuid.uuid4().hex
        await self._client.publish(self._sentinel_topic, token, qos=1)
        async with asyncio.timeout(timeout_s):
            while token not in self._sentinels_seen:
                self._changed.clear()
                await self._changed.wait()

    async def publish(self, topic: str, payload: bytes | str, qos: int = 1) -> None:
        await self._client.publish(topic, payload, qos=qos)

    def on(self, topic: str) -> list[aiomqtt.Message]:
        return [m for m in self.messages if m.topic.value == topic]

    def json_on(self, topic: str) -> list[Any]:
        return [json.loads(m.payload) for m in self.on(topic)]  # type: ignore[arg-type]


async def clear_retained(host: str, port: int, prefix: str) -> None:
    """Remove the retained messages a test left under ``prefix`` on a shared broker."""
    async with Collector(host, port, f"{prefix}/#") as c:
        await c.sync()
        topics = {m.topic.value for m in c.messages if m.retain and m.payload}
        for topic in topics:
            await c._client.publish(topic, b"", qos=1, retain=True)


async def retained(host: str, port: int, topic_filter: str, **client_kwargs: Any) -> list[aiomqtt.Message]:
    """What a fresh subscriber gets for ``topic_filter`` right after subscribing: the retained messages."""
    async with Collector(host, port, topic_filter, **client_kwargs) as c:
        await c.sync()
        return list(c.messages)


def mqtt_config(host: str, port: int, prefix: str | None, **overrides: Any) -> MqttConfig:
    values: dict[str, Any] = {
        "enabled": True,
        "host": host,
        "port": port,
        "prefix": prefix,
        "reconnect_min_s": 0.05,
        "reconnect_max_s": 0.5,
        "state_rate_hz": 50.0,
    }
    if "command_tokens" not in overrides:
        values["command_auth"] = "open_lab_bench"  # tests on the loopback broker; tokens are tested on their own
    values.update(overrides)
    return MqttConfig(**values)


class RecordingHandler:
    """The daemon's side of commands, recording what it was asked; ``failures[request_id]`` is raised for it."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.failures: dict[str, Exception] = {}

    async def _record(self, verb: str, cmd: Any) -> dict[str, Any]:
        self.calls.append((verb, cmd))
        if cmd.request_id in self.failures:
            raise self.failures[cmd.request_id]
        return {"accepted": True, "run_id": f"run-{len(self.calls)}"}

    async def measure(self, cmd: MeasureCommand) -> dict[str, Any]:
        return await self._record("measure", cmd)

    async def calibrate(self, cmd: CalibrateCommand) -> dict[str, Any]:
        return await self._record("calibrate", cmd)

    async def abort(self, cmd: AbortCommand) -> dict[str, Any]:
        return await self._record("abort", cmd)

    async def confirm(self, cmd: ConfirmCommand) -> dict[str, Any]:
        return await self._record("confirm", cmd)


async def stored_result(
    store: Store, data_dir: Path, tmp_path: Path, result_topic: Callable[[str], Any], mass_kg: float
) -> tuple[RunRecord, ResultRecord]:
    """A measurement run with one archived raw file and its result, recorded with an outbox message."""
    run = await store.create_run("measurement", ROBOT, {"fixture_mass_kg": _FIXTURE_KG})
    await store.set_run_state(run.id, "running")
    src = tmp_path / "share" / f"{run.id}_NextGenDrive#3.r64"
    src.parent.mkdir(exist_ok=True)
    src.write_bytes(run.id.encode() * 64)
    f = await archive_file_async(src, archive_root(data_dir) / run.directory, timeout_s=30)
    await store.add_trace_file(run.id, f"{run.directory}/{src.name}", f.sha256, f.size)
    result = {"mass_kg": mass_kg, "u_kg": 0.35, "U_kg": 0.70, "k": 2, "loops": 10, "warnings": []}
    rec = await store.record_result(run.id, result, [f.sha256], publish=result_topic(run.id))
    await store.set_run_state(run.id, "completed")
    return run, rec


@contextlib.contextmanager
def asyncio_complaints(caplog: pytest.LogCaptureFixture) -> Iterator[list[str]]:
    """What asyncio reports while the block runs and when its garbage is collected after it: "Exception in
    callback", "Task was destroyed but it is pending", "Future exception was never retrieved"."""
    loop = asyncio.get_running_loop()
    said: list[str] = []

    def on_exception(loop: asyncio.AbstractEventLoop, context: dict[str, object]) -> None:
        said.append(f"{context.get('message')}: {context.get('exception')!r}")
        loop.default_exception_handler(context)

    previous = loop.get_exception_handler()
    loop.set_exception_handler(on_exception)
    try:
        yield said
        gc.collect()  # a task or future of a client left in a reference cycle is reported when it is finalised
    finally:
        loop.set_exception_handler(previous)
    said.extend(r.getMessage() for r in caplog.records if r.name == "asyncio")
