"""The multi-pose mass (issue #35): the mass from A3 torque differences between poses of one mounting, at lever
changes the kinematics give, in the spirit of eq. 3/4 (docs/accuracy.md, "Multi-pose mass").

Lever poses (:func:`lever_poses`): the measurement pose with A3 turned by Δ_k and A5 by −Δ_k. The flange keeps its
orientation, so the CoG offset of every flange load has the same lever to A3 in every pose (and its A5 torque does not
change at all); only the flange origin's horizontal lever to A3, L_k, changes (KR 500: 1.315 m in the measurement pose,
0.522 m with the forearm raised by 80°). The payload torque on A3 in pose k (holding-torque sign, MPA excluded):

    x_k = −g·m·L_k + c                                                   (MP1)

c: the CoG's part, the same in every pose. x_k = K_A3⁻¹(M_A3,k − M_0,k) with M_0,k the bare reading (MPA only) of pose
k and K_A3 the axis' gain (:class:`~rgse_daemon.pipeline.cog.AxisGain`, fitted on the campaign's points). A reading
offset o of the mounting (what Table 1 shows as about ±1 kg per point) is the same in every pose: it moves c, not
the slope. Least squares over the poses (weights w_k = 1 / var x_k):

    m = −Σ w_k (L_k − L̄)(x_k − x̄) / (g · Σ w_k (L_k − L̄)²)              (MP2; two poses: (x_v − x_h) / (g (L_h − L_v)))
    m_DuT = m − m_f                                                      (MP3)

What remains in U (standard uncertainties, :class:`MultiPoseUncertainty`): the visits' repeatability (a visit is one
loop in a pose: its noise, the seating of the wrist after the move, the drift left after the thermal correction), the
bare readings' means, K_A3's slope (its parameters and its model form; it holds the DH lengths' error of the lever
change, since K_A3 is calibrated in these poses with the same levers), the lever change's drift since the
calibration, β of the thermal correction, g.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy import stats

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import thermal as th
from rgse_daemon.pipeline.axis_gain import AxisGain
from rgse_daemon.pipeline.uncertainty import COVERAGE_K
from rgse_daemon.robots.model import RobotModel

#: Level of the F test that finds a DuT's visits scattering more than the calibration's visits did.
VISIT_F_LEVEL = 0.99
#: Relative standard uncertainty of the lever change between the poses *as it was when K_A3 was calibrated*. The DH
#: rows' own error (a catalogue's lengths and mastering are good to about a millimetre and a few hundredths of a
#: degree: ~1 mm of the 0.79 m lever change) does not enter here: K_A3 is calibrated on loads of known mass in these
#: poses of this arm, with the same catalogue levers, so its secant reads g·ΔL·K as one product and the DH error is
#: part of it (and of the gain term's uncertainty). What K_A3 cannot hold is the lever change changing between the
#: calibration and the run: the arm's thermal expansion, 2.3e-5/K for an aluminium casting (half that for steel) over
#: 10 K, 2.3e-4 (docs/accuracy.md, "Multi-pose mass").
LEVER_DRIFT_U_REL = 2.3e-4
#: The smallest lever change (m) between the poses that the mass may rest on.
MIN_LEVER_CHANGE_M = 0.3


@dataclass(frozen=True)
class LeverPose:
    """One pose of the scheme: its name, A1..A6 (deg) and the flange origin's horizontal lever to A3 (m)."""

    name: str
    q_deg: tuple[float, ...]
    lever_a3_m: float


def flange_lever_a3_m(q_deg: Sequence[float], robot: RobotModel | None = None) -> float:
    """L: the flange origin's horizontal lever to A3 (m, positive in front), the mass column of the gravity
    regressor's A3 row over −g."""
    return float(-kin.gravity_regressor(q_deg, 1.0, robot)[2, 0])


def pose_name(a3_offset_deg: float) -> str:
    """A lever pose's name, as the CoG scheme ``lever`` calls it (:func:`~rgse_daemon.pipeline.cog.cog_poses`):
    ``meas`` for the measurement pose, else e.g. ``A3-80``."""
    return "meas" if a3_offset_deg == 0.0 else f"A3{a3_offset_deg:+g}"


def lever_poses(measurement_pose_deg: Sequence[float], a3_offsets_deg: Sequence[float] | None = None,
                robot: RobotModel | None = None) -> list[LeverPose]:
    """The scheme's poses: the measurement pose with A3 + Δ_k and A5 − Δ_k (``a3_offsets_deg`` default: the
    robot's ``multipose_a3_deg``). DataError if the robot has none, a pose lies outside the axis ranges, the flange
    does not keep its orientation (A4 ≠ 0) or the levers change by less than :data:`MIN_LEVER_CHANGE_M`."""
    r = robots.active() if robot is None else robot
    offsets = r.multipose_a3_deg if a3_offsets_deg is None else tuple(a3_offsets_deg)
    if len(offsets) < 2:
        raise DataError(f"multi-pose mass: robot {r.key} has no lever poses (robots/{r.key}.py multipose_a3_deg needs "
                        f"at least two A3 offsets)")
    base = np.asarray(measurement_pose_deg, dtype=float)
    if base.shape != (6,) or not np.all(np.isfinite(base)) or abs(base[3]) > 1e-9:
        raise DataError(f"multi-pose mass: the measurement pose must be six finite angles with A4 = 0, got "
                        f"{list(measurement_pose_deg)!r}")
    out = []
    rot0 = kin.flange_frame(base, r)[:3, :3]
    for d in offsets:
        q = base + np.array([0.0, 0.0, d, 0.0, -d, 0.0])
        if not kin.within_limits(q, robot=r):
            raise DataError(f"multi-pose mass: lever pose A3 {d:+g}° {q.tolist()} is outside the axis ranges")
        if not np.allclose(kin.flange_frame(q, r)[:3, :3], rot0, atol=1e-9):
            raise DataError(f"multi-pose mass: lever pose A3 {d:+g}° turns the flange (the measurement pose's A2 and "
                            f"A3 must keep A3 and A5 parallel)")
        out.append(LeverPose(pose_name(d), tuple(float(v) for v in q), flange_lever_a3_m(q, r)))
    levers = [p.lever_a3_m for p in out]
    if max(levers) - min(levers) < MIN_LEVER_CHANGE_M:
        raise DataError(f"multi-pose mass: the poses change the lever to A3 by only {max(levers) - min(levers):.3f} m "
                        f"(at least {MIN_LEVER_CHANGE_M} m)")
    return out


def visit_order(poses: Sequence[LeverPose], visits_per_pose: int) -> list[LeverPose]:
    """The order of the visits: back and forth (A B B A A B …), so that a drift linear in time has the same mean in
    every pose."""
    if visits_per_pose < 1:
        raise DataError(f"multi-pose mass: visits per pose must be >= 1, got {visits_per_pose}")
    out: list[LeverPose] = []
    for j in range(visits_per_pose):
        out += list(poses) if j % 2 == 0 else list(reversed(poses))
    return out


@dataclass(frozen=True)
class PoseVisits:
    """The A3 readings of one pose: per visit (one loop) the pre-processed mean (Nm; brought to the calibration's
    temperature where β is applied) and the mean of reading × (T − T_ref) (Nm·K) over its samples, for β's share of
    U (zeros where β is not applied)."""

    pose: str
    torque_a3_nm: np.ndarray
    thermal_lever_nm_k: np.ndarray

    @property
    def n(self) -> int:
        return int(np.size(self.torque_a3_nm))


#: A DuT's visits further than this from the reference temperature (K) with the drift left uncorrected get a warning
#: (as the single pose's loops, ``inline.THERMAL_NOTE_K``).
THERMAL_NOTE_K = 1.0
@dataclass(frozen=True)
class RunDrift:
    """A3's drift coefficient as the DuT's own visits show it: regression through the origin of r_kj − r̄_k on
    r̄_k·(T_kj − T̄_k) over the poses (as :func:`~rgse_daemon.pipeline.thermal.fit_axis` does a campaign's points),
    its standard uncertainty from one visit's repeatability σ (u = σ/√Σx²): the calibration's (a run has too few
    visits to estimate σ itself: two poses visited twice leave one degree of freedom), or the run's own residual
    scatter where that is larger; the visits' largest temperature span within a pose (K)."""

    beta_per_k: float
    u_beta_per_k: float
    span_k: float


def run_drift(readings: Sequence[tuple[np.ndarray, np.ndarray]], visit_sigma_nm: float) -> RunDrift | None:
    """:class:`RunDrift` from each pose's visits ``(A3 readings Nm, motor temperatures K)`` and one visit's
    repeatability (Nm); None where no pose has two visits with temperatures that differ, or σ is not known (≤ 0)."""
    if not (visit_sigma_nm > 0.0 and math.isfinite(visit_sigma_nm)):
        return None
    xs, ys, spans = [], [], []
    for r, t in readings:
        r, t = np.asarray(r, float), np.asarray(t, float)
        if r.size < 2 or not np.all(np.isfinite(t)):
            continue
        xs.append(r.mean() * (t - t.mean()))
        ys.append(r - r.mean())
        spans.append(float(np.ptp(t)))
    if not xs:
        return None
    x, y = np.concatenate(xs), np.concatenate(ys)
    sxx = float(x @ x)
    if sxx <= 0.0:
        return None
    beta = float(x @ y) / sxx
    # the calibration's σ, unless this run's own visits scatter more about the fitted drift (visits − poses − 1
    # degrees of freedom; one with two poses visited twice): the larger is taken, never the smaller
    dof = x.size - len(xs) - 1
    res = y - beta * x
    sigma = max(visit_sigma_nm, math.sqrt(float(res @ res) / dof)) if dof >= 1 else visit_sigma_nm
    return RunDrift(beta, sigma / math.sqrt(sxx), max(spans))


@dataclass(frozen=True)
class VisitDrift:
    """How the multi-pose mass treats A3's thermal drift: the visits brought to ``reference_k`` (where K_A3 and the
    bare readings hold) with the campaign's β where it is applied; else left as read, and U's ``thermal`` term carries
    the drift a |β| up to ``bound_per_k`` could cause over their offset (rectangular). ``u_beta_per_k``: u(β) where
    applied, bound/√3 where not; 0 without a reference temperature or β. ``note``: how it was decided (the result's
    ``thermal``); ``warnings``: what the operator must see."""

    reference_k: float | None
    beta_per_k: float
    u_beta_per_k: float
    applied: bool
    note: str
    warnings: tuple[str, ...] = ()

    def visits(self, pose: str, readings_nm: np.ndarray, temps_k: np.ndarray) -> PoseVisits:
        """The pose's visits as MP1–MP3 take them: readings at the reference temperature where β is applied, and
        reading × (T − T_ref) for the thermal term."""
        r, t = np.asarray(readings_nm, float), np.asarray(temps_k, float)
        if self.reference_k is None or not np.all(np.isfinite(t)):
            return PoseVisits(pose, r, np.zeros(r.size))
        dt = t - self.reference_k
        return PoseVisits(pose, r * (1.0 - self.beta_per_k * dt) if self.applied else r, r * dt)


def visit_drift(campaign: th.ThermalDrift | None, reference_k: float | None,
                readings: Mapping[str, tuple[np.ndarray, np.ndarray]], drift_prior_per_k: float,
                visit_sigma_nm: float) -> VisitDrift:
    """Issue 33's rule for the multi-pose mass: the campaign's A3 β corrects the visits (each pose's ``(A3 readings,
    motor temperatures)``) to ``reference_k`` (the torsional campaign's A3 temperature) only where the data resolve it:

    * the campaign resolves β (span ≥ 1 K, |β| ≥ 3 u), and the visits' mean and the reference both lie within 3 × its
      span of the campaign's own reference temperature (the single pose's rule, for both ends of the correction); or
    * the campaign resolves β, and the run's own visits show the same β (:func:`run_drift` with one visit's
      repeatability ``visit_sigma_nm``: the run's β is at least 3 of its standard uncertainties from 0 and differs
      from the campaign's by at most 3 standard uncertainties of their difference, the campaign's significance rule)
      over a span of their own ≥ 1 K that has the reference within 3 × that span: the drift is then seen to be
      linear over the temperatures that matter, and the campaign's β (the better estimate) corrects it.

    Otherwise the visits are not corrected, U carries the campaign's bound (:meth:`ThermalDrift.drift_bound_per_k`)
    over their offset and a warning says so; without β there is nothing to correct or bound with, and a reference
    missing while β exists is warned about. DataError where a visit has no A3 motor temperature (the drift can be
    neither corrected nor bounded: ``auto`` then takes the single pose)."""
    temps = np.concatenate([np.asarray(t, float) for _, t in readings.values()]) if readings else np.zeros(0)
    if campaign is None:
        return VisitDrift(reference_k, 0.0, 0.0, False, "no thermal drift in the calibration")
    if reference_k is None:
        why = "the torsional campaign recorded no A3 motor temperature"
        return VisitDrift(None, 0.0, 0.0, False, f"not corrected: {why}",
                          (f"thermal drift of A3 neither corrected nor bounded in the multi-pose mass: {why}",))
    missing = [pose for pose, (_, t) in readings.items() if not np.all(np.isfinite(np.asarray(t, float)))]
    if missing or temps.size == 0:
        raise DataError(f"multi-pose mass: a visit of pose(s) {', '.join(missing) or 'all'} has no A3 motor "
                        f"temperature: the thermal drift from the torsional campaign's {reference_k:.1f} K can be "
                        f"neither corrected nor bounded")
    offset = float(np.mean(temps) - reference_k)
    beta, u_beta = campaign.coeff_per_k["A3"], campaign.u_coeff_per_k["A3"]
    # β holds where the campaign fitted it: the visits and the temperature they are brought to (K_A3's) both within
    # 3 × its span of its own reference (the single pose's rule, for both ends of the correction)
    why = campaign.unresolved("A3")
    if why is None:
        span, ref_c = campaign.span_k["A3"], campaign.reference_k["A3"]
        far = [f"{what} is {d:+.1f} K from it" for what, d in (("the visits' mean", float(np.mean(temps)) - ref_c),
                                                               ("the torsional campaign", reference_k - ref_c))
               if abs(d) > th.MAX_EXTRAPOLATION * span]
        if far:
            why = (f"{' and '.join(far)}, beyond {th.MAX_EXTRAPOLATION:g} × the {span:.2g} K span β was fitted on "
                   f"about the campaign's {ref_c:.1f} K")
    if why is None:
        return VisitDrift(reference_k, beta, u_beta, True, f"campaign's β applied over {offset:+.1f} K")
    run = run_drift(list(readings.values()), visit_sigma_nm) if campaign.unresolved("A3") is None else None
    if run is not None:
        agree = abs(run.beta_per_k - beta) <= th.MIN_SIGNIFICANCE * math.hypot(run.u_beta_per_k, u_beta)
        # agreement alone is no evidence where the run's u is of β's own size (0 would agree too): the run must
        # resolve a drift of its own, by the campaign's significance rule
        resolved = abs(run.beta_per_k) >= th.MIN_SIGNIFICANCE * run.u_beta_per_k
        covered = run.span_k >= th.MIN_SPAN_K and abs(offset) <= th.MAX_EXTRAPOLATION * run.span_k
        seen = (f"the run's visits show β = {100 * run.beta_per_k:+.4f} ± {100 * run.u_beta_per_k:.4f} %/K over "
                f"{run.span_k:.2g} K")
        if agree and resolved and covered:
            return VisitDrift(reference_k, beta, u_beta, True,
                              f"campaign's β applied over {offset:+.1f} K: {seen}, the same within "
                              f"{th.MIN_SIGNIFICANCE:g} standard uncertainties")
        why += f"; {seen}" + ("" if agree else ", not the campaign's") + \
            ("" if resolved else f", not resolved ({th.MIN_SIGNIFICANCE:g} u from 0 needed)") + \
            ("" if covered else f", a span that does not reach the reference {offset:+.1f} K away")
    elif campaign.unresolved("A3") is None and not (visit_sigma_nm > 0.0 and math.isfinite(visit_sigma_nm)):
        why += "; the run's own drift not checked: the calibration gives no visit repeatability (K_A3's u_fit_nm, " \
            "missing in a CAL.json fitted before it; refit to have it)"
    bound = campaign.drift_bound_per_k("A3", drift_prior_per_k)
    source = f"the prior {100 * drift_prior_per_k:.3g} %/K" if bound >= drift_prior_per_k else \
        "the campaign's |β| + 2 u(β)"
    warnings = () if abs(offset) <= THERMAL_NOTE_K else (
        f"thermal drift of A3 not corrected in the multi-pose mass: β = {100 * beta:+.3f} ± {100 * u_beta:.3f} %/K "
        f"is not applied to the visits ({why}); U carries a drift of up to {100 * bound:.3g} %/K ({source}) over "
        f"the {offset:+.1f} K offset. Measure the DuT at the torsional campaign's motor temperature "
        f"({reference_k:.1f} K), or calibrate over a temperature span that covers it",)
    return VisitDrift(reference_k, 0.0, bound / math.sqrt(3.0), False, f"not corrected: {why}", warnings)


@dataclass(frozen=True)
class PoseBias:
    """The bare reading (MPA only) of a pose: mean A3 (Nm), its standard uncertainty, mean reading × (T − T_ref)."""

    torque_a3_nm: float
    u_nm: float
    thermal_lever_nm_k: float = 0.0


@dataclass(frozen=True)
class MultiPoseCalibration:
    """What the multi-pose mass needs from the calibration: the poses, their bare readings, the repeatability of one
    visit (pooled standard deviation of visit means about their pose's mean, Nm, with its degrees of freedom), A3's
    gain, β's standard uncertainty (1/K; 0 where not applied), the lever change's relative standard uncertainty
    (:data:`LEVER_DRIFT_U_REL` where K_A3 was calibrated in these poses of this arm), g."""

    poses: tuple[LeverPose, ...]
    bias: Mapping[str, PoseBias]
    visit_sigma_nm: float
    visit_dof: int
    gain_a3: AxisGain
    u_beta_per_k: float
    lever_u_rel: float
    g_m_s2: float


def pose_bias(visits: Sequence[PoseVisits]) -> tuple[dict[str, PoseBias], float, int]:
    """The bare readings of the poses from their visits: mean and standard error per pose, and the pooled visit
    standard deviation with its degrees of freedom (Σ (n_k − 1))."""
    ss, dof, out = 0.0, 0, {}
    for v in visits:
        t = np.asarray(v.torque_a3_nm, float)
        if t.size < 2:
            raise DataError(f"multi-pose bias: pose {v.pose} needs at least two visits, got {t.size}")
        ss += float(np.sum((t - t.mean()) ** 2))
        dof += t.size - 1
        out[v.pose] = (float(t.mean()), t.size, float(np.mean(v.thermal_lever_nm_k)))
    sigma = math.sqrt(ss / dof)
    return ({k: PoseBias(mean, sigma / math.sqrt(n), lever) for k, (mean, n, lever) in out.items()}, sigma, dof)


@dataclass(frozen=True)
class MultiPoseUncertainty:
    """Standard uncertainties (kg) of the multi-pose mass by source; U = k·u with k = 2 (the visits' part widened
    by Student's factor where their standard deviation rests on few degrees of freedom)."""

    u_visits_kg: float
    u_bias_kg: float
    u_gain_kg: float
    u_lever_kg: float
    u_thermal_kg: float
    u_g_kg: float = 0.0
    student_factor: float = 1.0

    @property
    def u_kg(self) -> float:
        return float(math.sqrt(sum(v**2 for v in self.components().values())))

    @property
    def expanded_kg(self) -> float:
        return COVERAGE_K * self.u_kg

    def components(self) -> dict[str, float]:
        """Each source's standard uncertainty (kg), the visits' with the Student factor applied."""
        d = {k.removeprefix("u_").removesuffix("_kg"): float(v) for k, v in asdict(self).items()
             if k != "student_factor"}
        d["visits"] *= self.student_factor
        return d


@dataclass(frozen=True)
class MultiPoseMass:
    gross_mass_kg: float
    """m of MP2: everything beyond the MPA (fixture and DuT), kg."""
    mass_kg: float
    """m_DuT of MP3, kg."""
    uncertainty: MultiPoseUncertainty
    payload_torque_a3_nm: dict[str, float]
    """x_k per pose (Nm)."""
    visits: dict[str, int]
    residual_nm: dict[str, float]
    """x_k minus the fitted line (MP1), Nm: zero with two poses."""
    warnings: list[str] = field(default_factory=list)
    thermal: str = ""
    """How A3's thermal drift was treated (:attr:`VisitDrift.note`); "" where the caller did not decide it."""

    def to_json(self) -> dict:
        u = self.uncertainty
        return {"method": "multipose", "mass_kg": self.mass_kg, "gross_mass_kg": self.gross_mass_kg,
                "U_kg": u.expanded_kg, "u_kg": u.u_kg, "k": COVERAGE_K, "budget_kg": u.components(),
                "student_factor": u.student_factor, "payload_torque_a3_nm": self.payload_torque_a3_nm,
                "visits": self.visits, "residual_nm": self.residual_nm, "warnings": list(self.warnings),
                "thermal": self.thermal}


def _student(dof: int) -> float:
    """t₀.₉₇₅(dof) / 1.96: the factor that keeps k = 2 near 95 % for a standard deviation of few degrees of freedom."""
    return float(stats.t.ppf(0.975, dof) / stats.norm.ppf(0.975)) if dof >= 1 else math.inf


def multipose_mass(visits: Sequence[PoseVisits], cal: MultiPoseCalibration, fixture_mass_kg: float = 0.0,
                   u_g_m_s2: float = 0.0) -> MultiPoseMass:
    """MP1–MP3 with U from the DuT's visits in the lever poses (one mounting) and the calibration's section.

    DataError (naming the pose) when a pose has no visits or no bare reading, or fewer than two poses are measured.
    """
    by_name = {p.name: p for p in cal.poses}
    seen = [v for v in visits if v.n > 0]
    for v in seen:
        if v.pose not in by_name:
            raise DataError(f"multi-pose mass: pose {v.pose!r} is not one of the calibration's "
                            f"{', '.join(by_name)}")
        if v.pose not in cal.bias:
            raise DataError(f"multi-pose mass: the calibration has no bare reading in pose {v.pose}")
    if len(seen) < 2:
        raise DataError(f"multi-pose mass: {len(seen)} pose(s) with visits; the mass needs at least two")
    warnings: list[str] = []
    # the repeatability of one visit: the calibration's, unless this DuT's visits scatter significantly more
    ss = sum(float(np.sum((v.torque_a3_nm - np.mean(v.torque_a3_nm)) ** 2)) for v in seen)
    dof_dut = sum(v.n - 1 for v in seen)
    sigma, dof = cal.visit_sigma_nm, cal.visit_dof
    if dof_dut > 0:
        s2 = ss / dof_dut
        if dof < 1 or s2 > sigma**2 * stats.f.ppf(VISIT_F_LEVEL, dof_dut, dof):
            if dof >= 1:
                warnings.append(f"the DuT's visits scatter {math.sqrt(s2):.2f} Nm, more than the calibration's "
                                f"{sigma:.2f} Nm (F test at {VISIT_F_LEVEL:g}): U rests on the DuT's own scatter")
            sigma, dof = math.sqrt(s2), dof_dut
    if not dof >= 1:
        raise DataError("multi-pose mass: no repeatability of a visit (the calibration has none and each pose was "
                        "visited once)")
    g = cal.g_m_s2
    lever = np.array([by_name[v.pose].lever_a3_m for v in seen])
    if lever.max() - lever.min() < MIN_LEVER_CHANGE_M:
        raise DataError(f"multi-pose mass: the measured poses change the lever to A3 by only "
                        f"{lever.max() - lever.min():.3f} m")
    r_mean = np.array([float(np.mean(v.torque_a3_nm)) for v in seen])
    n_vis = np.array([v.n for v in seen], float)
    bias = [cal.bias[v.pose] for v in seen]
    n_norm = r_mean - np.array([b.torque_a3_nm for b in bias])  # M_A3,k − M_0,k
    x = cal.gain_a3.payload_torque_nm(n_norm)
    slope = cal.gain_a3.slope(x)  # dr/dx: a reading error δ moves x by δ/slope
    var_visits = sigma**2 / n_vis / slope**2
    var_bias = np.array([b.u_nm for b in bias]) ** 2 / slope**2
    w = 1.0 / (var_visits + var_bias)
    lbar = float(np.sum(w * lever) / np.sum(w))
    coef = -w * (lever - lbar) / (g * float(np.sum(w * (lever - lbar) ** 2)))  # m = Σ coef_k · x_k (MP2)
    m = float(coef @ x)
    resid = x - (float(np.sum(w * x) / np.sum(w)) - g * m * (lever - lbar))
    u_gain = gain_u_kg(cal.gain_a3, n_norm, coef)
    th_dut = np.array([float(np.mean(v.thermal_lever_nm_k)) for v in seen])
    th_bias = np.array([b.thermal_lever_nm_k for b in bias])
    u = MultiPoseUncertainty(
        u_visits_kg=float(math.sqrt(np.sum(coef**2 * var_visits))),
        u_bias_kg=float(math.sqrt(np.sum(coef**2 * var_bias))),
        u_gain_kg=u_gain,
        u_lever_kg=abs(m) * cal.lever_u_rel,
        u_thermal_kg=abs(float(np.sum(coef * (th_dut - th_bias) / slope))) * cal.u_beta_per_k,
        u_g_kg=abs(m) * u_g_m_s2 / g,
        student_factor=_student(dof),
    )
    lo, hi = sorted(abs(t) for t in cal.gain_a3.torque_range_nm)
    outside = [v.pose for v, xk in zip(seen, x, strict=True) if not lo - 0.1 * (hi - lo) <= abs(xk)
               <= hi + 0.1 * (hi - lo)]
    if outside:
        warnings.append(f"A3 payload torque in pose(s) {', '.join(outside)} outside the calibrated "
                        f"{lo:.0f}..{hi:.0f} Nm")
    if m - fixture_mass_kg < -u.expanded_kg:
        raise DataError(f"multi-pose mass: the DuT's mass comes out at {m - fixture_mass_kg:.3f} ± "
                        f"{u.expanded_kg:.3f} kg, below zero (is the DuT mounted, the fixture mass right?)")
    return MultiPoseMass(m, m - fixture_mass_kg, u, {v.pose: float(xk) for v, xk in zip(seen, x, strict=True)},
                         {v.pose: v.n for v in seen}, {v.pose: float(r) for v, r in zip(seen, resid, strict=True)},
                         warnings)


def _mass_with(gain: AxisGain, n_norm: np.ndarray, coef: np.ndarray, params: np.ndarray | None = None) -> float:
    return float(coef @ gain.payload_torque_nm(n_norm, params))


def gain_u_kg(gain: AxisGain, n_norm_nm: np.ndarray, coef: np.ndarray) -> float:
    """K_A3's share of u (kg): the mass MP2 gives through each curve the calibration's points admit, not the slope
    at one torque, since MP2 reads K_A3 only as the secant between the poses' torques.

    As :meth:`AxisGain.slope_u_rel_parts` does for the slope: the chosen curve's parameters (jackknife covariance,
    widened by the Student factor of its points) propagated to m; and for every admissible candidate curve c the
    deviation of its m from the chosen one's, as the half-width of a rectangular distribution, with its own
    parameters' part: u = max over c of √(d_c²/3 + u_c²)."""
    def u_params(g: AxisGain) -> tuple[float, float]:
        k = np.asarray(g.params, float)
        m0 = _mass_with(g, n_norm_nm, coef)
        cov = np.asarray(g.covariance, float) * gain.student_factor()
        jac = np.empty(k.size)
        for i in range(k.size):
            h = 1e-6 * max(abs(k[i]), 1e-6)
            kp = k.copy()
            kp[i] += h
            jac[i] = (_mass_with(g, n_norm_nm, coef, kp) - m0) / h
        return m0, math.sqrt(max(float(jac @ cov @ jac), 0.0))

    m_chosen, u = u_params(gain)
    for c in gain.admissible_candidates():
        if c.model == gain.model or c.covariance is None or len(c.params) != len(c.covariance):
            continue
        try:
            m_c, u_c = u_params(replace(gain, model=c.model, params=c.params, covariance=c.covariance))
        except DataError:  # a candidate that is not monotone at these readings
            continue
        u = max(u, math.sqrt((m_c - m_chosen) ** 2 / 3.0 + u_c**2))
    return u


def predict_multipose_U_kg(cal: MultiPoseCalibration, gross_mass_kg: float, visits_per_pose: int,
                           offset_k: float = 0.0) -> float:
    """The U (kg, k = 2) MP1–MP3 will give a load of ``gross_mass_kg`` (everything beyond the MPA) visited
    ``visits_per_pose`` times in each of the calibration's poses, before anything is measured: MP1–MP3 run on the
    readings K_A3 predicts in each pose (reading = bias + K_A3(−g·m·L_k)), each pose's visits scattering by exactly
    one visit's repeatability — the calibration's where it has one, else K_A3's in-point scatter (``u_fit_nm``).
    DataError when neither is known. ``offset_k``: the visits' expected A3 temperature less the reference K_A3 and
    the bare readings hold at; with ``cal.u_beta_per_k`` (:func:`predicted_drift`) it gives U's ``thermal`` term as
    the run would (reading × offset per visit)."""
    sigma, dof = cal.visit_sigma_nm, cal.visit_dof
    if dof < 1:
        sigma = cal.gain_a3.u_fit_nm
    if not (sigma > 0.0 and math.isfinite(sigma)):
        raise DataError("multi-pose prediction: no repeatability of a visit in the calibration (neither visits nor "
                        "K_A3's in-point scatter u_fit_nm)")
    n = max(int(visits_per_pose), 1)
    pattern = np.resize([1.0, -1.0], n)
    pattern = pattern - pattern.mean()
    spread = pattern / np.std(pattern, ddof=1) * sigma if n > 1 else np.zeros(1)
    visits = []
    for p in cal.poses:
        x = -cal.g_m_s2 * gross_mass_kg * p.lever_a3_m
        reading = cal.bias[p.name].torque_a3_nm + float(cal.gain_a3.reading_nm(np.array([x]))[0])
        visits.append(PoseVisits(p.name, reading + spread, (reading + spread) * float(offset_k)))
    if dof < 1 and n < 2:
        raise DataError("multi-pose prediction: one visit per pose and no repeatability in the calibration")
    planned = replace(cal, visit_sigma_nm=sigma, visit_dof=dof) if dof >= 1 else cal
    return multipose_mass(visits, planned).uncertainty.expanded_kg


def predicted_drift(campaign: th.ThermalDrift | None, reference_k: float | None, visits_k: float | None,
                    drift_prior_per_k: float, visit_sigma_nm: float) -> VisitDrift:
    """How :func:`visit_drift` will treat A3's drift in a run whose visits all lie at ``visits_k`` (the A3 motor
    temperature before the run, K), for :func:`predict_multipose_U_kg`: β applied where the campaign resolves it and
    both ends lie within 3 × its span; else the bound. This is the campaign's decision alone: a run's own visits
    may still confirm a resolved β over a span of their own, which cannot be foreseen
    (``analysis.multipose.predict_methods`` gives U both ways there). No β, no reference or no temperature before the
    run: no thermal term (the note says which)."""
    if campaign is None or reference_k is None:
        return visit_drift(campaign, reference_k, {}, drift_prior_per_k, visit_sigma_nm)
    if visits_k is None or not math.isfinite(visits_k):
        return VisitDrift(reference_k, 0.0, 0.0, False, "not predicted: no A3 motor temperature before the run")
    steady = np.full(2, float(visits_k))
    return visit_drift(campaign, reference_k, {"expected": (np.ones(2), steady)}, drift_prior_per_k, visit_sigma_nm)


def predict_single_U_kg(reproducibility_u_kg: float) -> float:
    """The single pose's U (kg, k = 2) before the run: k times the calibration's reproducibility term (eq. 21's
    propagation of the held-out per-axis scatter of a new mounting, :meth:`Reproducibility.u_kg`). The loops' and the
    curve's terms are left out: a lower bound, so the prediction never favours the multi-pose mass by them (they
    were 0.2 kg of the wing box's 1.26 kg of u, docs/accuracy.md)."""
    return COVERAGE_K * float(reproducibility_u_kg)


def choose_method(predicted: Mapping[str, tuple[float, float]]) -> str:
    """``auto``: the method with the least U² × robot minutes (what a lab gets for its robot time: U shrinks as
    1/√time under repetition, so U²·t is the time to a given U). ``predicted``: method → (U kg, robot minutes),
    predicted before the run (:func:`predict_multipose_U_kg`, :func:`predict_single_U_kg`); a tie goes to the first."""
    if not predicted:
        raise DataError("method choice: no method predicted")
    return min(predicted, key=lambda k: predicted[k][0] ** 2 * predicted[k][1])
