"""``rgse reference``: a crane-scale weighing from the simulated Kern scale (TCP ``socket://`` and a pty), recorded
on the run next to its in-line result, compared as in paper Table 2, and shown by the report."""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rgse_daemon.analysis.reference import EVENT_KIND, FAILED_KIND, references
from rgse_daemon.commands import reference as reference_cmd
from rgse_daemon.config import ScaleConfig
from rgse_daemon.errors import ConfigError, DataError
from rgse_daemon.io import IoFrameError, IoTimeout
from rgse_daemon.io.scale import parse_line
from rgse_daemon.report import build_report
from rgse_daemon.store import Repository
from simulators.scale import ScaleSim, ScaleSimConfig
from tests.report.conftest import FIXTURE_KG, World, write_config
from tests.support.chromium import REPO, Dom
from tests.support.cli import one_line_error

D_KG = 0.1


def _args(cfg: Path, run_id: str, *, as_json: bool = True, timeout: float = 10.0) -> argparse.Namespace:
    return argparse.Namespace(run=run_id, config=cfg, json=as_json, weighed="gross", timeout=timeout, operators=3,
                              operation_min=43.0)


def _scale(sim: ScaleSim, **extra: object) -> dict[str, object]:
    return {"port": sim.url, "request_interval_s": 0.05, "resolution_kg": D_KG, **extra}


@pytest.mark.parametrize("transport", ["tcp", "pty"])
async def test_reference_weighing_is_recorded_compared_and_reported(world: World, tmp_path: Path, capsys,
                                                                    transport: str) -> None:
    w = world.copy(tmp_path)
    res = w.filled.result
    async with ScaleSim(ScaleSimConfig(true_mass_kg=117.6, resolution_kg=D_KG, settle_s=0.1, seed=4),
                        transport) as sim:  # type: ignore[arg-type]
        assert sim.url.startswith("socket://") == (transport == "tcp")
        cfg = write_config(tmp_path / "rgse.toml", w.data_dir, _scale(sim))
        assert await asyncio.to_thread(reference_cmd.run, _args(cfg, w.filled.run_id)) == 0
        out = json.loads(capsys.readouterr().out)
        assert await asyncio.to_thread(reference_cmd.run, _args(cfg, w.filled.run_id, as_json=False)) == 0
        text = capsys.readouterr().out

    ref, cmp = out["reference"], out["comparison"]
    assert abs(ref["mass_kg"] - 117.6) <= D_KG
    assert parse_line(ref["raw_line"], ScaleConfig(), "test").mass_kg == ref["mass_kg"]
    assert ref["u_kg"] == pytest.approx(D_KG / math.sqrt(3)) and ref["weighed"] == "gross"
    assert ref["net_mass_kg"] == ref["mass_kg"] - FIXTURE_KG and ref["fixture_mass_kg"] == FIXTURE_KG
    assert ref["operators"] == 3 and ref["operation_min"] == 43.0
    # Table 2 arithmetic on the stored numbers
    assert cmp["inline_net_kg"] == res["mass_kg"] and cmp["inline_U_kg"] == res["U_kg"]
    assert cmp["difference_kg"] == res["mass_kg"] - ref["net_mass_kg"]
    assert cmp["difference_pct"] == pytest.approx(100 * cmp["difference_kg"] / ref["net_mass_kg"])
    assert cmp["limit_kg"] == pytest.approx(math.hypot(res["U_kg"], 2 * ref["u_kg"]))
    assert cmp["agree"] == (abs(cmp["difference_kg"]) <= cmp["limit_kg"])
    rows = {r["parameter"]: r for r in out["table2"]}
    assert rows["net mass (kg)"]["inline_robot"] == f"{res['mass_kg']:.2f} ± {res['U_kg']:.2f}"
    assert rows["total number of operators"] == {"parameter": "total number of operators",
                                                 "reference_crane_scale": "3", "inline_robot": "1"}
    assert "net mass (kg)" in text and ("agree" in text or "DISAGREE" in text)

    with Repository.open(None, w.data_dir) as repo:
        stored = references(repo, w.filled.run_id)
        assert len(stored) == 2
        first = stored[0]
        assert first.event_id == out["event_id"] and first.result_id == out["result_id"]
        assert first.data() == {k: v for k, v in ref.items() if k != "recorded_utc"}
        page = build_report(repo, w.data_dir, tmp_path / "out", run_id=w.filled.run_id)
    dom = Dom(page.read_text(encoding="utf-8"))
    assert [float(v) for v in dom.fields["ref.mass_kg"]] == [r.mass_kg for r in stored]
    assert dom.fields["ref.raw"] == [r.raw_line for r in stored]
    assert float(dom.fields["ref.difference_kg"][0]) == res["mass_kg"] - stored[-1].net_mass_kg
    assert next(d.get("data-figure") for d in dom.images) == "mass_vs_ecss"


async def test_a_heavier_reference_disagrees(world: World, tmp_path: Path, capsys) -> None:
    w = world.copy(tmp_path)
    async with ScaleSim(ScaleSimConfig(true_mass_kg=130.0, resolution_kg=D_KG, settle_s=0.05), "tcp") as sim:
        cfg = write_config(tmp_path / "rgse.toml", w.data_dir, _scale(sim))
        assert await asyncio.to_thread(reference_cmd.run, _args(cfg, w.filled.run_id)) == 0
    cmp = json.loads(capsys.readouterr().out)["comparison"]
    assert cmp["agree"] is False and cmp["difference_kg"] < -10


@pytest.mark.parametrize(("true_kg", "weighed"), [(0.0, "gross"), (5.0, "gross"), (0.0, "net")])
async def test_a_weighing_of_no_dut_is_refused_and_recorded(world: World, tmp_path: Path, true_kg: float,
                                                            weighed: str) -> None:
    """A stable reading of an empty hook (or of less than the fixture that a gross weighing includes) is no reference
    of the DuT: refused with the reading named, and the reading kept on the run as a failed weighing."""
    w = world.copy(tmp_path)
    async with ScaleSim(ScaleSimConfig(true_mass_kg=true_kg, resolution_kg=D_KG, settle_s=0.05), "tcp") as sim:
        cfg = write_config(tmp_path / "rgse.toml", w.data_dir, _scale(sim))
        args = _args(cfg, w.filled.run_id)
        args.weighed = weighed
        with pytest.raises(DataError, match=rf"the crane scale read -?\d+\.\d{{3}} kg \({weighed}.* is no weighing "
                                            r"of the DuT"):
            await asyncio.to_thread(reference_cmd.run, args)
    with Repository.open(None, w.data_dir) as repo:
        events = [e for e in repo.events(run_id=w.filled.run_id) if e.kind in (EVENT_KIND, FAILED_KIND)]
    assert [e.kind for e in events] == [FAILED_KIND]
    data = events[0].data or {}
    assert data["error_type"] == "DataError" and abs(data["mass_kg"] - true_kg) <= D_KG and data["raw_line"]


async def test_scale_timeout_is_reported_and_recorded(world: World, tmp_path: Path) -> None:
    w = world.copy(tmp_path)
    async with ScaleSim(ScaleSimConfig(never_stable=True, resolution_kg=D_KG), "tcp") as sim:
        cfg = write_config(tmp_path / "rgse.toml", w.data_dir, _scale(sim))
        with pytest.raises(IoTimeout, match=r"no stable weighing within 0\.5 s"):
            await asyncio.to_thread(reference_cmd.run, _args(cfg, w.filled.run_id, timeout=0.5))
    with Repository.open(None, w.data_dir) as repo:
        events = [e for e in repo.events(run_id=w.filled.run_id) if e.kind in (EVENT_KIND, FAILED_KIND)]
    assert [e.kind for e in events] == [FAILED_KIND]
    assert events[0].data is not None and events[0].data["error_type"] == "IoTimeout"


async def test_bad_frames_are_reported_and_recorded(world: World, tmp_path: Path) -> None:
    w = world.copy(tmp_path)
    async with ScaleSim(ScaleSimConfig(garble_rate=1.0, resolution_kg=D_KG, settle_s=0.0, stream_period_s=0.01),
                        "pty") as sim:
        cfg = write_config(tmp_path / "rgse.toml", w.data_dir, _scale(sim, max_consecutive_bad_frames=3))
        with pytest.raises(IoFrameError, match="3 bad frames in a row"):
            await asyncio.to_thread(reference_cmd.run, _args(cfg, w.filled.run_id))
    with Repository.open(None, w.data_dir) as repo:
        (event,) = [e for e in repo.events(run_id=w.filled.run_id) if e.kind == FAILED_KIND]
    assert event.data is not None
    assert event.data["error_type"] == "IoFrameError" and event.data["bad_frames"] >= 3
    assert event.data["last_bad_line"]


def test_reference_needs_a_scale_and_an_in_line_result(world: World, tmp_path: Path) -> None:
    no_scale = write_config(tmp_path / "a.toml", world.data_dir)
    with pytest.raises(ConfigError, match="no \\[scale\\] section"):
        reference_cmd.run(_args(no_scale, world.filled.run_id))
    # the scale is never opened when the run cannot be compared (nothing listens on this port)
    scale = write_config(tmp_path / "b.toml", world.data_dir, {"port": "socket://127.0.0.1:9", "resolution_kg": D_KG})
    with pytest.raises(DataError, match="no in-line result"):
        reference_cmd.run(_args(scale, world.filled.calibration_run_id))
    with pytest.raises(DataError, match="no-such-run"):
        reference_cmd.run(_args(scale, "no-such-run"))


@pytest.mark.parametrize("data_dir_exists", [False, True], ids=["fresh", "empty-data-dir"])
def test_reference_of_a_run_in_a_store_that_does_not_exist_creates_no_store(tmp_path: Path, capsys,
                                                                            data_dir_exists: bool) -> None:
    """A wrong --config (or a data_dir without a store yet): the command says which store it searched, exit 2, and
    leaves no empty rgse.sqlite3 (nor its data_dir) behind — as ``rgse report`` does."""
    data_dir = tmp_path / "data"
    if data_dir_exists:
        data_dir.mkdir()
    cfg = write_config(tmp_path / "rgse.toml", data_dir, {"port": "socket://127.0.0.1:9", "resolution_kg": D_KG})
    err = one_line_error(capsys, ["reference", "--run", "no-such-run", "--config", str(cfg)])
    assert sorted(p.name for p in tmp_path.iterdir()) == (["data", "rgse.toml"] if data_dir_exists else ["rgse.toml"])
    assert not data_dir_exists or list(data_dir.iterdir()) == []
    assert "no-such-run" in err and f"sqlite store {data_dir / 'rgse.sqlite3'} does not exist" in err, err


def test_reference_without_config_in_a_fresh_directory_creates_nothing(tmp_path: Path) -> None:
    """As an operator types it in the wrong directory: one line, exit 2, the directory left as it was."""
    env = {k: v for k, v in os.environ.items() if not k.upper().startswith("RGSE_")}
    env["PYTHONPATH"] = str(REPO)
    proc = subprocess.run([sys.executable, "-m", "rgse_daemon", "reference", "--run", "no-such-run"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "no [scale] section" in proc.stderr, proc.stderr
    scale_env = {**env, "RGSE_SCALE__PORT": "socket://127.0.0.1:9"}  # a scale from the environment, no --config
    proc = subprocess.run([sys.executable, "-m", "rgse_daemon", "reference", "--run", "no-such-run"], cwd=tmp_path,
                          env=scale_env, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert list(tmp_path.iterdir()) == []
    for fragment in ("no-such-run", "sqlite store data/rgse.sqlite3 does not exist", "--config FILE"):
        assert fragment in proc.stderr, (fragment, proc.stderr)
