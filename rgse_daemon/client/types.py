"""What the Python client hands back: the daemon's messages (docs/interfaces.md §4.2) as typed, frozen records.

Each record keeps the daemon's whole JSON object in ``raw``: the payloads are open (fields may be added), the
typed fields are the stable (S) ones a script relies on.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import ValidationError

from rgse_daemon.errors import DataError, RgseError
from rgse_daemon.io.commands import CalibrationPoint
from rgse_daemon.verdict import Status, status_of

#: Engine states after which a run is over (the state persists until the next run).
TERMINAL = frozenset({"done", "failed", "aborted"})
#: The end of a run whose daemon died during it: the restarted daemon's recovery publishes the run's final result
#: with this ``state`` (a measurement or properties run; an interrupted campaign is continued instead).
INTERRUPTED = "interrupted"
#: What the hint of an interrupted run tells the operator (nothing is left to abort: the recovery stopped it).
INTERRUPTED_HINT = ("the daemon stopped during the run; on its restart it stopped program and trace and kept the "
                    "raw files (docs/recovery.md); nothing is left to abort: start the run again")


class Refused(RgseError):
    """The daemon answered a command with ``ok: false``; ``reason`` is its words (exit status 1)."""

    def __init__(self, verb: str, reason: str) -> None:
        super().__init__(f"cmd/{verb} refused by the daemon: {reason}")
        self.verb = verb
        self.reason = reason


class RunFailed(RgseError):
    """A run ended ``failed``, ``aborted`` or ``interrupted`` (its daemon died during it); ``reason`` says why as
    far as the daemon said it (exit status 1)."""

    def __init__(self, run_id: str, state: str, reason: str) -> None:
        super().__init__(f"run {run_id} {state}: {reason}")
        self.run_id = run_id
        self.state = state
        self.reason = reason


class ResultRefused(RunFailed):
    """The run completed and its result is ``refused`` (rgse_daemon.verdict): no figure, and ``reason`` says why (too
    few loops left after setting the disturbed ones aside, an operating point far outside the calibration). ``result``
    is the daemon's result object (its ``error``, ``loops_used``, ``loops_set_aside``); state ``refused``. A result,
    not a failed run: ``rgse run`` exits 2 with it, as ``rgse mass`` does with its refusal."""

    def __init__(self, run_id: str, result: dict[str, Any]) -> None:
        super().__init__(run_id, "refused", str(result.get("reason") or "no reason given"))
        self.result = result


class WaitTimeout(RgseError):
    """What a wait was for did not happen within its deadline (exit status 1: the work did not finish)."""


def _f(doc: dict[str, Any], key: str) -> float | None:
    value = doc.get(key)
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _i(doc: dict[str, Any], key: str) -> int | None:
    value = doc.get(key)
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _s(doc: dict[str, Any], key: str) -> str | None:
    value = doc.get(key)
    return value if isinstance(value, str) else None


@dataclass(frozen=True)
class DaemonState:
    """The daemon's retained ``state`` (§4.2)."""

    engine: str
    run_id: str | None
    run_kind: str | None
    connected: bool
    time: str | None
    mode_op: str | None
    motor_temps_k: tuple[float, ...] | None
    raw: dict[str, Any] = field(repr=False)

    @classmethod
    def of(cls, doc: dict[str, Any]) -> DaemonState:
        ctl = doc.get("controller") if isinstance(doc.get("controller"), dict) else {}
        temps = ctl.get("motor_temps_k")
        return cls(
            engine=str(doc.get("engine", "?")),
            run_id=_s(doc, "run_id"),
            run_kind=_s(doc, "run_kind"),
            connected=doc.get("connected") is True,
            time=_s(doc, "time"),
            mode_op=_s(ctl, "mode_op"),
            motor_temps_k=tuple(float(t) for t in temps if isinstance(t, int | float)) if isinstance(temps, list)
            else None,
            raw=doc,
        )


@dataclass(frozen=True)
class ProgressEvent:
    """One engine event of a run (§4.2 ``progress``)."""

    kind: str
    time: str | None
    """When the engine emitted it: ISO 8601 UTC as the daemon sends it (§4.2), like :attr:`DaemonState.time`."""
    run_id: str
    message: str = ""
    step: str | None = None
    loop_index: int | None = None
    loop_count: int | None = None
    eta_s: float | None = None
    data: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, run_id: str, doc: dict[str, Any]) -> ProgressEvent:
        data = doc.get("data")
        return cls(kind=str(doc.get("kind", "?")), time=_s(doc, "time"), run_id=run_id,
                   message=_s(doc, "message") or "", step=_s(doc, "step"), loop_index=_i(doc, "loop_index"),
                   loop_count=_i(doc, "loop_count"), eta_s=_f(doc, "eta_s"),
                   data=data if isinstance(data, dict) else {})

    @property
    def state(self) -> str | None:
        """The new engine state of a ``state`` event."""
        return str(self.data.get("state")) if self.kind == "state" else None


@dataclass(frozen=True)
class Prompt:
    """The daemon waits for the operator: mount this load of campaign point ``point_index`` (0-based), confirm. A
    properties run with the inertia asks once to take the DuT off for the tare (``inertia_tare``; ``point_index`` 0
    there means nothing); ``data`` is the prompt's whole data."""

    run_id: str
    point_index: int
    kind: str
    mass_kg: float | None
    lever_a3_m: float | None
    lever_a5_m: float | None
    n_cb: int | None
    cb_lever_a5_m: float | None
    message: str
    data: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def inertia_tare(self) -> bool:
        """The tare of the inertia: take the DuT off (MPA and fixture stay), then confirm."""
        return self.data.get("inertia_tare") is True

    @classmethod
    def of(cls, ev: ProgressEvent) -> Prompt:
        d = ev.data
        return cls(run_id=ev.run_id, point_index=_i(d, "point_index") or 0, kind=str(d.get("kind", "?")),
                   mass_kg=_f(d, "mass_kg"), lever_a3_m=_f(d, "lever_a3_m"), lever_a5_m=_f(d, "lever_a5_m"),
                   n_cb=_i(d, "n_cb"), cb_lever_a5_m=_f(d, "cb_lever_a5_m"), message=ev.message, data=dict(d))


@dataclass(frozen=True)
class Identity:
    """Who and what a run measures (the ``identity`` of the ``measure``/``properties`` commands, interfaces §4.3):
    stored with the run, shown in its report and published with its result."""

    dut_name: str | None = None
    serial_number: str | None = None
    """The DuT's serial number."""
    part_number: str | None = None
    project: str | None = None
    operator: str | None = None
    note: str | None = None

    def as_command(self) -> dict[str, str] | None:
        doc = {k: v for k, v in self.__dict__.items() if v}
        return doc or None

    @classmethod
    def of(cls, doc: Any) -> Identity | None:
        """The ``identity`` object of a result, None without one."""
        if not isinstance(doc, dict):
            return None
        return cls(**{k: str(doc[k]) for k in cls.__dataclass_fields__ if isinstance(doc.get(k), str)})


def _status(doc: dict[str, Any]) -> Status:
    """The result's ``status`` as the daemon sent it, else derived by the same rule (a daemon before it)."""
    value = doc.get("status")
    return value if value in ("ok", "warning", "refused") else status_of(doc)


@dataclass(frozen=True)
class MeasurementResult:
    """The result of a measurement run (§4.2 ``result``; the fields of ``rgse mass --json``)."""

    run_id: str
    robot: str | None
    mass_kg: float
    u_kg: float | None
    U_kg: float | None
    k: float | None
    gross_mass_kg: float | None
    fixture_mass_kg: float | None
    loops: int | None
    calibration_id: str | None
    method: str | None
    warnings: tuple[str, ...]
    raw: dict[str, Any] = field(repr=False)
    status: Status = "ok"
    """``ok``, ``warning`` (read :attr:`warnings`) or ``refused`` (rgse_daemon.verdict)."""
    identity: Identity | None = None

    @classmethod
    def of(cls, run_id: str, doc: dict[str, Any]) -> MeasurementResult:
        mass = _f(doc, "mass_kg")
        if mass is None:
            raise DataError(f"run {run_id}: result without a numeric mass_kg: {sorted(doc)}")
        return cls(run_id=run_id, robot=_s(doc, "robot"), mass_kg=mass, u_kg=_f(doc, "u_kg"), U_kg=_f(doc, "U_kg"),
                   k=_f(doc, "k"), gross_mass_kg=_f(doc, "gross_mass_kg"), fixture_mass_kg=_f(doc, "fixture_mass_kg"),
                   loops=_i(doc, "loops"), calibration_id=_s(doc, "calibration_id"), method=_s(doc, "method"),
                   warnings=tuple(str(w) for w in doc.get("warnings") or ()), raw=doc, status=_status(doc),
                   identity=Identity.of(doc.get("identity")))


@dataclass(frozen=True)
class CalibrationResult:
    """The result of a calibration campaign (§4.2 ``result``; the object of ``rgse calibrate --json``)."""

    run_id: str
    robot: str | None
    calibration_id: str
    method: str | None
    points: int | None
    in_sample_mean_abs_err_pct: float | None
    loo_mean_abs_err_pct: float | None
    loo_max_abs_err_kg: float | None
    warnings: tuple[str, ...]
    raw: dict[str, Any] = field(repr=False)
    status: Status = "ok"

    @classmethod
    def of(cls, run_id: str, doc: dict[str, Any]) -> CalibrationResult:
        cal = _s(doc, "calibration_id")
        if cal is None:
            raise DataError(f"run {run_id}: calibration result without a calibration_id: {sorted(doc)}")
        return cls(run_id=run_id, robot=_s(doc, "robot"), calibration_id=cal, method=_s(doc, "method"),
                   points=_i(doc, "points"), in_sample_mean_abs_err_pct=_f(doc, "in_sample_mean_abs_err_pct"),
                   loo_mean_abs_err_pct=_f(doc, "loo_mean_abs_err_pct"),
                   loo_max_abs_err_kg=_f(doc, "loo_max_abs_err_kg"),
                   warnings=tuple(str(w) for w in doc.get("warnings") or ()), raw=doc, status=_status(doc))


def _xyz(doc: dict[str, Any], key: str) -> tuple[float, float, float] | None:
    value = doc.get(key)
    if isinstance(value, list) and len(value) == 3 and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        return (float(value[0]), float(value[1]), float(value[2]))
    return None


def _matrix(doc: dict[str, Any], key: str) -> Matrix3 | None:
    value = doc.get(key)
    if isinstance(value, list) and len(value) == 3:
        rows = [_xyz({"r": row}, "r") for row in value]
        if all(r is not None for r in rows):
            return (rows[0], rows[1], rows[2])  # type: ignore[return-value]
    return None


Vector3 = tuple[float, float, float]
Matrix3 = tuple[Vector3, Vector3, Vector3]


@dataclass(frozen=True)
class MassEstimate:
    """One mass method's estimate in a properties result (§4.2 ``mass_methods``): the DuT's mass and its U (k = 2),
    kg, and the robot time of that method's loops, s."""

    method: str
    """``single`` (the paper's pose, eq. 21) or ``multipose`` (torque differences between the lever poses)."""
    mass_kg: float
    U_kg: float
    robot_time_s: float | None

    @classmethod
    def all_of(cls, doc: dict[str, Any]) -> tuple[MassEstimate, ...]:
        methods = doc.get("mass_methods")
        if not isinstance(methods, dict):
            return ()
        out = []
        for name, m in methods.items():
            mass, u = (_f(m, "mass_kg"), _f(m, "U_kg")) if isinstance(m, dict) else (None, None)
            if mass is not None and u is not None:
                out.append(cls(str(name), mass, u, _f(m, "robot_time_s")))
        return tuple(out)


@dataclass(frozen=True)
class PropertiesResult:
    """The result of a mass-properties run: the measurement's mass and the CoG, flange and DuT frame (m), each with
    its U (k = 2); ``raw["cog"]`` holds the whole CoG result (scheme, poses, budget). A run with the inertia also
    has the tensor about the CoG in the DuT frame and the principal moments (ascending) with U (k = 2, kg·m²) and
    the principal axes (unit vectors in the DuT frame, one per moment); ``raw["inertia"]`` holds the whole
    identification. ``None`` where the run did not measure the inertia."""

    run_id: str
    robot: str | None
    mass_kg: float
    U_kg: float | None
    cog_m: tuple[float, float, float]
    U_cog_m: tuple[float, float, float]
    cog_dut_m: tuple[float, float, float] | None
    U_cog_dut_m: tuple[float, float, float] | None
    calibration_id: str | None
    warnings: tuple[str, ...]
    raw: dict[str, Any] = field(repr=False)
    principal_moments_kgm2: Vector3 | None = None
    U_principal_moments_kgm2: Vector3 | None = None
    principal_axes_dut: Matrix3 | None = None
    inertia_cog_dut_kgm2: Matrix3 | None = None
    U_inertia_cog_dut_kgm2: Matrix3 | None = None
    status: Status = "ok"
    identity: Identity | None = None
    mass_method: str | None = None
    """Where :attr:`mass_kg` comes from: ``single`` or ``multipose`` (None: a daemon before the multi-pose mass)."""
    mass_method_requested: str | None = None
    """What the run was asked for: ``single``, ``multipose`` or ``auto`` (``auto`` chose :attr:`mass_method`)."""
    mass_methods: tuple[MassEstimate, ...] = ()
    """Every method's estimate the run computed (both with ``multipose`` and ``auto``)."""

    @classmethod
    def of(cls, run_id: str, doc: dict[str, Any]) -> PropertiesResult:
        mass, cog, u_cog = _f(doc, "mass_kg"), _xyz(doc, "cog_m"), _xyz(doc, "U_cog_m")
        if mass is None or cog is None or u_cog is None:
            raise DataError(f"run {run_id}: properties result without a numeric mass_kg, cog_m and U_cog_m (three "
                            f"each): {sorted(doc)}")
        return cls(run_id=run_id, robot=_s(doc, "robot"), mass_kg=mass, U_kg=_f(doc, "U_kg"), cog_m=cog,
                   U_cog_m=u_cog, cog_dut_m=_xyz(doc, "cog_dut_m"), U_cog_dut_m=_xyz(doc, "U_cog_dut_m"),
                   calibration_id=_s(doc, "calibration_id"),
                   warnings=tuple(str(w) for w in doc.get("warnings") or ()), raw=doc,
                   principal_moments_kgm2=_xyz(doc, "principal_moments_kgm2"),
                   U_principal_moments_kgm2=_xyz(doc, "U_principal_moments_kgm2"),
                   principal_axes_dut=_matrix(doc, "principal_axes_dut"),
                   inertia_cog_dut_kgm2=_matrix(doc, "inertia_cog_dut_kgm2"),
                   U_inertia_cog_dut_kgm2=_matrix(doc, "U_inertia_cog_dut_kgm2"), status=_status(doc),
                   identity=Identity.of(doc.get("identity")), mass_method=_s(doc, "mass_method"),
                   mass_method_requested=_s(doc, "mass_method_requested"), mass_methods=MassEstimate.all_of(doc))


Result = MeasurementResult | CalibrationResult | PropertiesResult


@dataclass(frozen=True)
class FixtureFrame:
    """The fixture and the DuT's frame of a properties run (the ``properties`` command's ``fixture``): the fixture's
    CoG in the flange frame (m), the DuT frame's origin (m) and KUKA A, B, C (deg) in the flange frame."""

    cog_flange_m: tuple[float, float, float]
    dut_origin_flange_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dut_abc_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def as_command(self) -> dict[str, Any]:
        return {"cog_flange_m": [float(v) for v in self.cog_flange_m],
                "dut_origin_flange_m": [float(v) for v in self.dut_origin_flange_m],
                "dut_abc_deg": [float(v) for v in self.dut_abc_deg]}


@dataclass(frozen=True)
class CampaignPoint:
    """One load configuration of a campaign, as the ``calibrate`` command takes it."""

    kind: Literal["zero", "mass", "torque"]
    mass_kg: float
    lever_a3_m: float
    lever_a5_m: float

    def as_command(self) -> dict[str, Any]:
        return {"kind": self.kind, "mass_kg": self.mass_kg, "lever_a3_m": self.lever_a3_m,
                "lever_a5_m": self.lever_a5_m}


#: Keys of a ``[[point]]`` in a points file; a manifest's per-point trace keys are allowed and ignored.
POINT_KEYS = ("kind", "mass_kg", "lever_a3_m", "lever_a5_m")
IGNORED_KEYS = ("traces", "trace", "bodies", "name")


def load_points(path: Path) -> list[CampaignPoint]:
    """The campaign of a TOML points file: ``[[point]]`` tables with ``kind``, ``mass_kg``, ``lever_a3_m``,
    ``lever_a5_m`` (a campaign ``manifest.toml`` also qualifies: its trace keys are ignored). Each point is checked
    with the daemon's own schema; :class:`DataError` names the file, the point and the problem."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DataError(f"{path}: cannot read the points file: {exc}") from exc
    except RecursionError:  # tomllib's answer to arrays nested thousands deep
        raise DataError(f"{path}: cannot read the points file: nested too deeply") from None
    raw = doc.get("point")
    if not isinstance(raw, list) or not raw:
        raise DataError(f"{path}: no [[point]] tables")
    points = []
    for i, p in enumerate(raw, start=1):
        where = f"{path} [[point]] #{i}"
        if not isinstance(p, dict):
            raise DataError(f"{where}: not a table")
        unknown = sorted(set(p) - set(POINT_KEYS) - set(IGNORED_KEYS))
        if unknown:
            raise DataError(f"{where}: unknown key(s) {', '.join(unknown)}; expected {', '.join(POINT_KEYS)}")
        try:
            cp = CalibrationPoint.model_validate({k: p[k] for k in POINT_KEYS if k in p}, strict=False)
        except ValidationError as exc:
            problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise DataError(f"{where}: {problems}") from None
        points.append(CampaignPoint(cp.kind, cp.mass_kg, cp.lever_a3_m, cp.lever_a5_m))
    return points
