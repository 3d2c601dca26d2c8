"""``rgse doctor``'s broker check leaves no connection behind when the broker does not answer or the check is given up.

The check connects once (connecting, and the login it carries, is the check). aiomqtt (2.5) leaves the connection of
a connect that fails after the socket was opened (no CONNACK within its timeout) or that is cancelled to itself: its
misc task runs on and the socket stays open. The broker here is a raw TCP listener that never answers CONNECT (a
wrong port, a hung broker); the controller is not there (refused at once), so only the checks around it run.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from rgse_daemon.commands.krl import template_defaults
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.doctor import run_doctor
from tests.support.mqtt import TcpPeer, aiomqtt_tasks, asyncio_complaints, free_port
from tests.support.polling import wait_until


def _config(broker_port: int, data_dir: Path) -> Config:
    return config_from_mapping({
        "controller": {"host": "127.0.0.1", "port": free_port()},  # nothing listens: refused at once
        "paths": {"data_dir": str(data_dir)},
        "mqtt": {"enabled": True, "host": "127.0.0.1", "port": broker_port, "command_auth": "open_lab_bench"},
    })


async def test_the_broker_check_closes_a_connection_whose_connack_does_not_come(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            cfg = _config(peer.port, tmp_path / "data")
            report = await run_doctor(cfg, template_defaults(cfg), record=False)
            broker = next(c for c in report.checks if c.name == "broker")
            assert broker.ok is False and "timed out" in broker.detail, broker
            assert peer.accepted == 1
            await wait_until(lambda: peer.closed_by_client == 1, "the check closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)  # the peer closed its side: nothing of the client may still react to that
    assert complaints == []


async def test_a_doctor_cancelled_during_the_broker_check_closes_its_connection(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A doctor given up (Ctrl-C, a caller's deadline) while the broker check waits for the CONNACK: the cancellation
    goes through, promptly, and the connection is closed, not left connected to the broker."""
    with asyncio_complaints(caplog) as complaints:
        async with TcpPeer() as peer:
            cfg = _config(peer.port, tmp_path / "data")
            doctor = asyncio.create_task(run_doctor(cfg, template_defaults(cfg), record=False))
            await wait_until(lambda: peer.accepted == 1, "the broker check connected", timeout_s=10)
            doctor.cancel()
            async with asyncio.timeout(2):  # well inside the check's 5 s CONNACK timeout
                with pytest.raises(asyncio.CancelledError):
                    await doctor
            await wait_until(lambda: peer.closed_by_client == 1, "the check closed its connection", timeout_s=3)
            assert aiomqtt_tasks() == []
        await asyncio.sleep(0.1)
    assert complaints == []


async def test_the_broker_check_uses_the_daemons_tls_context(tmp_path: Path) -> None:
    """The check connects as the daemon would, with the daemon's TLS context: a CA file that holds no certificate
    fails the check by name, before anything connects (it built its own TLS parameters, which paho read only while
    connecting)."""
    ca = tmp_path / "ca.pem"
    ca.write_text("not a certificate\n")
    async with TcpPeer() as peer:
        cfg = config_from_mapping({
            "controller": {"host": "127.0.0.1", "port": free_port()},
            "paths": {"data_dir": str(tmp_path / "data")},
            "mqtt": {"enabled": True, "host": "127.0.0.1", "port": peer.port, "command_auth": "open_lab_bench",
                     "tls": True, "tls_ca_file": str(ca)},
        })
        report = await run_doctor(cfg, template_defaults(cfg), record=False)
        broker = next(c for c in report.checks if c.name == "broker")
        assert broker.ok is False, broker
        assert f"mqtt.tls_ca_file {ca}: cannot load CA certificates" in broker.detail, broker
        assert peer.accepted == 0
