"""Fixtures of the daemon tests: a simulated KR C4 on a real socket, a private Mosquitto, the Modbus I/O simulator,
and a calibration fitted by the offline ``rgse calibrate --campaign`` path from a simulated campaign."""

from __future__ import annotations

import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

# The helpers of other test directories are imported as ``tests.<dir>.<module>``: that needs the checkout on the
# path also when pytest is started as ``.venv/bin/pytest`` (``python -m pytest`` puts it there itself).
_REPO = str(Path(__file__).resolve().parents[2])
if _REPO not in sys.path:
    sys.path.insert(0, _REPO)

from daemon_helpers import fit_sim_calibration  # noqa: E402

from rgse_daemon.krl.render import globals_dat_text  # noqa: E402
from simulators.krc4.sim import SimulatedKrc4  # noqa: E402
from simulators.modbus_io import ModbusIoSim  # noqa: E402
from tests.mqtt.mqtt_helpers import MosquittoProcess  # noqa: E402

SIM_SEED = 7
TIME_SCALE = 100.0


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    """The simulated KR C4 on this test's event loop (C3 Bridge on a loopback port), KRL globals installed."""
    async with SimulatedKrc4(tmp_path / "share", seed=SIM_SEED, time_scale=TIME_SCALE, latency_s=0.0) as s:
        s.install_globals(globals_dat_text())
        yield s


@pytest.fixture
async def private_broker(tmp_path: Path) -> AsyncIterator[MosquittoProcess]:
    """A Mosquitto of this test alone, with persistence: the only kind of broker a test may restart."""
    broker = MosquittoProcess(tmp_path / "mosquitto")
    await broker.start()
    try:
        yield broker
    finally:
        await broker.stop()


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
    """CAL.json of the simulated robot, fitted once per session."""
    return fit_sim_calibration(tmp_path_factory.mktemp("sim-calibration"))
