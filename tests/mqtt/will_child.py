"""A daemon stand-in for the last-will test: runs a real MqttBridge until it is killed (SIGKILL, no goodbye).

Usage: python will_child.py HOST PORT PREFIX DATA_DIR
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from rgse_daemon.config import MqttConfig
from rgse_daemon.io.mqtt import MqttBridge
from rgse_daemon.store import Store


class _Handler:
    async def measure(self, cmd: object) -> dict:
        return {}

    calibrate = abort = confirm = measure


async def main(host: str, port: int, prefix: str, data_dir: Path) -> None:
    cfg = MqttConfig(enabled=True, host=host, port=port, prefix=prefix, keepalive_s=5,
                     command_auth="open_lab_bench")
    async with (
        await Store.open(None, data_dir) as store,
        MqttBridge(cfg, "KR500R2830-1234", store, _Handler(), "9.9.9"),
    ):
        await asyncio.Event().wait()  # until killed


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), sys.argv[3], Path(sys.argv[4])))
