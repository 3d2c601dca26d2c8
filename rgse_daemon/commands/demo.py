"""``rgse demo``: the whole story on the built-in simulated KR C4, through the daemon's real code paths.

A simulated KR 500 R2830, or with ``--robot kr10r1440`` the paper's subscale KR 10 R1440-2 (C3 Bridge server on a
loopback port, KRL interpreter, physics with the paper's error sources, KUKA Trace) runs in scaled time. The daemon
(:class:`rgse_daemon.app.Daemon`: network link, KRL rendering and the interlock's static check, program
push/select/start, runtime monitor, trace start and pull over the link's file operations, archive, pipeline, store,
outbox) then

1. runs a calibration campaign (the zero point, stacks of calibration bodies, torque points with the test adapter);
   the simulated operator mounts each load when the daemon asks for it and confirms;
   — and the torsional points (calibration bodies on a bracket off the flange axis, in every pose of the CoG
   scheme) that calibrate A3..A6 for torque;
2. measures a DuT in line in a mass-properties run: a ReFEx-like wing box (107.3 kg, its CoG off the flange axis;
   on a 10.288 kg fixture), first its mass (10 loops in the measurement pose), then its centre of gravity in the
   CoG poses of the ``lever`` scheme on the KR 500 (the paper's poses and the multi-pose mass's raised pose; the mass
   method ``auto`` chosen before the run by predicted U per robot minute; the KR 10 has no lever poses: ``paper``;
   the ``full`` scheme's eight poses would take four times the robot time in the campaign and the run, see README
   "Centre of gravity"); with ``--inertia`` then its inertia tensor: the DuT's
   excitation, the simulated operator takes the DuT off when asked, the tare's excitation.

It prints true vs measured mass and CoG with the expanded uncertainty U (k = 2), and timings: robot time (what the
robot needs: motion, settling, recording — converted to real time) and daemon overhead (pulling, archiving,
computing).

Progress goes to stderr: on a terminal as two bars (the campaign's points × loops, the measurement's loops with their
estimated time left) under the operator prompts, alarms and results; elsewhere as one plain line per event.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol
from urllib.parse import urlsplit

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.app import Daemon
from rgse_daemon.commands import add_json
from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.errors import ConfigError, RgseError
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.pipeline.cog import cog_poses
from rgse_daemon.procedures.calibration import CampaignPoint, table1_points, torque_point, torsional_points
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.inertia import TARE_PROMPT
from rgse_daemon.procedures.properties import PropertiesSettings
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.progress import new_progress, running, terminal_console
from rgse_daemon.robots import RobotModel
from simulators.krc4 import physics as ph
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.process import SimProcess

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress

log = logging.getLogger(__name__)

SEED = 2024
#: Simulated seconds per wall second: a ~20 simulated minutes campaign + run in well under two minutes.
TIME_SCALE = 200.0
#: The CoG poses of the KR 500 demo's properties run (and of its torsional calibration points): the paper's poses and
#: the multi-pose mass's raised lever pose (issue #35), so that the run offers both masses; a robot without lever poses
#: (the KR 10) measures the paper's (:func:`cog_scheme`).
COG_SCHEME = "lever"


def cog_scheme(robot: RobotModel) -> str:
    """The demo's CoG scheme on ``robot``: ``lever`` where it has the multi-pose mass's lever poses, else ``paper``."""
    return COG_SCHEME if robot.multipose_a3_deg else "paper"


def mass_method(robot: RobotModel) -> str:
    """The demo's mass method: ``auto`` (chosen before the run by predicted U per robot minute) where the robot has
    lever poses, else the paper's ``single`` pose."""
    return "auto" if robot.multipose_a3_deg else "single"
#: The stacks of the shortened Table 1 campaign, and which of the robot's torsional points it measures (two to six
#: bodies at both signs of x and y, so that the A3..A6 payload torques span the DuT's in both poses).
CAMPAIGN_BODIES = (0, 1, 2, 3, 5, 7, 8, 10)
TORSIONAL_INDICES = (0, 2, 3, 4)
#: The demo's DuT on each robot (a DuT sized for the arm) and the farthest point of fixture + DuT from the flange.
DEMO_DUTS: dict[str, tuple[Callable[[], ph.AsymmetricDut], float]] = {
    "kr500r2830": (ph.refex_wing_box, 1.0),  # the paper's in-line run (Table 2): ReFEx wing box on its fixture
    "kr10r1440": (ph.subscale_box, 0.35),
}
#: Bodies on the test adapter at each of the robot's torque levers (None: its ``torque_body_count``), where the
#: demo's DuT needs a calibrated configuration near it (pipeline/envelope.py, ``POINT_INSIDE``). The KR 10's 4.6 kg box
#: on its fixture (5.1 kg about 0.2 m in front of A5) lies between the mass stack and the 8-body torque rows, about
#: 15 % of the torque range from either: its middle torque point carries 6 bodies (5.2 kg at 0.18 m), as a lab would
#: plan a campaign around its DuT (``rgse plan``).
DEMO_TORQUE_BODIES: dict[str, tuple[int | None, ...]] = {"kr10r1440": (None, 6, None)}


@dataclass(frozen=True)
class DemoSetup:
    """What the demo runs on one robot: the robot, the name it is stored under, the DuT, and the campaign."""

    robot: RobotModel
    name: str
    dut: ph.AsymmetricDut
    fixture_mass_kg: float
    payload_lever_max_m: float
    campaign: list[CampaignPoint]

    @property
    def dut_mass_kg(self) -> float:
        return self.dut.mass_kg


def demo_setup(robot_key: str = robots.DEFAULT_KEY) -> DemoSetup:
    """The demo on ``robot_key`` (made the active robot while building it: the load set is the robot's).

    The campaign: a shortened Table 1 (zero, seven stacks, the robot's torque-based points, with
    :data:`DEMO_TORQUE_BODIES` where the DuT needs a point near it), then the bare MPA and
    four loads on the torsional bracket in every CoG pose. Every point is a new mounting with its own offsets (Table
    1's scatter): more points, fewer loops each, give the calibration's reproducibility and curve more to rest on than
    more loops of the same mounting."""
    robot = robots.get(robot_key)
    if robot.key not in DEMO_DUTS:
        raise ConfigError(f"--robot {robot_key}: the demo has no DuT for {robot.title}")
    previous = robots.activate(robot)
    try:
        make_dut, lever_m = DEMO_DUTS[robot.key]
        loads = robot.calibration
        torsional = tuple(loads.torsional_points[i] for i in TORSIONAL_INDICES)
        bodies = DEMO_TORQUE_BODIES.get(robot.key, (None,) * len(loads.torque_levers_a5_m))
        torque = [torque_point(lever, n) for lever, n in zip(loads.torque_levers_a5_m, bodies, strict=True)]
        campaign = [*table1_points(n_bodies=CAMPAIGN_BODIES, torque_levers_a5_m=()), *torque,
                    *torsional_points(cog_scheme(robot), torsional)]
        return DemoSetup(robot, f"{robot.title.replace(' ', '')}-SIM", make_dut(), loads.fixture_mass_kg, lever_m,
                         campaign)
    finally:
        robots.activate(previous)


#: The KR 500 demo's figures under their former names (bench/soak.py imports them).
_KR500_DEMO = demo_setup()
ROBOT = _KR500_DEMO.name
DUT = _KR500_DEMO.dut
DUT_MASS_KG = DUT.mass_kg
FIXTURE_MASS_KG = _KR500_DEMO.fixture_mass_kg
CAMPAIGN = _KR500_DEMO.campaign
CAMPAIGN_LOOPS = 2
SETTLE_S = 4.0
MEASUREMENT_LOOPS = 10
#: Loops in each CoG pose of the properties run (after its MEASUREMENT_LOOPS mass loops).
PROPERTIES_LOOPS_PER_POSE = 2
DEADLINE_S = 600.0
#: The simulated controller's file work (bytes per wall second): a real C3 Bridge's ~100 kB/s scaled like the
#: robot's time, as everything the controller does. At the unscaled rate a loop's pull (3.3 s) outlasted its trace
#: (12 s of robot time, 0.06 s at 200x): the demo waited on pulls that a real recording hides, and called them
#: overhead. bench/robot_time.py measures the daemon's overhead at a real file rate.
FILE_RATE_BYTES_S = 100e3 * TIME_SCALE


def demo_config(sim: SimProcess, data_dir: Path, mqtt_url: str | None, console_port: int | None = None,
                time_scale: float = TIME_SCALE, file_rate_bytes_s: float | None = None,
                setup: DemoSetup = _KR500_DEMO) -> Config:
    """The demo's daemon configuration; ``time_scale`` the simulator's, ``file_rate_bytes_s`` the controller file
    rate the daemon sizes its file deadlines by (None: the default; bench/robot_time.py scales both); ``setup`` the
    robot's demo (its DuT, fixture and payload reach)."""
    mqtt: dict[str, Any] = {"enabled": False}
    if mqtt_url is not None:
        u = urlsplit(mqtt_url)
        if u.scheme not in ("mqtt", "tcp") or not u.hostname:
            raise ConfigError(f"--mqtt {mqtt_url}: expected mqtt://HOST[:PORT]")
        # the demo's robot is the simulator it started: commands need no token
        mqtt = {"enabled": True, "host": u.hostname, "port": u.port or 1883, "command_auth": "open_lab_bench"}
    return config_from_mapping(
        {
            "robot": {"name": setup.name, "model": setup.robot.key},
            "controller": {"host": "127.0.0.1", "port": sim.port, "protocol": "c3bridge",
                           "share_dir": str(sim.share_dir),
                           # the simulated controller's clock runs time_scale times faster than the wall clock: the
                           # run's waits in the robot's time (settling, the warm-up's windows) are divided by it, and
                           # a trace's wall time is its configured time divided by it (a loop's work past the trace's
                           # end is then overhead, not recording: procedures/loop.py)
                           "time_scale": time_scale,
                           **({} if file_rate_bytes_s is None else {"file_rate_bytes_s": file_rate_bytes_s})},
            "paths": {"data_dir": str(data_dir)},
            # the demo shares a 2-core machine with its simulated controller (and, under `make test`, with the test
            # run): a scheduling hiccup of the daemon's event loop > 0.1 s is a stale snapshot and trips the
            # interlock. A dedicated measurement PC keeps the 0.1 s default; the simulated robot moves in T1.
            "limits": {"snapshot_stale_s": 0.5},
            # in the robot's time (controller.time_scale divides them): the paper's 2 x 2 s of settling after each
            # brake-release move, the warm-up's windows
            "measurement": {"loops": MEASUREMENT_LOOPS, "settle_s": SETTLE_S, "trace_period_s": 0.012,
                            "trace_samples": 1000, "warmup_cycles": 2, "fixture_mass_kg": setup.fixture_mass_kg,
                            "payload_lever_max_m": setup.payload_lever_max_m, "warmup_until_steady": True,
                            "warmup_steady_window_s": 300.0, "warmup_max_s": 2400.0},
            "mqtt": mqtt,
            "console": {"enabled": console_port is not None, "port": 8080 if console_port is None else console_port},
        },
        "<demo>",
    )


#: Events shown as a line of their own (on a terminal, loop events move the bars instead).
MESSAGE_KINDS = ("confirm", "alarm", "result")


class View(Protocol):
    """Where the demo's progress goes (stderr): a context manager taking notes and engine events."""

    def __enter__(self) -> View: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...

    def note(self, text: str) -> None: ...

    def event(self, ev: Event) -> None: ...


class SilentView:
    """Quiet (``--json``, the bench) off a terminal: nothing on stderr."""

    def __enter__(self) -> SilentView:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        return None

    def note(self, text: str) -> None:
        return None

    def event(self, ev: Event) -> None:
        return None


class PlainView(SilentView):
    """Off a terminal: one plain line per note and per message or loop event (tests and CI logs read them)."""

    def note(self, text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def event(self, ev: Event) -> None:
        if ev.kind in (*MESSAGE_KINDS, "loop"):
            self.note(f"  [{ev.kind}] {ev.message}")


class BarsView:
    """On a terminal: a bar for the calibration campaign (points × loops) and one for the measurement's loops (with
    the time left the loop events estimate); notes and confirm/alarm/result messages are printed above the bars."""

    def __init__(self, console: Console, campaign_loops: int, measurement_loops: int) -> None:
        from rich.progress import TextColumn

        self.progress: Progress = new_progress(console, TextColumn("{task.fields[eta]}"))
        self.campaign = self.progress.add_task("calibration campaign", total=campaign_loops, eta="")
        self.measurement = self.progress.add_task("in-line measurement", total=measurement_loops, eta="",
                                                  start=False)
        self._running = running(self.progress)

    def __enter__(self) -> BarsView:
        self._running.__enter__()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._running.__exit__(exc_type, exc, tb)

    def note(self, text: str, style: str | None = None) -> None:
        self.progress.console.print(text, style=style, markup=False, highlight=False)

    def event(self, ev: Event) -> None:
        if ev.kind in MESSAGE_KINDS:
            self.note(f"  [{ev.kind}] {ev.message}", style="bold red" if ev.kind == "alarm" else None)
        if ev.kind not in ("step", "loop") or ev.loop_index is None or ev.loop_count is None:
            return
        if "point_index" in ev.data:  # a campaign loop (a torsional point has loops in every CoG pose)
            if ev.kind == "loop":
                self.progress.advance(self.campaign)
            return
        if ev.data.get("phase") == "cog":  # the CoG poses: their lines say where the run is
            return
        self.progress.start_task(self.measurement)  # its first loop began (a no-op after that)
        if ev.kind == "loop":
            eta = "" if ev.eta_s is None else f"eta {timedelta(seconds=round(ev.eta_s))}"
            self.progress.update(self.measurement, completed=ev.loop_index, total=ev.loop_count, eta=eta,
                                 refresh=True)


def demo_view(*, quiet: bool, bars: bool, setup: DemoSetup = _KR500_DEMO) -> View:
    """Bars if ``bars`` and stderr is an interactive terminal; else plain lines, or nothing if ``quiet``."""
    console = terminal_console() if bars else None
    if console is not None:
        return BarsView(console, campaign_loops(setup), MEASUREMENT_LOOPS)
    return SilentView() if quiet else PlainView()


def campaign_loops(setup: DemoSetup = _KR500_DEMO) -> int:
    """The campaign's loops: ``CAMPAIGN_LOOPS`` per point, in every CoG pose for a torsional point."""
    poses = len(cog_poses(kin.measurement_pose(robot=setup.robot), cog_scheme(setup.robot)))
    return sum(CAMPAIGN_LOOPS * (poses if p.kind == "torsional" else 1) for p in setup.campaign)


class Operator:
    """The simulated lab operator: mounts the load the daemon asks for, then confirms; shows progress on ``view``."""

    def __init__(self, sim: SimProcess, daemon_ref: list[Daemon], view: View) -> None:
        self.sim = sim
        self.daemon_ref = daemon_ref
        self.view = view
        self._tasks: set[asyncio.Task[None]] = set()
        self.dut_truth: Any = None
        """The simulator's truth of the DuT's last trace, kept when the inertia's tare takes the DuT off (after that
        the simulator's truth is the tare's: no DuT on the flange)."""

    def __call__(self, ev: Event) -> None:
        if ev.kind == "confirm":
            task = asyncio.get_running_loop().create_task(self._mount_and_confirm(dict(ev.data)))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        self.view.event(ev)

    async def _mount_and_confirm(self, d: dict[str, Any]) -> None:
        engine = self.daemon_ref[0].engine
        assert engine is not None
        if d.get(TARE_PROMPT) is True:  # the inertia's tare: the DuT comes off, MPA and fixture stay
            self.dut_truth = await self.sim.truth()
            await self.sim.mount(ph.dut_payload(0.0, (0.0, 0.0, 0.0)))
            engine.confirm("operator took the DuT off")
            return
        await self.sim.mount(campaign_point_payload(d))
        engine.confirm(f"operator mounted point {d['point_index']}")


async def _wait(task: asyncio.Task[Any], what: str) -> Any:
    try:
        async with asyncio.timeout(DEADLINE_S):
            return await task
    except TimeoutError as exc:
        raise RgseError(f"demo: {what} did not finish within {DEADLINE_S:.0f} s") from exc


async def run_demo(*, quiet: bool, report_dir: Path | None, mqtt_url: str | None, bars: bool = False,
                   console_port: int | None = None, inertia: bool = False, seed: int = SEED,
                   robot: str = robots.DEFAULT_KEY) -> dict[str, Any]:
    """The demo; progress on stderr: bars on a terminal if ``bars``, else plain lines unless ``quiet``. ``seed``
    draws the simulated robot (its gains, offsets, noise; bench/demo_repeat.py repeats the demo over seeds);
    ``robot``: which arm (``rgse_daemon/robots/``), simulated with its own scenario, load set and DuT."""
    setup = demo_setup(robot)
    previous = robots.activate(setup.robot)  # the daemon activates it too; the operator's loads are its
    try:
        return await _run_demo(setup, quiet=quiet, report_dir=report_dir, mqtt_url=mqtt_url, bars=bars,
                               console_port=console_port, inertia=inertia, seed=seed)
    finally:
        robots.activate(previous)


async def _run_demo(setup: DemoSetup, *, quiet: bool, report_dir: Path | None, mqtt_url: str | None, bars: bool,
                    console_port: int | None, inertia: bool, seed: int) -> dict[str, Any]:
    t_start = time.monotonic()
    dut = setup.dut
    with demo_view(quiet=quiet, bars=bars, setup=setup) as view, \
            tempfile.TemporaryDirectory(prefix="rgse-demo-") as tmp:
        root = Path(tmp)
        # the simulated controller in its own process, as a real KR C4 is its own machine: its CPU work must not
        # stall the daemon's event loop and its 20 Hz interlock monitor
        sim = SimProcess(root / "share", seed=seed, time_scale=TIME_SCALE, globals_dat=globals_dat_text(),
                         file_rate_bytes_s=FILE_RATE_BYTES_S, robot=setup.robot.key)
        await asyncio.to_thread(sim.start)
        try:
            cfg = demo_config(sim, root / "data", mqtt_url, console_port, setup=setup)
            ref: list[Daemon] = []
            operator = Operator(sim, ref, view)
            daemon = Daemon(cfg, on_event=operator)
            ref.append(daemon)
            stop = asyncio.Event()
            service = asyncio.create_task(daemon.run(stop), name="rgse-demo-daemon")
            try:
                async with asyncio.timeout(30):
                    await daemon.connected.wait()
                view.note(f"console: {daemon.console.url}" if daemon.console is not None else
                          "console: off (rgse demo --console PORT, or make demo CONSOLE=PORT, serves it)")
                view.note(f"{setup.robot.title}: calibration campaign: {len(setup.campaign)} points x "
                          f"{CAMPAIGN_LOOPS} loops")
                t0 = time.monotonic()
                cal_settings = RunSettings.from_config(cfg, loops=CAMPAIGN_LOOPS, warmup_cycles=1)
                calibration = await _wait(
                    await daemon.start_calibration(points=setup.campaign, method="auto", settings=cal_settings),
                    "the calibration campaign",
                )
                t_cal = time.monotonic() - t0
                await sim.mount(dut.payload())
                view.note(f"in-line mass properties: {MEASUREMENT_LOOPS} mass loops, then the CoG poses "
                          f"({cog_scheme(setup.robot)}) x {PROPERTIES_LOOPS_PER_POSE} loops, mass method "
                          f"{mass_method(setup.robot)}")
                t0 = time.monotonic()
                result = await _wait(await daemon.start_properties(
                    props=PropertiesSettings(cog_scheme(setup.robot), PROPERTIES_LOOPS_PER_POSE,
                                             ph.fixture_cog_flange_m(), dut.dut_origin_flange_m, dut.dut_abc_deg,
                                             inertia, mass_method=mass_method(setup.robot))),
                    "the properties run")
                t_meas = time.monotonic() - t0
                # the DuT as mounted for the run: with --inertia its truth from before the tare took it off
                true_cog_m = _true_dut_cog_m(operator.dut_truth if operator.dut_truth is not None
                                             else await sim.truth(), setup)
                report_path = None
                if report_dir is not None:
                    report_path = await _write_report(cfg, result["run_id"], report_dir)
            finally:
                stop.set()
                async with asyncio.timeout(60):
                    await service
        finally:
            await asyncio.to_thread(sim.stop)
    timing = result["timing"]
    robot_wall_s = float(timing["robot_time_s"])
    overhead_s = float(timing["overhead_s"])
    true_mass_kg = setup.dut_mass_kg
    return {**_inertia_summary(result, dut), **{
        "robot": setup.robot.key,
        "seed": seed,
        "mass_kg": result["mass_kg"],
        "true_mass_kg": true_mass_kg,
        "error_kg": result["mass_kg"] - true_mass_kg,
        "U_kg": result["U_kg"],
        "within_U": abs(result["mass_kg"] - true_mass_kg) <= result["U_kg"],
        "loops": result["loops"],
        "robot_time_s": robot_wall_s * TIME_SCALE,
        "overhead_s": overhead_s,
        "overhead_pct_of_robot_time": 100.0 * overhead_s / (robot_wall_s * TIME_SCALE),
        # per loop: robot time as the real robot would need it (simulated time), daemon overhead in wall time (pull,
        # archive, store), plus the run's one-off computation of the mass
        "per_loop": [{"robot_s": float(lp["robot_s"]) * TIME_SCALE, "overhead_s": float(lp["overhead_s"]),
                      "pull_s": float(lp["pull_s"]), "store_s": float(lp["store_s"])} for lp in timing["per_loop"]],
        "compute_s": float(timing["compute_s"]),
        "time_scale": TIME_SCALE,
        "run_id": result["run_id"],
        "calibration": {
            "calibration_id": calibration["calibration_id"],
            "method": calibration["method"],
            "points": calibration["points"],
            "in_sample_mean_abs_err_pct": calibration["in_sample_mean_abs_err_pct"],
            "loo_mean_abs_err_pct": calibration["loo_mean_abs_err_pct"],
        },
        # the CoG of the same run: flange frame with U (k = 2), the simulator's truth as mounted
        "cog_m": result["cog_m"],
        "U_cog_m": result["U_cog_m"],
        "true_cog_m": true_cog_m,
        "cog_error_mm": [1000.0 * (c - t) for c, t in zip(result["cog_m"], true_cog_m, strict=True)],
        "cog_within_U": all(abs(c - t) <= u for c, t, u in zip(result["cog_m"], true_cog_m, result["U_cog_m"],
                                                                strict=True)),
        "cog_dut_m": result["cog_dut_m"],
        "U_cog_dut_m": result["U_cog_dut_m"],
        "cog_scheme": cog_scheme(setup.robot),
        # the mass methods the run measured, side by side (issue #35): each one's mass, U (k = 2), error against the
        # truth and the robot time of its own loops (real-time equivalent); which one the result reports and why
        "mass_method": result.get("mass_method", "single"),
        "mass_choice": result.get("mass_choice"),
        "mass_methods": {k: {"mass_kg": v["mass_kg"], "U_kg": v["U_kg"], "error_kg": v["mass_kg"] - true_mass_kg,
                             "within_U": abs(v["mass_kg"] - true_mass_kg) <= v["U_kg"],
                             "robot_time_s": float(v.get("robot_time_s") or 0.0) * TIME_SCALE}
                         for k, v in (result.get("mass_methods") or {}).items()},
        "mass_robot_time_s": float(timing["mass_robot_time_s"]) * TIME_SCALE,
        "cog_robot_time_s": float(timing["cog_robot_time_s"]) * TIME_SCALE,
        # why the mass loops stopped (pipeline/stopping.py: loop term below share, target U met, max loops)
        "stop_reason": result.get("stop_reason"),
        "stop_rule": result.get("stop_rule"),
        # the campaign's loops (motion, settling, recording) as the real robot needs them, its points' stop reasons
        "calibration_robot_time_s": float(calibration.get("robot_time_s", 0.0)) * TIME_SCALE,
        "calibration_points_stop": calibration.get("points_stop", []),
        "wall_s": {"calibration": t_cal, "measurement": t_meas, "total": time.monotonic() - t_start},
        "warnings": result.get("warnings", []),
        "status": result.get("status", "ok"),
        "report": str(report_path) if report_path is not None else None,
    }}


def _inertia_summary(result: dict[str, Any], dut: ph.AsymmetricDut) -> dict[str, Any]:
    """The inertia of the run (if it measured it) beside the simulator's truth: principal moments ascending with U
    (k = 2), and the robot time of the two excitations (real-time equivalent)."""
    if "principal_moments_kgm2" not in result:
        return {}
    moments, u = result["principal_moments_kgm2"], result["U_principal_moments_kgm2"]
    truth = [float(v) for v in dut.principal_moments_kgm2]
    return {
        "principal_moments_kgm2": moments,
        "U_principal_moments_kgm2": u,
        "true_principal_moments_kgm2": truth,
        "principal_moments_within_U": [abs(m - t) <= ui for m, t, ui in zip(moments, truth, u, strict=True)],
        "inertia_cog_dut_kgm2": result["inertia_cog_dut_kgm2"],
        "U_inertia_cog_dut_kgm2": result["U_inertia_cog_dut_kgm2"],
        "principal_axes_dut": result["principal_axes_dut"],
        "inertia_robot_time_s": float(result["timing"]["inertia_robot_time_s"]) * TIME_SCALE,
    }


def _true_dut_cog_m(truth: Any, setup: DemoSetup) -> list[float]:
    """The DuT's CoG as the simulator mounted it (its mounting's shift included), flange frame (m): everything on
    the flange minus MPA and fixture."""
    if truth is None:
        raise RgseError("demo: the simulator recorded no trace, so it has no truth to compare with")
    total = [truth.payload_mass_kg * c for c in truth.payload_cog_flange_m]
    mpa = ph.mpa()
    fixture_cog = ph.fixture_cog_flange_m()
    return [(t - mpa.mass_kg * m - setup.fixture_mass_kg * f) / setup.dut_mass_kg
            for t, m, f in zip(total, mpa.cog_flange_m, fixture_cog, strict=True)]


async def _write_report(cfg: Config, run_id: str, out: Path) -> Path:
    from rgse_daemon.commands import report  # optional part: the HTML report

    return await asyncio.to_thread(report.write, cfg, run_id=run_id, out_dir=out)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse demo``."""
    add_json(p)
    p.add_argument("--report", type=Path, metavar="DIR", help="also write the HTML report into DIR")
    p.add_argument("--mqtt", metavar="URL", help="also publish on this broker, e.g. mqtt://127.0.0.1:1883")
    p.add_argument("--console", type=int, metavar="PORT", help="also serve the web console on 127.0.0.1:PORT")
    p.add_argument("--inertia", action="store_true",
                   help="the properties run also measures the inertia tensor (DuT and tare excitation)")
    p.add_argument("--seed", type=int, default=2024, metavar="N",
                   help="the simulated robot's seed (gains, offsets, noise; default 2024)")
    p.add_argument("--robot", default="kr500r2830", metavar="MODEL",
                   help="the simulated arm: kr500r2830 (default, the paper's) or kr10r1440 (its subscale bench)")


def run(args: argparse.Namespace) -> int:
    summary = asyncio.run(run_demo(quiet=args.json, report_dir=args.report, mqtt_url=args.mqtt, bars=True,
                                   console_port=getattr(args, "console", None),
                                   inertia=bool(getattr(args, "inertia", False)),
                                   seed=int(getattr(args, "seed", SEED)),
                                   robot=str(getattr(args, "robot", robots.DEFAULT_KEY))))
    if args.json:
        print(json.dumps(summary))
        return 0
    c = summary["calibration"]
    print(f"calibration {c['calibration_id']} ({c['method']}, {c['points']} points): "
          f"in-sample {c['in_sample_mean_abs_err_pct']:.3f} %, leave-one-out {c['loo_mean_abs_err_pct']:.3f} %")
    print(f"robot          {summary['robot']}")
    print(f"true mass      {summary['true_mass_kg']:9.3f} kg")
    print(f"measured mass  {summary['mass_kg']:9.3f} kg ± {summary['U_kg']:.3f} kg (U, k = 2)   "
          f"error {summary['error_kg']:+.3f} kg  {'within' if summary['within_U'] else 'OUTSIDE'} U   "
          f"({summary['mass_method']})")
    for name, mm_ in summary["mass_methods"].items():
        print(f"  {name:11s}  {mm_['mass_kg']:9.3f} kg ± {mm_['U_kg']:.3f} kg   error {mm_['error_kg']:+.3f} kg  "
              f"{'within' if mm_['within_U'] else 'OUTSIDE'} U   robot time {mm_['robot_time_s'] / 60:.1f} min")
    mm = [1000.0 * v for v in summary["cog_m"]]
    umm = [1000.0 * v for v in summary["U_cog_m"]]
    tmm = [1000.0 * v for v in summary["true_cog_m"]]
    print(f"true CoG       x {tmm[0]:7.2f}, y {tmm[1]:7.2f}, z {tmm[2]:7.2f} mm (flange frame)")
    print(f"measured CoG   x {mm[0]:7.2f} ± {umm[0]:.2f}, y {mm[1]:7.2f} ± {umm[1]:.2f}, z {mm[2]:7.2f} ± {umm[2]:.2f}"
          f" mm (U, k = 2; {summary['cog_scheme']} scheme)   {'within' if summary['cog_within_U'] else 'OUTSIDE'} U")
    if "principal_moments_kgm2" in summary:
        for k, (v, u, t) in enumerate(zip(summary["principal_moments_kgm2"], summary["U_principal_moments_kgm2"],
                                          summary["true_principal_moments_kgm2"], strict=True), 1):
            print(f"principal moment I{k}: {v:7.3f} ± {u:.3f} kg·m² (U, k = 2), true {t:7.3f}   "
                  f"{'within' if abs(v - t) <= u else 'OUTSIDE'} U")
        print(f"inertia excitation (DuT and tare): robot time {summary['inertia_robot_time_s'] / 60:.1f} min")
    print(f"calibration campaign: robot time {summary['calibration_robot_time_s'] / 60:.1f} min (loops; warm-ups "
          f"and load changes not counted)")
    print(f"{summary['loops']} mass loops ({summary['stop_reason']}) and the CoG poses: robot time "
          f"{summary['robot_time_s'] / 60:.1f} min "
          f"(mass {summary['mass_robot_time_s'] / 60:.1f}, CoG {summary['cog_robot_time_s'] / 60:.1f}; real-time "
          f"equivalent), "
          f"daemon overhead {summary['overhead_s']:.2f} s ({summary['overhead_pct_of_robot_time']:.2f} %)")
    w = summary["wall_s"]
    print(f"wall time: campaign {w['calibration']:.1f} s, mass properties {w['measurement']:.1f} s, "
          f"total {w['total']:.1f} s (simulator at {summary['time_scale']:g}x)")
    if summary["report"] is not None:
        print(f"report: {summary['report']}")
    print(f"status: {summary['status']}" + (f" ({len(summary['warnings'])} warning(s))" if summary["warnings"]
                                              else ""))
    for warning in summary["warnings"]:
        print(f"warning: {warning}")
    return 0
