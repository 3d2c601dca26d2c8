"""A connection attempt the bridge gives up (a stop during the connect, a CONNACK that never comes) leaves nothing.

aiomqtt (2.5) runs paho's blocking connect in an executor thread and then waits for the CONNACK. A cancellation
there used to leave the connection to itself: the thread connected anyway and aiomqtt's ``Client._misc_loop`` task
ran on after ``MqttBridge.stop()`` had returned (a live client of a stopped daemon), and a CONNACK wait cancelled
by asyncio left a cancelled future that aiomqtt's disconnect callback then read ("Exception in callback").

The brokers here are raw TCP listeners, so that the connect is slow for certain: one whose accept queue is full
(the connect's SYN is dropped and retried after about a second, with the thread waiting in ``connect()``), then
forwarding to the real Mosquitto; and one that accepts and never answers CONNECT.
"""

from __future__ import annotations

import asyncio

import aiomqtt
import paho.mqtt.client as paho
import pytest

from rgse_daemon.io import mqtt_client
from rgse_daemon.io.mqtt import ConnectionState, MqttBridge
from rgse_daemon.store import Store
from tests.support.mqtt import ROBOT, RecordingHandler, TcpPeer, aiomqtt_tasks, asyncio_complaints, mqtt_config
from tests.support.polling import wait_until


async def test_a_stop_during_the_threaded_tcp_connect_leaves_no_client_behind(
    system_broker: tuple[str, int], prefix: str, store: Store, caplog: pytest.LogCaptureFixture
) -> None:
    """The stop lands while aiomqtt's executor thread is still in paho's ``connect()``: the stop waits for that
    thread and closes the connection it made, rather than leaving a client that connects (and stays connected,
    its misc task running) after the daemon said it had stopped."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(forward_to=system_broker, backlog_full=True) as peer:
            bridge = MqttBridge(mqtt_config("127.0.0.1", peer.port, prefix), ROBOT, store, RecordingHandler(), "1",
                                timeout_s=5)
            await bridge.start()
            await asyncio.sleep(0.3)  # the connect's SYN was dropped: its thread waits in connect() for the retry
            assert bridge.connection_state is ConnectionState.CONNECTING and peer.accepted == 0
            stopping = asyncio.create_task(bridge.stop())
            await asyncio.sleep(0.1)
            peer.release()  # the retried SYN (about 1 s after the first) gets through while the stop runs
            async with asyncio.timeout(10):
                await stopping
            assert bridge.connection_state is ConnectionState.STOPPED
            assert aiomqtt_tasks() == []
            # the thread's connection reached the broker (before the stop returned, or, unfixed, after it) ...
            await wait_until(lambda: peer.accepted == 1, "the thread's connect arrived", timeout_s=10)
            # ... and was closed by the client, not left open with aiomqtt's misc task pinging it
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
    assert complaints == []


async def test_a_stop_whose_deadline_passes_in_the_threaded_connect_closes_the_connection_once_made(
    system_broker: tuple[str, int], prefix: str, store: Store, caplog: pytest.LogCaptureFixture
) -> None:
    """The connect thread can block longer than the stop may take (up to paho's connect timeout): the stop returns
    at its deadline, says so, and the connection is closed as soon as the thread has made it."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer(forward_to=system_broker, backlog_full=True) as peer:
            bridge = MqttBridge(mqtt_config("127.0.0.1", peer.port, prefix), ROBOT, store, RecordingHandler(), "1",
                                timeout_s=5, stop_timeout_s=0.2)
            await bridge.start()
            await asyncio.sleep(0.3)  # the connect's SYN was dropped: its thread waits in connect() for the retry
            assert bridge.connection_state is ConnectionState.CONNECTING and peer.accepted == 0
            async with asyncio.timeout(2):
                await bridge.stop()
            assert any("not closed within 0.2 s" in r.getMessage() for r in caplog.records)
            peer.release()
            await wait_until(lambda: peer.accepted == 1, "the thread's connect arrived", timeout_s=10)
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
            await wait_until(lambda: aiomqtt_tasks() == [], "aiomqtt's tasks ended", timeout_s=3)
    assert complaints == []


async def test_a_stop_during_the_connack_wait_closes_the_connection_and_asyncio_logs_nothing(
    store: Store, caplog: pytest.LogCaptureFixture
) -> None:
    """A broker that accepts TCP and never answers CONNECT: the stop is prompt (the existing promptness test), and
    it also closes that connection — aiomqtt's misc task does not run on — and the broker closing its side later
    makes asyncio log nothing (aiomqtt read the CONNACK future the cancellation had left cancelled)."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            bridge = MqttBridge(mqtt_config("127.0.0.1", peer.port, "rgse/silent"), ROBOT, store, RecordingHandler(),
                                "1", timeout_s=30)
            await bridge.start()
            await wait_until(lambda: peer.accepted == 1, "the connection accepted", timeout_s=10)
            async with asyncio.timeout(5):  # well inside the 30 s connect timeout
                await bridge.stop()
            assert aiomqtt_tasks() == []
            await wait_until(lambda: peer.closed_by_client == 1, "the client closed its connection", timeout_s=3)
        await asyncio.sleep(0.1)  # the peer closed its side: nothing of the client may still react to that
    assert complaints == []


async def test_a_connect_whose_connack_times_out_closes_its_connection(
    store: Store, caplog: pytest.LogCaptureFixture
) -> None:
    """Each attempt against a broker that never answers CONNECT ends at ``timeout_s``; the bridge closes the
    attempt's connection then (aiomqtt leaves it open, its misc task running, until the keepalive runs out),
    so a long outage of that kind does not pile up connections and tasks."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            cfg = mqtt_config("127.0.0.1", peer.port, "rgse/silent", reconnect_min_s=0.01, reconnect_max_s=0.05)
            bridge = MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1", timeout_s=0.3)
            async with bridge:
                await wait_until(lambda: peer.accepted >= 3, "three attempts", timeout_s=15)
                await wait_until(lambda: peer.closed_by_client >= 2, "the timed-out attempts closed", timeout_s=3)
                assert peer.closed_by_client >= peer.accepted - 1  # all but the attempt in flight
                assert aiomqtt_tasks().count("Client._misc_loop") <= 1  # that of the attempt in flight, if any
            assert aiomqtt_tasks() == []
            await wait_until(lambda: peer.closed_by_client == peer.accepted, "every connection closed", timeout_s=3)
    assert complaints == []


def test_the_aiomqtt_internals_the_bridge_relies_on_are_there() -> None:
    """What the bridge reads or overrides of aiomqtt's private side to tear down a connect it gives up (see
    ``rgse_daemon.io.mqtt_client.Client`` and ``_close_unentered``): a rename in an aiomqtt upgrade fails here, not
    silently in the field (where the guards would make a stop during a connect slow again, or leave it open)."""
    assert callable(getattr(aiomqtt.Client, "_client_connect", None))
    assert mqtt_client._CONNECT_RETURN_SEEN
    # every wait for an ack goes through _wait_for, which Client overrides (a cancellation with the ack is not lost)
    assert callable(getattr(aiomqtt.Client, mqtt_client._WAIT_FOR, None))
    assert mqtt_client.Client._wait_for is not aiomqtt.Client._wait_for

    async def build() -> aiomqtt.Client:
        return aiomqtt.Client("127.0.0.1")

    client = asyncio.run(build())
    assert isinstance(getattr(client, "_client", None), paho.Client)
    assert hasattr(client, "_misc_task") and client._misc_task is None
    # the disconnect reason read (Client) and the CONNACK wait a cancelled connect leaves (Client._on_disconnect)
    assert isinstance(getattr(client, "_disconnected", None), asyncio.Future)
    assert isinstance(getattr(client, "_connected", None), asyncio.Future)
    # paho calls aiomqtt's _on_disconnect as the bound method, so the subclass' override is the one it calls
    assert callable(getattr(aiomqtt.Client, "_on_disconnect", None))
    assert client._client.on_disconnect == client._on_disconnect
