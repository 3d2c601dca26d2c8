"""The inertia excitation: T1 on the payload's bounding box, rendered KRL accepted by the interlock's static check,
and the same design at twice the speed refused."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon.analysis.inertia import excitation_program
from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.safety.static import CheckContext, check_program

WING_POINTS = ex.box_corners([0.0, 0.0, 0.35], [0.8, 0.3, 0.15])
WING = ex.Payload(107.3, (0.02, 0.01, 0.35), WING_POINTS)


@pytest.fixture(scope="module")
def design() -> ex.Excitation:
    return ex.design(WING, optimise=False)


def _ctx() -> CheckContext:
    return CheckContext(payload_mass_kg=WING.mass_kg, payload_cog_flange_m=WING.cog_flange_m,
                        payload_points_flange_m=WING_POINTS, start_axes_deg=tuple(kin.measurement_pose()))


def test_every_box_corner_stays_under_the_limit_on_the_planned_motion(design: ex.Excitation) -> None:
    q, qd, _, tags, total = ex.planned_motion(design.start_deg, design.moves, step_s=0.01)
    assert total > 20.0 and set(np.unique(tags)) == {0, 4, 5, 6}
    worst = 0.0
    for qk, qdk in zip(q[::3], qd[::3], strict=True):
        for p in WING_POINTS:
            worst = max(worst, float(np.linalg.norm(kin.point_velocity_mm_s(qk, qdk, p))))
    assert 150.0 < worst <= 200.0  # close to the limit (information) and under it
    assert design.max_point_speed_mm_s <= 200.0
    for m in design.moves:
        assert kin.within_limits(m.target_deg)


def test_design_determines_all_six_parameters(design: ex.Excitation) -> None:
    assert np.isfinite(design.log_det) and design.condition_number < 20.0


def test_the_rendered_program_passes_the_static_check(design: ex.Excitation) -> None:
    prog = excitation_program(design)
    assert check_program(prog.src_text, prog.dat_text, _ctx(), "rgse_inertia.src") == []


def test_the_same_design_at_twice_the_limit_is_refused() -> None:
    fast = ex.design(WING, optimise=False, limit_mm_s=400.0)
    prog = excitation_program(fast)
    violations = check_program(prog.src_text, prog.dat_text, _ctx(), "rgse_inertia.src")
    assert violations and {v.rule for v in violations} == {"SPEED"}


def test_the_optimiser_improves_the_design_criterion() -> None:
    cube = ex.Payload(60.0, (0.0, 0.0, 0.28), ex.box_corners([0.0, 0.0, 0.28], [0.25, 0.25, 0.25]))
    plain = ex.design(cube, optimise=False)
    tuned = ex.design(cube, optimise=True, max_evaluations=8)
    assert tuned.log_det > plain.log_det  # the spread start is not already optimal
