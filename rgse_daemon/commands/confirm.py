"""``rgse confirm --config FILE [--run RUN_ID] [--point N] [--message TEXT] [--timeout S]``: tell the running
daemon that the step its run waits for is done (e.g. the calibration load of a campaign point is mounted); the
message is recorded with the confirmation in the run's events.

Publishes a ``confirm`` command (interfaces §4; schema :class:`~rgse_daemon.io.commands.ConfirmCommand`) on the
daemon's broker, as configured in FILE, and waits for the daemon's reply to it. Without ``--run`` the run is the
one the daemon's retained ``state`` names; the daemon itself checks that this run is the one waiting. Prints the
reply (one JSON line on stdout). Exit 0 when the daemon accepted; 1 when it refused (its reason on stderr) or its
state names no run; 2 on a bad configuration or command, an unreachable broker, a daemon whose retained status is
offline, or no reply within ``--timeout`` (default 10 s). See :mod:`rgse_daemon.commands.status` for the client.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rgse_daemon.commands.operator_cli import report_reply, run_operator
from rgse_daemon.errors import EXIT_FAILED
from rgse_daemon.io.operator import Conversation, Unreachable, check_fields, check_timeout, describe_status, endpoint

#: How long to wait for the daemon's state when the run is not named (it is retained: normally at once).
STATE_WAIT_S = 3.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse confirm``."""
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--run", metavar="RUN_ID", help="the run waiting (default: the run of the daemon's state)")
    p.add_argument("--point", type=int, metavar="N", help="index of the campaign point whose load is mounted")
    p.add_argument("--message", metavar="TEXT", help="the operator's note, recorded with the confirmation")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the reply (default 10)")


def run(args: argparse.Namespace) -> int:
    ep = endpoint(args.config)
    timeout_s = check_timeout(getattr(args, "timeout", None))
    run_id: str | None = getattr(args, "run", None)
    point: int | None = getattr(args, "point", None)
    message: str | None = getattr(args, "message", None)
    t = ep.topics

    async def body(conv: Conversation) -> dict[str, Any] | None:
        await conv.subscribe([t.reply("confirm"), t.status, *([t.state] if run_id is None else [])])
        target = run_id
        if target is None:
            wait_s = min(STATE_WAIT_S, timeout_s / 2)  # leave time for the command; say why if the state is missing
            await conv.read_retained(wait_s, until=t.state)
            state = conv.json_of(t.state)
            if not isinstance(state, dict):
                raise Unreachable(
                    f"{ep.broker}: no daemon state on {t.state} within {wait_s:g} s (daemon status: "
                    f"{describe_status(conv.json_of(t.status))}); name the run with --run RUN_ID"
                )
            target = state.get("run_id")
            if not target and await conv.daemon_offline(wait_s):
                # a stopped daemon's last state is stale: say it is offline, as rgse abort does (exit 2)
                raise Unreachable(
                    f"{ep.broker}: the daemon is not running (its retained status: {conv.describe_status()}); "
                    f"nothing can be confirmed until it runs again"
                )
            if not target:
                print(
                    f"rgse confirm: nothing to confirm: the daemon's state (at {state.get('time', '?')}) names no run "
                    f"in progress (engine {state.get('engine', '?')})",
                    file=sys.stderr,
                )
                return None
        return await conv.command("confirm", {"run_id": target, "point": point, "message": message})

    async def main() -> int:
        # validated before any network I/O
        check_fields("confirm", {"run_id": run_id or "pending", "point": point, "message": message})
        reply = await Conversation(ep, "confirm", timeout_s).run(body)
        return EXIT_FAILED if reply is None else report_reply("confirm", reply)

    return run_operator("confirm", args, main)
