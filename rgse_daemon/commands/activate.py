"""``rgse activate CAL.json --config FILE``: make an offline calibration (``rgse calibrate``'s CAL.json) the active
calibration of the configured robot, as a finished campaign makes its own.

The file is read and validated in full first (:func:`rgse_daemon.calfile.read`); a file of another robot is refused
(a calibration is only ever used for the robot it names). The store keeps the document under its id; its provenance
— the file's path and SHA-256, the calibration it replaced, who activated it and the note — is recorded as the event
``calibration_activated``. A running daemon uses it from its next run on.
"""

from __future__ import annotations

import argparse
import asyncio
import getpass
import hashlib
import json
from pathlib import Path
from typing import Any

from rgse_daemon import calfile
from rgse_daemon.commands import add_json
from rgse_daemon.config import load_config
from rgse_daemon.errors import EXIT_OK, DataError
from rgse_daemon.store import EventLevel, Store


async def activate(cal_path: Path, config_path: Path | None, note: str | None) -> dict[str, Any]:
    cfg = load_config(config_path)
    doc, cal = calfile.read_document(cal_path)
    calfile.check_robot(cal_path, cal, cfg.robot.name)
    sha256, where = await asyncio.to_thread(_sha256_and_path, cal_path)
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        before = await store.active_calibration(cfg.robot.name)
        record = await store.add_calibration(doc, activate=True)
        provenance = {"calibration_id": record.id, "file": where, "sha256": sha256,
                      "replaced": before.id if before is not None else None, "by": getpass.getuser(), "note": note}
        event = await store.add_event(
            EventLevel.INFO, "calibration_activated",
            f"calibration {record.id} ({record.method}) activated from {cal_path.name}"
            + (f", replacing {before.id}" if before is not None and before.id != record.id else ""),
            data=provenance)
    return {**provenance, "robot": cfg.robot.name, "method": record.method, "event_id": event.id}


def _sha256_and_path(path: Path) -> tuple[str, str]:
    return hashlib.sha256(path.read_bytes()).hexdigest(), str(path.resolve())


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse activate``."""
    p.add_argument("calibration", type=Path, metavar="CAL.json")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its robot and store)")
    p.add_argument("--note", metavar="TEXT", help="why, recorded with the activation")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    note = getattr(args, "note", None)
    if note is not None and not note.strip():
        raise DataError("--note: empty")
    out = asyncio.run(activate(args.calibration, getattr(args, "config", None), note))
    if getattr(args, "json", False):
        print(json.dumps(out))
    else:
        was = f" (was {out['replaced']})" if out["replaced"] not in (None, out["calibration_id"]) else ""
        print(f"calibration {out['calibration_id']} ({out['method']}) is the active calibration of {out['robot']}"
              f"{was}; sha256 {out['sha256'][:12]}…, recorded as event {out['event_id']}")
    return EXIT_OK
