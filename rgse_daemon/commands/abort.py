"""``rgse abort --config FILE [--reason TEXT] [--run RUN_ID] [--timeout S]``: stop the running daemon's run now
and leave the robot safe.

Publishes an ``abort`` command (interfaces §4; schema :class:`~rgse_daemon.io.commands.AbortCommand`) on the
daemon's broker, as configured in FILE, and waits for the daemon's reply to it. Without ``--run`` the daemon
aborts whatever run is in progress; with it, only that run. Prints the reply (one JSON line on stdout). Exit 0
when the daemon accepted; 1 when it refused (its reason on stderr); 2 on a bad configuration or command, an
unreachable broker, or no reply within ``--timeout`` (default 10 s). See :mod:`rgse_daemon.io.operator`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rgse_daemon.commands.operator_cli import report_reply, run_operator
from rgse_daemon.io.operator import Conversation, check_fields, check_timeout, endpoint

DEFAULT_REASON = "aborted by the operator (rgse abort)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse abort``."""
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--reason", metavar="TEXT", help="why (recorded with the run)")
    p.add_argument("--run", metavar="RUN_ID", help="abort only this run (default: the run in progress)")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the reply (default 10)")


def run(args: argparse.Namespace) -> int:
    ep = endpoint(args.config)
    timeout_s = check_timeout(getattr(args, "timeout", None))
    reason = getattr(args, "reason", None)
    fields = {"reason": DEFAULT_REASON if reason is None else reason, "run_id": getattr(args, "run", None)}
    t = ep.topics

    async def body(conv: Conversation) -> dict[str, Any]:
        await conv.subscribe([t.reply("abort"), t.status])
        return await conv.command("abort", fields)

    async def main() -> int:
        check_fields("abort", fields)  # before any network I/O
        return report_reply("abort", await Conversation(ep, "abort", timeout_s).run(body))

    return run_operator("abort", args, main)
