"""The demo's campaign covers the demo's DuT on each robot: in the simulator's nominal statics (no error sources),
the DuT's normalised (M_A3, M_A5) in the measurement pose lies inside the envelope the campaign's mass and torque
points span (pipeline/envelope.py), so the demo's result is no extrapolation and carries no envelope warning."""

from __future__ import annotations

import dataclasses

import pytest

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.commands.demo import DEMO_DUTS, demo_setup
from rgse_daemon.pipeline.envelope import Envelope, check
from simulators.krc4 import physics as ph


@pytest.mark.parametrize("key", sorted(DEMO_DUTS))
def test_the_demo_s_dut_lies_at_a_calibrated_configuration(key: str) -> None:
    robot = robots.get(key)
    previous = robots.activate(robot)
    try:
        setup = demo_setup(key)
        q = kin.measurement_pose()

        def torques(payload: ph.Payload) -> tuple[float, float]:
            t = kin.gravity_torques_nm(q, [(b.mass_kg, b.cog_flange_m) for b in payload.bodies], kin.G_PAPER_M_S2,
                                       robot)
            return float(t[2]), float(t[4])

        points = [torques(ph.campaign_point_payload(dataclasses.asdict(p)))
                  for p in setup.campaign if p.kind != "torsional"]
        zero = points[0]
        a3, a5 = zip(*((m3 - zero[0], m5 - zero[1]) for m3, m5 in points), strict=True)
        dut = torques(setup.dut.payload())
        result = check(Envelope.from_torques(a3, a5), dut[0] - zero[0], dut[1] - zero[1])
    finally:
        robots.activate(previous)
    assert result.status == "inside", result.detail
