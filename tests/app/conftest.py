"""Fixtures of the daemon tests: a simulated KR C4 on a real socket, a private Mosquitto, the Modbus I/O simulator,
and a calibration fitted by the offline ``rgse calibrate --campaign`` path from a simulated campaign."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.krl.render import globals_dat_text
from simulators.krc4.sim import SimulatedKrc4
from simulators.modbus_io import ModbusIoSim
from tests.support.cogcal import fit_sim_cog_calibration
from tests.support.daemon import fit_sim_calibration
from tests.support.sessioncache import once_per_run

SIM_SEED = 7
TIME_SCALE = 100.0


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    """The simulated KR C4 on this test's event loop (C3 Bridge on a loopback port), KRL globals installed."""
    async with SimulatedKrc4(tmp_path / "share", seed=SIM_SEED, time_scale=TIME_SCALE, latency_s=0.0) as s:
        s.install_globals(globals_dat_text())
        yield s



@pytest.fixture
async def modbus_sim() -> AsyncIterator[ModbusIoSim]:
    sim = ModbusIoSim()
    sim.set_input("estop_ok", True)  # the lab at rest: E-stop chain closed, area not cleared, no AUT key
    await sim.start()
    try:
        yield sim
    finally:
        await sim.stop()


@pytest.fixture(scope="session")
def calibration_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """CAL.json of the simulated robot, fitted once per run (tests/faults' is the same document)."""
    return once_per_run(tmp_path_factory, "sim-calibration", fit_sim_calibration)


@pytest.fixture(scope="session")
def cog_calibration_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """CAL.json of the simulated robot with its torsional (CoG) section, paper scheme, fitted once per run."""
    return once_per_run(tmp_path_factory, "cog-calibration-paper", lambda d: fit_sim_cog_calibration(d, "paper"))
