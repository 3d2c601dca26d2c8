"""The daemon (``rgse daemon --config``): one asyncio service that owns the components and their lifecycle.

Components, started in this order and stopped in the reverse one, each stop with a bounded wait (architecture
lesson 6)::

    store       SQLite/PostgreSQL; interrupted runs of a dead daemon are marked at start
    safety I/O  the Modbus module (optional); its inputs feed the interlock
    MQTT        status (last will ``offline``), state, progress, alarms, results from the outbox, commands
    controller  the KR C4 link; (re)connected in the background with jittered backoff
    engine      one :class:`~rgse_daemon.procedures.engine.RunEngine` with the interlock monitor — one run at a
                time, because the robot is one resource: a second request is refused with the reason

systemd (``Type=notify``): ``READY=1`` once the store is open and the components started, ``WATCHDOG=1`` from the
event loop only while the loop is responsive and the store answers, ``STOPPING=1`` on SIGTERM. A calibration
campaign that a previous daemon left interrupted is continued at its first incomplete point (its next step asks the
operator to confirm the mounted load).

Commands (MQTT ``cmd/<verb>`` or in-process) are the :class:`~rgse_daemon.io.mqtt.CommandHandler` methods:
``measure``, ``calibrate``, ``abort``, ``confirm``; each answers at once (run id) and the run goes on in a task.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import random
import time
from collections.abc import Awaitable, Callable
from typing import Any

from rgse_daemon import __version__
from rgse_daemon.config import Config
from rgse_daemon.controller import Controller, Snapshot
from rgse_daemon.errors import LinkError, RgseError
from rgse_daemon.io.commands import AbortCommand, CalibrateCommand, ConfirmCommand, MeasureCommand
from rgse_daemon.procedures.calibration import CB_MASS_KG, CampaignPoint, run_calibration
from rgse_daemon.procedures.common import RunSettings, static_checker
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.measurement import run_measurement
from rgse_daemon.safety.monitor import DEFAULT_POLL_PERIOD_S, Monitor
from rgse_daemon.store import RunKind, RunState, Store
from rgse_daemon.systemd import Notifier

log = logging.getLogger(__name__)

#: Bounded waits of the ordered shutdown, per component (s).
STOP_TIMEOUT_S = 15.0


class Busy(RgseError):
    """A run is already in progress: the robot is one resource."""


class NotConnected(RgseError):
    """The controller link is not up (yet): no run can start."""


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


class Daemon:
    """The service. ``await Daemon(cfg).run(stop)`` runs until ``stop`` is set (SIGTERM), then shuts down in order.

    ``on_event`` (optional) sees every engine event too: the demo prints from it, tests and the operator's
    confirmation hook answer prompts from it.
    """

    def __init__(
        self,
        cfg: Config,
        *,
        notifier: Notifier | None = None,
        on_event: Callable[[Event], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.robot = cfg.robot.name
        self.notifier = notifier or Notifier()
        self._on_event = on_event
        self.store: Store | None = None
        self.krc: Controller | None = None
        self.engine: RunEngine | None = None
        self.safety_io: Any = None  # rgse_daemon.io.modbus.SafetyIo when configured
        self.mqtt: Any = None  # rgse_daemon.io.mqtt.MqttBridge when enabled
        self.connected = asyncio.Event()
        self.run_task: asyncio.Task[Any] | None = None
        self.run_kind: str | None = None
        self.last_result: dict[str, Any] | None = None
        self.last_error: str | None = None
        self._tasks: list[asyncio.Task[Any]] = []
        self._stopping = False
        self._alarms_active: set[str] = set()
        self._resumed = False

    # --- lifecycle -----------------------------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Start every component, serve until ``stop`` is set, then stop them in reverse order."""
        async with contextlib.AsyncExitStack() as stack:
            self.store = await Store.open(self.cfg.store.url, self.cfg.paths.data_dir)
            stack.push_async_callback(self._bounded, "store", self.store.close)
            recovered = await self.store.recover_interrupted(self.robot)
            if recovered:
                log.warning("runs left running by a previous daemon marked interrupted: %s", recovered)

            if self.cfg.modbus is not None:
                from rgse_daemon.io.modbus import SafetyIo

                self.safety_io = SafetyIo(self.cfg.modbus)
                await self.safety_io.start()
                stack.push_async_callback(self._bounded, "safety I/O", self.safety_io.stop)

            if self.cfg.mqtt.enabled:
                from rgse_daemon.io.mqtt import MqttBridge

                self.mqtt = MqttBridge(self.cfg.mqtt, self.robot, self.store, self, __version__)
                await self.mqtt.start()
                stack.push_async_callback(self._bounded, "mqtt", self.mqtt.stop)

            stack.push_async_callback(self._stop_run)
            self._spawn(self._controller_loop(stop), "controller")
            self._spawn(self._state_loop(), "state")
            if self.notifier.watchdog_interval_s is not None:
                self._spawn(self._watchdog_loop(self.notifier.watchdog_interval_s), "watchdog")
            stack.push_async_callback(self._cancel_tasks)

            self.notifier.ready(f"serving robot {self.robot}")
            log.info("rgse daemon %s serving robot %s", __version__, self.robot)
            await stop.wait()
            self._stopping = True
            self.notifier.stopping()
            log.info("stopping")

    async def _bounded(self, what: str, close: Callable[[], Awaitable[Any]]) -> None:
        """Close one component within :data:`STOP_TIMEOUT_S`; a failure is logged, the shutdown goes on."""
        try:
            async with asyncio.timeout(STOP_TIMEOUT_S):
                await close()
        except TimeoutError:
            log.error("stopping %s took longer than %.0f s; abandoned", what, STOP_TIMEOUT_S)
        except Exception:
            log.exception("stopping %s failed", what)

    def _spawn(self, coro: Awaitable[Any], name: str) -> None:
        self._tasks.append(asyncio.create_task(coro, name=f"rgse-{name}"))  # type: ignore[arg-type]

    async def _cancel_tasks(self) -> None:
        for t in self._tasks:
            t.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=STOP_TIMEOUT_S)
        for t in self._tasks:
            if t.done() and not t.cancelled() and t.exception() is not None:
                log.error("task %s failed: %r", t.get_name(), t.exception())
        self._tasks.clear()

    async def _stop_run(self) -> None:
        """Shutdown with a run in progress: cancel it (the finaliser makes the robot safe, the store marks the run
        interrupted) and wait, bounded."""
        task = self.run_task
        if task is None or task.done():
            return
        task.cancel()
        await asyncio.wait({task}, timeout=STOP_TIMEOUT_S)

    # --- the controller link -----------------------------------------------------------------------------------
    async def _controller_loop(self, stop: asyncio.Event) -> None:
        """Keep the controller connected; the first connect may fail (controller booting): back off and retry."""
        c = self.cfg.controller
        delay = c.reconnect_min_s
        while not stop.is_set():
            try:
                async with Controller.connect(c) as krc:
                    self.krc = krc
                    self.engine = self._make_engine(krc)
                    self.connected.set()
                    delay = c.reconnect_min_s
                    log.info("controller %s:%d connected (%s)", c.host, c.port, krc.protocol)
                    self._alarm_cleared("link")
                    if not self._resumed:
                        self._resumed = True
                        await self.resume_interrupted_campaign()
                    await stop.wait()
                    await self._stop_run()  # the run uses this link: end it before the link closes
            except LinkError as exc:
                self._alarm("link", f"controller {c.host}:{c.port} unreachable: {exc}")
            finally:
                self.connected.clear()
                self.krc = None
            if stop.is_set():
                return
            await asyncio.sleep(delay * random.uniform(0.5, 1.0))  # jittered exponential backoff
            delay = min(delay * 2.0, c.reconnect_max_s)

    def _make_engine(self, krc: Controller) -> RunEngine:
        inputs = self.safety_io.inputs if self.safety_io is not None else None
        engine = RunEngine(
            krc,
            checker=static_checker(self.cfg.limits, self.cfg.measurement.payload_lever_max_m),
            monitor=Monitor(krc, inputs=inputs,
                            stale_periods=self.cfg.limits.snapshot_stale_s / DEFAULT_POLL_PERIOD_S),
            share_dir=self.cfg.controller.share_dir,
        )
        engine.subscribe(self._event)
        return engine

    # --- events out ----------------------------------------------------------------------------------------------
    def _event(self, ev: Event) -> None:
        if self._on_event is not None:
            self._on_event(ev)
        if self.mqtt is not None:
            if ev.kind == "alarm":
                self.mqtt.publish_alarm(ev.to_json())
            elif ev.kind == "result":
                self.mqtt.notify_outbox()  # the result is in the store's outbox already
            elif ev.run_id is not None:
                self.mqtt.publish_progress(ev.run_id, ev.to_json())
        if self.safety_io is not None and ev.kind in ("alarm", "state"):
            color = "red" if ev.kind == "alarm" else self._light_for(ev.data.get("state"))
            if color is not None:
                asyncio.get_running_loop().create_task(self._set_light(color))

    @staticmethod
    def _light_for(state: str | None) -> str | None:
        return {"running": "yellow", "paused": "yellow", "finalizing": "yellow", "confirm": "yellow",
                "done": "green", "idle": "green", "failed": "red", "aborted": "red"}.get(state or "")

    async def _set_light(self, color: str) -> None:
        from rgse_daemon.io.modbus import LightColor

        try:
            async with asyncio.timeout(2.0):
                await self.safety_io.set_light(LightColor(color))
                await self.safety_io.set_running(color == "yellow")
        except (TimeoutError, RgseError) as exc:
            log.warning("stack light %s not set: %s", color, exc)

    def _alarm(self, kind: str, message: str) -> None:
        """Publish a daemon-level alarm once per kind until it clears (log each distinct error once)."""
        if kind in self._alarms_active:
            return
        self._alarms_active.add(kind)
        log.error("%s", message)
        if self.mqtt is not None:
            self.mqtt.publish_alarm({"kind": kind, "message": message})

    def _alarm_cleared(self, kind: str) -> None:
        self._alarms_active.discard(kind)

    async def _state_loop(self) -> None:
        """Publish the retained ``state``: controller snapshot, interlock/engine state, link health."""
        period = 1.0 / self.cfg.mqtt.state_rate_hz
        while True:
            await asyncio.sleep(period)
            if self.mqtt is None:
                continue
            state: dict[str, Any] = {"engine": self.engine.state if self.engine else "disconnected",
                                     "run_id": self.engine.run_id if self.engine and self.run_active else None,
                                     "run_kind": self.run_kind if self.run_active else None}
            krc = self.krc
            if krc is not None:
                try:
                    async with asyncio.timeout(self.cfg.controller.request_timeout_s * 2):
                        state["controller"] = snapshot_json(await krc.snapshot())
                except (TimeoutError, LinkError) as exc:
                    state["controller"] = None
                    state["controller_error"] = str(exc) or type(exc).__name__
                state["link"] = krc.health()
            if self.safety_io is not None:
                state["safety_io"] = dataclasses.asdict(self.safety_io.inputs)
            self.mqtt.publish_state(state)

    async def _watchdog_loop(self, interval_s: float) -> None:
        """Ping systemd's watchdog only while healthy: the loop runs (or this task would not) and the store answers."""
        while True:
            t0 = time.monotonic()
            healthy = True
            try:
                assert self.store is not None
                async with asyncio.timeout(interval_s):
                    await self.store.active_calibration(self.robot)
            except (TimeoutError, RgseError) as exc:
                healthy = False
                log.error("watchdog: store not answering (%s); not pinging", exc)
            if healthy:
                self.notifier.watchdog()
            await asyncio.sleep(max(0.0, interval_s - (time.monotonic() - t0)))

    # --- runs ----------------------------------------------------------------------------------------------------
    @property
    def run_active(self) -> bool:
        return self.run_task is not None and not self.run_task.done()

    def _start_run(self, kind: str, coro_factory: Callable[[RunEngine, Store], Awaitable[Any]]) -> asyncio.Task[Any]:
        if self._stopping:
            raise Busy("the daemon is stopping")
        if self.run_active:
            raise Busy(f"a {self.run_kind} run is in progress; abort it first or wait")
        if self.engine is None or not self.connected.is_set():
            raise NotConnected(f"controller {self.cfg.controller.host}:{self.cfg.controller.port} not connected")
        assert self.store is not None
        engine, store = self.engine, self.store
        self.run_kind = kind

        async def runner() -> Any:
            try:
                result = await coro_factory(engine, store)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.error("%s run failed: %s", kind, self.last_error)
                raise
            self.last_result = result
            return result

        self.run_task = asyncio.create_task(runner(), name=f"rgse-run-{kind}")
        self.run_task.add_done_callback(lambda t: t.cancelled() or t.exception())  # retrieved: logged above
        return self.run_task

    async def start_measurement(self, *, loops: int | None = None, fixture_mass_kg: float | None = None,
                                dry_run: bool = False) -> asyncio.Task[Any]:
        overrides: dict[str, Any] = {}
        if loops is not None:
            overrides["loops"] = loops
        if fixture_mass_kg is not None:
            overrides["fixture_mass_kg"] = fixture_mass_kg
        settings = RunSettings.from_config(self.cfg, **overrides)
        inputs = self.safety_io.inputs if self.safety_io is not None else None
        return self._start_run(
            "measurement",
            lambda engine, store: run_measurement(
                self._dry(engine) if dry_run else engine, store, self.cfg, settings=settings, inputs=inputs
            ),
        )

    def _dry(self, engine: RunEngine) -> RunEngine:
        dry = RunEngine(engine.krc, checker=engine.checker, monitor=None, dry_run=True, share_dir=engine.share_dir)
        dry.subscribe(self._event)
        return dry

    async def start_calibration(self, *, points: list[CampaignPoint] | None = None, method: str = "auto",
                                run_id: str | None = None, settings: RunSettings | None = None) -> asyncio.Task[Any]:
        inputs = self.safety_io.inputs if self.safety_io is not None else None
        return self._start_run(
            "calibration",
            lambda engine, store: run_calibration(engine, store, self.cfg, points=points, method=method,
                                                  run_id=run_id, settings=settings, inputs=inputs),
        )

    async def resume_interrupted_campaign(self) -> asyncio.Task[Any] | None:
        """Continue the newest campaign of this robot that a previous daemon left interrupted, if any."""
        assert self.store is not None
        runs = await self.store.list_runs(robot=self.robot)
        for r in runs:
            if r.kind == RunKind.CALIBRATION and r.state == RunState.INTERRUPTED:
                log.info("continuing interrupted calibration campaign %s", r.id)
                return await self.start_calibration(run_id=r.id, method=r.config.get("method", "auto"))
        return None

    # --- CommandHandler (MQTT cmd/<verb>) ---------------------------------------------------------------------------
    async def measure(self, cmd: MeasureCommand) -> dict[str, Any]:
        await self.start_measurement(loops=cmd.loops, fixture_mass_kg=cmd.fixture_mass_kg, dry_run=cmd.dry_run)
        return {"accepted": "measurement", "dry_run": cmd.dry_run}

    async def calibrate(self, cmd: CalibrateCommand) -> dict[str, Any]:
        points = None
        if cmd.points is not None:
            points = [CampaignPoint(p.kind, p.mass_kg, p.lever_a3_m, p.lever_a5_m,
                                    0 if p.kind == "zero" else max(1, round(p.mass_kg / CB_MASS_KG)))
                      for p in cmd.points]
        await self.start_calibration(points=points, method=cmd.method or "auto")
        return {"accepted": "calibration", "points": len(points) if points else None}

    async def abort(self, cmd: AbortCommand) -> dict[str, Any]:
        engine = self.engine
        if engine is None or not self.run_active:
            raise RgseError("no run in progress")
        if cmd.run_id is not None and engine.run_id != cmd.run_id:
            raise RgseError(f"run {cmd.run_id} is not the run in progress ({engine.run_id})")
        engine.abort(cmd.reason)
        return {"aborting": engine.run_id}

    async def confirm(self, cmd: ConfirmCommand) -> dict[str, Any]:
        engine = self.engine
        if engine is None or not engine.waiting_for_confirmation:
            raise RgseError("no run waits for a confirmation")
        if engine.run_id != cmd.run_id:
            raise RgseError(f"run {cmd.run_id} is not the run waiting ({engine.run_id})")
        engine.confirm(f"point {cmd.point}" if cmd.point is not None else "confirmed")
        return {"confirmed": cmd.run_id}
