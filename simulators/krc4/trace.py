"""KUKA Trace on the simulated KR C4: the ``$TRACE`` variables, their state machine, and the file set it leaves.

Driven exactly as on a real controller (docs/controller.md §5.1)::

    $TRACE.CONFIG[] = "meas.xml"     ; a file in DIR/TRACE (the ".xml" may be left out)
    $TRACE.NAME[]   = "dut_l01"      ; empty: the config's <Basename>
    $TRACE.MODE     = #T_START       ; from a client over the link, or from a KRL program
    ... $TRACE.STATE: #T_END → #T_WAIT → #TRIGGERED → #T_WRITING → #T_END
    $TRACE.MODE     = #T_STOP        ; optional: ends the recording early (shorter files)

Decisions where the public record is silent (said here, tested in ``tests/sim_e2e``):

* **Refusals.** ``#T_START`` is refused *as a write* (a failed write on the link, with code 3 where the message
  type carries one, i.e. #5/#7; a KRL program that writes it stops with a runtime error) when the configuration file
  is missing or invalid (rgse_daemon.trace.config's strict parser: unknown elements, rates other than 1/4/12 ms,
  ``Time`` beyond the buffer of ``buffer_limit_s``), when it names a module other than ``KRCIpo`` /
  ``NextGenDrive#1..6`` or a trigger the simulator does not know, when the trace name is not a usable file name, or
  (code 2) while a trace is still active. ``$TRACE.STATE`` then stays as it was and :attr:`TraceEngine.last_error`
  says why. A real KR C4 shows a message on the smartHMI and does not start (the exact behaviour of the write is
  not documented publicly); refusing the write is the nearest thing a client can observe over the link.
* **Triggers** (the ID-to-event mapping of KUKA's trigger modules is not public; the simulator's choice):
  no ``<Trigger>``, or ``KRCIpo`` ID 1: triggered at once; ``KRCIpo`` ID 2: when a robot program is started (#10
  start/run); ``KRCIpo`` ID 3: when the next motion starts. A KRL program triggers a trace simply by writing
  ``$TRACE.MODE = #T_START`` itself at the right moment. ``#T_STOP`` while waiting ends with no files.
* **Length.** The recording ends ``Time − PreTrigger`` simulated seconds after the trigger, or at ``#T_STOP``. The file
  holds the pre-trigger part actually available (at most ``PreTrigger``, at most the time spent armed) plus the
  recording. Modules at a slower rate than the fastest one are decimated from it (rates are 1/4/12 ms: integer
  ratios).
* **Channels.** Channel IDs are opaque (their names are not public): a ``NextGenDrive#k`` module always records the
  seven drive channels of ``simulators.krc4.physics.CHANNELS``; ``KRCIpo`` records the flange position and the
  override. The samples come from the :class:`TraceSource` (the physics model, see ``sim.py``).
* **Writing.** ``#T_WRITING`` lasts as long as the controller needs to write the files, modelled as
  ``write_rate_bytes_s`` (simulated bytes per second, settable at runtime). The file sets appear one module after
  the other, each file atomically (``tracefiles.write_trace_set``: temporary name, fsync, rename, data before
  header; written in a staging folder beside the share and renamed into ``TRACE``, so that no temporary name is
  ever listed there); ``N_PROG.TXT`` first, holding the selected program's text if there is one. Only then ``#T_END``.
* ``$TRACE.MODE`` keeps the value last written (the trace's end does not write it back).
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import re
import shutil
import tempfile
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Protocol

import numpy as np

from rgse_daemon.durable import fsync_dir
from rgse_daemon.errors import DataError, RgseError, VariableError
from rgse_daemon.link.krlvalue import parse_value
from rgse_daemon.trace.config import TraceConfig, parse_trace_config
from simulators.krc4.files import FileOpError, ShareFiles
from simulators.krc4.tracefiles import write_trace_set
from simulators.krc4.variables import CODE_ACCESS, CODE_ARGUMENT, VariableStore

_log = logging.getLogger(__name__)

#: Interpolation cycle (s, simulated): how often the engine looks at its clock, triggers and the robot's axes.
IPO_PERIOD_S = 0.012
#: Shortest wall-clock sleep between engine ticks (s): keeps scaled-time runs from spinning the CPU.
MIN_TICK_WALL_S = 0.002
#: Default simulated write speed of the controller's disk for trace files (bytes per simulated second).
DEFAULT_WRITE_RATE_BYTES_S = 4e6
#: Longest wall time one file-set write may take before it counts as failed (s).
WRITE_DEADLINE_S = 60.0

IPO_MODULE = "KRCIpo"
DRIVE_MODULES = tuple(f"NextGenDrive#{i}" for i in range(1, 7))

#: Trigger (module, ID) → what fires it; see the module docstring.
TRIGGER_IMMEDIATE = (IPO_MODULE, 1)
TRIGGER_PROGRAM_START = (IPO_MODULE, 2)
TRIGGER_MOTION_START = (IPO_MODULE, 3)
KNOWN_TRIGGERS: dict[tuple[str, int], str] = {
    TRIGGER_IMMEDIATE: "at once",
    TRIGGER_PROGRAM_START: "robot program started",
    TRIGGER_MOTION_START: "motion started",
}

_BAD_NAME = re.compile(r'[\\/:*?"<>|,\x00-\x1f]')

Modules = Mapping[str, Mapping[str, tuple[np.ndarray, str]]]
"""module → channel → (physical values, unit), as ``write_trace_set`` takes them."""


class TraceState(StrEnum):
    """``$TRACE.STATE`` values, in the order a trace passes them."""

    END = "#T_END"
    WAIT = "#T_WAIT"
    TRIGGERED = "#TRIGGERED"
    WRITING = "#T_WRITING"


class SimClock:
    """Simulated time: ``time_scale`` simulated seconds pass per wall-clock second (monotonic)."""

    def __init__(self, time_scale: float) -> None:
        if not (math.isfinite(time_scale) and time_scale > 0.0):
            raise ValueError(f"time_scale must be finite and positive, got {time_scale}")
        self.time_scale = time_scale
        self._origin = time.monotonic()

    def now_s(self) -> float:
        """Simulated seconds since the clock was made."""
        return (time.monotonic() - self._origin) * self.time_scale

    async def tick(self, period_s: float = IPO_PERIOD_S) -> None:
        """Sleep about ``period_s`` simulated seconds (at least :data:`MIN_TICK_WALL_S` wall)."""
        await asyncio.sleep(max(period_s / self.time_scale, MIN_TICK_WALL_S))


class TraceSource(Protocol):
    """Where the samples come from (the simulated robot, see ``sim.py``)."""

    def begin(self, name: str) -> object:
        """Called at the trigger: remember whatever the recording needs (pose, payload, physics state)."""
        ...

    def axes_deg(self) -> tuple[float, ...]:
        """The robot's axes now (deg): sampled every tick for the position channels."""
        ...

    def record(
        self,
        token: object,
        modules: tuple[str, ...],
        n_samples: int,
        period_s: float,
        pre_s: float,
        axes_track: tuple[np.ndarray, np.ndarray],
    ) -> Modules:
        """The samples of ``modules`` (n_samples every period_s, the first pre_s before the trigger).

        ``axes_track`` = (times s relative to the first sample, axes deg (n, 6)) as seen while recording. Called
        in a worker thread, once the recording has ended.
        """
        ...

    def program_text(self) -> str | None:
        """Text of the selected robot program (for ``N_PROG.TXT``), or None."""
        ...


@dataclass(frozen=True)
class TraceRequest:
    """What ``#T_START`` armed: the parsed configuration, the trace name and the file it came from."""

    config: TraceConfig
    name: str
    config_file: str

    @property
    def period_s(self) -> float:
        """The fastest module's sample period (s): the one the samples are taken at."""
        return min(m.period_s for m in self.config.modules)

    @property
    def trigger(self) -> tuple[str, int]:
        t = self.config.trigger
        return TRIGGER_IMMEDIATE if t is None else (t.module_name, t.id)


class TraceEngine:
    """KUKA Trace of the simulated controller; see the module docstring.

    Parameters
    ----------
    store:
        The variables; the engine registers a setter on ``$TRACE.MODE`` and keeps ``$TRACE.STATE``.
    files:
        The share: configurations are read from and file sets written to its ``TRACE`` folder.
    source:
        Gives the samples (:class:`TraceSource`).
    clock:
        Simulated time.
    write_rate_bytes_s:
        Simulated disk speed: how long ``#T_WRITING`` lasts.
    """

    def __init__(
        self,
        store: VariableStore,
        files: ShareFiles,
        source: TraceSource,
        clock: SimClock,
        *,
        write_rate_bytes_s: float = DEFAULT_WRITE_RATE_BYTES_S,
    ) -> None:
        if not write_rate_bytes_s > 0.0:
            raise ValueError("write_rate_bytes_s must be positive")
        self.store = store
        self.files = files
        self.source = source
        self.clock = clock
        self.write_rate_bytes_s = write_rate_bytes_s
        self.last_error: str | None = None
        self.transitions: deque[tuple[str, TraceState]] = deque(maxlen=1000)
        """(trace name, state entered), oldest first: the sequence each trace went through."""
        self.written: dict[str, list[Path]] = {}
        """Trace name → the files of its last file set."""
        self._task: asyncio.Task[None] | None = None
        self._stop = asyncio.Event()
        self._fired: set[tuple[str, int]] = set()
        self._state = TraceState.END
        store.update("$TRACE.STATE", TraceState.END.value)
        store.register_setter("$TRACE.MODE", self._on_mode)

    @property
    def state(self) -> TraceState:
        return self._state

    @property
    def trace_dir(self) -> Path:
        """The controller's ``C:\\KRC\\ROBOTER\\TRACE`` folder on the share."""
        return self.files.resolve("/TRACE")

    def fire(self, trigger: tuple[str, int]) -> None:
        """An event that may trigger an armed trace (``TRIGGER_PROGRAM_START``, ``TRIGGER_MOTION_START``)."""
        if self._state is TraceState.WAIT:
            self._fired.add(trigger)

    async def aclose(self, timeout_s: float = 5.0) -> None:
        """End a running trace task (no files written if cut short), at most ``timeout_s``."""
        task, self._task = self._task, None
        if task is None or task.done():
            return
        task.cancel()
        async with asyncio.timeout(timeout_s):
            await asyncio.gather(task, return_exceptions=True)

    # --- $TRACE.MODE --------------------------------------------------------------------------------------------
    def _on_mode(self, value: str) -> None:
        mode = value.strip().upper()
        if mode == "#T_STOP":
            self._stop.set()  # ends a recording early; no effect when idle or writing
            return
        if self._state is not TraceState.END:
            self.last_error = f"#T_START refused: a trace is active ({self._state.value})"
            raise VariableError("$TRACE.MODE", self.last_error, CODE_ACCESS)
        request = self._prepare()
        self._stop = asyncio.Event()
        self._fired = set()
        self.last_error = None
        self._enter(request.name, TraceState.WAIT)
        self._task = asyncio.get_running_loop().create_task(self._run(request), name=f"trace:{request.name}")

    def _prepare(self) -> TraceRequest:
        """Load and check what ``#T_START`` is to start; VariableError (code 3) says why not."""
        cfg_name = self._text("$TRACE.CONFIG[]")
        try:
            if not cfg_name or _BAD_NAME.search(cfg_name):
                raise DataError(f"$TRACE.CONFIG[] {cfg_name!r} is not a configuration file name")
            file_name = cfg_name if cfg_name.lower().endswith(".xml") else cfg_name + ".xml"
            try:
                raw = self.files.load(f"/TRACE/{file_name}")
            except FileOpError as exc:
                raise DataError(f"trace configuration {file_name} not found in TRACE") from exc
            config = parse_trace_config(raw.decode("utf-8", "replace"), file_name)
            unknown = [m.name for m in config.modules if m.name != IPO_MODULE and m.name not in DRIVE_MODULES]
            if unknown:
                raise DataError(f"{file_name}: module(s) {', '.join(unknown)} not on this controller")
            request = TraceRequest(config, self._text("$TRACE.NAME[]") or config.basename, file_name)
            if request.trigger not in KNOWN_TRIGGERS:
                raise DataError(f"{file_name}: trigger {request.trigger[0]} ID {request.trigger[1]} is not simulated")
            if _BAD_NAME.search(request.name) or request.name.strip() != request.name:
                raise DataError(f"trace name {request.name!r} is not usable as a file name")
        except DataError as exc:
            self.last_error = str(exc)
            raise VariableError("$TRACE.MODE", f"#T_START refused: {exc}", CODE_ARGUMENT) from exc
        return request

    def _text(self, name: str) -> str:
        value = parse_value(self.store.read(name))
        return value.strip() if isinstance(value, str) else ""

    def _enter(self, name: str, state: TraceState) -> None:
        self._state = state
        self.store.update("$TRACE.STATE", state.value)
        self.transitions.append((name, state))

    # --- one trace ----------------------------------------------------------------------------------------------
    async def _run(self, request: TraceRequest) -> None:
        try:
            await self._record_and_write(request)
        except RgseError as exc:
            self.last_error = str(exc)
            _log.error("trace %s failed: %s", request.name, exc)
        except (OSError, ValueError, TimeoutError) as exc:
            self.last_error = f"{type(exc).__name__}: {exc}"
            _log.error("trace %s failed: %s", request.name, self.last_error)
        except Exception as exc:  # a simulator bug must not kill the task silently; the trace still ends
            self.last_error = f"internal error: {exc!r}"
            _log.exception("trace %s failed", request.name)
        finally:
            self._enter(request.name, TraceState.END)

    async def _record_and_write(self, request: TraceRequest) -> None:
        cfg = request.config
        armed_s = self.clock.now_s()
        while request.trigger != TRIGGER_IMMEDIATE and request.trigger not in self._fired:
            if self._stop.is_set():
                return  # stopped before the trigger: nothing recorded
            await self.clock.tick()
        trigger_s = self.clock.now_s()
        pre_s = min(cfg.pretrigger_s, trigger_s - armed_s)
        token = self.source.begin(request.name)
        self._enter(request.name, TraceState.TRIGGERED)
        record_s = cfg.time_s - cfg.pretrigger_s
        times, axes = [0.0], [self.source.axes_deg()]
        while not self._stop.is_set():
            elapsed = self.clock.now_s() - trigger_s
            if elapsed >= record_s:
                elapsed = record_s
                break
            times.append(elapsed)
            axes.append(self.source.axes_deg())
            await self.clock.tick()
        else:
            elapsed = min(self.clock.now_s() - trigger_s, record_s)
        self._enter(request.name, TraceState.WRITING)
        period_s = request.period_s
        n_samples = max(1, round((pre_s + elapsed) / period_s))
        track = (np.asarray(times) + pre_s, np.asarray(axes, dtype=float))
        names = tuple(m.name for m in cfg.modules)
        # in a worker thread: the samples of a long moving trace are a second or more of numerics, and a real
        # controller's trace does not hold up its C3 Bridge server (the daemon's interlock reads it at 20 Hz)
        samples = await asyncio.to_thread(self.source.record, token, names, n_samples, period_s, pre_s, track)
        await self._write(request, samples, period_s)

    async def _write(self, request: TraceRequest, samples: Modules, period_s: float) -> None:
        """Write the file set module by module, pacing by the simulated disk speed; each file atomically."""
        directory = self.trace_dir
        prog_text = self.source.program_text()
        written: list[Path] = []
        async with asyncio.timeout(WRITE_DEADLINE_S):
            staging = await asyncio.to_thread(_make_staging, self.files.root.parent, directory)
        try:
            for module in request.config.modules:
                step = round(module.period_s / period_s)
                channels = {ch: (np.asarray(v)[::step], unit) for ch, (v, unit) in samples[module.name].items()}
                n_bytes = sum(v.nbytes for v, _ in channels.values())
                await asyncio.sleep(n_bytes / self.write_rate_bytes_s / self.clock.time_scale)
                async with asyncio.timeout(WRITE_DEADLINE_S):
                    written += await asyncio.to_thread(
                        _write_module,
                        staging,
                        directory,
                        request.name,
                        module.period_s,
                        {module.name: channels},
                        prog_text if not written else None,
                    )
        finally:
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)
        self.written[request.name] = written


def _make_staging(parent: Path, directory: Path) -> Path | None:
    """A private folder beside the share (same file system as ``directory``) to write trace files in before they
    are renamed into ``TRACE``: the folder then never shows a temporary name. None if that is not possible (the
    files are then written in ``TRACE`` itself, still atomically, via hidden temporary names)."""
    directory.mkdir(parents=True, exist_ok=True)
    try:
        staging = Path(tempfile.mkdtemp(prefix=".krc4-trace-staging-", dir=parent))
    except OSError:
        return None
    if staging.stat().st_dev != directory.stat().st_dev:
        shutil.rmtree(staging, ignore_errors=True)
        return None
    return staging


def _write_module(
    staging: Path | None,
    directory: Path,
    name: str,
    period_s: float,
    modules: Modules,
    prog_text: str | None,
) -> list[Path]:
    """Write one module's files (and ``N_PROG.TXT`` if given) into ``directory``; their final paths.

    With a staging folder, every file is complete there first and then renamed into ``directory`` in the order
    ``write_trace_set`` wrote them (data, .trc, then the .dat header).
    """
    if staging is None:
        return write_trace_set(directory, name, period_s, modules, prog_text=prog_text)
    final = []
    for path in write_trace_set(staging, name, period_s, modules, prog_text=prog_text):
        target = directory / path.name
        os.replace(path, target)
        final.append(target)
    fsync_dir(directory)
    return final
