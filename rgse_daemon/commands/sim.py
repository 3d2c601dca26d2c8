"""``rgse sim``: run the simulated KR C4 as a C3 Bridge / KUKAVARPROXY server until SIGINT or SIGTERM (exit 0).

The whole simulated controller (:class:`simulators.krc4.sim.SimulatedKrc4`: server, variable store, KRL
interpreter, physics of the ``--scenario`` and KUKA Trace, in ``--time-scale``) is built by :func:`build_simulator`.

When the server listens, one line goes to stdout: ``rgse sim: listening on HOST:PORT (share DIR); control on
HOST:CPORT`` (useful with ``--port 0``); logs go to stderr. The control port (``--control-port``, loopback) takes what a
person at the robot does (mount a load or a DuT, the mode selector, the enabling switch): ``rgse sim-op`` is its
client (:mod:`simulators.krc4.control`).

``--commission`` does to the simulator what a lab does once to a new KR C4 (README, "The lab's path"): the handshake
globals installed and ``RGSE_GLOBALS.DAT`` and the resident program (rendered with ``--config``'s settings, as
``rgse krl render`` makes them) copied to ``KRC:\\R1\\PROGRAM``, so that ``rgse doctor`` passes against it.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import signal
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rgse_daemon import robots
from rgse_daemon.config import Config, load_config
from rgse_daemon.doctor import GLOBALS_FILE, PROGRAM_DIR, RESIDENT, krl_bytes
from rgse_daemon.errors import ConfigError, LinkError
from rgse_daemon.krl.render import default_params, globals_dat_text, render
from simulators.krc4 import scenario as sim_scenario
from simulators.krc4.control import ControlServer
from simulators.krc4.server import DEFAULT_FILE_RATE_BYTES_S
from simulators.krc4.sim import SimulatedKrc4

log = logging.getLogger(__name__)

#: Largest accepted ``--time-scale`` (simulated s per wall s); beyond it the 2 ms service time means nothing.
MAX_TIME_SCALE = 1000.0


@dataclass(frozen=True)
class SimOptions:
    """Everything ``rgse sim`` was asked for, validated.

    ``scenario`` is the parsed TOML table (empty without ``--scenario``); ``time_scale`` is simulated seconds per
    wall-clock second.
    """

    host: str = "127.0.0.1"
    port: int = 7000
    share_dir: Path | None = None
    scenario_path: Path | None = None
    scenario: dict[str, Any] = field(default_factory=dict)
    time_scale: float = 1.0
    globals_dat: str | None = None
    """The text of ``--globals FILE`` (``rgse krl render``'s rgse_globals.dat), installed at start."""
    control_port: int | None = 7001
    """The control port (what a person at the robot does; ``None``: none, 0: any free port); ``--control-port``'s
    default is ``port + 1``."""
    commission: Config | None = None
    """Commission at start with this configuration's settings (``--commission``), else ``None``."""


def load_scenario(path: Path) -> dict[str, Any]:
    """Read a scenario TOML file; ``ConfigError`` naming the file if it is missing, unreadable or not TOML."""
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read scenario: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: scenario is not UTF-8 text") from exc
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: scenario is not valid TOML: {exc}") from exc
    except RecursionError:  # tomllib's answer to arrays nested thousands deep
        raise ConfigError(f"{path}: scenario is not valid TOML: nested too deeply") from None


def options_from_args(args: argparse.Namespace) -> SimOptions:
    """Validate the command line before any I/O on the network."""
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port} is not 0..65535")
    if not (math.isfinite(args.time_scale) and 0 < args.time_scale <= MAX_TIME_SCALE):
        raise ConfigError(f"--time-scale {args.time_scale} must be > 0 and <= {MAX_TIME_SCALE:g}")
    share = args.share
    if share is not None and share.exists() and not share.is_dir():
        raise ConfigError(f"--share {share}: not a directory")
    scenario = load_scenario(args.scenario) if args.scenario is not None else {}
    globals_dat = None
    if getattr(args, "globals", None) is not None:
        try:
            globals_dat = args.globals.read_bytes().decode("iso-8859-1")
        except OSError as exc:
            raise ConfigError(f"--globals {args.globals}: cannot read: {exc.strerror or exc}") from exc
    control_port = getattr(args, "control_port", None)
    if control_port is not None and not (control_port == -1 or 0 <= control_port <= 65535):
        raise ConfigError(f"--control-port {control_port} is not 0..65535 (or -1: no control port)")
    commission = None
    if getattr(args, "commission", False):
        commission = load_config(args.config) if getattr(args, "config", None) is not None else Config()
    elif getattr(args, "config", None) is not None:
        raise ConfigError("--config is read only with --commission (the settings the programs are rendered with)")
    return SimOptions(args.host, args.port, share, args.scenario, scenario, args.time_scale, globals_dat,
                      _control_port(control_port, args.port), commission)


def _control_port(asked: int | None, port: int) -> int | None:
    """``--control-port``: -1 none; default the C3 Bridge port + 1, or any free port beside ``--port 0``."""
    if asked == -1:
        return None
    if asked is None:
        return 0 if port == 0 else port + 1 if port < 65535 else port - 1
    return asked


def commission(sim: SimulatedKrc4, cfg: Config) -> list[str]:
    """What a lab does once to a new KR C4, done to the simulator: the handshake globals installed, and
    ``RGSE_GLOBALS.DAT`` and ``RGSE_RESIDENT.SRC`` (rendered with ``cfg``, as ``rgse krl render --config`` makes it)
    copied to ``KRC:\\R1\\PROGRAM``. Returns the files written."""
    from rgse_daemon.commands.krl import template_defaults  # a sibling command's rendering defaults

    globals_text = globals_dat_text()
    sim.install_globals(globals_text)
    resident = render(RESIDENT, default_params(RESIDENT, template_defaults(cfg))).src_text
    written = []
    for name, text in ((GLOBALS_FILE, globals_text), (PROGRAM_DIR + RESIDENT.upper() + ".SRC", resident)):
        path = sim.files.resolve(name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(krl_bytes(text))
        written.append(name)
    return written


def build_simulator(options: SimOptions) -> SimulatedKrc4:
    """The whole simulated controller as ``rgse sim`` runs it (not yet listening): server, variable store, KRL
    interpreter, physics of the scenario and KUKA Trace, in the requested time scale."""
    return SimulatedKrc4(
        options.share_dir,
        scenario_in_time_scale(options.scenario_path, options.time_scale),
        time_scale=options.time_scale,
        host=options.host,
        port=options.port,
    )


def scenario_in_time_scale(path: Path | None, time_scale: float) -> sim_scenario.Scenario:
    """The scenario ``rgse sim`` runs (``path``; None: the active robot's own, ``scenarios/default.toml`` for the
    KR 500) with the controller's file work in the same time scale as its motions and traces: the scenario's
    ``[server] file_rate_bytes_s`` (a real C3 Bridge's, 100 kB/s guessed; the server's default where it sets none)
    times ``time_scale``. Unscaled, a loop's pull (3.3 s) outlasts its 12 s trace at 100x and the rehearsal waits on
    it; ``rgse doctor`` measures what the simulator serves either way."""
    scenario = sim_scenario.load_scenario(path) if path is not None else sim_scenario.scenario_for(robots.active().key)
    rate = (scenario.server.file_rate_bytes_s or DEFAULT_FILE_RATE_BYTES_S) * time_scale
    return scenario.model_copy(update={"server": scenario.server.model_copy(update={"file_rate_bytes_s": rate})})


async def serve(options: SimOptions, stop: asyncio.Event) -> None:
    """Listen until ``stop`` is set, then close every connection."""
    sim = build_simulator(options)
    if options.globals_dat is not None:  # what installing it once on a real controller does (krl/README.md)
        names = sim.install_globals(options.globals_dat)
        log.info("handshake globals installed: %s", ", ".join(names))
    if options.commission is not None:
        log.info("commissioned: %s", ", ".join(commission(sim, options.commission)))
    control = ControlServer(sim, options.host, options.control_port) if options.control_port is not None else None
    try:
        await sim.start()
        if control is not None:
            await control.start()
    except OSError as exc:
        await sim.close()
        raise LinkError(f"cannot listen on {options.host}:{options.port}"
                        f"{f' / control {options.control_port}' if control is not None else ''}: "
                        f"{exc.strerror or exc}") from exc
    try:
        where = f"; control on {options.host}:{control.port}" if control is not None else ""
        print(f"rgse sim: listening on {options.host}:{sim.port} (share {sim.share_dir}){where}", flush=True)
        await stop.wait()
    finally:
        if control is not None:
            await control.close()
        await sim.close()
    log.info("simulated KR C4 stopped after %d requests", sim.server.counters.requests)


async def _main(options: SimOptions) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    signals = (signal.SIGINT, signal.SIGTERM)
    for sig in signals:
        loop.add_signal_handler(sig, stop.set)
    try:
        await serve(options, stop)
    finally:
        for sig in signals:
            loop.remove_signal_handler(sig)
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse sim``."""
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=7000)
    p.add_argument("--share", type=Path, metavar="DIR", help="the controller's 'roboter' share directory")
    p.add_argument("--scenario", type=Path, metavar="FILE", help="scenario TOML (physics, errors, faults)")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X", help="simulated s per wall s")
    p.add_argument("--globals", type=Path, metavar="FILE",
                   help="install this rgse_globals.dat (from rgse krl render) at start, as done once on a real "
                        "controller: without it the programs stop at their first handshake variable")
    p.add_argument("--control-port", type=int, default=None, metavar="PORT",
                   help="what a person at the robot does, for rgse sim-op (default --port + 1 on --host, any free "
                        "port with --port 0; -1: none)")
    p.add_argument("--commission", action="store_true",
                   help="commission as a real KR C4 is once: handshake globals, RGSE_GLOBALS.DAT and the resident "
                        "program (rendered with --config) installed, so rgse doctor passes")
    p.add_argument("--config", type=Path, metavar="FILE", help="with --commission: the daemon's configuration")


def run(args: argparse.Namespace) -> int:
    return asyncio.run(_main(options_from_args(args)))
