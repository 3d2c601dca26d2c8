"""The multi-pose mass on the simulated KR 500 (``simulators.krc4.physics``), known truth: a Table-1-like campaign
(:func:`~tests.support.simcampaign.simulate_campaign`) plus the bare MPA visiting the lever poses, then one mounting of
a DuT measured both ways — the paper's single pose (its loops in the measurement pose) and the lever poses' visits.

A visit is one loop in a pose (the daemon's loop: brake-release move about the pose, settle, trace, brakes), reached
by a PTP from the previous pose. The simulator's roughness is as it is: per-mounting offsets and CoG shift, thermal
drift, release transient, hysteresis, settling, noise, spikes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon.analysis.calibration import CampaignData, campaign_points, campaign_thermal
from rgse_daemon.pipeline import axis_gain
from rgse_daemon.pipeline import multipose as mp
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.thermal import ThermalDrift
from simulators.krc4 import physics as ph
from tests.support.simcampaign import CHANGE_BODIES_S, LOOP_S, SETTLE_S, G, SimCampaign, simulate_campaign

#: Seconds a PTP between two lever poses takes in the simulation's thermal clock (the drives hold the load).
POSE_MOVE_S = 20.0


@dataclass(frozen=True)
class MultiPoseCampaign:
    campaign: SimCampaign
    model: ph.RobotModel
    data: CampaignData
    calibration: mp.MultiPoseCalibration
    thermal: ThermalDrift
    beta_applied: bool


def _thermal_applied(drift: ThermalDrift) -> bool:
    return drift.unresolved("A3") is None


def visit(model: ph.RobotModel, q_deg, payload: ph.Payload, drift: ThermalDrift, applied: bool,
          n_samples: int = 250, period_s: float = 0.012) -> tuple[float, float]:
    """One loop in pose ``q_deg`` (already reached): brake-release move, settle, trace, brakes for the rest of the
    loop. Returns the pre-processed A3 mean (Nm; brought to β's reference temperature where ``applied``) and its
    mean reading × (T − T_ref) (Nm·K; 0 where not applied)."""
    model.brake_release_move(q_deg)
    model.hold(SETTLE_S)
    tr = model.sample_trace(q_deg, payload, n_samples, period_s)
    model.apply_brakes(max(LOOP_S - SETTLE_S - n_samples * period_s, 0.0))
    a3 = tr[3]["Istmoment"]
    temp = float(np.mean(tr[3]["Motortemperatur"]))
    mean = pp.process_loop(a3, period_s, pp.PAPER).torque_nm
    if not applied:
        return mean, 0.0
    return drift.correct_nm("A3", mean, temp), mean * (temp - drift.reference_k["A3"])


def visit_poses(model: ph.RobotModel, poses: list[mp.LeverPose], visits_per_pose: int, payload: ph.Payload,
                drift: ThermalDrift, applied: bool, start_deg=None) -> list[mp.PoseVisits]:
    """The visits of one mounting in :func:`~rgse_daemon.pipeline.multipose.visit_order`."""
    got: dict[str, list[tuple[float, float]]] = {p.name: [] for p in poses}
    here = np.asarray(kin.measurement_pose() if start_deg is None else start_deg, float)
    for p in mp.visit_order(poses, visits_per_pose):
        q = np.asarray(p.q_deg, float)
        if not np.allclose(q, here):
            model.move(here, q, POSE_MOVE_S)
            here = q
        got[p.name].append(visit(model, q, payload, drift, applied))
    return [mp.PoseVisits(k, np.array([a for a, _ in v]), np.array([b for _, b in v])) for k, v in got.items()]


def a3_gain(data: CampaignData) -> axis_gain.AxisGain:
    """K_A3 from the campaign's loaded points: the A3 reading normalised with the MPA's zero point against the
    expected payload torque −g·m·r_A3 (holding-torque sign), each point its own group (one mounting)."""
    points, _, _ = campaign_points(data, pp.PAPER)
    loaded = points.mass_kg > 0
    x, r = -points.expected_a3_nm[loaded], points.torque_a3_nm[loaded]
    gain, _ = axis_gain.select_gain(3, x, r, np.ones_like(x), np.arange(x.size))
    return gain


#: The lever points: calibration bodies stacked on the MPA, each a new mounting that visits every lever pose.
LEVER_POINT_BODIES = (2, 4, 6, 8, 10)


def lever_points(model: ph.RobotModel, poses: list[mp.LeverPose], bias: dict[str, mp.PoseBias], drift: ThermalDrift,
                 applied: bool, bodies: tuple[int, ...] = LEVER_POINT_BODIES, visits_per_pose: int = 1
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacks of nominal bodies, each mounted anew and visiting the lever poses: (expected payload torque x on A3
    from the nominal load, bias-corrected reading r, point index) per visit, for K_A3 with a per-point offset."""
    xs, rs, grp = [], [], []
    for k, n in enumerate(bodies):
        stack = ph.calibration_stack(n)
        model.apply_brakes(CHANGE_BODIES_S)
        model.new_mounting()
        for v in visit_poses(model, poses, visits_per_pose, ph.Payload((ph.mpa(), *stack)), drift, applied):
            q = next(p.q_deg for p in poses if p.name == v.pose)
            x = float(kin.gravity_regressor(q, G)[2] @ ph.Payload(stack).theta)
            for t in v.torque_a3_nm:
                xs.append(x)
                rs.append(float(t) - bias[v.pose].torque_a3_nm)
                grp.append(k)
    return np.array(xs), np.array(rs), np.array(grp)


def simulate_multipose_campaign(seed: int, bias_visits: int = 4, scenario=None, lever_gain: bool = True
                                ) -> MultiPoseCampaign:
    """The paper's campaign, then the bare MPA (one mounting) visiting the lever poses ``bias_visits`` times each;
    ``lever_gain``: K_A3 from :func:`lever_points` (each load's own offset cancels), else from the paper's points."""
    camp, model = simulate_campaign(seed, scenario=scenario)
    data = CampaignData(camp.manifest, [[(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point]
                                        for point in camp.loops], [],
                        loop_temps_k=[[(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in point]
                                      for point in camp.loops])
    drift = campaign_thermal(data, pp.PAPER)
    applied = _thermal_applied(drift)
    poses = mp.lever_poses(kin.measurement_pose())
    model.apply_brakes(CHANGE_BODIES_S)
    model.new_mounting()
    bare = visit_poses(model, poses, bias_visits, ph.Payload((ph.mpa(),)), drift, applied)
    bias, sigma, dof = mp.pose_bias(bare)
    if lever_gain:
        x, r, grp = lever_points(model, poses, bias, drift, applied)
        gain, _ = axis_gain.select_gain(3, x, r, np.ones_like(x), grp)
    else:
        gain = a3_gain(data)
    cal = mp.MultiPoseCalibration(tuple(poses), bias, sigma, dof, gain,
                                  drift.u_coeff_per_k["A3"] if applied else 0.0, mp.LEVER_DRIFT_U_REL, G)
    return MultiPoseCampaign(camp, model, data, cal, drift, applied)
