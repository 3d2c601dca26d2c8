"""Issue 31 6d: ``abort`` and ``confirm`` cannot be starved by a flood of commands on other topics.

A real flood against a real Mosquitto of this test alone: ``mosquitto_pub -l`` (its own process, in C) publishes
junk to ``cmd/measure`` as fast as it can, with no token, as anyone who reaches the broker can. Meanwhile an
operator sends valid aborts and confirms, one after the other; each must be handled and answered."""

from __future__ import annotations

import asyncio
import contextlib
import json
import uuid
from collections.abc import AsyncIterator
from typing import Any

import aiomqtt
import pytest

from rgse_daemon.io.mqtt import INCOMING_QUEUE, Inbox, MqttBridge
from rgse_daemon.store import Store
from tests.support.mqtt import ROBOT, Collector, MosquittoProcess, RecordingHandler, mqtt_config
from tests.support.polling import wait_until

TOKENS = ("s3cret-flood",)
PREFIX = "rgse-flood"
#: Valid commands sent during the flood (the issue: 5 of 6 aborts got no reply).
SENT = 6
#: A hang guard per reply, not a timing check: a reply dropped never comes.
REPLY_WAIT_S = 10.0
JUNK = b'{"request_id": "junk", "loops": 3}\n' * 20000


@contextlib.asynccontextmanager
async def flood(port: int, topic: str) -> AsyncIterator[asyncio.subprocess.Process]:
    """``mosquitto_pub -l`` publishing junk lines to ``topic`` (QoS 0) until the block ends."""
    proc = await asyncio.create_subprocess_exec(
        "mosquitto_pub", "-h", "127.0.0.1", "-p", str(port), "-t", topic, "-l", "-q", "0", "-i", "flooder",
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
    assert proc.stdin is not None
    stdin = proc.stdin

    async def feed() -> None:
        with contextlib.suppress(ConnectionError):
            while True:
                stdin.write(JUNK)
                await stdin.drain()

    feeding = asyncio.create_task(feed())
    try:
        yield proc
    finally:
        feeding.cancel()
        await asyncio.gather(feeding, return_exceptions=True)
        proc.kill()
        await proc.wait()


@pytest.mark.parametrize("verb", ["abort", "confirm"])
async def test_abort_and_confirm_are_answered_through_a_flood_on_another_topic(
        private_broker: MosquittoProcess, store: Store, verb: str) -> None:
    handler = RecordingHandler()
    port = private_broker.port
    bridge = MqttBridge(mqtt_config("127.0.0.1", port, PREFIX, command_tokens=TOKENS), ROBOT, store, handler, "1",
                        timeout_s=5)
    async with Collector("127.0.0.1", port, f"{PREFIX}/cmd/{verb}/reply") as op, bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        async with flood(port, f"{PREFIX}/cmd/measure"):
            await wait_until(lambda: bridge.counters.refused_commands > 1000, "the flood reaching the daemon", 30)
            answered = 0
            for _ in range(SENT):
                rid = uuid.uuid4().hex[:12]
                body: dict[str, Any] = {"request_id": rid, "token": TOKENS[0], "reason": "stop"} \
                    if verb == "abort" else {"request_id": rid, "token": TOKENS[0], "run_id": "run-1"}
                await op.publish(f"{PREFIX}/cmd/{verb}", json.dumps(body))

                def mine(ms: list[Any], rid: str = rid) -> bool:
                    return any(json.loads(m.payload).get("request_id") == rid for m in ms)

                with contextlib.suppress(AssertionError, TimeoutError):
                    await op.wait_for(mine, f"the reply to {verb} {rid}", REPLY_WAIT_S)
                    answered += 1
            flooded = bridge.counters.refused_commands
    assert flooded > 1000  # the flood was real: thousands refused meanwhile
    assert answered == SENT, f"{answered} of {SENT} {verb} commands answered during the flood ({flooded} refused)"
    assert [v for v, _ in handler.calls] == [verb] * SENT


async def test_while_the_urgent_connection_is_down_an_authorised_abort_jumps_the_full_queue(store: Store) -> None:
    """The main connection's incoming queue (what serves abort and confirm while their own connection is down): an
    authorised abort is taken ahead of a full queue of junk; one without the right token waits in line with it."""
    bridge = MqttBridge(mqtt_config("127.0.0.1", 1, PREFIX, command_tokens=TOKENS), ROBOT, store,
                        RecordingHandler(), "1", timeout_s=5)
    inbox = Inbox(INCOMING_QUEUE, urgent=bridge._urgent_message)

    def message(verb: str, doc: dict[str, Any]) -> aiomqtt.Message:
        return aiomqtt.Message(f"{PREFIX}/cmd/{verb}", json.dumps(doc).encode(), qos=1, retain=False, mid=1,
                               properties=None)

    for i in range(INCOMING_QUEUE):
        inbox.put_nowait(message("measure", {"request_id": f"junk-{i}"}))
    with pytest.raises(asyncio.QueueFull):
        inbox.put_nowait(message("measure", {"request_id": "one-more"}))
    with pytest.raises(asyncio.QueueFull):  # no token: no place of its own
        inbox.put_nowait(message("abort", {"request_id": "forged", "reason": "x"}))
    inbox.put_nowait(message("abort", {"request_id": "real", "reason": "x", "token": TOKENS[0]}))
    first = await inbox.get()
    assert json.loads(first.payload)["request_id"] == "real"
    assert json.loads((await inbox.get()).payload)["request_id"] == "junk-0"
