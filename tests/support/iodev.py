"""Helpers shared by the field-device tests."""

from __future__ import annotations

from rgse_daemon.config import ModbusConfig


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
