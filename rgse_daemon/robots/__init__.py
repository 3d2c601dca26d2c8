"""The robots the daemon knows, one module each, and the active one (``[robot] model``).

A leaf package (pyproject.toml contract): it imports nothing of the project. :func:`get` looks a robot up by its
key; :func:`active` is the robot the process measures with, chosen once at start-up by :func:`activate` from the
configuration (``rgse demo --robot`` and the tests choose it the same way). The functions of
:mod:`rgse_daemon.kinematics` default to :func:`active`.
"""

from __future__ import annotations

from rgse_daemon.robots import kr10r1440, kr500r2830
from rgse_daemon.robots.model import CalibrationLoads, DefaultCell, DhRow, RobotModel

ROBOTS: dict[str, RobotModel] = {r.key: r for r in (kr500r2830.ROBOT, kr10r1440.ROBOT)}
DEFAULT_KEY = kr500r2830.ROBOT.key

_active: RobotModel = ROBOTS[DEFAULT_KEY]


def get(key: str) -> RobotModel:
    """The robot called ``key`` (case-insensitive); an unknown key is refused with the known ones named."""
    robot = ROBOTS.get(key.lower())
    if robot is None:
        raise ValueError(f"unknown robot model {key!r}; known: {', '.join(sorted(ROBOTS))}")
    return robot


def active() -> RobotModel:
    """The robot this process measures with (the default KR 500 R2830 until :func:`activate` chose another)."""
    return _active


def activate(robot: RobotModel | str) -> RobotModel:
    """Make ``robot`` (a model or its key) the active one; returns the one it replaced."""
    global _active
    previous = _active
    _active = get(robot) if isinstance(robot, str) else robot
    return previous


__all__ = ["DEFAULT_KEY", "ROBOTS", "CalibrationLoads", "DefaultCell", "DhRow", "RobotModel", "activate", "active",
           "get"]
