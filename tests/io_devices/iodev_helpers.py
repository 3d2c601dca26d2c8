"""Helpers shared by the field-device tests (imported by name: this directory is on sys.path under pytest)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

from rgse_daemon.config import ModbusConfig


async def wait_until(condition: Callable[[], bool], timeout_s: float = 10.0, what: str = "condition") -> None:
    """Poll ``condition`` until true; fail the test (not hang it) if it never becomes true."""
    try:
        async with asyncio.timeout(timeout_s):
            while True:
                if condition():
                    return
                await asyncio.sleep(0.01)
    except TimeoutError:
        pytest.fail(f"{what} not reached within {timeout_s} s")


def fast_cfg(port: int, **overrides: object) -> ModbusConfig:
    """A client configuration with short periods so that the tests run fast."""
    values: dict[str, object] = {
        "port": port,
        "poll_period_s": 0.02,
        "stale_after_polls": 50,
        "request_timeout_s": 0.5,
        "connect_timeout_s": 1.0,
        "reconnect_min_s": 0.02,
        "reconnect_max_s": 0.1,
    }
    values.update(overrides)
    return ModbusConfig.model_validate(values)
