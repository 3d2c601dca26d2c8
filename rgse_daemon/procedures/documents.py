"""Run documents: what a run records, as typed values (bluesky's documents, architecture lesson 1).

A plan never holds the store. What it wants on the record it yields as a document; the engine hands each document
first to its :class:`Recorder` (the store: :class:`~rgse_daemon.procedures.recorder.StoreRecorder`, awaited, bounded;
an error there fails the plan, as a lost record must) and then to the document subscribers (the MQTT publisher,
the report; plain callables that must not block). Documents are messages that are not inert: a dry run records
nothing.

The life of a run, in order::

    OpenRun
      [PointStarted]                                   campaign: per point, after the operator's confirmation
        LoopStarted → LoopRecording → LoopRecorded → TraceArchived      × loops
      [PointDone]
    Result                                             the mass, or the fitted calibration (made active)
    CloseRun                                           completed / aborted / failed / interrupted

:class:`OpenRun` and :class:`CloseRun` are sent by the engine itself (:meth:`RunEngine.execute`, the one run
skeleton of the measurement and the calibration campaign); the plan yields the documents in between. Documents
carry no run id: the engine knows which run it executes and gives it to the recorder.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol

from rgse_daemon.procedures.messages import Msg
from rgse_daemon.store import ArchivedFile, LoopRecord, PointRecord, RunKind, RunState, TraceFileRecord

#: The run id of a dry run (nothing is recorded under it).
DRY_RUN_ID = "dry-run"


@dataclass(frozen=True)
class RunContext:
    """Where a run records: its id and its directory under the archive root (raw files, manifest, CAL.json)."""

    run_id: str
    run_dir: Path
    archive: Path

    @classmethod
    def dry(cls) -> RunContext:
        """The context of a dry run: nothing is pulled or written, so the paths are never used."""
        return cls(DRY_RUN_ID, Path(DRY_RUN_ID), Path("."))


@dataclass(frozen=True)
class CampaignProgress:
    """Reply to :class:`~rgse_daemon.procedures.messages.ReadCampaign`: what the store holds of the run so far."""

    points: tuple[PointRecord, ...] = ()
    loops: tuple[LoopRecord, ...] = ()
    trace_files: tuple[TraceFileRecord, ...] = ()


@dataclass(frozen=True)
class Document(Msg):
    """Base of every run document (see the module docstring)."""


@dataclass(frozen=True)
class OpenRun(Document):
    """A run begins: a new run of ``kind`` (a campaign with its ``points``, the specs the operator will mount), or
    the continuation of the interrupted campaign ``resume_run_id``. Reply: the :class:`RunContext`."""

    kind: RunKind
    robot: str
    config: dict[str, Any] = field(default_factory=dict)
    points: tuple[dict[str, Any], ...] = ()
    resume_run_id: str | None = None

    def dry_reply(self) -> RunContext:
        return RunContext.dry()


@dataclass(frozen=True)
class PointStarted(Document):
    """The operator confirmed the load of campaign point ``point_index`` (``said``: the prompt and the operator's
    ``note``); loops of an earlier attempt at this point are superseded, the point is being measured."""

    point_index: int
    said: str
    note: str = ""


@dataclass(frozen=True)
class LoopStarted(Document):
    """Loop ``index`` (1-based within the run) begins its brake-release move; its trace will be ``trace``."""

    index: int
    trace: str
    robot_start_utc: datetime
    point_index: int | None = None


@dataclass(frozen=True)
class LoopRecording(Document):
    """The robot settled; the trace of loop ``index`` starts recording."""

    index: int
    robot_end_utc: datetime
    record_start_utc: datetime


@dataclass(frozen=True)
class LoopRecorded(Document):
    """The controller wrote the trace of loop ``index``."""

    index: int
    record_end_utc: datetime


@dataclass(frozen=True)
class TraceArchived(Document):
    """The trace files of loop ``index`` are durable and verified in the run directory (absolute paths, SHA-256,
    size); ``deleted`` tells whether the controller's copies are gone (else ``delete_note`` says why; empty: the
    delete comes after this document is recorded)."""

    index: int
    trace: str
    files: tuple[ArchivedFile, ...]
    deleted: bool
    delete_note: str = ""


@dataclass(frozen=True)
class PointDone(Document):
    """Every loop of campaign point ``point_index`` is archived."""

    point_index: int


@dataclass(frozen=True)
class Result(Document):
    """The run's result (``rgse mass --json`` / the calibration summary) with the SHA-256 of the raw files it was
    computed from; ``calibration`` (a campaign) is the fitted CAL.json document, to be stored and made active. The
    recorder stores it with its outbox message (``<prefix>/run/<run_id>/result``) in one transaction."""

    result: dict[str, Any]
    trace_sha256: Sequence[str]
    calibration: dict[str, Any] | None = None


@dataclass(frozen=True)
class CloseRun(Document):
    """How the run ended: completed, aborted, failed (``detail``: the cause) or interrupted (the daemon stopped;
    a campaign then resumes)."""

    state: RunState
    detail: str | None = None


class Recorder(Protocol):
    """Where documents become durable (the store). ``record`` is awaited by the engine, with a deadline."""

    async def record(self, run_id: str | None, doc: Document) -> Any:
        """Make ``doc`` durable; returns the reply of the document (:class:`RunContext` for :class:`OpenRun`)."""
        ...

    async def campaign(self, run_id: str) -> CampaignProgress: ...
