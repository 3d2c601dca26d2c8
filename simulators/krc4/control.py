"""The simulated KR C4's lab side: what a person at the robot does, offered on a small control port.

On a real cell people mount loads, turn the mode selector, hold the enabling switch and acknowledge stop messages;
none of that goes over the controller's C3 Bridge port. ``rgse sim`` therefore serves those actions on a port of
their own (``--control-port``, loopback by default), and ``rgse sim-op`` is its client, so that the lab's path can be
rehearsed on the simulator: a campaign's loads and a DuT mounted when the daemon asks for them.

Wire: one JSON object per line (UTF-8, at most :data:`MAX_LINE_BYTES`), one JSON reply per line:
``{"ok": true, ...}`` or ``{"ok": false, "error": "<what was wrong>"}``. Requests (``op``):

==================  =====================================================================================
``mount``           ``load``: ``{"kind": "nothing"}`` (bare flange), ``{"kind": "mpa"}`` (the mounting plate),
                    ``{"kind": "bodies", "n_cb": N}`` (MPA + N calibration bodies, Table 1),
                    ``{"kind": "torque", "n_cb": N, "cb_lever_a5_m": L}`` (MPA, test adapter, N bodies at L),
                    ``{"kind": "point", "point": {...}}`` (what a daemon's confirm prompt asks for),
                    ``{"kind": "dut", "mass_kg": M, "cog_m": [x, y, z], "inertia_kgm2": [Jx, Jy, Jz],
                    "fixture_mass_kg": F}`` (a device under test on its fixture on the MPA; inertia and fixture
                    optional). Every mounting seats a little differently, as on the real robot.
``mode``            ``mode``: ``T1``, ``T2``, ``AUT`` or ``EX`` (the mode selector; a running program stops)
``enabling_switch`` ``held``: true or false (releasing it in T1 is a STOP 2 with a stop message)
``acknowledge``     acknowledge the stop message on the smartPAD
``status``          what is mounted, the mode, the program state and the time scale
==================  =====================================================================================
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import Callable, Mapping
from typing import Any

from simulators.krc4.physics import (
    FIXTURE_MASS_KG,
    N_CB_MAX,
    Payload,
    campaign_point_payload,
    dut_payload,
    mass_calibration_payload,
    torque_calibration_payload,
)
from simulators.krc4.sim import SimulatedKrc4

log = logging.getLogger(__name__)

#: Longest request line accepted (bytes); a longer one is answered with an error and the connection closed.
MAX_LINE_BYTES = 4096
#: A client that sends nothing for this long is dropped (s).
IDLE_TIMEOUT_S = 300.0
#: Largest DuT mass the control port mounts (kg): beyond any robot of the project, a typo rather than a load.
MAX_DUT_KG = 2000.0
#: Largest distance of a DuT's CoG from the flange (m).
MAX_COG_M = 3.0


class ControlError(ValueError):
    """A control request that cannot be carried out; the message names the field and the problem."""


def _number(doc: Mapping[str, Any], key: str, lo: float, hi: float, default: float | None = None) -> float:
    value = doc.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ControlError(f"{key}: expected a finite number, got {value!r}")
    if not lo <= value <= hi:
        raise ControlError(f"{key}: {value:g} is outside {lo:g}..{hi:g}")
    return float(value)


def _triple(doc: Mapping[str, Any], key: str, bound: float, default: tuple[float, ...] | None = None) -> tuple[
        float, float, float]:
    value = doc.get(key, default)
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ControlError(f"{key}: expected three numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or abs(v) > bound:
            raise ControlError(f"{key}[{i}]: expected a finite number within +-{bound:g}, got {v!r}")
        out.append(float(v))
    return out[0], out[1], out[2]


def _count(doc: Mapping[str, Any], key: str, hi: int) -> int:
    value = doc.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
        raise ControlError(f"{key}: expected a whole number 0..{hi}, got {value!r}")
    return value


def payload_of(load: Any) -> tuple[Payload, str]:
    """The payload a ``mount`` request's ``load`` describes, and a one-line description of it."""
    if not isinstance(load, dict):
        raise ControlError(f"load: expected an object with a 'kind', got {load!r}")
    kind = load.get("kind")
    try:
        if kind == "nothing":
            return Payload(), "nothing (bare flange)"
        if kind == "mpa":
            return mass_calibration_payload(0), "the MPA"
        if kind == "bodies":
            n = _count(load, "n_cb", N_CB_MAX)
            return mass_calibration_payload(n), f"the MPA with {n} calibration bodies"
        if kind == "torque":
            n = _count(load, "n_cb", N_CB_MAX)
            lever = _number(load, "cb_lever_a5_m", 0.0, 10.0)
            return torque_calibration_payload(n, lever), f"the test adapter with {n} bodies at {lever:g} m from A5"
        if kind == "point":
            point = load.get("point")
            if not isinstance(point, dict) or point.get("kind") not in ("zero", "mass", "torque", "torsional"):
                raise ControlError("point: expected a confirm prompt's data with kind zero, mass, torque or torsional")
            return campaign_point_payload(point), f"the load of a {point['kind']} point"
        if kind == "dut":
            mass = _number(load, "mass_kg", 0.0, MAX_DUT_KG)
            if mass <= 0.0:
                raise ControlError("mass_kg: a DuT has a mass > 0")
            cog = _triple(load, "cog_m", MAX_COG_M)
            inertia = _triple(load, "inertia_kgm2", 1e4, (0.0, 0.0, 0.0))
            fixture = _number(load, "fixture_mass_kg", 0.0, MAX_DUT_KG, FIXTURE_MASS_KG)
            return (dut_payload(mass, cog, inertia, fixture_mass_kg=fixture),
                    f"a DuT of {mass:g} kg at CoG {cog} m on a {fixture:g} kg fixture")
    except (KeyError, TypeError) as exc:
        raise ControlError(f"load {kind}: missing or wrong field ({exc})") from exc
    except ValueError as exc:
        if isinstance(exc, ControlError):
            raise
        raise ControlError(f"load {kind}: {exc}") from exc
    raise ControlError(f"load.kind: {kind!r} is not one of nothing, mpa, bodies, torque, point, dut")


class ControlServer:
    """Serves :mod:`simulators.krc4.control`'s requests for one :class:`SimulatedKrc4` (loopback by default)."""

    def __init__(self, sim: SimulatedKrc4, host: str = "127.0.0.1", port: int = 0) -> None:
        self.sim = sim
        self.host = host
        self._port = port
        self._server: asyncio.Server | None = None
        self.mounted = "nothing (bare flange)"
        self._ops: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
            "mount": self._mount, "mode": self._mode, "enabling_switch": self._enabling_switch,
            "acknowledge": self._acknowledge, "status": self._status,
        }

    @property
    def port(self) -> int:
        assert self._server is not None, "not started"
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, self.host, self._port, limit=MAX_LINE_BYTES + 2)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            async with asyncio.timeout(5.0):
                await self._server.wait_closed()

    def handle(self, line: bytes) -> dict[str, Any]:
        """One request line to its reply (errors as ``{"ok": false, "error": ...}``, never raised)."""
        try:
            try:
                doc = json.loads(line.decode("utf-8"), object_pairs_hook=_unique_keys)
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ControlError(f"request is not a JSON object: {exc}") from exc
            if not isinstance(doc, dict):
                raise ControlError("request is not a JSON object")
            op = doc.get("op")
            if op not in self._ops:
                raise ControlError(f"op: {op!r} is not one of {', '.join(self._ops)}")
            return {"ok": True, **self._ops[op](doc)}
        except ControlError as exc:
            return {"ok": False, "error": str(exc)}

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                try:
                    async with asyncio.timeout(IDLE_TIMEOUT_S):
                        line = await reader.readline()
                except (TimeoutError, ConnectionError):
                    return
                except ValueError:  # longer than the limit
                    writer.write(b'{"ok": false, "error": "request line too long"}\n')
                    await writer.drain()
                    return
                if not line:
                    return
                if not line.strip():
                    continue
                reply = self.handle(line)
                writer.write(json.dumps(reply).encode() + b"\n")
                async with asyncio.timeout(10.0):
                    await writer.drain()
        except (ConnectionError, TimeoutError):
            return  # the client went away or stopped reading: its connection is closed below
        finally:
            writer.close()

    # --- the operations -----------------------------------------------------------------------------------------
    def _mount(self, doc: dict[str, Any]) -> dict[str, Any]:
        payload, what = payload_of(doc.get("load"))
        self.sim.mount(payload)
        self.mounted = what
        log.info("mounted %s (%.3f kg)", what, payload.mass_kg)
        return {"mounted": what, "mass_kg": round(payload.mass_kg, 6)}

    def _mode(self, doc: dict[str, Any]) -> dict[str, Any]:
        mode = doc.get("mode")
        if not isinstance(mode, str):
            raise ControlError(f"mode: expected T1, T2, AUT or EX, got {mode!r}")
        try:
            self.sim.set_mode(mode)
        except ValueError as exc:
            raise ControlError(f"mode: {exc}") from exc
        return {"mode": mode.strip().upper().lstrip("#")}

    def _enabling_switch(self, doc: dict[str, Any]) -> dict[str, Any]:
        held = doc.get("held")
        if not isinstance(held, bool):
            raise ControlError(f"held: expected true or false, got {held!r}")
        self.sim.set_enabling_switch(held)
        return {"enabling_switch": "held" if held else "released"}

    def _acknowledge(self, doc: dict[str, Any]) -> dict[str, Any]:
        self.sim.acknowledge()
        return {"acknowledged": True}

    def _status(self, doc: dict[str, Any]) -> dict[str, Any]:
        return {"mounted": self.mounted, "mass_kg": round(self.sim.payload.mass_kg, 6),
                "mode": self.sim.store.read("$MODE_OP").lstrip("#"),
                "program_state": self.sim.store.read("$PRO_STATE1").lstrip("#"),
                "time_scale": self.sim.clock.time_scale}


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise ControlError(f"duplicate key {key!r} in the request")
        doc[key] = value
    return doc
