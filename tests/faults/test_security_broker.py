"""Finding 8 of #12: secure by default, and the documented broker set-up tested against a real Mosquitto.

The broker is started by the test on a loopback port with TLS only (a CA and a server certificate made here with
openssl), logins from mosquitto_passwd and deploy/mosquitto.acl as its ACL — the set-up docs/security.md
describes. The daemon's side is the real MqttBridge with ``command_auth = "broker_acl"``.
"""

from __future__ import annotations

import asyncio
import json
import os
import ssl
import subprocess
import sys
import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

from rgse_daemon.config import MqttConfig, config_from_mapping
from rgse_daemon.errors import ConfigError
from rgse_daemon.io.mqtt import MqttBridge
from rgse_daemon.store import Store
from tests.support.mqtt import MosquittoProcess, RecordingHandler, clear_retained, mqtt_config
from tests.support.polling import wait_until

ROOT = Path(__file__).resolve().parents[2]
ACL = ROOT / "deploy" / "mosquitto.acl"
ROBOT = "KR500R2830-SEC"
PREFIX = f"rgse/{ROBOT}"
PASSWORDS = {"rgse": "daemon-pw-1", "operator": "operator-pw-2", "viewer": "viewer-pw-3"}


def run(*argv: str) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, f"{argv[0]}: {done.stderr}"


def make_pki(d: Path) -> tuple[Path, Path, Path]:
    """A CA and a server certificate for 127.0.0.1 signed by it (openssl, RSA 2048, valid 2 days)."""
    d.mkdir()
    ca_key, ca, key, csr, crt, ext = (d / n for n in ("ca.key", "ca.pem", "broker.key", "broker.csr", "broker.pem",
                                                      "san.cnf"))
    run("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=rgse test CA",
        "-keyout", str(ca_key), "-out", str(ca))
    run("openssl", "req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout", str(key),
        "-out", str(csr))
    ext.write_text("subjectAltName=IP:127.0.0.1\n")
    run("openssl", "x509", "-req", "-in", str(csr), "-CA", str(ca), "-CAkey", str(ca_key), "-CAcreateserial",
        "-days", "2", "-extfile", str(ext), "-out", str(crt))
    return ca, crt, key


@pytest.fixture
async def broker(tmp_path: Path) -> AsyncIterator[tuple[MosquittoProcess, Path]]:
    ca, crt, key = make_pki(tmp_path / "pki")
    passwd = tmp_path / "passwd"
    for i, (user, pw) in enumerate(PASSWORDS.items()):
        run("mosquitto_passwd", *(["-c"] if i == 0 else []), "-b", str(passwd), user, pw)
    b = MosquittoProcess(tmp_path / "mosquitto", f"cafile {ca}\ncertfile {crt}\nkeyfile {key}\n"
                         f"allow_anonymous false\npassword_file {passwd}\nacl_file {ACL}\n")
    await b.start()
    try:
        yield b, ca
    finally:
        await b.stop()


@pytest.fixture
async def store(tmp_path: Path) -> AsyncIterator[Store]:
    s = await Store.open(None, tmp_path / "data", timeout_s=10.0)
    try:
        yield s
    finally:
        await s.close()


def client(port: int, ca: Path | None, user: str | None, password: str | None = None) -> aiomqtt.Client:
    tls = ssl.create_default_context(cafile=str(ca)) if ca is not None else None
    return aiomqtt.Client("127.0.0.1", port, identifier=f"{user}-{uuid.uuid4().hex[:6]}", username=user,
                          password=PASSWORDS.get(user or "") if password is None else password, tls_context=tls,
                          timeout=5)


async def next_json(c: aiomqtt.Client, topic: str) -> dict[str, Any]:
    async with asyncio.timeout(15):
        async for m in c.messages:
            if m.topic.value == topic:
                return json.loads(m.payload)  # type: ignore[arg-type]
    raise AssertionError(f"nothing on {topic}")


async def test_tls_logins_and_acl_let_only_operators_command(broker, store):
    b, ca = broker
    handler = RecordingHandler()
    cfg = mqtt_config("127.0.0.1", b.port, PREFIX, tls=True, tls_ca_file=ca, username="rgse",
                      password=PASSWORDS["rgse"], command_auth="broker_acl")
    bridge = MqttBridge(cfg, ROBOT, store, handler, "1", timeout_s=5)
    async with bridge:
        await wait_until(lambda: bridge.connected, "the daemon logged in over TLS")
        async with client(b.port, ca, "viewer") as viewer, client(b.port, ca, "operator") as operator:
            await operator.subscribe(f"{PREFIX}/cmd/+/reply", qos=1)
            await viewer.subscribe(f"{PREFIX}/status", qos=1)
            # a viewer's command and an operator's forged status are dropped by the broker (ACL) ...
            await viewer.publish(f"{PREFIX}/cmd/abort", json.dumps({"request_id": "v-1", "reason": "x"}), qos=1)
            await operator.publish(f"{PREFIX}/status", json.dumps({"state": "forged"}), qos=1, retain=True)
            await operator.publish(f"{PREFIX}/cmd/abort/reply", json.dumps({"request_id": "v-1", "ok": True}), qos=1)
            # ... an operator's command, sent after them, reaches the daemon and is answered
            await operator.publish(f"{PREFIX}/cmd/measure", json.dumps({"request_id": "o-1", "dry_run": True}), qos=1)
            reply = await next_json(operator, f"{PREFIX}/cmd/measure/reply")
            status = await next_json(viewer, f"{PREFIX}/status")
    assert reply["request_id"] == "o-1" and reply["ok"] is True
    assert [(verb, cmd.request_id) for verb, cmd in handler.calls] == [("measure", "o-1")]
    assert status["state"] == "online", status
    log = b.log_text
    assert "Denied PUBLISH" in log and f"'{PREFIX}/cmd/abort'" in log and f"'{PREFIX}/status'" in log, log[-3000:]


@pytest.mark.parametrize(("user", "password", "tls"), [
    (None, "", True),                 # anonymous
    ("operator", "wrong", True),      # a wrong password
    ("operator", None, False),        # the right login, in clear text, on the TLS port
], ids=["anonymous", "wrong-password", "plaintext"])
async def test_broker_refuses_clients_without_a_valid_login_over_tls(broker, user, password, tls):
    b, ca = broker
    with pytest.raises(aiomqtt.MqttError):
        async with client(b.port, ca if tls else None, user, password):
            pass  # the connect itself must be refused


def test_mqtt_without_tokens_is_refused_unless_explicitly_opened():
    with pytest.raises(ValueError, match="command_tokens is empty, so any client that reaches the broker could "
                                         "move the robot"):
        MqttConfig(enabled=True)
    with pytest.raises(ValueError, match=r"broker_acl.*needs username"):
        MqttConfig(enabled=True, command_auth="broker_acl")
    assert MqttConfig(enabled=True, command_tokens=("t0ken-1",)).command_auth == "token"
    assert MqttConfig(enabled=True, command_auth="broker_acl", username="rgse").command_tokens == ()
    assert MqttConfig(enabled=True, command_auth="open_lab_bench").command_auth == "open_lab_bench"
    assert MqttConfig().command_auth == "token"  # MQTT off: no commands, nothing to authorise
    with pytest.raises(ConfigError, match=r"mqtt: Value error|mqtt: command_tokens is empty"):
        config_from_mapping({"mqtt": {"enabled": True}}, "rgse.toml")


def test_daemon_with_an_open_broker_config_exits_2_naming_the_fix(tmp_path):
    config = tmp_path / "rgse.toml"
    config.write_text('[mqtt]\nenabled = true\nhost = "127.0.0.1"\n')
    env = {k: v for k, v in os.environ.items() if not k.upper().startswith("RGSE_")}
    done = subprocess.run([sys.executable, "-m", "rgse_daemon", "daemon", "--config", str(config)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "command_tokens is empty" in done.stderr and "open_lab_bench" in done.stderr, done.stderr


async def test_tokens_guard_commands_by_default(tmp_path, store):
    """The default mode over a real broker (the machine's Mosquitto): a command without the token is refused
    unheard, with it accepted."""
    prefix = f"rgse-test/{uuid.uuid4().hex[:12]}"
    handler = RecordingHandler()
    cfg = MqttConfig(enabled=True, host="127.0.0.1", port=1883, prefix=prefix, command_tokens=("s3cret-tok",),
                     reconnect_min_s=0.05, reconnect_max_s=0.5)
    bridge = MqttBridge(cfg, ROBOT, store, handler, "1", timeout_s=5)
    async with bridge, aiomqtt.Client("127.0.0.1", 1883, timeout=5) as c:
        await wait_until(lambda: bridge.connected, "bridge connected")
        await c.subscribe(f"{prefix}/cmd/+/reply", qos=1)
        await c.publish(f"{prefix}/cmd/measure", json.dumps({"request_id": "n-1"}), qos=1)
        refused = await next_json(c, f"{prefix}/cmd/measure/reply")
        await c.publish(f"{prefix}/cmd/measure", json.dumps({"request_id": "t-1", "token": "s3cret-tok"}), qos=1)
        accepted = await next_json(c, f"{prefix}/cmd/measure/reply")
    await clear_retained("127.0.0.1", 1883, prefix)
    assert refused["ok"] is False and "unauthorised" in refused["error"]
    assert accepted["ok"] is True and [cmd.request_id for _, cmd in handler.calls] == ["t-1"]
