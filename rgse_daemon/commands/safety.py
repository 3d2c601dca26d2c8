"""``rgse safety status|clear --config FILE``: the safety latch (:mod:`rgse_daemon.safety.latch`).

The daemon latches when it could not confirm that a stop reached the robot; then it admits no run. ``status`` shows
the latch (exit 0 clear, 1 set); ``clear --message TEXT`` removes it after the operator checked the robot (exit 0;
1 if none was set). What was cleared, by whose note, is appended to ``<data_dir>/safety-latch.log``.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import UTC, datetime
from pathlib import Path

from rgse_daemon.config import load_config
from rgse_daemon.errors import EXIT_FAILED, EXIT_OK
from rgse_daemon.safety.latch import CLEAR_HINT, clear_latch, read_latch


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse safety``."""
    safety_sub = p.add_subparsers(dest="safety_command", required=True, metavar="ACTION")
    c = safety_sub.add_parser("status", help="show the latch (exit 0 clear, 1 set)")
    c.add_argument("--config", type=Path, required=True, metavar="FILE")
    c = safety_sub.add_parser("clear", help="clear the latch after checking the robot is stopped")
    c.add_argument("--config", type=Path, required=True, metavar="FILE")
    c.add_argument("--message", required=True, metavar="TEXT", help="what the operator checked (logged)")


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    data_dir = cfg.paths.data_dir
    if args.safety_command == "status":
        latch = read_latch(data_dir)
        if latch is None:
            print("safety latch: clear")
            return EXIT_OK
        print(f"safety latch: SET at {latch.time_utc or '?'}: {latch.reason}\n{CLEAR_HINT}")
        return EXIT_FAILED
    latch = clear_latch(data_dir)
    if latch is None:
        print("safety latch: was not set; nothing cleared", file=sys.stderr)
        return EXIT_FAILED
    now = datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
    with open(data_dir / "safety-latch.log", "a", encoding="utf-8") as f:
        f.write(json.dumps({"cleared_utc": now, "message": args.message, "latch": latch.to_json()}) + "\n")
    print(f"safety latch cleared (set at {latch.time_utc or '?'}: {latch.reason})")
    return EXIT_OK
