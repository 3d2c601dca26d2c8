"""The torsional calibration campaign: bias per pose and K per axis from loads of known position, issue #14.

Loads of known mass and position are measured in every pose of a CoG scheme (:func:`rgse_daemon.pipeline.cog.cog_poses`)
against the bare MPA (the bias of each pose). Each axis A3..A6 gets a gain K(x) on its payload torque x
(:class:`rgse_daemon.pipeline.axis_gain.AxisGain`), chosen and validated by leaving out whole points
(:func:`fit_torsional`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline.axis_gain import AxisGain, fit_gain, select_gain
from rgse_daemon.pipeline.cog import CogPose

#: Axes whose payload torque the torsional calibration fits (A1 carries none in these poses, A2 is not needed).
COG_AXES = (3, 4, 5, 6)


@dataclass(frozen=True)
class PoseMean:
    """Mean torque A1..A6 of one pose (Nm, NaN where not traced) and the standard error of each mean."""

    torque_nm: tuple[float, ...]
    sigma_nm: tuple[float, ...]


@dataclass(frozen=True)
class TorsionalPoint:
    """One loaded point of the campaign: the load beyond the MPA (mass kg, CoG in the flange frame m) and its mean
    torques in every pose of the scheme (by pose name)."""

    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    poses: dict[str, PoseMean]


@dataclass(frozen=True)
class TorsionalFit:
    """Result of the torsional calibration: bias per pose (Nm, standard uncertainty), K per axis with the
    evaluation of every gain model, and the held-out residuals (Nm) of the chosen ones."""

    bias: dict[str, PoseMean]
    gains: dict[int, AxisGain]
    evaluations: dict[int, dict]
    heldout_nm: dict[int, np.ndarray]


def fit_torsional(poses: Sequence[CogPose], bias: dict[str, PoseMean], points: Sequence[TorsionalPoint],
                  axes: Sequence[int] = COG_AXES, g_m_s2: float = kin.G_PAPER_M_S2) -> TorsionalFit:
    """Per-axis K from loads of known mass and position measured in every pose, against the bare reading (MPA
    only) of the same pose: r = reading − bias, x = Y(q)·[m, m·c] (the gravity regressor), r = K(x) fitted per axis
    over all points and poses, the gain model chosen by leave-one-point-out error (:func:`select_gain`)."""
    names = [p.name for p in poses]
    missing = [n for n in names if n not in bias]
    if missing:
        raise DataError(f"torsional calibration: no bare (MPA only) reading in pose(s) {', '.join(missing)}")
    xs: dict[int, list[float]] = {ax: [] for ax in axes}
    rs: dict[int, list[float]] = {ax: [] for ax in axes}
    ss: dict[int, list[float]] = {ax: [] for ax in axes}
    grp: dict[int, list[int]] = {ax: [] for ax in axes}
    for k, pt in enumerate(points):
        if not pt.mass_kg > 0:
            raise DataError(f"torsional point #{k + 1}: mass must be > 0 kg (the bias point is separate)")
        theta = pt.mass_kg * np.array([1.0, *pt.cog_flange_m])
        for pose in poses:
            if pose.name not in pt.poses:
                raise DataError(f"torsional point #{k + 1}: not measured in pose {pose.name}")
            x = kin.gravity_regressor(pose.q_deg, g_m_s2) @ theta
            m, b = pt.poses[pose.name], bias[pose.name]
            for ax in axes:
                r = m.torque_nm[ax - 1] - b.torque_nm[ax - 1]
                if not np.isfinite(r):
                    continue
                xs[ax].append(float(x[ax - 1]))
                rs[ax].append(float(r))
                s = np.hypot(m.sigma_nm[ax - 1], b.sigma_nm[ax - 1])
                ss[ax].append(float(s) if np.isfinite(s) and s > 0 else 1.0)
                grp[ax].append(k)
    gains, evaluations, heldout = {}, {}, {}
    for ax in axes:
        if not xs[ax]:
            continue
        x, r, s, g = (np.array(v) for v in (xs[ax], rs[ax], ss[ax], grp[ax]))
        gain, ev = select_gain(ax, x, r, s, g)
        gains[ax] = gain
        evaluations[ax] = ev
        heldout[ax] = fit_gain(ax, x, r, s, g, gain.model, ev["point_offsets"])[1]
    if not gains:
        raise DataError("torsional calibration: no axis A3..A6 was traced")
    return TorsionalFit(dict(bias), gains, evaluations, heldout)
