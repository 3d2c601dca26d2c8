"""The workspace rule between its path samples (issue #31's survivors of mutmut on ``workspace_violation``): the
margin that covers the path between samples is added on every side of every wall and keep-out box, and a path is
sampled at most 0.5° (L1) apart however long it is. Each limit is met exactly (refused: a touch counts) and missed by
a micrometre (allowed); a thin keep-out box crossed between coarse samples is found."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rgse_daemon.config import BoxConfig, CellConfig
from rgse_daemon.kinematics import joint_frames
from rgse_daemon.safety.static import WORKSPACE_STEP_DEG, CheckContext, _Checker

START = (30.0, -90.0, 90.0, 0.0, 0.0, 0.0)
TARGET = (31.0, -90.0, 90.0, 0.0, 0.0, 0.0)  # 1° of A1: 3 samples 0.5° apart
#: A 2 mm payload box just behind the flange: the flange and the box's face on it decide.
PAYLOAD = BoxConfig(min_m=(-0.001, -0.001, -0.002), max_m=(0.001, 0.001, 0.0))


def cell(walls: BoxConfig | None = None, keep_out: tuple[BoxConfig, ...] = ()) -> CellConfig:
    return CellConfig(floor_z_m=-5.0, walls=walls or BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=(20.0, 20.0, 20.0)),
                      keep_out=keep_out, payload_box_flange_m=PAYLOAD)


def sampled(start: tuple[float, ...], target: tuple[float, ...]) -> tuple[np.ndarray, float]:
    """Every tested point of every sample (samples × 11 × 3, m) and the margin, by the rule's own sampling argument
    worked out here: samples at most 0.5° (L1) apart with both ends, margin = step/2 · r_max · (1 + 2 step)."""
    q0, q1 = np.array(start), np.array(target)
    l1 = float(np.abs(q1 - q0).sum())
    n = math.ceil(l1 / WORKSPACE_STEP_DEG) + 1
    step = math.radians(l1 / (n - 1))
    corners = np.array([(x, y, z) for x in (PAYLOAD.min_m[0], PAYLOAD.max_m[0])
                        for y in (PAYLOAD.min_m[1], PAYLOAD.max_m[1]) for z in (PAYLOAD.min_m[2], PAYLOAD.max_m[2])])
    pts, r_max = [], 0.0
    for s in np.linspace(0.0, 1.0, n):
        f = joint_frames(q0 + s * (q1 - q0))
        p = np.vstack([corners @ f[5, :3, :3].T + f[5, :3, 3], f[5, :3, 3], f[4, :3, 3], f[2, :3, 3]])
        r_max = max(r_max, float(np.linalg.norm(p[:, None, :] - f[None, :, :3, 3], axis=2).max()))
        pts.append(p)
    return np.array(pts), step / 2.0 * r_max * (1.0 + 2.0 * step)


def violation(c: CellConfig, start: tuple[float, ...] = START, target: tuple[float, ...] = TARGET) -> str | None:
    return _Checker(CheckContext(start_axes_deg=start, cell=c)).workspace_violation(start, target)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_wall_low_side_within_the_margin_of_the_sampled_path(axis: int) -> None:
    pts, margin = sampled(START, TARGET)
    assert 0.005 < margin < 0.05
    low = float(pts[:, :, axis].min()) - margin

    def walls(at: float) -> BoxConfig:
        lo = [-20.0, -20.0, -5.0]
        lo[axis] = at
        return BoxConfig(min_m=tuple(lo), max_m=(20.0, 20.0, 20.0))

    why = violation(cell(walls(low)))
    assert why is not None and f"margin {margin * 1000:.0f} mm between path samples" in why
    assert violation(cell(walls(low - 1e-6))) is None


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_wall_high_side_within_the_margin_of_the_sampled_path(axis: int) -> None:
    pts, margin = sampled(START, TARGET)
    high = float(pts[:, :, axis].max()) + margin

    def walls(at: float) -> BoxConfig:
        hi = [20.0, 20.0, 20.0]
        hi[axis] = at
        return BoxConfig(min_m=(-20.0, -20.0, -5.0), max_m=tuple(hi))

    why = violation(cell(walls(high)))
    assert why is not None and "leaves the cell at (" + "xyz"[axis] + " = " in why
    assert violation(cell(walls(high + 1e-6))) is None


@pytest.mark.parametrize("side", ["below", "above"])
def test_a_keep_out_box_within_the_margin_of_the_sampled_path(side: str) -> None:
    """A keep-out box beside the flange's path in x, its near face exactly the margin from the nearest tested point
    of any sample (less a nanometre): entered (refused); a micrometre farther: clear. The box spans the path in y and
    z."""
    pts, margin = sampled(START, TARGET)
    flange = pts[:, 8, :]
    y_lo, y_hi = float(flange[:, 1].min()) - 0.1, float(flange[:, 1].max()) + 0.1
    z_lo, z_hi = float(flange[:, 2].min()) - 0.1, float(flange[:, 2].max()) + 0.1
    near = pts[(pts[:, :, 1] >= y_lo - margin) & (pts[:, :, 1] <= y_hi + margin)
               & (pts[:, :, 2] >= z_lo - margin) & (pts[:, :, 2] <= z_hi + margin)]

    def box(gap: float) -> BoxConfig:
        if side == "above":  # the box beyond the largest x
            x = float(near[:, 0].max()) + margin + gap
            return BoxConfig(min_m=(x, y_lo, z_lo), max_m=(x + 0.5, y_hi, z_hi))
        x = float(near[:, 0].min()) - margin - gap
        return BoxConfig(min_m=(x - 0.5, y_lo, z_lo), max_m=(x, y_hi, z_hi))

    why = violation(cell(keep_out=(box(-1e-9),)))  # a nanometre inside: (x + margin) − margin is not x in floats
    assert why is not None and "enters keep-out box 1" in why and f"margin {margin * 1000:.0f} mm" in why
    assert violation(cell(keep_out=(box(1e-6),))) is None


def test_a_thin_keep_out_box_crossed_between_coarse_samples_is_found() -> None:
    """A1 swept by 200°: 401 samples. A 10 mm cube where the flange passes halfway between two of 50 evenly spaced
    samples (4.1° apart there: 0.18 m of the flange's path) is still found: the samples are 0.5° apart, and the margin
    covers what lies between them."""
    start, target = (-100.0, -90.0, 90.0, 0.0, 0.0, 0.0), (100.0, -90.0, 90.0, 0.0, 0.0, 0.0)
    a1 = -100.0 + 200.0 * 10.5 / 49  # halfway between the 11th and 12th of 50 samples
    o6 = joint_frames((a1, -90.0, 90.0, 0.0, 0.0, 0.0))[5, :3, 3]
    cube = BoxConfig(min_m=tuple(float(v) - 0.005 for v in o6), max_m=tuple(float(v) + 0.005 for v in o6))
    why = violation(cell(keep_out=(cube,)), start, target)
    assert why is not None and why.split(" enters keep-out box 1 ")[0] in ("the flange", "the payload box"), why
    assert violation(cell(), start, target) is None


@pytest.mark.parametrize(("far_end_m", "enters"), [(0.39, True), (0.41, False)])
def test_a_rod_through_the_payload_box_between_its_corners(far_end_m: float, enters: bool) -> None:
    """Held in the measurement pose (the flange's z axis is the world's x): a 0.4 m payload box reaching 0.4 m out
    of the flange, and a 10 mm rod along the world's y, crossing the box's axis 0.39 m out (inside the box, near its
    far face) or 0.41 m out (beyond it). No corner, nor the flange, wrist or elbow, lies in the rod: only the box's
    own faces (its centre and half sizes) decide."""
    meas = (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)
    f = joint_frames(meas)
    assert f[5, :3, 2] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
    at = f[5, :3, 3] + f[5, :3, :3] @ np.array([0.0, 0.0, far_end_m])
    rod = BoxConfig(min_m=(float(at[0]) - 0.005, -1.0, float(at[2]) - 0.005),
                    max_m=(float(at[0]) + 0.005, 1.0, float(at[2]) + 0.005))
    c = cell(keep_out=(rod,)).model_copy(update={"payload_box_flange_m": BoxConfig(min_m=(-0.2, -0.2, 0.0),
                                                                                  max_m=(0.2, 0.2, 0.4))})
    why = violation(c, meas, meas)
    assert (why is not None and why.startswith("the payload box enters keep-out box 1")) is enters, why
