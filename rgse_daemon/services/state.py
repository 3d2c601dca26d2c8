"""What the daemon says about itself: the retained ``state`` message, and the systemd watchdog."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from collections.abc import Callable
from typing import Any

from rgse_daemon.errors import LinkError, RgseError
from rgse_daemon.krc import Snapshot
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.services.admission import RunAdmission
from rgse_daemon.services.link import ControllerLink
from rgse_daemon.store import Store
from rgse_daemon.systemd import Notifier
from rgse_daemon.utc import iso_utc

log = logging.getLogger("rgse_daemon.app")


def snapshot_json(snap: Snapshot) -> dict[str, Any]:
    """A controller snapshot as plain JSON for the ``state`` topic."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        if isinstance(v, bool | int | float | str) or v is None:
            return v
        return str(v)

    d = plain(snap)
    d.pop("raw", None)  # the decoded fields say it; the raw strings would double the message
    return d


class StatePublisher:
    """Publishes the retained ``state`` at ``[mqtt] state_rate_hz``: the controller snapshot, the interlock and
    engine state, link health, the safety inputs and the daemon's counters."""

    def __init__(self, link: ControllerLink, admission: RunAdmission, *, rate_hz: float,
                 engine: Callable[[], RunEngine | None], mqtt: Callable[[], Any], safety_io: Any) -> None:
        self.link = link
        self.admission = admission
        self.period_s = 1.0 / rate_hz
        self._engine = engine
        self._mqtt = mqtt
        self.safety_io = safety_io

    async def document(self) -> dict[str, Any]:
        engine, active = self._engine(), self.admission.active
        state: dict[str, Any] = {"engine": engine.state if engine else "disconnected",
                                 "run_id": engine.run_id if engine and active else None,
                                 "run_kind": self.admission.kind.value if active and self.admission.kind else None,
                                 "connected": self.link.connected.is_set(),
                                 "daemon": self.link.counters.as_dict()}
        krc = self.link.krc
        if krc is not None:
            try:
                async with asyncio.timeout(self.link.cfg.request_timeout_s * 2):
                    state["controller"] = snapshot_json(await krc.snapshot())
            except (TimeoutError, LinkError) as exc:
                state["controller"] = None
                state["controller_error"] = str(exc) or type(exc).__name__
            state["link"] = krc.health()
        elif self.link.error is not None:
            state["controller_error"] = self.link.error
        if self.safety_io is not None:
            inputs = self.safety_io.inputs
            state["safety_io"] = {**dataclasses.asdict(inputs), "time_utc": iso_utc(inputs.time_utc)}
        return state

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.period_s)
            mqtt = self._mqtt()
            if mqtt is None:
                continue
            try:
                mqtt.publish_state(await self.document())
            except RgseError as exc:  # a state this loop cannot publish must not end the loop
                log.error("state not published: %s", exc)
            except Exception as exc:  # nor a bug: the state stops for one period, not for the daemon's life
                log.error("state not published: %r", exc)


async def watchdog_loop(notifier: Notifier, store: Store, robot: str, interval_s: float) -> None:
    """Ping systemd's watchdog only while healthy: the loop runs (or this task would not) and the store answers."""
    while True:
        t0 = time.monotonic()
        healthy = True
        try:
            async with asyncio.timeout(interval_s):
                await store.active_calibration(robot)
        except (TimeoutError, RgseError) as exc:
            healthy = False
            log.error("watchdog: store not answering (%s); not pinging", exc)
        if healthy:
            notifier.watchdog()
        await asyncio.sleep(max(0.0, interval_s - (time.monotonic() - t0)))
