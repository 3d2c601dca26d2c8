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
``measure``, ``properties``, ``calibrate``, ``abort``, ``confirm``; ``measure``, ``properties`` and ``calibrate``
answer once the run has started, with its run id, and the run goes on in a task.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from rgse_daemon import __version__, robots
from rgse_daemon import kinematics as kin
from rgse_daemon.config import Config
from rgse_daemon.controller import Controller
from rgse_daemon.errors import RgseError
from rgse_daemon.io.commands import (
    AbortCommand,
    CalibrateCommand,
    CalibrationPoint,
    ConfirmCommand,
    MeasureCommand,
    PropertiesCommand,
)
from rgse_daemon.procedures.calibration import CampaignPoint, run_calibration
from rgse_daemon.procedures.documents import Document, Result
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.measurement import run_measurement
from rgse_daemon.procedures.programs import static_checker
from rgse_daemon.procedures.properties import PropertiesSettings, run_properties
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.inputs import SafetyInputs
from rgse_daemon.safety.latch import SafetyLatch
from rgse_daemon.safety.monitor import DEFAULT_POLL_PERIOD_S, Monitor
from rgse_daemon.safety.static import mounted_payload
from rgse_daemon.services.admission import Busy, NotConnected, RunAdmission
from rgse_daemon.services.heartbeat import Heartbeat
from rgse_daemon.services.link import ControllerLink, DaemonCounters
from rgse_daemon.services.recovery import Recovery
from rgse_daemon.services.signals import Alarms, StackLight
from rgse_daemon.services.state import StatePublisher, snapshot_json, watchdog_loop
from rgse_daemon.store import RunKind, RunState, Store
from rgse_daemon.systemd import Notifier

log = logging.getLogger(__name__)

__all__ = ["Busy", "Daemon", "DaemonCounters", "NotConnected", "campaign_point", "snapshot_json"]

#: Bounded waits of the ordered shutdown, per component (s).
STOP_TIMEOUT_S = 15.0
#: A calibration point's mass must be this close to a whole number of calibration bodies (kg).
BODY_MASS_TOLERANCE_KG = 0.05

Inputs = Callable[[], SafetyInputs]


def campaign_point(p: CalibrationPoint, g_m_s2: float = kin.G_PAPER_M_S2) -> CampaignPoint:
    """A ``calibrate`` command's point (a manifest ``[[point]]``) with what the operator mounts for it: the number of
    calibration bodies and, for a torque point, where they sit on the test adapter (inverse of
    :func:`~rgse_daemon.procedures.calibration.torque_point`). A mass that is no whole number of bodies is refused."""
    if p.kind == "zero":
        if p.mass_kg != 0.0:
            raise RgseError(f"zero point with mass {p.mass_kg:g} kg: the zero point is the empty MPA (0 kg)")
        return CampaignPoint("zero", 0.0, p.lever_a3_m, p.lever_a5_m, 0)
    loads = robots.active().calibration  # the configured robot's load set
    cb_kg, ta_kg = loads.body_mass_kg, loads.adapter_mass_kg
    bodies_kg = p.mass_kg - (ta_kg if p.kind == "torque" else 0.0)
    n_cb = round(bodies_kg / cb_kg)
    if n_cb < 1 or abs(n_cb * cb_kg - bodies_kg) > BODY_MASS_TOLERANCE_KG:
        what = "test adapter + " if p.kind == "torque" else ""
        raise RgseError(f"{p.kind} point with mass {p.mass_kg:g} kg: not {what}a whole number of calibration bodies "
                        f"({cb_kg:g} kg each)")
    if p.kind == "mass":
        return CampaignPoint("mass", p.mass_kg, p.lever_a3_m, p.lever_a5_m, n_cb)
    ta_lever_a5_m = loads.adapter_torque_a5_nm / (g_m_s2 * ta_kg)
    cb_lever_a5_m = (p.mass_kg * p.lever_a5_m - ta_kg * ta_lever_a5_m) / (cb_kg * n_cb)
    return CampaignPoint("torque", p.mass_kg, p.lever_a3_m, p.lever_a5_m, n_cb, cb_lever_a5_m)


class Daemon:
    """The service. ``await Daemon(cfg).run(stop)`` runs until ``stop`` is set (SIGTERM), then shuts down in order.

    It composes the standing jobs of :mod:`rgse_daemon.services` (controller link, run admission, stack light and
    alarms, state) and answers the commands. ``on_event`` (optional) sees every engine event too: the demo prints
    from it, tests and the operator's confirmation hook answer prompts from it.
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
        # the configured arm is the one the kinematics, the renderer and the interlock use from here on
        robots.activate(cfg.robot_model)
        self.notifier = notifier or Notifier()
        self._on_event = on_event
        self.store: Store | None = None
        self.engine: RunEngine | None = None
        self.safety_io: Any = None  # rgse_daemon.io.modbus.SafetyIo when configured
        self.mqtt: Any = None  # rgse_daemon.io.mqtt.MqttBridge when enabled
        self.console: Any = None  # rgse_daemon.services.console.Console when enabled
        self.counters = DaemonCounters()
        self.light = StackLight(None)
        self.alarms = Alarms(self._publish_alarm, self.light)
        self.link = ControllerLink(cfg.controller, self.counters, self.alarms, busy=lambda: self.run_active,
                                   data_dir=cfg.paths.data_dir)
        self.heartbeat: Heartbeat | None = None
        self.admission = RunAdmission(cfg, self.counters, self._current_inputs, self._run_failed, self._run_refused,
                                      on_link_lost=self.link.lost_during_run)
        self._confirm_data: dict[str, Any] = {}
        self._prompt_open = False
        self._tasks: list[asyncio.Task[Any]] = []
        self._controller_task: asyncio.Task[None] | None = None
        self._resumed = False
        self.latch = SafetyLatch(cfg.paths.data_dir)
        self.recovery: Recovery | None = None

    # --- what the jobs hold, as the rest of the code and the tests read it -----------------------------------------
    @property
    def connected(self) -> asyncio.Event:
        return self.link.connected

    @property
    def krc(self) -> Controller | None:
        return self.link.krc

    @property
    def link_error(self) -> str | None:
        return self.link.error

    @property
    def run_task(self) -> asyncio.Task[Any] | None:
        return self.admission.task

    @property
    def run_kind(self) -> RunKind | None:
        return self.admission.kind

    @property
    def run_active(self) -> bool:
        return self.admission.active

    @property
    def last_result(self) -> Any:
        return self.admission.last_result

    @property
    def last_error(self) -> str | None:
        return self.admission.last_error

    # --- lifecycle -----------------------------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Start every component, serve until ``stop`` is set, then stop them in reverse order."""
        async with contextlib.AsyncExitStack() as stack:
            self.store = await Store.open(self.cfg.store.url, self.cfg.paths.data_dir)
            stack.push_async_callback(self._bounded, "store", self.store.close)
            recovered = await self.store.recover_interrupted(self.robot)
            if recovered:
                log.warning("runs left running by a previous daemon marked interrupted: %s", [r.id for r in recovered])
            self.recovery = Recovery(self.cfg, self.store, self.latch, self._publish_alarm,
                                     lambda run_id, p: self.mqtt.publish_progress(run_id, p) if self.mqtt else None,
                                     lambda: self.mqtt.notify_outbox() if self.mqtt else None)

            if self.cfg.modbus is not None:
                from rgse_daemon.io.modbus import SafetyIo

                self.safety_io = SafetyIo(self.cfg.modbus)
                await self.safety_io.start()
                self.light.io = self.safety_io
                stack.push_async_callback(self._bounded, "safety I/O", self._stop_safety_io)
                self.light.want("green")  # idle; written as soon as the module answers

            if self.cfg.mqtt.enabled:
                from rgse_daemon.io.mqtt import MqttBridge

                self.mqtt = MqttBridge(self.cfg.mqtt, self.robot, self.store, self, __version__,
                                       stop_timeout_s=STOP_TIMEOUT_S * 2 / 3)  # within the bound below
                await self.mqtt.start()
                stack.push_async_callback(self._bounded, "mqtt", self.mqtt.stop)
                self.mqtt.publish_prompt(None)  # a prompt retained by a daemon that died while it waited is void

            state = StatePublisher(self.link, self.admission, rate_hz=self.cfg.mqtt.state_rate_hz,
                                   engine=lambda: self.engine, mqtt=lambda: self.mqtt, safety_io=self.safety_io)
            self._spawn(state.run(), "state")
            if self.cfg.console.enabled:
                await self._start_console(state, stack)
            if self.notifier.watchdog_interval_s is not None:
                self._spawn(watchdog_loop(self.notifier, self.store, self.robot, self.notifier.watchdog_interval_s),
                            "watchdog")
            if self.safety_io is not None:
                self._spawn(self.light.run(), "stack-light")
            stack.push_async_callback(self._cancel_tasks)
            # the controller-side watchdog's heartbeat, on a connection of its own, while the link is up; a beat
            # queued behind the controller's file work (a pull: no program runs, the watchdog is not armed) gets
            # that work's deadline added, as every other request does (link.connection.ServerLoad)
            self.heartbeat = Heartbeat(self.cfg.controller, self.alarms, self.link.connected.is_set,
                                       connection=self.link.heartbeat_connection())
            self._spawn(self.heartbeat.run(stop), "heartbeat")
            # before each connect counts: stop what was left running, finish interrupted runs (docs/recovery.md)
            self._controller_task = asyncio.create_task(
                self.link.run(stop, self._link_up, self._link_down, prepare=self.recovery.on_connect),
                name="rgse-controller")
            stack.push_async_callback(self._stop_controller)
            stack.push_async_callback(self.admission.stop)

            self.notifier.ready(f"serving robot {self.robot}")
            log.info("rgse daemon %s serving robot %s", __version__, self.robot)
            await stop.wait()
            self.admission.stopping = True
            self.notifier.stopping()
            log.info("stopping")

    async def _start_console(self, state: StatePublisher, stack: contextlib.AsyncExitStack) -> None:
        from rgse_daemon.services.console import Console

        assert self.store is not None
        self.console = Console(self.cfg.console, robot=self.robot, handler=self, state=state.document,
                               light=lambda: self.light.color, store=self.store, store_url=self.cfg.store.url,
                               data_dir=self.cfg.paths.data_dir, tokens=self.cfg.mqtt.command_tokens,
                               open_bench=self.cfg.mqtt.command_auth == "open_lab_bench",
                               rate_hz=max(self.cfg.mqtt.state_rate_hz, 10.0))
        await self.console.start()
        stack.push_async_callback(self._bounded, "console", self.console.stop)

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
        """A standing job of the daemon. If it ends with an error, that is an alarm at once (published, stack light
        red), not a line in the log at shutdown."""
        task = asyncio.create_task(coro, name=f"rgse-{name}")  # type: ignore[arg-type]

        def ended(t: asyncio.Task[Any]) -> None:
            if not t.cancelled() and t.exception() is not None:
                self.alarms.raise_(f"task_failed_{name}", f"daemon job {name} ended: {t.exception()!r}")

        task.add_done_callback(ended)
        self._tasks.append(task)

    async def _cancel_tasks(self) -> None:
        for t in self._tasks:
            t.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=STOP_TIMEOUT_S)
        for t in self._tasks:
            if t.done() and not t.cancelled() and t.exception() is not None:
                log.error("task %s failed: %r", t.get_name(), t.exception())
        self._tasks.clear()

    async def _stop_controller(self) -> None:
        """End the controller loop (it closes the link), bounded. A connect attempt in flight is cancelled: no run
        uses a link that is not up."""
        task, self._controller_task = self._controller_task, None
        if task is None:
            return
        if self.link.connecting:  # not while the link closes: a cancel there would leave its connections open
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
        await self.light.write("off")
        await self.safety_io.stop()

    # --- the controller link -----------------------------------------------------------------------------------
    async def _link_up(self, krc: Controller) -> None:
        self.engine = self._make_engine(krc)
        if not self.run_active:
            self.light.want("green")
        if not self._resumed:
            self._resumed = True
            try:
                await self.resume_interrupted_campaign()
            except RgseError as exc:
                log.error("could not continue the interrupted calibration campaign: %s", exc)

    async def _link_down(self, lost: str | None) -> None:
        if lost is None:
            await self.admission.stop()  # the run uses this link: end it before the link closes
        else:
            await self.admission.wait_end()  # the interlock monitor trips on the lost link

    def _inputs(self) -> Inputs | None:
        """The safety inputs as the interlock reads them (a fresh view at each call), or None without the module."""
        io = self.safety_io
        if io is None:
            return None
        return lambda: io.inputs

    def _current_inputs(self) -> SafetyInputs | None:
        return self.safety_io.inputs if self.safety_io is not None else None

    def _make_engine(self, krc: Controller) -> RunEngine:
        inputs = self._inputs()
        engine = RunEngine(
            krc,
            checker=static_checker(self.cfg.limits, self.cfg.measurement.payload_lever_max_m, inputs,
                                   require_watchdog=self.cfg.controller.watchdog_required,
                                   payload=mounted_payload(self.cfg), cell=self.cfg.cell),
            monitor=Monitor(krc, inputs=inputs,
                            stale_periods=self.cfg.limits.snapshot_stale_s / DEFAULT_POLL_PERIOD_S,
                            on_unsafe=self.recovery.on_unsafe if self.recovery is not None else None),
            share_dir=self.cfg.controller.share_dir,
        )
        engine.subscribe(self._event)
        engine.subscribe_documents(self._document)
        return engine

    # --- events out ----------------------------------------------------------------------------------------------
    def _event(self, ev: Event) -> None:
        if ev.kind == "state" and ev.data.get("state") == "running":
            self.admission.mark_started(ev.run_id)
        if ev.kind == "confirm":
            self._confirm_data = dict(ev.data)
        if self._on_event is not None:
            self._on_event(ev)
        if self.console is not None:
            self.console.event(ev)
        if self.mqtt is not None:
            if ev.kind == "confirm":
                self.mqtt.publish_prompt(ev.to_json())
                self._prompt_open = True
            elif ev.kind == "state" and self._prompt_open and ev.data.get("state") != "confirm":
                self.mqtt.publish_prompt(None, ev.run_id)  # answered, or the run ended while it waited
                self._prompt_open = False
            if ev.kind == "alarm":
                self.mqtt.publish_alarm(ev.to_json())
            elif ev.run_id is not None and ev.kind != "result":  # a result goes out from the outbox: _document
                self.mqtt.publish_progress(ev.run_id, ev.to_json())
        if ev.kind == "alarm":
            self.light.want("red")
            if ev.data.get("watcher") == "link":  # the interlock tripped on the controller link: the link alarm too
                self.link.lost_during_run(str(ev.data.get("detail") or ev.message))
        elif ev.kind == "state":
            self.light.want_for_state(ev.data.get("state"))

    def _document(self, doc: Document) -> None:
        if isinstance(doc, Result) and self.mqtt is not None:
            self.mqtt.notify_outbox()  # the recorder stored the result with its outbox row: publish it now

    def _publish_alarm(self, doc: dict[str, Any]) -> None:
        if self.mqtt is not None:
            self.mqtt.publish_alarm(doc)
        if doc.get("kind") in ("safety_latch", "left_running_stopped", "run_interrupted"):
            self.light.want("red")

    def _run_failed(self, kind: RunKind, run_id: str | None, error: str) -> None:
        self._publish_alarm({"kind": "run_failed", "run_kind": kind.value, "run_id": run_id,
                             "message": f"{kind} run failed: {error}"})
        self.light.want("red")

    def _run_refused(self, kind: RunKind, reason: str) -> None:
        """A run request answered "no" before anything was recorded or moved: published as such, and the stack light
        is left as it is (red stays the colour of something that happened to the robot or a run)."""
        self._publish_alarm({"kind": "run_refused", "run_kind": kind.value, "reason": reason,
                             "message": f"{kind} run refused: {reason}"})

    # --- runs ----------------------------------------------------------------------------------------------------
    def _start_run(self, kind: RunKind, coro_factory: Callable[[RunEngine, Store], Awaitable[Any]],
                   engine: RunEngine | None = None) -> asyncio.Task[Any]:
        assert self.store is not None
        try:
            self.latch.check()
        except RgseError as exc:
            self.admission.refuse(kind, exc)
            raise
        self._confirm_data = {}
        return self.admission.start(kind, coro_factory, engine=engine if engine is not None else self.engine,
                                    krc=self.krc, store=self.store, connected=self.connected.is_set() and
                                    self.engine is not None, link_error=self.link_error)

    async def start_measurement(self, *, loops: int | None = None, fixture_mass_kg: float | None = None,
                                dry_run: bool = False, identity: dict[str, str] | None = None) -> asyncio.Task[Any]:
        overrides: dict[str, Any] = {"identity": identity} if identity else {}
        if loops is not None:
            overrides["loops"] = loops
        if fixture_mass_kg is not None:
            overrides["fixture_mass_kg"] = fixture_mass_kg
        settings = RunSettings.from_config(self.cfg, **overrides)
        if self.cfg.properties.when == "every_measurement":  # every measurement is a properties run
            return await self.start_properties(settings=settings, dry_run=dry_run)
        inputs = self._inputs()
        dry = self._dry(self.engine) if dry_run and self.engine is not None else None
        return self._start_run(
            RunKind.MEASUREMENT,
            lambda engine, store: run_measurement(engine, store, self.cfg, settings=settings, inputs=inputs),
            engine=dry,
        )

    async def start_properties(self, *, settings: RunSettings | None = None, props: PropertiesSettings | None = None,
                               dry_run: bool = False) -> asyncio.Task[Any]:
        """A mass-properties run (mass, then the CoG poses; :mod:`rgse_daemon.procedures.properties`)."""
        settings = settings or RunSettings.from_config(self.cfg)
        props = props or PropertiesSettings.from_config(self.cfg)
        inputs = self._inputs()
        dry = self._dry(self.engine) if dry_run and self.engine is not None else None
        return self._start_run(
            RunKind.PROPERTIES,
            lambda engine, store: run_properties(engine, store, self.cfg, settings=settings, props=props,
                                                 inputs=inputs),
            engine=dry,
        )

    def _dry(self, engine: RunEngine) -> RunEngine:
        dry = RunEngine(engine.krc, checker=engine.checker, monitor=None, dry_run=True, share_dir=engine.share_dir)
        dry.subscribe(self._event)
        dry.subscribe_documents(self._document)
        return dry

    async def start_calibration(self, *, points: list[CampaignPoint] | None = None, method: str = "auto",
                                run_id: str | None = None, settings: RunSettings | None = None) -> asyncio.Task[Any]:
        inputs = self._inputs()
        return self._start_run(
            RunKind.CALIBRATION,
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
                                            dry_run=cmd.dry_run,
                                            identity=cmd.identity.as_json() if cmd.identity else None)
        kind = self.admission.kind or RunKind.MEASUREMENT  # properties when every measurement is one
        return {"accepted": kind.value, "run_id": await self.admission.started(task), "dry_run": cmd.dry_run}

    async def properties(self, cmd: PropertiesCommand) -> dict[str, Any]:
        overrides: dict[str, Any] = {}
        if cmd.identity is not None and cmd.identity.as_json():
            overrides["identity"] = cmd.identity.as_json()
        if cmd.loops is not None:
            overrides["loops"] = cmd.loops
        if cmd.fixture_mass_kg is not None:
            overrides["fixture_mass_kg"] = cmd.fixture_mass_kg
        fixture = cmd.fixture
        props = PropertiesSettings.from_config(
            self.cfg, scheme=cmd.scheme, loops_per_pose=cmd.loops_per_pose,
            fixture_cog_flange_m=fixture.cog_flange_m if fixture is not None else None,
            dut_origin_flange_m=fixture.dut_origin_flange_m if fixture is not None else None,
            dut_abc_deg=fixture.dut_abc_deg if fixture is not None else None, inertia=cmd.inertia,
            mass_method=cmd.mass_method)
        task = await self.start_properties(settings=RunSettings.from_config(self.cfg, **overrides), props=props,
                                           dry_run=cmd.dry_run)
        return {"accepted": RunKind.PROPERTIES.value, "run_id": await self.admission.started(task),
                "dry_run": cmd.dry_run, "scheme": props.scheme, "inertia": props.inertia,
                "mass_method": props.mass_method}

    async def calibrate(self, cmd: CalibrateCommand) -> dict[str, Any]:
        points = [campaign_point(p) for p in cmd.points] if cmd.points is not None else None
        task = await self.start_calibration(points=points, method=cmd.method or "auto")
        return {"accepted": RunKind.CALIBRATION.value, "run_id": await self.admission.started(task),
                "points": len(points) if points else None}

    @property
    def run_engine(self) -> RunEngine | None:
        """The engine of the run in progress (a dry run has one of its own), None without a run."""
        return self.admission.engine if self.run_active else None

    async def abort(self, cmd: AbortCommand) -> dict[str, Any]:
        engine = self.run_engine
        if engine is None:
            raise RgseError("no run in progress")
        if cmd.run_id is not None and engine.run_id != cmd.run_id:
            now = "a dry run" if engine.dry_run else engine.run_id
            raise RgseError(f"run {cmd.run_id} is not the run in progress ({now})")
        engine.abort(cmd.reason)
        return {"aborting": engine.run_id, "dry_run": engine.dry_run}

    async def confirm(self, cmd: ConfirmCommand) -> dict[str, Any]:
        engine = self.run_engine
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
