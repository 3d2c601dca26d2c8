"""A real store (SQLite in a temporary directory) holding a calibration campaign run and a measurement run made from
generated trace files with the offline ``rgse calibrate`` / ``rgse mass`` path: built once per run, each module its
own copy, copied again by tests that modify it."""

from __future__ import annotations

import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.store import Repository
from tests.support.campaign import write_campaign, write_measurement
from tests.support.sessioncache import once_per_run
from tests.support.storefill import Filled, fill

DUT_KG = 107.3
FIXTURE_KG = 10.288


@dataclass(frozen=True)
class World:
    data_dir: Path
    filled: Filled

    def copy(self, dest: Path) -> World:
        shutil.copytree(self.data_dir, dest / "data")
        return World(dest / "data", self.filled)


def _build_world(base: Path) -> dict[str, Any]:
    """A campaign and a DuT run filled into a store under ``base``; where it lies and what was filled (JSON)."""
    write_campaign(base / "campaign", seed=3)
    write_measurement(base / "dut", DUT_KG, fixture_mass_kg=FIXTURE_KG, seed=11, n_loops=4)
    with Repository.open(None, base / "data") as repo:
        filled = fill(repo, base / "data", base / "campaign", base / "dut", base, method="auto")
    return {"data_dir": str(base / "data"), "filled": dataclasses.asdict(filled)}


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    """Each module its own copy of one world, built once per run (a campaign fit: ~17 s; three modules use it)."""
    built = once_per_run(tmp_path_factory, "report-world", _build_world)
    return World(Path(built["data_dir"]), Filled(**built["filled"])).copy(tmp_path_factory.mktemp("report-world"))


def write_config(path: Path, data_dir: Path, scale: dict[str, object] | None = None) -> Path:
    lines = ["[paths]", f"data_dir = {str(data_dir)!r}", ""]
    if scale:
        lines.append("[scale]")
        for k, v in scale.items():
            lines.append(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"')
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
