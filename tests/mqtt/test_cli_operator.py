"""``rgse confirm``, ``rgse abort``, ``rgse status``: run as subprocesses against the real broker and a real bridge.

The bridge (the daemon's MQTT face) runs in the test's loop with a recording handler; the CLI reads the same kind of
configuration file the daemon does, with the mqtt section pointing at the broker under the test's own prefix.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.commands.abort import DEFAULT_REASON
from rgse_daemon.config import load_config
from rgse_daemon.errors import RgseError
from rgse_daemon.io.commands import AbortCommand, ConfirmCommand
from rgse_daemon.io.mqtt import MqttBridge
from rgse_daemon.io.topics import Topics
from rgse_daemon.procedures import documents as d
from rgse_daemon.procedures.recorder import StoreRecorder
from rgse_daemon.store import RunKind, Store, archive_file_async
from tests.support.mqtt import ROBOT, RecordingHandler, free_port, mqtt_config, stored_result
from tests.support.polling import wait_until

VERSION = "9.8.7"


@dataclass(frozen=True)
class Ran:
    rc: int
    out: str
    err: str
    elapsed_s: float

    def reply(self) -> dict[str, Any]:
        lines = self.out.splitlines()
        assert len(lines) == 1, self.out
        doc = json.loads(lines[0])
        assert isinstance(doc, dict)
        return doc

    def one_line_error(self, *fragments: str) -> None:
        """Exit 2 with one line on stderr naming every fragment, and no traceback."""
        assert self.rc == 2, self
        assert len(self.err.strip().splitlines()) == 1 and "Traceback" not in self.err, self.err
        for f in fragments:
            assert f in self.err, (f, self.err)


async def rgse(*args: str | Path) -> Ran:
    """``python -m rgse_daemon.cli ARGS`` in a subprocess, without RGSE_* overrides from the environment."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RGSE_")}
    t0 = time.monotonic()
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "rgse_daemon.cli",
        *map(str, args),
        stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    try:
        out, err = await asyncio.wait_for(proc.communicate(), 60)
    except TimeoutError:
        proc.kill()
        await proc.wait()
        raise
    assert proc.returncode is not None
    return Ran(proc.returncode, out.decode(), err.decode(), time.monotonic() - t0)


def write_config(path: Path, host: str, port: int, prefix: str | None, extra: str = "") -> Path:
    prefix_line = f'prefix = "{prefix}"\n' if prefix is not None else ""
    if "command_tokens" not in extra and "command_auth" not in extra:
        extra += 'command_auth = "open_lab_bench"\n'  # the broker's own test clients only
    path.write_text(
        f'[robot]\nname = "{ROBOT}"\n\n[mqtt]\nenabled = true\nhost = "{host}"\nport = {port}\n{prefix_line}{extra}'
    )
    return path


@pytest.fixture
def config(tmp_path: Path, system_broker: tuple[str, int], prefix: str) -> Path:
    return write_config(tmp_path / "rgse.toml", *system_broker, prefix)


@contextlib.asynccontextmanager
async def daemon(
    broker: tuple[str, int], prefix: str, store: Store, handler: Any, **cfg: Any
) -> AsyncIterator[MqttBridge]:
    """A running bridge with ``handler`` behind it, connected."""
    bridge = MqttBridge(mqtt_config(*broker, prefix, **cfg), ROBOT, store, handler, VERSION, timeout_s=5)
    async with bridge:
        await wait_until(lambda: bridge.connected, "bridge connected")
        yield bridge


class RefusingHandler(RecordingHandler):
    """Records every command, then refuses it as the daemon does when nothing waits."""

    async def _record(self, verb: str, cmd: Any) -> dict[str, Any]:
        self.calls.append((verb, cmd))
        raise RgseError(f"no run for {verb}: nothing waits")


async def test_confirm_reaches_the_daemon_once_and_exits_0(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    async with daemon(system_broker, prefix, store, handler):
        ran = await rgse("confirm", "--config", config, "--run", "run-7", "--point", "2", "--message", "3 CBs on")
    assert ran.rc == 0 and ran.err == "", ran
    reply = ran.reply()
    assert reply["ok"] is True and reply["accepted"] is True and reply["request_id"].startswith("cli-")
    assert handler.calls == [("confirm", ConfirmCommand(request_id=reply["request_id"], run_id="run-7", point=2,
                                                        message="3 CBs on"))]


async def test_confirm_takes_the_run_from_the_daemons_retained_state(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    async with daemon(system_broker, prefix, store, handler) as bridge:
        bridge.publish_state({"engine": "confirm", "run_id": "run-9", "run_kind": "calibration"})
        await wait_until(lambda: bridge.counters.state_published >= 1, "state published")
        ran = await rgse("confirm", "--config", config)
    assert ran.rc == 0, ran
    assert handler.calls == [("confirm", ConfirmCommand(request_id=ran.reply()["request_id"], run_id="run-9"))]


async def test_confirm_when_the_state_names_no_run_exits_1_unsent(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    async with daemon(system_broker, prefix, store, handler) as bridge:
        bridge.publish_state({"engine": "idle", "run_id": None, "run_kind": None})
        await wait_until(lambda: bridge.counters.state_published >= 1, "state published")
        ran = await rgse("confirm", "--config", config)
    assert ran.rc == 1 and ran.out == "", ran
    assert "nothing to confirm" in ran.err and "engine idle" in ran.err, ran.err
    assert handler.calls == []


async def test_abort_carries_the_reason(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    async with daemon(system_broker, prefix, store, handler):
        named = await rgse("abort", "--config", config, "--reason", "fixture bolt loose", "--run", "run-3")
        default = await rgse("abort", "--config", config)
    assert named.rc == 0 and default.rc == 0, (named, default)
    assert handler.calls == [
        ("abort", AbortCommand(request_id=named.reply()["request_id"], run_id="run-3", reason="fixture bolt loose")),
        ("abort", AbortCommand(request_id=default.reply()["request_id"], reason=DEFAULT_REASON)),
    ]


@pytest.mark.parametrize("verb", ["confirm", "abort"])
async def test_a_refusal_exits_1_with_the_daemons_reason(
    system_broker: tuple[str, int], prefix: str, store: Store, config: Path, verb: str
) -> None:
    handler = RefusingHandler()
    async with daemon(system_broker, prefix, store, handler):
        ran = await rgse(verb, "--config", config, "--run", "run-1", "--timeout", "5")
    assert ran.rc == 1, ran
    reply = ran.reply()
    assert reply["ok"] is False and reply["error"] == f"no run for {verb}: nothing waits"
    assert ran.err.strip() == f"rgse {verb}: refused by the daemon: no run for {verb}: nothing waits"
    assert [(v, c.request_id) for v, c in handler.calls] == [(verb, reply["request_id"])]


async def test_commands_carry_the_configured_token(
    tmp_path: Path, system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler
) -> None:
    """The daemon demands a token: a CLI configuration without it is refused unheard, with it accepted."""
    without = write_config(tmp_path / "without.toml", *system_broker, prefix)
    with_token = write_config(tmp_path / "with.toml", *system_broker, prefix, 'command_tokens = ["s3cret"]\n')
    async with daemon(system_broker, prefix, store, handler, command_tokens=("s3cret",)):
        refused = await rgse("abort", "--config", without, "--reason", "r1")
        assert refused.rc == 1 and "unauthorised" in refused.err, refused
        assert handler.calls == []
        accepted = await rgse("abort", "--config", with_token, "--reason", "r2")
    assert accepted.rc == 0, accepted
    assert [(v, c.reason) for v, c in handler.calls] == [("abort", "r2")]


async def test_no_daemon_listening_exits_2_at_the_deadline(config: Path, prefix: str) -> None:
    abort, confirm = await asyncio.gather(
        rgse("abort", "--config", config, "--timeout", "1.5"),
        rgse("confirm", "--config", config, "--timeout", "1.5"),
    )
    abort.one_line_error("rgse abort: error: mqtt broker 127.0.0.1:1883", "no answer within 1.5 s",
                         f"{prefix}/cmd/abort/reply", "status: unknown")
    confirm.one_line_error("rgse confirm: error: mqtt broker 127.0.0.1:1883", f"no daemon state on {prefix}/state",
                           "--run RUN_ID")
    for ran in (abort, confirm):
        # a hang guard, not a timing check: it gave up at its deadline, not at the 60 s guard of rgse() (the margin
        # is the interpreter's start-up, which took 15 s for three at once on the loaded 2-core CI machine)
        assert ran.out == "" and ran.elapsed_s < 1.5 + 30, ran


async def test_a_stopped_daemon_is_named_offline(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    async with daemon(system_broker, prefix, store, handler):
        pass  # a clean stop leaves the retained status offline
    ran = await rgse("confirm", "--config", config, "--run", "run-1", "--timeout", "1")
    ran.one_line_error("no answer within 1 s", f"{prefix}/cmd/confirm/reply", "status: offline since", VERSION)
    assert handler.calls == []


async def test_confirm_and_abort_name_a_stopped_daemon_offline_after_a_failed_run(
    system_broker: tuple[str, int], prefix: str, store: Store, handler: RecordingHandler, config: Path
) -> None:
    """The daemon stopped after a failed run: its retained state names no run, its retained status is offline.
    confirm (without --run) says offline and exits 2 as abort does, not "nothing to confirm" with exit 1."""
    async with daemon(system_broker, prefix, store, handler) as bridge:
        bridge.publish_state({"engine": "failed", "run_id": None, "run_kind": None})
        await wait_until(lambda: bridge.counters.state_published >= 1, "state published")
    confirm, abort = await asyncio.gather(
        rgse("confirm", "--config", config, "--timeout", "2"),
        rgse("abort", "--config", config, "--timeout", "2"),
    )
    for verb, ran in (("confirm", confirm), ("abort", abort)):
        ran.one_line_error(f"rgse {verb}: error: mqtt broker", "status: offline since", VERSION)
        assert ran.out == "", ran
    assert "nothing to confirm" not in confirm.err and "not running" in confirm.err, confirm.err
    assert handler.calls == []


async def test_an_unreachable_broker_port_exits_2(tmp_path: Path) -> None:
    port = free_port()  # nothing listens there
    cfg = write_config(tmp_path / "rgse.toml", "127.0.0.1", port, "rgse-test/nobody")
    runs = await asyncio.gather(
        rgse("confirm", "--config", cfg, "--run", "run-1", "--timeout", "40"),
        rgse("abort", "--config", cfg, "--timeout", "40"),
        rgse("status", "--config", cfg, "--timeout", "40"),
    )
    for verb, ran in zip(("confirm", "abort", "status"), runs, strict=True):
        # refused at once, not "no answer within 40 s": a refused connect is not waited out to the deadline
        ran.one_line_error(f"rgse {verb}: error: mqtt broker 127.0.0.1:{port}: cannot connect")
        assert "no answer within" not in ran.err and ran.elapsed_s < 40, ran


async def test_status_prints_the_retained_status_state_and_results(
    system_broker: tuple[str, int],
    prefix: str,
    store: Store,
    data_dir: Path,
    tmp_path: Path,
    handler: RecordingHandler,
    config: Path,
) -> None:
    async with daemon(system_broker, prefix, store, handler) as bridge:
        run, _ = await stored_result(store, data_dir, tmp_path, bridge.result_message, 107.65)
        bridge.notify_outbox()
        bridge.publish_state({"engine": "idle", "run_id": None, "run_kind": None})
        await wait_until(lambda: bridge.counters.outbox_published >= 1, "result published")
        await wait_until(lambda: bridge.counters.state_published >= 1, "state published")
        as_json, as_text = await asyncio.gather(
            rgse("status", "--config", config, "--json"), rgse("status", "--config", config)
        )
    assert as_json.rc == 0 and as_json.err == "", as_json
    doc = json.loads(as_json.out)
    assert doc["broker"] == "127.0.0.1:1883" and doc["prefix"] == prefix
    assert doc["status"]["state"] == "online" and doc["status"]["version"] == VERSION
    assert doc["state"]["engine"] == "idle" and doc["state"]["mqtt"]["connection"] == "connected"
    assert list(doc["results"]) == [run.id] and doc["results"][run.id]["mass_kg"] == 107.65
    assert as_text.rc == 0, as_text
    assert f"status   online since {doc['status']['since']}, version {VERSION}" in as_text.out
    assert "state    engine idle" in as_text.out
    assert f"{run.id}  mass 107.650 kg, U 0.700 kg (k = 2)" in as_text.out


async def test_status_of_a_prefix_nothing_retained_on(config: Path) -> None:
    ran = await rgse("status", "--config", config, "--json")
    assert ran.rc == 0, ran
    doc = json.loads(ran.out)
    assert (doc["status"], doc["state"], doc["results"]) == (None, None, {})


async def test_bad_configuration_or_command_exits_2_before_any_network_io(tmp_path: Path) -> None:
    port = free_port()  # would fail differently ("cannot connect") if it were contacted
    good = write_config(tmp_path / "good.toml", "127.0.0.1", port, "rgse-test/nobody")
    disabled = tmp_path / "disabled.toml"
    disabled.write_text("[mqtt]\nenabled = false\n")
    slash_only = write_config(tmp_path / "slash.toml", "127.0.0.1", port, "/")
    runs = await asyncio.gather(
        rgse("status", "--config", tmp_path / "missing.toml"),
        rgse("abort", "--config", disabled),
        rgse("confirm", "--config", good, "--point", "5000"),
        rgse("abort", "--config", good, "--reason", ""),
        rgse("confirm", "--config", good, "--run", "../etc"),
        rgse("status", "--config", good, "--timeout", "0"),
        rgse("status", "--config", slash_only),
    )
    expected = [
        "cannot read config file",
        "mqtt.enabled is false",
        "cmd/confirm: schema: point",
        "cmd/abort: schema: reason",
        "cmd/confirm: schema: run_id",
        "--timeout 0.0: must be a finite number",
        "empty once the trailing '/' is dropped",
    ]
    for ran, fragment in zip(runs, expected, strict=True):
        ran.one_line_error(fragment)
        assert "cannot connect" not in ran.err


async def test_a_result_under_a_prefix_with_a_trailing_slash_reaches_rgse_status(
    system_broker: tuple[str, int], prefix: str, store: Store, data_dir: Path, tmp_path: Path,
    handler: RecordingHandler,
) -> None:
    """Regression: ``prefix = "plant/rgse/"`` (the config allows it) once sent results to ``plant/rgse//run/…/result``
    while the bridge and ``rgse status`` used ``plant/rgse``: nobody received them. The config drops the slash once;
    the run's recorder, the bridge and the operator's client all take their topics from it."""
    config = write_config(tmp_path / "slash.toml", *system_broker, prefix + "/")
    cfg = load_config(config)
    assert cfg.mqtt.prefix == prefix
    recorder = StoreRecorder(store, data_dir, Topics.of(cfg.mqtt, cfg.robot.name))
    run = await recorder.record(None, d.OpenRun(RunKind.MEASUREMENT, ROBOT, {"fixture_mass_kg": 10.288}))
    src = tmp_path / "share" / f"{run.run_id}_NextGenDrive#3.r64"
    src.parent.mkdir()
    src.write_bytes(b"raw" * 64)
    f = await archive_file_async(src, run.run_dir, timeout_s=30)
    await recorder.record(run.run_id, d.LoopStarted(1, "t1", datetime.now(UTC)))
    await recorder.record(run.run_id, d.TraceArchived(1, "t1", (f,), deleted=True))
    result = {"mass_kg": 107.65, "u_kg": 0.35, "U_kg": 0.70, "k": 2, "loops": 1, "warnings": []}
    await recorder.record(run.run_id, d.Result(result, [f.sha256]))
    assert [o.topic for o in await store.pending_outbox()] == [f"{prefix}/run/{run.run_id}/result"]
    async with MqttBridge(cfg.mqtt, ROBOT, store, handler, VERSION, timeout_s=5) as bridge:
        assert bridge.prefix == prefix
        await wait_until(lambda: bridge.counters.outbox_published >= 1, "result published")
        ran = await rgse("status", "--config", config, "--json")
    assert ran.rc == 0, ran
    doc = json.loads(ran.out)
    assert doc["prefix"] == prefix and doc["results"][run.run_id]["mass_kg"] == 107.65
