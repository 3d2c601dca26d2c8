"""Scenario of the simulated KR C4's torque estimate: every error source of the paper, as numbers in one TOML file.

``load_scenario(path)`` validates a TOML file (unknown keys and out-of-range values raise :class:`ConfigError`
naming the key); ``default_scenario()`` is ``scenarios/default.toml``, tuned to the paper's magnitudes (Table 1
measured/expected ratios, σ 5–25 Nm, ≈2 °C per trace). The physics that uses these numbers is in ``physics.py``.

Axes are keyed ``A1`` .. ``A6``; every axis has the same fields, so a scenario can make any axis as bad as A5.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rgse_daemon import robots
from rgse_daemon.errors import ConfigError

DEFAULT_SCENARIO_PATH = Path(__file__).with_name("scenarios") / "default.toml"
AXIS_KEYS = ("A1", "A2", "A3", "A4", "A5", "A6")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AxisErrors(_Model):
    """How the controller's torque estimate (``Istmoment``) of one axis deviates from the true torque."""

    # Non-linear gain on the payload torque x = |τ_payload| (Nm), Table 1 measured/expected:
    #   G(x) = gain0 + gain_sat · (1 − exp(−x / tau_sat_nm))
    #          + gain_slope_per_knm · x/1000 + gain_quad_per_knm2 · (x/1000)²
    # (the paper fits K_A3 with a polynomial, eq. 19, and K_A5 with exponentials, eq. 20)
    gain0: float = Field(1.0, ge=0.5, le=1.5)
    gain_sat: float = Field(0.0, ge=-0.5, le=0.5)
    tau_sat_nm: float = Field(500.0, gt=0.0, le=1e5)
    gain_slope_per_knm: float = Field(0.0, ge=-0.2, le=0.2)
    gain_quad_per_knm2: float = Field(0.0, ge=-0.05, le=0.05)
    noise_nm: float = Field(5.0, ge=0.0, le=200.0)
    """σ of the white noise on Istmoment (Nm)."""
    thermal_coeff_per_k: float = Field(0.0, ge=-0.02, le=0.02)
    """Relative change of the whole torque reading per K of motor temperature above ambient."""
    release_transient_frac: float = Field(0.0, ge=-0.1, le=0.1)
    """Relative offset of the reading right after a brake release, decaying with ``release.time_constant_s``."""
    hysteresis_nm: float = Field(0.0, ge=0.0, le=500.0)
    """Gear friction that stays locked in: reading offset −sign(last approach) · hysteresis_nm."""
    settle_amplitude_nm: float = Field(0.0, ge=0.0, le=2000.0)
    """Amplitude of the damped oscillation after the brake-release move (Nm)."""
    mount_offset_nm: float = Field(0.0, ge=0.0, le=200.0)
    """σ of a reading offset fixed for one mounting of a load and new at every re-mount (Nm): how the load seats
    on the flange, preload of the bolts, the gear's contact pattern. Table 1's points scatter about ±1 kg around any
    smooth K; loops of one mounting cannot see it."""
    hold_temperature_rise_k: float = Field(40.0, ge=0.0, le=120.0)
    """Motor temperature rise above ambient at thermal equilibrium while holding with brakes released (K)."""
    torque_constant_nm_a: float = Field(2.0, gt=0.0, le=50.0)
    """Motor torque constant k_t (Nm/A, motor side)."""
    gear_ratio: float = Field(200.0, gt=0.0, le=1000.0)
    """Gear ratio motor/axis: Iststrom = Istmoment / (k_t · ratio)."""


class ArmModel(_Model):
    """The robot's own mass: link masses (kg) and CoGs in the DH link frames (m), and the pinned bias."""

    links: list[tuple[int, float, tuple[float, float, float]]] = Field(
        default_factory=lambda: [
            (2, 420.0, (0.60, 0.0, 0.0)),
            (3, 280.0, (0.03, 0.10, 0.0)),
            (4, 120.0, (0.0, 0.0, -0.45)),
            (5, 70.0, (0.0, -0.12, 0.0)),
            (6, 8.0, (0.0, 0.0, -0.02)),
        ]
    )
    link_inertia_kgm2: dict[int, tuple[float, float, float]] = Field(default_factory=lambda: {
        1: (80.0, 100.0, 90.0), 2: (8.0, 60.0, 60.0), 3: (15.0, 17.0, 15.0), 4: (10.7, 10.7, 1.4),
        5: (1.2, 1.2, 1.0), 6: (0.046, 0.046, 0.09)})
    """Inertia of each link about its CoG in its DH frame (kg·m², principal moments along the frame's axes; the
    dynamics only). Default the KR 500's: link 2 the 1.3 m upper arm along its x, link 4 the wrist tube along z."""
    column_mass_kg: float = Field(900.0, ge=0.0, le=5000.0)
    """The rotating column (link 1): mass (kg), on the A1 axis' side, no gravity torque (the dynamics only)."""
    column_cog_m: tuple[float, float, float] = (0.15, 0.0, -0.35)
    motor_inertia_kgm2: tuple[float, float, float, float, float, float] = (0.006, 0.006, 0.004, 0.0006, 0.0006,
                                                                           0.0004)
    """Rotor (plus first gear stage) inertia of each axis' motor, motor side (kg·m²); reflected as J · N²."""
    bias_measurement_pose_nm: dict[str, float] = Field(default_factory=dict)
    """Reading (Nm, noise-free, cold) of the bare arm in the measurement pose, per axis key. For the keys given, a
    constant residual (bearings, gears, the controller's own model: eq. 17–18's M0) is added so that the reading
    matches; the paper reports 1320.46 Nm at A3 and 315.96 Nm at A5 (signs: holding torque, negative in front)."""

    @model_validator(mode="after")
    def _check(self) -> ArmModel:
        for link, mass, _cog in self.links:
            if not 1 <= link <= 6:
                raise ValueError(f"link index {link} is not 1..6")
            if not 0.0 <= mass <= 5000.0:
                raise ValueError(f"link mass {mass} kg is outside 0..5000")
        for key, value in self.bias_measurement_pose_nm.items():
            if key not in AXIS_KEYS:
                raise ValueError(f"bias key {key!r} is not one of {', '.join(AXIS_KEYS)}")
            if abs(value) > 20000.0:
                raise ValueError(f"bias {key} = {value} Nm is implausible")
        return self


class Thermal(_Model):
    ambient_k: float = Field(293.15, ge=250.0, le=330.0)
    heat_time_constant_s: float = Field(240.0, gt=1.0, le=1e5)
    """First-order time constant of the winding temperature while holding (brakes released)."""
    cool_time_constant_s: float = Field(300.0, gt=1.0, le=1e5)
    """... and while the brakes are applied (no current)."""


class Release(_Model):
    time_constant_s: float = Field(3.0, gt=0.0, le=600.0)
    """Decay of the thermal/electrical transient after a brake release."""


class Settle(_Model):
    time_constant_s: float = Field(0.6, gt=0.0, le=60.0)
    frequency_hz: float = Field(2.5, ge=0.0, le=50.0)


class Spikes(_Model):
    rate_per_sample: float = Field(0.001, ge=0.0, le=0.1)
    amplitude_nm: float = Field(100.0, ge=0.0, le=5000.0)


class Mounting(_Model):
    """How a load seats on the flange, new at every (re-)mount."""

    cog_shift_m: float = Field(0.0, ge=0.0, le=0.05)
    """σ of the load's CoG shift along the flange axis per mounting (m): a real torque change on every axis, equal
    on A3 and A5 (it cancels in eq. 3/4's mass, not in the per-axis torques of eq. 17/18)."""


class Kinematics(_Model):
    """How this arm as built differs from its catalogue DH rows (``[kinematics]``), drawn once per simulated robot
    (per seed): every DH length (a_{i-1}, d_i, the catalogue's zeros included) by N(0, ``length_sigma_m``), every twist
    alpha_{i-1} but A1's (the A1 axis stays plumb) by N(0, ``twist_sigma_deg``) and every zero offset (mastering) by
    N(0, ``zero_offset_sigma_deg``).
    The physics (static and dynamic torques) uses the arm as built; the controller's positions, its motion planning
    and the daemon use the catalogue, as on a real KR C4 without KUKA's absolute-accuracy option. 0: the catalogue's
    exact arm (a test's world, not a real one)."""

    length_sigma_m: float = Field(0.0, ge=0.0, le=0.01)
    twist_sigma_deg: float = Field(0.0, ge=0.0, le=0.5)
    zero_offset_sigma_deg: float = Field(0.0, ge=0.0, le=0.5)


class ServerBehaviour(_Model):
    """How the controller's C3 Bridge server behaves where the real one is slow or unknown (``[server]``); a key
    left out takes the server's default (``simulators.krc4.server.ServerConfig``, the environment variables
    ``RGSE_SIM_LISTING`` / ``RGSE_SIM_PATHS`` for the variants)."""

    file_rate_bytes_s: float | None = Field(None, gt=0.0, le=1e10)
    """Bytes per second of the controller's file work (a #30 Begin loads the whole file before it answers)."""
    listing: str | None = Field(None, pattern="^(fields|bare|text)$")
    """#21 answer format: ``fields``, ``bare`` or ``text`` (simulators.krc4.files.LISTING_VARIANTS)."""
    path_forms: str | None = Field(None, pattern="^(any|disk|krc)$")
    """Accepted path forms: ``any``, ``disk`` or ``krc`` (simulators.krc4.files.PATH_FORM_VARIANTS)."""


class Scenario(_Model):
    """All error sources of the simulated torque estimate, and the server's behaviour (``server``)."""

    axes: dict[str, AxisErrors] = Field(default_factory=lambda: {k: AxisErrors() for k in AXIS_KEYS})
    arm: ArmModel = ArmModel()
    thermal: Thermal = Thermal()
    release: Release = Release()
    settle: Settle = Settle()
    spikes: Spikes = Spikes()
    mounting: Mounting = Mounting()
    kinematics: Kinematics = Kinematics()
    server: ServerBehaviour = ServerBehaviour()
    g_m_s2: float = Field(9.81, ge=9.7, le=9.9)
    """Gravity of the simulated world (the paper uses 9.81; Bremen is 9.8134)."""
    robot: str = robots.DEFAULT_KEY
    """The simulated arm (``rgse_daemon/robots/``): its kinematics, ranges, speeds and calibration load set."""

    @field_validator("robot")
    @classmethod
    def _known_robot(cls, value: str) -> str:
        return robots.get(value).key

    @model_validator(mode="after")
    def _all_axes(self) -> Scenario:
        unknown = sorted(set(self.axes) - set(AXIS_KEYS))
        if unknown:
            raise ValueError(f"unknown axis key(s) {', '.join(unknown)}; expected A1..A6")
        return self

    def axis(self, index: int) -> AxisErrors:
        """Errors of axis ``index`` (1..6); axes missing from the file get the defaults."""
        return self.axes.get(f"A{index}", AxisErrors())


def _format(source: str, exc: ValidationError) -> str:
    problems = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
        problems.append(f"{where}: {msg}")
    return f"{source}: " + "; ".join(problems)


def scenario_from_mapping(data: dict[str, Any], source: str = "<scenario>") -> Scenario:
    """Validate a parsed mapping; raises :class:`ConfigError` naming every bad key."""
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format(source, exc)) from exc


def load_scenario(path: Path | str) -> Scenario:
    """Read and validate a scenario TOML file."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read scenario: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: scenario is not UTF-8: {exc}") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    return scenario_from_mapping(data, str(p))


def default_scenario() -> Scenario:
    """The paper-like default (``scenarios/default.toml``): the KR 500 R2830."""
    return load_scenario(DEFAULT_SCENARIO_PATH)


def scenario_for(robot: str) -> Scenario:
    """The default scenario of the arm ``robot`` (a robot key): ``scenarios/<key>.toml``, or ``default.toml`` for the
    default robot."""
    key = robots.get(robot).key
    if key == robots.DEFAULT_KEY:
        return default_scenario()
    scenario = load_scenario(DEFAULT_SCENARIO_PATH.with_name(f"{key}.toml"))
    if scenario.robot != key:
        raise ConfigError(f"scenarios/{key}.toml simulates {scenario.robot}, not {key}")
    return scenario
