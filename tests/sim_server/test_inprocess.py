"""The controller interface and the in-process link to the simulated KR C4 (simulators/krc4/inprocess.py).

The Controller implements every member of :class:`KrcController` with the Protocol's own signature; the in-process
link answers what the TCP link answers, and is no kinder: the server's faults, deadlines, file work time and
one-at-a-time service all hold without the socket."""

from __future__ import annotations

import asyncio
import dataclasses
import inspect
import time
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.config import Config, config_from_mapping
from rgse_daemon.controller import Controller
from rgse_daemon.errors import LinkClosed, LinkTimeout
from rgse_daemon.krc import KrcController
from rgse_daemon.link.errors import CommandError
from simulators.krc4.inprocess import in_process_controller
from simulators.krc4.physics import dut_payload
from simulators.krc4.sim import SimulatedKrc4

TRACE = "C:\\KRC\\ROBOTER\\TRACE\\"


def _config(sim: SimulatedKrc4, tmp_path: Path, **controller: object) -> Config:
    return config_from_mapping({
        "controller": {"host": "127.0.0.1", "port": sim.port or 7000, "protocol": "c3bridge",
                       "request_timeout_s": 1.0, **controller},
        "paths": {"data_dir": str(tmp_path / "data")},
    })


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[SimulatedKrc4]:
    s = SimulatedKrc4(tmp_path / "share", seed=3, time_scale=100.0, latency_s=0.0)
    try:
        yield s
    finally:
        await s.close()


def _members() -> list[str]:
    return [n for n in vars(KrcController) if not n.startswith("_") and n not in ("layout",)]


def test_the_protocol_names_what_its_users_call_and_the_controller_has_each_with_its_signature() -> None:
    assert {"snapshot", "read_many", "put_file", "get_file", "list_dir", "delete_file", "stop_program",
            "busy_until", "protocol"} <= set(_members())
    for name in _members():
        want, have = getattr(KrcController, name), getattr(Controller, name)
        if isinstance(want, property):
            assert isinstance(have, property), name
            continue
        assert inspect.iscoroutinefunction(want) == inspect.iscoroutinefunction(have), name
        want_params = list(inspect.signature(want).parameters.values())
        have_params = {p.name: p for p in inspect.signature(have).parameters.values()}
        for p in want_params:
            assert p.name in have_params, f"Controller.{name} lacks parameter {p.name}"
            assert have_params[p.name].kind == p.kind, f"Controller.{name}({p.name}): {p.kind} in the Protocol"
            assert (p.default is inspect.Parameter.empty) == (have_params[p.name].default is inspect.Parameter.empty)


async def test_in_process_and_tcp_read_the_same_controller(sim: SimulatedKrc4, tmp_path: Path) -> None:
    sim.mount(dut_payload(50.0, (0.0, 0.0, 0.2)))
    cfg = _config(sim, tmp_path)
    async with in_process_controller(sim.server, cfg.controller) as krc:
        assert isinstance(krc, KrcController)
        local = await krc.snapshot()
        await krc.put_file(TRACE + "x.dat", bytes(range(256)) * 40)
        listed = await krc.list_dir(TRACE)
    await sim.start()
    async with Controller.connect(_config(sim, tmp_path).controller) as krc:
        remote = await krc.snapshot()
        assert await krc.get_file(TRACE + "x.dat") == bytes(range(256)) * 40
        assert await krc.list_dir(TRACE) == listed
    timing = ("taken_at_s", "read_duration_s")
    assert local.complete and remote.complete
    assert {k: v for k, v in dataclasses.asdict(local).items() if k not in timing} == \
           {k: v for k, v in dataclasses.asdict(remote).items() if k not in timing}


async def test_the_servers_faults_hold_in_process(sim: SimulatedKrc4, tmp_path: Path) -> None:
    cfg = _config(sim, tmp_path)
    async with in_process_controller(sim.server, cfg.controller) as krc:
        sim.server.faults.drop_on_variable = "$MODE_OP"
        with pytest.raises(LinkClosed):
            await krc.snapshot()
        sim.server.faults.drop_on_variable = None
        assert (await krc.snapshot()).mode_op == "T1"  # the link reconnects, as over TCP

        sim.server.faults.stall_next = True
        t0 = time.monotonic()
        with pytest.raises(LinkTimeout):
            await krc.read_raw("$OV_PRO")
        assert time.monotonic() - t0 >= cfg.controller.request_timeout_s  # the deadline, not an instant error

        sim.server.faults.refuse_types = {23: 2}
        await krc.put_file(TRACE + "y.dat", b"y")
        with pytest.raises(CommandError):
            await krc.delete_file(TRACE + "y.dat")
        assert (sim.share_dir / "TRACE" / "y.dat").exists()


async def test_file_work_takes_its_time_and_status_reads_wait_behind_it(sim: SimulatedKrc4, tmp_path: Path) -> None:
    sim.server.config.file_rate_bytes_s = 200_000.0
    data = bytes(100_000)  # 0.5 s of the controller's file work
    (sim.share_dir / "TRACE" / "big.dat").write_bytes(data)
    cfg = _config(sim, tmp_path)
    async with in_process_controller(sim.server, cfg.controller) as krc:
        t0 = time.monotonic()
        pull = asyncio.create_task(krc.get_file(TRACE + "big.dat"))
        await asyncio.sleep(0.1)
        assert krc.busy_until() > time.monotonic()  # the monitor's file window sees the work in flight
        snap = await krc.snapshot()  # queued behind the file work on the single-threaded server
        assert time.monotonic() - t0 >= 0.45 and snap.complete
        assert await pull == data


async def test_a_closed_simulator_is_a_refused_link(sim: SimulatedKrc4, tmp_path: Path) -> None:
    await sim.close()
    with pytest.raises(LinkClosed):
        async with in_process_controller(sim.server, _config(sim, tmp_path).controller) as krc:
            raise AssertionError(f"a closed simulator gave a link: {krc!r}")


async def test_the_torque_reading_follows_pose_load_and_mounting(sim: SimulatedKrc4) -> None:
    """The settled reading is computed once per pose, payload and mounting; each change gives a new one."""
    sim.store.update("$PERI_RDY", "TRUE")

    def torques() -> np.ndarray:
        return np.array([float(sim.store.read(f"$TORQUE_AXIS_ACT[{i}]")) for i in range(1, 7)])

    def expected() -> np.ndarray:
        return np.round(sim.model.static_reading_nm(sim.interpreter.axes_deg, sim.payload), 3)

    first = torques()
    np.testing.assert_allclose(first, expected(), atol=1e-9)
    sim.mount(dut_payload(80.0, (0.0, 0.1, 0.3)))
    loaded = torques()
    assert np.abs(loaded - first).max() > 10.0
    np.testing.assert_allclose(loaded, expected(), atol=1e-9)
    sim.model.knock([0.0, 5.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(torques() - loaded, [0.0, 5.0, 0.0, 0.0, 0.0, 0.0], atol=2e-3)
    sim.interpreter.axes_deg = sim.interpreter.axes_deg + np.array([0.0, 0.0, 10.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(torques(), expected(), atol=1e-9)
