"""The KR C4 as the daemon's procedures see it: :class:`KrcController`, the values it returns, and nothing of a wire.

The engine (``procedures/``), the interlock (``safety/monitor.py``, ``safety/makesafe.py``), recovery
(``services/recovery.py``) and ``rgse doctor`` are typed against :class:`KrcController`, a structural
:class:`typing.Protocol`. What implements it:

* :class:`rgse_daemon.controller.Controller`: the TCP link to a real (or simulated) KR C4, which switches between C3
  Bridge and plain KUKAVARPROXY inside itself (snapshots, files over the wire or the mounted share);
* in the tests, the same :class:`~rgse_daemon.controller.Controller` over an in-process link to the simulated KR C4
  (``simulators/krc4/inprocess.py``): no socket, every other part the same (docs/architecture.md, "The controller
  interface").

A new controller protocol (RSI, mxAutomation) implements these methods; the procedures do not change.

The values (:class:`Snapshot`, :class:`Pose`, :class:`LoadData`, :class:`DirEntry`) live here, below every
implementation; :mod:`rgse_daemon.controller` re-exports them.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from rgse_daemon import config
from rgse_daemon.errors import VariableError
from rgse_daemon.filelayout import FileLayout
from rgse_daemon.link.krlvalue import KrlValue

AXES = range(1, 7)
#: What one snapshot reads, in this order (26 variables: one #6 with C3 Bridge).
SNAPSHOT_VARIABLES: tuple[str, ...] = (
    "$MODE_OP",
    "$PRO_STATE1",
    "$PRO_NAME1[]",
    "$AXIS_ACT",
    "$POS_ACT",
    *(f"$TORQUE_AXIS_ACT[{i}]" for i in AXES),
    *(f"$MOT_TEMP[{i}]" for i in AXES),
    "$TRACE.STATE",
    "$PERI_RDY",
    "$USER_SAF",
    "$STOPMESS",
    "$OV_PRO",
    "$LOAD",
    "$BRAKE_SIG",
    "$VEL_ACT",
    "$ROB_STOPPED",
)


@dataclass(frozen=True)
class Pose:
    """``$POS_ACT``: TCP position in mm and orientation in degrees (KUKA A/B/C = Z/Y/X Euler angles)."""

    x_mm: float
    y_mm: float
    z_mm: float
    a_deg: float
    b_deg: float
    c_deg: float
    status: int | None = None
    turn: int | None = None


@dataclass(frozen=True)
class LoadData:
    """``$LOAD``: payload mass in kg (−1 = "unknown payload" mode), centre of mass in mm, inertia in kg·m²."""

    mass_kg: float
    cog_mm: tuple[float, float, float]
    inertia_kgm2: tuple[float, float, float]


@dataclass(frozen=True)
class Snapshot:
    """One reading of the controller's state. A field is ``None`` when its variable could not be read or parsed;
    ``errors`` then says why (by variable name). ``raw`` keeps every value text as read.

    Enumerations are given without ``#`` (``mode_op == "T1"``, ``pro_state1 == "P_ACTIVE"``).
    """

    taken_at_s: float  # wall clock (time.time()) when the read finished
    read_duration_s: float
    mode_op: str | None
    pro_state1: str | None
    pro_name1: str | None
    axes_deg: tuple[float, ...] | None  # A1..A6 of $AXIS_ACT
    pos_act: Pose | None
    torques_nm: tuple[float | None, ...]  # $TORQUE_AXIS_ACT[1..6]
    motor_temps_k: tuple[float | None, ...]  # $MOT_TEMP[1..6], Kelvin
    trace_state: str | None
    peri_rdy: bool | None
    user_saf: bool | None
    stopmess: bool | None
    ov_pro_pct: int | None
    load: LoadData | None
    brake_sig: str | None  # one character per axis, "1" = brake released
    vel_act_m_s: float | None
    rob_stopped: bool | None
    raw: Mapping[str, str] = field(default_factory=dict)
    errors: Mapping[str, str] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return not self.errors


@dataclass(frozen=True)
class DirEntry:
    """One entry of :meth:`KrcController.list_dir`: the name as the server gave it (a full name or only the entry's
    own) and the server's info text, whose format the protocol leaves open (parsed defensively)."""

    name: str
    info: str = ""
    listed_as: str = ""
    """The name exactly as the server listed it, when that was not the full name (only the entry's own name)."""

    @property
    def is_dir(self) -> bool:
        return self.name.endswith(("\\", "/"))

    @property
    def base_name(self) -> str:
        return re.split(r"[\\/]", self.name.rstrip("\\/"))[-1]

    @property
    def size_bytes(self) -> int | None:
        """The size if the info text is ``<itemType>;<sizeBytes>;<attributes>;<modified>`` (four integers), else
        ``None``: an unknown format is never guessed at."""
        parts = self.info.split(";")
        if len(parts) == 4 and all(p.strip().isdigit() for p in parts):
            return int(parts[1])
        return None


@runtime_checkable
class KrcController(Protocol):
    """What the procedures, the interlock, recovery and ``rgse doctor`` ask of the controller.

    Every method raises :class:`~rgse_daemon.errors.LinkError` (``LinkTimeout``, ``LinkClosed``) when the controller
    cannot be reached, :class:`~rgse_daemon.errors.VariableError` when it refuses one variable,
    :class:`~rgse_daemon.link.errors.CommandError` when it refuses a command or file operation, and
    :class:`~rgse_daemon.errors.NotAllowedError` for a write outside the allow-list (before anything is sent).
    """

    layout: FileLayout | None
    """The TRACE folder's working path form (``rgse doctor``'s record, or probed); the doctor sets it to try one."""

    @property
    def protocol(self) -> config.Protocol:
        """Which server answers (C3 Bridge or plain KUKAVARPROXY): what the doctor reports and checks."""
        ...

    def health(self) -> dict[str, object]:
        """Link health for the ``state`` topic."""
        ...

    def busy_until(self) -> float:
        """Monotonic time by which the controller's file work in flight must end (0.0: none)."""
        ...

    def file_timeout_s(self, size_bytes: int) -> float:
        """Deadline of one file operation moving ``size_bytes``."""
        ...

    # --- variables --------------------------------------------------------------------------------------------------
    async def snapshot(self) -> Snapshot:
        """:data:`SNAPSHOT_VARIABLES` read at once and decoded; an unreadable variable leaves its field ``None``."""
        ...

    async def read_raw(self, name: str) -> str:
        """The value text of one variable."""
        ...

    async def read(self, name: str) -> KrlValue:
        """One variable, parsed."""
        ...

    async def read_many(self, names: Sequence[str]) -> Mapping[str, str | VariableError]:
        """Many variables: each name maps to its value text or the error that refused it."""
        ...

    async def write(self, name: str, value: KrlValue) -> KrlValue:
        """Write a Python value as KRL (allow-list only)."""
        ...

    async def write_raw(self, name: str, text: str) -> str:
        """Write KRL value text as is (allow-list only)."""
        ...

    # --- programs ---------------------------------------------------------------------------------------------------
    async def select_program(self, name: str, params: str = "", *, force: bool = False) -> None: ...

    async def start_program(self, interpreter: int = ...) -> None: ...

    async def stop_program(self, interpreter: int = ...) -> None: ...

    async def cancel_program(self, interpreter: int = ...) -> None: ...

    # --- files ------------------------------------------------------------------------------------------------------
    async def put_file(self, name: str, data: bytes) -> None:
        """Write ``data`` to controller file ``name`` (overwriting)."""
        ...

    async def get_file(self, name: str, *, size_bytes: int | None = None) -> bytes:
        """The content of controller file ``name`` (exactly ``size_bytes`` of them when given)."""
        ...

    async def list_dir(self, path: str) -> list[DirEntry]:
        """Entries of a controller folder or mask."""
        ...

    async def delete_file(self, name: str, *, always: bool = False) -> None:
        """Delete controller file ``name``."""
        ...
