"""scripts/ensure-services.sh, run as `make test` runs it: silent success when both services are up, and a clear
failure (exit 1, never a skip) when one is not."""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "ensure-services.sh"


def _run(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=60, env={**os.environ, **env}
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_already_up_path_succeeds_quietly() -> None:
    done = _run()
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")


def test_check_mode_fails_clearly_when_mosquitto_is_not_there() -> None:
    port = _free_port()
    done = _run("--check", RGSE_TEST_MQTT_PORT=str(port))
    assert done.returncode == 1
    assert f"FAILED: Mosquitto is not accepting connections on 127.0.0.1:{port}" in done.stderr
    assert "PostgreSQL" not in done.stderr.split("FAILED")[0]  # PostgreSQL itself was fine


def test_check_mode_fails_clearly_when_the_test_database_is_unusable() -> None:
    url = "postgresql://postgres@127.0.0.1:5432/rgse_no_such_database"
    done = _run("--check", RGSE_TEST_PG_URL=url)
    assert done.returncode == 1
    assert f"FAILED: PostgreSQL is not usable at {url}" in done.stderr


def test_unknown_arguments_are_refused() -> None:
    done = _run("--bogus")
    assert done.returncode == 2 and "usage:" in done.stderr
