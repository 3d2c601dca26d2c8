"""Fixtures for the field-device tests: a running Modbus I/O simulator."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from simulators.modbus_io import ModbusIoSim


@pytest.fixture
async def modbus_sim() -> AsyncIterator[ModbusIoSim]:
    sim = ModbusIoSim()
    await sim.start()
    try:
        yield sim
    finally:
        await sim.stop()
