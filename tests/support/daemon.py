"""Helpers of the daemon tests.

* :func:`daemon_config`: a configuration for short runs against the simulators and a private broker.
* :func:`running_daemon`: ``Daemon(cfg).run(stop)`` as a task, connected, stopped (bounded) on exit.
* :class:`Events`: the daemon's ``on_event`` hook that keeps every event and lets a test await one.
* :func:`command`: an MQTT command and its reply, as an operator's tool sends it.
* :class:`StayingSubscriber`: a subscriber with a persistent session that reconnects across a broker restart.
* :func:`fit_sim_calibration`: CAL.json of the simulated robot by the offline ``rgse calibrate --campaign`` path.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
import uuid
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import aiomqtt

from rgse_daemon import robots
from rgse_daemon.analysis.calibration import fit_campaign
from rgse_daemon.app import STOP_TIMEOUT_S, Daemon
from rgse_daemon.config import Config, MeasurementConfig, config_from_mapping
from rgse_daemon.procedures.events import Event
from rgse_daemon.store import Store
from rgse_daemon.systemd import Notifier
from tests.support.mqtt import Collector
from tests.support.simcampaign import ROBOT, simulate_campaign, simulate_measurement, write_dirs

__all__ = ["ROBOT"]

PREFIX = f"rgse/{ROBOT}"
FIXTURE_KG = robots.get(robots.DEFAULT_KEY).calibration.fixture_mass_kg
COMMAND_TOKEN = "daemon-test-token"  # commands that move the robot need one (secure by default)
#: Deadline of waits on the daemon (a hang guard, not a timing check).
WAIT_S = 60.0


def daemon_config(
    data_dir: Path,
    *,
    controller_port: int,
    share_dir: Path | None = None,
    broker_port: int | None = None,
    modbus_port: int | None = None,
    **measurement: Any,
) -> Config:
    """Short runs (2 loops of 250 samples, one warm-up cycle) with quick reconnects everywhere; the interlock's
    snapshot staleness and the controller-side watchdog's bound at 1 s, so a loaded test machine does not trip
    them (tests/faults/test_controller_watchdog.py sets the watchdog's default bound back)."""
    ms = {"loops": 2, "settle_s": 0.01, "trace_period_s": 0.012, "trace_samples": 250, "warmup_cycles": 1,
          "fixture_mass_kg": FIXTURE_KG, "payload_lever_max_m": 1.0, "program_timeout_s": 60.0,
          "trace_timeout_s": 30.0}
    if "warmup_until_steady" in MeasurementConfig.model_fields:
        ms["warmup_until_steady"] = False  # one warm-up run, not "until the motors are thermally steady"
    ms.update(measurement)
    data: dict[str, Any] = {
        "robot": {"name": ROBOT},
        "controller": {"host": "127.0.0.1", "port": controller_port, "protocol": "c3bridge",
                       "connect_timeout_s": 2.0, "request_timeout_s": 2.0, "reconnect_min_s": 0.05,
                       "reconnect_max_s": 0.4, **({"share_dir": str(share_dir)} if share_dir else {}),
                       "watchdog_bound_s": 1.0},
        "paths": {"data_dir": str(data_dir)},
        "limits": {"snapshot_stale_s": 1.0},
        "measurement": ms,
        "mqtt": {"enabled": broker_port is not None, "host": "127.0.0.1", "port": broker_port or 1883,
                 "reconnect_min_s": 0.05, "reconnect_max_s": 0.4, "state_rate_hz": 20.0,
                 "command_tokens": [COMMAND_TOKEN]},
    }
    if modbus_port is not None:
        data["modbus"] = {"host": "127.0.0.1", "port": modbus_port, "poll_period_s": 0.05, "stale_after_polls": 40,
                          "request_timeout_s": 1.0, "connect_timeout_s": 1.0, "reconnect_min_s": 0.05,
                          "reconnect_max_s": 0.2}
    return config_from_mapping(data, "<test>")


def fit_sim_calibration(directory: Path, seed: int = 5) -> dict[str, Any]:
    """A Table-1-like campaign on the simulated KR 500 (same physics as the simulated KR C4), written as a campaign
    directory and fitted as ``rgse calibrate --campaign DIR`` does
    (:func:`rgse_daemon.analysis.calibration.fit_campaign`)."""
    campaign, model = simulate_campaign(seed, n_loops=2)
    write_dirs(campaign, simulate_measurement(model, 50.0, n_loops=1), directory / "campaign", directory / "dut")
    doc, _ = fit_campaign(directory / "campaign", "auto")
    return doc.to_dict()


async def seed_calibration(cfg: Config, doc: dict[str, Any]) -> str:
    """Store and activate ``doc`` in the daemon's store, as the campaign does (``add_calibration(activate=True)``)."""
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        cal = await store.add_calibration(doc, activate=True)
    return cal.id


async def first_of(aw: Awaitable[Any], watched: asyncio.Task[Any], what: str, timeout_s: float = WAIT_S) -> Any:
    """Await ``aw`` unless ``watched`` (the daemon) ends first (then raise why) or the deadline passes."""
    waiter = asyncio.ensure_future(aw)
    try:
        done, _ = await asyncio.wait({waiter, watched}, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
        if waiter in done:
            return waiter.result()
        if watched in done:
            raise AssertionError(f"{what}: the daemon ended first: {watched.exception()!r}")
        raise AssertionError(f"{what}: not within {timeout_s:g} s")
    finally:
        if not waiter.done():
            waiter.cancel()
            await asyncio.gather(waiter, return_exceptions=True)


@dataclass
class RunningDaemon:
    daemon: Daemon
    stop: asyncio.Event
    task: asyncio.Task[None]

    async def shutdown(self) -> float:
        """Set ``stop`` and wait for ``run()`` to return; returns how long that took (s)."""
        t0 = time.monotonic()
        self.stop.set()
        async with asyncio.timeout(6 * STOP_TIMEOUT_S):
            await self.task
        return time.monotonic() - t0


@contextlib.asynccontextmanager
async def running_daemon(cfg: Config, *, notifier: Notifier | None = None,
                         on_event: Callable[[Event], None] | None = None,
                         connected: bool = True) -> AsyncIterator[RunningDaemon]:
    """The daemon as ``rgse daemon`` runs it, in-process; waits until the controller is connected (unless
    ``connected=False``); on exit stops it (bounded) and re-raises whatever ``run()`` raised."""
    daemon = Daemon(cfg, notifier=notifier or Notifier({}), on_event=on_event)
    stop = asyncio.Event()
    running = RunningDaemon(daemon, stop, asyncio.create_task(daemon.run(stop), name="test-daemon"))
    try:
        if connected:
            await first_of(daemon.connected.wait(), running.task, "controller connected")
        yield running
    finally:
        if not running.task.done():
            await running.shutdown()
        else:
            running.task.result()


async def run_end(running: RunningDaemon, timeout_s: float = WAIT_S) -> Any:
    """The outcome of the daemon's current run (its value, or it raises why it failed), within a deadline."""
    task = running.daemon.run_task
    assert task is not None
    return await first_of(asyncio.shield(task), running.task, "the run ends", timeout_s)


class Events:
    """The daemon's ``on_event``: keeps every engine event; ``hooks`` see each one as it happens (they must not
    block, like every subscriber)."""

    def __init__(self) -> None:
        self.events: list[Event] = []
        self.hooks: list[Callable[[Event], None]] = []
        self._changed = asyncio.Event()

    def __call__(self, ev: Event) -> None:
        self.events.append(ev)
        for hook in list(self.hooks):
            hook(ev)
        self._changed.set()

    def of(self, kind: str) -> list[Event]:
        return [e for e in self.events if e.kind == kind]

    def states(self) -> list[str]:
        return [e.data["state"] for e in self.of("state")]

    async def wait_for(self, predicate: Callable[[Event], bool], what: str, timeout_s: float = WAIT_S) -> Event:
        """The first event (seen so far or coming) for which ``predicate`` holds."""
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    for ev in self.events:
                        if predicate(ev):
                            return ev
                    self._changed.clear()
                    await self._changed.wait()
        except TimeoutError:
            raise AssertionError(f"{what}: not within {timeout_s:g} s") from None


async def command(peer: Collector, verb: str, body: dict[str, Any], timeout_s: float = WAIT_S) -> dict[str, Any]:
    """Publish ``cmd/<verb>`` with a fresh request id and return the daemon's reply to it. ``peer`` must be
    subscribed to ``<prefix>/cmd/+/reply``."""
    rid = uuid.uuid4().hex[:16]
    reply_topic = f"{PREFIX}/cmd/{verb}/reply"

    def replies() -> list[dict[str, Any]]:
        return [r for r in peer.json_on(reply_topic) if r.get("request_id") == rid]

    await peer.publish(f"{PREFIX}/cmd/{verb}", json.dumps({"request_id": rid, "token": COMMAND_TOKEN, **body}))
    await peer.wait_for(lambda _: bool(replies()), f"a reply to cmd/{verb} {rid}", timeout_s)
    (reply,) = replies()
    return reply


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retain: bool


@dataclass
class StayingSubscriber:
    """A subscriber that stays subscribed across broker restarts: persistent session (``clean_session=False``, QoS
    1, so the broker keeps its subscriptions and queues messages while it is away) and a reconnect loop that
    subscribes again after every connect (the broker then re-sends the retained messages, flagged retained).

    :meth:`sync` makes "everything published before now has arrived" observable: a sentinel round trip."""

    host: str
    port: int
    topics: tuple[str, ...]
    messages: list[Received] = field(default_factory=list)
    connects: int = 0
    _identifier: str = field(default_factory=lambda: f"staying-{uuid.uuid4().hex[:8]}")
    _sentinel: str = field(default_factory=lambda: f"rgse-test-sentinel/{uuid.uuid4().hex}")
    _seen: set[str] = field(default_factory=set)
    _client: aiomqtt.Client | None = None
    _changed: asyncio.Event = field(default_factory=asyncio.Event)
    _task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Self:
        self._task = asyncio.create_task(self._run(), name="staying-subscriber")
        await self.wait_until(lambda: self._client is not None, "the staying subscriber connected")
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        assert self._task is not None
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)

    async def _run(self) -> None:
        while True:
            try:
                async with aiomqtt.Client(self.host, self.port, identifier=self._identifier, clean_session=False,
                                          timeout=5) as client:
                    for t in (*self.topics, self._sentinel):
                        await client.subscribe(t, qos=1)
                    self.connects += 1
                    self._client = client
                    self._changed.set()
                    async for m in client.messages:
                        payload = m.payload if isinstance(m.payload, bytes) else str(m.payload).encode()
                        if m.topic.value == self._sentinel:
                            self._seen.add(payload.decode())
                        else:
                            self.messages.append(Received(m.topic.value, payload, bool(m.retain)))
                        self._changed.set()
            except aiomqtt.MqttError:
                pass
            finally:
                self._client = None
            await asyncio.sleep(0.05)  # reconnect backoff while the broker is away

    async def wait_until(self, predicate: Callable[[], bool], what: str, timeout_s: float = WAIT_S) -> None:
        """Until ``predicate`` holds (checked whenever a message arrived or the connection changed)."""
        try:
            async with asyncio.timeout(timeout_s):
                while not predicate():
                    self._changed.clear()
                    await self._changed.wait()
        except TimeoutError:
            raise AssertionError(f"{what}: not within {timeout_s:g} s") from None

    async def sync(self, timeout_s: float = WAIT_S) -> None:
        """Return once a message published now (on a connected session) has come back."""
        token = uuid.uuid4().hex
        async with asyncio.timeout(timeout_s):
            while True:
                await self.wait_until(lambda: self._client is not None, "the staying subscriber connected", timeout_s)
                client = self._client
                assert client is not None
                try:
                    await client.publish(self._sentinel, token, qos=1)
                    break
                except aiomqtt.MqttError:
                    continue  # the connection went away under us: publish again on the next one
        await self.wait_until(lambda: token in self._seen, "the sentinel came back", timeout_s)

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]
