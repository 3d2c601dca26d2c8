"""Commands over a real broker: valid ones reach the handler and are answered; anything else is refused unheard."""

from __future__ import annotations

import asyncio
import contextlib
import json
import ssl
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.io.commands import (
    AbortCommand,
    CalibrateCommand,
    CommandRefused,
    ConfirmCommand,
    MeasureCommand,
    parse_command,
)
from rgse_daemon.io.mqtt import MqttBridge
from rgse_daemon.store import Store, StoreError
from tests.support.mqtt import ROBOT, Collector, MosquittoProcess, RecordingHandler, mqtt_config, retained
from tests.support.polling import wait_until

TOKENS = ("s3cret-1", "s3cret-2")


class Session:
    """A running bridge plus an operator's client listening to replies and alarms."""

    def __init__(self, bridge: MqttBridge, client: Collector) -> None:
        self.bridge = bridge
        self.client = client

    async def send(self, verb: str, payload: Any) -> None:
        raw = payload if isinstance(payload, bytes | str) else json.dumps(payload)
        await self.client.publish(f"{self.bridge.prefix}/cmd/{verb}", raw)

    async def replies(self, n: int) -> list[tuple[str, dict[str, Any]]]:
        """The first ``n`` replies as (verb, payload)."""
        p = self.bridge.prefix

        def got(ms: list[Any]) -> bool:
            return len([m for m in ms if m.topic.value.endswith("/reply")]) >= n

        await self.client.wait_for(got, f"{n} replies")
        out = []
        for m in self.client.messages:
            if m.topic.value.endswith("/reply"):
                verb = m.topic.value[len(f"{p}/cmd/") : -len("/reply")]
                out.append((verb, json.loads(m.payload)))
        return out[:n]

    def alarms(self) -> list[dict[str, Any]]:
        return self.client.json_on(f"{self.bridge.prefix}/alarm")


@contextlib.asynccontextmanager
async def _session(
    broker: tuple[str, int], prefix: str, store: Store, handler: Any, **kw: Any
) -> AsyncIterator[Session]:
    cfg_overrides = {k: kw.pop(k) for k in list(kw) if k in ("command_tokens",)}
    bridge = MqttBridge(mqtt_config(*broker, prefix, **cfg_overrides), ROBOT, store, handler, "1", timeout_s=5, **kw)
    async with Collector(*broker, f"{prefix}/cmd/+/reply", f"{prefix}/alarm") as client, bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        yield Session(bridge, client)


@pytest.fixture
async def session(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler
) -> AsyncIterator[Session]:
    async with _session(system_broker, prefix, store, handler) as s:
        yield s


@pytest.fixture
async def guarded(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler
) -> AsyncIterator[Session]:
    """A bridge that demands a token."""
    async with _session(system_broker, prefix, store, handler, command_tokens=TOKENS) as s:
        yield s


async def test_valid_commands_reach_the_handler_and_are_answered_ok(
    session: Session, handler: RecordingHandler
) -> None:
    await session.send("measure", {"request_id": "m-1", "loops": 10, "fixture_mass_kg": 10.288, "dry_run": True})
    await session.send(
        "calibrate",
        {
            "request_id": "c-1",
            "method": "paper",
            "points": [
                {"kind": "zero", "mass_kg": 0.0, "lever_a3_m": 1.29, "lever_a5_m": 0.265},
                {"kind": "mass", "mass_kg": 20.93, "lever_a3_m": 1.3075, "lever_a5_m": 0.2825},
            ],
        },
    )
    await session.send("confirm", {"request_id": "f-1", "run_id": "run-1", "point": 1})
    await session.send("abort", {"request_id": "a-1", "reason": "operator"})
    replies = dict((body["request_id"], (verb, body)) for verb, body in await session.replies(4))
    assert {rid: verb for rid, (verb, _) in replies.items()} == {
        "m-1": "measure",
        "c-1": "calibrate",
        "f-1": "confirm",
        "a-1": "abort",
    }
    assert all(body["ok"] is True and body["accepted"] is True for _, body in replies.values())

    calls = dict((cmd.request_id, cmd) for _, cmd in handler.calls)
    assert calls["m-1"] == MeasureCommand(request_id="m-1", loops=10, fixture_mass_kg=10.288, dry_run=True)
    cal = calls["c-1"]
    assert isinstance(cal, CalibrateCommand) and cal.method == "paper" and [p.mass_kg for p in cal.points] == [0, 20.93]
    assert calls["f-1"] == ConfirmCommand(request_id="f-1", run_id="run-1", point=1)
    assert calls["a-1"] == AbortCommand(request_id="a-1", reason="operator")
    assert session.bridge.counters.commands == 4 and session.bridge.counters.refused_commands == 0
    await session.client.sync()
    assert session.alarms() == []


async def test_a_command_seen_again_is_answered_again_and_not_run_twice(
    session: Session, handler: RecordingHandler
) -> None:
    """A QoS 1 redelivery (a PUBACK lost with the connection) or a script that sends twice: the same verb and
    request_id run once; the second copy gets the first one's reply. Another verb with that id is another command."""
    await session.send("measure", {"request_id": "m-1", "loops": 3})
    first = await session.replies(1)
    await session.send("measure", {"request_id": "m-1", "loops": 3})
    await session.send("abort", {"request_id": "m-1", "reason": "operator"})
    got = await session.replies(3)
    assert got[0] == got[1] == ("measure", {"accepted": True, "run_id": "run-1", "request_id": "m-1", "ok": True})
    assert first == got[:1] and got[2][0] == "abort" and got[2][1]["run_id"] == "run-2"
    assert [(verb, cmd.request_id) for verb, cmd in handler.calls] == [("measure", "m-1"), ("abort", "m-1")]
    assert session.bridge.counters.duplicate_commands == 1 and session.bridge.counters.commands == 2
    assert session.alarms() == []  # not a refusal


@pytest.mark.parametrize(
    ("verb", "payload", "request_id", "error"),
    [
        ("measure", b'{"request_id": "x-1", "loops": ', None, "malformed JSON"),
        ("measure", b"\xff\xfe", None, "malformed JSON"),
        ("measure", b'["request_id", "x-2"]', None, "a JSON object expected"),
        ("measure", {"request_id": "x-3", "loops": 10, "dryrun": True}, "x-3", "dryrun: unknown field"),
        ("measure", {"request_id": "x-4", "loops": "10"}, "x-4", "loops: Input should be a valid integer"),
        ("measure", {"request_id": "x-5", "loops": 0}, "x-5", "loops: Input should be greater than or equal to 1"),
        ("measure", {"request_id": "x-6", "fixture_mass_kg": "NaN"}, "x-6", "fixture_mass_kg"),
        ("abort", {"request_id": "x-7"}, "x-7", "reason: Field required"),
        ("confirm", {"request_id": "x-8", "run_id": "../etc"}, "x-8", "run_id"),
        ("calibrate", {"request_id": "x-9", "points": [{"kind": "zero"}]}, "x-9", "points.0.mass_kg"),
        ("selfdestruct", {"request_id": "x-10"}, None, "unknown verb 'selfdestruct'"),
        ("measure", {"loops": 3}, None, "request_id: Field required"),
        # issue 31 6e: the last of two equal keys does not silently win (a run that is not the dry run asked for)
        ("measure", b'{"request_id": "x-11", "dry_run": true, "dry_run": false}', "x-11", "duplicate key 'dry_run'"),
        ("calibrate", b'{"request_id": "x-12", "points": [{"kind": "zero", "mass_kg": 0, "mass_kg": 5, '
                      b'"lever_a3_m": 1.29, "lever_a5_m": 0.265}]}', "x-12", "duplicate key 'mass_kg'"),
        ("abort", b'{"request_id": "x-13", "request_id": "x-14", "reason": "x"}', None, "duplicate key 'request_id'"),
    ],
)
async def test_bad_commands_are_refused_without_effect(
    session: Session,
    handler: RecordingHandler,
    verb: str,
    payload: Any,
    request_id: str | None,
    error: str,
) -> None:
    await session.send(verb, payload)
    ((reply_verb, reply),) = await session.replies(1)
    assert reply_verb == verb
    assert reply["ok"] is False and reply["request_id"] == request_id and error in reply["error"]
    await session.client.wait_for(lambda ms: any(m.topic.value.endswith("/alarm") for m in ms), "alarm")
    (alarm,) = session.alarms()
    assert alarm["kind"] == "refused_command" and alarm["message"] == "refused command"
    assert alarm["verb"] == verb and alarm["request_id"] == request_id and error in alarm["error"]
    assert handler.calls == []
    assert session.bridge.counters.refused_commands == 1 and session.bridge.counters.commands == 0


async def test_a_deeply_nested_payload_is_refused_and_the_next_command_is_served(
    session: Session, handler: RecordingHandler
) -> None:
    """60 000 nested '[' make the json module raise RecursionError (not a ValueError): it is refused like any
    malformed JSON, and the command loop goes on (no reconnect, the command behind it is not lost)."""
    await session.send("measure", b"[" * 60000)
    await session.send("measure", {"request_id": "after", "loops": 3})
    (verb, refused), (_, served) = await session.replies(2)
    assert verb == "measure" and refused == {"request_id": None, "ok": False,
                                             "error": "malformed JSON: nested too deeply"}
    assert served["request_id"] == "after" and served["ok"] is True
    assert [cmd.request_id for _, cmd in handler.calls] == ["after"]
    assert session.bridge.counters.connects == 1 and session.bridge.counters.refused_commands == 1


async def test_unknown_verbs_of_any_length_cost_bounded_memory_and_log(
    session: Session, handler: RecordingHandler, caplog: pytest.LogCaptureFixture
) -> None:
    """Anyone who can publish picks the verb (the topic level, up to 64 KiB, checked before any token): each is
    answered on its own reply topic, but what the daemon keeps and writes about it is cut short."""
    verbs = [f"v{i}-" + "x" * 20000 for i in range(20)]
    for verb in verbs:
        await session.send(verb, {"request_id": "u"})
    replies = await session.replies(len(verbs))
    assert [v for v, _ in replies] == verbs  # the sender hears its refusal where it listens
    assert all(r["error"] == f"unknown verb {v[:64] + '…'!r}; expected one of measure, properties, calibrate, "
               "abort, confirm" for v, r in replies)
    await session.client.wait_for(lambda ms: len(session.alarms()) == len(verbs), "the alarms")
    assert all(a["verb"] == v[:64] + "…" for v, a in zip(verbs, session.alarms(), strict=True))
    refusals = [r.getMessage() for r in caplog.records if "refused command" in r.getMessage()]
    assert refusals and all(len(m) < 400 for m in refusals)
    # what the bridge remembers to log each problem once: one entry for every unknown verb together (it kept one
    # per verb, 20 kB each, for the daemon's lifetime)
    assert len(session.bridge._log._last) == 1
    assert handler.calls == []


async def test_a_retained_command_is_not_replayed_to_a_new_session(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler
) -> None:
    """A command left retained on the broker is delivered to every new subscription, e.g. the daemon's after a
    reconnect or a restart: it is refused there; the same command sent live is carried out."""
    topic = f"{prefix}/cmd/measure"
    async with Collector(*system_broker, f"{prefix}/nothing") as sender:
        await sender._client.publish(topic, json.dumps({"request_id": "r-1", "loops": 3}), qos=1, retain=True)
    try:
        async with _session(system_broker, prefix, store, handler) as session:
            ((_, reply),) = await session.replies(1)
            assert reply == {"request_id": "r-1", "ok": False,
                             "error": "retained command ignored: publish commands with retain=false"}
            assert handler.calls == []
            await session.send("measure", {"request_id": "r-2", "loops": 3})
            await wait_until(lambda: len(handler.calls) == 1, "the live command reached the handler")
            assert handler.calls[0][1].request_id == "r-2"
    finally:
        async with Collector(*system_broker, f"{prefix}/nothing") as sender:
            await sender._client.publish(topic, b"", qos=1, retain=True)  # clear it from the shared broker


async def test_without_the_right_token_nothing_happens(guarded: Session, handler: RecordingHandler) -> None:
    await guarded.send("measure", {"request_id": "t-1", "loops": 3})
    await guarded.send("measure", {"request_id": "t-2", "loops": 3, "token": "guess"})
    await guarded.send("abort", {"request_id": "t-3", "reason": "x", "token": None})
    # unauthorised and against the schema: the sender learns it is unauthorised, nothing about the schema
    await guarded.send("measure", {"request_id": "t-4", "bogus": 1})
    refused = await guarded.replies(4)
    # abort comes on a connection of its own (issue 31 6d): its reply's place among the others is not fixed
    assert sorted((r["request_id"], v, r["ok"]) for v, r in refused) == sorted((rid, v, ok) for v, rid, ok in [
        ("measure", "t-1", False),
        ("measure", "t-2", False),
        ("abort", "t-3", False),
        ("measure", "t-4", False),
    ])
    assert all("unauthorised" in r["error"] and "bogus" not in r["error"] for _, r in refused)
    assert handler.calls == [] and guarded.bridge.counters.refused_commands == 4

    await guarded.send("measure", {"request_id": "t-5", "loops": 3, "token": TOKENS[1]})
    (ok,) = [r for _, r in await guarded.replies(5) if r["request_id"] == "t-5"]
    assert ok["ok"] is True and ok["request_id"] == "t-5"
    ((verb, cmd),) = handler.calls
    assert verb == "measure" and cmd.loops == 3 and "s3cret" not in repr(cmd)
    await guarded.client.sync()
    assert len(guarded.alarms()) == 4


async def test_handler_failures_become_error_replies_and_the_bridge_keeps_serving(
    session: Session, handler: RecordingHandler
) -> None:
    handler.failures = {"e-1": StoreError("store: disk full"), "e-2": ValueError("a bug")}
    await session.send("measure", {"request_id": "e-1"})
    await session.send("measure", {"request_id": "e-2"})
    first = await session.replies(2)
    await session.send("measure", {"request_id": "e-3"})
    _, _, (_, third) = await session.replies(3)
    errors = {r["request_id"]: r for _, r in first}
    assert errors["e-1"] == {"request_id": "e-1", "ok": False, "error": "store: disk full"}
    assert errors["e-2"]["ok"] is False and errors["e-2"]["error"] == "ValueError: a bug"
    assert third["ok"] is True and third["request_id"] == "e-3"
    assert session.bridge.counters.command_errors == 2 and session.bridge.counters.commands == 3


class SlowHandler(RecordingHandler):
    """``measure`` never answers (until cancelled); ``abort`` answers at once."""

    def __init__(self) -> None:
        super().__init__()
        self.cancelled = asyncio.Event()

    async def measure(self, cmd: MeasureCommand) -> dict[str, Any]:
        self.calls.append(("measure", cmd))
        try:
            await asyncio.Event().wait()
        except asyncio.CancelledError:
            self.cancelled.set()
            raise
        raise AssertionError("unreachable")


async def test_a_slow_handler_times_out_and_does_not_block_other_commands(
    system_broker: tuple[str, int], prefix: str, store: Store
) -> None:
    handler = SlowHandler()
    async with _session(system_broker, prefix, store, handler, command_timeout_s=1.0) as s:
        await s.send("measure", {"request_id": "slow"})
        await wait_until(lambda: len(handler.calls) == 1, "measure reached the handler")
        await s.send("abort", {"request_id": "quick", "reason": "operator"})
        (verb, quick), (_, slow) = await s.replies(2)
        assert verb == "abort" and quick["ok"] is True  # answered while measure was still running
        assert slow["request_id"] == "slow" and slow["ok"] is False and "outcome unknown" in slow["error"]
        assert handler.cancelled.is_set() and s.bridge.counters.command_errors == 1


async def test_commands_in_flight_are_cancelled_on_stop(
    system_broker: tuple[str, int], prefix: str, store: Store
) -> None:
    handler = SlowHandler()
    async with _session(system_broker, prefix, store, handler) as s:
        await s.send("measure", {"request_id": "slow"})
        await wait_until(lambda: len(handler.calls) == 1, "measure reached the handler")
    assert handler.cancelled.is_set()  # the leak guard of conftest checks nothing else was left running


async def test_username_and_password_are_used(
    tmp_path: Path, store: Store, handler: RecordingHandler, caplog: pytest.LogCaptureFixture
) -> None:
    pw = tmp_path / "passwd"
    proc = await asyncio.create_subprocess_exec("mosquitto_passwd", "-b", "-c", str(pw), "rgse", "pa55")
    assert await asyncio.wait_for(proc.wait(), 10) == 0
    broker = MosquittoProcess(tmp_path / "auth", f"allow_anonymous false\npassword_file {pw}\n")
    await broker.start()
    try:
        addr = ("127.0.0.1", broker.port)
        wrong = MqttBridge(
            mqtt_config(*addr, "auth", username="rgse", password="nope"), ROBOT, store, handler, "1", timeout_s=3
        )
        async with wrong:
            await wait_until(lambda: wrong.counters.connect_failures >= 3, "refused three times, backing off")
            assert not wrong.connected and wrong.counters.connects == 0
        refusals = [r for r in caplog.records if r.name == "rgse_daemon.io.mqtt" and "cannot connect" in r.message]
        assert len(refusals) == 1, "the same error is logged once, not on every attempt"
        right = MqttBridge(
            mqtt_config(*addr, "auth", username="rgse", password="pa55"), ROBOT, store, handler, "1", timeout_s=3
        )
        async with right:
            await wait_until(lambda: right.connected, "connected with the right password")
        (status,) = await retained(*addr, "auth/status", username="rgse", password="pa55")
        assert json.loads(status.payload)["state"] == "offline"
    finally:
        await broker.stop()


def test_parse_command_without_a_broker() -> None:
    """The schema layer alone: verbs, strict types, bounds, token before schema."""
    cmd = parse_command("measure", b'{"request_id": "r", "fixture_mass_kg": 10}')
    assert cmd == MeasureCommand(request_id="r", fixture_mass_kg=10.0) and cmd.dry_run is False
    with pytest.raises(CommandRefused, match="dry_run") as exc:
        parse_command("measure", b'{"request_id": "r", "dry_run": "yes"}')
    assert exc.value.request_id == "r" and exc.value.verb == "measure"
    with pytest.raises(CommandRefused, match="exceeds"):
        parse_command("abort", b'{"reason": "' + b"x" * 70000 + b'"}')
    with pytest.raises(CommandRefused, match="unauthorised"):
        parse_command("abort", b'{"request_id": "r", "reason": "x", "token": "s3cret-10"}', TOKENS)
    assert parse_command("abort", b'{"request_id": "r", "reason": "x", "token": "s3cret-1"}', TOKENS).reason == "x"


def test_the_identity_of_a_measure_or_properties_command() -> None:
    """interfaces §4.3 ``identity``: the given keys kept (control characters escaped), unknown keys, empty or
    overlong values and non-strings refused."""
    cmd = parse_command("measure", json.dumps({"request_id": "r", "identity": {
        "dut_name": "Refex wing box", "serial_number": "SN-0042", "note": "bolts\x1b[2J torqued"}}))
    assert cmd.identity is not None and cmd.identity.as_json() == {
        "dut_name": "Refex wing box", "serial_number": "SN-0042", "note": "bolts\\x1b[2J torqued"}
    assert parse_command("properties", json.dumps({"request_id": "r", "identity": {"project": "GSE-7"}})
                         ).identity.as_json() == {"project": "GSE-7"}
    assert parse_command("measure", json.dumps({"request_id": "r", "identity": {}})).identity.as_json() is None
    for bad, said in (({"customer": "ESA"}, "identity.customer: unknown field"),
                      ({"dut_name": ""}, "identity.dut_name"), ({"dut_name": "x" * 201}, "identity.dut_name"),
                      ({"serial_number": 42}, "identity.serial_number")):
        with pytest.raises(CommandRefused, match=said):
            parse_command("measure", json.dumps({"request_id": "r", "identity": bad}))


async def _run(*argv: str) -> None:
    proc = await asyncio.create_subprocess_exec(
        *argv, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT
    )
    out, _ = await asyncio.wait_for(proc.communicate(), 30)
    assert proc.returncode == 0, f"{argv[0]}: {out.decode(errors='replace')}"


async def test_tls_with_a_private_ca(tmp_path: Path, store: Store, handler: RecordingHandler) -> None:
    """A broker with a certificate signed by our own CA: the bridge verifies it with ``tls_ca_file``."""
    d = tmp_path / "pki"
    d.mkdir()
    ca_key, ca, key, csr, crt = (d / n for n in ("ca.key", "ca.pem", "server.key", "server.csr", "server.pem"))
    await _run(
        "openssl",
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "2",
        "-subj",
        "/CN=rgse test CA",
        "-keyout",
        str(ca_key),
        "-out",
        str(ca),
    )
    await _run(
        "openssl",
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-subj",
        "/CN=127.0.0.1",
        "-keyout",
        str(key),
        "-out",
        str(csr),
    )
    ext = d / "san.cnf"
    ext.write_text("subjectAltName=IP:127.0.0.1\n")
    await _run(
        "openssl",
        "x509",
        "-req",
        "-in",
        str(csr),
        "-CA",
        str(ca),
        "-CAkey",
        str(ca_key),
        "-CAcreateserial",
        "-days",
        "2",
        "-extfile",
        str(ext),
        "-out",
        str(crt),
    )
    broker = MosquittoProcess(tmp_path / "tls", f"allow_anonymous true\ncafile {ca}\ncertfile {crt}\nkeyfile {key}\n")
    await broker.start()
    try:
        addr = ("127.0.0.1", broker.port)
        cfg = mqtt_config(*addr, "tls", tls=True, tls_ca_file=ca)
        bridge = MqttBridge(cfg, ROBOT, store, handler, "1", timeout_s=3)
        async with bridge:
            await wait_until(lambda: bridge.connected, "connected over TLS")
        untrusting = MqttBridge(mqtt_config(*addr, "tls", tls=True), ROBOT, store, handler, "1", timeout_s=3)
        async with untrusting:  # the system CAs do not know our CA: the handshake must fail
            await wait_until(lambda: untrusting.counters.connect_failures >= 1, "certificate refused")
            assert untrusting.counters.connects == 0
        tls = ssl.create_default_context(cafile=str(ca))
        (status,) = await retained(*addr, "tls/status", tls_context=tls)
        assert json.loads(status.payload)["state"] == "offline"
    finally:
        await broker.stop()
