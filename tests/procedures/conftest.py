"""Fixtures: a simulated KR C4 on a real socket, the daemon's Controller, store, engine and short run settings."""

from __future__ import annotations

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


def make_config(sim: SimulatedKrc4, data_dir: Path, **measurement: object) -> Config:
    ms = {"loops": 2, "settle_s": 0.01, "trace_period_s": 0.012, "trace_samples": 250, "warmup_cycles": 1,
          "fixture_mass_kg": 10.288, "program_timeout_s": 60.0, "trace_timeout_s": 30.0,
          "warmup_until_steady": False, **measurement}
    return config_from_mapping({
        "robot": {"name": ROBOT},
        "controller": {"host": "127.0.0.1", "port": sim.port, "protocol": "c3bridge", "share_dir": str(sim.share_dir),
                       "request_timeout_s": 2.0, "watchdog_bound_s": 1.0},  # a loaded machine: as the monitor
        "paths": {"data_dir": str(data_dir)},
        "measurement": ms,
        # support.plans.long_motion runs 60 warm-up cycles (up to 3186 s of motion by the check's bound): the tests
        # that interrupt it need a program that long to be allowed
        "limits": {"max_motion_s": 3600.0},
    })


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    async with SimulatedKrc4(tmp_path / "share", seed=7, time_scale=TIME_SCALE, latency_s=0.0) as s:
        install_globals(s)
        yield s


@pytest.fixture
def cfg(sim: SimulatedKrc4, tmp_path: Path) -> Config:
    return make_config(sim, tmp_path / "data")


@pytest.fixture
def settings(cfg: Config) -> RunSettings:
    return RunSettings.from_config(cfg)


@pytest.fixture
async def krc(cfg: Config) -> AsyncIterator[Controller]:
    async with Controller.connect(cfg.controller) as c, beating(cfg.controller):  # the daemon's heartbeat
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
