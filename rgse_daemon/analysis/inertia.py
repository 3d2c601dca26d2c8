"""The inertia of a DuT from a run directory's motion traces (issue #15), and the excitation program of a run.

One code path for ``rgse inertia`` and a run that includes inertia. The numbers are computed in
:mod:`rgse_daemon.pipeline.inertia`; the moves are designed in :mod:`rgse_daemon.pipeline.excitation`.

A run directory holds two KUKA Trace sets recorded while ``rgse_inertia`` ran, the *tare* (MPA and fixture) and the
*DuT* (on the same fixture), with the drives of A4–A6 (``Sollposition``, ``Istposition``, ``Istmoment``; with
``Motortemperatur`` the reading's thermal drift between the two runs is fitted too), and a
manifest ``inertia.toml`` (docs/interfaces.md)::

    [inertia]
    dut_trace = "inertia_dut"          # trace names in the directory; or lists of them, pair by pair (a long
    tare_trace = "inertia_tare"        # excitation in several programs, one trace each)
    base_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]   # A1..A6 of the axes a trace does not hold (A1..A3)
    mass_kg = 107.3                    # the DuT, from the static measurement
    cog_flange_m = [-0.041, -0.028, 0.345]
    U_cog_flange_m = [0.002, 0.002, 0.002]          # k = 2
    dut_abc_deg = [90.0, 0.0, 0.0]     # the DuT frame on the flange (KUKA A, B, C)
    fixture_mass_kg = 30.0             # what the tare run carries (MPA + fixture): the calibration's operating point
    fixture_cog_flange_m = [0.0, 0.0, 0.04]

With a CAL.json whose ``torsional`` section has gain curves for A4–A6, the readings are taken through them
(``pipeline.inertia.TorqueCalibration``) and the relative uncertainty of each one's slope at the run's operating
point (parameters and model form, ``AxisGain.slope_u_rel``) enters U, axis by axis, with a warning where that
operating point lies outside the torques the calibration covered; without one, 1:1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon.errors import DataError
from rgse_daemon.krl.render import InertiaMove, InertiaParams, RenderedProgram, render
from rgse_daemon.manifest import check_keys, read_toml
from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.pipeline import inertia as inr
from rgse_daemon.pipeline.axis_gain import AxisGain
from rgse_daemon.trace.channels import ISTMOMENT, ISTPOSITION, MOTORTEMPERATUR, SOLLPOSITION, drive_module
from rgse_daemon.trace.diadem import read_trace_set

#: $ACC_AXIS (%) of the first move, to the start pose.
START_ACC_PCT = 20.0
MANIFEST = "inertia.toml"
#: The farthest plausible CoG from the flange (m): the KR 500's load diagram ends well within it.
MAX_COG_M = 5.0
#: ECSS-E-10-03C: the inertia tensor within ±3 %.
ECSS_REL = 0.03


def excitation_program(design: ex.Excitation, rest_s: float = 0.0) -> RenderedProgram:
    """The KRL of a designed excitation (template ``rgse_inertia``), ``rest_s`` of standstill after each move; the
    static check still decides the push."""
    return moves_program(design.start_deg, design.moves, rest_s)


def moves_program(start_deg: Sequence[float], moves: Sequence[ex.Move], rest_s: float = 0.0) -> RenderedProgram:
    """``rgse_inertia`` for ``moves`` (a whole excitation or a part of it) from ``start_deg``."""
    first = moves[0]
    params = InertiaParams(vel_axis_pct=min(first.vel_axis_pct), acc_axis_pct=START_ACC_PCT,
                           start_pose=tuple(float(v) for v in start_deg), rest_s=rest_s,
                           moves=tuple(InertiaMove(pose=m.target_deg, vel_axis_pct=m.vel_axis_pct,
                                                   acc_axis_pct=m.acc_axis_pct) for m in moves))
    return render(InertiaParams.template, params)


def _names(v: str | tuple[str, ...]) -> tuple[str, ...]:
    return (v,) if isinstance(v, str) else tuple(v)


@dataclass(frozen=True)
class InertiaManifest:
    dut_trace: str | tuple[str, ...]
    """One trace, or several (the parts of the excitation in order); the tare's pair with them one by one."""
    tare_trace: str | tuple[str, ...]
    base_deg: tuple[float, ...]
    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    U_cog_flange_m: tuple[float, float, float]
    dut_abc_deg: tuple[float, float, float]
    fixture_mass_kg: float
    fixture_cog_flange_m: tuple[float, float, float]

    def to_toml(self) -> str:
        def arr(v: Any) -> str:
            return "[" + ", ".join(repr(float(x)) for x in v) + "]"

        def names(v: str | tuple[str, ...]) -> str:
            return f'"{v}"' if isinstance(v, str) else "[" + ", ".join(f'"{n}"' for n in v) + "]"

        return "\n".join([
            "[inertia]",
            f"dut_trace = {names(self.dut_trace)}",
            f"tare_trace = {names(self.tare_trace)}",
            f"base_deg = {arr(self.base_deg)}",
            f"mass_kg = {float(self.mass_kg)!r}",
            f"cog_flange_m = {arr(self.cog_flange_m)}",
            f"U_cog_flange_m = {arr(self.U_cog_flange_m)}",
            f"dut_abc_deg = {arr(self.dut_abc_deg)}",
            f"fixture_mass_kg = {float(self.fixture_mass_kg)!r}",
            f"fixture_cog_flange_m = {arr(self.fixture_cog_flange_m)}",
            "",
        ])


def _floats(d: dict[str, Any], key: str, n: int, where: str) -> tuple[float, ...]:
    v = d.get(key)
    if not isinstance(v, list) or len(v) != n or not all(isinstance(x, int | float) and math.isfinite(x) for x in v):
        raise DataError(f"{where}: {key} must be {n} finite numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _cog(d: dict[str, Any], key: str, where: str) -> tuple[float, float, float]:
    """A CoG in the flange frame: finite and within MAX_COG_M of the flange (the robot cannot carry one farther)."""
    c = _floats(d, key, 3, where)
    if math.hypot(*c) > MAX_COG_M:
        raise DataError(f"{where}: {key} = {list(c)!r} is {math.hypot(*c):.3g} m from the flange, more than "
                        f"{MAX_COG_M:g} m: not a CoG the robot can carry (metres, not millimetres?)")
    return c  # type: ignore[return-value]


#: The keys of ``[inertia]`` (docs/interfaces.md); any other is refused (a misspelt optional key would take its
#: default).
INERTIA_KEYS = ("dut_trace", "tare_trace", "base_deg", "mass_kg", "cog_flange_m", "U_cog_flange_m", "dut_abc_deg",
                "fixture_mass_kg", "fixture_cog_flange_m")


def load_manifest(directory: Path) -> InertiaManifest:
    path = directory / MANIFEST
    if not path.exists():
        raise DataError(f"{path}: no inertia manifest in the run directory")
    doc = read_toml(path)
    check_keys(doc, ("inertia",), str(path))
    sec = doc.get("inertia")
    if not isinstance(sec, dict):
        raise DataError(f"{path}: no [inertia] table")
    check_keys(sec, INERTIA_KEYS, f"{path} [inertia]")
    for key in ("dut_trace", "tare_trace"):
        v = sec.get(key)
        if isinstance(v, list) and v and all(isinstance(n, str) for n in v):
            sec[key] = tuple(v)
        elif not isinstance(v, str):
            raise DataError(f"{path}: {key} must be a trace name or a list of them, got {v!r}")
    if len(_names(sec["dut_trace"])) != len(_names(sec["tare_trace"])):
        raise DataError(f"{path}: {len(_names(sec['dut_trace']))} DuT traces but {len(_names(sec['tare_trace']))} "
                        "tare traces: they pair one by one")
    same = [d for d, t in zip(_names(sec["dut_trace"]), _names(sec["tare_trace"]), strict=True) if d == t]
    if same:
        raise DataError(f"{path}: dut_trace and tare_trace both name {same[0]!r}: the tare is its own run (MPA and "
                        "fixture without the DuT), its trace differs from the DuT's")
    mass = sec.get("mass_kg")
    if not isinstance(mass, int | float) or not mass > 0:
        raise DataError(f"{path}: mass_kg must be a positive number, got {mass!r}")
    fmass = sec.get("fixture_mass_kg", 0.0)
    if not isinstance(fmass, int | float) or not fmass >= 0:
        raise DataError(f"{path}: fixture_mass_kg must be >= 0, got {fmass!r}")
    cog = _cog(sec, "cog_flange_m", str(path))
    u_cog = _floats(sec, "U_cog_flange_m", 3, str(path)) if "U_cog_flange_m" in sec else (0.0, 0.0, 0.0)
    if any(u < 0 for u in u_cog):
        raise DataError(f"{path}: U_cog_flange_m must be >= 0 (an expanded uncertainty), got {list(u_cog)!r}")
    return InertiaManifest(
        sec["dut_trace"], sec["tare_trace"], _floats(sec, "base_deg", 6, str(path)), float(mass),
        cog, u_cog,  # type: ignore[arg-type]
        _floats(sec, "dut_abc_deg", 3, str(path)) if "dut_abc_deg" in sec else (0.0, 0.0, 0.0),  # type: ignore[arg-type]
        float(fmass),
        _cog(sec, "fixture_cog_flange_m", str(path)) if "fixture_cog_flange_m" in sec else (0.0, 0.0, 0.0),
    )


def read_strokes(directory: Path, name: str, base_deg: tuple[float, ...]) -> tuple[list[inr.Stroke], float]:
    """The strokes (one per motion) of trace ``name`` and its sample period; axes not traced stand at ``base_deg``."""
    ts = read_trace_set(directory, name)
    traced = [ax for ax in range(1, 7) if drive_module(ax) in ts.files]
    missing = [ax for ax in inr.WRIST_AXES if ax not in traced]
    if missing:
        raise DataError(f"{directory}: trace {name!r} lacks the drives of A{', A'.join(map(str, missing))}")
    first = ts.files[drive_module(traced[0])]
    n, period = first.n_samples, float(first.period_s)
    soll = np.tile(np.asarray(base_deg, float), (n, 1))
    ist = soll.copy()
    tau = np.full((n, 6), np.nan)
    temp = np.full((n, 6), np.nan)
    for ax in traced:
        tf = ts.files[drive_module(ax)]
        if tf.n_samples != n or not math.isclose(tf.period_s, period, rel_tol=1e-9):
            raise DataError(f"{tf.dat_path}: {tf.n_samples} samples every {tf.period_s} s, the other drives of the "
                            f"trace have {n} every {period} s")
        for arr, ch in ((soll, SOLLPOSITION), (ist, ISTPOSITION), (tau, ISTMOMENT)):
            values = np.asarray(tf.channel(ch).values, float)
            if not np.all(np.isfinite(values)):
                raise DataError(f"{tf.dat_path}: channel {ch!r} is not finite")
            arr[:, ax - 1] = values
        if MOTORTEMPERATUR in tf.channels:
            temp[:, ax - 1] = np.asarray(tf.channel(MOTORTEMPERATUR).values, float)
    has_temp = all(np.all(np.isfinite(temp[:, ax - 1])) for ax in inr.WRIST_AXES)
    t = np.arange(n) * period
    strokes = []
    for sl in inr.split_strokes(soll):
        lo, hi = max(sl.start - round(0.15 / period), 0), min(sl.stop + round(0.15 / period), n)
        strokes.append(inr.Stroke(t[lo:hi], ist[lo:hi], tau[lo:hi], soll[lo:hi],
                                  temp_k=np.nan_to_num(temp[lo:hi], nan=0.0) if has_temp else None))
    return strokes, period


def torque_calibration(gains: dict[int, AxisGain], fixture_mass_kg: float,
                       fixture_cog_flange_m: Sequence[float]) -> inr.TorqueCalibration:
    """The wrist axes' gain curves of a calibration (CAL.json's torsional section) as the identification takes
    them, with what the tare run carries (MPA and fixture: with the DuT the operating point), the slopes'
    uncertainty as a function of the payload torque (taken at the run's operating point) and the torques each curve
    covered (an operating point outside them gets a warning)."""
    wrist = {ax: g for ax, g in gains.items() if ax in inr.WRIST_AXES}
    fix = float(fixture_mass_kg)
    return inr.TorqueCalibration(wrist, (fix, *(fix * float(c) for c in fixture_cog_flange_m)),  # type: ignore[arg-type]
                                 slope_u_rel_at={ax: g.slope_u_rel for ax, g in wrist.items()},
                                 covered_nm={ax: g.torque_range_nm for ax, g in wrist.items()})


def compute_inertia_dir(directory: Path | str, calibration_path: Path | str | None = None,
                        n_bootstrap: int = inr.N_BOOTSTRAP) -> inr.InertiaResult:
    """The identification of a run directory (see the module docstring)."""
    directory = Path(directory)
    man = load_manifest(directory)
    strokes: list[inr.Stroke] = []
    periods: set[float] = set()
    for dut_name, tare_name in zip(_names(man.dut_trace), _names(man.tare_trace), strict=True):
        dut, period = read_strokes(directory, dut_name, man.base_deg)
        tare, period_t = read_strokes(directory, tare_name, man.base_deg)
        if not math.isclose(period, period_t, rel_tol=1e-9) or any(
                not math.isclose(period, p, rel_tol=1e-9) for p in periods):
            raise DataError(f"{directory}: traces {dut_name} and {tare_name} have different sample periods "
                            f"({period} / {period_t} s, others {sorted(periods)})")
        periods.add(period)
        if len(dut) != len(tare):
            raise DataError(f"{directory}: the DuT trace {dut_name} has {len(dut)} motions, the tare {tare_name} "
                            f"{len(tare)}: not the same excitation")
        try:
            strokes += [inr.difference(d, t) for d, t in zip(dut, tare, strict=True)]
        except ValueError as exc:
            raise DataError(f"{directory}: {dut_name} / {tare_name}: {exc}") from exc
    cal = None
    if calibration_path is not None:
        tors = calfile.read(calibration_path).torsional
        if tors is None:
            raise DataError(f"{calibration_path}: no torsional section (the gain curves of A4..A6)")
        cal = torque_calibration(tors.gains, man.fixture_mass_kg, man.fixture_cog_flange_m)
    try:
        return inr.identify(strokes, period, man.mass_kg, man.cog_flange_m, dut_abc_deg=man.dut_abc_deg,
                            calibration=cal, u_cog_flange_m=tuple(u / 2.0 for u in man.U_cog_flange_m),
                            n_bootstrap=n_bootstrap)
    except inr.NotPhysical as exc:
        raise DataError(f"{directory}: {exc}; check {MANIFEST}: dut_trace / tare_trace swapped? cog_flange_m, "
                        "mass_kg right?") from exc
    except ValueError as exc:
        raise DataError(f"{directory}: {exc}") from exc
