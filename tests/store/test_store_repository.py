"""Store operations against real SQLite files and a real PostgreSQL server (each test runs on both)."""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
import threading
from datetime import UTC, datetime
from pathlib import Path

import pytest

from rgse_daemon.store import (
    EventLevel,
    LoopState,
    NotFound,
    OutboxMessage,
    PointState,
    Repository,
    RunKind,
    RunState,
    StoreConflict,
    StoreError,
    archive_file,
    archive_root,
    relative_path,
)
from rgse_daemon.store.migrations import MIGRATIONS

from .conftest import ROBOT, calibration_doc

RESULT = {
    "mass_kg": 107.65, "u_kg": 0.35, "U_kg": 0.70, "k": 2, "gross_mass_kg": 117.94, "fixture_mass_kg": 10.288,
    "loops": 2, "samples_used": 4253, "samples_total": 10000, "calibration_id": "cal-1", "method": "paper",
    "cog_m": None, "warnings": [],
}


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _run_with_files(repo: Repository, n: int = 2) -> tuple[str, list[str]]:
    run = repo.create_run(RunKind.MEASUREMENT, ROBOT, {"loops": n}, run_id="run-1")
    repo.set_run_state(run.id, RunState.RUNNING)
    hashes = []
    for i in range(n):
        repo.add_loop(run.id, i, f"dut_l{i + 1:02d}")
        h = _sha(f"file {i}")
        repo.add_trace_file(run.id, f"{run.directory}/dut_l{i + 1:02d}_NextGenDrive#3.r64", h, 1000 + i, loop_index=i)
        hashes.append(h)
    return run.id, hashes


def test_open_creates_the_schema_once(store_url: str | None, data_dir: Path) -> None:
    with Repository.open(store_url, data_dir) as repo:
        assert repo.schema_version() == len(MIGRATIONS)
        repo.create_run("measurement", ROBOT, {})
    with Repository.open(store_url, data_dir) as repo:  # re-open: nothing re-applied, data still there
        assert repo.schema_version() == len(MIGRATIONS)
        assert len(repo.list_runs()) == 1


def test_sqlite_store_is_a_wal_file_under_the_data_dir_with_foreign_keys(data_dir: Path) -> None:
    with Repository.open(None, data_dir) as repo:
        assert repo.dialect == "sqlite"
        with pytest.raises(StoreError, match="FOREIGN KEY"):
            # A loop pointing at a campaign point that does not exist: only the database's FK check can refuse it.
            run = repo.create_run("calibration", ROBOT, {})
            repo.add_loop(run.id, 0, "cal00_l01", point_index=3)
    conn = sqlite3.connect(data_dir / "rgse.sqlite3")
    try:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    finally:
        conn.close()


def test_run_lifecycle(repo: Repository) -> None:
    run = repo.create_run("measurement", ROBOT, {"fixture_mass_kg": 10.288}, run_id="m-1")
    assert (run.state, run.kind, run.directory) == (RunState.QUEUED, RunKind.MEASUREMENT, "runs/m-1")
    assert run.started_utc is None
    assert repo.create_run("measurement", ROBOT, {"fixture_mass_kg": 10.288}, run_id="m-1") == run  # idempotent
    with pytest.raises(StoreConflict, match="m-1: already exists"):
        repo.create_run("measurement", ROBOT, {"fixture_mass_kg": 11.0}, run_id="m-1")

    running = repo.set_run_state("m-1", "running")
    assert running.state == RunState.RUNNING and running.started_utc is not None and running.ended_utc is None
    done = repo.set_run_state("m-1", RunState.COMPLETED)
    assert done.ended_utc is not None and done.ended_utc >= running.started_utc
    assert repo.set_run_state("m-1", RunState.COMPLETED) == done  # same state: no change
    with pytest.raises(StoreConflict, match="m-1: cannot go from completed to running"):
        repo.set_run_state("m-1", RunState.RUNNING)
    failed = repo.set_run_state(repo.create_run("calibration", ROBOT, {}).id, "failed", detail="link lost")
    assert failed.detail == "link lost"

    assert [r.id for r in repo.list_runs(state="completed")] == ["m-1"]
    assert [r.state for r in repo.list_runs(robot=ROBOT, kind="calibration")] == [RunState.FAILED]
    assert repo.robots() == [ROBOT]
    with pytest.raises(NotFound, match="'nope': no such run"):
        repo.get_run("nope")


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("weighing", ROBOT, {}), "run kind 'weighing': must be one of measurement, properties, calibration"),
        (("measurement", "bad/robot", {}), "robot name 'bad/robot'"),
        (("measurement", ROBOT, {"x": math.nan}), "run config: not storable as JSON"),
        (("measurement", ROBOT, [1, 2]), "run config: must be a JSON object"),
    ],
)
def test_bad_run_input_is_a_typed_error_naming_the_field(repo: Repository, args: tuple, match: str) -> None:
    with pytest.raises(StoreError, match=match):
        repo.create_run(*args)


def test_bad_paths_and_hashes_are_refused(repo: Repository) -> None:
    run = repo.create_run("measurement", ROBOT, {})
    for bad in ("../escape.r64", "/abs/x.r64", "runs//x", "runs/./x", ""):
        with pytest.raises(StoreError, match="path"):
            repo.add_trace_file(run.id, bad, _sha("x"), 1)
    with pytest.raises(StoreError, match="not a lower-case hex SHA-256"):
        repo.add_trace_file(run.id, "runs/x.r64", "ABC", 1)
    with pytest.raises(StoreError, match="run directory"):
        repo.create_run("measurement", ROBOT, {}, directory="../elsewhere")
    with pytest.raises(NotFound):
        repo.add_trace_file("no-such-run", "runs/x.r64", _sha("x"), 1)


def test_campaign_points_and_loops_keep_progress(repo: Repository) -> None:
    run = repo.create_run("calibration", ROBOT, {"points": 2}, run_id="cal-run")
    specs = [
        {"kind": "zero", "mass_kg": 0.0, "lever_a3_m": 1.29, "lever_a5_m": 0.265},
        {"kind": "mass", "mass_kg": 20.93, "lever_a3_m": 1.3075, "lever_a5_m": 0.2825},
    ]
    points = repo.add_points(run.id, specs)
    assert [(p.index, p.state, p.spec) for p in points] == [(0, PointState.PENDING, specs[0]), (1, "pending", specs[1])]
    assert repo.add_points(run.id, specs) == points  # idempotent
    with pytest.raises(StoreConflict, match="point 1: already stored with another specification"):
        repo.add_points(run.id, [specs[0], {**specs[1], "mass_kg": 21.0}])

    loop = repo.add_loop(run.id, 0, "cal00_l01", point_index=0)
    assert loop.state == LoopState.PENDING and loop.point_index == 0
    assert repo.add_loop(run.id, 0, "cal00_l01", point_index=0) == loop
    with pytest.raises(StoreConflict):
        repo.add_loop(run.id, 0, "cal00_l99", point_index=0)

    t0 = datetime(2024, 5, 1, 12, 0, 0, 250_000, tzinfo=UTC)
    t1 = datetime(2024, 5, 1, 12, 0, 12, tzinfo=UTC)
    rec = repo.update_loop(run.id, 0, state="recording", robot_start_utc=t0, record_start_utc=t0)
    rec = repo.update_loop(run.id, 0, state=LoopState.ARCHIVED, robot_end_utc=t1, record_end_utc=t1)
    assert (rec.state, rec.robot_start_utc, rec.robot_end_utc, rec.record_start_utc, rec.record_end_utc) == (
        LoopState.ARCHIVED, t0, t1, t0, t1,
    )
    assert repo.set_point_state(run.id, 0, "done").state == PointState.DONE
    assert [p.state for p in repo.points(run.id)] == [PointState.DONE, PointState.PENDING]
    with pytest.raises(NotFound):
        repo.update_loop(run.id, 7, state="failed")
    with pytest.raises(NotFound):
        repo.set_point_state(run.id, 9, "done")
    with pytest.raises(StoreError, match="naive datetime"):
        repo.update_loop(run.id, 0, robot_start_utc=datetime(2024, 1, 1))  # naive on purpose
    with pytest.raises(StoreError, match="loop state 'paused'"):
        repo.update_loop(run.id, 0, state="paused")


def test_trace_files_are_indexed_once_and_never_replaced(repo: Repository) -> None:
    run_id, hashes = _run_with_files(repo)
    files = repo.trace_files(run_id)
    assert [(f.loop_index, f.sha256, f.size_bytes) for f in files] == [(0, hashes[0], 1000), (1, hashes[1], 1001)]
    assert repo.add_trace_file(run_id, files[0].path, hashes[0], 1000, loop_index=0) == files[0]
    with pytest.raises(StoreConflict, match="raw files are never replaced"):
        repo.add_trace_file(run_id, files[0].path, _sha("other"), 1000, loop_index=0)


def test_a_result_must_reference_archived_raw_files_and_is_idempotent(repo: Repository) -> None:
    run_id, hashes = _run_with_files(repo)
    topic = f"rgse/{ROBOT}/run/{run_id}/result"

    with pytest.raises(StoreConflict, match="not archived trace files of this run"):
        repo.record_result(run_id, RESULT, [hashes[0], _sha("never archived")], publish=OutboxMessage(topic))
    with pytest.raises(StoreError, match="names no raw trace files"):
        repo.record_result(run_id, RESULT, [])
    assert repo.results(run_id) == [] and repo.pending_outbox() == []  # the refused calls left nothing

    res = repo.record_result(run_id, RESULT, list(reversed(hashes)), publish=OutboxMessage(topic))
    assert res.result == RESULT and res.calibration_id == "cal-1" and res.trace_sha256 == tuple(sorted(hashes))
    again = repo.record_result(run_id, RESULT, hashes, publish=OutboxMessage(topic))
    assert again == res  # same id, one row, no second MQTT message
    assert [r.id for r in repo.results(run_id)] == [res.id]
    (msg,) = repo.pending_outbox()
    assert (msg.topic, msg.retained, msg.qos, json.loads(msg.payload)) == (topic, True, 1, RESULT)

    # Re-processing with another calibration is another result of the same run, from the same raw files.
    other = repo.record_result(run_id, {**RESULT, "mass_kg": 107.7, "calibration_id": "cal-2"}, hashes)
    assert other.id != res.id and len(repo.results(run_id)) == 2
    with pytest.raises(StoreError, match="MQTT topic 'rgse/#'"):
        repo.record_result(run_id, {**RESULT, "mass_kg": 1.0}, hashes, publish=OutboxMessage("rgse/#"))


def test_a_result_has_its_status_in_its_own_column_also_for_rows_stored_before_it(repo: Repository) -> None:
    """ok / warning from the result's warnings, refused from its status; the column is queryable on SQLite and
    PostgreSQL, and a row of the former schema (status NULL) reads with the status its document gives."""
    run_id, hashes = _run_with_files(repo)
    ok = repo.record_result(run_id, {**RESULT, "warnings": []}, hashes)
    warned = repo.record_result(run_id, {**RESULT, "mass_kg": 107.5, "warnings": ["loops disagree"]}, hashes)
    refused = repo.record_result(run_id, {"status": "refused", "reason": "too few loops", "warnings": []}, hashes)
    assert (ok.status, warned.status, refused.status) == ("ok", "warning", "refused")
    rows = repo._db.execute("SELECT id, status FROM results WHERE run_id = ? ORDER BY status", (run_id,))
    assert [(r["id"], r["status"]) for r in rows] == [(ok.id, "ok"), (refused.id, "refused"), (warned.id, "warning")]
    with pytest.raises(StoreError):
        repo._db.execute("UPDATE results SET status = 'fine' WHERE id = ?", (ok.id,))
    repo._db.execute("UPDATE results SET status = NULL WHERE id = ?", (warned.id,))  # as stored before migration 2
    assert repo.get_result(warned.id).status == "warning"


def test_outbox_rows_are_marked_published_never_deleted(repo: Repository) -> None:
    a = repo.enqueue("rgse/R/alarm", {"kind": "interlock_trip"}, qos=1)
    b = repo.enqueue("rgse/R/status", '{"state":"online"}', retained=True, qos=1)
    assert [m.id for m in repo.pending_outbox()] == [a.id, b.id]
    other = repo.enqueue("rgse/OTHER/alarm", {"kind": "link_lost"})  # another robot's daemon on a fleet store
    assert [m.id for m in repo.pending_outbox(topic_prefix="rgse/R/")] == [a.id, b.id]
    assert [m.id for m in repo.pending_outbox(topic_prefix="rgse/OTHER/")] == [other.id]
    assert [m.id for m in repo.pending_outbox(limit=1)] == [a.id]
    assert json.loads(a.payload) == {"kind": "interlock_trip"} and b.payload == '{"state":"online"}'

    failed = repo.record_publish_failure(a.id, "broker unreachable")
    assert (failed.attempts, failed.last_error, failed.published_utc) == (1, "broker unreachable", None)
    done = repo.mark_published(a.id)
    assert done.published_utc is not None and done.attempts == 2
    assert repo.mark_published(a.id).published_utc == done.published_utc  # idempotent, first time kept
    assert [m.id for m in repo.pending_outbox(topic_prefix="rgse/R/")] == [b.id]
    assert repo.get_outbox(a.id).published_utc == done.published_utc  # still there

    with pytest.raises(StoreError, match="MQTT QoS 3"):
        repo.enqueue("rgse/R/x", {}, qos=3)
    with pytest.raises(StoreError, match="MQTT topic"):
        repo.enqueue("rgse/+/x", {})
    with pytest.raises(NotFound):
        repo.mark_published(10_000)


def test_events_and_alarms(repo: Repository) -> None:
    run = repo.create_run("measurement", ROBOT, {})
    e1 = repo.add_event("error", "interlock_trip", "A1 outside ±45°", run_id=run.id, data={"a1_deg": 47.5})
    e2 = repo.add_event(EventLevel.WARNING, "link_lost", "no answer for 3 s")
    assert (e1.level, e1.kind, e1.run_id, e1.data) == (EventLevel.ERROR, "interlock_trip", run.id, {"a1_deg": 47.5})
    assert [e.id for e in repo.events()] == [e1.id, e2.id]
    assert [e.id for e in repo.events(after_id=e1.id)] == [e2.id]
    assert [e.id for e in repo.events(run_id=run.id)] == [e1.id]
    with pytest.raises(StoreError, match="event level 'fatal'"):
        repo.add_event("fatal", "x", "y")
    with pytest.raises(StoreError):
        repo.add_event("info", "x", "for a run that does not exist", run_id="ghost")  # foreign key


def test_recover_interrupted_marks_only_running_runs_of_the_robot(repo: Repository) -> None:
    crashed = repo.create_run("calibration", ROBOT, {}, run_id="crashed")
    repo.set_run_state(crashed.id, "running")
    repo.add_points(crashed.id, [{"kind": "zero"}, {"kind": "mass"}])
    repo.set_point_state(crashed.id, 0, "done")
    repo.set_point_state(crashed.id, 1, "measuring")
    repo.add_loop(crashed.id, 0, "cal00_l01", point_index=0)
    repo.update_loop(crashed.id, 0, state="archived")
    repo.add_loop(crashed.id, 1, "cal01_l01", point_index=1)
    repo.update_loop(crashed.id, 1, state="recording")
    queued = repo.create_run("measurement", ROBOT, {}, run_id="queued")
    other = repo.create_run("measurement", "OTHER-ROBOT", {}, run_id="other")
    repo.set_run_state(other.id, "running")

    recovered = repo.recover_interrupted(robot=ROBOT)

    assert [(r.id, r.state) for r in recovered] == [("crashed", RunState.INTERRUPTED)]
    assert "raw files kept" in (recovered[0].detail or "") and recovered[0].ended_utc is not None
    assert [lp.state for lp in repo.loops(crashed.id)] == [LoopState.ARCHIVED, LoopState.INTERRUPTED]
    assert [p.state for p in repo.points(crashed.id)] == [PointState.DONE, PointState.PENDING]
    assert repo.get_run(queued.id).state == RunState.QUEUED
    assert repo.get_run(other.id).state == RunState.RUNNING  # a fleet store: another daemon's run is left alone
    assert [e.kind for e in repo.events(run_id=crashed.id)] == ["run_interrupted"]
    assert repo.recover_interrupted(robot=ROBOT) == []  # nothing left to recover

    resumed = repo.set_run_state(crashed.id, "running")  # the campaign continues after the restart
    assert resumed.ended_utc is None and resumed.started_utc == repo.get_run(crashed.id).started_utc
    assert [r.id for r in repo.recover_interrupted()] == ["crashed", "other"]  # no robot: every running run


def test_archive_and_store_together(repo: Repository, tmp_path: Path, data_dir: Path) -> None:
    run = repo.create_run("measurement", ROBOT, {})
    src = tmp_path / "share" / "dut_l01_NextGenDrive#5.r64"
    src.parent.mkdir()
    src.write_bytes(b"\x00\x01" * 500)
    root = archive_root(data_dir)
    archived = archive_file(src, root / run.directory, expected_size=1000)
    rec = repo.add_trace_file(run.id, relative_path(archived.path, root), archived.sha256, archived.size)
    assert rec.path == f"runs/{run.id}/dut_l01_NextGenDrive#5.r64"
    assert (root / rec.path).read_bytes() == src.read_bytes()


def test_calibration_activation_from_two_connections_at_once(store_url: str | None, data_dir: Path) -> None:
    # Two daemons (or a daemon and an operator's CLI) switching the active calibration of one robot concurrently.
    with Repository.open(store_url, data_dir) as repo:
        repo.add_calibration(calibration_doc("cal-a"))
        repo.add_calibration(calibration_doc("cal-b"))
    errors: list[BaseException] = []
    barrier = threading.Barrier(2)

    def flip(order: tuple[str, str]) -> None:
        try:
            with Repository.open(store_url, data_dir) as repo:
                barrier.wait(timeout=10)
                for i in range(40):
                    rec = repo.activate_calibration(order[i % 2])
                    if not rec.active:  # it must be active when the call returns, whatever the other one did
                        errors.append(AssertionError(f"{rec.id} not active after activate_calibration"))
        except BaseException as exc:  # collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=flip, args=(o,)) for o in (("cal-a", "cal-b"), ("cal-b", "cal-a"))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert errors == []
    with Repository.open(store_url, data_dir) as repo:
        assert sum(c.active for c in repo.calibrations(ROBOT)) == 1


def test_calibration_documents_are_checked_and_never_replaced(repo: Repository) -> None:
    first = repo.add_calibration(calibration_doc("cal-1"))
    assert first.active and first.method == "paper" and first.document == calibration_doc("cal-1")
    second = repo.add_calibration(calibration_doc("cal-2"))
    assert not second.active  # the robot already has an active calibration
    assert repo.add_calibration(calibration_doc("cal-2")) == second  # idempotent
    assert repo.activate_calibration("cal-2").active
    assert not repo.get_calibration("cal-1").active
    assert repo.add_calibration(calibration_doc("cal-3"), activate=True).active
    assert repo.active_calibration(ROBOT).id == "cal-3"  # type: ignore[union-attr]
    assert repo.active_calibration("NEW-ROBOT") is None
    with pytest.raises(StoreConflict, match="cal-1: already stored with a different document"):
        repo.add_calibration({**calibration_doc("cal-1"), "g": 9.80665})
    with pytest.raises(NotFound, match="'cal-x': no such calibration"):
        repo.activate_calibration("cal-x")
    with pytest.raises(StoreError, match="robot name None"):
        repo.add_calibration({k: v for k, v in calibration_doc("cal-4").items() if k != "robot"})
    with pytest.raises(StoreError, match=r"created_utc.*has no time zone"):
        repo.add_calibration({**calibration_doc("cal-5"), "created_utc": "2024-05-01T12:00:00"})
    with pytest.raises(StoreError, match="cal-6: not storable as JSON"):
        repo.add_calibration({**calibration_doc("cal-6"), "bias_nm": {"A3": math.inf}})


def test_a_properties_result_round_trips_exactly(repo: Repository) -> None:
    """A mass-properties run (issue #14) is stored as a measurement run with ``properties`` in its configuration;
    its result (CoG in two frames with U, the nested CoG result) comes back bit for bit, in the outbox too."""
    props = {"scheme": "full", "loops_per_pose": 2, "fixture_cog_flange_m": [0.0, 0.0, 0.055],
             "dut_origin_flange_m": [0.0, 0.0, 0.075], "dut_abc_deg": [90.0, 0.0, 0.0]}
    run = repo.create_run(RunKind.MEASUREMENT, ROBOT, {"loops": 2, "properties": props}, run_id="props-1")
    repo.set_run_state(run.id, RunState.RUNNING)
    repo.add_loop(run.id, 0, "cog_l01")
    h = _sha("pose file")
    repo.add_trace_file(run.id, f"{run.directory}/cog_l01_NextGenDrive#6.r64", h, 1000, loop_index=0)
    cog = {"cog_flange_m": [-0.04123456789012345, -0.028, 0.3450146454735719],
           "U_cog_flange_m": [0.0007123, 0.00091, 0.0161], "cog_dut_m": [-0.028, 0.04123456789012345, 0.27],
           "U_cog_dut_m": [0.00091, 0.0007123, 0.0161], "k": 2, "scheme": "full", "n_poses": 8,
           "warnings": ["A5: payload torques outside what the torsional calibration covered"],
           "budget": {"covariance_flange_m2": [[1e-7, 2e-9, 0.0], [2e-9, 2e-7, 0.0], [0.0, 0.0, 6e-5]],
                      "chi2_red": 0.93}}
    result = {**RESULT, "run_kind": "properties", "cog_m": cog["cog_flange_m"], "U_cog_m": cog["U_cog_flange_m"],
              "cog_dut_m": cog["cog_dut_m"], "U_cog_dut_m": cog["U_cog_dut_m"], "cog": cog,
              "mass_traces": ["dut_l01"], "cog_poses": [{"name": "meas", "q_deg": [0.0, -90.0, 90.0, 0.0, 0.0, 0.0],
                                                          "traces": ["cog_l01"]}]}
    topic = f"rgse/{ROBOT}/run/{run.id}/result"
    repo.record_result(run.id, result, [h], publish=OutboxMessage(topic))
    (stored,) = repo.results(run.id)
    assert stored.result == result and repo.get_run(run.id).config["properties"] == props
    (msg,) = repo.pending_outbox()
    assert json.loads(msg.payload) == result
