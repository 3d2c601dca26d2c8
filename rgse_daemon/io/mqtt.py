"""The daemon's MQTT face (interfaces §4): status, state, progress, results, alarms out; commands in.

Why it is shaped like this: the broker is another machine on a plant network. It goes away, restarts and comes
back, and none of that may lose a measurement result, block a procedure or execute a stale command. So:

* **Lifecycle** (architecture lessons 6, 9): ``await bridge.start()`` starts one task running an outer reconnect
  loop around ``async with aiomqtt.Client(...)``; attempts are spaced by jittered exponential backoff between
  ``reconnect_min_s`` and ``reconnect_max_s``. The client registers a RETAINED last will
  ``{"state": "offline", "version", "since": null}`` on ``<prefix>/status`` (``since`` is null because only the
  broker knows when it fired), publishes retained ``{"state": "online", "version", "since": <connect time>}``
  on every connect, and ``await bridge.stop()`` publishes retained ``{"state": "offline", "since": <now>}`` before
  disconnecting cleanly (a clean DISCONNECT discards the will). Every step of stop is bounded; past
  ``stop_timeout_s`` the task is cancelled. A connect given up — a stop while it is in flight, a CONNACK that does
  not come within ``timeout_s`` — leaves nothing behind: aiomqtt runs paho's blocking connect in an executor thread,
  which a cancellation does not stop, so the bridge waits (bounded) for that thread to return and then closes the
  connection it made (:mod:`rgse_daemon.io.mqtt_client`); after ``stop()`` no client of the bridge is connected or
  has tasks.
* **Results only through the store's outbox.** ``store.record_result(..., publish=bridge.result_message(run_id))``
  writes the result and its outbox row in one transaction; the bridge's drainer publishes pending rows in id
  order (QoS 1, retained) and marks each published only after the broker's PUBACK. ``bridge.notify_outbox()``
  wakes the drainer at once; a sweep every ``outbox_sweep_s`` catches anything else (a row written by another
  process, a failed mark). Delivery is at least once: a broker outage or restart loses nothing (rows stay
  pending), and a crash between PUBACK and the mark re-publishes the row — to the same retained topic
  (``run/<run_id>/result``) with byte-identical content, so the retained message a subscriber reads is
  unchanged and a live subscriber sees at most an identical copy (as QoS 1 allows anyway). Nothing visible is
  duplicated.
* **Bounded memory, counted drops** (lessons 7, 9). ``publish_state`` keeps only the latest snapshot and sends
  at most ``state_rate_hz``; a snapshot replaced before it was sent counts in ``dropped_state``. Alarms, command
  replies and progress wait in one bounded queue (``queue_size``); overflow counts in ``dropped_messages``.
  Progress (QoS 0) published while disconnected is dropped and counted (``dropped_progress``): stale progress
  is noise. Alarms and replies queued during an outage are sent after the reconnect. The operator prompt
  (``prompt``) is retained with QoS 1: a console or client that reconnects during a prompt finds it.
* **Abort and confirm have a path of their own** (:data:`URGENT_VERBS`): a second connection to the broker
  (client id ``<client_id>-urgent``, no will) subscribes to ``cmd/abort`` and ``cmd/confirm`` only and sends their
  replies, so that a flood on other topics, which the main connection reads behind, cannot starve them. While it is
  down the main connection serves them, an authorised one ahead of the rest of its incoming queue.
* **Commands** arrive on ``<prefix>/cmd/<verb>`` (QoS 1) and are validated by :mod:`rgse_daemon.io.commands`.
  Malformed, unauthorised, schema-violating and unknown-verb commands are refused WITHOUT EFFECT: a reply
  ``{request_id, ok: false, error}`` on ``<prefix>/cmd/<verb>/reply`` and an ``alarm``. Valid ones call the
  :class:`CommandHandler` (each in its own task, so ``abort`` is served while ``measure`` is still answering,
  bounded by ``command_timeout_s``) and get ``{request_id, ok: true, ...handler's dict}``; a handler exception
  becomes ``{ok: false, error}`` (logged once). The session is clean (``clean_session``): commands sent while
  the daemon was away are NOT delivered later — a "measure" from ten minutes ago must not move the robot now.
* **Counters** (:class:`MqttCounters`) are exposed as ``bridge.counters`` and published inside every state
  message under ``"mqtt"``, with the connection state. Each distinct error is logged once (lesson 11).

Public API::

    bridge = MqttBridge(cfg.mqtt, cfg.robot.name, store, handler, version)   # validates, no I/O
    await bridge.start() ... await bridge.stop()        # or: async with bridge: ...
    bridge.publish_state({...})                         # non-blocking; rate-limited, keep-latest
    bridge.publish_progress(run_id, {...})              # non-blocking; QoS 0
    bridge.publish_alarm({"kind": ..., "message": ...}) # non-blocking; QoS 1
    bridge.publish_prompt({...} | None)                 # non-blocking; QoS 1, retained
    await store.record_result(run_id, result, hashes, publish=bridge.result_message(run_id)); bridge.notify_outbox()
    bridge.counters, bridge.connection_state, bridge.topics
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import json
import logging
import math
import random
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import datetime
from enum import StrEnum
from types import TracebackType
from typing import Any, Protocol, Self

import aiomqtt

from rgse_daemon.aio import within
from rgse_daemon.config import MqttConfig
from rgse_daemon.errors import ConfigError, RgseError
from rgse_daemon.io.commands import (
    COMMANDS,
    AbortCommand,
    CalibrateCommand,
    Command,
    CommandRefused,
    ConfirmCommand,
    MeasureCommand,
    PropertiesCommand,
    authorised,
    parse_command,
    shown_verb,
)
from rgse_daemon.io.mqtt_client import Client, connection, tls_context
from rgse_daemon.io.topics import FORBIDDEN_IN_LEVEL, MqttError, Topics
from rgse_daemon.logs import RepeatThrottle
from rgse_daemon.store import OutboxMessage, Store, StoreError
from rgse_daemon.utc import iso_utc, now_utc

log = logging.getLogger(__name__)
#: The MQTT client library's logger: a flood of its "Message queue is full" is written once, then counted.
_client_log = log.getChild("client")
_client_throttle = RepeatThrottle()
_client_log.addFilter(_client_throttle)

#: Command handler calls in flight at once; more are refused ("busy") rather than queued without bound.
MAX_COMMANDS_IN_FLIGHT = 8
#: The verbs that stop or steer a run in progress: they come and are answered on a connection of their own (and, while
#: it is down, an authorised one takes a lane of its own in the main connection's incoming queue), so that a flood of
#: commands on other topics cannot starve them.
URGENT_VERBS = frozenset({"abort", "confirm"})
#: Incoming messages held in the urgent lane; more are refused like a full queue.
URGENT_INCOMING = 64
#: Incoming messages held in the ordinary lane (the broker client reads on and drops what does not fit).
INCOMING_QUEUE = 256
#: (verb, request_id) of the latest commands run, with their replies: a command seen again (a QoS 1 redelivery after
#: a lost PUBACK, a script that sends twice) is answered with the first one's reply and not run a second time.
REMEMBERED_COMMANDS = 1000


#: Deadline of the retained "offline" publish when stopping, and of the flush of the queue before it (s).
STOP_PUBLISH_TIMEOUT_S = 3.0
#: A session's workers are cancelled when it ends; one still running this long after its cancellation is cancelled
#: again (s): a cancellation lost inside a library (Python 3.11's ``wait_for``, see :mod:`rgse_daemon.io.mqtt_client`)
#: must not keep the session, and with it the clean stop's "offline", from ending.
RECANCEL_AFTER_S = 0.1


class Inbox(asyncio.Queue[aiomqtt.Message]):
    """The broker client's incoming queue, in two lanes: what ``urgent(message)`` says is urgent is served first and
    bounded apart (:data:`URGENT_INCOMING`), so that the ordinary lane, full of a flood, never holds it back; what it
    says is None is not queued (another connection serves it)."""

    def __init__(self, maxsize: int, urgent: Callable[[aiomqtt.Message], bool | None]) -> None:
        self._is_urgent = urgent
        self._lane_urgent = False  # the lane of the message being put (full() and _put() look at it)
        super().__init__(maxsize)

    def _init(self, maxsize: int) -> None:
        self._urgent: collections.deque[aiomqtt.Message] = collections.deque()
        self._ordinary: collections.deque[aiomqtt.Message] = collections.deque()

    def qsize(self) -> int:
        return len(self._urgent) + len(self._ordinary)

    def empty(self) -> bool:
        return not (self._urgent or self._ordinary)

    def full(self) -> bool:
        if self._lane_urgent:
            return len(self._urgent) >= URGENT_INCOMING
        return 0 < self.maxsize <= len(self._ordinary)

    def put_nowait(self, item: aiomqtt.Message) -> None:
        lane = self._is_urgent(item)
        if lane is None:  # served by the urgent connection: not this one's to queue
            return
        self._lane_urgent = lane
        try:
            super().put_nowait(item)
        finally:
            self._lane_urgent = False

    def _put(self, item: aiomqtt.Message) -> None:
        (self._urgent if self._lane_urgent else self._ordinary).append(item)

    def _get(self) -> aiomqtt.Message:
        return self._urgent.popleft() if self._urgent else self._ordinary.popleft()


class ConnectionState(StrEnum):
    STOPPED = "stopped"
    CONNECTING = "connecting"
    CONNECTED = "connected"
    BACKOFF = "backoff"  # waiting before the next connection attempt


@dataclass
class MqttCounters:
    """What the bridge did since it was created; published in the state message under ``"mqtt"``."""

    connects: int = 0
    """Successful connections (CONNACK accepted)."""
    reconnects: int = 0
    """Successful connections after the first one."""
    connect_failures: int = 0
    published: int = 0
    """Messages the broker took (QoS 1: acknowledged; QoS 0: written), every topic."""
    publish_errors: int = 0
    state_published: int = 0
    dropped_state: int = 0
    """State snapshots replaced by a newer one before they were sent (rate limit, outage)."""
    dropped_progress: int = 0
    dropped_messages: int = 0
    """Alarms, replies or progress refused because the outgoing queue was full."""
    commands: int = 0
    """Valid commands passed to the handler."""
    command_errors: int = 0
    """Valid commands whose handler raised or timed out."""
    refused_commands: int = 0
    duplicate_commands: int = 0
    """Commands whose verb and request_id were seen before: answered again, not run again."""
    outbox_published: int = 0
    """Outbox rows (results) published and marked published in the store."""
    outbox_sweeps: int = 0
    """Completed passes of the outbox drainer that left nothing pending."""

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class CommandHandler(Protocol):
    """What the daemon does on a valid command. Each returns a JSON-serialisable dict copied into the reply.

    A method should answer promptly (accept, queue, return a run id); it is cancelled after
    ``command_timeout_s`` and the sender gets an error reply. Raising refuses the command with the message.
    """

    async def measure(self, cmd: MeasureCommand) -> dict[str, Any]: ...

    async def properties(self, cmd: PropertiesCommand) -> dict[str, Any]: ...

    async def calibrate(self, cmd: CalibrateCommand) -> dict[str, Any]: ...

    async def abort(self, cmd: AbortCommand) -> dict[str, Any]: ...

    async def confirm(self, cmd: ConfirmCommand) -> dict[str, Any]: ...


@dataclass(frozen=True)
class _Out:
    topic: str
    payload: str
    qos: int
    retain: bool = False


def _json_default(value: object) -> str:
    """Datetimes in a payload are written as :func:`~rgse_daemon.utc.iso_utc` (one time format)."""
    if isinstance(value, datetime):
        return iso_utc(value)
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def _dumps(value: Any, what: str) -> str:
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False, ensure_ascii=False, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise MqttError(f"{what}: not JSON-serialisable: {exc}") from exc


def _now() -> str:
    return now_utc()


def _names(tasks: set[asyncio.Task[Any]]) -> str:
    return ", ".join(sorted(repr(t.get_name()) for t in tasks))


class _LogOnce:
    """Log each distinct problem once per key, and again only when it changes or after it was resolved."""

    def __init__(self, logger: logging.Logger) -> None:
        self._logger = logger
        self._last: dict[str, str] = {}

    def problem(self, key: str, message: str, *, level: int = logging.WARNING, exc_info: bool = False) -> None:
        if self._last.get(key) != message:
            self._last[key] = message
            self._logger.log(level, "%s", message, exc_info=exc_info)

    def resolved(self, key: str, message: str | None = None) -> None:
        if self._last.pop(key, None) is not None and message:
            self._logger.info("%s", message)


class MqttBridge:
    """Publishes the daemon's status, state, progress, alarms and (from the outbox) results; serves commands.

    Construction validates everything and does no I/O (lesson 6). Times are in seconds.
    """

    def __init__(
        self,
        cfg: MqttConfig,
        robot: str,
        store: Store,
        handler: CommandHandler,
        version: str,
        *,
        timeout_s: float = 10.0,
        command_timeout_s: float = 30.0,
        outbox_sweep_s: float = 5.0,
        queue_size: int = 1000,
        stop_timeout_s: float | None = None,
    ) -> None:
        if cfg.reconnect_min_s > cfg.reconnect_max_s:
            raise ConfigError("mqtt.reconnect_min_s must not exceed mqtt.reconnect_max_s")
        if cfg.password is not None and cfg.username is None:
            raise ConfigError("mqtt.password is set without mqtt.username")
        for name, value in (
            ("timeout_s", timeout_s),
            ("command_timeout_s", command_timeout_s),
            ("outbox_sweep_s", outbox_sweep_s),
        ):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"mqtt bridge {name} {value!r}: must be a finite number > 0")
        if queue_size < 1:
            raise ConfigError(f"mqtt bridge queue_size {queue_size!r}: must be >= 1")
        self._cfg = cfg
        self._robot = robot
        self._store = store
        self._handler = handler
        self._version = version
        self._timeout_s = float(timeout_s)
        self._command_timeout_s = float(command_timeout_s)
        self._outbox_sweep_s = float(outbox_sweep_s)
        self._queue_size = queue_size
        # Connect (socket + CONNACK), offline publish and disconnect each take at most about timeout_s.
        self._stop_timeout_s = 4 * self._timeout_s if stop_timeout_s is None else float(stop_timeout_s)
        self._tls = tls_context(cfg)
        self._client_id = cfg.client_id or f"rgse-{robot}-{secrets.token_hex(4)}"
        self.topics = Topics.of(cfg, robot)
        self.counters = MqttCounters()

        self._state = ConnectionState.STOPPED
        self._task: asyncio.Task[None] | None = None
        self._stopping = asyncio.Event()
        self._outbox_wake = asyncio.Event()
        self._connected = False
        self._online_at: float | None = None  # when the current session was subscribed and said online
        # Latest state snapshot not yet sent: (sequence, snapshot).
        self._state_pending: tuple[int, dict[str, Any]] | None = None
        self._state_seq = 0
        self._state_wake = asyncio.Event()
        self._outq: collections.deque[_Out] = collections.deque()
        self._outq_urgent: collections.deque[_Out] = collections.deque()  # replies to abort and confirm
        self._urgent_wake = asyncio.Event()
        self._urgent_up = False  # the urgent connection is subscribed: it serves abort and confirm
        self._urgent_task: asyncio.Task[None] | None = None
        self._main_online = asyncio.Event()  # the main connection is subscribed and said online
        self._outq_wake = asyncio.Event()
        self._outq_empty = asyncio.Event()  # set while nothing is queued: what a clean stop waits for
        self._outq_empty.set()
        self._command_tasks: set[asyncio.Task[None]] = set()
        # (verb, request_id) -> the reply sent, None while the command runs (REMEMBERED_COMMANDS, oldest dropped)
        self._remembered: collections.OrderedDict[tuple[str, str], str | None] = collections.OrderedDict()
        self._log = _LogOnce(log)

    # --- properties ----------------------------------------------------------------------------------------------
    @property
    def prefix(self) -> str:
        return self.topics.prefix

    @property
    def connection_state(self) -> ConnectionState:
        return self._state

    @property
    def connected(self) -> bool:
        return self._connected

    def result_message(self, run_id: str) -> OutboxMessage:
        """The outbox message under which a run's result is to be published (retained, QoS 1)."""
        return OutboxMessage(self.topics.result(run_id), retained=True, qos=1)

    # --- lifecycle ----------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Start the reconnect loop; returns at once (the first connection is made in the background)."""
        if self._task is not None:
            raise MqttError("mqtt bridge: already started")
        self._stopping.clear()
        if self._cfg.command_auth == "open_lab_bench" and not self._cfg.command_tokens:
            log.warning("mqtt %s: command_auth = open_lab_bench: any client that reaches %s:%d can move the robot "
                        "(lab bench only; docs/security.md)", self.prefix, self._cfg.host, self._cfg.port)
        self._task = asyncio.create_task(self._run(), name=f"mqtt-bridge {self.prefix}")
        self._urgent_task = asyncio.create_task(self._run_urgent(), name=f"mqtt-bridge {self.prefix} abort/confirm")

    async def stop(self) -> None:
        """Publish retained offline, disconnect, end the loop and the command tasks; bounded. Idempotent."""
        task, self._task = self._task, None
        urgent, self._urgent_task = self._urgent_task, None
        self._stopping.set()
        # one deadline for the whole stop, not one per step: the steps' waits added up past the daemon's bound
        # (seen: 15.006 and 15.009 s against 15 s, "stopping mqtt took longer than 15 s")
        deadline = asyncio.get_running_loop().time() + self._stop_timeout_s

        def left_s() -> float:
            return max(0.0, deadline - asyncio.get_running_loop().time())

        if urgent is not None:  # it ends on _stopping (a clean disconnect; the main connection says offline)
            if not self._urgent_up:
                # waiting for the main connection, or its own connect/subscribe in flight: nothing to close cleanly,
                # and a connect in flight would hold the stop for its whole timeout
                urgent.cancel()
            else:
                try:  # its clean disconnect gets at most a quarter of the stop: the main connection's is the one
                    await within(asyncio.shield(urgent), min(left_s(), self._stop_timeout_s / 4))
                except TimeoutError:
                    urgent.cancel()
            await asyncio.wait({urgent}, timeout=max(left_s() / 2, 0.1))  # a cancelled close keeps its own deadline
        connecting = task is not None and self._state is ConnectionState.CONNECTING
        if connecting:
            # no session to close cleanly: a connect in flight (a broker that does not answer) would hold the stop
            # for a whole connect timeout; the broker has no session of ours to keep, or sends our will for it.
            # The task then closes what the connect made (bounded by stop_timeout_s, see _connection): cancelled
            # once only, so that this is not interrupted
            task.cancel()
        commands = list(self._command_tasks)
        for t in commands:
            t.cancel()
        try:
            if commands:
                await asyncio.gather(*commands, return_exceptions=True)
            if task is not None and not connecting:
                try:
                    await within(asyncio.shield(task), max(left_s(), 0.1))
                except TimeoutError:
                    log.warning("mqtt %s: no clean stop within %g s; cancelling", self.prefix, self._stop_timeout_s)
        finally:
            if task is not None:
                if not connecting and not task.done():
                    task.cancel()
                await asyncio.wait({task}, timeout=max(left_s(), 1.0))  # its cancelled close keeps a deadline
            self._state = ConnectionState.STOPPED
            self._connected = False
            for record in _client_throttle.pending():  # the counts of a flood not yet written
                _client_log.handle(record)

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    # --- publishing (non-blocking) ------------------------------------------------------------------------------
    def publish_state(self, snapshot: dict[str, Any]) -> None:
        """Offer the latest controller/interlock/link snapshot; sent retained at most ``state_rate_hz``.

        Keeps only the newest: a snapshot replaced before it was sent counts in ``dropped_state``.
        """
        if not isinstance(snapshot, dict):
            raise MqttError(f"state: a dict expected, got {type(snapshot).__name__}")
        text = _dumps(snapshot, "state")  # refuse a bad snapshot here, at its source
        if self._state_pending is not None:
            self.counters.dropped_state += 1
        self._state_seq += 1
        self._state_pending = (self._state_seq, json.loads(text))  # a deep copy: the caller may keep mutating
        self._state_wake.set()

    def publish_progress(self, run_id: str, progress: dict[str, Any]) -> None:
        """Progress of a run (step, loop i/n, eta); QoS 0, dropped (and counted) while disconnected."""
        topic = self.topics.progress(run_id)
        payload = _dumps(progress, f"progress of run {run_id}")
        if not self._connected:
            self.counters.dropped_progress += 1
            return
        self._enqueue(_Out(topic, payload, qos=0))

    def publish_alarm(self, alarm: dict[str, Any]) -> None:
        """An alarm (interlock trip, link loss, refused command); QoS 1, queued across outages (bounded).

        ``time`` is added (UTC) unless given.
        """
        if not isinstance(alarm, dict):
            raise MqttError(f"alarm: a dict expected, got {type(alarm).__name__}")
        self._enqueue(_Out(self.topics.alarm, _dumps({"time": _now(), **alarm}, "alarm"), qos=1))

    def publish_prompt(self, prompt: dict[str, Any] | None, run_id: str | None = None) -> None:
        """The operator prompt a run waits for (the ``confirm`` event), retained with QoS 1 on ``<prefix>/prompt``
        and queued across outages, so that a console or client that (re)connects finds it; ``None``: no prompt is
        pending any more (answered, or the run of ``run_id`` ended) — retained ``{"pending": false}``."""
        doc = ({"pending": True, **prompt} if prompt is not None
               else {"pending": False, "run_id": run_id, "time": _now()})
        self._enqueue(_Out(self.topics.prompt, _dumps(doc, "prompt"), qos=1, retain=True))

    def notify_outbox(self) -> None:
        """A row was added to the outbox: publish it now rather than at the next sweep."""
        self._outbox_wake.set()

    def _enqueue(self, out: _Out, *, urgent: bool = False) -> None:
        """Queue ``out``; ``urgent`` (the reply to an abort or a confirm) goes out on the urgent connection while
        it is up."""
        if urgent and self._urgent_up:
            if len(self._outq_urgent) >= self._queue_size:
                self.counters.dropped_messages += 1
                return
            self._outq_urgent.append(out)
            self._urgent_wake.set()
            return
        if len(self._outq) >= self._queue_size:
            self.counters.dropped_messages += 1
            self._log.problem("queue", f"mqtt {self.prefix}: outgoing queue full ({self._queue_size}); dropping")
            return
        self._outq.append(out)
        self._outq_empty.clear()
        self._outq_wake.set()

    # --- the reconnect loop -------------------------------------------------------------------------------------
    def _client(self, *, urgent: bool = False) -> Client:
        if urgent:  # abort and confirm only; no will (the main connection's says offline)
            return Client(self._cfg.host, self._cfg.port, username=self._cfg.username, password=self._cfg.password,
                          identifier=f"{self._client_id}-urgent", logger=_client_log, clean_session=True,
                          keepalive=self._cfg.keepalive_s, timeout=self._timeout_s, tls_context=self._tls,
                          max_queued_incoming_messages=URGENT_INCOMING,
                          max_queued_outgoing_messages=self._queue_size)
        will = aiomqtt.Will(
            self.topics.status,
            _dumps({"state": "offline", "version": self._version, "since": None}, "will"),
            qos=1,
            retain=True,
        )
        return Client(
            self._cfg.host,
            self._cfg.port,
            username=self._cfg.username,
            password=self._cfg.password,
            identifier=self._client_id,
            logger=_client_log,
            will=will,
            clean_session=True,
            keepalive=self._cfg.keepalive_s,
            timeout=self._timeout_s,
            tls_context=self._tls,
            max_queued_incoming_messages=INCOMING_QUEUE,
            max_queued_outgoing_messages=self._queue_size,
            queue_type=functools.partial(Inbox, urgent=self._urgent_message),  # type: ignore[arg-type]
        )

    def _urgent_message(self, message: aiomqtt.Message) -> bool | None:
        """On the main connection: None for an ``abort`` or ``confirm`` while the urgent connection serves them; an
        authorised one (checked before the queue, as cheaply as that can be) is urgent otherwise."""
        verb = message.topic.value[len(self.prefix) + len("/cmd/"):]
        if verb not in URGENT_VERBS:
            return False
        if self._urgent_up:
            return None
        payload = message.payload
        return isinstance(payload, bytes | bytearray | str) and \
            authorised(bytes(payload) if not isinstance(payload, str) else payload, self._cfg.command_tokens)

    async def _run_urgent(self) -> None:
        """The second connection to the broker: subscribed to ``cmd/abort`` and ``cmd/confirm`` only, it has its own
        stream from the broker, so that a flood of commands on other topics (which the main connection reads
        behind) cannot hold an abort back; it sends their replies too. Reconnects with backoff like the main one."""
        attempt = 0
        where = f"mqtt {self._cfg.host}:{self._cfg.port} (abort/confirm)"
        while not self._stopping.is_set():
            # only beside an online main connection: the broker is there, and a stop during a connect has one
            # connection to close, not two
            online = asyncio.ensure_future(self._main_online.wait())
            stopping = asyncio.ensure_future(self._stopping.wait())
            try:
                await asyncio.wait([online, stopping], return_when=asyncio.FIRST_COMPLETED)
            finally:
                online.cancel()
                stopping.cancel()
            if self._stopping.is_set():
                return
            try:
                async with connection(self._client(urgent=True), close_s=self._timeout_s,
                                      cancelled_close_s=self._stop_timeout_s,
                                      on_not_closed=lambda m: self._log.problem("abandoned urgent", m)) as client:
                    for verb in sorted(URGENT_VERBS):
                        await client.subscribe(f"{self.prefix}/cmd/{verb}", qos=1, timeout=self._timeout_s)
                    self._urgent_up = True
                    attempt = 0
                    self._log.resolved("urgent", f"{where}: connected")
                    workers = [asyncio.create_task(self._receive(client), name="mqtt urgent receive"),
                               asyncio.create_task(self._send_urgent(client), name="mqtt urgent send")]
                    stop = asyncio.create_task(self._stopping.wait(), name="mqtt urgent stop")
                    try:
                        done, _ = await asyncio.wait([*workers, stop], return_when=asyncio.FIRST_COMPLETED)
                    finally:
                        self._urgent_up = False
                        await self._end_tasks([*workers, stop])
                    for t in workers:
                        if t in done:
                            t.result()
            except (aiomqtt.MqttError, MqttError, OSError) as exc:
                self._log.problem("urgent", f"{where}: {exc}")
            except Exception as exc:  # a bug: the main connection still serves abort and confirm; say so loudly
                self._log.problem("urgent", f"{where}: unexpected error: {exc!r}", level=logging.ERROR,
                                  exc_info=True)
            finally:
                self._urgent_up = False
                if self._outq_urgent:  # replies the urgent connection could not send: the main one sends them
                    self._outq.extendleft(reversed(self._outq_urgent))
                    self._outq_urgent.clear()
                    self._outq_empty.clear()
                    self._outq_wake.set()
            with contextlib.suppress(TimeoutError):
                await within(self._stopping.wait(), self._backoff_s(attempt))
            attempt += 1

    async def _send_urgent(self, client: aiomqtt.Client) -> None:
        while True:
            if not self._outq_urgent:
                self._urgent_wake.clear()
                await self._urgent_wake.wait()
                continue
            await self._publish(client, self._outq_urgent[0])  # on failure it stays first (then goes to the main)
            self._outq_urgent.popleft()

    def _connection(self) -> contextlib.AbstractAsyncContextManager[Client]:
        """``async with client``, except that a connect given up leaves nothing open (:func:`connection`): what it
        made is closed within ``stop_timeout_s`` on a stop (the stop's deadline; a stop arriving while a failed
        connect is closed waits for that) and within ``timeout_s`` otherwise."""
        return connection(self._client(), close_s=self._timeout_s, cancelled_close_s=self._stop_timeout_s,
                          on_not_closed=lambda message: self._log.problem("abandoned", message))

    def _backoff_s(self, attempt: int) -> float:
        lo, hi = self._cfg.reconnect_min_s, self._cfg.reconnect_max_s
        return random.uniform(lo, min(hi, lo * 2.0 ** min(attempt, 30)))

    async def _run(self) -> None:
        attempt = 0
        where = f"mqtt {self._cfg.host}:{self._cfg.port}"
        while not self._stopping.is_set():
            self._state = ConnectionState.CONNECTING
            connected = False
            self._online_at = None
            try:
                async with self._connection() as client:
                    connected = True
                    self._log.resolved("connect", f"{where}: connected")
                    await self._session(client)
            except aiomqtt.MqttError as exc:
                if connected:
                    self._log.problem("connect", f"{where}: connection lost: {exc}")
                else:
                    self.counters.connect_failures += 1
                    self._log.problem("connect", f"{where}: cannot connect: {exc}")
            except (MqttError, StoreError, OSError) as exc:
                self._log.problem("connect", f"{where}: {exc}")
            except Exception as exc:  # a bug: keep the daemon's MQTT face alive, but say so loudly
                self._log.problem(
                    "unexpected", f"{where}: unexpected error: {exc!r}", level=logging.ERROR, exc_info=True
                )
            finally:
                self._connected = False
            if self._stopping.is_set():
                break
            self._state = ConnectionState.BACKOFF
            if self._online_at is not None and time.monotonic() - self._online_at >= self._cfg.reconnect_max_s:
                attempt = 0  # the session was online and held: reconnect quick. One that drops right after CONNACK
                #              (another client with our id kicking us off, an ACL refusing our subscriptions) keeps
                #              backing off, even when the loss shows only as the subscribe's or the online publish's
                #              timeout (aiomqtt does not fail a pending call on a disconnect)
            delay = self._backoff_s(attempt)
            attempt += 1
            with contextlib.suppress(TimeoutError):  # the backoff elapsed: try again
                await within(self._stopping.wait(), delay)
        self._state = ConnectionState.STOPPED

    async def _session(self, client: aiomqtt.Client) -> None:
        """One connection: announce online, subscribe, run the workers until the connection ends or stop."""
        self.counters.connects += 1
        if self.counters.connects > 1:
            self.counters.reconnects += 1
        # subscribed before saying online: "online" means commands are heard
        await client.subscribe(self.topics.commands, qos=1, timeout=self._timeout_s)
        online = {"state": "online", "version": self._version, "since": _now()}
        await self._publish(client, _Out(self.topics.status, _dumps(online, "status"), qos=1, retain=True))
        self._connected = True
        self._main_online.set()
        self._state = ConnectionState.CONNECTED
        self._online_at = time.monotonic()
        workers = [
            asyncio.create_task(self._receive(client), name="mqtt receive"),
            asyncio.create_task(self._send_queued(client), name="mqtt send"),
            asyncio.create_task(self._send_state(client), name="mqtt state"),
            asyncio.create_task(self._drain_outbox(client), name="mqtt outbox"),
        ]
        stop = asyncio.create_task(self._stopping.wait(), name="mqtt stop")
        try:
            done, _ = await asyncio.wait([*workers, stop], return_when=asyncio.FIRST_COMPLETED)
            sender = workers[1]
            if stop in done and not sender.done() and not self._outq_empty.is_set():
                # A clean stop: the sender first sends what is queued (a prompt withdrawn as the run ended, the
                # last alarms and replies), within STOP_PUBLISH_TIMEOUT_S; what is left then stays queued. (Cancelled
                # mid-publish, a message could reach the broker and be sent again by a later flush: a duplicate.)
                empty = asyncio.ensure_future(self._outq_empty.wait())
                try:
                    await asyncio.wait([empty, sender], timeout=STOP_PUBLISH_TIMEOUT_S,
                                       return_when=asyncio.FIRST_COMPLETED)
                finally:
                    empty.cancel()
        finally:
            self._connected = False
            self._main_online.clear()
            await self._end_tasks([*workers, stop])
        for t in workers:
            if t in done:
                t.result()  # the connection ended: raises why (aiomqtt.MqttError)
        # A clean stop: the will is discarded on DISCONNECT, so say offline ourselves first (briefly: a broker that
        # does not acknowledge within STOP_PUBLISH_TIMEOUT_S will not be helped by waiting longer)
        offline = {"state": "offline", "version": self._version, "since": _now()}
        await self._publish(client, _Out(self.topics.status, _dumps(offline, "status"), qos=1, retain=True),
                            timeout_s=min(self._timeout_s, STOP_PUBLISH_TIMEOUT_S))

    async def _end_tasks(self, tasks: list[asyncio.Task[Any]]) -> None:
        """Cancel a session's ``tasks`` and wait until they have ended, at most ``min(timeout_s,
        STOP_PUBLISH_TIMEOUT_S)``. One still running :data:`RECANCEL_AFTER_S` after its cancellation lost it, and is
        cancelled again (said once). One still running at the bound is left behind, cancelled, and said so: the session
        goes on to its end (a clean stop's "offline" and DISCONNECT) rather than wait on it."""
        loop = asyncio.get_running_loop()
        bound_s = min(self._timeout_s, STOP_PUBLISH_TIMEOUT_S)
        deadline = loop.time() + bound_s
        pending = {t for t in tasks if not t.done()}
        try:
            while pending:
                for t in pending:
                    t.cancel()
                left_s = deadline - loop.time()
                if left_s <= 0:
                    self._log.problem("left behind", f"mqtt {self.prefix}: {_names(pending)} still running {bound_s:g}"
                                      " s after being cancelled; left behind", level=logging.ERROR)
                    return
                _, pending = await asyncio.wait(pending, timeout=min(RECANCEL_AFTER_S, left_s))
                if pending:
                    self._log.problem("recancel", f"mqtt {self.prefix}: {_names(pending)} still running "
                                      f"{RECANCEL_AFTER_S:g} s after being cancelled (a cancellation lost); cancelled "
                                      "again")
        except asyncio.CancelledError:
            for t in pending:
                t.cancel()
            raise
        finally:
            for t in tasks:  # read now (asyncio would report it unread); why the connection ended is raised later
                if t.done() and not t.cancelled():
                    t.exception()

    async def _publish(self, client: aiomqtt.Client, out: _Out, timeout_s: float | None = None) -> None:
        try:
            await client.publish(out.topic, out.payload, qos=out.qos, retain=out.retain,
                                 timeout=self._timeout_s if timeout_s is None else timeout_s)
        except aiomqtt.MqttError:
            self.counters.publish_errors += 1
            raise
        self.counters.published += 1

    # --- session workers ----------------------------------------------------------------------------------------
    async def _send_queued(self, client: aiomqtt.Client) -> None:
        while True:
            if not self._outq:
                self._outq_wake.clear()
                await self._outq_wake.wait()
                continue
            out = self._outq[0]
            await self._publish(client, out)  # on failure the message stays first, for the next connection
            self._outq.popleft()
            if not self._outq:
                self._outq_empty.set()
                self._log.resolved("queue")  # only once it is empty: a flood that keeps it near full warns once

    async def _send_state(self, client: aiomqtt.Client) -> None:
        period_s = 1.0 / self._cfg.state_rate_hz
        while True:
            if self._state_pending is None:
                self._state_wake.clear()
                await self._state_wake.wait()
                continue
            seq, snapshot = self._state_pending
            payload = {
                **snapshot,
                "time": _now(),
                "mqtt": {"connection": self._state.value, **self.counters.as_dict()},
            }
            await self._publish(client, _Out(self.topics.state, _dumps(payload, "state"), qos=1, retain=True))
            self.counters.state_published += 1
            if self._state_pending is not None and self._state_pending[0] == seq:
                self._state_pending = None
            await asyncio.sleep(period_s)  # the rate limit: newer snapshots meanwhile replace each other

    async def _drain_outbox(self, client: aiomqtt.Client) -> None:
        while True:
            self._outbox_wake.clear()  # before reading: a row added from here on wakes the next round
            try:
                await self._publish_pending(client)
                self._log.resolved("outbox", f"mqtt {self.prefix}: outbox drained again")
            except StoreError as exc:
                self._log.problem("outbox", f"mqtt {self.prefix}: outbox: {exc}")
            with contextlib.suppress(TimeoutError):  # sweep anyway: a row may have been added by another process
                await within(self._outbox_wake.wait(), self._outbox_sweep_s)

    async def _publish_pending(self, client: aiomqtt.Client) -> None:
        while True:
            rows = await self._store.pending_outbox(100)
            if not rows:
                self.counters.outbox_sweeps += 1
                return
            for row in rows:
                try:
                    await self._publish(client, _Out(row.topic, row.payload, qos=row.qos, retain=row.retained))
                except aiomqtt.MqttError as exc:
                    try:
                        await self._store.record_publish_failure(row.id, str(exc) or type(exc).__name__)
                    except StoreError as store_exc:
                        self._log.problem("outbox", f"mqtt {self.prefix}: outbox: {store_exc}")
                    raise
                # Published (PUBACK) but not yet marked: a crash here re-publishes identical retained content.
                await self._store.mark_published(row.id)
                self.counters.outbox_published += 1

    async def _receive(self, client: aiomqtt.Client) -> None:
        prefix_len = len(self.prefix) + len("/cmd/")
        async for message in client.messages:
            verb = message.topic.value[prefix_len:]
            payload = message.payload
            if isinstance(payload, str):
                payload = payload.encode()
            elif not isinstance(payload, bytes | bytearray):
                payload = b"" if payload is None else str(payload).encode()
            self._dispatch(verb, bytes(payload), retained=bool(message.retain))

    # --- commands -----------------------------------------------------------------------------------------------
    def _dispatch(self, verb: str, payload: bytes, *, retained: bool = False) -> None:
        try:
            cmd = parse_command(verb, payload, self._cfg.command_tokens)
            if retained:
                # A retained command is replayed by the broker to every new subscription: after a reconnect or a
                # restart it would start a motion nobody asked for now. Commands count only when sent live.
                raise CommandRefused(verb, "retained command ignored: publish commands with retain=false",
                                     cmd.request_id)
            key = (verb, cmd.request_id)
            if key in self._remembered:
                self._answer_again(key)
                return
            if len(self._command_tasks) >= MAX_COMMANDS_IN_FLIGHT:
                raise CommandRefused(verb, f"busy: {MAX_COMMANDS_IN_FLIGHT} commands in flight", cmd.request_id)
        except CommandRefused as exc:
            self._refuse(exc)
            return
        except Exception as exc:  # a bug in the checks: refuse this one command, never end the command loop
            log.error("mqtt %s: cmd/%s: checking the command failed", self.prefix, verb[:64], exc_info=True)
            self._refuse(CommandRefused(verb, f"not checked: {type(exc).__name__}"))
            return
        self._remembered[key] = None
        while len(self._remembered) > REMEMBERED_COMMANDS:
            self._remembered.popitem(last=False)
        task = asyncio.create_task(self._run_command(cmd), name=f"mqtt cmd {verb} {cmd.request_id}")
        self._command_tasks.add(task)
        task.add_done_callback(self._command_tasks.discard)

    def _answer_again(self, key: tuple[str, str]) -> None:
        """A command seen before: its reply again if it has one (the sender may have missed it), nothing while it
        still runs (its reply is on the way); never run a second time."""
        verb, request_id = key
        self.counters.duplicate_commands += 1
        reply = self._remembered[key]
        # once per verb, not per copy: a flood of copies must not become a flood of log lines (the counter counts)
        self._log.problem(f"duplicate {verb}", f"mqtt {self.prefix}: cmd/{verb}: a command seen before (request_id "
                          f"{request_id}, the first such) is not run again; copies are answered with the first reply "
                          f"and counted in duplicate_commands", level=logging.INFO)
        if reply is not None:
            self._enqueue(_Out(self.topics.reply(verb), reply, qos=1), urgent=verb in URGENT_VERBS)

    def _refuse(self, exc: CommandRefused) -> None:
        self.counters.refused_commands += 1
        # one key per verb of ours and one for all unknown verbs: keys chosen by the sender would grow without bound
        key = f"refused {exc.verb}" if exc.verb in COMMANDS else "refused unknown verb"
        self._log.problem(key, f"mqtt {self.prefix}: refused command: {exc}")
        reply = {"request_id": exc.request_id, "ok": False, "error": exc.problem}
        # An unknown verb is still answered on its own reply topic: the sender listens there.
        if all(c not in exc.verb for c in FORBIDDEN_IN_LEVEL) and exc.verb:
            self._enqueue(_Out(self.topics.reply(exc.verb), _dumps(reply, "reply"), qos=1))
        self.publish_alarm(
            {
                "kind": "refused_command",
                "message": "refused command",
                "verb": shown_verb(exc.verb),
                "request_id": exc.request_id,
                "error": exc.problem,
            }
        )

    async def _run_command(self, cmd: Command) -> None:
        verb = cmd.VERB
        self.counters.commands += 1
        try:
            async with asyncio.timeout(self._command_timeout_s):
                result = await getattr(self._handler, verb)(cmd)
            if not isinstance(result, dict):
                raise MqttError(f"handler returned {type(result).__name__}, not a dict")
            payload = _dumps({**result, "request_id": cmd.request_id, "ok": True}, f"reply to {verb}")
        except TimeoutError:
            self.counters.command_errors += 1
            error = f"no answer from the daemon within {self._command_timeout_s:g} s; outcome unknown"
            self._log.problem(f"command {verb}", f"mqtt {self.prefix}: cmd/{verb}: {error}")
            payload = _dumps({"request_id": cmd.request_id, "ok": False, "error": error}, "reply")
        except Exception as exc:
            self.counters.command_errors += 1
            error = str(exc) if isinstance(exc, RgseError) else f"{type(exc).__name__}: {exc}"
            self._log.problem(
                f"command {verb}",
                f"mqtt {self.prefix}: cmd/{verb} failed: {error}",
                exc_info=not isinstance(exc, RgseError),
            )
            payload = _dumps({"request_id": cmd.request_id, "ok": False, "error": error}, "reply")
        if (verb, cmd.request_id) in self._remembered:
            self._remembered[(verb, cmd.request_id)] = payload
        self._enqueue(_Out(self.topics.reply(verb), payload, qos=1), urgent=verb in URGENT_VERBS)
