"""A refused result as the daemon's outside world sees it: the retained MQTT result and the client's error."""

from __future__ import annotations

import json

import pytest

from rgse_daemon.client import ResultRefused, RgseClient
from rgse_daemon.config import Config
from tests.support.daemon import PREFIX
from tests.support.mqtt import retained


async def refused_over_mqtt_and_client(cfg: Config, broker_port: int, run_id: str, kind: str, reason: str,
                                       match: str) -> ResultRefused:
    """Assert that run ``run_id``'s retained result says ``refused`` with ``reason`` and that the client raises
    :class:`ResultRefused` matching ``match`` for it; returns that error."""
    (msg,) = await retained("127.0.0.1", broker_port, f"{PREFIX}/run/{run_id}/result")
    published = json.loads(msg.payload)  # type: ignore[arg-type]
    assert published["status"] == "refused" and published["reason"] == reason, published
    async with RgseClient.of(cfg) as client:
        with pytest.raises(ResultRefused, match=match) as exc:
            await client.result(run_id, kind, timeout_s=10)
    assert exc.value.state == "refused"
    return exc.value
