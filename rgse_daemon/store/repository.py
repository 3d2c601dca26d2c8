"""The store's operations as plain blocking methods on one connection.

The asyncio daemon uses these through :class:`rgse_daemon.store.store.Store`, which runs them in the store's own
worker thread with a deadline; command-line tools and tests may call them directly. Every method that changes data
is one transaction, and every write is either keyed by the caller (run id, loop index, path) or derived from the
content (result id), so repeating a call after a timeout never duplicates anything.
"""

from __future__ import annotations

import hashlib
import json
import secrets
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from rgse_daemon.store.backend import Backend, Row, open_backend
from rgse_daemon.store.errors import NotFound, StoreConflict, StoreError
from rgse_daemon.store.migrations import migrate
from rgse_daemon.store.records import (
    RUN_TRANSITIONS,
    CalibrationRecord,
    EventLevel,
    EventRecord,
    LoopRecord,
    LoopState,
    OutboxMessage,
    OutboxRecord,
    PointRecord,
    PointState,
    ResultRecord,
    RunKind,
    RunRecord,
    RunState,
    TraceFileRecord,
    canonical_json,
    check_enum,
    check_id,
    check_index,
    check_relative_path,
    check_robot,
    check_sha256,
    from_text,
    opt_from_text,
    to_text,
)
from rgse_daemon.verdict import status_of

Clock = Callable[[], datetime]

_INTERRUPTED_DETAIL = "found running when the store was opened (daemon killed or power lost); raw files kept"


def utc_now() -> datetime:
    return datetime.now(UTC)


class Repository:
    """All store operations over one open database connection (SQLite or PostgreSQL)."""

    def __init__(self, backend: Backend, clock: Clock = utc_now) -> None:
        self._db = backend
        self._clock = clock

    @classmethod
    def open(
        cls, url: str | None, data_dir: Path, *, timeout_s: float = 10.0, clock: Clock = utc_now
    ) -> Repository:
        """Connect and bring the schema up to date. ``url`` as in :func:`~rgse_daemon.store.backend.open_backend`;
        ``timeout_s`` bounds every lock wait and statement in the database (and the connect)."""
        backend = open_backend(url, data_dir, timeout_s)
        repo = cls(backend, clock)
        try:
            migrate(backend, repo._now)
        except BaseException:
            backend.close()
            raise
        return repo

    @property
    def description(self) -> str:
        return self._db.description

    @property
    def dialect(self) -> str:
        return self._db.dialect.name

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _now(self) -> str:
        return to_text(self._clock())

    def schema_version(self) -> int:
        rows = self._db.execute("SELECT MAX(version) AS v FROM schema_version")
        return int(rows[0]["v"] or 0)

    # --- robots -------------------------------------------------------------------------------------------------
    def _ensure_robot(self, robot: str) -> None:
        """Insert the robot if new and lock its row until the transaction ends (serialises per-robot changes)."""
        self._db.execute(
            "INSERT INTO robots (name, created_utc) VALUES (?, ?) ON CONFLICT (name) DO NOTHING", (robot, self._now())
        )
        self._db.execute(f"SELECT name FROM robots WHERE name = ?{self._db.dialect.lock_rows}", (robot,))

    def robots(self) -> list[str]:
        return [r["name"] for r in self._db.execute("SELECT name FROM robots ORDER BY name")]

    # --- runs ---------------------------------------------------------------------------------------------------
    def create_run(
        self,
        kind: RunKind | str,
        robot: str,
        config: dict[str, Any],
        *,
        run_id: str | None = None,
        directory: str | None = None,
    ) -> RunRecord:
        """Record a new run in state ``queued``.

        ``run_id`` defaults to a sortable UTC time stamp plus random suffix; ``directory`` (relative to the archive
        root) defaults to ``runs/<run_id>``. Creating the same run again with identical arguments returns it.
        """
        kind = check_enum(RunKind, kind, "run kind")
        check_robot(robot)
        if not isinstance(config, dict):
            raise StoreError(f"run config: must be a JSON object, got {type(config).__name__}")
        config_text = canonical_json(config, "run config")
        now = self._clock()
        if run_id is None:
            run_id = f"{now.astimezone(UTC).strftime('%Y%m%dT%H%M%SZ')}-{secrets.token_hex(4)}"
        check_id(run_id, "run id")
        directory = check_relative_path(directory or f"runs/{run_id}", "run directory")
        with self._db.transaction():
            self._ensure_robot(robot)
            existing = self._db.execute("SELECT * FROM runs WHERE id = ?", (run_id,))
            if existing:
                rec = _run(existing[0])
                wanted = (kind, robot, json.loads(config_text), directory)
                if (rec.kind, rec.robot, rec.config, rec.directory) != wanted:
                    raise StoreConflict(f"run {run_id}: already exists with other kind, robot, config or directory")
                return rec
            self._db.execute(
                "INSERT INTO runs (id, kind, robot, state, created_utc, config, directory)"
                " VALUES (?, ?, ?, ?, ?, ?, ?)",
                (run_id, kind.value, robot, RunState.QUEUED.value, to_text(now), config_text, directory),
            )
            return self._get_run(run_id)

    def _get_run(self, run_id: str, lock: bool = False) -> RunRecord:
        suffix = self._db.dialect.lock_rows if lock else ""
        rows = self._db.execute(f"SELECT * FROM runs WHERE id = ?{suffix}", (run_id,))
        if not rows:
            raise NotFound(f"run {run_id!r}: no such run")
        return _run(rows[0])

    def get_run(self, run_id: str) -> RunRecord:
        return self._get_run(run_id)

    def list_runs(
        self, *, robot: str | None = None, state: RunState | str | None = None, kind: RunKind | str | None = None
    ) -> list[RunRecord]:
        """Runs, oldest first, optionally filtered."""
        where, params = [], []
        if robot is not None:
            where.append("robot = ?")
            params.append(check_robot(robot))
        if state is not None:
            where.append("state = ?")
            params.append(check_enum(RunState, state, "run state").value)
        if kind is not None:
            where.append("kind = ?")
            params.append(check_enum(RunKind, kind, "run kind").value)
        clause = f" WHERE {' AND '.join(where)}" if where else ""
        return [_run(r) for r in self._db.execute(f"SELECT * FROM runs{clause} ORDER BY created_utc, id", params)]

    def set_run_state(self, run_id: str, state: RunState | str, detail: str | None = None) -> RunRecord:
        """Move a run along :data:`RUN_TRANSITIONS`; setting the state it already has changes nothing.

        ``running`` stamps the start time (first time only) and clears an end time left by an interruption; a final
        state or ``interrupted`` stamps the end time.
        """
        state = check_enum(RunState, state, "run state")
        with self._db.transaction():
            run = self._get_run(run_id, lock=True)
            if run.state == state:
                return run
            if state not in RUN_TRANSITIONS[run.state]:
                raise StoreConflict(f"run {run_id}: cannot go from {run.state.value} to {state.value}")
            now = self._now()
            if state == RunState.RUNNING:
                self._db.execute(
                    "UPDATE runs SET state = ?, started_utc = COALESCE(started_utc, ?), ended_utc = NULL, detail = ?"
                    " WHERE id = ?",
                    (state.value, now, detail, run_id),
                )
            else:
                self._db.execute(
                    "UPDATE runs SET state = ?, ended_utc = ?, detail = ? WHERE id = ?",
                    (state.value, now, detail, run_id),
                )
            return self._get_run(run_id)

    def recover_interrupted(self, robot: str | None = None) -> list[RunRecord]:
        """Mark runs left ``running`` by a dead daemon as ``interrupted``; call once at daemon start.

        Their loops that were recording become ``interrupted``, campaign points being measured go back to
        ``pending`` (so a resumed campaign measures them again), an event is logged per run, and nothing is deleted.
        With a shared (fleet) database pass ``robot`` so only this daemon's runs are touched.
        """
        where, params = "state = ?", [RunState.RUNNING.value]
        if robot is not None:
            where += " AND robot = ?"
            params.append(check_robot(robot))
        with self._db.transaction():
            rows = self._db.execute(
                f"SELECT id FROM runs WHERE {where} ORDER BY created_utc, id{self._db.dialect.lock_rows}", params
            )
            now = self._now()
            for row in rows:
                run_id = row["id"]
                self._db.execute(
                    "UPDATE runs SET state = ?, ended_utc = ?, detail = ? WHERE id = ?",
                    (RunState.INTERRUPTED.value, now, _INTERRUPTED_DETAIL, run_id),
                )
                self._db.execute(
                    "UPDATE loops SET state = ?, updated_utc = ? WHERE run_id = ? AND state = ?",
                    (LoopState.INTERRUPTED.value, now, run_id, LoopState.RECORDING.value),
                )
                self._db.execute(
                    "UPDATE campaign_points SET state = ?, updated_utc = ? WHERE run_id = ? AND state = ?",
                    (PointState.PENDING.value, now, run_id, PointState.MEASURING.value),
                )
                self._insert_event(
                    EventLevel.WARNING, "run_interrupted", f"run {run_id}: {_INTERRUPTED_DETAIL}", run_id, None
                )
            return [self._get_run(r["id"]) for r in rows]

    # --- campaign points ----------------------------------------------------------------------------------------
    def add_points(self, run_id: str, specs: Sequence[dict[str, Any]]) -> list[PointRecord]:
        """Store a campaign's points (index = position in ``specs``); repeating with the same specs is a no-op."""
        texts = []
        for i, spec in enumerate(specs):
            if not isinstance(spec, dict):
                raise StoreError(f"run {run_id} point {i}: must be a JSON object, got {type(spec).__name__}")
            texts.append(canonical_json(spec, f"run {run_id} point {i}"))
        with self._db.transaction():
            self._get_run(run_id)
            now = self._now()
            for i, text in enumerate(texts):
                rows = self._db.execute("SELECT spec FROM campaign_points WHERE run_id = ? AND idx = ?", (run_id, i))
                if rows:
                    if rows[0]["spec"] != text:
                        raise StoreConflict(f"run {run_id} point {i}: already stored with another specification")
                    continue
                self._db.execute(
                    "INSERT INTO campaign_points (run_id, idx, spec, state, updated_utc) VALUES (?, ?, ?, ?, ?)",
                    (run_id, i, text, PointState.PENDING.value, now),
                )
        return self.points(run_id)

    def set_point_state(self, run_id: str, index: int, state: PointState | str) -> PointRecord:
        state = check_enum(PointState, state, "point state")
        check_index(index, "point index")
        with self._db.transaction():
            rows = self._db.execute(
                "UPDATE campaign_points SET state = ?, updated_utc = ? WHERE run_id = ? AND idx = ? RETURNING *",
                (state.value, self._now(), run_id, index),
            )
            if not rows:
                raise NotFound(f"run {run_id!r} point {index}: no such campaign point")
            return _point(rows[0])

    def points(self, run_id: str) -> list[PointRecord]:
        rows = self._db.execute("SELECT * FROM campaign_points WHERE run_id = ? ORDER BY idx", (run_id,))
        return [_point(r) for r in rows]

    # --- loops --------------------------------------------------------------------------------------------------
    def add_loop(self, run_id: str, index: int, trace_name: str, *, point_index: int | None = None) -> LoopRecord:
        """Record a planned measurement loop (state ``pending``); the same loop again returns the stored one."""
        check_index(index, "loop index")
        check_id(trace_name, "trace name")
        if point_index is not None:
            check_index(point_index, "point index")
        with self._db.transaction():
            self._get_run(run_id)
            rows = self._db.execute("SELECT * FROM loops WHERE run_id = ? AND idx = ?", (run_id, index))
            if rows:
                rec = _loop(rows[0])
                if (rec.trace_name, rec.point_index) != (trace_name, point_index):
                    raise StoreConflict(f"run {run_id} loop {index}: already stored with another trace or point")
                return rec
            rows = self._db.execute(
                "INSERT INTO loops (run_id, idx, point_idx, trace_name, state, updated_utc)"
                " VALUES (?, ?, ?, ?, ?, ?) RETURNING *",
                (run_id, index, point_index, trace_name, LoopState.PENDING.value, self._now()),
            )
            return _loop(rows[0])

    def update_loop(
        self,
        run_id: str,
        index: int,
        *,
        state: LoopState | str | None = None,
        robot_start_utc: datetime | None = None,
        robot_end_utc: datetime | None = None,
        record_start_utc: datetime | None = None,
        record_end_utc: datetime | None = None,
    ) -> LoopRecord:
        """Set a loop's state and/or its robot-motion and trace-recording times (only the arguments given)."""
        sets: list[str] = []
        params: list[Any] = []
        if state is not None:
            sets.append("state = ?")
            params.append(check_enum(LoopState, state, "loop state").value)
        for column, value in (
            ("robot_start_utc", robot_start_utc),
            ("robot_end_utc", robot_end_utc),
            ("record_start_utc", record_start_utc),
            ("record_end_utc", record_end_utc),
        ):
            if value is not None:
                sets.append(f"{column} = ?")
                params.append(to_text(value, column))
        sets.append("updated_utc = ?")
        params.append(self._now())
        with self._db.transaction():
            rows = self._db.execute(
                f"UPDATE loops SET {', '.join(sets)} WHERE run_id = ? AND idx = ? RETURNING *",
                [*params, run_id, index],
            )
            if not rows:
                raise NotFound(f"run {run_id!r} loop {index}: no such loop")
            return _loop(rows[0])

    def loops(self, run_id: str) -> list[LoopRecord]:
        return [_loop(r) for r in self._db.execute("SELECT * FROM loops WHERE run_id = ? ORDER BY idx", (run_id,))]

    # --- trace files --------------------------------------------------------------------------------------------
    def add_trace_file(
        self, run_id: str, path: str, sha256: str, size_bytes: int, *, loop_index: int | None = None
    ) -> TraceFileRecord:
        """Index an archived raw file (``path`` relative to the archive root).

        Call after :func:`~rgse_daemon.store.archive.archive_file` returned. The same path with the same hash and
        size is a no-op; with a different hash it is a :class:`StoreConflict` (raw data is never replaced).
        """
        check_relative_path(path, "trace file path")
        check_sha256(sha256, f"trace file {path} sha256")
        check_index(size_bytes, f"trace file {path} size")
        if loop_index is not None:
            check_index(loop_index, "loop index")
        with self._db.transaction():
            self._get_run(run_id)
            rows = self._db.execute("SELECT * FROM trace_files WHERE path = ?", (path,))
            if rows:
                rec = _trace_file(rows[0])
                if (rec.run_id, rec.sha256, rec.size_bytes, rec.loop_index) != (run_id, sha256, size_bytes, loop_index):
                    raise StoreConflict(
                        f"trace file {path}: already indexed for run {rec.run_id} with sha256 {rec.sha256[:12]}…,"
                        f" {rec.size_bytes} bytes; raw files are never replaced"
                    )
                return rec
            rows = self._db.execute(
                "INSERT INTO trace_files (run_id, loop_idx, path, sha256, size_bytes, archived_utc)"
                " VALUES (?, ?, ?, ?, ?, ?) RETURNING *",
                (run_id, loop_index, path, sha256, size_bytes, self._now()),
            )
            return _trace_file(rows[0])

    def trace_files(self, run_id: str) -> list[TraceFileRecord]:
        rows = self._db.execute("SELECT * FROM trace_files WHERE run_id = ? ORDER BY id", (run_id,))
        return [_trace_file(r) for r in rows]

    # --- calibrations -------------------------------------------------------------------------------------------
    def add_calibration(
        self, document: dict[str, Any], *, run_id: str | None = None, activate: bool = False
    ) -> CalibrationRecord:
        """Store a CAL.json document (interfaces §3) under its ``calibration_id``.

        It becomes the robot's active calibration if ``activate`` or if the robot has none yet, so a robot with any
        calibration always has exactly one active. Adding the identical document again is a no-op (plus activation
        if asked); another document under the same id is a :class:`StoreConflict`.
        """
        if not isinstance(document, dict):
            raise StoreError(f"calibration document: must be a JSON object, got {type(document).__name__}")
        cal_id = check_id(document.get("calibration_id"), "calibration_id")
        robot = check_robot(document.get("robot"))
        method = document.get("method")
        if not isinstance(method, str) or not method:
            raise StoreError(f"calibration {cal_id}: 'method' must be a non-empty string, got {method!r}")
        created = _parse_document_time(document.get("created_utc"), f"calibration {cal_id} created_utc")
        text = canonical_json(document, f"calibration {cal_id}")
        with self._db.transaction():
            self._ensure_robot(robot)
            if run_id is not None:
                self._get_run(run_id)
            rows = self._db.execute("SELECT document FROM calibrations WHERE id = ?", (cal_id,))
            if rows:
                if rows[0]["document"] != text:
                    raise StoreConflict(f"calibration {cal_id}: already stored with a different document")
            else:
                self._db.execute(
                    "INSERT INTO calibrations (id, robot, created_utc, method, document, active, added_utc, run_id)"
                    " VALUES (?, ?, ?, ?, ?, 0, ?, ?)",
                    (cal_id, robot, created, method, text, self._now(), run_id),
                )
            has_active = self._db.execute("SELECT id FROM calibrations WHERE robot = ? AND active = 1", (robot,))
            if activate or not has_active:
                self._activate(cal_id, robot)
            return self._get_calibration(cal_id)

    def activate_calibration(self, calibration_id: str) -> CalibrationRecord:
        """Make this calibration its robot's only active one, atomically (the old one is deactivated in the same
        transaction; a unique index makes two active rows impossible)."""
        with self._db.transaction():
            cal = self._get_calibration(calibration_id)
            self._ensure_robot(cal.robot)
            self._activate(calibration_id, cal.robot)
            return self._get_calibration(calibration_id)

    def _activate(self, calibration_id: str, robot: str) -> None:
        # Deactivate first: the partial unique index is checked statement by statement.
        self._db.execute(
            "UPDATE calibrations SET active = 0 WHERE robot = ? AND active = 1 AND id <> ?", (robot, calibration_id)
        )
        self._db.execute(
            "UPDATE calibrations SET active = 1, activated_utc = ? WHERE id = ? AND active = 0",
            (self._now(), calibration_id),
        )

    def _get_calibration(self, calibration_id: str) -> CalibrationRecord:
        rows = self._db.execute("SELECT * FROM calibrations WHERE id = ?", (calibration_id,))
        if not rows:
            raise NotFound(f"calibration {calibration_id!r}: no such calibration")
        return _calibration(rows[0])

    def get_calibration(self, calibration_id: str) -> CalibrationRecord:
        return self._get_calibration(calibration_id)

    def active_calibration(self, robot: str) -> CalibrationRecord | None:
        rows = self._db.execute("SELECT * FROM calibrations WHERE robot = ? AND active = 1", (check_robot(robot),))
        return _calibration(rows[0]) if rows else None

    def calibrations(self, robot: str | None = None) -> list[CalibrationRecord]:
        if robot is None:
            rows = self._db.execute("SELECT * FROM calibrations ORDER BY added_utc, id")
        else:
            rows = self._db.execute(
                "SELECT * FROM calibrations WHERE robot = ? ORDER BY added_utc, id", (check_robot(robot),)
            )
        return [_calibration(r) for r in rows]

    # --- results ------------------------------------------------------------------------------------------------
    def record_result(
        self,
        run_id: str,
        result: dict[str, Any],
        trace_sha256: Sequence[str],
        *,
        publish: OutboxMessage | None = None,
    ) -> ResultRecord:
        """Store a result (interfaces §1 ``rgse mass --json``) computed from the run's archived raw files.

        Every hash in ``trace_sha256`` must be an archived trace file of this run, so no result exists that its raw
        files cannot reproduce. The result id is derived from run, result and inputs: recording the same result
        again returns the stored row and queues nothing new. With ``publish``, the MQTT message is queued in the
        outbox in the same transaction (durable first, published after).
        """
        if not isinstance(result, dict):
            raise StoreError(f"run {run_id} result: must be a JSON object, got {type(result).__name__}")
        text = canonical_json(result, f"run {run_id} result")
        hashes = sorted({check_sha256(h, f"run {run_id} result input") for h in trace_sha256})
        if not hashes:
            raise StoreError(f"run {run_id} result: names no raw trace files; a result must be reproducible")
        if publish is not None:
            _check_topic(publish.topic)
            _check_qos(publish.qos)
        result_id = hashlib.sha256(
            canonical_json({"run_id": run_id, "result": result, "trace_sha256": hashes}, "result id").encode()
        ).hexdigest()[:32]
        cal_id = result.get("calibration_id")
        with self._db.transaction():
            self._get_run(run_id)
            if self._db.execute("SELECT id FROM results WHERE id = ?", (result_id,)):
                return self._get_result(result_id)
            files = self._db.execute("SELECT id, sha256 FROM trace_files WHERE run_id = ?", (run_id,))
            missing = [h for h in hashes if h not in {f["sha256"] for f in files}]
            if missing:
                raise StoreConflict(
                    f"run {run_id} result: input(s) {', '.join(h[:12] + '…' for h in missing)} are not archived trace "
                    "files of this run; a result must be reproducible from its raw files"
                )
            self._db.execute(
                "INSERT INTO results (id, run_id, calibration_id, result, created_utc, status)"
                " VALUES (?, ?, ?, ?, ?, ?)",
                (result_id, run_id, cal_id if isinstance(cal_id, str) else None, text, self._now(), status_of(result)),
            )
            for f in files:
                if f["sha256"] in hashes:
                    self._db.execute(
                        "INSERT INTO result_inputs (result_id, trace_file_id) VALUES (?, ?)", (result_id, f["id"])
                    )
            if publish is not None:
                self._insert_outbox(publish.topic, text, publish.retained, publish.qos)
            return self._get_result(result_id)

    def _get_result(self, result_id: str) -> ResultRecord:
        rows = self._db.execute("SELECT * FROM results WHERE id = ?", (result_id,))
        if not rows:
            raise NotFound(f"result {result_id!r}: no such result")
        inputs = self._db.execute(
            "SELECT DISTINCT t.sha256 AS sha256 FROM result_inputs i JOIN trace_files t ON t.id = i.trace_file_id"
            " WHERE i.result_id = ? ORDER BY t.sha256",
            (result_id,),
        )
        return _result(rows[0], tuple(r["sha256"] for r in inputs))

    def get_result(self, result_id: str) -> ResultRecord:
        return self._get_result(result_id)

    def results(self, run_id: str) -> list[ResultRecord]:
        rows = self._db.execute("SELECT id FROM results WHERE run_id = ? ORDER BY created_utc, id", (run_id,))
        return [self._get_result(r["id"]) for r in rows]

    # --- events and alarms --------------------------------------------------------------------------------------
    def add_event(
        self,
        level: EventLevel | str,
        kind: str,
        message: str,
        *,
        run_id: str | None = None,
        data: dict[str, Any] | None = None,
    ) -> EventRecord:
        """Log an event or alarm (interlock trip, link loss, refused command) durably."""
        level = check_enum(EventLevel, level, "event level")
        check_id(kind, "event kind")
        if not isinstance(message, str) or not message:
            raise StoreError(f"event {kind}: message must be a non-empty string")
        data_text = None if data is None else canonical_json(data, f"event {kind} data")
        with self._db.transaction():
            return self._insert_event(level, kind, message, run_id, data_text)

    def _insert_event(
        self, level: EventLevel, kind: str, message: str, run_id: str | None, data_text: str | None
    ) -> EventRecord:
        rows = self._db.execute(
            "INSERT INTO events (time_utc, level, kind, message, run_id, data) VALUES (?, ?, ?, ?, ?, ?) RETURNING *",
            (self._now(), level.value, kind, message, run_id, data_text),
        )
        return _event(rows[0])

    def events(self, *, run_id: str | None = None, after_id: int = 0, limit: int = 1000) -> list[EventRecord]:
        """Events with id > ``after_id``, oldest first (page with the last id seen)."""
        check_index(after_id, "after_id")
        check_index(limit, "limit")
        if run_id is None:
            rows = self._db.execute("SELECT * FROM events WHERE id > ? ORDER BY id LIMIT ?", (after_id, limit))
        else:
            rows = self._db.execute(
                "SELECT * FROM events WHERE run_id = ? AND id > ? ORDER BY id LIMIT ?", (run_id, after_id, limit)
            )
        return [_event(r) for r in rows]

    # --- MQTT outbox --------------------------------------------------------------------------------------------
    def enqueue(self, topic: str, payload: Any, *, retained: bool = False, qos: int = 1) -> OutboxRecord:
        """Queue an MQTT message durably; a string payload is sent as is, anything else as canonical JSON."""
        _check_topic(topic)
        _check_qos(qos)
        text = payload if isinstance(payload, str) else canonical_json(payload, f"outbox payload for {topic}")
        with self._db.transaction():
            return self._insert_outbox(topic, text, retained, qos)

    def _insert_outbox(self, topic: str, payload: str, retained: bool, qos: int) -> OutboxRecord:
        rows = self._db.execute(
            "INSERT INTO outbox (topic, payload, retained, qos, created_utc) VALUES (?, ?, ?, ?, ?) RETURNING *",
            (topic, payload, 1 if retained else 0, qos, self._now()),
        )
        return _outbox(rows[0])

    def pending_outbox(self, limit: int = 100, *, topic_prefix: str | None = None) -> list[OutboxRecord]:
        """Messages not yet published, oldest first: publish them in this order.

        On a shared (fleet) database pass ``topic_prefix`` (e.g. ``rgse/<robot>/``) so each daemon publishes only
        its own robot's messages.
        """
        check_index(limit, "limit")
        if topic_prefix is None:
            rows = self._db.execute("SELECT * FROM outbox WHERE published_utc IS NULL ORDER BY id LIMIT ?", (limit,))
        else:
            rows = self._db.execute(
                "SELECT * FROM outbox WHERE published_utc IS NULL AND substr(topic, 1, ?) = ? ORDER BY id LIMIT ?",
                (len(topic_prefix), topic_prefix, limit),
            )
        return [_outbox(r) for r in rows]

    def mark_published(self, outbox_id: int) -> OutboxRecord:
        """Record that the broker acknowledged the message. The row is kept; marking twice keeps the first time."""
        with self._db.transaction():
            rows = self._db.execute(
                "UPDATE outbox SET published_utc = COALESCE(published_utc, ?), attempts = attempts + 1"
                " WHERE id = ? RETURNING *",
                (self._now(), outbox_id),
            )
            if not rows:
                raise NotFound(f"outbox message {outbox_id}: no such message")
            return _outbox(rows[0])

    def record_publish_failure(self, outbox_id: int, error: str) -> OutboxRecord:
        """Count a failed publish attempt and keep its error visible; the message stays pending."""
        with self._db.transaction():
            rows = self._db.execute(
                "UPDATE outbox SET attempts = attempts + 1, last_error = ? WHERE id = ? RETURNING *",
                (str(error)[:2000], outbox_id),
            )
            if not rows:
                raise NotFound(f"outbox message {outbox_id}: no such message")
            return _outbox(rows[0])

    def get_outbox(self, outbox_id: int) -> OutboxRecord:
        rows = self._db.execute("SELECT * FROM outbox WHERE id = ?", (outbox_id,))
        if not rows:
            raise NotFound(f"outbox message {outbox_id}: no such message")
        return _outbox(rows[0])


# --- helpers -------------------------------------------------------------------------------------------------------
def _parse_document_time(value: object, what: str) -> str:
    if not isinstance(value, str):
        raise StoreError(f"{what}: must be an ISO-8601 UTC time string, got {value!r}")
    try:
        ts = datetime.fromisoformat(value)
    except ValueError as exc:
        raise StoreError(f"{what}: {value!r} is not an ISO-8601 time") from exc
    if ts.tzinfo is None:
        raise StoreError(f"{what}: {value!r} has no time zone; give UTC ('Z')")
    return to_text(ts, what)


def _check_topic(topic: object) -> None:
    if (
        not isinstance(topic, str)
        or not topic
        or len(topic.encode()) > 65535
        or any(c in topic for c in "+#\x00")
    ):
        raise StoreError(f"MQTT topic {topic!r}: must be a non-empty topic name without wildcards")


def _check_qos(qos: object) -> None:
    if qos not in (0, 1, 2) or isinstance(qos, bool):
        raise StoreError(f"MQTT QoS {qos!r}: must be 0, 1 or 2")


def _run(r: Row) -> RunRecord:
    return RunRecord(
        id=r["id"],
        kind=RunKind(r["kind"]),
        robot=r["robot"],
        state=RunState(r["state"]),
        created_utc=from_text(r["created_utc"]),
        started_utc=opt_from_text(r["started_utc"]),
        ended_utc=opt_from_text(r["ended_utc"]),
        config=json.loads(r["config"]),
        directory=r["directory"],
        detail=r["detail"],
    )


def _point(r: Row) -> PointRecord:
    return PointRecord(
        run_id=r["run_id"],
        index=r["idx"],
        spec=json.loads(r["spec"]),
        state=PointState(r["state"]),
        updated_utc=from_text(r["updated_utc"]),
    )


def _loop(r: Row) -> LoopRecord:
    return LoopRecord(
        run_id=r["run_id"],
        index=r["idx"],
        point_index=r["point_idx"],
        trace_name=r["trace_name"],
        state=LoopState(r["state"]),
        robot_start_utc=opt_from_text(r["robot_start_utc"]),
        robot_end_utc=opt_from_text(r["robot_end_utc"]),
        record_start_utc=opt_from_text(r["record_start_utc"]),
        record_end_utc=opt_from_text(r["record_end_utc"]),
        updated_utc=from_text(r["updated_utc"]),
    )


def _trace_file(r: Row) -> TraceFileRecord:
    return TraceFileRecord(
        id=int(r["id"]),
        run_id=r["run_id"],
        loop_index=r["loop_idx"],
        path=r["path"],
        sha256=r["sha256"],
        size_bytes=int(r["size_bytes"]),
        archived_utc=from_text(r["archived_utc"]),
    )


def _calibration(r: Row) -> CalibrationRecord:
    return CalibrationRecord(
        id=r["id"],
        robot=r["robot"],
        created_utc=from_text(r["created_utc"]),
        method=r["method"],
        document=json.loads(r["document"]),
        active=bool(r["active"]),
        added_utc=from_text(r["added_utc"]),
        activated_utc=opt_from_text(r["activated_utc"]),
        run_id=r["run_id"],
    )


def _result(r: Row, hashes: tuple[str, ...]) -> ResultRecord:
    result = json.loads(r["result"])
    return ResultRecord(
        id=r["id"],
        run_id=r["run_id"],
        calibration_id=r["calibration_id"],
        result=result,
        created_utc=from_text(r["created_utc"]),
        trace_sha256=hashes,
        status=r["status"] or status_of(result),  # NULL: stored before the column existed
    )


def _event(r: Row) -> EventRecord:
    return EventRecord(
        id=int(r["id"]),
        time_utc=from_text(r["time_utc"]),
        level=EventLevel(r["level"]),
        kind=r["kind"],
        message=r["message"],
        run_id=r["run_id"],
        data=None if r["data"] is None else json.loads(r["data"]),
    )


def _outbox(r: Row) -> OutboxRecord:
    return OutboxRecord(
        id=int(r["id"]),
        topic=r["topic"],
        payload=r["payload"],
        retained=bool(r["retained"]),
        qos=int(r["qos"]),
        created_utc=from_text(r["created_utc"]),
        published_utc=opt_from_text(r["published_utc"]),
        attempts=int(r["attempts"]),
        last_error=r["last_error"],
    )
