"""The operator's client (``rgse status/confirm/abort`` and the Python client) leaves nothing behind when it gives up.

Its connections are short and end at one deadline (:class:`~rgse_daemon.io.operator.Conversation`) or are held by
a script for its lifetime (:class:`~rgse_daemon.io.operator.Session`). aiomqtt (2.5) runs paho's blocking connect in
an executor thread and then waits for the CONNACK; a deadline that lands in either wait used to leave the connection
to itself — the thread connected anyway, aiomqtt's misc task ran on pinging the socket, and a CONNACK wait cancelled
by the deadline made aiomqtt's disconnect callback raise ("Exception in callback") when the socket closed later. And
a session the broker ended while the subscribe waited for its SUBACK (another client taking the client id over) left
aiomqtt's "Unexpected disconnection" unread: "Future exception was never retrieved" once the client was collected.
And a deadline that ends within a millisecond of aiomqtt's own CONNACK timeout (they are equally long) made closing
the connection fail inside aiomqtt's disconnect callback.

The brokers are raw TCP listeners (:class:`~tests.support.mqtt.TcpPeer`) where the connect must be slow for certain,
and the machine's Mosquitto, behind such a listener that holds a SUBSCRIBE back, for the takeovers.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable
from typing import Any

import pytest

from rgse_daemon.config import config_from_mapping
from rgse_daemon.io.operator import DISCONNECT_S, Conversation, Endpoint, Session, Unreachable, endpoint_of
from tests.support.mqtt import SUBSCRIBE, SessionThief, TcpPeer, aiomqtt_tasks, asyncio_complaints
from tests.support.polling import wait_until


def _endpoint(port: int, prefix: str = "rgse/silent") -> Endpoint:
    return endpoint_of(config_from_mapping({"mqtt": {"enabled": True, "host": "127.0.0.1", "port": port,
                                                     "prefix": prefix, "command_auth": "open_lab_bench"}}))


async def _read_status(conv: Conversation) -> dict[str, Any]:
    t = conv.ep.topics
    await conv.subscribe((t.status, t.state))
    await conv.read_retained(0.05)
    return {"status": conv.json_of(t.status)}


def _ignore(topic: str, doc: Any, retained: bool) -> None:
    """A session's message handler that takes no interest in the messages."""


async def _failure(aw: Awaitable[object]) -> str:
    """Why ``aw`` raised :class:`Unreachable`, as text: the exception itself (its traceback holds the client) is not
    kept, so that the client can be collected before the test checks what asyncio said."""
    try:
        await aw
    except Unreachable as exc:
        return str(exc)
    return "no failure"


async def test_a_conversation_whose_connack_does_not_come_closes_its_connection(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A broker that accepts TCP and never answers CONNECT (a wrong port, a hung broker): ``rgse status`` says so at
    its deadline, and the connection it opened is closed then, not left to aiomqtt's misc task until the keepalive
    runs out; the broker closing its side afterwards makes asyncio log nothing."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            with pytest.raises(Unreachable, match=r"no answer within 0\.5 s while connecting"):
                await Conversation(_endpoint(peer.port), "status", 0.5).run(_read_status)
            assert peer.accepted == 1
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)  # the peer closed its side: nothing of the client may still react to that
    assert complaints == []


async def test_conversations_whose_deadline_meets_the_connack_timeout_close_their_connections(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A conversation's deadline and its client's CONNACK timeout are equally long: against a broker that never
    answers CONNECT they end within a millisecond of each other. aiomqtt's timeout cancels its CONNACK future and
    replaces it only a few loop iterations later; the DISCONNECT that closes the connection given up, written in
    between, made aiomqtt's disconnect callback raise ``CancelledError`` inside paho ("Exception in callback") before
    paho closed the socket, which then stayed open with aiomqtt's misc task. A race, most often lost with a few
    conversations at a time (as scripts or several consoles run them): a hundred, five at a time."""

    async def give_up() -> None:
        with pytest.raises(Unreachable, match="while connecting"):
            await Conversation(ep, "status", 0.05).run(_read_status)

    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(backlog=16) as peer:
            ep = _endpoint(peer.port)
            for _ in range(20):
                await asyncio.gather(*(give_up() for _ in range(5)))
            assert peer.accepted == 100
            await wait_until(lambda: peer.closed_by_client == 100, "every connection closed", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)
    assert complaints == []


async def test_a_conversation_whose_deadline_passes_in_the_threaded_connect_closes_the_connection_once_made(
    system_broker: tuple[str, int], caplog: pytest.LogCaptureFixture
) -> None:
    """The deadline lands while aiomqtt's executor thread is still in paho's ``connect()`` (the broker's accept queue
    is full: the SYN is retried about a second later). The conversation is over, but the thread goes on and connects
    — that connection is closed as soon as it is made, bounded by the disconnect's deadline, rather than held with
    aiomqtt's misc task pinging it."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(forward_to=system_broker, backlog_full=True) as peer:
            conv = Conversation(_endpoint(peer.port), "status", 0.3)
            running = asyncio.create_task(conv.run(_read_status))
            await asyncio.sleep(0.5)  # past the deadline, the thread still waits in connect() for the SYN's retry
            assert peer.accepted == 0
            peer.release()
            t0 = time.monotonic()
            with pytest.raises(Unreachable, match=r"no answer within 0\.3 s while connecting"):
                await running
            assert time.monotonic() - t0 < DISCONNECT_S + 0.5
            await wait_until(lambda: peer.accepted == 1, "the thread's connect arrived", timeout_s=10)
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            await wait_until(lambda: aiomqtt_tasks() == [], "aiomqtt's tasks ended", timeout_s=3)
    assert complaints == []


async def test_a_session_whose_connack_does_not_come_closes_its_connection(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The long-lived session of the Python client, against a broker that never answers CONNECT: ``async with``
    raises :class:`Unreachable` at the session's deadline, and the connection is closed then."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            ep = _endpoint(peer.port)
            with pytest.raises(Unreachable, match=r"no connection within 0\.5 s"):
                async with Session(ep, "client", [ep.topics.status], _ignore, timeout_s=0.5):
                    pytest.fail("connected to a broker that never answers")
            assert peer.accepted == 1
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)
    assert complaints == []


async def test_a_session_cancelled_while_connecting_closes_its_connection(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A script that gives up on a session while it connects (its own deadline, a Ctrl-C) cancels the ``async
    with``: the cancellation goes through, and the connection being made is closed, not left connected."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            ep = _endpoint(peer.port)

            async def connect() -> None:
                async with Session(ep, "client", [ep.topics.status], _ignore, timeout_s=30):
                    pytest.fail("connected to a broker that never answers")

            connecting = asyncio.create_task(connect())
            await wait_until(lambda: peer.accepted == 1, "the connection accepted", timeout_s=10)
            connecting.cancel()
            async with asyncio.timeout(DISCONNECT_S + 1):  # well inside the session's 30 s
                with pytest.raises(asyncio.CancelledError):
                    await connecting
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)
    assert complaints == []


async def test_a_conversation_taken_over_while_subscribing_leaves_no_exception_unretrieved(
    system_broker: tuple[str, int], prefix: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The broker ends the session while the subscribe waits for its SUBACK — here another client takes the client
    id over, as a broker restart or a network drop would end it too. aiomqtt fails no pending call on a lost
    connection, so the conversation ends at its deadline, and aiomqtt's "Unexpected disconnection" was read by
    nobody: asyncio logged "Future exception was never retrieved" (a traceback on the CLI's stderr) once the client
    was collected. The SUBSCRIBE is held back on its way to the broker, so that the takeover lands while it waits."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(forward_to=system_broker, hold_from=SUBSCRIBE) as peer:
            conv = Conversation(_endpoint(peer.port, prefix), "status", 1.0)
            running = asyncio.create_task(_failure(conv.run(_read_status)))
            del conv
            await wait_until(lambda: peer.held == 1, "the subscribe sent", timeout_s=5)
            async with SessionThief(*system_broker, peer.client_ids[0]):
                assert "no answer within 1 s while subscribing" in await running
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
    assert complaints == []


async def test_a_session_taken_over_while_subscribing_leaves_no_exception_unretrieved(
    system_broker: tuple[str, int], prefix: str, caplog: pytest.LogCaptureFixture
) -> None:
    """As for a conversation: the Python client's session, whose connection the broker ends while ``async with``
    waits for the SUBACK, raises :class:`Unreachable` at its deadline, and leaves no unread exception behind."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(forward_to=system_broker, hold_from=SUBSCRIBE) as peer:
            ep = _endpoint(peer.port, prefix)

            async def connect() -> None:
                async with Session(ep, "client", [ep.topics.status], _ignore, timeout_s=1.0):
                    pytest.fail("subscribed though the SUBSCRIBE never reached the broker")

            running = asyncio.create_task(_failure(connect()))
            await wait_until(lambda: peer.held == 1, "the subscribe sent", timeout_s=5)
            async with SessionThief(*system_broker, peer.client_ids[0]):
                assert "no connection within 1 s" in await running
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
    assert complaints == []
