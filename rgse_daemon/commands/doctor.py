"""``rgse doctor --config FILE [--json] [--no-record]``: the commissioning checklist of a controller and its
surroundings (:mod:`rgse_daemon.doctor`). Never moves the robot. Prints one line per check, each failed one with
its fix; records the controller's file layout in the data directory (unless ``--no-record``). Exit 0 when every
check passed, 1 when one failed, 2 on a bad configuration."""

from __future__ import annotations

import argparse
import asyncio
import json
from pathlib import Path

from rgse_daemon.commands import add_json
from rgse_daemon.commands.krl import template_defaults
from rgse_daemon.config import load_config
from rgse_daemon.doctor import run_doctor


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse doctor``."""
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--no-record", action="store_true", help="do not record the controller's file layout")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    report = asyncio.run(run_doctor(cfg, template_defaults(cfg), record=not args.no_record))
    if args.json:
        print(json.dumps({"ok": report.ok, "checks": [c.__dict__ for c in report.checks],
                          "layout_file": str(report.layout_file) if report.layout_file else None}))
    else:
        print(report.text())
    return 0 if report.ok else 1
