"""What the operator commands (``rgse status``, ``confirm``, ``abort``) share on the command line: running one
conversation with the daemon (:mod:`rgse_daemon.io.operator`) and turning its outcome into output and an exit status.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Coroutine
from typing import Any

from rgse_daemon.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK
from rgse_daemon.io.commands import CommandRefused
from rgse_daemon.io.operator import Unreachable


def report_reply(command: str, reply: dict[str, Any]) -> int:
    """Print the daemon's reply (one JSON line on stdout); 0 when accepted, 1 (reason on stderr) when refused."""
    print(json.dumps(reply))
    if reply.get("ok") is True:
        return EXIT_OK
    print(f"rgse {command}: refused by the daemon: {reply.get('error') or 'no reason given'}", file=sys.stderr)
    return EXIT_FAILED


def run_operator(command: str, args: argparse.Namespace, main: Callable[[], Coroutine[Any, Any, int]]) -> int:
    """Run an operator command; broker problems and invalid commands end in one line on stderr and exit 2."""
    try:
        return asyncio.run(main())
    except (Unreachable, CommandRefused) as exc:
        if getattr(args, "debug", False):
            raise
        print(f"rgse {command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
