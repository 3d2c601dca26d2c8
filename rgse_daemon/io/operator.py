"""The operator's MQTT client: what ``rgse status``, ``rgse confirm`` and ``rgse abort`` say to a running daemon.

Broker, prefix, credentials, TLS and command token come from the daemon's own configuration file. Each use is one
short connection with a fresh client id (never the configured ``client_id``: a broker drops the older of two
connections with the same id, which would be the daemon's), a clean session, no will, and ONE deadline over
everything it waits for: connect, subscribe, publish, the reply (the disconnect after it, or the close of a connect
it ended, is bounded by ``DISCONNECT_S``). A command is validated with the daemon's own
:func:`~rgse_daemon.io.commands.parse_command` before it is sent; the reply is told apart from other senders' by its
``request_id`` (the daemon copies it from the command; replies of every sender share the reply topic).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import secrets
import ssl
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import aiomqtt

from rgse_daemon.config import Config, load_config
from rgse_daemon.errors import ConfigError, RgseError
from rgse_daemon.io.commands import parse_command
from rgse_daemon.io.mqtt_client import Client, connection, enter, tls_context
from rgse_daemon.io.topics import Topics

log = logging.getLogger(__name__)

T = TypeVar("T")

DEFAULT_TIMEOUT_S = 10.0
#: Retained messages come right after the subscription is granted; this long without another one ends reading.
RETAINED_QUIET_S = 0.5
#: Bound of the disconnect at the end of a conversation (s).
DISCONNECT_S = 2.0


class Unreachable(RgseError):
    """The broker or the daemon did not answer as needed within the deadline (exit status 2)."""


@dataclass(frozen=True)
class Endpoint:
    """Where the daemon of a configuration file talks: its broker, credentials and topic prefix."""

    host: str
    port: int
    topics: Topics
    username: str | None
    password: str | None = field(repr=False)
    tls: ssl.SSLContext | None
    keepalive_s: int
    token: str | None = field(repr=False)
    """The first configured command token, sent with every command (``None``: commands carry none)."""

    @property
    def broker(self) -> str:
        return f"mqtt broker {self.host}:{self.port}{' (TLS)' if self.tls is not None else ''}"


def endpoint(path: Path) -> Endpoint:
    """The daemon's MQTT endpoint from its configuration file; :class:`ConfigError` when it has none."""
    return endpoint_of(load_config(path), path)


def endpoint_of(cfg: Config, path: Path | str = "<config>") -> Endpoint:
    """The MQTT endpoint of the daemon configured by ``cfg`` (``path`` names it in errors)."""
    m = cfg.mqtt
    if not m.enabled:
        raise ConfigError(f"{path}: mqtt.enabled is false: the daemon of this configuration is not on a broker")
    if m.password is not None and m.username is None:
        raise ConfigError(f"{path}: mqtt.password is set without mqtt.username")
    return Endpoint(
        host=m.host,
        port=m.port,
        topics=Topics.of(m, cfg.robot.name),  # as the daemon's bridge derives them
        username=m.username,
        password=m.password,
        tls=tls_context(m),
        keepalive_s=m.keepalive_s,
        token=m.command_tokens[0] if m.command_tokens else None,
    )


def check_timeout(value: float | None) -> float:
    """``--timeout``: a finite number of seconds > 0; ``None`` gives the default."""
    if value is None:
        return DEFAULT_TIMEOUT_S
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"--timeout {value!r}: must be a finite number of seconds > 0")
    return float(value)


def payload_json(message: aiomqtt.Message) -> Any:
    """A message's payload as JSON, or as text when it is not JSON."""
    raw = message.payload
    if isinstance(raw, bytes | bytearray):
        try:
            return json.loads(raw)
        except (ValueError, UnicodeDecodeError, RecursionError):  # RecursionError: nested too deeply
            return bytes(raw).decode("utf-8", errors="replace")
    if isinstance(raw, str):
        try:
            return json.loads(raw)
        except (ValueError, RecursionError):
            return raw
    return raw


def describe_status(status: Any) -> str:
    """The daemon's retained ``status`` in words."""
    if not isinstance(status, dict):
        return "unknown (nothing retained: has a daemon with this prefix ever connected?)"
    text = str(status.get("state", "?"))
    if status.get("since"):
        text += f" since {status['since']}"
    elif status.get("state") == "offline":
        text += " (connection lost: the broker sent its last will)"
    if status.get("version"):
        text += f", version {status['version']}"
    return text


def daemon_offline(status: Any) -> bool:
    """Whether the daemon's retained ``status`` says it is not on the broker (stopped, or its last will)."""
    return isinstance(status, dict) and status.get("state") == "offline"


def new_client(ep: Endpoint, purpose: str, timeout_s: float) -> Client:
    """An operator's connection: a fresh client id (never the daemon's), a clean session, no will. Enter it with
    :func:`~rgse_daemon.io.mqtt_client.enter` (or :func:`~rgse_daemon.io.mqtt_client.connection`), so that a connect
    given up leaves nothing open."""
    return Client(
        ep.host,
        ep.port,
        username=ep.username,
        password=ep.password,
        identifier=f"rgse-cli-{purpose}-{secrets.token_hex(6)}",
        logger=log.getChild("client"),
        clean_session=True,
        keepalive=ep.keepalive_s,
        timeout=timeout_s,
        tls_context=ep.tls,
    )


def _not_closed(message: str) -> None:
    """A connect given up whose close goes on past ``DISCONNECT_S`` (its connect thread is still connecting; the
    connection is closed once made): not worth a warning on the operator's stderr, whose one error line says what
    went wrong."""
    log.debug("%s", message)


async def subscribe_checked(client: aiomqtt.Client, ep: Endpoint, filters: Iterable[str]) -> None:
    """Subscribe (QoS 1) to ``filters``; :class:`Unreachable` when the broker refuses one (ACL)."""
    wanted = list(filters)
    granted = await client.subscribe([(f, 1) for f in wanted])
    refused = [f for f, g in zip(wanted, granted, strict=False) if int(getattr(g, "value", g)) >= 0x80]
    if refused:
        raise Unreachable(f"{ep.broker}: subscription refused (broker ACL?): {', '.join(refused)}")


class Conversation:
    """One short connection to the daemon's broker under one deadline.

    ``doing`` says what is being waited for, so that a timeout or a lost connection is reported as the step it
    interrupted; ``latest`` keeps the newest message per topic.
    """

    def __init__(self, ep: Endpoint, purpose: str, timeout_s: float) -> None:
        self.ep = ep
        self.timeout_s = timeout_s
        self.doing = "connecting"
        self.latest: dict[str, aiomqtt.Message] = {}
        self._client = new_client(ep, purpose, timeout_s)  # its per-call bound; the deadline below ends first

    async def run(self, body: Callable[[Conversation], Awaitable[T]]) -> T:
        """Connect, run ``body``, disconnect; :class:`Unreachable` on any broker problem or at the deadline.

        The deadline covers connecting and ``body``; the disconnect after it is bounded by ``DISCONNECT_S``, and a
        failed disconnect after ``body`` returned does not change the outcome. So is the close of a connect that the
        deadline ended (its connect thread may still be connecting: the connection is closed once it is made).
        """
        answered = False
        try:
            async with asyncio.timeout(self.timeout_s) as deadline, connection(self._client, close_s=DISCONNECT_S,
                                                                               on_not_closed=_not_closed):
                try:
                    value = await body(self)
                    answered = True
                    deadline.reschedule(None)  # the answer is in
                finally:
                    self._client.timeout = min(self.timeout_s, DISCONNECT_S)  # bounds the disconnect
        except TimeoutError:
            raise Unreachable(
                f"{self.ep.broker}: no answer within {self.timeout_s:g} s while {self.doing}{self._hint()}"
            ) from None
        except aiomqtt.MqttError as exc:
            if not answered:
                what = "cannot connect" if self.doing == "connecting" else f"connection lost while {self.doing}"
                raise Unreachable(f"{self.ep.broker}: {what}: {exc}") from None
            log.debug("%s: disconnect: %s", self.ep.broker, exc)
        return value

    def _hint(self) -> str:
        if self.doing.startswith(("connecting", "subscribing")):
            return ""
        return f"; the daemon's retained status: {self.describe_status()}"

    def describe_status(self) -> str:
        """The daemon's retained status as received so far, in words (:func:`describe_status`)."""
        return describe_status(self.json_of(self.ep.topics.status))

    async def daemon_offline(self, wait_s: float) -> bool:
        """Whether the daemon's retained status says it is offline; waits up to ``wait_s`` for that status if it
        has not arrived yet (it is retained: normally at once). Subscribe to the status topic first."""
        if self.ep.topics.status not in self.latest:
            await self.read_retained(wait_s, until=self.ep.topics.status)
        return daemon_offline(self.json_of(self.ep.topics.status))

    def json_of(self, topic: str) -> Any:
        message = self.latest.get(topic)
        return None if message is None else payload_json(message)

    async def subscribe(self, filters: Iterable[str]) -> None:
        wanted = list(filters)
        self.doing = f"subscribing to {', '.join(wanted)}"
        await subscribe_checked(self._client, self.ep, wanted)

    def _keep(self, message: aiomqtt.Message) -> None:
        if message.payload not in (None, b"", ""):  # an empty retained payload is a cleared topic
            self.latest[message.topic.value] = message

    async def read_retained(self, quiet_s: float = RETAINED_QUIET_S, *, until: str | None = None) -> None:
        """Collect messages until none RETAINED came for ``quiet_s`` (live ones, e.g. state, do not extend it).

        With ``until``: stop as soon as that topic has a message, waiting for it up to ``quiet_s``.
        """
        self.doing = "reading the retained topics" if until is None else f"waiting for a message on {until}"
        loop = asyncio.get_running_loop()
        quiet_until = loop.time() + quiet_s
        while until is None or until not in self.latest:
            left = quiet_until - loop.time()
            if left <= 0:
                return
            try:
                async with asyncio.timeout(left):  # nested in the deadline; not wait_for (3.11 can lose a cancel)
                    message = await anext(self._client.messages)
            except TimeoutError:
                return
            self._keep(message)
            if message.retain and until is None:
                quiet_until = loop.time() + quiet_s

    async def command(self, verb: str, fields: dict[str, Any]) -> dict[str, Any]:
        """Send one command and return the daemon's reply to it; subscribe to the reply topic first."""
        request_id, raw = build_command(verb, fields, self.ep.token)
        reply_topic = self.ep.topics.reply(verb)
        topic = self.ep.topics.command(verb)
        self.doing = f"publishing to {topic}"
        await self._client.publish(topic, raw, qos=1)
        self.doing = f"waiting for the daemon's reply on {reply_topic}"
        async for message in self._client.messages:
            self._keep(message)
            if message.topic.value != reply_topic:
                continue
            doc = payload_json(message)
            if isinstance(doc, dict) and doc.get("request_id") == request_id:
                return doc
        raise aiomqtt.MqttError("message stream ended")  # aiomqtt ends it only by raising; for the type checker


class Session:
    """A long-lived operator connection (for scripts and the Python client): one connect, the subscriptions held,
    every message handed to ``on_message(topic, payload, retained)`` as it arrives, and commands whose replies are
    matched by ``request_id``. Every wait has its own deadline; a lost connection ends the session (the reader's
    error is raised to whoever waits next) — a script should fail loudly rather than silently miss a prompt.
    """

    def __init__(self, ep: Endpoint, purpose: str, filters: Iterable[str],
                 on_message: Callable[[str, Any, bool], None], timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.ep = ep
        self.timeout_s = check_timeout(timeout_s)
        self._filters = list(filters)
        self._on_message = on_message
        self._purpose = purpose
        self._mqtt: Client | None = None  # made on entering: an aiomqtt client belongs to the running loop
        self._replies: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self._reader: asyncio.Task[None] | None = None
        self.failure: BaseException | None = None

    @property
    def _client(self) -> Client:
        if self._mqtt is None:
            raise RuntimeError("Session: use it as `async with`")
        return self._mqtt

    async def __aenter__(self) -> Session:
        self._mqtt = new_client(self.ep, self._purpose, self.timeout_s)
        try:
            async with asyncio.timeout(self.timeout_s):
                # a connect given up (this deadline, a cancellation) is closed within DISCONNECT_S
                await enter(self._client, close_s=DISCONNECT_S, on_not_closed=_not_closed)
                try:
                    replies = f"{self.ep.topics.prefix}/cmd/+/reply"
                    await subscribe_checked(self._client, self.ep, [*self._filters, replies])
                except BaseException:
                    await self._client.__aexit__(None, None, None)
                    raise
        except TimeoutError:
            raise Unreachable(f"{self.ep.broker}: no connection within {self.timeout_s:g} s") from None
        except aiomqtt.MqttError as exc:
            raise Unreachable(f"{self.ep.broker}: cannot connect: {exc}") from None
        self._reader = asyncio.create_task(self._read(), name="rgse-operator-session")
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._reader is not None:
            self._reader.cancel()
            await asyncio.gather(self._reader, return_exceptions=True)
        self._client.timeout = min(self.timeout_s, DISCONNECT_S)
        try:
            async with asyncio.timeout(DISCONNECT_S + 1.0):
                await self._client.__aexit__(None, None, None)
        except (aiomqtt.MqttError, TimeoutError) as exc:
            log.debug("%s: disconnect: %s", self.ep.broker, exc)

    async def _read(self) -> None:
        try:
            async for message in self._client.messages:
                if message.payload in (None, b"", ""):
                    continue  # a cleared retained topic
                topic = message.topic.value
                try:
                    doc = payload_json(message)
                    if topic.endswith("/reply") and isinstance(doc, dict):
                        waiter = self._replies.pop(str(doc.get("request_id")), None)
                        if waiter is not None and not waiter.done():
                            waiter.set_result(doc)
                            continue
                    self._on_message(topic, doc, bool(message.retain))
                except Exception:  # one message it cannot take must not end the reading, unnoticed, for good
                    log.error("%s: a message on %s not handled", self.ep.broker, topic, exc_info=True)
        except aiomqtt.MqttError as exc:
            self.failure = Unreachable(f"{self.ep.broker}: connection lost: {exc}")
            for waiter in self._replies.values():
                if not waiter.done():
                    waiter.set_exception(self.failure)
            self._on_message("", None, False)  # wakes the waiters, who find ``failure``

    async def command(self, verb: str, fields: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        """Send one command (validated first: :class:`CommandRefused`) and return the daemon's reply to it;
        :class:`Unreachable` when no reply comes within ``timeout_s`` (default: the session's)."""
        if self.failure is not None:
            raise self.failure
        request_id, raw = build_command(verb, fields, self.ep.token)
        waiter: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._replies[request_id] = waiter
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        try:
            async with asyncio.timeout(wait_s):
                await self._client.publish(self.ep.topics.command(verb), raw, qos=1)
                return await waiter
        except TimeoutError:
            raise Unreachable(
                f"{self.ep.broker}: no reply to cmd/{verb} within {wait_s:g} s on {self.ep.topics.reply(verb)}"
            ) from None
        except aiomqtt.MqttError as exc:
            raise Unreachable(f"{self.ep.broker}: cmd/{verb} not sent: {exc}") from None
        finally:
            self._replies.pop(request_id, None)


def build_command(verb: str, fields: dict[str, Any], token: str | None) -> tuple[str, bytes]:
    """A command with a fresh ``request_id``, checked as the daemon checks it; :class:`CommandRefused` if not."""
    request_id = f"cli-{secrets.token_hex(8)}"
    doc = {"request_id": request_id, **{k: v for k, v in fields.items() if v is not None}}
    if token is not None:
        doc["token"] = token
    raw = json.dumps(doc, separators=(",", ":")).encode()
    parse_command(verb, raw, (token,) if token is not None else ())
    return request_id, raw


def check_fields(verb: str, fields: dict[str, Any]) -> None:
    """Check the operator's part of a command before any network I/O; :class:`CommandRefused` if invalid."""
    build_command(verb, fields, None)


# --- rgse status ---------------------------------------------------------------------------------------------------
async def read_status(ep: Endpoint, timeout_s: float) -> dict[str, Any]:
    """The retained status, state and results under the endpoint's prefix."""
    t = ep.topics

    async def body(conv: Conversation) -> dict[str, Any]:
        await conv.subscribe((t.status, t.state, t.results))
        await conv.read_retained()
        results = {}
        head, tail = f"{t.prefix}/run/", "/result"
        for topic in sorted(conv.latest):
            if topic.startswith(head) and topic.endswith(tail):
                results[topic[len(head) : -len(tail)]] = conv.json_of(topic)
        return {
            "broker": f"{ep.host}:{ep.port}",
            "prefix": t.prefix,
            "status": conv.json_of(t.status),
            "state": conv.json_of(t.state),
            "results": results,
        }

    return await Conversation(ep, "status", timeout_s).run(body)
