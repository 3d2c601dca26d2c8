"""Helpers of the client, ``rgse run``, console and two-robot tests: a short campaign, its points file, and the
person at the simulated robot who mounts what a prompt asks for."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

from rgse_daemon import robots
from rgse_daemon.client import CampaignPoint, Prompt
from rgse_daemon.procedures.calibration import table1_points
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4

#: Zero, 2, 5 and 10 bodies and one torque point: the fewest that fit, quick on the simulator.
SHORT_CAMPAIGN = table1_points(n_bodies=(0, 2, 5, 10),
                               torque_levers_a5_m=robots.get(robots.DEFAULT_KEY).calibration.torque_levers_a5_m[1:2])


def short_points() -> list[CampaignPoint]:
    """:data:`SHORT_CAMPAIGN` as the client's points."""
    return [CampaignPoint(p.kind, p.mass_kg, p.lever_a3_m, p.lever_a5_m) for p in SHORT_CAMPAIGN]  # type: ignore


def write_points(path: Path, points: Sequence[CampaignPoint] | None = None) -> Path:
    """A points file (``[[point]]`` tables) of ``points`` (default: the short campaign)."""
    lines = []
    for p in points or short_points():
        lines += ["[[point]]", f'kind = "{p.kind}"', f"mass_kg = {p.mass_kg!r}", f"lever_a3_m = {p.lever_a3_m!r}",
                  f"lever_a5_m = {p.lever_a5_m!r}", ""]
    path.write_text("\n".join(lines))
    return path


def operator_at(sim: SimulatedKrc4, seen: list[Prompt] | None = None) -> Callable[[Prompt], str]:
    """The person at the robot: mounts what the prompt asks for on the simulated flange and says so."""

    def on_prompt(prompt: Prompt) -> str:
        if seen is not None:
            seen.append(prompt)
        sim.mount(campaign_point_payload(dataclasses.asdict(prompt)))
        return f"mounted point {prompt.point_index}"

    return on_prompt
