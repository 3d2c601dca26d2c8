"""The simulated KR C4 in its own OS process, as a real controller is its own machine.

Run in the daemon's process, the simulator's CPU work (KRL interpreter, physics, writing trace files) competes with
the daemon for the interpreter lock and can delay the interlock monitor's 20 Hz snapshots by more than its staleness
limit. In a child process it competes only for CPU cores, as a real KR C4 on the network would not at all.

The parent talks to the child over a pipe for what the lab does beside the network (the operator mounting a load)
and what a test may inspect (the ground truth of the last trace)::

    with SimProcess(share_dir, seed=2024, time_scale=200.0, globals_dat=text) as sim:
        ... Controller.connect(host="127.0.0.1", port=sim.port) ...
        await sim.mount(payload)
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from rgse_daemon.errors import RgseError
from simulators.krc4.physics import Payload, TraceTruth

log = logging.getLogger(__name__)

#: Deadline for the child to import, start listening and report its port (s).
START_TIMEOUT_S = 60.0
#: Deadline of one request to the child (mount, truth) (s).
REQUEST_TIMEOUT_S = 10.0
#: Deadline for a clean stop before the child is terminated (s).
STOP_TIMEOUT_S = 20.0


class SimProcessError(RgseError):
    """The simulator process did not start, did not answer in time, or refused a request."""


def _child_main(conn: Connection, share_dir: str, seed: int | None, time_scale: float, latency_s: float,
                globals_dat: str | None, file_rate_bytes_s: float | None = None, robot: str | None = None) -> None:
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s sim: %(name)s: %(message)s")
    try:
        asyncio.run(_child(conn, share_dir, seed, time_scale, latency_s, globals_dat, file_rate_bytes_s, robot))
    except KeyboardInterrupt:  # the parent's Ctrl-C reaches the whole process group
        pass


async def _child(conn: Connection, share_dir: str, seed: int | None, time_scale: float, latency_s: float,
                 globals_dat: str | None, file_rate_bytes_s: float | None = None, robot: str | None = None) -> None:
    from rgse_daemon import robots
    from simulators.krc4.scenario import ServerBehaviour, scenario_for  # the parent needs none of it
    from simulators.krc4.sim import SimulatedKrc4

    loop = asyncio.get_running_loop()
    try:
        scenario = scenario_for(robots.DEFAULT_KEY if robot is None else robot)
        if file_rate_bytes_s is not None:
            scenario = scenario.model_copy(
                update={"server": ServerBehaviour(file_rate_bytes_s=file_rate_bytes_s)})
        sim = SimulatedKrc4(share_dir, scenario=scenario, seed=seed, time_scale=time_scale, latency_s=latency_s)
        await sim.start()
    except Exception as exc:
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    try:
        if globals_dat is not None:
            sim.install_globals(globals_dat)  # installed once on a real controller (krl/README.md)
        conn.send(("ready", sim.port, str(sim.share_dir)))
        while True:
            try:
                msg = await loop.run_in_executor(None, conn.recv)
            except EOFError:  # the parent is gone
                return
            verb = msg[0]
            if verb == "stop":
                return
            try:
                if verb == "mount":
                    sim.mount(msg[1])
                    conn.send(("ok", None))
                elif verb == "truth":
                    conn.send(("ok", sim.truth))
                elif verb == "peek":  # the controller's own variables, as its smartPAD shows them
                    conn.send(("ok", {name: sim.store.read(name) for name in msg[1]}))
                elif verb == "update":  # a variable changed on the controller's side (e.g. the mode selector)
                    sim.store.update(msg[1], msg[2])
                    conn.send(("ok", None))
                elif verb == "fault":  # set one of the server's fault injections (server.Faults)
                    setattr(sim.server.faults, msg[1], msg[2])
                    conn.send(("ok", None))
                else:
                    conn.send(("error", f"unknown request {verb!r}"))
            except Exception as exc:
                conn.send(("error", f"{verb}: {type(exc).__name__}: {exc}"))
    finally:
        await sim.close()


class SimProcess:
    """A :class:`~simulators.krc4.sim.SimulatedKrc4` served from a child process (``spawn``); see the module doc."""

    def __init__(
        self,
        share_dir: Path,
        *,
        seed: int | None = 0,
        time_scale: float = 100.0,
        latency_s: float = 0.002,
        globals_dat: str | None = None,
        file_rate_bytes_s: float | None = None,
        robot: str | None = None,
    ) -> None:
        """``file_rate_bytes_s``: the controller's file work (``None``: the server's default, a real C3 Bridge's
        ~100 kB/s); scaled up along with ``time_scale`` where large traces are pulled. ``robot``: the simulated arm
        (a key of ``rgse_daemon.robots``; ``None``: the default KR 500 R2830) with its scenario."""
        self.share_dir = Path(share_dir)
        ctx = mp.get_context("spawn")  # no fork of a process that runs threads and an event loop
        self._conn, child_conn = ctx.Pipe()
        self._proc = ctx.Process(
            target=_child_main,
            args=(child_conn, str(self.share_dir), seed, time_scale, latency_s, globals_dat, file_rate_bytes_s, robot),
            name="rgse-sim-krc4",
            daemon=True,
        )
        self._child_conn = child_conn
        self._lock = threading.Lock()
        self._broken: str | None = None
        self.port = 0

    def start(self) -> None:
        """Start the child and wait until it listens (blocking, bounded by :data:`START_TIMEOUT_S`)."""
        self._proc.start()
        self._child_conn.close()  # the child holds its end; EOF reaches us if it dies
        if not self._conn.poll(START_TIMEOUT_S):
            self._kill()
            raise SimProcessError(f"simulated KR C4 process did not start within {START_TIMEOUT_S:.0f} s")
        try:
            reply = self._conn.recv()
        except EOFError:
            self._kill()
            raise SimProcessError(f"simulated KR C4 process exited at start (code {self._proc.exitcode})") from None
        if reply[0] != "ready":
            self._kill()
            raise SimProcessError(f"simulated KR C4 process failed to start: {reply[1]}")
        self.port = int(reply[1])
        self.share_dir = Path(reply[2])

    def stop(self) -> None:
        """Ask the child to close its server and programs; terminate it if it does not within the deadline."""
        if self._proc.is_alive():
            try:
                with self._lock:
                    self._conn.send(("stop",))
            except (BrokenPipeError, OSError):
                pass  # the child is already gone: join/terminate below
            self._proc.join(STOP_TIMEOUT_S)
        self._kill()
        self._conn.close()

    def _kill(self) -> None:
        if self._proc.is_alive():
            log.warning("simulated KR C4 process did not stop in time: terminating it")
            self._proc.terminate()
            self._proc.join(5.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(5.0)

    def __enter__(self) -> SimProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _request_blocking(self, msg: tuple[Any, ...]) -> Any:
        with self._lock:
            if self._broken is not None:
                raise SimProcessError(f"simulated KR C4 process unusable: {self._broken}")
            try:
                self._conn.send(msg)
                if not self._conn.poll(REQUEST_TIMEOUT_S):
                    # a late answer would be taken for the next request's: this pipe cannot be used again
                    self._broken = f"no answer to {msg[0]!r} within {REQUEST_TIMEOUT_S:.0f} s"
                    raise SimProcessError(f"simulated KR C4 process: {self._broken}")
                reply = self._conn.recv()
            except (EOFError, BrokenPipeError, OSError) as exc:
                self._broken = f"pipe closed ({type(exc).__name__})"
                raise SimProcessError(f"simulated KR C4 process: {self._broken}") from exc
        if reply[0] != "ok":
            raise SimProcessError(f"simulated KR C4 process refused {msg[0]!r}: {reply[1]}")
        return reply[1]

    async def mount(self, payload: Payload) -> None:
        """The operator bolts ``payload`` onto the flange (builders in ``simulators.krc4.physics``)."""
        await asyncio.to_thread(self._request_blocking, ("mount", payload))

    async def peek(self, *names: str) -> dict[str, str]:
        """The simulator's own values of ``names`` (ground truth, not what a client read over the link)."""
        return await asyncio.to_thread(self._request_blocking, ("peek", names))

    async def fault(self, name: str, value: Any) -> None:
        """Set ``server.faults.<name>`` in the child (see :class:`simulators.krc4.server.Faults`)."""
        await asyncio.to_thread(self._request_blocking, ("fault", name, value))

    async def update(self, name: str, value: str) -> None:
        """Set ``name`` to the value text ``value`` in the controller's variable store (no client involved)."""
        await asyncio.to_thread(self._request_blocking, ("update", name, value))

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    async def truth(self) -> TraceTruth | None:
        """Ground truth of the last trace the simulator wrote."""
        return await asyncio.to_thread(self._request_blocking, ("truth",))
