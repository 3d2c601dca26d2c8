"""The multi-pose mass of a properties run directory (issue #35): the A3 traces of its lever poses (CoG scheme
``lever``), the bare readings and K_A3 of CAL.json's ``torsional`` section, β of ``fit.thermal``. The numbers are
computed in :mod:`rgse_daemon.pipeline.multipose`; one code path for the daemon and a re-analysis of the files.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from rgse_daemon import calfile
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import TORQUE_CHANNEL, load_manifest, mean_temperature_k, read_toml
from rgse_daemon.pipeline import multipose as mp
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.trace.diadem import read_trace_set

A3_MODULE = "NextGenDrive#3"


def _readings(directory: Path, pose: str, traces: list[str], pre: pp.Preprocessing) -> tuple[np.ndarray, np.ndarray]:
    """Per loop of the pose: the pre-processed A3 mean (Nm, as read) and its mean A3 motor temperature (K; NaN where
    the trace has none)."""
    means, temps = [], []
    for t in traces:
        ts = read_trace_set(directory, t)
        tf = ts.files.get(A3_MODULE)
        if tf is None:
            raise DataError(f"{directory}: trace {t!r} of pose {pose} has no A3 drive ({A3_MODULE})")
        values = np.asarray(ts.channel(A3_MODULE, TORQUE_CHANNEL).values, float)
        means.append(pp.process_loop(values, float(tf.period_s), pre).torque_nm)
        temp = mean_temperature_k(tf)
        temps.append(math.nan if temp is None else float(temp))
    return np.array(means), np.array(temps)


def _calibration(calf: calfile.CalFile, where: str, poses_q: dict[str, tuple[float, ...]], g_m_s2: float
                 ) -> mp.MultiPoseCalibration:
    """The multi-pose section of CAL.json for the poses ``poses_q`` (name → A1..A6): their bare readings and K_A3."""
    tors = calf.torsional
    if tors is None or 3 not in tors.gains:
        raise DataError(f"{where}: no torsional section with A3's gain: the multi-pose mass needs a CoG calibration "
                        f"in scheme 'lever'")
    poses, bias = [], {}
    for n, q in poses_q.items():
        cal_pose = tors.poses.get(n)
        if cal_pose is None:
            raise DataError(f"{where}: torsional section has no bare reading in pose {n}")
        if max(abs(a - b) for a, b in zip(cal_pose.q_deg, q, strict=True)) > 0.5:
            raise DataError(f"{where}: pose {n} {list(q)} is not the calibration's {list(cal_pose.q_deg)}")
        poses.append(mp.LeverPose(n, q, mp.flange_lever_a3_m(q)))
        bias[n] = mp.PoseBias(cal_pose.bias_nm[2], cal_pose.u_bias_nm[2])
    return mp.MultiPoseCalibration(tuple(poses), bias, 0.0, 0, tors.gains[3], 0.0, mp.LEVER_DRIFT_U_REL, g_m_s2)


def predict_methods(calf: calfile.CalFile, meas_pose_deg: tuple[float, ...], single_loops: int,
                    visits_per_pose: int, loop_robot_s: float, where: str = "CAL.json",
                    motor_temp_a3_k: float | None = None, drift_prior_per_k: float = DRIFT_PRIOR_PER_K
                    ) -> dict[str, dict[str, Any]]:
    """Before a properties run: each mass method's predicted U (kg, k = 2) and the robot minutes of its own loops,
    from CAL.json alone. The single pose: its reproducibility term (:func:`mp.predict_single_U_kg`), ``single_loops``
    loops. The multi-pose mass: MP1–MP3 on the readings K_A3 predicts (:func:`mp.predict_multipose_U_kg`) for the
    heaviest load the torsional calibration covered (the largest A3 payload torque it saw, in the measurement pose:
    its U grows with the mass, the single pose's does not, so a lighter DuT only favours it more),
    ``visits_per_pose`` loops in each lever pose, with U's ``thermal`` term as the run would carry it were its
    visits at ``motor_temp_a3_k`` (the A3 motor temperature before the run; :func:`mp.predicted_drift`: u(β) where β
    will be applied, else the campaign's bound, at most ``drift_prior_per_k``, over their offset from the torsional
    campaign's temperature; ``thermal``: how, ``offset_k``). DataError (naming the file) where the multi-pose
    section is missing."""
    cu = calf.fit.uncertainty
    if cu is None:
        raise DataError(f"{where}: fit.uncertainty missing: the single pose's U cannot be predicted")
    cal = calf.calibration
    out = {"single": {"U_kg": mp.predict_single_U_kg(cu.reproducibility.u_kg(cal.g_m_s2, cal.lever_difference_m)),
                      "robot_min": single_loops * loop_robot_s / 60.0, "loops": single_loops}}
    poses = mp.lever_poses(meas_pose_deg)
    mcal = _calibration(calf, where, {p.name: p.q_deg for p in poses}, cal.g_m_s2)
    x_max = max(abs(t) for t in mcal.gain_a3.torque_range_nm)
    mass = x_max / (cal.g_m_s2 * max(p.lever_a3_m for p in mcal.poses))
    t_state = (calf.torsional.thermal_state_k or {}).get("A3") if calf.torsional is not None else None
    reference_k = None if t_state is None else float(t_state)
    campaign = calf.fit.thermal
    drift = mp.predicted_drift(campaign, reference_k, motor_temp_a3_k, drift_prior_per_k, mcal.gain_a3.u_fit_nm)
    offset_k = (motor_temp_a3_k - reference_k if drift.u_beta_per_k > 0.0 and reference_k is not None
                and motor_temp_a3_k is not None else 0.0)

    def u_kg(u_beta_per_k: float) -> float:
        return mp.predict_multipose_U_kg(dataclasses.replace(mcal, u_beta_per_k=u_beta_per_k), mass,
                                         visits_per_pose, offset_k)

    multi: dict[str, Any] = {"U_kg": u_kg(drift.u_beta_per_k),
                             "robot_min": len(poses) * visits_per_pose * loop_robot_s / 60.0,
                             "loops": len(poses) * visits_per_pose, "at_gross_mass_kg": mass,
                             "thermal": drift.note, "offset_k": offset_k}
    if not drift.applied and offset_k != 0.0 and campaign is not None and campaign.unresolved("A3") is None:
        # β resolved but not applicable from the campaign alone: the run's own visits may still confirm it
        # (mp.visit_drift), which cannot be foreseen. U as the run gives it then; the bound's U beside it
        multi["U_unconfirmed_kg"] = multi["U_kg"]
        multi["U_kg"] = u_kg(campaign.u_coeff_per_k["A3"])
        multi["thermal"] = (f"β applied if the run's own visits confirm it (U {multi['U_kg']:.2f} kg), else "
                            f"{drift.note} (U {multi['U_unconfirmed_kg']:.2f} kg)")
    out["multipose"] = multi
    return out


def compute_multipose_dir(directory: Path | str, calibration_path: Path | str,
                          fixture_mass_kg: float | None = None,
                          drift_prior_per_k: float = DRIFT_PRIOR_PER_K) -> mp.MultiPoseMass:
    """MP1–MP3 for a properties run directory measured in the ``lever`` scheme, A3's thermal drift by issue 33's
    rule (:func:`mp.visit_drift`; ``drift_prior_per_k`` as ``measurement.drift_prior_per_k``). DataError naming the
    file when the run has no lever poses, CAL.json no torsional section with their bare readings and K_A3, or a pose
    one loop."""
    directory = Path(directory)
    calf = calfile.read(calibration_path)
    pre, tors = calf.preprocessing, calf.torsional
    if tors is None or 3 not in tors.gains:
        raise DataError(f"{calibration_path}: no torsional section with A3's gain: the multi-pose mass needs a CoG "
                        f"calibration in scheme 'lever'")
    man = load_manifest(directory)
    props = read_toml(man.path).get("properties") or {}
    specs = {p["name"]: (tuple(float(v) for v in p["q_deg"]), list(p["traces"])) for p in props.get("pose", [])}
    names = [n for n in specs if n == "meas" or n.startswith("A3")]
    if len(names) < 2:
        raise DataError(f"{man.path}: no lever poses (measure in CoG scheme 'lever' for the multi-pose mass)")
    # K_A3 and the bare readings hold at the torsional campaign's mean A3 temperature: the DuT's loops are brought
    # there with the campaign's β where the data resolve it (not to the mass campaign's reference: K_A3 would then be
    # off by β·ΔT, 1.5 % over the 20 K between a cold mass campaign and a warm torsional one)
    t_state = (tors.thermal_state_k or {}).get("A3")
    readings = {n: _readings(directory, n, specs[n][1], pre or pp.PAPER) for n in names}
    cal = _calibration(calf, str(calibration_path), {n: specs[n][0] for n in names}, man.setup.g_m_s2)
    # one visit's repeatability for the run's own drift: K_A3's in-point scatter (as the prediction takes it)
    drift = mp.visit_drift(calf.fit.thermal, None if t_state is None else float(t_state), readings,
                           drift_prior_per_k, cal.gain_a3.u_fit_nm)
    cal = dataclasses.replace(cal, u_beta_per_k=drift.u_beta_per_k)
    m_f = man.fixture_mass_kg if fixture_mass_kg is None else fixture_mass_kg
    result = mp.multipose_mass([drift.visits(n, *readings[n]) for n in names], cal, 0.0 if m_f is None else m_f)
    return dataclasses.replace(result, warnings=[*drift.warnings, *result.warnings], thermal=drift.note)
