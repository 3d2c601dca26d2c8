"""CoG estimation: the paper's eq. 5–7, the pose schemes, the torsional K, the GLS estimator and the DuT frame."""

from __future__ import annotations

import numpy as np
import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import axis_gain, cog
from simulators.krc4 import physics as ph

G = kin.G_PAPER_M_S2


def test_cog_paper_eq5_to_7():
    m = 100.0
    a, b, c = cog.cog_paper(m, m_linear_0_nm=G * m * 0.5, m_torsion_0_nm=G * m * 0.02, m_torsion_90_nm=-G * m * 0.03)
    assert (a, b, c) == pytest.approx((0.5, -0.03, 0.02))
    with pytest.raises(DataError):
        cog.cog_paper(0.0, 1.0, 1.0, 1.0)


def test_paper_method_on_the_measurement_pose_geometry():
    """eq. 5–7 with torques from the kinematics: A5 gives the lever a, A6 at 0° and 90° the offsets c and b."""
    m, cog_true = 80.0, np.array([0.03, -0.02, 0.40])
    q0 = kin.measurement_pose()
    q90 = q0.copy()
    q90[5] = 90.0
    t0 = kin.gravity_torques_nm(q0, [(m, cog_true)])
    t90 = kin.gravity_torques_nm(q90, [(m, cog_true)])
    a, b, c = cog.cog_paper(m, -t0[4], t0[5], t90[5])
    assert a == pytest.approx(kin.D6_M + cog_true[2])  # lever to A5 = d6 + cz
    assert abs(c) == pytest.approx(abs(cog_true[1]))  # flange y offset is horizontal at A6 = 0
    assert abs(b) == pytest.approx(abs(cog_true[0]))  # ... flange x after turning A6 by 90°


# --- the mass-properties run: poses, K, the estimator, compute_cog -------------------------------------------------
def test_cog_poses_schemes_within_limits_with_approach():
    base = kin.measurement_pose()
    paper = cog.cog_poses(base, "paper")
    assert [p.name for p in paper] == ["meas", "A6+90"]
    full = cog.cog_poses(base, "full")
    assert len(full) == 8 and len({p.name for p in full}) == 8
    for p in full:
        assert kin.within_limits(p.q_deg) and kin.within_limits(p.q_approach_deg)
        dq = np.array(p.q_deg) - np.array(p.q_approach_deg)
        assert dq.tolist() == [0.0, 0.0, 0.0, cog.APPROACH_DEG, 0.0, cog.APPROACH_DEG]
    assert sorted(p.q_deg[5] for p in full[:4]) == [0.0, 90.0, 180.0, 270.0]
    with pytest.raises(DataError, match="unknown CoG scheme"):
        cog.cog_poses(base, "fancy")
    near_limit = base.copy()
    near_limit[4] = 100.0
    with pytest.raises(DataError, match="outside the axis ranges"):
        cog.cog_poses(near_limit, "full")


def _gain(axis: int, params: tuple[float, ...], u_point: float = 0.0) -> axis_gain.AxisGain:
    n = len(params)
    return axis_gain.AxisGain(axis, {1: "linear", 2: "poly2", 3: "poly3"}[n], params,
                        tuple(tuple(1e-8 if i == j else 0.0 for j in range(n)) for i in range(n)), u_point,
                        (-2000.0, 2000.0))


def test_axis_gain_inverts_its_reading():
    g = _gain(5, (0.92, 0.31, -0.05))
    x = np.array([-1500.0, -300.0, -1.0, 0.0, 2.0, 450.0, 1800.0])
    np.testing.assert_allclose(g.payload_torque_nm(g.reading_nm(x)), x, atol=1e-9)
    assert axis_gain.AxisGain.from_dict(5, g.to_dict()) == g
    with pytest.raises(DataError, match="A5"):
        axis_gain.AxisGain.from_dict(5, {**g.to_dict(), "params": [0.9, 0.1]})


def test_fit_gain_recovers_a_known_curve_and_validates_held_out():
    rng = np.random.default_rng(3)
    true = (0.95, 0.2)
    x = rng.uniform(-800.0, 800.0, 60)
    group = np.repeat(np.arange(10), 6)
    r = x * (true[0] + true[1] * np.abs(x) / 1000.0) + rng.normal(0.0, 0.5, 60)
    gain, ev = axis_gain.select_gain(4, x, r, np.full(60, 0.5), group)
    assert gain.model in ("poly2", "poly3")
    grid = np.linspace(-800.0, 800.0, 9)
    np.testing.assert_allclose(gain.reading_nm(grid), grid * (true[0] + true[1] * np.abs(grid) / 1000.0), atol=1.5)
    assert ev["models"]["linear"]["heldout_rms_nm"] > 5 * ev["models"]["poly2"]["heldout_rms_nm"]
    with pytest.raises(DataError, match="cannot validate"):
        axis_gain.fit_gain(4, x[:12], r[:12], np.ones(12), group[:12], "poly3")
    with pytest.raises(DataError, match="not monotone"):  # a reading falling with the load is no calibration
        axis_gain.fit_gain(4, x, -r, np.full(60, 0.5), group, "sat300")
    sat, _ = axis_gain.fit_gain(4, x, r, np.full(60, 0.5), group, "sat300")
    np.testing.assert_allclose(sat.payload_torque_nm(sat.reading_nm(grid)), grid, atol=1e-6)


def _exact_poses(c_dut, m_dut, gains, offsets, scheme="full", fixture=(10.0, (0.0, 0.0, 0.005))):
    m_fix, c_fix = fixture
    theta = np.array([m_dut + m_fix, *(m_dut * np.asarray(c_dut) + m_fix * np.asarray(c_fix))])
    out = []
    for p in cog.cog_poses(kin.measurement_pose(), scheme):
        x = kin.gravity_regressor(p.q_deg) @ theta
        r = np.full(6, np.nan)
        for ax, g in gains.items():
            r[ax - 1] = g.reading_nm(np.array([x[ax - 1]]))[0] + offsets.get(ax, 0.0)
        out.append(cog.PoseTorques(p.name, p.q_deg, tuple(r), (0.1,) * 6, (0.1,) * 6))
    return out


def test_gls_recovers_the_cog_through_nonlinear_gains_and_mount_offsets():
    gains = {3: _gain(3, (0.92, -0.01)), 4: _gain(4, (0.96,)), 5: _gain(5, (0.91, 0.28, -0.1)), 6: _gain(6, (1.04,))}
    c_dut, m = np.array([-0.041, -0.028, 0.335]), 107.3
    poses = _exact_poses(c_dut, m, gains, {3: 7.0, 4: -2.0, 5: -9.0, 6: 1.5})
    fit = cog.estimate_cog_gls(poses, gains, dut_mass_kg=m, u_dut_mass_kg=0.0, fixture_mass_kg=10.0,
                               fixture_cog_m=(0.0, 0.0, 0.005))
    assert fit.fitted_offsets
    np.testing.assert_allclose(fit.cog_m, c_dut, atol=1e-7)
    assert fit.offsets_nm == pytest.approx({"A3": 7.0, "A4": -2.0, "A5": -9.0, "A6": 1.5})  # in the reading, Nm
    # the paper's two poses: no offsets can be fitted; with none present the CoG is still exact
    paper = _exact_poses(c_dut, m, gains, {}, "paper")
    fit2 = cog.estimate_cog_gls(paper, gains, dut_mass_kg=m, u_dut_mass_kg=0.1, fixture_mass_kg=10.0,
                                fixture_cog_m=(0.0, 0.0, 0.005))
    assert not fit2.fitted_offsets
    np.testing.assert_allclose(fit2.cog_m, c_dut, atol=1e-7)
    assert np.all(np.sqrt(np.diag(fit2.cov_parts_m2["mass"])) > 0)


def test_gls_refuses_pose_sets_that_cannot_determine_the_cog():
    gains = {4: _gain(4, (0.96,)), 5: _gain(5, (1.1,)), 6: _gain(6, (1.04,))}
    meas_only = _exact_poses((0.01, 0.02, 0.3), 50.0, gains, {})[:1]
    with pytest.raises(DataError, match="do not determine all three CoG coordinates"):
        cog.estimate_cog_gls(meas_only, gains, dut_mass_kg=50.0, u_dut_mass_kg=0.0, fixture_mass_kg=0.0,
                             fixture_cog_m=(0, 0, 0))
    with pytest.raises(DataError, match="mass must be > 0"):
        cog.estimate_cog_gls(meas_only, gains, dut_mass_kg=0.0, u_dut_mass_kg=0.0, fixture_mass_kg=0.0,
                             fixture_cog_m=(0, 0, 0))


def test_dut_frame_transform_matches_the_simulators_frame():
    dut = ph.AsymmetricDut("box", 50.0, (0.01, -0.02, 0.30), (0.005, 0.01, 0.025), (30.0, -10.0, 5.0))
    cov = np.diag([1e-6, 4e-6, 9e-6])
    c, cov_dut = cog.to_dut_frame(dut.cog_flange_m, cov, dut.dut_origin_flange_m, dut.dut_abc_deg)
    np.testing.assert_allclose(c, dut.cog_dut_m, atol=1e-12)
    np.testing.assert_allclose(kin.kuka_abc_deg(cog.kuka_rotation(dut.dut_abc_deg)), dut.dut_abc_deg, atol=1e-9)
    assert np.trace(cov_dut) == pytest.approx(np.trace(cov))  # a rotation keeps the total variance
    wing = ph.refex_wing_box()
    assert wing.mass_kg == 107.3 and 0.02 < np.hypot(*wing.cog_flange_m[:2]) < 0.1


@pytest.mark.parametrize("c", [0.02, 0.2, 5.0])
def test_the_torsional_catalogue_is_the_same_for_every_torque_scale(c):
    """A robot whose payload torques are c times the KR 500's meets the same gain shapes over its own range: every
    torque (the payload torque, the reading and its σ) scaled by c gives the same choice, the same held-out errors
    times c and the same relative curve. With a fixed 100-800 Nm grid of saturating scales a small robot's axis met
    only nearly linear sat terms and a large one's only sharp ones, and the choice moved with c."""
    rng = np.random.default_rng(11)
    x = rng.uniform(-700.0, 700.0, 60)
    group = np.repeat(np.arange(10), 6)
    # a drive whose gain saturates over the first ~200 Nm (A4-like), scatter per point and per reading
    r = x * (0.9 + 0.12 * (1.0 - np.exp(-np.abs(x) / 200.0))) + rng.normal(0.0, 2.0, 10)[group] \
        + rng.normal(0.0, 0.5, 60)
    s = np.full(60, 0.5)
    base, ev = axis_gain.select_gain(4, x, r, s, group)
    scaled, ev_c = axis_gain.select_gain(4, c * x, c * r, c * s, group)
    assert base.model.startswith("sat")  # the shape of this drive, found at the base scale
    assert axis_gain.gain_model_params(scaled.model) == axis_gain.gain_model_params(base.model)
    names, names_c = list(ev["models"]), list(ev_c["models"])
    assert len(names) == len(names_c) == 8
    assert names.index(base.model) == names_c.index(scaled.model)
    np.testing.assert_allclose([ev_c["models"][m]["heldout_rms_nm"] for m in names_c],
                               [c * ev["models"][m]["heldout_rms_nm"] for m in names], rtol=1e-3)
    grid = np.linspace(-700.0, 700.0, 15)
    np.testing.assert_allclose(scaled.reading_nm(c * grid), c * base.reading_nm(grid), rtol=2e-3, atol=1e-9)


def test_gain_model_names():
    assert axis_gain.gain_models(np.array([-800.0, 400.0])) == ("linear", "poly2", "poly3", "sat100", "sat200",
                                                                 "sat300", "sat500", "sat800")
    assert [axis_gain.gain_model_params(m) for m in ("linear", "poly3", "sat46.2", "sat300")] == [1, 3, 2, 2]
    assert [axis_gain.gain_model_params(m) for m in ("poly4", "sat", "sat-5", "sat0", "satx", "satnan")] == [None] * 6
    with pytest.raises(DataError, match="unknown gain model"):
        axis_gain.fit_gain(4, np.linspace(1, 100, 30), np.linspace(1, 100, 30), np.ones(30), np.repeat(np.arange(6), 5),
                     "poly4")
