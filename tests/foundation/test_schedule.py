"""The order ``make test``'s workers get the tests in (tests/support/schedule.py): the stories (``slow``) at the heads
of the worksteal shares, longest first to the least loaded share, every other test once and in its order."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from tests.conftest import pytest_collection_modifyitems
from tests.support.schedule import share_sizes, stories_first


def test_share_sizes_are_worksteal_s_cut() -> None:
    assert share_sizes(10, 2) == [5, 5]
    assert share_sizes(11, 2) == [5, 6]
    assert share_sizes(10, 3) == [3, 3, 4]
    assert share_sizes(1, 2) == [0, 1]


def test_stories_go_to_the_heads_of_the_shares_balanced_and_the_rest_keeps_its_order() -> None:
    times = {"a": 180.0, "b": 130.0, "c": 100.0, "d": 50.0}
    items = ["t1", "b", "t2", "t3", "d", "t4", "a", "t5", "t6", "c", "t7", "t8"]
    out = stories_first(items, 2, times.get)
    assert sorted(out) == sorted(items)
    first, second = out[:6], out[6:]
    # LPT: a (180) to share 0, b (130) and c (100) to share 1 (130 < 180, then 230 > 180), d (50) to share 0
    assert first[:2] == ["a", "d"] and second[:2] == ["b", "c"]
    assert [t for t in out if t.startswith("t")] == ["t1", "t2", "t3", "t4", "t5", "t6", "t7", "t8"]


def test_one_worker_keeps_the_collection_order() -> None:
    items = ["t1", "a", "t2"]
    assert stories_first(items, 1, {"a": 100.0}.get) == items


def test_more_stories_than_a_share_holds_spill_to_the_other() -> None:
    times = {f"s{i}": float(10 - i) for i in range(5)}
    out = stories_first(["s0", "s1", "s2", "s3", "s4", "t1"], 2, times.get)
    # s0 (10) and s3 (7) to share 0, s1 (9) and s2 (8) to share 1, s4 (6) at the tie to share 0, which is full then
    assert out == ["s0", "s3", "s4", "s1", "s2", "t1"]


class FakeItem:
    """What the hook asks of a collected test: its name and its ``slow`` marker."""

    def __init__(self, name: str, mark: pytest.MarkDecorator | None = None) -> None:
        self.name = name
        self.mark = mark

    def get_closest_marker(self, name: str) -> pytest.Mark | None:
        return self.mark.mark if self.mark is not None and self.mark.name == name else None


@pytest.mark.parametrize("workers", [None, 1, 2])
def test_the_suite_s_own_hook_orders_what_xdist_s_workers_collect(workers: int | None) -> None:
    """The conftest hook as xdist's workers run it (their ``workerinput`` says how many there are): a story at the
    head of each share, the longest on the first, the other tests in their order; one process keeps the order."""
    items = [FakeItem("t1"), FakeItem("t2"), FakeItem("short", pytest.mark.slow(expected_s=100)), FakeItem("t3"),
             FakeItem("long", pytest.mark.slow(expected_s=180)), FakeItem("t4")]
    config = SimpleNamespace() if workers is None else SimpleNamespace(workerinput={"workercount": workers})
    order = list(items)
    pytest_collection_modifyitems(config, order)  # type: ignore[arg-type]
    names = [item.name for item in order]
    if workers == 2:
        assert names == ["long", "t1", "t2", "short", "t3", "t4"]
    else:
        assert names == ["t1", "t2", "short", "t3", "long", "t4"]
