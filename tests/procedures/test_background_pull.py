"""The pull off the robot's path (engine PullStart/PullJoin) on the simulated KR C4: a failed background pull stops
the run at once with nothing deleted; a motion waits for every pull in flight (the file-window rule)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from rgse_daemon.manifest import MODULE_A5
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, axes_of, program, run_checked, trace_config_xml
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.store.archive import ArchiveConflict
from simulators.krc4.sim import SimulatedKrc4


def _on_controller(sim: SimulatedKrc4, trace: str) -> list[str]:
    return sorted(p.name for p in (sim.share_dir / "TRACE").iterdir() if p.name.startswith(f"{trace}_"))


def _record(s: RunSettings, trace: str) -> m.Plan:
    yield m.PutFile(TRACE_DIR + TRACE_CONFIG_NAME, trace_config_xml(s).encode())
    yield m.TraceStart(trace, TRACE_CONFIG_NAME)
    yield m.TraceWait(30)


async def test_a_failed_background_pull_stops_the_run_at_once_and_deletes_nothing(
        sim: SimulatedKrc4, engine: RunEngine, settings: RunSettings, tmp_path: Path):
    dest = tmp_path / "run"
    dest.mkdir()
    (dest / f"bad_{MODULE_A5}.r64").write_bytes(b"an earlier, different file")  # archiving must not overwrite it
    reached: list[str] = []

    def plan() -> m.Plan:
        yield from _record(settings, "bad")
        yield m.PullStart("bad", dest)
        reached.append("started")
        yield m.Sleep(60.0)  # the next loop's settling and recording: the failure must not wait for its end
        reached.append("slept")
        yield m.PullJoin("bad")

    t0 = time.monotonic()
    with pytest.raises(ArchiveConflict):
        await engine.run(plan())
    assert time.monotonic() - t0 < 30.0 and reached == ["started"]
    assert len(_on_controller(sim, "bad")) >= 4  # every file still on the controller
    assert engine.pulls_in_flight == ()


async def test_motion_waits_for_the_pull_in_flight(sim: SimulatedKrc4, engine: RunEngine, settings: RunSettings,
                                                   krc, tmp_path: Path):
    dest = tmp_path / "run"
    archived_at_push: list[list[str]] = []
    put = krc.put_file

    async def watched_put(name: str, data: bytes, *a, **kw):
        if name.upper().endswith(".SRC"):
            archived_at_push.append(sorted(p.name for p in dest.iterdir() if p.is_file()) if dest.exists() else [])
        return await put(name, data, *a, **kw)

    krc.put_file = watched_put  # type: ignore[method-assign]

    def plan() -> m.Plan:
        yield from _record(settings, "first")
        yield m.PullStart("first", dest)
        snap = yield m.ReadState()
        yield from run_checked(program("rgse_brake_release", settings, axes_of(snap, settings.meas_pose_deg)),
                               settings)
        return (yield m.PullJoin("first"))

    pulled, waited_s, total_s = await engine.run(plan())
    names = sorted(f.path.name for f in pulled.files)
    assert archived_at_push == [names]  # the program went to the controller only once the pull had ended
    assert 0.0 <= waited_s <= total_s and sim.moves >= 1
    assert _on_controller(sim, "first") == sorted(pulled.names)  # nothing deleted: the plan indexes first


def test_a_move_rendered_ahead_is_used_only_where_the_robot_still_stands():
    from types import SimpleNamespace

    from rgse_daemon.procedures.loop import RENDER_AHEAD_TOLERANCE_DEG, LoopOutcome, LoopTiming, _ahead

    axes = (0.0, -90.0, 90.0, 0.0, 45.0, 0.0)
    prev = LoopOutcome("t", LoopTiming(), next_program="the move", next_axes_deg=axes)
    near = tuple(a + 0.5 * RENDER_AHEAD_TOLERANCE_DEG for a in axes)
    moved = (*axes[:4], axes[4] + 2 * RENDER_AHEAD_TOLERANCE_DEG, axes[5])
    assert _ahead(prev, SimpleNamespace(axes_deg=near)) == "the move"
    assert _ahead(prev, SimpleNamespace(axes_deg=moved)) is None  # rendered again from the live axes
    assert _ahead(prev, SimpleNamespace(axes_deg=None)) is None
    assert _ahead(None, SimpleNamespace(axes_deg=axes)) is None
    assert _ahead(LoopOutcome("t", LoopTiming()), SimpleNamespace(axes_deg=axes)) is None


async def test_a_plan_that_leaves_a_pull_unjoined_fails(sim: SimulatedKrc4, engine: RunEngine, settings: RunSettings,
                                                        tmp_path: Path):
    """Its files would never be indexed (nor the controller copies deleted): a plan bug, never a completed run."""
    from rgse_daemon.errors import RgseError

    def plan() -> m.Plan:
        yield from _record(settings, "orphan")
        yield m.PullStart("orphan", tmp_path / "run")

    with pytest.raises(RgseError, match="pulls not joined: orphan"):
        await engine.run(plan())
    assert engine.pulls_in_flight == () and len(_on_controller(sim, "orphan")) >= 4
