"""A simulated Modbus TCP safety I/O module (pymodbus server) with settable inputs and fault injection.

Public API
----------
``ModbusIoSim(cfg=ModbusConfig(), host="127.0.0.1", port=0)``
    ``await sim.start()`` binds (port 0 picks a free port; ``sim.port`` tells which), ``await sim.stop()``;
    also ``async with``. ``start()`` after ``stop()`` serves again on the same port (a module reboot).
``sim.set_input("area_cleared" | "aut_permitted" | "estop_ok", bool)``; ``sim.inputs`` (dict).
``sim.light`` -> ``"off" | "green" | "yellow" | "red" | "invalid"`` (several lamps on), ``sim.running``,
``sim.coils`` (dict address -> bool of every coil written), ``sim.requests`` (count served).
Fault injection: ``sim.drop_connections()`` (close every client socket, keep listening), ``sim.mute = True``
(read requests but never answer), ``sim.refuse = True`` (answer every request with exception code 4,
SERVER_DEVICE_FAILURE), ``stop()`` (stop serving).

The register map is the client's ``ModbusConfig`` (see ``rgse_daemon.io.modbus``): the sim serves the inputs on
the configured table and addresses, the outputs as coils. Like a real I/O module, its coils start at 0 (all
lamps off) on every start.
"""

from __future__ import annotations

from typing import Literal

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from rgse_daemon.config import ModbusConfig

InputName = Literal["area_cleared", "aut_permitted", "estop_ok"]
_READ_FC = {1: "coils", 2: "discrete_inputs"}
_WRITE_COIL_FC = (5, 15)


class ModbusIoSim:
    """One simulated I/O module; its state lives here in Python, the pymodbus datastore is synced on access."""

    def __init__(self, cfg: ModbusConfig | None = None, host: str = "127.0.0.1", port: int = 0) -> None:
        self.cfg = cfg or ModbusConfig()
        self.host = host
        self.port = port
        self.inputs: dict[str, bool] = {"area_cleared": False, "aut_permitted": False, "estop_ok": False}
        self.coils: dict[int, bool] = {}
        self.mute = False
        self.refuse = False
        self.requests = 0
        self._server: ModbusTcpServer | None = None

    # test-side controls -----------------------------------------------------------------------------------
    def set_input(self, name: InputName, value: bool) -> None:
        if name not in self.inputs:
            raise KeyError(f"unknown input {name!r}; known: {sorted(self.inputs)}")
        self.inputs[name] = bool(value)

    def set_all_inputs(self, value: bool) -> None:
        for name in self.inputs:
            self.inputs[name] = bool(value)

    @property
    def light(self) -> str:
        out = self.cfg.outputs
        on = [
            color
            for color, addr in (("green", out.light_green), ("yellow", out.light_yellow), ("red", out.light_red))
            if self.coils.get(addr, False)
        ]
        if not on:
            return "off"
        return on[0] if len(on) == 1 else "invalid"

    @property
    def running(self) -> bool:
        return self.coils.get(self.cfg.outputs.running, False)

    @property
    def serving(self) -> bool:
        return self._server is not None

    def drop_connections(self) -> None:
        """Close every client connection (as a module whose switch port flaps); keep listening."""
        if self._server is not None:
            for conn in list(self._server.active_connections.values()):
                conn.close()

    # lifecycle --------------------------------------------------------------------------------------------
    async def start(self) -> None:
        if self._server is not None:
            return
        self.coils = {}  # a rebooted module starts with its outputs off
        addrs = [*self.cfg.inputs.model_dump().values(), *self.cfg.outputs.model_dump().values()]
        n_bits = (max(addrs) // 16 + 1) * 16
        device = SimDevice(
            id=0,  # answers every unit id
            simdata=(
                [SimData(0, values=[False] * n_bits, datatype=DataType.BITS)],
                [SimData(0, values=[False] * n_bits, datatype=DataType.BITS)],
                [SimData(0, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, values=0, datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )
        server = ModbusTcpServer(device, address=(self.host, self.port), trace_packet=self._trace_packet)
        await server.serve_forever(background=True)
        self._server = server
        self.port = server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()

    async def __aenter__(self) -> ModbusIoSim:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # pymodbus hooks ---------------------------------------------------------------------------------------
    def _trace_packet(self, sending: bool, packet: bytes) -> bytes:
        """Outgoing packets vanish while muted: the client sees a module that no longer answers."""
        return b"" if (sending and self.mute) else packet

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        _count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """Called by pymodbus before every access: refuse if asked, sync inputs in, record coil writes."""
        self.requests += 1
        if self.refuse:
            return ExcCodes.DEVICE_FAILURE
        if function_code in _WRITE_COIL_FC and set_values is not None:
            for i, value in enumerate(set_values):
                self.coils[address + i] = bool(value)
        table = _READ_FC.get(function_code)
        if table is not None:
            self._sync_bits(table, start_address, registers)
        return None

    def _sync_bits(self, table: str, start_register: int, registers: list[int]) -> None:
        """Write the Python-side state into the packed registers pymodbus is about to answer from."""
        bits: dict[int, bool] = {}
        if table == "coils":
            bits.update(self.coils)
        if table == self.cfg.input_table:
            ins = self.cfg.inputs
            bits[ins.area_cleared] = self.inputs["area_cleared"]
            bits[ins.aut_permitted] = self.inputs["aut_permitted"]
            bits[ins.estop_ok] = self.inputs["estop_ok"]
        for addr, value in bits.items():
            reg, bit = addr // 16 - start_register, addr % 16
            if 0 <= reg < len(registers):
                registers[reg] = registers[reg] | (1 << bit) if value else registers[reg] & ~(1 << bit)
