"""The daemon's configuration: a TOML file validated by pydantic models.

Unknown keys are an error, every bound is checked here, before any network I/O. Environment variables
``RGSE_<SECTION>__<KEY>`` override the file (e.g. ``RGSE_CONTROLLER__HOST=10.0.0.5``), as systemd units
and CI like to do.
"""

from __future__ import annotations

import functools
import math
import os
import re
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, get_args

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict, SettingsError

from rgse_daemon import robots
from rgse_daemon.errors import ConfigError
from rgse_daemon.robots import RobotModel

#: ISO 10218-1 reduced speed that the controller itself enforces in T1 (docs/controller.md §2).
T1_CONTROLLER_LIMIT_MM_S = 250.0

Seconds = Annotated[float, Field(gt=0.0, le=3600.0)]

#: The largest ``measurement.drift_prior_per_k`` (1/K): 5 %/K, over ten times any drift a warmed-up drive's torque
#: estimate is known to have; beyond it the bound is a typo, not a prior.
MAX_DRIFT_PRIOR_PER_K = 0.05


T = TypeVar("T")


def _non_empty_path(value: object) -> object:
    # Path("") is Path("."): an empty path would silently mean the current directory
    if isinstance(value, str) and not value.strip():
        raise ValueError('must not be empty (write "." for the current directory)')
    return value


#: A path from the file: TOML has no path type, so a string is the path (strict mode would want a Path object).
ConfigPath = Annotated[Path, Strict(False), BeforeValidator(_non_empty_path)]

#: A TOML array (a list) is a tuple; its items stay strict (the model's mode).
Array = Annotated[T, Strict(False)]


# --- the Modbus safety I/O module (io/modbus.py) ---------------------------------------------------------------
Address = int  # zero-based Modbus address of one bit
MAX_BITS_PER_READ = 2000  # Modbus application protocol limit for FC 1 / FC 2


# --- configuration -------------------------------------------------------------------------------------------
class _Strict(BaseModel):
    # strict: a wrong type in the file is an error, never coerced (true is no port, "10" no loop count); an int is
    # still a float. Environment overrides are text and are converted before (see _LaxEnvironment).
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


class InputMap(_Strict):
    """Addresses of the three safety inputs (one bit each, 1 = safe)."""

    area_cleared: Address = Field(0, ge=0, le=65535)
    aut_permitted: Address = Field(1, ge=0, le=65535)
    estop_ok: Address = Field(2, ge=0, le=65535)


class OutputMap(_Strict):
    """Coil addresses of the stack light and the "measurement running" output."""

    light_green: Address = Field(0, ge=0, le=65535)
    light_yellow: Address = Field(1, ge=0, le=65535)
    light_red: Address = Field(2, ge=0, le=65535)
    running: Address = Field(3, ge=0, le=65535)


class ModbusConfig(_Strict):
    """Where the safety I/O module is, its register map, and how hard to try."""

    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(502, ge=1, le=65535)
    unit_id: int = Field(1, ge=0, le=247)
    input_table: Literal["discrete_inputs", "coils"] = "discrete_inputs"
    inputs: InputMap = InputMap()
    outputs: OutputMap = OutputMap()
    poll_period_s: float = Field(0.1, gt=0.0, le=10.0)
    stale_after_polls: int = Field(3, ge=2, le=100)
    """A reading older than this many poll periods counts as unsafe."""
    request_timeout_s: float = Field(0.5, gt=0.0, le=30.0)
    connect_timeout_s: float = Field(2.0, gt=0.0, le=60.0)
    reconnect_min_s: float = Field(0.2, gt=0.0, le=60.0)
    reconnect_max_s: float = Field(5.0, gt=0.0, le=600.0)

    @model_validator(mode="after")
    def _consistent(self) -> ModbusConfig:
        if self.reconnect_min_s > self.reconnect_max_s:
            raise ValueError("reconnect_min_s must not exceed reconnect_max_s")
        ins = list(self.inputs.model_dump().values())
        outs = list(self.outputs.model_dump().values())
        if len(set(ins)) != len(ins):
            raise ValueError(f"input addresses must be distinct, got {self.inputs.model_dump()}")
        if len(set(outs)) != len(outs):
            raise ValueError(f"output addresses must be distinct, got {self.outputs.model_dump()}")
        if self.input_table == "coils" and set(ins) & set(outs):
            raise ValueError("with input_table='coils' input and output addresses must not overlap")
        if max(ins) - min(ins) + 1 > MAX_BITS_PER_READ:
            raise ValueError(f"input addresses must lie within {MAX_BITS_PER_READ} bits of each other")
        return self

    @property
    def stale_after_s(self) -> float:
        return self.stale_after_polls * self.poll_period_s


# --- the serial crane scale (io/scale.py) --------------------------------------------------------------------
KERN_LINE_REGEX = r"^(?P<stab>ST|US),(?P<kind>GS|NT),(?P<sign>[+-]) *(?P<value>\d+(?:\.\d+)?) *(?P<unit>[A-Za-z%]+)$"
UNIT_TO_KG: dict[str, float] = {"kg": 1.0, "g": 1e-3, "t": 1e3, "lb": 0.45359237}
_REQUIRED_GROUPS = {"value", "unit"}


class ScaleConfig(BaseModel):
    """How to reach the crane scale and how to read its lines."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)

    port: str = Field("/dev/ttyUSB0", min_length=1)
    """A device path or a pyserial URL such as ``socket://10.0.0.8:4001``."""
    baudrate: int = Field(9600, gt=0, le=921600)
    bytesize: Literal[7, 8] = 8
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    mode: Literal["request", "stream"] = "request"
    request_cmd: str = Field("S", min_length=1, max_length=8)
    request_interval_s: float = Field(0.5, gt=0.0, le=60.0)
    resolution_kg: float = Field(0.1, gt=0.0, le=100.0)
    """The scale's d (HFB 300K100: 0.1 kg); sets the uncertainty and the agreement of consecutive frames."""
    line_regex: str = KERN_LINE_REGEX
    stable_tokens: Array[tuple[str, ...]] = ("ST",)
    checksum: Literal["none", "xor8"] = "none"
    stable_frames_required: int = Field(1, ge=1, le=100)
    max_consecutive_bad_frames: int = Field(20, ge=1, le=10_000)
    max_line_bytes: int = Field(128, ge=16, le=4096)
    open_timeout_s: float = Field(3.0, gt=0.0, le=60.0)
    default_timeout_s: float = Field(30.0, gt=0.0, le=3600.0)

    @field_validator("line_regex")
    @classmethod
    def _regex_usable(cls, value: str) -> str:
        try:
            compiled = re.compile(value)
        except re.error as exc:
            raise ValueError(f"line_regex does not compile: {exc}") from exc
        missing = _REQUIRED_GROUPS - set(compiled.groupindex)
        if missing:
            raise ValueError(f"line_regex lacks the named groups {sorted(missing)}")
        return value

    @property
    def u_kg(self) -> float:
        return self.resolution_kg / math.sqrt(3.0)


class _Section(BaseModel):
    # NaN and inf are refused as such ("finite number"), not by a bound they happen to fail.
    # strict as _Strict: wrong types are errors, not coerced
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


class Protocol(StrEnum):
    AUTO = "auto"  # probe @PROXY_TYPE and use C3 Bridge features when present
    C3BRIDGE = "c3bridge"
    KVP = "kvp"


def _default_robot() -> RobotModel:
    return robots.get(robots.DEFAULT_KEY)


class RobotConfig(_Section):
    name: str = Field("KR500R2830", min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$")
    """Robot identity: copied into results, names the MQTT topics, binds calibrations to this robot."""
    model: str = Field(robots.DEFAULT_KEY, min_length=1, max_length=64)
    """Which arm it is (``rgse_daemon/robots/``): its kinematics, axis ranges and speeds, poses, load diagram and
    calibration load set. The limits' defaults and upper bounds are this robot's."""

    @field_validator("model")
    @classmethod
    def _known_model(cls, value: str) -> str:
        return robots.get(value).key


class ControllerConfig(_Section):
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(7000, ge=1, le=65535)
    protocol: Annotated[Protocol, Strict(False)] = Protocol.AUTO  # the file gives the value, a str
    connect_timeout_s: Seconds = 3.0
    request_timeout_s: Seconds = 2.0
    pool_size: int = Field(4, ge=1, le=10)  # KVP serves at most 10 clients
    keepalive_s: float = Field(10.0, gt=0.0, lt=30.0)  # KVP drops clients idle for ~30 s
    reconnect_min_s: Seconds = 0.2
    reconnect_max_s: Seconds = 10.0
    share_dir: ConfigPath | None = None
    """The controller's ``roboter`` share mounted locally: the file path used with plain KUKAVARPROXY."""
    watchdog_bound_s: float = Field(0.75, ge=0.2, le=2.0)
    """The controller-side watchdog (docs/security.md): the heartbeat sets the controller's ``$TIMER[16]`` to minus
    this (ms) on every beat; a program whose heartbeat is older than this brakes on its path and halts."""
    watchdog_period_s: float = Field(0.1, ge=0.02, le=0.5)
    """How often the heartbeat beats; at most a quarter of ``watchdog_bound_s``."""
    watchdog_required: bool = True
    """The static check refuses a program that moves before it arms the watchdog (rule ``WATCHDOG``)."""
    file_rate_bytes_s: float = Field(40_000.0, gt=0.0)
    """The slowest rate (bytes/s) the controller's file work may run at: a file operation's deadline is
    ``request_timeout_s`` + bytes / this. The real C3 Bridge loads a whole file before its first reply; ``rgse
    doctor`` measures the real rate (keep this at about half of it; the default assumes 100 kB/s, 2.5× margin)."""
    time_scale: float = Field(1.0, ge=1.0, le=1000.0)
    """Controller seconds per wall-clock second: 1 for a real KR C4 (the default). A simulated one (``rgse sim
    --time-scale X``) runs X times faster; the run's waits in the robot's time (``measurement.settle_s``,
    ``warmup_steady_window_s``, ``warmup_max_s``) are then divided by X, and a trace's wall time is its configured
    time divided by X (``rgse demo`` sets it to its simulator's scale)."""

    @model_validator(mode="after")
    def _backoff_ordered(self) -> ControllerConfig:
        if self.reconnect_min_s > self.reconnect_max_s:
            raise ValueError("reconnect_min_s must not exceed reconnect_max_s")
        if self.watchdog_period_s > self.watchdog_bound_s / 4.0:
            raise ValueError("watchdog_period_s must be at most a quarter of watchdog_bound_s")
        return self


class PathsConfig(_Section):
    data_dir: ConfigPath = Path("./data")
    """Run archive, raw trace files and the SQLite store live below this directory."""


class LimitsConfig(_Section):
    t1_speed_mm_s: float = Field(200.0, gt=0.0, le=T1_CONTROLLER_LIMIT_MM_S)
    """Worst-case Cartesian speed of any point of the kinematic chain (paper §2.2: 200 mm/s)."""
    a1_range_deg: float = Field(default_factory=lambda: _default_robot().a1_envelope_deg, gt=0.0)
    """Software envelope around A1 (paper §2.2: ±45°); default the robot's, at most its A1 range."""
    max_payload_kg: float = Field(default_factory=lambda: _default_robot().max_payload_kg, gt=0.0)
    """Default and upper bound: the robot's load diagram (KR 500: 611 kg)."""
    max_a5_torque_nm: float = Field(default_factory=lambda: _default_robot().max_a5_torque_nm, gt=0.0)
    """Default and upper bound: the robot's load diagram (KR 500: 3330 Nm)."""
    brake_release_max_deg: float = Field(45.0, gt=0.0, le=90.0)
    snapshot_stale_s: float = Field(0.1, ge=0.05, le=1.0)
    """The runtime monitor polls at 20 Hz; a snapshot older than this (link lost or slow) trips the interlock."""
    max_motion_s: float = Field(600.0, gt=0.0, le=3600.0)
    """Upper bound of one program's motion time (s), or of one pass of a loop that waits for a host command each
    pass (the resident program): a program whose estimated bound is longer is refused (bounded motion)."""
    axis_ramp_max_s: float = Field(2.0, gt=0.0, le=10.0)
    """The longest an axis can take to reach its maximum speed at 100 % ``$ACC_AXIS`` and override (s): the motion
    time bound's assumption about accelerations, which KUKA does not publish (a KR 500 takes well under 1 s)."""


class StoreConfig(_Section):
    url: str | None = None
    """``None``: SQLite file ``<data_dir>/rgse.sqlite3``; ``postgresql://user@host:5432/db`` for a shared store."""

    @model_validator(mode="after")
    def _known_scheme(self) -> StoreConfig:
        if self.url is not None and not self.url.startswith(("postgresql://", "postgres://", "sqlite:///")):
            raise ValueError("url must start with postgresql://, postgres:// or sqlite:///")
        return self


class MeasurementConfig(_Section):
    """The in-line measurement run (paper Fig. 24) and its trace recording."""

    loops: int = Field(10, ge=1, le=100)
    """The most measurement loops, each: brake-release move → settle → trace (paper: 10). A run stops earlier when
    more loops no longer change U (``stop_loop_share``, ``stop_target_U_kg``; rgse_daemon/pipeline/stopping.py)."""
    min_loops: int = Field(3, ge=3, le=100)
    """The fewest loops the stop rule stops at (>= 3: the loop-to-loop consistency check needs three;
    ``pipeline.stopping.MIN_LOOPS``). A ``loops`` below it is the run's count."""
    stop_loop_share: float = Field(0.2, ge=0.0, lt=1.0)
    """Stop once the loop term of U is at most this share of u: more loops could then shrink U by at most
    1 - sqrt(1 - share²) (2 % at 0.2). 0 switches the test off."""
    stop_target_U_kg: float | None = Field(None, gt=0.0)
    """Stop once U (k = 2) predicted for the loops measured is at most this (kg); None: no target."""
    replacement_loops: int = Field(3, ge=0, le=20)
    """Loops a run may measure beyond ``loops`` to replace loops the integrity check set aside (missing samples, a
    step inside the loop, a loop far from the others; rgse_daemon/pipeline/integrity.py) when fewer than
    ``min_loops`` (or ``loops``, if smaller) are kept. Once spent, the mass rests on the loops kept, or the result is
    refused (too few). 0: never measure more than ``loops``."""
    settle_s: float = Field(4.0, ge=0.0, le=120.0)
    """Waiting time after the brake-release move before recording (paper: 2 × 2 s)."""
    trace_period_s: Literal[0.001, 0.004, 0.012] = 0.012
    """KUKA Trace sample period; the controller offers 1, 4 and 12 ms."""
    trace_samples: int = Field(1000, ge=10, le=50_000)
    """Samples per loop and trace (paper: 1 kS per loop); bounded by the controller's trace buffer."""
    brake_release_deg: float = Field(35.0, gt=0.0, le=90.0)
    """φ': the equal angle A3 and A5 rotate by in the brake-release move (paper §2.4.4)."""
    warmup_cycles: int = Field(3, ge=0, le=100)
    """Cycles of one warm-up program run (paper §2.4.4 A); 0 skips the warm-up."""
    warmup_amplitude_deg: float = Field(20.0, gt=0.0, le=90.0)
    warmup_until_steady: bool = True
    """Repeat the warm-up run until the A3 and A5 motor temperatures ($MOT_TEMP) are steady: the torque estimate
    drifts with motor temperature, so the zero point, every calibration point and the DuT must be measured in the
    same thermal state. False: one warm-up run."""
    warmup_steady_k: float = Field(1.0, gt=0.0, le=10.0)
    """Steady: neither motor temperature changed by more than this over the last ``warmup_steady_window_s``."""
    warmup_steady_window_s: float = Field(300.0, ge=0.0, le=3600.0)
    """Warm-up motion time over which the temperatures must stay within ``warmup_steady_k``."""
    warmup_max_s: float = Field(2400.0, gt=0.0, le=14_400.0)
    """Give up waiting for a steady state after this much warm-up motion; the run goes on with a warning."""
    fixture_mass_kg: float = Field(0.0, ge=0.0)
    """m_f: mass of the DuT fixture, subtracted from the gross mass (eq. 21)."""
    drift_prior_per_k: float = Field(0.003, gt=0.0, le=MAX_DRIFT_PRIOR_PER_K)
    """The outer bound on the thermal drift coefficient |β| (1/K) that U carries where the calibration's β is not
    applied (``pipeline.thermal.DRIFT_PRIOR_PER_K``, 0.3 %/K; ``rgse mass --drift-prior`` offline): alone where the
    campaign's temperature span is too small to resolve β, else over the campaign's |β| + 2 u(β)."""
    payload_lever_max_m: float = Field(default_factory=lambda: _default_robot().payload_lever_max_m, gt=0.0, le=3.0)
    """Farthest point of fixture + DuT from the flange: sets the worst-case Cartesian speed."""
    program_timeout_s: Seconds = 600.0
    trace_timeout_s: Seconds = 120.0


Coordinate_m = Annotated[float, Field(ge=-3.0, le=3.0)]
Angle_deg = Annotated[float, Field(ge=-360.0, le=360.0)]
CellCoordinate_m = Annotated[float, Field(ge=-20.0, le=20.0)]
Point_m = Array[tuple[CellCoordinate_m, CellCoordinate_m, CellCoordinate_m]]


class BoxConfig(_Section):
    """An axis-aligned box (m): ``min_m`` and ``max_m`` corners."""

    min_m: Point_m
    max_m: Point_m

    @model_validator(mode="after")
    def _ordered(self) -> BoxConfig:
        if not all(lo < hi for lo, hi in zip(self.min_m, self.max_m, strict=True)):
            raise ValueError(f"min_m {self.min_m} must be below max_m {self.max_m} on every axis")
        return self


#: The default room around the robot's foot (m): walls at ±this in x and y, the ceiling this high above the base (a
#: project choice, the same for every robot; a site sets its own ``[cell] walls``).
CELL_WALLS_HALF_WIDTH_M = 4.5
CELL_CEILING_M = 5.0


def robot_cell_defaults(robot: RobotModel) -> dict[str, Any]:
    """``[cell]``'s defaults for ``robot``: its ``cell`` (the frame it stands on, the payload's box) in the default
    room."""
    c = robot.cell
    h, w, room = c.frame_height_m, c.frame_half_width_m, CELL_WALLS_HALF_WIDTH_M
    return {
        "floor_z_m": -h,
        "walls": BoxConfig(min_m=(-room, -room, -h), max_m=(room, room, CELL_CEILING_M)),
        "keep_out": (BoxConfig(min_m=(-w, -w, -h), max_m=(w, w, 0.0)),),
        "payload_box_flange_m": BoxConfig(min_m=c.payload_box_min_m, max_m=c.payload_box_max_m),
    }


def _default_cell(name: str) -> Any:
    return robot_cell_defaults(_default_robot())[name]


class CellConfig(_Section):
    """The cell the robot moves in, for the static check's workspace rule: in the robot's base frame ($ROBROOT: on
    the A1 axis at the robot's foot, z up, x forward at A1 = 0), m. The flange, the wrist centre, the elbow and the
    box of DuT and fixture must stay inside the cell, above the floor and out of every keep-out box along every
    motion. Defaults: the configured robot's (``rgse_daemon/robots/``: its ``cell``); the KR 500's are the paper's
    cell, the robot on its 600 mm frame."""

    floor_z_m: float = Field(default_factory=lambda: _default_cell("floor_z_m"), ge=-5.0, le=0.0)
    """Height of the floor in the base frame: minus the height of the robot's frame (paper: 600 mm)."""
    walls: BoxConfig = Field(default_factory=lambda: _default_cell("walls"))
    """The cell's walls and ceiling (its floor is ``floor_z_m``, whichever is higher counts)."""
    keep_out: Array[tuple[BoxConfig, ...]] = Field(default_factory=lambda: _default_cell("keep_out"))
    """Boxes nothing may enter; default: the robot's frame under its base."""
    payload_box_flange_m: BoxConfig = Field(default_factory=lambda: _default_cell("payload_box_flange_m"))
    """The box around DuT and fixture in the flange frame (m; z out of the flange, x down in the home pose). Keep it
    within ``measurement.payload_lever_max_m`` of the flange on every axis (the speed bound's cube)."""

    @classmethod
    def of_robot(cls, robot: RobotModel) -> CellConfig:
        """The default cell of ``robot``."""
        return cls(**robot_cell_defaults(robot))

    dut_mass_kg: float | None = Field(None, ge=0.0)
    """The DuT's expected mass (kg) for the load diagram check of every push (with the fixture's mass and CoG);
    ``None``: the heaviest the limits allow, less the fixture. At most ``limits.max_payload_kg``."""
    dut_cog_flange_m: Array[tuple[Coordinate_m, Coordinate_m, Coordinate_m]] | None = None
    """The DuT's expected CoG in the flange frame (m); ``None``: on the flange axis, as far out as the A5 torque
    limit allows the heaviest payload with 10 % margin in the measurement pose."""


class FixtureFrameConfig(_Section):
    """The fixture between MPA and DuT and the DuT's own frame, for the CoG (issue #14). The fixture's mass is
    ``measurement.fixture_mass_kg``."""

    cog_flange_m: Array[tuple[Coordinate_m, Coordinate_m, Coordinate_m]] | None = None
    """The fixture's CoG in the flange frame (m); needed when the fixture has a mass (its moment is subtracted)."""
    dut_origin_flange_m: Array[tuple[Coordinate_m, Coordinate_m, Coordinate_m]] = (0.0, 0.0, 0.0)
    """Origin of the DuT's own frame in the flange frame (m)."""
    dut_abc_deg: Array[tuple[Angle_deg, Angle_deg, Angle_deg]] = (0.0, 0.0, 0.0)
    """Orientation of the DuT's frame in the flange frame: KUKA A, B, C (Z-Y-X, deg)."""


class PropertiesConfig(_Section):
    """The mass-properties run (mass, then the CoG poses; interfaces §4, README "Centre of gravity")."""

    scheme: Literal["paper", "full", "lever"] = "full"
    """The CoG poses: ``paper`` (eq. 5-7: measurement pose, A6 +90°), ``full`` (A6 0/90/180/270°, A4/A5 tilts) or
    ``lever`` (the paper's and the multi-pose mass's lever poses: forearm raised, A5 turned back)."""
    mass_method: Literal["single", "multipose", "auto"] = "single"
    """Where a properties run's mass comes from: ``single`` (the paper's pose), ``multipose`` (the lever poses; needs
    scheme ``lever`` and loops_per_pose >= 2; the measurement pose then gets loops_per_pose loops, not the stop rule's,
    and the single pose's figure comes from them) or ``auto`` (chosen before the run by the least predicted U² per
    robot minute)."""
    loops_per_pose: int = Field(2, ge=1, le=20)
    """Brake-release loops (each with one trace of the A3..A6 drives) in every CoG pose."""
    when: Literal["on_request", "every_measurement"] = "on_request"
    """``on_request``: only a properties run (MQTT ``properties``, ``rgse run properties``) measures the CoG;
    ``every_measurement``: every measurement run is a properties run."""
    inertia: bool = False
    """Also the inertia tensor (issue #15): after the CoG poses the DuT's excitation, then, once the operator took
    the DuT off (a prompt), the tare's; needs the calibration's torque gains of A4..A6."""
    inertia_repeats: int = Field(2, ge=1, le=16)
    """Back-and-forth swings of each wrist axis per orientation in the inertia excitation (``excitation.REPEATS``);
    more lower the noise part of the error and lengthen the run (README "Inertia")."""
    fixture: FixtureFrameConfig = FixtureFrameConfig()


class MqttConfig(_Section):
    enabled: bool = False
    host: str = Field("127.0.0.1", min_length=1)
    port: int = Field(1883, ge=1, le=65535)
    prefix: str | None = Field(None, pattern=r"^[^#+]+$")
    """Topic prefix; ``None`` gives ``rgse/<robot name>`` (interfaces §4). A trailing ``/`` is dropped here, once
    (``plant/rgse/`` is ``plant/rgse``): every topic is ``<prefix>/<level>``."""
    username: str | None = None
    password: str | None = None
    tls: bool = False
    tls_ca_file: ConfigPath | None = None
    client_id: str | None = None
    keepalive_s: int = Field(30, ge=5, le=3600)
    reconnect_min_s: Seconds = 0.5
    reconnect_max_s: Seconds = 30.0
    state_rate_hz: float = Field(2.0, gt=0.0, le=50.0)
    """Maximum rate of the retained ``state`` topic; high-rate state beyond the queue is dropped and counted."""
    command_tokens: Array[tuple[str, ...]] = ()
    """If not empty, a command must carry one of these in its ``token`` field (authorisation)."""
    command_auth: Literal["token", "broker_acl", "open_lab_bench"] = "token"
    """Who may send commands that move the robot (docs/security.md). ``token`` (default): only a client that knows
    one of ``command_tokens`` (which must then be set). ``broker_acl``: the broker authenticates every client and its
    ACL lets only operators publish to ``<prefix>/cmd/#`` (deploy/mosquitto.acl); the daemon must log in
    (``username``). ``open_lab_bench``: anyone who reaches the broker — only on an isolated lab bench."""

    @model_validator(mode="after")
    def _commands_authenticated(self) -> MqttConfig:
        if not self.enabled:
            return self
        if self.command_auth == "token" and not self.command_tokens:
            raise ValueError(
                "command_tokens is empty, so any client that reaches the broker could move the robot: set "
                "command_tokens, or command_auth = \"broker_acl\" (broker login + ACL, see docs/security.md), or "
                "command_auth = \"open_lab_bench\" on an isolated lab bench"
            )
        if self.command_auth == "broker_acl" and not self.username:
            raise ValueError("command_auth = \"broker_acl\" needs username (and password): the broker's ACL "
                             "can only tell clients apart when they log in")
        return self

    @field_validator("command_tokens")
    @classmethod
    def _tokens_usable(cls, tokens: tuple[str, ...]) -> tuple[str, ...]:
        for i, t in enumerate(tokens):
            if not t.strip():
                raise ValueError(f"token {i} is empty: an empty token would authorise a command without one")
            if len(t) > 256 or any(c.isspace() or not c.isprintable() for c in t):
                raise ValueError(f"token {i} must be 1-256 printable characters without spaces")
        return tokens

    @field_validator("prefix")
    @classmethod
    def _prefix_without_trailing_slash(cls, prefix: str | None) -> str | None:
        if prefix is None:
            return None
        if not prefix.rstrip("/"):
            raise ValueError(f"{prefix!r}: empty once the trailing '/' is dropped; leave it out for rgse/<robot>")
        return prefix.rstrip("/")


class ConsoleConfig(_Section):
    """The operator's web console served by the daemon (off by default)."""

    enabled: bool = False
    host: str = Field("127.0.0.1", min_length=1)
    """Address to listen on; the default serves only this machine (put a reverse proxy with TLS in front)."""
    port: int = Field(8080, ge=0, le=65535)
    """TCP port; 0 picks a free one (tests)."""
    allowed_hosts: Array[tuple[Annotated[str, Field(min_length=1, max_length=253)], ...]] = ()
    """Host names (without port) the console answers to besides ``host``, ``localhost``, ``127.0.0.1`` and ``::1``
    (and this machine's names when ``host`` is a wildcard): e.g. the name a TLS reverse proxy forwards. A request for
    any other ``Host`` is refused, so that a DNS-rebound name cannot reach the page."""


class Config(BaseSettings):
    """The whole configuration file."""

    model_config = SettingsConfigDict(
        extra="forbid", frozen=True, env_prefix="RGSE_", env_nested_delimiter="__", strict=True
    )

    robot: RobotConfig = RobotConfig()
    controller: ControllerConfig = ControllerConfig()
    paths: PathsConfig = PathsConfig()
    limits: LimitsConfig = LimitsConfig()
    store: StoreConfig = StoreConfig()
    measurement: MeasurementConfig = MeasurementConfig()
    properties: PropertiesConfig = PropertiesConfig()
    cell: CellConfig = CellConfig()
    mqtt: MqttConfig = MqttConfig()
    console: ConsoleConfig = ConsoleConfig()
    modbus: ModbusConfig | None = None
    """The Modbus TCP safety I/O module; absent: no area-cleared input, so AUT is never allowed."""
    scale: ScaleConfig | None = None
    """The reference crane scale on a serial line; absent: `rgse reference` is unavailable."""

    @model_validator(mode="before")
    @classmethod
    def _robot_defaults(cls, data: Any) -> Any:
        # the limits' and the cell's defaults are the configured robot's (a KR 10 must not inherit the KR 500's
        # 611 kg, nor its 1.5 m payload box)
        if not isinstance(data, dict):
            return data
        robot_section = data.get("robot")
        key = robot_section.get("model") if isinstance(robot_section, dict) else None
        if not isinstance(key, str):
            return data
        try:
            robot = robots.get(key)
        except ValueError:
            return data  # RobotConfig names the unknown model
        data = dict(data)
        for section, defaults in (
            ("limits", {"a1_range_deg": robot.a1_envelope_deg, "max_payload_kg": robot.max_payload_kg,
                        "max_a5_torque_nm": robot.max_a5_torque_nm}),
            ("measurement", {"payload_lever_max_m": robot.payload_lever_max_m}),
            ("cell", robot_cell_defaults(robot)),
        ):
            given = data.get(section, {})
            if isinstance(given, dict):
                data[section] = {**defaults, **given}
        return data

    @property
    def robot_model(self) -> RobotModel:
        """The configured arm (``[robot] model``)."""
        return robots.get(self.robot.model)

    @model_validator(mode="after")
    def _limits_within_the_robot(self) -> Config:
        r, lim = self.robot_model, self.limits
        problems = []
        a1_max = min(-r.axis_range_deg[0][0], r.axis_range_deg[0][1])
        if lim.a1_range_deg > a1_max:
            problems.append(f"limits.a1_range_deg = {lim.a1_range_deg:g} exceeds the {r.title}'s A1 range "
                            f"±{a1_max:g} deg")
        if lim.max_payload_kg > r.max_payload_kg:
            problems.append(f"limits.max_payload_kg = {lim.max_payload_kg:g} exceeds the {r.title}'s load diagram "
                            f"({r.max_payload_kg:g} kg)")
        if lim.max_a5_torque_nm > r.max_a5_torque_nm:
            problems.append(f"limits.max_a5_torque_nm = {lim.max_a5_torque_nm:g} exceeds the {r.title}'s load "
                            f"diagram ({r.max_a5_torque_nm:g} Nm)")
        if self.cell.dut_mass_kg is not None and self.cell.dut_mass_kg > lim.max_payload_kg:
            problems.append(f"cell.dut_mass_kg = {self.cell.dut_mass_kg:g} exceeds limits.max_payload_kg = "
                            f"{lim.max_payload_kg:g}")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    @model_validator(mode="after")
    def _properties_fixture(self) -> Config:
        # a measurement that is always a properties run must know where the fixture's mass sits (its moment is part
        # of every CoG pose's torque); an on-request run is checked when it is asked for
        if (self.properties.when == "every_measurement" and self.measurement.fixture_mass_kg > 0
                and self.properties.fixture.cog_flange_m is None):
            raise ValueError("properties.when = \"every_measurement\" with measurement.fixture_mass_kg > 0 needs "
                             "properties.fixture.cog_flange_m (the fixture's CoG in the flange frame, m)")
        return self

    @model_validator(mode="after")
    def _measurement_within_limits(self) -> Config:
        # the interlock refuses a program that breaks a limit: a measurement setting outside the limits would only
        # fail at the push (or at `rgse krl render`), so it is refused here, where its key can be named
        m, lim = self.measurement, self.limits
        problems = []
        refused = "(the interlock would refuse the move; raise the limit only as the cell's risk assessment allows)"
        if m.brake_release_deg > lim.brake_release_max_deg:
            problems.append(f"measurement.brake_release_deg = {m.brake_release_deg:g} exceeds "
                            f"limits.brake_release_max_deg = {lim.brake_release_max_deg:g} {refused}")
        if m.warmup_amplitude_deg > lim.brake_release_max_deg:
            problems.append(f"measurement.warmup_amplitude_deg = {m.warmup_amplitude_deg:g} exceeds "
                            f"limits.brake_release_max_deg = {lim.brake_release_max_deg:g} {refused}")
        if m.fixture_mass_kg > lim.max_payload_kg:
            problems.append(f"measurement.fixture_mass_kg = {m.fixture_mass_kg:g} exceeds "
                            f"limits.max_payload_kg = {lim.max_payload_kg:g} (the fixture alone is over the payload "
                            "limit)")
        cog = self.properties.fixture.cog_flange_m
        if cog is not None and math.hypot(*cog) > m.payload_lever_max_m:
            # the speed bound counts only the points within payload_lever_max_m of the flange
            problems.append(f"properties.fixture.cog_flange_m is {math.hypot(*cog):g} m from the flange, beyond "
                            f"measurement.payload_lever_max_m = {m.payload_lever_max_m:g} (the farthest point of "
                            "fixture + DuT, which the T1 speed bound covers)")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # Environment overrides the file's values (passed as init kwargs); no dotenv or secret dirs. The models are
        # strict for the file; an environment value is text and is converted first (_LaxEnvironment).
        return (_LaxEnvironment(settings_cls, env_settings), init_settings)


@functools.cache
def _lax_adapter(annotation: Any) -> TypeAdapter[Any]:
    return TypeAdapter(annotation)


def _model_of(annotation: Any) -> type[BaseModel] | None:
    """The model class of a section field (``ModbusConfig | None`` too), if it is one."""
    for a in (annotation, *get_args(annotation)):
        if isinstance(a, type) and issubclass(a, BaseModel):
            return a
    return None


def _from_text(fields: dict[str, FieldInfo], data: dict[str, Any]) -> dict[str, Any]:
    """The environment's values converted from text as pydantic's lax mode does (``"7000"`` is port 7000, ``"1"``
    true, as docs/configuration.md promises), field by field; a value that does not convert is left as it is, so the
    strict validation names it (and the variable it came from). Only the type is converted here: every bound and
    check is the model's."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        f = fields.get(key)
        model = _model_of(f.annotation) if f is not None else None
        if f is None or f.annotation is None:
            out[key] = value
        elif model is not None:
            out[key] = _from_text(model.model_fields, value) if isinstance(value, dict) else value
        else:
            try:
                out[key] = _lax_adapter(_with_validators(f)).validate_python(value)
            except ValidationError:
                out[key] = value
    return out


def _with_validators(f: FieldInfo) -> Any:
    """The field's type with its own before-validators (pydantic keeps those of a top-level ``Annotated`` in
    ``metadata``): without them ``""`` converts to ``Path(".")`` and the model's empty-path check never sees the
    text, so ``RGSE_PATHS__DATA_DIR=`` silently meant the current directory. Bounds stay the model's."""
    validators = tuple(m for m in f.metadata if isinstance(m, BeforeValidator))
    return Annotated[(f.annotation, *validators)] if validators else f.annotation


class _LaxEnvironment(PydanticBaseSettingsSource):
    """pydantic-settings' environment source, its text values converted to the fields' types (see _from_text)."""

    def __init__(self, settings_cls: type[BaseSettings], env: PydanticBaseSettingsSource) -> None:
        super().__init__(settings_cls)
        self._env = env

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:
        return self._env.get_field_value(field, field_name)

    def __call__(self) -> dict[str, Any]:
        return _blank_paths_as_text(_from_text(self.settings_cls.model_fields, self._env()))


def _blank_paths_as_text(data: dict[str, Any]) -> dict[str, Any]:
    """A variable set to empty (or blank) text for a path key gives that text back to the model, whose empty-path
    check then refuses it naming the variable. pydantic-settings converts a key's text by its bare type, so ``""``
    arrived here as ``Path(".")``: ``RGSE_PATHS__DATA_DIR=`` (an easy slip in a systemd ``EnvironmentFile``) ran the
    daemon with its store in its working directory instead of refusing to start."""
    for upper, name in _env_variables().items():
        raw = os.environ.get(name)
        if raw is None or raw.strip():
            continue
        *sections, key = upper[len(ENV_PREFIX):].lower().split("__")
        where: Any = data
        for section in sections:
            where = where.get(section) if isinstance(where, dict) else None
        if isinstance(where, dict) and isinstance(where.get(key), Path):
            where[key] = raw
    return data


ENV_PREFIX = "RGSE_"


def _env_variables() -> dict[str, str]:
    """The ``RGSE_*`` environment variables by upper-case name (pydantic-settings matches them case-blind)."""
    return {k.upper(): k for k in os.environ if k.upper().startswith(ENV_PREFIX)}


def _env_name(loc: tuple[int | str, ...], env: dict[str, str]) -> str | None:
    """The environment variable that set the field at ``loc`` (or its section), if one did."""
    keys = [str(p) for p in loc if isinstance(p, str)]
    for k in range(len(keys), 0, -1):
        name = ENV_PREFIX + "__".join(keys[:k]).upper()
        if name in env:
            return env[name]
    return None


#: pydantic's error types for a value of the wrong type (strict mode: nothing is coerced).
_TYPE_ERRORS = {"int_type", "float_type", "bool_type", "string_type", "tuple_type", "model_type", "dict_type",
                "path_type", "is_instance_of"}


def _toml_type(value: object) -> str:
    """TOML's name of a parsed value's type (``controller.port: Input should be a valid integer, got a boolean``)."""
    names = {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "an array",
             tuple: "an array", dict: "a table"}
    return names.get(type(value), f"a {type(value).__name__}")


def _format_validation_error(source: str, exc: ValidationError) -> str:
    env = _env_variables()
    problems = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"])
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
        if err["type"] in _TYPE_ERRORS and "input" in err:
            msg += f", got {_toml_type(err['input'])}"  # the type only: the value may be a password
        var = _env_name(err["loc"], env)
        if not where:  # a check across sections: its message names the keys
            problems.append(msg)
        else:
            problems.append(f"{where} (from environment {var}): {msg}" if var else f"{where}: {msg}")
    return f"{source}: " + "; ".join(problems)


def _settings_error(source: str, exc: SettingsError) -> str:
    """One line for an environment value pydantic-settings could not even parse (a section or list is JSON)."""
    cause = exc.__cause__
    field_name = str(exc).split('"')[1] if str(exc).count('"') >= 2 else ""
    names = sorted(v for k, v in _env_variables().items()
                   if k == ENV_PREFIX + field_name.upper() or k.startswith(ENV_PREFIX + field_name.upper() + "__"))
    why = f"{type(cause).__name__}: {cause}" if cause is not None else str(exc)
    return (f"{source}: environment {', '.join(names) or ENV_PREFIX + '*'}: not a valid value for {field_name!r} "
            f"(a whole section or a list must be JSON): {why}")


def _check_env_sections(source: str) -> None:
    """``RGSE_<SECTION>__<KEY>`` must name a config section (an unknown key inside one is refused by the section's
    model): a misspelt section would otherwise be ignored. Variables without ``__`` (``RGSE_LOG_FORMAT``) are not
    configuration."""
    for upper, name in sorted(_env_variables().items()):
        section, sep, _ = upper[len(ENV_PREFIX):].partition("__")
        if sep and section.lower() not in Config.model_fields:
            raise ConfigError(f"{source}: environment {name}: no config section {section.lower()!r} "
                              f"(sections: {', '.join(Config.model_fields)})")


def config_from_mapping(data: dict[str, Any], source: str = "<config>") -> Config:
    """Validate an already parsed mapping plus the environment; raises :class:`ConfigError` naming every bad field
    (and the environment variable it came from, if one did)."""
    _check_env_sections(source)
    try:
        return Config(**data)
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(source, exc)) from exc
    except SettingsError as exc:
        raise ConfigError(_settings_error(source, exc)) from exc


def load_config(path: Path | str | None) -> Config:
    """Read and validate a TOML config file; ``None`` gives the defaults (plus environment overrides).

    The process's configuration: its ``[robot] model`` becomes the active robot (:func:`rgse_daemon.robots.activate`),
    the one the kinematics, the renderer and the interlock use by default."""
    cfg = _load_config(path)
    robots.activate(cfg.robot_model)
    return cfg


def _load_config(path: Path | str | None) -> Config:
    if path is None:
        return config_from_mapping({}, "<defaults>")
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read config file: {exc.strerror}") from exc
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    except RecursionError:  # tomllib's answer to arrays nested thousands deep
        raise ConfigError(f"{p}: not valid TOML: nested too deeply") from None
    return config_from_mapping(data, str(p))
