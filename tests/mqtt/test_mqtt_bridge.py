"""The MQTT bridge against real brokers: status and last will, results from the outbox, broker restart, state."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from rgse_daemon.config import MqttConfig
from rgse_daemon.errors import ConfigError
from rgse_daemon.io.mqtt import ConnectionState, MqttBridge, MqttError
from rgse_daemon.store import Store
from tests.support.mqtt import (
    ROBOT,
    Collector,
    MosquittoProcess,
    RecordingHandler,
    SessionThief,
    asyncio_complaints,
    mqtt_config,
    retained,
    stored_result,
)
from tests.support.polling import wait_until

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent


def _state_of(payload: bytes | bytearray) -> str:
    return json.loads(payload)["state"]


# --- status and last will ---------------------------------------------------------------------------------------
async def test_status_is_retained_online_while_running_and_offline_after_a_clean_stop(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler
) -> None:
    bridge = MqttBridge(mqtt_config(*system_broker, prefix), ROBOT, store, handler, "1.2.3", timeout_s=5)
    status = f"{prefix}/status"
    async with Collector(*system_broker, status) as live:
        async with bridge:
            await live.wait_for(lambda ms: len(ms) >= 1, "online status")
            (msg,) = await retained(*system_broker, status)
            assert msg.retain
            online = json.loads(msg.payload)
            assert online["state"] == "online" and online["version"] == "1.2.3"
            assert isinstance(online["since"], str) and online["since"].endswith("Z")
            assert bridge.connected and bridge.connection_state == ConnectionState.CONNECTED
        await live.wait_for(lambda ms: len(ms) >= 2, "offline status")
    assert [_state_of(m.payload) for m in live.messages] == ["online", "offline"]
    (msg,) = await retained(*system_broker, status)
    offline = json.loads(msg.payload)
    assert offline["state"] == "offline" and offline["version"] == "1.2.3" and isinstance(offline["since"], str)
    assert bridge.connection_state == ConnectionState.STOPPED and not bridge.connected
    assert bridge.counters.connects == 1 and bridge.counters.reconnects == 0
    await bridge.stop()  # idempotent


async def test_last_will_publishes_retained_offline_when_the_daemon_is_killed(
    system_broker: tuple[str, int], prefix: str, tmp_path: Path
) -> None:
    status = f"{prefix}/status"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    async with Collector(*system_broker, status) as live:
        child = await asyncio.create_subprocess_exec(
            sys.executable,
            str(HERE / "will_child.py"),
            *map(str, system_broker),
            prefix,
            str(tmp_path / "d"),
            env=env,
            stdin=subprocess.DEVNULL,
        )
        try:
            await live.wait_for(lambda ms: any(_state_of(m.payload) == "online" for m in ms), "child online")
            child.send_signal(signal.SIGKILL)  # no clean disconnect: only the broker can say offline now
            assert await asyncio.wait_for(child.wait(), 10) == -signal.SIGKILL
            await live.wait_for(lambda ms: _state_of(ms[-1].payload) == "offline", "last will")
        finally:
            if child.returncode is None:
                child.kill()
                await asyncio.wait_for(child.wait(), 10)
    will = json.loads(live.messages[-1].payload)
    assert will == {"state": "offline", "version": "9.9.9", "since": None}
    (msg,) = await retained(*system_broker, status)
    assert msg.retain and json.loads(msg.payload) == will


# --- results through the outbox ---------------------------------------------------------------------------------
async def _result_published_exactly_once(
    broker: tuple[str, int], prefix: str, store: Store, data_dir: Path, tmp_path: Path
) -> None:
    cfg = mqtt_config(*broker, prefix)
    results = f"{prefix}/run/+/result"
    async with Collector(*broker, results) as live:
        async with MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1", timeout_s=5) as bridge:
            await wait_until(lambda: bridge.connected, "connected")
            run, rec = await stored_result(store, data_dir, tmp_path, bridge.result_message, 107.65)
            bridge.notify_outbox()
            await wait_until(lambda: bridge.counters.outbox_published == 1, "outbox row published")
        await live.sync()
        (msg,) = live.messages
        assert msg.topic.value == f"{prefix}/run/{run.id}/result"
        assert json.loads(msg.payload) == rec.result
        assert await store.pending_outbox() == []

        # A restarted daemon finds nothing pending and publishes nothing again.
        async with MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1", timeout_s=5) as again:
            await wait_until(lambda: again.counters.outbox_sweeps >= 1, "first sweep of the restarted bridge")
        await live.sync()
        assert len(live.messages) == 1 and again.counters.outbox_published == 0

    fresh = await retained(*broker, results)
    assert len(fresh) == 1 and fresh[0].retain
    assert fresh[0].topic.value == f"{prefix}/run/{run.id}/result"
    assert json.loads(fresh[0].payload) == (await store.get_result(rec.id)).result


async def test_a_result_is_published_from_the_outbox_exactly_once_and_retained(
    system_broker: tuple[str, int], prefix: str, store: Store, data_dir: Path, tmp_path: Path
) -> None:
    await _result_published_exactly_once(system_broker, prefix, store, data_dir, tmp_path)


async def test_outbox_on_postgresql(
    system_broker: tuple[str, int], prefix: str, pg_store: Store, data_dir: Path, tmp_path: Path
) -> None:
    assert pg_store.dialect == "postgresql"
    await _result_published_exactly_once(system_broker, prefix, pg_store, data_dir, tmp_path)


async def test_outbox_rows_are_published_in_order_and_the_sweep_finds_rows_nobody_announced(
    system_broker: tuple[str, int], prefix: str, store: Store, data_dir: Path, tmp_path: Path
) -> None:
    cfg = mqtt_config(*system_broker, prefix)
    async with Collector(*system_broker, f"{prefix}/run/+/result") as live:
        bridge = MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1", timeout_s=5, outbox_sweep_s=0.2)
        async with bridge:
            await wait_until(lambda: bridge.connected, "connected")
            runs = [await stored_result(store, data_dir, tmp_path, bridge.result_message, 100.0 + i) for i in range(5)]
            # no notify_outbox(): the periodic sweep must find them
            await wait_until(lambda: bridge.counters.outbox_published == 5, "swept")
        await live.sync()
    assert [m.topic.value for m in live.messages] == [bridge.topics.result(run.id) for run, _ in runs]
    assert [json.loads(m.payload)["mass_kg"] for m in live.messages] == [100.0 + i for i in range(5)]


async def test_broker_restart_loses_nothing_and_duplicates_nothing_visible(
    private_broker: MosquittoProcess, store: Store, data_dir: Path, tmp_path: Path
) -> None:
    broker = ("127.0.0.1", private_broker.port)
    prefix = f"rgse/{ROBOT}"
    cfg = mqtt_config(*broker, None)  # the default prefix, rgse/<robot>
    bridge = MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1", timeout_s=3)
    assert bridge.prefix == prefix
    async with bridge:
        await wait_until(lambda: bridge.connected, "connected")
        before = [await stored_result(store, data_dir, tmp_path, bridge.result_message, 50.0)]
        bridge.notify_outbox()
        await wait_until(lambda: bridge.counters.outbox_published == 1, "first result published")

        await private_broker.stop()
        await wait_until(lambda: not bridge.connected, "connection loss noticed")
        during = [await stored_result(store, data_dir, tmp_path, bridge.result_message, 60.0 + i) for i in range(3)]
        bridge.notify_outbox()
        assert len(await store.pending_outbox()) == 3  # durable, waiting for the broker

        await private_broker.start()  # same port, same persistence directory
        await wait_until(lambda: bridge.counters.outbox_published == 4, "results written during the outage published")
        assert await store.pending_outbox() == []
        assert bridge.counters.reconnects >= 1 and bridge.counters.connects == bridge.counters.reconnects + 1

        fresh = await retained(*broker, f"{prefix}/run/+/result")
        by_topic: dict[str, list[bytes]] = {}
        for m in fresh:
            by_topic.setdefault(m.topic.value, []).append(bytes(m.payload))  # type: ignore[arg-type]
        expected = {bridge.topics.result(run.id): rec for run, rec in before + during}
        assert set(by_topic) == set(expected)
        for topic, payloads in by_topic.items():
            assert len(payloads) == 1, f"{topic}: {len(payloads)} retained copies"
            assert json.loads(payloads[0]) == (await store.get_result(expected[topic].id)).result
        (status,) = await retained(*broker, f"{prefix}/status")
        assert _state_of(status.payload) == "online"


# --- state ------------------------------------------------------------------------------------------------------
async def test_state_is_rate_limited_keeping_the_latest_and_drops_are_counted(
    system_broker: tuple[str, int], prefix: str, store: Store
) -> None:
    cfg = mqtt_config(*system_broker, prefix, state_rate_hz=2.0)
    state = f"{prefix}/state"
    async with Collector(*system_broker, state) as live, MqttBridge(cfg, ROBOT, store, RecordingHandler(), "1") as b:
        await wait_until(lambda: b.connected, "connected")
        # A burst without a single await in between: only the newest can ever be sent.
        for i in range(50):
            b.publish_state({"seq": i, "mode": "T1"})
        await live.wait_for(lambda ms: any(json.loads(m.payload)["seq"] == 49 for m in ms), "first burst")
        for i in range(50, 100):
            b.publish_state({"seq": i, "mode": "T1"})
        await live.wait_for(lambda ms: any(json.loads(m.payload)["seq"] == 99 for m in ms), "second burst")
        await wait_until(lambda: b.counters.state_published == 2, "PUBACK of the second state")
        assert [json.loads(m.payload)["seq"] for m in live.messages] == [49, 99]
        assert b.counters.dropped_state == 98
        last = json.loads(live.messages[-1].payload)
        assert last["mode"] == "T1" and last["mqtt"]["connection"] == "connected"
        assert last["mqtt"]["dropped_state"] >= 98 and "outbox_published" in last["mqtt"]

        # Interleaved with the loop: whatever the rate, sent + dropped accounts for every snapshot, the last wins.
        for i in range(100, 120):
            b.publish_state({"seq": i, "mode": "T1"})
            await asyncio.sleep(0.01)
        await wait_until(lambda: b.counters.state_published + b.counters.dropped_state == 120, "all sent or dropped")
        await live.sync()
        seqs = [json.loads(m.payload)["seq"] for m in live.messages]
        assert seqs == sorted(seqs) and seqs[-1] == 119 and len(seqs) == b.counters.state_published
    (msg,) = await retained(*system_broker, state)
    assert json.loads(msg.payload)["seq"] == 119


# --- progress and alarms ----------------------------------------------------------------------------------------
async def test_alarms_queued_before_the_connection_are_sent_after_it_and_progress_while_away_is_dropped(
    system_broker: tuple[str, int], prefix: str, store: Store
) -> None:
    bridge = MqttBridge(mqtt_config(*system_broker, prefix), ROBOT, store, RecordingHandler(), "1", timeout_s=5)
    bridge.publish_alarm({"kind": "link_loss", "message": "controller link lost"})
    bridge.publish_progress("run-1", {"step": "warm-up"})
    assert bridge.counters.dropped_progress == 1
    async with Collector(*system_broker, f"{prefix}/alarm", f"{prefix}/run/+/progress") as live, bridge:
        await live.wait_for(lambda ms: len(ms) >= 1, "alarm")
        await wait_until(lambda: bridge.connected, "connected")
        bridge.publish_progress("run-1", {"step": "loop", "i": 1, "n": 10, "eta_s": 42.0})
        await live.wait_for(lambda ms: len(ms) >= 2, "progress")
    (alarm,) = live.json_on(f"{prefix}/alarm")
    assert alarm["kind"] == "link_loss" and alarm["message"] == "controller link lost" and "time" in alarm
    (progress,) = live.on(f"{prefix}/run/run-1/progress")
    assert progress.qos == 0 and json.loads(progress.payload) == {"step": "loop", "i": 1, "n": 10, "eta_s": 42.0}


async def test_what_is_queued_when_the_daemon_stops_goes_out_before_offline(
    system_broker: tuple[str, int], prefix: str, store: Store
) -> None:
    """A run that ends as the daemon stops withdraws its prompt and raises its alarms in the last moments: a clean stop
    sends what is queued before it says offline (it cancelled the sender, and the queue was lost)."""
    bridge = MqttBridge(mqtt_config(*system_broker, prefix), ROBOT, store, RecordingHandler(), "1", timeout_s=5)
    async with Collector(*system_broker, f"{prefix}/alarm", f"{prefix}/status") as live:
        async with bridge:
            await wait_until(lambda: bridge.connected, "connected")
            for i in range(50):
                bridge.publish_alarm({"kind": "test", "message": f"alarm {i}"})
            bridge.publish_prompt(None, "run-1")  # the run ended while it waited
        await live.wait_for(lambda ms: any(_state_of(m.payload) == "offline" for m in live.on(f"{prefix}/status")),
                            "offline status")
    assert [a["message"] for a in live.json_on(f"{prefix}/alarm")] == [f"alarm {i}" for i in range(50)]
    (prompt,) = await retained(*system_broker, f"{prefix}/prompt")
    assert json.loads(prompt.payload)["pending"] is False


async def test_unpublishable_messages_are_refused_at_their_source(store: Store) -> None:
    bridge = MqttBridge(mqtt_config("127.0.0.1", 1883, "p"), ROBOT, store, RecordingHandler(), "1")
    with pytest.raises(MqttError, match="not JSON-serialisable"):
        bridge.publish_state({"x": float("nan")})
    with pytest.raises(MqttError, match="run id"):
        bridge.publish_progress("a/b", {})
    with pytest.raises(MqttError, match="run id"):
        bridge.result_message("#")
    with pytest.raises(MqttError, match="a dict expected"):
        bridge.publish_alarm(["not", "a", "dict"])  # type: ignore[arg-type]
    await bridge.start()
    try:
        with pytest.raises(MqttError, match="already started"):
            await bridge.start()
    finally:
        await bridge.stop()


def test_bad_settings_are_config_errors_before_any_io(tmp_path: Path) -> None:
    def make(cfg: MqttConfig) -> MqttBridge:
        return MqttBridge(cfg, ROBOT, None, RecordingHandler(), "1")  # type: ignore[arg-type]

    with pytest.raises(ConfigError, match="reconnect_min_s"):
        make(MqttConfig(reconnect_min_s=5, reconnect_max_s=1))
    with pytest.raises(ConfigError, match=r"without mqtt\.username"):
        make(MqttConfig(password="secret"))
    with pytest.raises(ConfigError, match="cannot load CA"):
        make(MqttConfig(tls=True, tls_ca_file=tmp_path / "missing.pem"))
    with pytest.raises(ConfigError, match="tls is false"):
        make(MqttConfig(tls_ca_file=tmp_path / "ca.pem"))
    with pytest.raises(ConfigError, match="timeout_s"):
        MqttBridge(MqttConfig(), ROBOT, None, RecordingHandler(), "1", timeout_s=0)  # type: ignore[arg-type]


async def test_stop_during_a_connect_that_gets_no_answer_is_prompt(store: Store) -> None:
    """A broker that accepts TCP but never answers CONNECT (hung, or a firewall's half-open port): stop does not
    wait out the connect timeout (30 s here) — there is no session to close cleanly."""
    accepted = asyncio.Event()
    held: list[asyncio.StreamWriter] = []

    async def silent(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        held.append(writer)
        accepted.set()

    server = await asyncio.start_server(silent, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        bridge = MqttBridge(mqtt_config("127.0.0.1", port, "rgse/silent"), ROBOT, store, RecordingHandler(), "1",
                            timeout_s=30)
        await bridge.start()
        async with asyncio.timeout(10):
            await accepted.wait()
        assert not bridge.connected
        async with asyncio.timeout(5):  # well inside the 30 s connect timeout
            await bridge.stop()
        assert bridge.connection_state is ConnectionState.STOPPED
    finally:
        for w in held:
            w.close()
        server.close()
        await server.wait_closed()


async def test_a_session_that_drops_right_after_connack_keeps_backing_off(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler,
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A broker that accepts the connection and drops the session at once (here: another client with our id takes
    the session over right after each CONNACK, as a second daemon with the same client_id would) gets ever longer
    pauses, not a reconnect every reconnect_min_s forever: a session shorter than reconnect_max_s resets nothing."""
    client_id = f"rgse-test-{uuid.uuid4().hex[:12]}"
    # A takeover that lands while the subscribe or the "online" publish awaits its ack is noticed only when that
    # call times out (aiomqtt does not fail pending calls on a disconnect): such a session lasts up to timeout_s,
    # here longer than reconnect_max_s. It never got online, so it does not count as a session that held.
    cfg = mqtt_config(*system_broker, prefix, client_id=client_id, reconnect_min_s=0.05, reconnect_max_s=0.5)
    bridge = MqttBridge(cfg, ROBOT, store, handler, "1", timeout_s=1)
    attempts: list[int] = []  # observation only: the attempt number each pause is computed for (not exposed)
    backoff = bridge._backoff_s
    monkeypatch.setattr(bridge, "_backoff_s", lambda attempt: attempts.append(attempt) or backoff(attempt))
    async with SessionThief(*system_broker, client_id) as thief, bridge:
        await wait_until(lambda: len(attempts) >= 4, "four reconnects", timeout_s=30)
    assert attempts[:4] == [0, 1, 2, 3]
    # each connect succeeded (CONNACK) and each session was then lost to the thief: not connect failures
    assert bridge.counters.connect_failures == 0
    assert bridge.counters.connects >= 4 and bridge.counters.reconnects == bridge.counters.connects - 1
    assert thief.takeovers >= bridge.counters.connects - 1  # the bridge's connect pushed the thief off each time
    said = [r.message for r in caplog.records if r.name == "rgse_daemon.io.mqtt"]
    assert any("connection lost" in m for m in said) and not any("cannot connect" in m for m in said)


async def test_a_session_taken_over_leaves_no_exception_unretrieved(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler,
    caplog: pytest.LogCaptureFixture
) -> None:
    """Each takeover ends a session with aiomqtt's "Unexpected disconnection" set on a future of the client. When the
    session ends otherwise (its subscribe or "online" publish times out waiting for the ack, or a stop), nobody read
    that future: asyncio logged "Future exception was never retrieved" once the client was collected."""
    client_id = f"rgse-test-{uuid.uuid4().hex[:12]}"
    # A short timeout_s: many sessions. Which call sees a takeover is a race: about half of the sessions are lost
    # while the subscribe or the online publish awaits its ack (the others fail a publish at once, which reads the
    # reason), so twenty sessions leave some unread (3 to 12 of 20 in six runs before the fix).
    cfg = mqtt_config(*system_broker, prefix, client_id=client_id, reconnect_min_s=0.01, reconnect_max_s=0.05)
    bridge = MqttBridge(cfg, ROBOT, store, handler, "1", timeout_s=0.25)
    with asyncio_complaints(caplog) as complaints:
        async with bridge:
            async with SessionThief(*system_broker, client_id) as thief:
                await wait_until(lambda: bridge.counters.connects >= 20, "twenty sessions", timeout_s=30)
            # the takeovers end: the bridge reconnects and stays online, and this test ends with a clean stop (a stop
            # in the middle of a connect is the subject of test_mqtt_connect_teardown.py)
            await wait_until(lambda: bridge.connected, "online once the takeovers ended", timeout_s=10)
    assert [m for m in complaints if "never retrieved" in m] == []
    # and the bridge reconnected after each takeover: lost sessions, no failed connects
    assert thief.takeovers >= 19 and bridge.counters.connect_failures == 0
    said = [r.message for r in caplog.records if r.name == "rgse_daemon.io.mqtt"]
    assert any("connection lost" in m for m in said)
