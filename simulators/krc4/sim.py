"""The assembled simulated KR C4: variables, KRL interpreter, physics, KUKA Trace and the C3 Bridge server as one.

::

    async with SimulatedKrc4(share_dir, scenario=None, seed=0, time_scale=100.0, host="127.0.0.1", port=0) as sim:
        sim.port                          # connect rgse_daemon.controller.Controller here
        sim.mount(dut_payload(100.0, (0.0, 0.0, 0.3)))   # what the operator bolts onto the flange
        sim.set_enabling_switch(False)    # T1 operator: release = STOP 2
        sim.truth                         # physics.TraceTruth of the last trace (sim.truths[name] per trace)

``rgse sim`` runs ``await sim.serve_forever()`` (until cancelled or :meth:`SimulatedKrc4.close`).

How the parts meet:

* **Programs** (C3 Bridge #10) go to :class:`~simulators.krc4.krl.KrlInterpreter`, loading ``.src``/``.dat`` from the
  share. Starting a program fires the trace trigger ``KRCIpo`` 2, every motion start ``KRCIpo`` 3.
* **Motions heat the motors and restart the settling clock**: at the end of every motion (including one cut short
  by a stop) the physics gets ``RobotModel.move(from, to, duration)``. The paper's brake-release move (A3 and A5 the
  same angle away and back) is thus two such moves: no special recognition is needed, its effect on the estimate
  (approach direction, release transient and settling restarting at the last move's end, heating) follows from
  the moves themselves. Between motions the physics holds (drives on, ``$PERI_RDY``) or cools (drives off).
* **Live variables** are computed on read: ``$TORQUE_AXIS_ACT[i]`` is the physics' noise-free, cold, settled
  estimate at the current pose with the mounted payload while the drives are on, 0 while they are off (brakes
  hold the load); ``$CURR_ACT[i]`` is that torque through k_t · gear ratio (A); ``$MOT_TEMP[i]`` the winding
  temperature (K); ``$BRAKE_SIG`` all ones while the drives are on. ``$AXIS_ACT``/``$AXIS_ACT_MEAS``/``$POS_ACT``
  (forward kinematics) are kept by the interpreter. Noise, drift and transients show only in traces.
* **Traces** (:mod:`simulators.krc4.trace`) sample the physics for the pose and payload at the trigger, with the
  physics state (temperatures, time since the last motion, approach directions) of that moment. If the robot
  moves during a trace, every sample follows the planned motions exactly (:class:`~simulators.krc4.motion.
  MotionHistory`, in the simulator's clock): positions from the profiles, ``Istmoment`` from the rigid-body
  dynamics plus friction through the error model (:mod:`simulators.krc4.dynamics`, whose docstring holds the
  contract). ``$TORQUE_AXIS_ACT[i]`` read during a motion is the noise-free dynamic reading.
"""

from __future__ import annotations

import asyncio
import copy
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import robots
from rgse_daemon.errors import ConfigError
from rgse_daemon.krl.ast import Decl
from rgse_daemon.krl.parser import parse_dat
from simulators.krc4.dynamics import SERVO_LAG_S, RobotDynamics, dynamic_reading_nm, sample_motion_trace
from simulators.krc4.krl import KrlInterpreter, MotionEvent, ProgramLoader, share_loader
from simulators.krc4.motion import MotionHistory, MotionSamples, axis_lines_batched
from simulators.krc4.physics import CHANNEL_UNITS, CHANNELS, Payload, RobotModel, RobotState, TraceTruth
from simulators.krc4.scenario import Scenario, load_scenario, scenario_for, scenario_from_mapping
from simulators.krc4.server import KrcServer, ServerConfig
from simulators.krc4.trace import (
    DRIVE_MODULES,
    IPO_MODULE,
    TRIGGER_MOTION_START,
    TRIGGER_PROGRAM_START,
    Modules,
    SimClock,
    TraceEngine,
)
from simulators.krc4.variables import INTERPRETER_ROBOT, Kind, ProState, VariableStore, module_name

_log = logging.getLogger(__name__)

MODES = ("T1", "T2", "AUT", "EX")
#: Largest time scale accepted (simulated s per wall s), as ``rgse sim --time-scale``.
MAX_TIME_SCALE = 1000.0


@dataclass(frozen=True)
class _Snapshot:
    """The robot at a trace's trigger: what its samples are computed from."""

    name: str
    q_deg: np.ndarray
    payload: Payload
    state: RobotState
    moves_before: int
    t_s: float  # simulated clock at the trigger


class _ProgramControl:
    """The ProgramHost the server drives: the interpreter, plus the trace trigger 'robot program started'."""

    def __init__(self, sim: SimulatedKrc4) -> None:
        self._sim = sim
        self._interp = sim.interpreter

    def select(self, name: str, params: str, force: bool) -> None:
        self._interp.select(name, params, force)

    def run(self, name: str, params: str, force: bool) -> None:
        self._sim._sync_physics()  # the time before the start passed with the drives as they were
        self._interp.run(name, params, force)
        self._sim.trace.fire(TRIGGER_PROGRAM_START)

    def reset(self, interpreter: int) -> None:
        self._interp.reset(interpreter)

    def start(self, interpreter: int) -> None:
        self._sim._sync_physics()
        self._interp.start(interpreter)
        if interpreter == INTERPRETER_ROBOT:
            self._sim.trace.fire(TRIGGER_PROGRAM_START)

    def stop(self, interpreter: int) -> None:
        self._interp.stop(interpreter)

    def cancel(self, interpreter: int) -> None:
        self._interp.cancel(interpreter)


def _scenario(scenario: Scenario | Path | str | Mapping[str, Any] | None) -> Scenario | None:
    if scenario is None or isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, Mapping):
        return scenario_from_mapping(dict(scenario))
    return load_scenario(scenario)


class SimulatedKrc4:
    """One simulated KR C4 with an arm of ``rgse_daemon/robots/`` (the scenario's ``robot``; default the KR 500 R2830)
    on a TCP port; see the module docstring.

    Parameters
    ----------
    share_dir:
        The controller's ``roboter`` share (programs in ``R1/PROGRAM``, traces in ``TRACE``); a temporary
        directory if ``None``.
    scenario:
        The physics' error sources: a :class:`Scenario`, a TOML path, a parsed TOML table, or ``None`` for
        ``scenarios/default.toml``. Invalid → :class:`ConfigError`.
    seed:
        Seed of the physics' random numbers (noise, spikes): same seed and same calls, same traces.
    time_scale:
        Simulated seconds per wall second (0 < x ≤ 1000).
    host, port:
        Where the C3 Bridge server listens (port 0: any free port, see :attr:`port`).
    latency_s:
        Service time of every request (a real KR C4: ≈ 2 ms); tests use 0.
    """

    def __init__(
        self,
        share_dir: Path | str | None = None,
        scenario: Scenario | Path | str | Mapping[str, Any] | None = None,
        seed: int | None = 0,
        time_scale: float = 100.0,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        latency_s: float = 0.002,
    ) -> None:
        if not 0.0 < time_scale <= MAX_TIME_SCALE:
            raise ConfigError(f"time_scale {time_scale} must be > 0 and <= {MAX_TIME_SCALE:g}")
        # the scenario names the simulated arm; without one, the active robot's default scenario. The arm is made
        # the process's active robot: the kinematics, the motion limits and the load set are its from here on
        resolved = _scenario(scenario)
        if resolved is None:
            resolved = scenario_for(robots.active().key)
        robots.activate(resolved.robot)
        self.model = RobotModel(resolved, seed=seed)
        self.dynamics = RobotDynamics(self.model.scenario, robot=self.model.robot)
        self.history = MotionHistory()
        """The planned motions in the simulator's clock (what the dynamics of a moving trace follow)."""
        self.clock = SimClock(time_scale)
        self.store = VariableStore()
        behaviour = {k: v for k, v in self.model.scenario.server.model_dump().items() if v is not None}
        self.server = KrcServer(
            ServerConfig(host=host, port=port, latency_s=latency_s, **behaviour),
            Path(share_dir) if share_dir is not None else None,
            store=self.store,
        )
        self.files = self.server.files
        for folder in ("/TRACE", "KRC:\\R1\\PROGRAM"):  # every KR C4 has them
            self.files.resolve(folder).mkdir(parents=True, exist_ok=True)
        self._selected: tuple[str, str] | None = None  # (module, .src text) of the last loaded program
        self.interpreter = KrlInterpreter(self.store, self._loader(share_loader(self.files)), time_scale=time_scale)
        self.server.program_host = _ProgramControl(self)
        self.interpreter.add_motion_listener(self._on_motion)
        self.trace = TraceEngine(self.store, self.files, self, self.clock)
        self.payload = Payload()
        self.truths: dict[str, TraceTruth] = {}
        self.moves = 0
        self._motion_start: MotionEvent | None = None
        self._move_anchor = (0.0, 0.0)  # (clock, interpreter time) at the start of the current move
        self._physics_s = self.clock.now_s()
        self._static_cache: tuple[Payload, tuple[object, ...], np.ndarray] | None = None
        self._register_getters()

    # --- lifecycle ----------------------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        """The TCP port the server listens on (after :meth:`start`)."""
        return self.server.port

    @property
    def share_dir(self) -> Path:
        return self.files.root

    async def start(self) -> None:
        """Listen on the configured host and port."""
        await self.server.start()

    async def close(self) -> None:
        """Stop the program and trace tasks, then the server (each bounded)."""
        try:
            await self.trace.aclose()
            await self.interpreter.aclose()
        finally:
            await self.server.close()

    async def serve_forever(self) -> None:
        """Serve until cancelled or :meth:`close` is called; closes everything on the way out."""
        try:
            await self.server.serve_forever()
        finally:
            await asyncio.shield(self.close())

    async def __aenter__(self) -> SimulatedKrc4:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- the lab and the operator -------------------------------------------------------------------------------
    def install_globals(self, dat_text: str, file: str = "rgse_globals.dat") -> list[str]:
        """What installing a DEFDAT with ``DECL GLOBAL`` variables once on the controller does (krl/README.md):
        its globals exist from then on, so the daemon can read and write them over the link. Returns their names."""
        data = parse_dat(dat_text, file)
        kinds = {"INT": Kind.INT, "REAL": Kind.REAL, "BOOL": Kind.BOOL}
        defaults = {"INT": "0", "REAL": "0.0", "BOOL": "FALSE"}
        names = []
        for decl in data.decls:
            if not (isinstance(decl, Decl) and decl.is_global):
                continue
            if decl.type_name not in kinds:
                raise ConfigError(f"{file}: global {decl.names[0].name} of type {decl.type_name} is not supported")
            for dn in decl.names:
                if not self.store.is_declared(dn.name):
                    self.store.declare_global(dn.name, kinds[decl.type_name], defaults[decl.type_name])
                names.append(dn.name)
        return names

    def mount(self, payload: Payload) -> None:
        """What is bolted onto the flange from now on (builders in ``simulators.krc4.physics``); every mounting seats
        a little differently (:meth:`RobotModel.new_mounting`)."""
        self.payload = payload
        self.model.new_mounting()

    @property
    def truth(self) -> TraceTruth | None:
        """Ground truth of the last trace: true mass, CoG, torques and every error term."""
        return self.model.last_truth

    def set_enabling_switch(self, held: bool) -> None:
        """Hold or release the smartPAD enabling switch (T1/T2: release = STOP 2, ``$STOPMESS`` TRUE)."""
        self._sync_physics()
        self.interpreter.set_enabling_switch(held)

    def set_start_key(self, pressed: bool) -> None:
        """Press or release the start key (T1/T2: release stops the program)."""
        self.interpreter.set_start_key(pressed)

    def acknowledge(self) -> None:
        """Acknowledge the stop message on the smartPAD (``$STOPMESS`` FALSE)."""
        self.interpreter.acknowledge()

    def set_mode(self, mode: str) -> None:
        """Turn the mode selector to ``T1``/``T2``/``AUT``/``EX`` (``$MODE_OP``); a running program stops."""
        m = mode.strip().upper().lstrip("#")
        if m not in MODES:
            raise ValueError(f"mode {mode!r} is not one of {', '.join(MODES)}")
        if self.interpreter.state is ProState.ACTIVE:
            self.interpreter.stop(INTERPRETER_ROBOT)
        self.store.update("$MODE_OP", f"#{m}")

    # --- physics bookkeeping ------------------------------------------------------------------------------------
    def _drives_on(self) -> bool:
        return self.store.read("$PERI_RDY").strip().upper() == "TRUE"

    def _sync_physics(self) -> None:
        """Let the physics stand (holding or braked) up to now; motions account for their own time."""
        now = self.clock.now_s()
        dt = now - self._physics_s
        self._physics_s = now
        if dt <= 0.0 or self._motion_start is not None:
            return
        if self._drives_on():
            self.model.hold(dt)
        else:
            self.model.apply_brakes(dt)

    def _on_motion(self, event: MotionEvent) -> None:
        if event.move is not None and event.kind == "start":
            self._move_anchor = (self.clock.now_s(), event.t_s)
            self.history.add(self._move_anchor[0], event.move)
        if event.kind == "brake":
            if event.move is not None:
                # the ramp starts where the interpreter was on its move: same time into the move, in the clock
                clock_t0, interp_t0 = self._move_anchor
                self.history.add(clock_t0 + max(0.0, event.t_s - interp_t0), event.move)
            return
        if event.kind == "start":
            self._sync_physics()
            self._motion_start = event
            self.trace.fire(TRIGGER_MOTION_START)
            return
        start, self._motion_start = self._motion_start, None
        if start is None:
            return
        self.model.move(start.q_deg, event.q_deg, max(0.0, event.t_s - start.t_s))
        self.moves += 1
        self._physics_s = self.clock.now_s()

    def _loader(self, load: ProgramLoader) -> ProgramLoader:
        """Remember the text of the program the interpreter loads (for the trace's ``N_PROG.TXT``)."""

        def remembering(name: str) -> tuple[str, str, str | None]:
            mod, src, dat = load(name)
            self._selected = (mod, src)
            return mod, src, dat

        return remembering

    # --- live variables -----------------------------------------------------------------------------------------
    def _q(self) -> np.ndarray:
        return np.asarray(self.interpreter.axes_deg, dtype=float)

    def _torques_nm(self) -> np.ndarray:
        if not self._drives_on():
            return np.zeros(6)
        now = self.clock.now_s()
        if self.history.active(now) is not None:
            m = self.history.sample(np.array([now - SERVO_LAG_S]))  # the arm, following the command
            return dynamic_reading_nm(self.model, self.dynamics, m.q_deg[0], m.qd_deg_s[0], m.qdd_deg_s2[0],
                                      self.payload)
        return self._static_reading_nm()

    def _static_reading_nm(self) -> np.ndarray:
        """The settled reading at the current pose: a function of the pose, the payload and this mounting only, so
        computed once for the six ``$TORQUE_AXIS_ACT[i]`` of a snapshot (and each poll while nothing changes)."""
        model = self.model
        q = self._q()
        key = (q.tobytes(), model.mount_offset_nm.tobytes(), model.mount_cog_shift_m, model.residual_nm.tobytes())
        cached = self._static_cache
        if cached is None or cached[0] is not self.payload or cached[1] != key:  # a payload is immutable
            cached = self._static_cache = (self.payload, key, model.static_reading_nm(q, self.payload))
        return cached[2].copy()

    def _register_getters(self) -> None:
        axes = [self.model.scenario.axis(i) for i in range(1, 7)]
        kt_ratio = [a.torque_constant_nm_a * a.gear_ratio for a in axes]

        def torque(i: int) -> str:
            return repr(round(float(self._torques_nm()[i]), 3))

        def current(i: int) -> str:
            return repr(round(float(self._torques_nm()[i]) / kt_ratio[i], 4))

        def temperature(i: int) -> str:
            self._sync_physics()
            return str(round(float(self.model.state.motor_temp_k[i])))

        for i in range(6):
            self.store.register_getter(f"$TORQUE_AXIS_ACT[{i + 1}]", lambda i=i: torque(i))
            self.store.register_getter(f"$CURR_ACT[{i + 1}]", lambda i=i: current(i))
            self.store.register_getter(f"$MOT_TEMP[{i + 1}]", lambda i=i: temperature(i))
        self.store.register_getter("$BRAKE_SIG", lambda: "B111111" if self._drives_on() else "B000000")

    # --- TraceSource --------------------------------------------------------------------------------------------
    def begin(self, name: str) -> object:
        self._sync_physics()
        return _Snapshot(name, self._q().copy(), self.payload, copy.deepcopy(self.model.state), self.moves,
                         self.clock.now_s())

    def axes_deg(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self._q())

    def record(
        self,
        token: object,
        modules: tuple[str, ...],
        n_samples: int,
        period_s: float,
        pre_s: float,
        axes_track: tuple[np.ndarray, np.ndarray],
    ) -> Modules:
        assert isinstance(token, _Snapshot)
        self._sync_physics()
        t_s = np.arange(n_samples) * period_s
        motion = self.history.sample(token.t_s - pre_s + t_s)
        stopped_inside = np.isfinite(motion.t_since_stop_s) & (motion.t_since_stop_s <= t_s)
        if motion.moving.any() or stopped_inside.any():
            return self._record_motion(token, modules, n_samples, period_s, pre_s, motion)
        moved = self.moves != token.moves_before
        state_now = copy.deepcopy(self.model.state)
        drives = self.model.sample_trace(
            token.q_deg,
            token.payload,
            n_samples,
            period_s,
            t_since_release_s=max(0.0, token.state.t_since_release_s - pre_s),
            motor_temp_k=token.state.motor_temp_k,
            last_approach_sign=token.state.last_approach_sign,
        )
        if moved:  # the motion's effect on the state wins over the trace's standing still
            self.model.state = state_now
        self._physics_s = self.clock.now_s()
        truth = self.model.last_truth
        assert truth is not None
        self.truths[token.name] = truth
        track_t, track_q = axes_track
        q_t = np.column_stack([np.interp(t_s, track_t, track_q[:, i]) for i in range(6)])  # (n, 6)
        out: dict[str, dict[str, tuple[np.ndarray, str]]] = {}
        for k, module in enumerate(DRIVE_MODULES, start=1):
            if module not in modules:
                continue
            ch = drives[k]
            jitter = ch["Istposition"] - ch["Sollposition"]
            ch = {**ch, "Sollposition": q_t[:, k - 1], "Istposition": q_t[:, k - 1] + jitter}
            out[module] = {name: (ch[name], CHANNEL_UNITS[name]) for name in CHANNELS}
        if IPO_MODULE in modules:
            out[IPO_MODULE] = self._ipo_channels(q_t)
        return out

    def _ipo_channels(self, q_t: np.ndarray) -> dict[str, tuple[np.ndarray, str]]:
        """The interpolator's channels for the axes ``q_t`` (n, 6): flange position and override."""
        xyz = axis_lines_batched(q_t)[0][:, 5] * 1000.0  # the flange's origin, mm
        override = float(self.store.read("$OV_PRO"))
        return {
            "Sollposition X": (xyz[:, 0], "mm"),
            "Sollposition Y": (xyz[:, 1], "mm"),
            "Sollposition Z": (xyz[:, 2], "mm"),
            "Programmoverride": (np.full(len(q_t), override), "%"),
        }

    def _record_motion(self, token: _Snapshot, modules: tuple[str, ...], n_samples: int, period_s: float,
                       pre_s: float, motion: MotionSamples) -> Modules:
        """A trace during which the robot moved: every sample from the planned motions and the dynamics (the arm
        follows the command ``SERVO_LAG_S`` late)."""
        times = token.t_s - pre_s + np.arange(n_samples) * period_s
        drives = sample_motion_trace(
            self.model,
            self.dynamics,
            token.payload,
            motion,
            period_s,
            t_since_release_s=max(0.0, token.state.t_since_release_s - pre_s),
            motor_temp_k=token.state.motor_temp_k,
            last_approach_sign=token.state.last_approach_sign,
            actual=self.history.sample(times - SERVO_LAG_S),
        )
        truth = self.model.last_truth
        assert truth is not None
        self.truths[token.name] = truth
        out: dict[str, dict[str, tuple[np.ndarray, str]]] = {}
        for k, module in enumerate(DRIVE_MODULES, start=1):
            if module in modules:
                out[module] = {name: (drives[k][name], CHANNEL_UNITS[name]) for name in CHANNELS}
        if IPO_MODULE in modules:
            out[IPO_MODULE] = self._ipo_channels(motion.q_deg)
        return out

    def program_text(self) -> str | None:
        selected = module_name(self.store.read("$PRO_NAME1[]").strip().strip('"'))
        if self._selected is None or not selected or selected != self._selected[0]:
            return None
        return self._selected[1]
