"""``rgse daemon --config FILE``: run the service until SIGTERM/SIGINT (the systemd entry point); exit 0 after a
clean stop. The configuration is validated completely before any network I/O (exit 2 when it is not valid).

Without ``-v`` it says on stderr what it serves when it starts and when the controller first answers (two lines: a
person who started it in a terminal sees that it runs; the journal gets the same), nothing more unless warned."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path

from rgse_daemon.app import Daemon
from rgse_daemon.config import Config, load_config
from rgse_daemon.logs import JournalFormatter, JsonFormatter, syslog_priority
from rgse_daemon.store import describe_store


def _say(text: str) -> None:
    """One start/stop line on stderr, in the format the log handler writes there: the journal reads an sd-daemon
    priority prefix on every line (``<6>``, info) and a ``json`` log stream must stay one object per line."""
    line = f"rgse daemon: {text}"
    formatter = next((h.formatter for h in logging.getLogger().handlers
                      if isinstance(h.formatter, JournalFormatter | JsonFormatter)), None)
    if isinstance(formatter, JournalFormatter):
        line = f"<{syslog_priority(logging.INFO)}>{line}"
    elif isinstance(formatter, JsonFormatter):
        line = formatter.format(logging.LogRecord(__name__, logging.INFO, __file__, 0, line, None, None))
    print(line, file=sys.stderr, flush=True)


def serving(cfg: Config) -> str:
    """The start line: robot, controller, store, MQTT and console."""
    c = cfg.controller
    mqtt = f"mqtt {cfg.mqtt.host}:{cfg.mqtt.port}" if cfg.mqtt.enabled else "mqtt off"
    console = f"console http://{cfg.console.host}:{cfg.console.port}/" if cfg.console.enabled else "console off"
    return (f"robot {cfg.robot.name}, controller {c.host}:{c.port}, {describe_store(cfg.store.url, cfg.paths.data_dir)}"
            f", {mqtt}, {console}; waiting for the controller")


async def _announce_connected(daemon: Daemon) -> None:
    await daemon.connected.wait()
    _say("controller connected; runs can start")


async def _serve(daemon: Daemon) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    _say(serving(daemon.cfg))
    announce = asyncio.create_task(_announce_connected(daemon))
    try:
        await daemon.run(stop)
    finally:
        announce.cancel()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        _say("stopped")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse daemon``."""
    p.add_argument("--config", type=Path, required=True, metavar="FILE")


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    asyncio.run(_serve(Daemon(cfg)))
    return 0
