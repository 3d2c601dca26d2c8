"""Calibration campaigns and DuT measurements on the simulated KR 500 (``simulators.krc4.physics``), known truth.

The paper's procedure per loop (§2.4.2): brake-release move (±35° on A3/A5), settle, one trace, brakes applied for
the rest of the loop; bodies are changed with the brakes applied. The torque estimate carries the scenario's
non-linear gains, thermal drift, release transient, hysteresis, settling, noise and spikes.

The *true* calibration bodies are not the nominal ones: each body's mass is drawn around the nominal 20.93 kg with
``body_mass_u_kg`` (and the test adapter around 19.20 kg), while the manifest states the nominal masses, as a real
campaign with weighed bodies would. Everything is returned in memory (what ``rgse`` reads from the trace files);
:func:`write_dirs` writes the same data as real KUKA trace file sets and manifests.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.manifest import Loop, Manifest, PointSpec, Setup
from simulators.krc4 import physics as ph
from simulators.krc4.scenario import Scenario
from simulators.krc4.tracefiles import write_trace_set

ROBOT = "KR500R2830-SIM"
G = 9.81
DR = robots.get(robots.DEFAULT_KEY).lever_difference_m
SETTLE_S = 4.0
LOOP_S = 150.0
CHANGE_BODIES_S = 600.0
#: Torque rows: A5 lever of the 10 bodies on the test adapter (Table 1's three torque rows).
TORQUE_ROW_LEVERS_A5_M = robots.get(robots.DEFAULT_KEY).calibration.torque_levers_a5_m


@dataclass(frozen=True)
class SimCampaign:
    manifest: Manifest
    loops: list[list[Loop]]
    body_masses_kg: np.ndarray


@dataclass(frozen=True)
class SimMeasurement:
    loops: list[Loop]
    true_dut_mass_kg: float
    fixture_mass_kg: float


@dataclass(frozen=True)
class Knock:
    """The load is knocked (or its fixture settles) during loop ``loop`` (0-based) after ``fraction`` of its samples:
    the A3 and A5 readings shift by ``a3_nm``/``a5_nm`` from then on (``RobotModel.knock``)."""

    loop: int
    fraction: float
    a3_nm: float
    a5_nm: float


def _measure(model: ph.RobotModel, payload: ph.Payload, n_loops: int, n_samples: int, period_s: float,
             prefix: str, warm_s: float = 0.0, knock: Knock | None = None, change_s: float = CHANGE_BODIES_S,
             loop_s: float = LOOP_S, pose_offset_deg: tuple[float, ...] | None = None) -> list[Loop]:
    """One mounting of ``payload`` and its loops; ``warm_s``: the drives hold (and heat) that long first;
    ``change_s``: brakes applied that long before (the bodies are changed); ``loop_s``: one loop's duration;
    ``pose_offset_deg``: A1..A6 added to the measurement pose (a load measured in another pose)."""
    q = kin.measurement_pose()
    if pose_offset_deg is not None:
        q = q + np.asarray(pose_offset_deg, float)
    model.apply_brakes(change_s)
    model.new_mounting()
    if warm_s > 0:
        model.hold(warm_s)
    out = []
    for k in range(n_loops):
        model.brake_release_move(q)
        model.hold(SETTLE_S)
        if knock is not None and knock.loop == k:
            first = round(knock.fraction * n_samples)
            a = model.sample_trace(q, payload, first, period_s)
            model.knock([0.0, 0.0, knock.a3_nm, 0.0, knock.a5_nm, 0.0])
            b = model.sample_trace(q, payload, n_samples - first, period_s)
            tr = {ax: {ch: np.concatenate([a[ax][ch], b[ax][ch]]) for ch in a[ax]} for ax in (3, 5)}
        else:
            tr = model.sample_trace(q, payload, n_samples, period_s)
        out.append(Loop(f"{prefix}_l{k + 1:02d}", tr[3]["Istmoment"], tr[5]["Istmoment"], period_s,
                        float(np.mean(tr[3]["Motortemperatur"])), float(np.mean(tr[5]["Motortemperatur"])),
                        (float(np.median(tr[3]["Istposition"])), float(np.median(tr[5]["Istposition"])))))
        model.apply_brakes(max(loop_s - SETTLE_S - n_samples * period_s, 0.0))
    return out


def with_gap(loop: Loop, channel: str, start: float, length: float) -> Loop:
    """``loop`` with samples missing (NaN; the trace writer writes DIAdem's no-value marker) from ``start`` for
    ``length`` (fractions of the loop) in ``channel``: ``"A3"``/``"A5"`` (Istmoment) or ``"all"`` (both; a temperature
    gap is written by :func:`write_dirs` from ``gaps``)."""
    n = loop.torque_a3_nm.size
    sl = slice(int(start * n), int(start * n) + max(int(length * n), 1))
    a3, a5 = np.array(loop.torque_a3_nm, float), np.array(loop.torque_a5_nm, float)
    if channel in ("A3", "all"):
        a3[sl] = np.nan
    if channel in ("A5", "all"):
        a5[sl] = np.nan
    return replace(loop, torque_a3_nm=a3, torque_a5_nm=a5)


def _bodies(masses_kg: np.ndarray, template: tuple[ph.RigidBody, ...]) -> tuple[ph.RigidBody, ...]:
    return tuple(replace(b, mass_kg=float(m)) for b, m in zip(template, masses_kg, strict=False))


def simulate_campaign(seed: int, n_loops: int = 3, n_samples: int = 250, period_s: float = 0.012,
                      body_mass_u_kg: float = 0.01, scenario: Scenario | None = None,
                      torque_rows: tuple[tuple[int, float], ...] | None = None, warm_s: float = 0.0,
                      change_s: float = CHANGE_BODIES_S, loop_s: float = LOOP_S
                      ) -> tuple[SimCampaign, ph.RobotModel]:
    """A Table-1-like campaign: MPA, MPA + 1..10 bodies, the torque rows (``(n_cb, cb_lever_a5_m)`` on the test
    adapter; default Table 1's three, 10 bodies at :data:`TORQUE_ROW_LEVERS_A5_M`); every point a new mounting.
    ``warm_s``: the loop's cycle runs that long before the campaign (a warm-up); ``change_s``: brakes applied
    while the bodies are changed; ``loop_s``: one loop's duration. A warmed-up campaign whose bodies are changed
    quickly (``warm_s=3600, change_s=5, loop_s=40``) is thermally steady: its loops differ by 0.2 K within a point,
    so the drift coefficient rests on a small span."""
    model = ph.RobotModel(scenario, seed=seed)
    rng = np.random.default_rng(10_000 + seed)
    true_cb = ph.CB_MASS_KG + rng.normal(0.0, body_mass_u_kg, ph.N_CB_MAX)
    true_ta = ph.TA_MASS_KG + rng.normal(0.0, body_mass_u_kg)
    specs, loops = [], []
    timing = {"change_s": change_s, "loop_s": loop_s}
    if warm_s > 0:  # warm-up: the loop's cycle (brake-release move, hold, brakes) run until warm_s have passed
        q = kin.measurement_pose()
        for _ in range(int(warm_s // loop_s)):
            model.brake_release_move(q)
            model.hold(SETTLE_S + n_samples * period_s)
            model.apply_brakes(max(loop_s - SETTLE_S - n_samples * period_s, 0.0))
    for n in range(ph.N_CB_MAX + 1):
        payload = ph.Payload((ph.mpa(), *_bodies(true_cb[:n], ph.calibration_stack(n))))
        l3, l5 = ph.paper_levers_m(n)
        name = f"cal{n:02d}"
        loops.append(_measure(model, payload, n_loops, n_samples, period_s, name, **timing))
        specs.append(PointSpec("zero" if n == 0 else "mass", round(ph.CB_MASS_KG * n, 2), l3, l5,
                               tuple(lp.trace for lp in loops[-1]), n))
    rows = torque_rows if torque_rows is not None else tuple((ph.N_CB_MAX, lv) for lv in TORQUE_ROW_LEVERS_A5_M)
    for j, (n_cb, lever_a5) in enumerate(rows):
        nominal_torque_mass = n_cb * ph.CB_MASS_KG + ph.TA_MASS_KG
        nominal = ph.torque_calibration_payload(n_cb, lever_a5)
        mpa_b, ta, *cbs = nominal.bodies
        payload = ph.Payload((mpa_b, replace(ta, mass_kg=float(true_ta)), *_bodies(true_cb[:n_cb], tuple(cbs))))
        # the manifest's lever: the nominal load's torque about A5 over its nominal weight
        lever = (ph.TA_TORQUE_A5_NM + G * n_cb * ph.CB_MASS_KG * lever_a5) / (G * nominal_torque_mass)
        name = f"cal{11 + j:02d}"
        loops.append(_measure(model, payload, n_loops, n_samples, period_s, name, **timing))
        specs.append(PointSpec("torque", round(nominal_torque_mass, 2), lever + DR, lever,
                               tuple(lp.trace for lp in loops[-1]), n_cb + 1))
    man = Manifest(Path("manifest.toml"), Setup(ROBOT, G, DR, body_mass_u_kg=body_mass_u_kg), specs)
    return SimCampaign(man, loops, np.r_[true_cb, true_ta]), model


def simulate_measurement(model: ph.RobotModel, dut_mass_kg: float, dut_cog_z_m: float = 0.25, n_loops: int = 3,
                         n_samples: int = 250, period_s: float = 0.012, warm_s: float = 0.0,
                         knock: Knock | None = None, change_s: float = CHANGE_BODIES_S,
                         pose_offset_deg: tuple[float, ...] | None = None) -> SimMeasurement:
    """A DuT on the ReFEx fixture on the MPA, measured after the campaign on the same simulated robot; ``warm_s``:
    the drives hold that long before the loops (a warmer robot than during the campaign); ``knock``: the load is
    knocked during one loop; ``change_s``: how long the brakes were applied before (the DuT is mounted);
    ``pose_offset_deg``: measured that far (A1..A6) from the measurement pose."""
    payload = ph.dut_payload(dut_mass_kg, (0.0, 0.0, dut_cog_z_m))
    return SimMeasurement(_measure(model, payload, n_loops, n_samples, period_s, "dut", warm_s, knock, change_s,
                                   pose_offset_deg=pose_offset_deg),
                          dut_mass_kg, ph.FIXTURE_MASS_KG)


def _write_loop(directory: Path, lp: Loop, temperature_gap: slice | None = None) -> None:
    modules: dict[str, dict[str, tuple[np.ndarray, str]]] = {}
    axes = (None, None) if lp.axes_deg is None else lp.axes_deg
    for module, torque, temp, q in (("NextGenDrive#3", lp.torque_a3_nm, lp.motor_temp_a3_k, axes[0]),
                                    ("NextGenDrive#5", lp.torque_a5_nm, lp.motor_temp_a5_k, axes[1])):
        modules[module] = {"Istmoment": (torque, "Nm")}
        if q is not None:  # the loop's position (the drive records it per sample; at standstill it holds it)
            modules[module]["Istposition"] = (np.full(torque.size, q), "deg")
        if temp is not None:  # the loop's mean motor temperature as the channel (the drive records it per sample)
            values = np.full(torque.size, temp)
            if temperature_gap is not None:
                values[temperature_gap] = np.nan  # written as the no-value marker
            modules[module]["Motortemperatur"] = (values, "K")
    write_trace_set(directory, lp.trace, lp.period_s, modules)


def write_dirs(campaign: SimCampaign, measurement: SimMeasurement, cal_dir: Path, dut_dir: Path,
               temperature_gaps: dict[str, slice] | None = None) -> None:
    """The campaign and the measurement as real directories (manifest.toml + KUKA trace file sets);
    ``temperature_gaps``: per trace name, samples of its Motortemperatur channels written as missing."""
    gaps = temperature_gaps or {}
    setup = campaign.manifest.setup
    head = ["[setup]", f'robot = "{setup.robot}"', f"g = {setup.g_m_s2!r}",
            f"lever_difference_m = {setup.lever_difference_m!r}", f"body_mass_u_kg = {setup.body_mass_u_kg!r}", ""]
    cal_dir.mkdir(parents=True, exist_ok=True)
    lines = list(head)
    for spec, loops in zip(campaign.manifest.points, campaign.loops, strict=True):
        for lp in loops:
            _write_loop(cal_dir, lp, gaps.get(lp.trace))
        lines += ["[[point]]", f'kind = "{spec.kind}"', f"mass_kg = {spec.mass_kg!r}",
                  f"lever_a3_m = {spec.lever_a3_m!r}", f"lever_a5_m = {spec.lever_a5_m!r}", f"bodies = {spec.bodies}",
                  "traces = [" + ", ".join(f'"{lp.trace}"' for lp in loops) + "]", ""]
    (cal_dir / "manifest.toml").write_text("\n".join(lines), encoding="utf-8")
    dut_dir.mkdir(parents=True, exist_ok=True)
    for lp in measurement.loops:
        _write_loop(dut_dir, lp, gaps.get(lp.trace))
    text = [*head, "[measurement]", f"fixture_mass_kg = {measurement.fixture_mass_kg!r}",
            "traces = [" + ", ".join(f'"{lp.trace}"' for lp in measurement.loops) + "]", ""]
    (dut_dir / "manifest.toml").write_text("\n".join(text), encoding="utf-8")
