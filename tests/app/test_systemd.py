"""sd_notify over a real AF_UNIX datagram socket, as systemd receives it."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from rgse_daemon.systemd import Notifier


def _receiver(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(2.0)
    return sock


def test_ready_status_watchdog_stopping(tmp_path: Path) -> None:
    path = tmp_path / "notify.sock"
    with _receiver(path) as rx:
        n = Notifier({"NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "20000000", "WATCHDOG_PID": str(os.getpid())})
        assert n.enabled
        assert n.watchdog_interval_s == 10.0
        assert n.ready("measuring")
        assert rx.recv(4096) == b"READY=1\nSTATUS=measuring"
        assert n.watchdog()
        assert rx.recv(4096) == b"WATCHDOG=1"
        assert n.stopping()
        assert rx.recv(4096) == b"STOPPING=1"


def test_abstract_socket_address() -> None:
    name = f"rgse-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as rx:
        rx.bind("\0" + name)
        rx.settimeout(2.0)
        assert Notifier({"NOTIFY_SOCKET": "@" + name}).status("idle")
        assert rx.recv(4096) == b"STATUS=idle"


def test_outside_systemd_is_a_no_op() -> None:
    n = Notifier({})
    assert not n.enabled
    assert n.watchdog_interval_s is None
    assert not n.ready("x")


def test_watchdog_meant_for_another_process_is_ignored() -> None:
    n = Notifier({"NOTIFY_SOCKET": "/nonexistent", "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"})
    assert n.watchdog_interval_s is None


def test_send_failure_is_reported_not_raised(tmp_path: Path) -> None:
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "absent.sock")})
    assert n.enabled
    assert not n.watchdog()
    assert not n.watchdog()  # logged once, still no exception
