"""Property: after any sequence of add/activate operations, every robot that has calibrations has exactly one
active, and it is the one the operations say (the latest activated, else the first added)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import Bundle, RuleBasedStateMachine, initialize, invariant, rule, run_state_machine_as_test

from rgse_daemon.store import NotFound, Repository, StoreConflict

from .conftest import calibration_doc

ROBOT_SUFFIXES = ("A", "B", "C")
_instances = itertools.count()


class CalibrationActivation(RuleBasedStateMachine):
    """Drives a real store; the model is {robot: active id} plus each calibration's robot.

    All examples share one database (opening and migrating one per example would dominate the run time); each
    example uses robots and calibration ids of its own, so examples cannot see each other.
    """

    calibrations = Bundle("calibrations")

    def __init__(self, repo: Repository) -> None:
        super().__init__()
        self.repo = repo
        self.prefix = f"m{next(_instances)}"
        self.robots = tuple(f"{self.prefix}-KR500-{s}" for s in ROBOT_SUFFIXES)
        self.robot_of: dict[str, str] = {}
        self.active: dict[str, str] = {}
        self.counter = 0

    @initialize()
    def empty_store_has_no_active_calibration(self) -> None:
        assert all(self.repo.active_calibration(r) is None for r in self.robots)

    @rule(target=calibrations, robot_index=st.sampled_from(range(len(ROBOT_SUFFIXES))), activate=st.booleans())
    def add(self, robot_index: int, activate: bool) -> str:
        robot = self.robots[robot_index]
        self.counter += 1
        cal_id = f"{self.prefix}-cal-{self.counter}"
        rec = self.repo.add_calibration(calibration_doc(cal_id, robot=robot), activate=activate)
        self.robot_of[cal_id] = robot
        if activate or robot not in self.active:
            self.active[robot] = cal_id
        assert rec.active == (self.active[robot] == cal_id)
        return cal_id

    @rule(cal_id=calibrations, activate=st.booleans())
    def add_again(self, cal_id: str, activate: bool) -> None:
        robot = self.robot_of[cal_id]
        self.repo.add_calibration(calibration_doc(cal_id, robot=robot), activate=activate)
        if activate:
            self.active[robot] = cal_id

    @rule(cal_id=calibrations)
    def add_conflicting(self, cal_id: str) -> None:
        with pytest.raises(StoreConflict):
            self.repo.add_calibration(calibration_doc(cal_id, robot=self.robot_of[cal_id], method="other"))

    @rule(cal_id=calibrations)
    def activate(self, cal_id: str) -> None:
        rec = self.repo.activate_calibration(cal_id)
        assert rec.active
        self.active[self.robot_of[cal_id]] = cal_id

    @rule()
    def activate_unknown(self) -> None:
        with pytest.raises(NotFound):
            self.repo.activate_calibration("cal-unknown")

    @invariant()
    def exactly_one_active_per_robot_with_calibrations(self) -> None:
        by_robot: dict[str, list[str]] = {}
        for robot in self.robots:
            for cal in self.repo.calibrations(robot):
                if cal.active:
                    by_robot.setdefault(cal.robot, []).append(cal.id)
        having = {robot for robot in self.robot_of.values()}
        assert set(by_robot) == having
        assert all(len(ids) == 1 for ids in by_robot.values()), by_robot
        assert {robot: ids[0] for robot, ids in by_robot.items()} == self.active
        for robot in self.robots:
            got = self.repo.active_calibration(robot)
            assert (got.id if got else None) == self.active.get(robot)

MACHINE_SETTINGS = settings(max_examples=25, stateful_step_count=15, deadline=None)


def test_calibration_activation_sqlite(data_dir: Path) -> None:
    with Repository.open(None, data_dir) as repo:
        run_state_machine_as_test(lambda: CalibrationActivation(repo), settings=MACHINE_SETTINGS)


def test_calibration_activation_postgresql(pg_url: str, data_dir: Path) -> None:
    with Repository.open(pg_url, data_dir) as repo:
        run_state_machine_as_test(lambda: CalibrationActivation(repo), settings=MACHINE_SETTINGS)
