"""The daemon (``rgse daemon --config``): one asyncio service that owns the components and their lifecycle.

Components, started in this order and stopped in the reverse one, each stop with a bounded wait (architecture
lesson 6)::

    store       SQLite/PostgreSQL; interrupted runs of a dead daemon are marked at start
    safety I/O  the Modbus module (optional); its inputs feed the interlock, it shows the stack light
    MQTT        status (last will ``offline``), state, progress, alarms, results from the outbox, commands
    controller  the KR C4 link; (re)connected in the background with jittered exponential backoff
    engine      one :class:`~rgse_daemon.procedures.engine.RunEngine` with the interlock monitor — one run at a
                time, because the robot is one resource: a second request is refused with the reason

Shutdown (``stop`` set, SIGTERM) goes the other way: the run in progress is cancelled first, while the link is
still open, so its finaliser stops program and trace and the store marks the run ``interrupted``; then the link
closes, the background loops end, MQTT says ``offline``, the stack light goes dark, the store closes.

The controller link is watched while idle (a read every :data:`LINK_PROBE_S`; during a run the interlock monitor
watches it at 20 Hz and trips): when it is lost, ``connected`` is cleared, a ``link`` alarm is published once and
the link is opened anew with backoff; ``connected`` is set again when it is back.

Safety I/O (optional ``[modbus]``): the inputs go to the run preconditions, to the static check of every program
(AUT only with "area cleared" and "key switch AUT permitted") and to the runtime monitor, which allows exactly the
operating mode a run started in and, in AUT, trips when an input drops or the module is unreachable (doubt = trip).
Without the module, AUT is never accepted.

systemd (``Type=notify``): ``READY=1`` once the store is open and the components started, ``WATCHDOG=1`` from the
event loop only while the loop is responsive and the store answers, ``STOPPING=1`` on SIGTERM. A calibration
campaign that a previous daemon left interrupted is continued at its first incomplete point (its next step asks the
operator to confirm the mounted load).

Commands (MQTT ``cmd/<verb>`` or in-process) are the :class:`~rgse_daemon.io.mqtt.CommandHandler` methods:
``measure``, ``calibrate``, ``abort``, ``confirm``; ``measure`` and ``calibrate`` answer once the run has started,
with its run id, and the run goes on in a task.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import random
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace
from typing import Any

from rgse_daemon import __version__
from rgse_daemon import kinematics as kin
from rgse_daemon.aio import within
from rgse_daemon.config import Config
from rgse_daemon.controller import Controller, Snapshot
from rgse_daemon.errors import LinkError, RgseError, VariableError
from rgse_daemon.filelayout import load_layout
from rgse_daemon.io.commands import AbortCommand, CalibrateCommand, CalibrationPoint, ConfirmCommand, MeasureCommand
from rgse_daemon.io.modbus import SafetyInputs
from rgse_daemon.procedures.calibration import CB_MASS_KG, TA_MASS_KG, TA_TORQUE_A5_NM, CampaignPoint, run_calibration
from rgse_daemon.procedures.common import PreconditionError, RunSettings, static_checker
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.measurement import run_measurement
from rgse_daemon.safety.monitor import DEFAULT_POLL_PERIOD_S, Monitor
from rgse_daemon.store import RunKind, RunState, Store
from rgse_daemon.systemd import Notifier

log = logging.getLogger(__name__)

#: Bounded waits of the ordered shutdown, per component (s).
STOP_TIMEOUT_S = 15.0
#: How often the idle controller link is probed (s).
LINK_PROBE_S = 1.0
#: How long ``measure``/``calibrate`` wait for the run to start before answering without its run id (s).
RUN_START_TIMEOUT_S = 10.0
#: Deadline of one stack light update (s).
LIGHT_TIMEOUT_S = 2.0
#: A calibration point's mass must be this close to a whole number of calibration bodies (kg).
BODY_MASS_TOLERANCE_KG = 0.05

Inputs = Callable[[], SafetyInputs]


class Busy(RgseError):
    """A run is already in progress: the robot is one resource."""


class NotConnected(RgseError):
    """The controller link is not up (yet): no run can start."""


@dataclass
class DaemonCounters:
    """What the daemon did since it started; published in the ``state`` message under ``"daemon"``."""

    controller_connects: int = 0
    controller_connect_failures: int = 0
    link_losses: int = 0
    """Losses of an established controller link."""
    runs_started: int = 0
    runs_refused: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


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


def campaign_point(p: CalibrationPoint, g_m_s2: float = kin.G_PAPER_M_S2) -> CampaignPoint:
    """A ``calibrate`` command's point (a manifest ``[[point]]``) with what the operator mounts for it: the number of
    calibration bodies and, for a torque point, where they sit on the test adapter (inverse of
    :func:`~rgse_daemon.procedures.calibration.torque_point`). A mass that is no whole number of bodies is refused."""
    if p.kind == "zero":
        if p.mass_kg != 0.0:
            raise RgseError(f"zero point with mass {p.mass_kg:g} kg: the zero point is the empty MPA (0 kg)")
        return CampaignPoint("zero", 0.0, p.lever_a3_m, p.lever_a5_m, 0)
    bodies_kg = p.mass_kg - (TA_MASS_KG if p.kind == "torque" else 0.0)
    n_cb = round(bodies_kg / CB_MASS_KG)
    if n_cb < 1 or abs(n_cb * CB_MASS_KG - bodies_kg) > BODY_MASS_TOLERANCE_KG:
        what = "test adapter + " if p.kind == "torque" else ""
        raise RgseError(f"{p.kind} point with mass {p.mass_kg:g} kg: not {what}a whole number of calibration bodies "
                        f"({CB_MASS_KG:g} kg each)")
    if p.kind == "mass":
        return CampaignPoint("mass", p.mass_kg, p.lever_a3_m, p.lever_a5_m, n_cb)
    ta_lever_a5_m = TA_TORQUE_A5_NM / (g_m_s2 * TA_MASS_KG)
    cb_lever_a5_m = (p.mass_kg * p.lever_a5_m - TA_MASS_KG * ta_lever_a5_m) / (CB_MASS_KG * n_cb)
    return CampaignPoint("torque", p.mass_kg, p.lever_a3_m, p.lever_a5_m, n_cb, cb_lever_a5_m)


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
        self.counters = DaemonCounters()
        self.run_task: asyncio.Task[Any] | None = None
        self.run_kind: str | None = None
        self.last_result: dict[str, Any] | None = None
        self.last_error: str | None = None
        self.link_error: str | None = None
        self._run_started: asyncio.Future[str | None] | None = None
        self._confirm_data: dict[str, Any] = {}
        self._tasks: list[asyncio.Task[Any]] = []
        self._controller_task: asyncio.Task[None] | None = None
        self._stopping = False
        self._alarms_active: set[str] = set()
        self._resumed = False
        self._light_wanted: str | None = None
        self._light_wake = asyncio.Event()

    # --- lifecycle -----------------------------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Start every component, serve until ``stop`` is set, then stop them in reverse order."""
        async with contextlib.AsyncExitStack() as stack:
            self.store = await Store.open(self.cfg.store.url, self.cfg.paths.data_dir)
            stack.push_async_callback(self._bounded, "store", self.store.close)
            recovered = await self.store.recover_interrupted(self.robot)
            if recovered:
                log.warning("runs left running by a previous daemon marked interrupted: %s", [r.id for r in recovered])

            if self.cfg.modbus is not None:
                from rgse_daemon.io.modbus import SafetyIo

                self.safety_io = SafetyIo(self.cfg.modbus)
                await self.safety_io.start()
                stack.push_async_callback(self._bounded, "safety I/O", self._stop_safety_io)
                self._want_light("green")  # idle; written as soon as the module answers

            if self.cfg.mqtt.enabled:
                from rgse_daemon.io.mqtt import MqttBridge

                self.mqtt = MqttBridge(self.cfg.mqtt, self.robot, self.store, self, __version__)
                await self.mqtt.start()
                stack.push_async_callback(self._bounded, "mqtt", self.mqtt.stop)

            self._spawn(self._state_loop(), "state")
            if self.notifier.watchdog_interval_s is not None:
                self._spawn(self._watchdog_loop(self.notifier.watchdog_interval_s), "watchdog")
            if self.safety_io is not None:
                self._spawn(self._light_loop(), "stack-light")
            stack.push_async_callback(self._cancel_tasks)
            self._controller_task = asyncio.create_task(self._controller_loop(stop), name="rgse-controller")
            stack.push_async_callback(self._stop_controller)
            stack.push_async_callback(self._stop_run)

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
        interrupted) and wait, bounded — while the controller link is still open."""
        task = self.run_task
        if task is None or task.done():
            return
        if task.cancelling() == 0:  # once: a second cancel would interrupt the finaliser that makes the robot safe
            log.warning("stopping: cancelling the %s run in progress", self.run_kind)
            task.cancel()
        done, _ = await asyncio.wait({task}, timeout=STOP_TIMEOUT_S)
        if not done:
            log.error("the %s run did not end within %.0f s of its cancellation", self.run_kind, STOP_TIMEOUT_S)

    async def _stop_controller(self) -> None:
        """End the controller loop (it closes the link), bounded. A connect attempt in flight is cancelled: no run
        uses a link that is not up."""
        task, self._controller_task = self._controller_task, None
        if task is None:
            return
        if not self.connected.is_set():
            task.cancel()
        done, _ = await asyncio.wait({task}, timeout=STOP_TIMEOUT_S)
        if not done:
            log.error("closing the controller link took longer than %.0f s; abandoned", STOP_TIMEOUT_S)
            task.cancel()
            await asyncio.wait({task}, timeout=STOP_TIMEOUT_S)
        elif not task.cancelled() and task.exception() is not None:
            log.error("controller loop failed: %r", task.exception())

    async def _stop_safety_io(self) -> None:
        """Dark stack light and "running" off (no daemon, no light), then stop polling."""
        assert self.safety_io is not None
        await self._write_light("off")
        await self.safety_io.stop()

    # --- the controller link -----------------------------------------------------------------------------------
    async def _controller_loop(self, stop: asyncio.Event) -> None:
        """Keep the controller connected; the first connect may fail (controller booting), a link may be lost: back
        off (jittered, exponential) and connect anew."""
        c = self.cfg.controller
        attempt = 0
        while not stop.is_set():
            try:
                # the path form and listing format `rgse doctor` found on this controller (probed if none)
                layout = load_layout(self.cfg.paths.data_dir)
                async with Controller.connect(c, layout=layout) as krc:
                    attempt = 0
                    self.krc = krc
                    self.engine = self._make_engine(krc)
                    self.counters.controller_connects += 1
                    self.link_error = None
                    self.connected.set()
                    log.info("controller %s:%d connected (%s)", c.host, c.port, krc.protocol)
                    self._alarm_cleared("link")
                    if not self.run_active:
                        self._want_light("green")
                    await self._resume_once()
                    lost = await self._supervise(krc, stop)
                    self.connected.clear()
                    if lost is None:
                        await self._stop_run()  # the run uses this link: end it before the link closes
                    else:
                        self.counters.link_losses += 1
                        self.link_error = lost
                        self._alarm("link", f"controller {c.host}:{c.port} link lost: {lost}")
                        await self._wait_run_end()  # the interlock monitor trips on the lost link
            except LinkError as exc:
                self.counters.controller_connect_failures += 1
                self.link_error = str(exc) or type(exc).__name__
                self._alarm("link", f"controller {c.host}:{c.port} unreachable: {self.link_error}")
            except Exception as exc:  # a bug must not end the controller link for good: say so, back off, retry
                log.exception("controller loop: unexpected error")
                self.link_error = f"{type(exc).__name__}: {exc}"
                self._alarm("link", f"controller {c.host}:{c.port}: unexpected error: {self.link_error}")
            finally:
                self.connected.clear()
                self.krc = None
            if stop.is_set():
                return
            with contextlib.suppress(TimeoutError):
                await within(stop.wait(), self._backoff_s(attempt))
            attempt += 1

    def _backoff_s(self, attempt: int) -> float:
        """Exponential backoff between ``reconnect_min_s`` and ``reconnect_max_s``, jittered (× 0.5…1)."""
        c = self.cfg.controller
        return min(c.reconnect_max_s, c.reconnect_min_s * 2.0 ** min(attempt, 30)) * random.uniform(0.5, 1.0)

    async def _supervise(self, krc: Controller, stop: asyncio.Event) -> str | None:
        """Wait for ``stop`` (returns None) or for the loss of the idle link (returns why)."""
        c = self.cfg.controller
        while True:
            with contextlib.suppress(TimeoutError):
                await within(stop.wait(), LINK_PROBE_S)
                return None
            if self.run_active:
                continue  # the interlock monitor reads the controller at 20 Hz and trips on link loss
            try:
                async with asyncio.timeout(c.connect_timeout_s + c.request_timeout_s):
                    await krc.read_raw("$MODE_OP")
            except VariableError:
                continue  # the controller answered: the link is up
            except TimeoutError:
                return f"no answer to a probe within {c.connect_timeout_s + c.request_timeout_s:g} s"
            except LinkError as exc:
                return str(exc) or type(exc).__name__

    async def _wait_run_end(self) -> None:
        task = self.run_task
        if task is not None and not task.done():
            await asyncio.wait({task})

    async def _resume_once(self) -> None:
        if self._resumed:
            return
        self._resumed = True
        try:
            await self.resume_interrupted_campaign()
        except RgseError as exc:
            log.error("could not continue the interrupted calibration campaign: %s", exc)

    def _inputs(self) -> Inputs | None:
        """The safety inputs as the interlock reads them (a fresh view at each call), or None without the module."""
        io = self.safety_io
        if io is None:
            return None
        return lambda: io.inputs

    def _make_engine(self, krc: Controller) -> RunEngine:
        inputs = self._inputs()
        engine = RunEngine(
            krc,
            checker=static_checker(self.cfg.limits, self.cfg.measurement.payload_lever_max_m, inputs),
            monitor=Monitor(krc, inputs=inputs,
                            stale_periods=self.cfg.limits.snapshot_stale_s / DEFAULT_POLL_PERIOD_S),
            share_dir=self.cfg.controller.share_dir,
        )
        engine.subscribe(self._event)
        return engine

    # --- events out ----------------------------------------------------------------------------------------------
    def _event(self, ev: Event) -> None:
        if ev.kind == "state" and ev.data.get("state") == "running":
            started = self._run_started
            if started is not None and not started.done():
                started.set_result(ev.run_id)
        if ev.kind == "confirm":
            self._confirm_data = dict(ev.data)
        if self._on_event is not None:
            self._on_event(ev)
        if self.mqtt is not None:
            if ev.kind == "alarm":
                self.mqtt.publish_alarm(ev.to_json())
            elif ev.kind == "result":
                self.mqtt.notify_outbox()  # the result is in the store's outbox already
            elif ev.run_id is not None:
                self.mqtt.publish_progress(ev.run_id, ev.to_json())
        if ev.kind in ("alarm", "state"):
            color = "red" if ev.kind == "alarm" else self._light_for(ev.data.get("state"))
            if color is not None:
                self._want_light(color)

    @staticmethod
    def _light_for(state: str | None) -> str | None:
        return {"running": "yellow", "paused": "yellow", "finalizing": "yellow", "confirm": "yellow",
                "done": "green", "idle": "green", "failed": "red", "aborted": "red"}.get(state or "")

    def _want_light(self, color: str) -> None:
        """Ask for a stack light colour; the light task writes the latest wish, in order (yellow also sets the
        "measurement running" output)."""
        if self.safety_io is None:
            return
        self._light_wanted = color
        self._light_wake.set()

    async def _light_loop(self) -> None:
        while True:
            await self._light_wake.wait()
            self._light_wake.clear()
            if self._light_wanted is not None:
                await self._write_light(self._light_wanted)

    async def _write_light(self, color: str) -> None:
        """Write light and "running" output, bounded. The module remembers both wishes and writes them again after a
        reconnect, so a failure here is only logged."""
        from rgse_daemon.io import IoLinkError
        from rgse_daemon.io.modbus import LightColor

        io = self.safety_io
        for what, write in (("stack light", lambda: io.set_light(LightColor(color))),
                            ("running output", lambda: io.set_running(color == "yellow"))):
            try:
                async with asyncio.timeout(LIGHT_TIMEOUT_S):
                    await write()
            except IoLinkError as exc:  # the module's own poller reports its link; the wish is kept
                log.debug("%s %s not written now: %s", what, color, exc)
            except (TimeoutError, RgseError) as exc:
                log.warning("%s %s not written: %s", what, color, exc)

    def _alarm(self, kind: str, message: str) -> None:
        """Publish a daemon-level alarm once per kind until it clears (log each distinct error once)."""
        if kind in self._alarms_active:
            return
        self._alarms_active.add(kind)
        log.error("%s", message)
        if self.mqtt is not None:
            self.mqtt.publish_alarm({"kind": kind, "message": message})
        self._want_light("red")

    def _alarm_cleared(self, kind: str) -> None:
        if kind in self._alarms_active:
            self._alarms_active.discard(kind)
            log.info("%s alarm cleared", kind)

    async def _state_loop(self) -> None:
        """Publish the retained ``state``: controller snapshot, interlock/engine state, link health, counters."""
        period = 1.0 / self.cfg.mqtt.state_rate_hz
        while True:
            await asyncio.sleep(period)
            if self.mqtt is None:
                continue
            state: dict[str, Any] = {"engine": self.engine.state if self.engine else "disconnected",
                                     "run_id": self.engine.run_id if self.engine and self.run_active else None,
                                     "run_kind": self.run_kind if self.run_active else None,
                                     "connected": self.connected.is_set(),
                                     "daemon": self.counters.as_dict()}
            krc = self.krc
            if krc is not None:
                try:
                    async with asyncio.timeout(self.cfg.controller.request_timeout_s * 2):
                        state["controller"] = snapshot_json(await krc.snapshot())
                except (TimeoutError, LinkError) as exc:
                    state["controller"] = None
                    state["controller_error"] = str(exc) or type(exc).__name__
                state["link"] = krc.health()
            elif self.link_error is not None:
                state["controller_error"] = self.link_error
            if self.safety_io is not None:
                inputs = self.safety_io.inputs
                state["safety_io"] = {**dataclasses.asdict(inputs), "time_utc": inputs.time_utc.isoformat()}
            try:
                self.mqtt.publish_state(state)
            except RgseError as exc:  # a state this loop cannot publish must not end the loop
                log.error("state not published: %s", exc)

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

    def _start_run(self, kind: str, coro_factory: Callable[[RunEngine, Store], Awaitable[Any]],
                   engine: RunEngine | None = None) -> asyncio.Task[Any]:
        """Reserve the robot for one run (synchronously: no second request can slip in) and start it in a task."""
        if self._stopping:
            self.counters.runs_refused += 1
            raise Busy("busy: the daemon is stopping")
        if self.run_active:
            self.counters.runs_refused += 1
            started = self._run_started
            run_id = started.result() if started is not None and started.done() else None
            raise Busy(f"busy: a {self.run_kind} run{f' ({run_id})' if run_id else ''} is in progress; "
                       "abort it first or wait")
        if self.engine is None or self.krc is None or not self.connected.is_set():
            self.counters.runs_refused += 1
            c = self.cfg.controller
            why = f" ({self.link_error})" if self.link_error else ""
            raise NotConnected(f"not connected: controller {c.host}:{c.port} is not connected{why}")
        assert self.store is not None
        main_engine, store = self.engine, self.store
        use = engine if engine is not None else main_engine
        krc = self.krc
        self.run_kind = kind
        self._run_started = asyncio.get_running_loop().create_future()
        self._confirm_data = {}
        self.counters.runs_started += 1

        async def runner() -> Any:
            try:
                await self._check_start_mode(krc, use)
                result = await coro_factory(use, store)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.error("%s run failed: %s", kind, self.last_error)
                if self.mqtt is not None:
                    started = self._run_started
                    run_id = started.result() if started is not None and started.done() else None
                    self.mqtt.publish_alarm({"kind": "run_failed", "run_kind": kind, "run_id": run_id,
                                             "message": f"{kind} run failed: {self.last_error}"})
                self._want_light("red")
                raise
            self.last_result = result
            return result

        self.run_task = asyncio.create_task(runner(), name=f"rgse-run-{kind}")
        self.run_task.add_done_callback(lambda t: t.cancelled() or t.exception())  # retrieved: logged above
        return self.run_task

    async def _check_start_mode(self, krc: Controller, engine: RunEngine) -> None:
        """Before anything is recorded or moved: AUT only with the safety I/O module's inputs all good (area
        cleared, key switch AUT permitted, E-stop OK, a fresh reading), else :class:`PreconditionError` — the plan's
        own preconditions, the static check and the monitor check it again. The runtime monitor then allows exactly
        the mode the run starts in (T1, or AUT when the module is configured): a mode change during the run trips."""
        timeout_s = self.cfg.controller.request_timeout_s * 2
        try:
            async with asyncio.timeout(timeout_s):
                snap = await krc.snapshot()
        except TimeoutError as exc:
            raise LinkError(f"no controller snapshot within {timeout_s:g} s") from exc
        mode = snap.mode_op
        if mode == "AUT":
            inputs = self.safety_io.inputs if self.safety_io is not None else None
            if inputs is None or not inputs.safe:
                why = "no safety I/O module configured" if inputs is None else (
                    inputs.reason or ", ".join(n for n, ok in (("area not cleared", inputs.area_cleared),
                                                               ("AUT key not turned", inputs.aut_permitted),
                                                               ("E-stop not OK", inputs.estop_ok)) if not ok))
                raise PreconditionError(f"refused to start: AUT needs the area cleared, the AUT key and E-stop OK "
                                        f"({why})")
        if engine.monitor is not None:
            allowed = {mode} if mode == "T1" or (mode == "AUT" and self.safety_io is not None) else {"T1"}
            engine.monitor.context = replace(engine.monitor.context, allowed_modes=frozenset(allowed))

    async def _started(self, task: asyncio.Task[Any]) -> str | None:
        """Wait until the run has started (its run id; None for a dry run) or has failed before (raises why)."""
        started = self._run_started
        assert started is not None
        await asyncio.wait({started, task}, timeout=RUN_START_TIMEOUT_S, return_when=asyncio.FIRST_COMPLETED)
        if started.done():
            return started.result()
        if task.done():
            if task.cancelled():
                raise RgseError("the run was cancelled before it started")
            exc = task.exception()
            if exc is not None:
                raise exc
        return None

    async def start_measurement(self, *, loops: int | None = None, fixture_mass_kg: float | None = None,
                                dry_run: bool = False) -> asyncio.Task[Any]:
        overrides: dict[str, Any] = {}
        if loops is not None:
            overrides["loops"] = loops
        if fixture_mass_kg is not None:
            overrides["fixture_mass_kg"] = fixture_mass_kg
        settings = RunSettings.from_config(self.cfg, **overrides)
        inputs = self._inputs()
        dry = self._dry(self.engine) if dry_run and self.engine is not None else None
        return self._start_run(
            "measurement",
            lambda engine, store: run_measurement(engine, store, self.cfg, settings=settings, inputs=inputs),
            engine=dry,
        )

    def _dry(self, engine: RunEngine) -> RunEngine:
        dry = RunEngine(engine.krc, checker=engine.checker, monitor=None, dry_run=True, share_dir=engine.share_dir)
        dry.subscribe(self._event)
        return dry

    async def start_calibration(self, *, points: list[CampaignPoint] | None = None, method: str = "auto",
                                run_id: str | None = None, settings: RunSettings | None = None) -> asyncio.Task[Any]:
        inputs = self._inputs()
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
        task = await self.start_measurement(loops=cmd.loops, fixture_mass_kg=cmd.fixture_mass_kg,
                                            dry_run=cmd.dry_run)
        return {"accepted": "measurement", "run_id": await self._started(task), "dry_run": cmd.dry_run}

    async def calibrate(self, cmd: CalibrateCommand) -> dict[str, Any]:
        points = [campaign_point(p) for p in cmd.points] if cmd.points is not None else None
        task = await self.start_calibration(points=points, method=cmd.method or "auto")
        return {"accepted": "calibration", "run_id": await self._started(task),
                "points": len(points) if points else None}

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
        waiting = self._confirm_data.get("point_index")
        if cmd.point is not None and waiting is not None and cmd.point != waiting:
            raise RgseError(f"run {cmd.run_id} waits for point {waiting}, not point {cmd.point}: nothing confirmed")
        note = cmd.message or (f"point {cmd.point}" if cmd.point is not None else "confirmed")
        engine.confirm(note)
        return {"confirmed": cmd.run_id}
