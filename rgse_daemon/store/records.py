"""What the store hands back: immutable records, state enums, and the value checks shared by all tables.

Timestamps are aware UTC datetimes in Python and fixed-width ISO-8601 text (``2024-05-01T12:00:00.000000Z``) in
the database, so they sort correctly as text on both SQLite and PostgreSQL. JSON documents are stored as canonical
text (sorted keys, no NaN) so that equal documents are equal strings.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import PurePosixPath
from typing import Any, TypeVar

from rgse_daemon.runkind import RunKind
from rgse_daemon.store.errors import StoreError

E = TypeVar("E", bound=StrEnum)

_TS_FORMAT = "%Y-%m-%dT%H:%M:%S.%fZ"
_ROBOT_NAME = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")  # as config.RobotConfig.name: it becomes an MQTT topic level
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_ID = re.compile(r"^[A-Za-z0-9_.:\-]{1,128}$")


class RunState(StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    COMPLETED = "completed"
    FAILED = "failed"
    INTERRUPTED = "interrupted"
    """Found ``running`` when the store was opened: the daemon died (SIGKILL, power loss). Raw files are kept."""
    ABORTED = "aborted"


#: Allowed run state changes. ``interrupted`` may resume (a campaign continues after a restart) or be closed.
RUN_TRANSITIONS: dict[RunState, frozenset[RunState]] = {
    RunState.QUEUED: frozenset({RunState.RUNNING, RunState.FAILED, RunState.ABORTED}),
    RunState.RUNNING: frozenset({RunState.COMPLETED, RunState.FAILED, RunState.ABORTED, RunState.INTERRUPTED}),
    RunState.INTERRUPTED: frozenset({RunState.RUNNING, RunState.COMPLETED, RunState.FAILED, RunState.ABORTED}),
    RunState.COMPLETED: frozenset(),
    RunState.FAILED: frozenset(),
    RunState.ABORTED: frozenset(),
}


class LoopState(StrEnum):
    PENDING = "pending"
    RECORDING = "recording"
    RECORDED = "recorded"  # the trace is complete on the controller, not yet archived here
    ARCHIVED = "archived"
    FAILED = "failed"
    INTERRUPTED = "interrupted"


class PointState(StrEnum):
    PENDING = "pending"
    MEASURING = "measuring"
    DONE = "done"
    FAILED = "failed"


class EventLevel(StrEnum):
    DEBUG = "debug"
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"
    CRITICAL = "critical"


@dataclass(frozen=True)
class RunRecord:
    id: str
    kind: RunKind
    robot: str
    state: RunState
    created_utc: datetime
    started_utc: datetime | None
    ended_utc: datetime | None
    config: dict[str, Any]
    directory: str
    """The run's directory relative to the archive root (POSIX separators)."""
    detail: str | None
    """Why the run failed, was aborted or interrupted."""


@dataclass(frozen=True)
class PointRecord:
    """One load configuration of a calibration campaign (a manifest ``[[point]]``) and how far it got."""

    run_id: str
    index: int
    spec: dict[str, Any]
    state: PointState
    updated_utc: datetime


@dataclass(frozen=True)
class LoopRecord:
    run_id: str
    index: int
    point_index: int | None
    trace_name: str
    state: LoopState
    robot_start_utc: datetime | None
    robot_end_utc: datetime | None
    record_start_utc: datetime | None
    record_end_utc: datetime | None
    updated_utc: datetime


@dataclass(frozen=True)
class TraceFileRecord:
    id: int
    run_id: str
    loop_index: int | None
    path: str
    """Relative to the archive root (POSIX separators)."""
    sha256: str
    size_bytes: int
    archived_utc: datetime


@dataclass(frozen=True)
class CalibrationRecord:
    id: str
    robot: str
    created_utc: datetime
    method: str
    document: dict[str, Any]
    """The CAL.json document (interfaces §3) exactly as added."""
    active: bool
    added_utc: datetime
    activated_utc: datetime | None
    run_id: str | None


@dataclass(frozen=True)
class ResultRecord:
    id: str
    """Derived from run, result and input hashes: recording the same result twice gives the same id, one row."""
    run_id: str
    calibration_id: str | None
    result: dict[str, Any]
    created_utc: datetime
    trace_sha256: tuple[str, ...]
    """The archived raw files the result was computed from (sorted)."""
    status: str = "ok"
    """``ok``, ``warning`` or ``refused`` (rgse_daemon.verdict), the column ``results.status``."""


@dataclass(frozen=True)
class EventRecord:
    id: int
    time_utc: datetime
    level: EventLevel
    kind: str
    message: str
    run_id: str | None
    data: dict[str, Any] | None


@dataclass(frozen=True)
class OutboxMessage:
    """Where and how to publish a result once it is stored."""

    topic: str
    retained: bool = True
    qos: int = 1


@dataclass(frozen=True)
class OutboxRecord:
    id: int
    topic: str
    payload: str
    retained: bool
    qos: int
    created_utc: datetime
    published_utc: datetime | None
    attempts: int
    last_error: str | None


# --- value conversion and checks ---------------------------------------------------------------------------------
def to_text(ts: datetime, what: str = "timestamp") -> str:
    if ts.tzinfo is None:
        raise StoreError(f"{what}: naive datetime {ts.isoformat()}; give an aware (UTC) time")
    return ts.astimezone(UTC).strftime(_TS_FORMAT)


def from_text(text: str) -> datetime:
    return datetime.strptime(text, _TS_FORMAT).replace(tzinfo=UTC)


def opt_from_text(text: str | None) -> datetime | None:
    return None if text is None else from_text(text)


def canonical_json(value: Any, what: str) -> str:
    """Canonical JSON text; NaN/Infinity and non-JSON types are a :class:`StoreError` naming ``what``."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False, ensure_ascii=False)
    except (TypeError, ValueError) as exc:
        raise StoreError(f"{what}: not storable as JSON: {exc}") from exc


def check_robot(name: object) -> str:
    if not isinstance(name, str) or not _ROBOT_NAME.fullmatch(name):
        raise StoreError(f"robot name {name!r}: must be 1-64 characters of A-Z a-z 0-9 _ . -")
    return name


def check_id(value: object, what: str) -> str:
    if not isinstance(value, str) or not _ID.fullmatch(value):
        raise StoreError(f"{what} {value!r}: must be 1-128 characters of A-Z a-z 0-9 _ . : -")
    return value


def check_sha256(value: object, what: str) -> str:
    if not isinstance(value, str) or not _SHA256.fullmatch(value):
        raise StoreError(f"{what}: {value!r} is not a lower-case hex SHA-256")
    return value


def check_relative_path(value: object, what: str) -> str:
    """A non-empty relative POSIX path that stays below its root (no ``..``, no absolute, no backslash)."""
    if not isinstance(value, str) or not value or "\\" in value or "\x00" in value:
        raise StoreError(f"{what} {value!r}: must be a non-empty relative POSIX path")
    p = PurePosixPath(value)
    if p.is_absolute() or any(part in ("..", "") for part in value.split("/")) or str(p) != value:
        raise StoreError(f"{what} {value!r}: must be a normalised relative path without '..'")
    return value


def check_index(value: object, what: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise StoreError(f"{what} {value!r}: must be an integer >= 0")
    return value


def check_enum(enum: type[E], value: object, what: str) -> E:
    try:
        return enum(value)
    except ValueError:
        allowed = ", ".join(e.value for e in enum)
        raise StoreError(f"{what} {value!r}: must be one of {allowed}") from None
