"""The safety latch: a stop the daemon could not confirm stays an alarm until an operator clears it.

When :func:`~rgse_daemon.safety.makesafe.stop_until_confirmed` passes its deadline without a read-back that shows
program and trace stopped, nobody knows whether the robot still moves. The daemon then *latches*: it writes
``<data_dir>/safety-latch.json`` (durably), publishes an alarm, and admits no run while the file exists — also after
a restart, because the file outlives the process.

Only an operator clears it, after looking at the robot: ``rgse safety clear --config FILE --message TEXT`` on the
measurement PC (deliberately not over MQTT: whoever clears it should be where the robot is). ``rgse safety status``
shows it. The running daemon reads the file at every run request, so clearing needs no restart.

If the file cannot be written (disk full), the latch is kept in memory (:class:`SafetyLatch`) until the daemon
restarts, and the log says so.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import InterlockError

_log = logging.getLogger(__name__)

LATCH_FILENAME = "safety-latch.json"
CLEAR_HINT = "check the robot, then clear it with: rgse safety clear --config FILE --message TEXT"


class SafetyLatched(InterlockError):
    """A run was refused because the safety latch is set."""


@dataclass(frozen=True)
class Latch:
    reason: str
    time_utc: str
    data: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"reason": self.reason, "time_utc": self.time_utc, "data": self.data}


def latch_path(data_dir: Path) -> Path:
    return Path(data_dir) / LATCH_FILENAME


def read_latch(data_dir: Path) -> Latch | None:
    """The latch set in ``data_dir``, or None. A file that cannot be read or parsed is still a latch (doubt)."""
    path = latch_path(data_dir)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except OSError as exc:
        return Latch(f"{path}: latch file unreadable ({exc})", "")
    try:
        doc = json.loads(text)
        return Latch(str(doc["reason"]), str(doc.get("time_utc", "")), dict(doc.get("data") or {}))
    except (ValueError, KeyError, TypeError, RecursionError) as exc:  # RecursionError: JSON nested too deeply
        return Latch(f"{path}: latch file not valid JSON ({exc}); it is still a latch", "")


def write_latch(data_dir: Path, latch: Latch) -> None:
    """Write the latch durably (temporary file, fsync, rename, fsync of the directory). Raises OSError."""
    path = latch_path(data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps(latch.to_json(), indent=2, sort_keys=True) + "\n")


def clear_latch(data_dir: Path) -> Latch | None:
    """Remove the latch; returns what was set (None: nothing was)."""
    latch = read_latch(data_dir)
    latch_path(data_dir).unlink(missing_ok=True)
    return latch


class SafetyLatch:
    """The daemon's view of the latch: the file in ``data_dir``, plus one kept in memory if the file could not be
    written."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        self._unwritten: Latch | None = None

    def current(self) -> Latch | None:
        return read_latch(self.data_dir) or self._unwritten

    def set(self, reason: str, data: dict[str, Any] | None = None) -> Latch:
        """Latch (the first cause is kept when it is already set)."""
        existing = self.current()
        if existing is not None:
            return existing
        latch = Latch(reason, datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z"),
                      dict(data or {}))
        try:
            write_latch(self.data_dir, latch)
        except OSError as exc:
            _log.critical("safety latch could not be written to %s (%s): kept in memory until the daemon restarts",
                          latch_path(self.data_dir), exc)
            self._unwritten = latch
        return latch

    def check(self) -> None:
        """Raise :class:`SafetyLatched` while the latch is set (the run admission calls this)."""
        latch = self.current()
        if latch is not None:
            raise SafetyLatched(f"refused: safety latch set{f' at {latch.time_utc}' if latch.time_utc else ''}: "
                                f"{latch.reason}; {CLEAR_HINT}")
