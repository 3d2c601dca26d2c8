"""Rendering the daemon's KRL templates (top-level ``krl/``) into the programs it pushes to the KR C4.

Templates are real KRL with ``{{name}}`` placeholders (KRL uses ``$`` for system variables, so ``string.Template`` is
out). Each template has a pydantic parameter model with bounds; :func:`render` validates the parameters, requires
that every placeholder of the template is supplied and every supplied value is used, formats numbers as KRL literals,
and parses the result (a syntax error there is a bug in a template, never the user's fault) before returning it.

Speeds: the axis speed (``$VEL_AXIS`` in % of the data-sheet maximum, the *same* table the simulator uses:
the active robot's ``max_axis_speed_deg_s``) is chosen by :func:`safe_axis_velocity_pct` so that the
worst-case Cartesian speed of every tracked point (elbow, wrist, flange and the payload points) stays below the T1
limit on every motion the program can make, at 100 % program override. The interlock's static check
(:mod:`rgse_daemon.safety.static`) re-verifies the rendered text independently before anything is pushed.

Usage::

    params = default_params("rgse_warmup", TemplateDefaults(payload_points_flange_m=cube_corners(1.5)))
    program = render("rgse_warmup", params)      # RenderedProgram(name, src_text, dat_text, params)
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, model_validator

from rgse_daemon import robots
from rgse_daemon.errors import ConfigError, KrlSyntaxError
from rgse_daemon.kinematics import SPEED_HEADROOM, max_point_speed_mm_s, measurement_pose
from rgse_daemon.krl.parser import parse_dat, parse_src

#: The templates: ``<name>.src`` (and an optional ``<name>.dat``) in the repository's top-level ``krl/`` directory.
TEMPLATE_DIR = Path(__file__).resolve().parents[2] / "krl"
#: The handshake globals, installed once beside the programs (not a template: it has no placeholders).
GLOBALS_DAT = "rgse_globals.dat"

PLACEHOLDER = re.compile(r"\{\{\s*([A-Za-z_][A-Za-z0-9_]*)\s*\}\}")

#: A1 software envelope the parameter models accept: the active robot's ``a1_envelope_deg`` (paper §2.2: ±45°); a
#: narrower configured envelope is enforced by the static check. This name is the default robot's (an alias).
A1_ENVELOPE_DEG = robots.get(robots.DEFAULT_KEY).a1_envelope_deg
#: Smallest axis speed worth rendering (%): below it a motion would take hours; refuse instead.
MIN_VEL_AXIS_PCT = 0.01

#: Operational (integration) pose and the CoG calibration poses of the default robot (aliases; the templates'
#: defaults are the active robot's ``operator_pose_deg`` and ``calibration_poses_deg``).
OPER_POSE_DEG: tuple[float, ...] = robots.get(robots.DEFAULT_KEY).operator_pose_deg
CAL_POSES_DEG: tuple[tuple[float, ...], ...] = robots.get(robots.DEFAULT_KEY).calibration_poses_deg


def _meas() -> tuple[float, ...]:
    return tuple(float(v) for v in measurement_pose())


def _oper() -> tuple[float, ...]:
    return robots.active().operator_pose_deg


def _cal_poses() -> tuple[tuple[float, ...], ...]:
    return robots.active().calibration_poses_deg


# --- KRL literals -----------------------------------------------------------------------------------------------------
def format_real(value: float) -> str:
    """A KRL REAL literal: always with a decimal point, at most 6 decimals, no exponent, no ``-0.0``."""
    if not math.isfinite(value):
        raise ValueError(f"not a finite number: {value}")
    text = f"{value:.6f}".rstrip("0")
    if text.endswith("."):
        text += "0"
    return "0.0" if text in ("-0.0", "0.0") else text


def format_int(value: int) -> str:
    """A KRL INT literal (32-bit signed)."""
    if isinstance(value, bool) or not -(2**31) <= int(value) < 2**31:
        raise ValueError(f"not a KRL INT: {value!r}")
    return str(int(value))


def format_axes(q_deg: Sequence[float]) -> str:
    """An E6AXIS aggregate of six axis angles in deg: ``{E6AXIS: A1 0.0, A2 -90.0, ...}``."""
    if len(q_deg) != 6:
        raise ValueError("an axis pose needs six angles A1..A6")
    return "{E6AXIS: " + ", ".join(f"A{i} {format_real(float(v))}" for i, v in enumerate(q_deg, 1)) + "}"


def _check_pose(q: tuple[float, ...]) -> tuple[float, ...]:
    if len(q) != 6 or not all(math.isfinite(v) for v in q):
        raise ValueError("a pose is six finite axis angles A1..A6 in deg")
    robot = robots.active()
    for i, (v, (lo, hi)) in enumerate(zip(q, robot.axis_range_deg, strict=True), 1):
        if not lo <= v <= hi:
            raise ValueError(f"A{i} = {v:g} deg is outside the axis range {lo:g}..{hi:g} deg")
    if abs(q[0]) > robot.a1_envelope_deg:
        raise ValueError(f"A1 = {q[0]:g} deg is outside the ±{robot.a1_envelope_deg:g} deg envelope (paper §2.2)")
    return tuple(float(v) for v in q)


PoseDeg = Annotated[tuple[float, float, float, float, float, float], AfterValidator(_check_pose)]
"""Six axis angles A1..A6 (deg) within the axis ranges and the A1 envelope."""

def _shift(q: Sequence[float], d3_deg: float, d5_deg: float) -> tuple[float, ...]:
    return (q[0], q[1], q[2] + d3_deg, q[3], q[4] + d5_deg, q[5])


# --- parameter models -------------------------------------------------------------------------------------------------
class TemplateParams(BaseModel):
    """Parameters common to every template: axis speed and acceleration in % of the data-sheet maxima."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    template: ClassVar[str]

    vel_axis_pct: float = Field(gt=0.0, le=100.0)
    """$VEL_AXIS[1..6] (% of the robot's max_axis_speed_deg_s): choose with :func:`safe_axis_velocity_pct`."""
    acc_axis_pct: float = Field(20.0, gt=0.0, le=100.0)
    """$ACC_AXIS[1..6] (%): gentle ramps; the speed bound does not depend on it."""

    def placeholders(self) -> dict[str, str]:
        """Placeholder name → KRL literal, exactly the placeholders of the template."""
        return {"vel_axis_pct": format_real(self.vel_axis_pct), "acc_axis_pct": format_real(self.acc_axis_pct)}

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        """Every sequence of poses the program can visit from ``start_deg`` (each list starts with a start pose)."""
        raise TypeError(f"{type(self).__name__} must define paths()")  # pragma: no cover - every model overrides


class MeasPoseParams(TemplateParams):
    template: ClassVar[str] = "rgse_meas_pose"
    meas_pose: PoseDeg = Field(default_factory=_meas)

    def placeholders(self) -> dict[str, str]:
        return {**super().placeholders(), "meas_pose": format_axes(self.meas_pose)}

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        return [[tuple(start_deg), self.meas_pose]]


class OperPoseParams(TemplateParams):
    template: ClassVar[str] = "rgse_oper_pose"
    oper_pose: PoseDeg = Field(default_factory=_oper)

    def placeholders(self) -> dict[str, str]:
        return {**super().placeholders(), "oper_pose": format_axes(self.oper_pose)}

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        return [[tuple(start_deg), self.oper_pose]]


class CalPoseParams(TemplateParams):
    template: ClassVar[str] = "rgse_cal_pose"
    cal_pose: PoseDeg = Field(default_factory=_meas)

    def placeholders(self) -> dict[str, str]:
        return {**super().placeholders(), "cal_pose": format_axes(self.cal_pose)}

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        return [[tuple(start_deg), self.cal_pose]]


class WarmupParams(TemplateParams):
    """Warm-up move (paper §2.4.4 A): A3 and A5 swing together by ±``amplitude_deg`` around the measurement pose."""

    template: ClassVar[str] = "rgse_warmup"
    meas_pose: PoseDeg = Field(default_factory=_meas)
    amplitude_deg: float = Field(20.0, gt=0.0, le=45.0)
    cycles: int = Field(3, ge=0, le=100)

    @model_validator(mode="after")
    def _swing_within_limits(self) -> WarmupParams:
        _check_pose(self.upper_pose)
        _check_pose(self.lower_pose)
        return self

    @property
    def upper_pose(self) -> tuple[float, ...]:
        return _shift(self.meas_pose, self.amplitude_deg, self.amplitude_deg)

    @property
    def lower_pose(self) -> tuple[float, ...]:
        return _shift(self.meas_pose, -self.amplitude_deg, -self.amplitude_deg)

    def placeholders(self) -> dict[str, str]:
        return {
            **super().placeholders(),
            "meas_pose": format_axes(self.meas_pose),
            "upper_pose": format_axes(self.upper_pose),
            "lower_pose": format_axes(self.lower_pose),
            "amplitude_deg": format_real(self.amplitude_deg),
            "cycles": format_int(self.cycles),
        }

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        swing = [self.upper_pose, self.lower_pose] * min(self.cycles, 1)
        return [[tuple(start_deg), self.meas_pose, *swing, self.meas_pose]]


class BrakeReleaseParams(TemplateParams):
    """Brake-release move (paper §2.4.4): A3 and A5 both rotate by φ' and return to the measurement pose."""

    template: ClassVar[str] = "rgse_brake_release"
    meas_pose: PoseDeg = Field(default_factory=_meas)
    angle_deg: float = Field(35.0, ge=-90.0, le=90.0)

    @model_validator(mode="after")
    def _rotated_within_limits(self) -> BrakeReleaseParams:
        if self.angle_deg == 0.0:
            raise ValueError("angle_deg must not be 0: a brake-release move has to move")
        _check_pose(self.rotated_pose)
        return self

    @property
    def rotated_pose(self) -> tuple[float, ...]:
        return _shift(self.meas_pose, self.angle_deg, self.angle_deg)

    def placeholders(self) -> dict[str, str]:
        return {
            **super().placeholders(),
            "meas_pose": format_axes(self.meas_pose),
            "angle_deg": format_real(self.angle_deg),
        }

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        return [[tuple(start_deg), self.meas_pose, self.rotated_pose, self.meas_pose]]


class ResidentParams(TemplateParams):
    """The resident program: every move above, requested one at a time through RGSE_CMD."""

    template: ClassVar[str] = "rgse_resident"
    meas_pose: PoseDeg = Field(default_factory=_meas)
    oper_pose: PoseDeg = Field(default_factory=_oper)
    cal_poses: tuple[PoseDeg, PoseDeg, PoseDeg, PoseDeg] = Field(default_factory=_cal_poses)  # type: ignore[assignment]
    warmup_amplitude_deg: float = Field(20.0, gt=0.0, le=45.0)
    warmup_cycles: int = Field(3, ge=0, le=100)
    brake_angle_deg: float = Field(35.0, ge=-90.0, le=90.0)

    @model_validator(mode="after")
    def _derived_within_limits(self) -> ResidentParams:
        if self.brake_angle_deg == 0.0:
            raise ValueError("brake_angle_deg must not be 0: a brake-release move has to move")
        for q in (*self._warmup().paths(self.meas_pose)[0], self._brake().rotated_pose):
            _check_pose(q)
        return self

    def _warmup(self) -> WarmupParams:
        return WarmupParams(
            vel_axis_pct=self.vel_axis_pct,
            acc_axis_pct=self.acc_axis_pct,
            meas_pose=self.meas_pose,
            amplitude_deg=self.warmup_amplitude_deg,
            cycles=self.warmup_cycles,
        )

    def _brake(self) -> BrakeReleaseParams:
        return BrakeReleaseParams(
            vel_axis_pct=self.vel_axis_pct,
            acc_axis_pct=self.acc_axis_pct,
            meas_pose=self.meas_pose,
            angle_deg=self.brake_angle_deg,
        )

    def placeholders(self) -> dict[str, str]:
        warm = self._warmup()
        return {
            **super().placeholders(),
            "meas_pose": format_axes(self.meas_pose),
            "oper_pose": format_axes(self.oper_pose),
            **{f"cal_pose_{i}": format_axes(q) for i, q in enumerate(self.cal_poses, 1)},
            "warmup_upper_pose": format_axes(warm.upper_pose),
            "warmup_lower_pose": format_axes(warm.lower_pose),
            "warmup_amplitude_deg": format_real(self.warmup_amplitude_deg),
            "warmup_cycles": format_int(self.warmup_cycles),
            "brake_angle_deg": format_real(self.brake_angle_deg),
        }

    def _commands(self, start: tuple[float, ...]) -> list[list[tuple[float, ...]]]:
        return [
            [start, self.meas_pose],
            *self._warmup().paths(start),
            *self._brake().paths(start),
            [start, self.oper_pose],
            *([start, q] for q in self.cal_poses),
        ]

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        # a command starts wherever the previous one left the robot: the start pose or any command's end pose
        starts = {tuple(start_deg)} | {p[-1] for p in self._commands(tuple(start_deg))}
        return [p for s in sorted(starts) for p in self._commands(s)]


AxisPcts = tuple[float, float, float, float, float, float]


class InertiaMove(BaseModel):
    """One move of the inertia excitation: the target and the $VEL_AXIS/$ACC_AXIS % (A1..A6) in force for it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    pose: PoseDeg
    vel_axis_pct: AxisPcts
    acc_axis_pct: AxisPcts

    @model_validator(mode="after")
    def _pcts_in_range(self) -> InertiaMove:
        for what, values in (("vel_axis_pct", self.vel_axis_pct), ("acc_axis_pct", self.acc_axis_pct)):
            if not all(0.0 < v <= 100.0 for v in values):
                raise ValueError(f"{what} must be in (0, 100] % for every axis, got {list(values)}")
        return self


class InertiaParams(TemplateParams):
    """The inertia excitation (issue #15), designed per payload by ``rgse_daemon.pipeline.excitation``:
    ``vel_axis_pct``/``acc_axis_pct`` hold for the move to ``start_pose``, each of ``moves`` sets its own."""

    template: ClassVar[str] = "rgse_inertia"
    start_pose: PoseDeg = Field(default_factory=_meas)
    moves: tuple[InertiaMove, ...] = Field(min_length=1, max_length=2000)
    rest_s: float = Field(0.0, ge=0.0, le=5.0)
    """``WAIT SEC`` after each move (0: none): the robot stands between the strokes, so that a trace splits into
    one stroke per move whatever the controller's interpolation cycle (``pipeline.inertia.split_strokes``)."""

    def placeholders(self) -> dict[str, str]:
        lines: list[str] = []
        vel = (self.vel_axis_pct,) * 6
        acc = (self.acc_axis_pct,) * 6
        for n, mv in enumerate(self.moves, 1):
            for sysvar, now, want in (("$VEL_AXIS", vel, mv.vel_axis_pct), ("$ACC_AXIS", acc, mv.acc_axis_pct)):
                lines += [f"  {sysvar}[{i}] = {format_real(w)}" for i, (o, w) in enumerate(zip(now, want,
                                                                                                strict=True), 1)
                          if o != w]
            vel, acc = mv.vel_axis_pct, mv.acc_axis_pct
            lines += [f"  RGSE_LOOP = {n}", f"  PTP {format_axes(mv.pose)}"]
            if self.rest_s > 0.0:
                lines.append(f"  WAIT SEC {format_real(self.rest_s)}")
        return {
            **super().placeholders(),
            "start_pose": format_axes(self.start_pose),
            "moves": "\n".join(lines),
            "n_moves": format_int(len(self.moves)),
        }

    def paths(self, start_deg: Sequence[float]) -> list[list[tuple[float, ...]]]:
        return [[tuple(start_deg), self.start_pose, *(mv.pose for mv in self.moves)]]


MODELS: dict[str, type[TemplateParams]] = {
    m.template: m
    for m in (
        MeasPoseParams,
        OperPoseParams,
        CalPoseParams,
        WarmupParams,
        BrakeReleaseParams,
        ResidentParams,
        InertiaParams,
    )
}
#: The templates in the order ``rgse krl render`` writes them. Not the inertia excitation: its moves are designed
#: for each payload (``rgse_daemon.pipeline.excitation``), there are no defaults to render it from.
TEMPLATES: tuple[str, ...] = tuple(n for n in MODELS if n != InertiaParams.template)


# --- speeds -----------------------------------------------------------------------------------------------------------
def path_bound_at_full_speed_mm_s(
    q_start_deg: Sequence[float], q_end_deg: Sequence[float], points_flange_m: Sequence[Sequence[float]]
) -> float:
    """Worst-case point speed (mm/s) of a PTP ``q_start_deg`` → ``q_end_deg`` at 100 % axis speed and override."""
    if np.allclose(q_start_deg, q_end_deg, atol=1e-9, rtol=0.0):
        return 0.0
    return max_point_speed_mm_s(q_start_deg, q_end_deg, robots.active().max_axis_speed_deg_s,
                                points_flange_m).bound_mm_s


def safe_axis_velocity_pct(
    paths: Sequence[Sequence[Sequence[float]]],
    limit_mm_s: float,
    points_flange_m: Sequence[Sequence[float]] = (),
    override_pct: float = 100.0,
) -> float:
    """Largest ``$VEL_AXIS`` % (same for all axes) that keeps every motion of ``paths`` under ``limit_mm_s``.

    The conservative speed bound of a synchronous PTP (``kinematics.max_point_speed_mm_s``) is proportional to the
    axis speeds, so the bound at 100 % scales down linearly; ``kinematics.SPEED_HEADROOM`` keeps a margin and the
    result is rounded *down* to 0.01 %. ``override_pct``: the largest program override that may be in force (the
    operator can raise it on the smartPAD, so 100 unless it is locked).

    Raises
    ------
    ValueError
        No axis speed ≥ ``MIN_VEL_AXIS_PCT`` keeps the motions under the limit.
    """
    if not limit_mm_s > 0.0 or not 0.0 < override_pct <= 100.0:
        raise ValueError("limit_mm_s must be positive and override_pct in (0, 100]")
    segments = {(tuple(q0), tuple(q1)) for path in paths for q0, q1 in itertools.pairwise(path)}
    worst = 0.0
    for q0, q1 in sorted(segments):
        worst = max(worst, path_bound_at_full_speed_mm_s(q0, q1, points_flange_m))
    if worst == 0.0:
        return 100.0
    pct = 100.0 * SPEED_HEADROOM * limit_mm_s / (worst * override_pct / 100.0)
    pct = min(100.0, math.floor(pct * 100.0) / 100.0)
    if pct < MIN_VEL_AXIS_PCT:
        raise ValueError(f"the motions need below {MIN_VEL_AXIS_PCT} % axis speed to stay under {limit_mm_s} mm/s")
    return pct


def cube_corners(half_side_m: float) -> list[tuple[float, float, float]]:
    """The 8 corners of a cube of half side ``half_side_m`` around the flange origin (flange frame, m).

    Speed is affine in the point (v = v_flange + ω × r) and its norm convex, so the corners bound the speed of every
    point of the cube, hence of every point within ``half_side_m`` of the flange (a payload of that reach).
    """
    if not half_side_m >= 0.0:
        raise ValueError("half_side_m must be >= 0")
    r = float(half_side_m)
    return [(sx * r, sy * r, sz * r) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]


# --- rendering --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RenderedProgram:
    """A program ready to push: ``name`` (module name), ``.src`` text, ``.dat`` text (``None`` if it has none)."""

    name: str
    src_text: str
    dat_text: str | None
    params: TemplateParams


def template_text(name: str) -> tuple[str, str | None]:
    """The raw ``.src`` and ``.dat`` (or ``None``) of template ``name``."""
    if name not in MODELS:
        raise ConfigError(f"unknown KRL template {name!r}; known: {', '.join(TEMPLATES)}")
    src = (TEMPLATE_DIR / f"{name}.src").read_text(encoding="latin-1")
    dat_path = TEMPLATE_DIR / f"{name}.dat"
    dat = dat_path.read_text(encoding="latin-1") if dat_path.is_file() else None
    return src, dat


def _substitute(text: str, values: Mapping[str, str], where: str) -> tuple[str, set[str]]:
    used: set[str] = set()

    def sub(m: re.Match[str]) -> str:
        key = m.group(1)
        if key not in values:
            raise ConfigError(f"{where}: placeholder {{{{{key}}}}} has no value")
        used.add(key)
        return values[key]

    out = PLACEHOLDER.sub(sub, text)
    leftover = re.search(r"\{\{[^{}]*\}\}", out)
    if leftover is not None:  # a malformed placeholder ("{{ 1x }}"): never push half-rendered text
        raise ConfigError(f"{where}: malformed placeholder {leftover.group(0)!r}")
    return out, used


def render(name: str, params: Mapping[str, Any] | TemplateParams) -> RenderedProgram:
    """Render template ``name`` with ``params`` (validated against its model).

    Raises
    ------
    ConfigError
        Unknown template, parameters out of bounds or unknown, a placeholder without value, a value no placeholder
        uses.
    RuntimeError
        The rendered text does not parse: a bug in the template (the text is never returned).
    """
    model_cls = MODELS.get(name)
    if model_cls is None:
        raise ConfigError(f"unknown KRL template {name!r}; known: {', '.join(TEMPLATES)}")
    try:
        model = (
            params
            if isinstance(params, model_cls)
            else model_cls.model_validate(params.model_dump() if isinstance(params, BaseModel) else dict(params))
        )
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or name}: {e['msg']}" for e in exc.errors())
        raise ConfigError(f"KRL template {name}: {problems}") from exc
    values = model.placeholders()
    src, dat = template_text(name)
    src_out, used = _substitute(src, values, f"{name}.src")
    dat_out = None
    if dat is not None:
        dat_out, used_dat = _substitute(dat, values, f"{name}.dat")
        used |= used_dat
    unused = sorted(set(values) - used)
    if unused:
        raise ConfigError(f"KRL template {name}: parameter(s) {', '.join(unused)} not used by the template")
    try:
        parse_src(src_out, f"{name}.src")
        if dat_out is not None:
            parse_dat(dat_out, f"{name}.dat")
    except KrlSyntaxError as exc:
        raise RuntimeError(f"template {name} rendered to invalid KRL (a bug in the template): {exc}") from exc
    return RenderedProgram(name, src_out, dat_out, model)


def globals_dat_text() -> str:
    """The handshake data list ``rgse_globals.dat`` (installed once; parsed here so a broken file never ships)."""
    text = (TEMPLATE_DIR / GLOBALS_DAT).read_text(encoding="latin-1")
    try:
        parse_dat(text, GLOBALS_DAT)
    except KrlSyntaxError as exc:
        raise RuntimeError(f"{GLOBALS_DAT} does not parse (a bug): {exc}") from exc
    return text


@dataclass(frozen=True)
class TemplateDefaults:
    """What the defaults of every template derive from (``rgse krl render`` fills it from the config).

    ``start_deg``: where the robot is when the program starts (the axis speed is chosen for the first motion from
    there and from every RGSE pose: measurement, operational and calibration poses); ``payload_points_flange_m``:
    the points whose speed matters; ``override_pct``: the largest program override that may be in force.
    """

    limit_mm_s: float = 200.0
    payload_points_flange_m: Sequence[Sequence[float]] = ()
    start_deg: tuple[float, ...] = field(default_factory=_meas)
    override_pct: float = 100.0
    acc_axis_pct: float = 20.0
    meas_pose: tuple[float, ...] = field(default_factory=_meas)
    oper_pose: tuple[float, ...] = field(default_factory=_oper)
    cal_pose: tuple[float, ...] = field(default_factory=_meas)
    cal_poses: tuple[tuple[float, ...], ...] = field(default_factory=_cal_poses)
    warmup_amplitude_deg: float = 20.0
    warmup_cycles: int = 3
    brake_angle_deg: float = 35.0
    extra: dict[str, Any] = field(default_factory=dict)
    """Further template parameters (by name) that override the above."""


def _one_line(exc: ValidationError) -> str:
    """Each problem as ``parameter: message``, on one line (not pydantic's multi-line dump)."""
    parts = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{where}: {msg}" if where else msg)
    return "; ".join(parts)


def default_params(name: str, d: TemplateDefaults) -> TemplateParams:
    """The parameters of template ``name`` from ``d``, with the axis speed from :func:`safe_axis_velocity_pct`."""
    base: dict[str, Any] = {"vel_axis_pct": 100.0, "acc_axis_pct": d.acc_axis_pct}
    specific: dict[str, dict[str, Any]] = {
        "rgse_meas_pose": {"meas_pose": d.meas_pose},
        "rgse_oper_pose": {"oper_pose": d.oper_pose},
        "rgse_cal_pose": {"cal_pose": d.cal_pose},
        "rgse_warmup": {"meas_pose": d.meas_pose, "amplitude_deg": d.warmup_amplitude_deg, "cycles": d.warmup_cycles},
        "rgse_brake_release": {"meas_pose": d.meas_pose, "angle_deg": d.brake_angle_deg},
        "rgse_resident": {
            "meas_pose": d.meas_pose,
            "oper_pose": d.oper_pose,
            "cal_poses": d.cal_poses,
            "warmup_amplitude_deg": d.warmup_amplitude_deg,
            "warmup_cycles": d.warmup_cycles,
            "brake_angle_deg": d.brake_angle_deg,
        },
    }
    if name not in specific:
        raise ConfigError(f"unknown KRL template {name!r}; known: {', '.join(TEMPLATES)}")
    try:
        model = MODELS[name].model_validate({**base, **specific[name], **d.extra})
        # the robot may be in any of the RGSE poses when the program starts, not only at start_deg
        starts = sorted({tuple(d.start_deg), tuple(d.meas_pose), tuple(d.oper_pose), *map(tuple, d.cal_poses)})
        paths = [p for s in starts for p in model.paths(s)]
        pct = safe_axis_velocity_pct(paths, d.limit_mm_s, d.payload_points_flange_m, d.override_pct)
    except ValidationError as exc:
        raise ConfigError(f"KRL template {name}: no safe parameters: {_one_line(exc)}") from exc
    except ValueError as exc:
        raise ConfigError(f"KRL template {name}: no safe parameters: {exc}") from exc
    return model.model_copy(update={"vel_axis_pct": pct})
