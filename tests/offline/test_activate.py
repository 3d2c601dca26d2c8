"""``rgse activate``: an offline CAL.json made the active calibration of the configured robot, with its provenance;
a file of another robot and a file that is no calibration are refused (exit 2) and change nothing (issue #34)."""

from __future__ import annotations

import asyncio
import hashlib
import json
import subprocess
import sys
from pathlib import Path

from rgse_daemon.config import load_config
from rgse_daemon.store import Store

TABLE1 = Path(__file__).resolve().parents[2] / "data" / "paper" / "table1_calibration.csv"


def rgse(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rgse_daemon", *args], capture_output=True, text=True, timeout=120)


async def _stored(config: Path) -> tuple[str | None, list[dict[str, object]]]:
    cfg = load_config(config)
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        active = await store.active_calibration(cfg.robot.name)
        events = [e.data or {} for e in await store.events() if e.kind == "calibration_activated"]
    return (active.id if active is not None else None), events


def test_activate_makes_a_calibration_file_active_with_its_provenance(tmp_path: Path) -> None:
    cal = tmp_path / "CAL.json"
    assert rgse("calibrate", "--points", str(TABLE1), "--out", str(cal)).returncode == 0
    cal_id = json.loads(cal.read_text())["calibration_id"]
    config = tmp_path / "rgse.toml"
    config.write_text(f'[robot]\nname = "KR500R2830"\n[paths]\ndata_dir = "{tmp_path / "data"}"\n')

    done = rgse("activate", str(cal), "--config", str(config), "--note", "Table 1 refit", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["calibration_id"] == cal_id and out["replaced"] is None
    active, events = asyncio.run(_stored(config))
    assert active == cal_id
    assert events == [{"calibration_id": cal_id, "file": str(cal.resolve()), "sha256":
                       hashlib.sha256(cal.read_bytes()).hexdigest(), "replaced": None, "by": out["by"],
                       "note": "Table 1 refit"}]

    # another robot's daemon refuses it, naming both robots, and its store keeps no calibration
    other = tmp_path / "other.toml"
    other.write_text(f'[robot]\nname = "KR10R1440"\n[paths]\ndata_dir = "{tmp_path / "other"}"\n')
    refused = rgse("activate", str(cal), "--config", str(other))
    assert refused.returncode == 2
    assert "belongs to robot 'KR500R2830'" in refused.stderr and "'KR10R1440'" in refused.stderr
    assert not (tmp_path / "other").exists()

    # a file that is no calibration: refused, the active one stays
    bad = tmp_path / "notes.json"
    bad.write_text('{"calibration_id": "x"}')
    refused = rgse("activate", str(bad), "--config", str(config))
    assert refused.returncode == 2 and str(bad) in refused.stderr
    assert asyncio.run(_stored(config))[0] == cal_id
