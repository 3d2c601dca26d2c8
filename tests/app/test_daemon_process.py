"""``rgse daemon --config FILE`` as systemd runs it: a separate process with ``$NOTIFY_SOCKET``, ``$WATCHDOG_USEC`` and
its stderr on the journal (``$JOURNAL_STREAM``), stopped by SIGTERM; against the simulated KR C4 and a real broker."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import sys
import uuid
from pathlib import Path

import aiomqtt

from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import ROBOT
from tests.support.mqtt import MosquittoProcess

WAIT_S = 30.0
TOKEN = "daemon-process-token"


def _config(path: Path, sim: SimulatedKrc4, broker_port: int, prefix: str, data_dir: Path) -> Path:
    path.write_text(f"""
[robot]
name = "{ROBOT}"

[controller]
host = "127.0.0.1"
port = {sim.port}
protocol = "c3bridge"
share_dir = "{sim.share_dir}"
reconnect_min_s = 0.05
reconnect_max_s = 0.4

[paths]
data_dir = "{data_dir}"

[mqtt]
enabled = true
host = "127.0.0.1"
port = {broker_port}
prefix = "{prefix}"
command_tokens = ["{TOKEN}"]
""", encoding="utf-8")
    return path


async def _next_datagram(sock: socket.socket, received: list[str]) -> str:
    data = await asyncio.wait_for(asyncio.get_running_loop().sock_recv(sock, 4096), WAIT_S)
    received.append(data.decode())
    return received[-1]


async def test_rgse_daemon_process_ready_serves_commands_and_stops_cleanly_on_sigterm(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    prefix = f"rgse-proc/{uuid.uuid4().hex[:8]}"
    cfg = _config(tmp_path / "rgse.toml", sim, private_broker.port, prefix, tmp_path / "data")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify.sock"))
    notify.setblocking(False)
    log_path = tmp_path / "journal.log"
    received: list[str] = []
    with notify, log_path.open("wb") as log:
        st = os.fstat(log.fileno())
        env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "400000",
               "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
        env.pop("RGSE_LOG_FORMAT", None)
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "rgse_daemon.cli", "--verbose", "daemon", "--config", str(cfg),
            stdout=asyncio.subprocess.PIPE, stderr=log, env=env)
        try:
            assert await _next_datagram(notify, received) == f"READY=1\nSTATUS=serving robot {ROBOT}"
            assert await _next_datagram(notify, received) == "WATCHDOG=1"
            async with aiomqtt.Client("127.0.0.1", private_broker.port, identifier=f"t-{uuid.uuid4().hex[:8]}",
                                      timeout=10) as client:
                await client.subscribe(f"{prefix}/#", qos=1)
                seen: dict[str, dict] = {}
                published = False
                async with asyncio.timeout(WAIT_S):
                    async for msg in client.messages:
                        seen[msg.topic.value] = json.loads(msg.payload)  # type: ignore[arg-type]
                        if not published and seen.get(f"{prefix}/status", {}).get("state") == "online":
                            # the daemon is on the broker (READY does not wait for it): a measurement without an
                            # active calibration is refused with the reason, nothing started
                            command = {"request_id": "p-1", "token": TOKEN}
                            await client.publish(f"{prefix}/cmd/measure", json.dumps(command), qos=1)
                            published = True
                        reply = seen.get(f"{prefix}/cmd/measure/reply")
                        if reply is not None:
                            break
            assert reply["request_id"] == "p-1" and reply["ok"] is False
            assert "no active calibration" in reply["error"], reply
            # systemd stops the service: SIGTERM, then STOPPING=1 and a clean exit 0 within the bound
            proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(proc.wait(), WAIT_S) == 0
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
        while True:
            try:
                received.append(notify.recv(4096).decode())
            except BlockingIOError:
                break
    assert "STOPPING=1" in received and set(received[1:]) <= {"WATCHDOG=1", "STOPPING=1"}
    # the retained status the dashboards see: offline, said by the daemon itself (a clean stop)
    async with aiomqtt.Client("127.0.0.1", private_broker.port, identifier=f"t-{uuid.uuid4().hex[:8]}",
                              timeout=10) as client:
        await client.subscribe(f"{prefix}/status", qos=1)
        async with asyncio.timeout(WAIT_S):
            async for msg in client.messages:
                status = json.loads(msg.payload)  # type: ignore[arg-type]
                break
    assert status["state"] == "offline" and status["since"] is not None
    # the journal got sd-daemon priority prefixes, no timestamps of our own
    lines = [ln for ln in log_path.read_text(encoding="utf-8").splitlines() if ln]
    assert lines and all(ln[:3] in ("<3>", "<4>", "<6>", "<7>") for ln in lines), lines[:5]
    assert any("serving robot" in ln or "connected" in ln for ln in lines), lines[:10]


async def test_rgse_daemon_refuses_a_bad_config_before_any_io(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[robot]\nname = "R"\n\n[controller]\nhost = "127.0.0.1"\nport = 99999\n', encoding="utf-8")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "rgse_daemon.cli", "daemon", "--config", str(cfg),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await asyncio.wait_for(proc.communicate(), WAIT_S)
    assert proc.returncode == 2 and out == b""
    text = err.decode()
    assert "bad.toml" in text and "port" in text and "Traceback" not in text, text
