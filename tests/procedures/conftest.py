"""Fixtures: a simulated KR C4, the daemon's Controller on it, store, engine and short run settings.

The engine's unit tests talk to the simulated KR C4 in process (``simulators/krc4/inprocess.py``: the daemon's own
Controller and link, the simulator's own server, only the socket replaced by an in-memory pipe). A test module
that asks for TCP starts its simulator (``await sim.start()``, or its own ``sim`` fixture): :func:`controller` and
:func:`heartbeat` then go over the socket. The interlock's tests (test_monitor.py, test_file_window.py) and the
campaign-then-measurement run (test_campaign_and_measurement.py) do. Every path is
also run end to end over TCP by the daemon's tests (tests/app, tests/sim_e2e)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.controller import Controller
from rgse_daemon.krl import ast as k
from rgse_daemon.krl.parser import parse_dat
from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.procedures.engine import RunEngine
from rgse_daemon.procedures.programs import static_checker
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.monitor import Monitor
from rgse_daemon.store import Store
from simulators.krc4.inprocess import InProcessConnection, in_process_controller
from simulators.krc4.sim import SimulatedKrc4
from simulators.krc4.variables import Kind
from tests.support.heartbeat import beating

ROBOT = "KR500R2830-SIM"
#: The simulator runs in the test's own process and event loop (its CPU work shares the interpreter lock), and the
#: 2-core machine may be busy: a snapshot may take longer than the daemon's default 2 poll periods (0.1 s) without
#: the link being lost. Tests of the staleness watcher itself (test_monitor.py) use their own limits.
STALE_PERIODS = 10.0
TIME_SCALE = 100.0


def install_globals(sim: SimulatedKrc4) -> None:
    """What installing ``krl/rgse_globals.dat`` once on the controller does: its GLOBAL handshake variables exist."""
    data = parse_dat(globals_dat_text(), "rgse_globals.dat")
    kinds = {"INT": Kind.INT, "REAL": Kind.REAL, "BOOL": Kind.BOOL}
    for decl in data.decls:
        assert isinstance(decl, k.Decl) and decl.is_global
        for dn in decl.names:
            default = {"INT": "0", "REAL": "0.0", "BOOL": "FALSE"}[decl.type_name]
            sim.store.declare_global(dn.name, kinds[decl.type_name], default)


#: ``controller.port`` of a simulator that does not listen (the in-process link does not use it).
UNUSED_PORT = 7000


def make_config(sim: SimulatedKrc4, data_dir: Path, **measurement: object) -> Config:
    ms = {"loops": 2, "settle_s": 0.01, "trace_period_s": 0.012, "trace_samples": 250, "warmup_cycles": 1,
          "fixture_mass_kg": 10.288, "program_timeout_s": 60.0, "trace_timeout_s": 30.0,
          "warmup_until_steady": False, **measurement}
    return config_from_mapping({
        "robot": {"name": ROBOT},
        "controller": {"host": "127.0.0.1", "port": sim.port or UNUSED_PORT, "protocol": "c3bridge",
                       # a loaded machine: as the monitor
                       "share_dir": str(sim.share_dir), "request_timeout_s": 2.0, "watchdog_bound_s": 1.0},
        "paths": {"data_dir": str(data_dir)},
        "measurement": ms,
        # support.plans.long_motion runs 60 warm-up cycles (up to 3186 s of motion by the check's bound): the tests
        # that interrupt it need a program that long to be allowed
        "limits": {"max_motion_s": 3600.0},
    })


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    """The simulated KR C4, not listening: the tests reach it in process."""
    s = SimulatedKrc4(tmp_path / "share", seed=7, time_scale=TIME_SCALE, latency_s=0.0)
    try:
        install_globals(s)
        yield s
    finally:
        await s.close()


def controller(sim: SimulatedKrc4, cfg: Config) -> contextlib.AbstractAsyncContextManager[Controller]:
    """The daemon's Controller on ``sim``: over TCP if it listens, else in process."""
    if sim.port:
        return Controller.connect(cfg.controller)
    return in_process_controller(sim.server, cfg.controller)


def heartbeat(sim: SimulatedKrc4, cfg: Config) -> contextlib.AbstractAsyncContextManager[object]:
    """The daemon's heartbeat on ``sim`` (its own connection, as in the daemon): over TCP if it listens."""
    if sim.port:
        return beating(cfg.controller)
    return beating(cfg.controller, connection=InProcessConnection.to(sim.server, cfg.controller, name="heartbeat"))


@pytest.fixture
def cfg(sim: SimulatedKrc4, tmp_path: Path) -> Config:
    return make_config(sim, tmp_path / "data")


@pytest.fixture
def settings(cfg: Config) -> RunSettings:
    return RunSettings.from_config(cfg)


@pytest.fixture
async def krc(sim: SimulatedKrc4, cfg: Config) -> AsyncIterator[Controller]:
    async with controller(sim, cfg) as c, heartbeat(sim, cfg):  # the daemon's heartbeat
        yield c


@pytest.fixture
async def store(cfg: Config) -> AsyncIterator[Store]:
    async with await Store.open(None, cfg.paths.data_dir) as st:
        yield st


def make_engine(krc: Controller, cfg: Config, *, dry_run: bool = False) -> RunEngine:
    return RunEngine(krc, checker=static_checker(cfg.limits, cfg.measurement.payload_lever_max_m),
                     monitor=Monitor(krc, stale_periods=STALE_PERIODS), dry_run=dry_run,
                     share_dir=cfg.controller.share_dir)


@pytest.fixture
def engine(krc: Controller, cfg: Config) -> RunEngine:
    return make_engine(krc, cfg)
