"""Finding 7 of #12: log hygiene. A command flood does not flood the log (once, then a count); control characters
from outside are escaped before the log and the store; every MQTT payload writes times one way (ISO 8601 UTC)."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import re
import shutil
import uuid
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path

import pytest

from rgse_daemon.io import mqtt as mqtt_mod
from rgse_daemon.io.commands import parse_command
from rgse_daemon.io.mqtt import MqttBridge
from rgse_daemon.logs import RepeatThrottle, setup_logging
from rgse_daemon.procedures.events import Event
from rgse_daemon.store import Store
from tests.support.mqtt import ROBOT, Collector, RecordingHandler, clear_retained, mqtt_config
from tests.support.polling import wait_until

BROKER = ("127.0.0.1", 1883)
ISO_UTC = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")
FLOOD = 20_000


@pytest.fixture
async def prefix() -> AsyncIterator[str]:
    """A topic prefix of this test alone on the machine's broker; its retained messages are cleared afterwards."""
    p = f"rgse-test/{uuid.uuid4().hex[:12]}"
    yield p
    await clear_retained(*BROKER, p)


@pytest.fixture
async def store(tmp_path: Path):
    s = await Store.open(None, tmp_path / "data", timeout_s=10.0)
    try:
        yield s
    finally:
        await s.close()


async def test_command_flood_writes_queue_full_once_then_the_count(store, prefix, caplog):
    """20 000 commands from another process (mosquitto_pub) overflow the MQTT client's incoming queue; its
    "Message queue is full" is written once, and the copies are counted and written when the bridge stops."""
    mosquitto_pub = shutil.which("mosquitto_pub")
    assert mosquitto_pub, "the flood needs mosquitto_pub (package mosquitto-clients)"
    caplog.set_level(logging.WARNING)
    bridge = MqttBridge(mqtt_config(*BROKER, prefix), ROBOT, store, RecordingHandler(), "1", timeout_s=5)
    payload = json.dumps({"request_id": "flood", "reason": "flood"}).encode()
    async with bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        before = mqtt_mod._client_throttle.suppressed_total
        proc = await asyncio.create_subprocess_exec(mosquitto_pub, "-h", BROKER[0], "-p", str(BROKER[1]), "-q", "0",
                                                    "-t", f"{prefix}/cmd/abort", "-l", stdin=asyncio.subprocess.PIPE)
        async with asyncio.timeout(120):
            await proc.communicate(b"\n".join([payload] * FLOOD) + b"\n")
            async with Collector(*BROKER, f"{prefix}/#") as c:
                await c.sync()  # the broker has handed everything on
            await wait_until(lambda: bridge.counters.commands + bridge.counters.refused_commands > 0, "a command")
        written = [r.getMessage() for r in caplog.records if "queue is full" in r.getMessage()]
        assert len(written) == 1, written[:3]
    suppressed = mqtt_mod._client_throttle.suppressed_total - before
    assert suppressed > 0, "the flood did not overflow the client's queue; nothing was tested"
    counts = [r.getMessage() for r in caplog.records if "queue is full" in r.getMessage()][1:]
    assert counts == [f"Message queue is full. Discarding message. [and {suppressed} more times in the last "
                      f"{counts[0].rsplit(' ', 2)[-2]} s]"], counts
    assert len(caplog.records) < 50, [r.getMessage() for r in caplog.records][:50]


def test_repeats_are_counted_per_window_and_reported():
    now = [0.0]
    throttle = RepeatThrottle(window_s=60.0, clock=lambda: now[0])
    log = logging.getLogger(f"rgse-test-throttle-{uuid.uuid4().hex}")
    log.propagate = False
    log.setLevel(logging.INFO)
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.addFilter(throttle)
    log.addHandler(handler)
    for i in range(5000):
        now[0] = i * 0.01
        log.warning("could not stop the program: %s", "TimeoutError")
        log.info("info is never throttled")
    now[0] = 61.0
    log.warning("could not stop the program: %s", "TimeoutError")  # a new window: written with the count
    log.warning("another warning")
    log.error("could not stop the program: TimeoutError")  # another level: its own key
    lines = out.getvalue().splitlines()
    warnings = [ln for ln in lines if "info" not in ln]
    assert warnings == ["could not stop the program: TimeoutError",
                        "could not stop the program: TimeoutError [and 4999 more times in the last 61 s]",
                        "another warning", "could not stop the program: TimeoutError"]
    assert lines.count("info is never throttled") == 5000
    log.warning("another warning")
    (pending,) = throttle.pending()
    assert pending.getMessage() == "another warning [and 1 more times in the last 0 s]"


def test_daemon_log_handler_throttles_and_escapes():
    out = io.StringIO()
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    root.handlers = []
    try:
        handler = setup_logging(logging.INFO, "text", out)
        assert handler is not None
        log = logging.getLogger("rgse-test.hygiene")
        for _ in range(1000):
            log.warning("refused command: reason %r", "x")
        log.warning("abort reason: %s", "stop\x00now\x1b[2J\x7f")
        handler.close()  # as at shutdown: the count not yet written
    finally:
        root.handlers, _ = saved
        root.setLevel(saved[1])
    text = out.getvalue()
    assert text.count("refused command") == 2 and "[and 999 more times" in text
    assert "stop\\x00now\\x1b[2J\\x7f" in text and "\x00" not in text and "\x1b" not in text


async def test_nul_in_an_abort_reason_reaches_neither_log_nor_store_raw(store, prefix, caplog):
    """An abort with NUL and an escape sequence in its reason, over the real broker: the daemon's side gets the
    reason escaped (nothing dropped), and the store keeps it as such."""
    handler = RecordingHandler()
    bridge = MqttBridge(mqtt_config(*BROKER, prefix), ROBOT, store, handler, "1", timeout_s=5)
    raw_reason = "door\x00open\x1b[31m red\nline2"
    async with Collector(*BROKER, f"{prefix}/cmd/+/reply") as c, bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        await c.publish(f"{prefix}/cmd/abort", json.dumps({"request_id": "a1", "reason": raw_reason}))
        await c.publish(f"{prefix}/cmd/confirm", json.dumps({"request_id": "c1", "run_id": "r1",
                                                             "message": "ok\x00\x07"}))
        await c.wait_for(lambda ms: len(ms) >= 2, "two replies")
    (_, abort), (_, confirm) = handler.calls
    assert abort.reason == "door\\x00open\\x1b[31m red\\x0aline2"
    assert confirm.message == "ok\\x00\\x07"
    assert all(ch not in abort.reason for ch in "\x00\x1b\n")


def test_parse_command_escapes_controls_in_free_text():
    cmd = parse_command("abort", json.dumps({"request_id": "r", "reason": "a\u0000b\u009bc"}).encode())
    assert cmd.reason == "a\\x00b\\x9bc"  # type: ignore[union-attr]


def test_event_times_are_iso_utc():
    ev = Event("alarm", "interlock tripped", data={"watcher": "speed"}, time_s=1_700_000_000.25)
    assert ev.to_json()["time"] == "2023-11-14T22:13:20.250Z"


async def test_every_alarm_and_progress_payload_has_one_time_format(store, prefix):
    """Interlock alarms (engine events: were epoch seconds), daemon alarms, refusals and progress over the real
    broker: every ``time``/``since``/``*_utc`` field is an ISO 8601 UTC string."""
    bridge = MqttBridge(mqtt_config(*BROKER, prefix), ROBOT, store, RecordingHandler(), "1", timeout_s=5)
    async with Collector(*BROKER, f"{prefix}/#") as c, bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        bridge.publish_alarm(Event("alarm", "speed 260 mm/s over 200", data={"watcher": "speed"}).to_json())
        bridge.publish_alarm({"kind": "link_lost", "message": "controller unreachable"})
        bridge.publish_progress("run-1", Event("step", run_id="run-1", step="warm-up").to_json())
        bridge.publish_state({"safety_io": {"time_utc": datetime(2026, 1, 2, 3, 4, 5, 678000, UTC)}})
        await c.publish(f"{prefix}/cmd/measure", b"not json")
        await c.wait_for(lambda ms: len([m for m in ms if m.topic.value.endswith("/alarm")]) >= 3, "3 alarms")
        await c.wait_for(lambda ms: any(m.topic.value.endswith("/state") for m in ms), "state")
        await c.sync()
        docs = [(m.topic.value, json.loads(m.payload)) for m in c.messages
                if m.payload and not m.topic.value.endswith("/cmd/measure")]
    times: list[tuple[str, str, object]] = []

    def walk(topic: str, doc: object) -> None:
        if isinstance(doc, dict):
            for k, v in doc.items():
                if k in ("time", "since") or k.endswith("_utc"):
                    times.append((topic, k, v))
                walk(topic, v)

    for topic, doc in docs:
        walk(topic, doc)
    kinds = {t.rsplit("/", 1)[-1] for t, _, _ in times}
    assert {"alarm", "progress", "state", "status"} <= kinds, kinds
    bad = [(t, k, v) for t, k, v in times if not (isinstance(v, str) and ISO_UTC.match(v)) and v is not None]
    assert not bad, bad
    assert ("state" in {t.rsplit("/", 1)[-1] for t, _, _ in times}
            and any(v == "2026-01-02T03:04:05.678Z" for _, _, v in times))
