"""The CoG measurement on the simulated KR 500 (``simulators.krc4.physics``), known truth: the torsional points of a
calibration campaign and a properties run of an asymmetric DuT, in memory or as real KUKA trace file sets.

The procedure per pose (the plan's): move to the pose's approach (A4/A6 5° below), into the pose; per loop the
brake-release move (±35° on A3/A5), settle, one trace of all six drives, brakes applied for the rest of the loop.
Every point, and the DuT, is a new mounting (its own reading offsets and CoG shift along the flange axis). The
calibration bodies' true masses scatter around the nominal 20.93 kg by ``body_mass_u_kg``; the manifest states the
nominal ones, as a real campaign would.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.analysis.cog import FixtureFrame, PoseReading, properties_manifest_toml
from rgse_daemon.pipeline import cog, torsion
from simulators.krc4 import physics as ph
from simulators.krc4.tracefiles import write_trace_set

SETTLE_S = 4.0
LOOP_S = 30.0
MOVE_S = 8.0
#: The torsional points (bodies on the bracket, their common CoG in the flange frame, m): two, four and six bodies
#: at both signs of x and y, along the flange axis from 0.30 to 0.50 m, so that the payload torques of A3..A6 span
#: those of a 100-130 kg DuT in every pose of the full scheme.
TORSIONAL_POINTS: tuple[tuple[int, tuple[float, float, float]], ...] = (
    robots.get(robots.DEFAULT_KEY).calibration.torsional_points)  # the KR 500's (rgse_daemon/robots/)


@dataclass(frozen=True)
class PoseTraces:
    """The loops of one pose: per loop the ``Istmoment`` of A1..A6 (array (6, n))."""

    name: str
    q_deg: tuple[float, ...]
    loops: list[np.ndarray]
    period_s: float
    temps_k: list[np.ndarray]
    """Per loop the ``Motortemperatur`` of A1..A6 (array (6, n), K)."""

    def reading(self) -> PoseReading:
        """Mean of the loop means and its standard error (what ``analysis.cog`` computes from the files, without
        the pre-processing's crop and filter)."""
        means = np.array([lp.mean(axis=1) for lp in self.loops])
        within = np.sqrt(sum((lp.std(axis=1) / np.sqrt(lp.shape[1])) ** 2 for lp in self.loops)) / len(self.loops)
        temps = np.mean([t.mean(axis=1) for t in self.temps_k], axis=0)
        return PoseReading(self.name, self.q_deg, tuple(means.mean(axis=0)), tuple(within), tuple(temps))


def warm_up(model: ph.RobotModel, cycles: int = 60) -> None:
    """Warm the drives up with the loop's own duty cycle (brake-release move, settle and trace with the brakes open,
    the rest of the loop braked) until the motor temperatures are steady, as the daemon's warm-up does: a long
    continuous hold would leave them hotter than the loops keep them, and the first points would drift."""
    q = kin.measurement_pose()
    for _ in range(cycles):
        model.brake_release_move(q)
        model.hold(SETTLE_S + 3.0)
        model.apply_brakes(LOOP_S - SETTLE_S - 3.0)


def measure_poses(model: ph.RobotModel, poses: list[cog.CogPose], payload: ph.Payload, n_loops: int = 2,
                  n_samples: int = 250, period_s: float = 0.012) -> list[PoseTraces]:
    """One mounting of ``payload`` measured in every pose."""
    model.new_mounting()
    q_prev = kin.measurement_pose()
    out = []
    for p in poses:
        q, q_app = np.array(p.q_deg), np.array(p.q_approach_deg)
        model.move(q_prev, q_app, MOVE_S)
        model.move(q_app, q, 1.0)
        loops, temps = [], []
        for _ in range(n_loops):
            model.brake_release_move(q)
            model.hold(SETTLE_S)
            tr = model.sample_trace(q, payload, n_samples, period_s)
            loops.append(np.array([tr[a]["Istmoment"] for a in range(1, 7)]))
            temps.append(np.array([tr[a]["Motortemperatur"] for a in range(1, 7)]))
            model.apply_brakes(max(LOOP_S - SETTLE_S - n_samples * period_s, 0.0))
        out.append(PoseTraces(p.name, p.q_deg, loops, period_s, temps))
        q_prev = q
    return out


@dataclass(frozen=True)
class TorsionalCampaign:
    """The torsional points as measured: the bare MPA (bias) first, then the loaded points (nominal mass, CoG)."""

    scheme: str
    poses: list[cog.CogPose]
    bias: list[PoseTraces]
    points: list[tuple[float, tuple[float, float, float], list[PoseTraces]]]

    def fit(self) -> torsion.TorsionalFit:
        bias = {t.name: _mean(t) for t in self.bias}
        pts = [torsion.TorsionalPoint(m, c, {t.name: _mean(t) for t in traces}) for m, c, traces in self.points]
        return torsion.fit_torsional(self.poses, bias, pts)


def _mean(t: PoseTraces) -> torsion.PoseMean:
    r = t.reading()
    return torsion.PoseMean(r.torque_nm, r.sigma_nm)


def simulate_torsional(model: ph.RobotModel, scheme: str = "full", n_loops: int = 2, n_samples: int = 250,
                       points: tuple = TORSIONAL_POINTS, body_mass_u_kg: float = 0.01, seed: int = 0
                       ) -> TorsionalCampaign:
    poses = cog.cog_poses(kin.measurement_pose(), scheme)
    rng = np.random.default_rng(20_000 + seed)
    bias = measure_poses(model, poses, ph.torsional_point_payload(0, 0.0, 0.0), n_loops, n_samples)
    out = []
    for n_cb, c in points:
        nominal = ph.torsional_point_payload(n_cb, *c)
        true = ph.Payload((nominal.bodies[0], *(replace(b, mass_kg=b.mass_kg + float(rng.normal(0, body_mass_u_kg)))
                                                  for b in nominal.bodies[1:])))
        out.append((n_cb * ph.CB_MASS_KG, c, measure_poses(model, poses, true, n_loops, n_samples)))
    return TorsionalCampaign(scheme, poses, bias, out)


@dataclass(frozen=True)
class PropertiesRun:
    dut: ph.AsymmetricDut
    poses: list[PoseTraces]
    true_cog_flange_m: np.ndarray
    """The DuT's CoG as mounted (the mounting's shift along the flange axis included), flange frame."""

    @property
    def fixture(self) -> FixtureFrame:
        return FixtureFrame(ph.FIXTURE_MASS_KG, ph.fixture_cog_flange_m(), self.dut.dut_origin_flange_m,
                            self.dut.dut_abc_deg)


def simulate_properties(model: ph.RobotModel, dut: ph.AsymmetricDut, scheme: str = "full", n_loops: int = 2,
                        n_samples: int = 250) -> PropertiesRun:
    poses = cog.cog_poses(kin.measurement_pose(), scheme)
    payload = dut.payload()
    traces = measure_poses(model, poses, payload, n_loops, n_samples)
    truth = model.last_truth
    # everything on the flange as mounted, minus MPA and fixture (known), is the DuT
    total = truth.payload_mass_kg * np.array([1.0, *truth.payload_cog_flange_m])
    known = sum(b.mass_kg * np.array([1.0, *b.cog_flange_m]) for b in payload.bodies if b.name != "DuT")
    return PropertiesRun(dut, traces, (total - known)[1:] / dut.mass_kg)


# --- as files ---------------------------------------------------------------------------------------------------------
def _write_pose(directory: Path, prefix: str, t: PoseTraces) -> list[str]:
    names = []
    for k, (loop, temp) in enumerate(zip(t.loops, t.temps_k, strict=True)):
        name = f"{prefix}_{t.name.replace('+', 'p').replace('-', 'm').replace('/', '_')}_l{k + 1:02d}"
        write_trace_set(directory, name, t.period_s,
                        {f"NextGenDrive#{a}": {"Istmoment": (loop[a - 1], "Nm"), "Motortemperatur": (temp[a - 1], "K")}
                         for a in range(1, 7)})
        names.append(name)
    return names


def torsional_manifest_lines(directory: Path, campaign: TorsionalCampaign) -> list[str]:
    """Write the torsional points' traces into a campaign directory; returns the manifest lines to append."""
    lines = ["[torsional]", f'scheme = "{campaign.scheme}"', ""]
    for p in campaign.poses:
        lines += ["[[torsional.pose]]", f'name = "{p.name}"', f"q_deg = {list(p.q_deg)!r}", ""]
    entries = [(0.0, (0.0, 0.0, 0.0), campaign.bias), *campaign.points]
    for k, (mass, c, traces) in enumerate(entries):
        lines += ["[[point]]", 'kind = "torsional"', f"mass_kg = {mass!r}", f"cog_flange_m = {list(c)!r}",
                  "[point.poses]"]
        for t in traces:
            names = _write_pose(directory, f"tor{k:02d}", t)
            lines.append(f'"{t.name}" = [' + ", ".join(f'"{n}"' for n in names) + "]")
        lines.append("")
    return lines


def write_properties_dir(directory: Path, run: PropertiesRun, *, robot: str, mass_kg: float | None = None,
                         u_mass_kg: float | None = None, scheme: str = "full",
                         measurement_pose_traces: bool = False) -> None:
    """The run as a properties run directory; without ``mass_kg`` the mass comes from the measurement pose's loops
    (``measurement_pose_traces``), as ``rgse mass`` measures it."""
    directory.mkdir(parents=True, exist_ok=True)
    poses = [(t.name, t.q_deg, _write_pose(directory, "prop", t)) for t in run.poses]
    setup = ["[setup]", f'robot = "{robot}"', f"g = {kin.G_PAPER_M_S2!r}", f"lever_difference_m = {kin.D4_M!r}", ""]
    if measurement_pose_traces:  # the measurement pose's loops, again under names of their own, are the mass run's
        meas = _write_pose(directory, "mass", next(t for t in run.poses if t.name == "meas"))
        setup += ["[measurement]", f"fixture_mass_kg = {ph.FIXTURE_MASS_KG!r}",
                  "traces = [" + ", ".join(f'"{n}"' for n in meas) + "]", ""]
    text = "\n".join(setup) + "\n" + properties_manifest_toml(scheme, run.fixture, poses, mass_kg=mass_kg,
                                                              u_mass_kg=u_mass_kg)
    (directory / "manifest.toml").write_text(text, encoding="utf-8")
