"""``rgse daemon --config FILE``: run the service until SIGTERM/SIGINT (the systemd entry point); exit 0 after a
clean stop. The configuration is validated completely before any network I/O (exit 2 when it is not valid)."""

from __future__ import annotations

import argparse
import asyncio
import signal

from rgse_daemon.app import Daemon
from rgse_daemon.config import load_config


async def _serve(daemon: Daemon) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await daemon.run(stop)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    asyncio.run(_serve(Daemon(cfg)))
    return 0
