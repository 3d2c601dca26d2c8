"""The order in which ``make test``'s workers get the tests: the whole stories first, spread over the workers.

``pytest -n W --dist worksteal`` hands worker k the k-th of W contiguous shares of the collection (each worker in
turn the remaining tests // the workers left), and a worker that runs out steals the second half of the longest
queue left, from its tail. A story of three minutes (a demo, the README's lab path) that lies late in its share
starts when the other worker has little left, and the run's end waits for it on one core while the other is idle.
:func:`stories_first` puts the tests marked ``slow`` at the heads of the shares instead, longest first (their
``expected_s``) to the share with the least story time (LPT), and the other tests behind them in their own order:
the last minutes of the run are then short tests on every worker. A test's place changes, not what it does."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

T = TypeVar("T")

#: A ``slow`` test without ``expected_s`` counts as a minute.
DEFAULT_EXPECTED_S = 60.0


def share_sizes(n: int, workers: int) -> list[int]:
    """The sizes of the workers' first shares as worksteal cuts ``n`` tests: worker k gets what is left // the
    workers left."""
    sizes, left = [], n
    for k in range(workers):
        sizes.append(left // (workers - k))
        left -= sizes[-1]
    return sizes


def stories_first(items: Sequence[T], workers: int, expected_s: Callable[[T], float | None]) -> list[T]:
    """``items`` reordered for ``workers`` worksteal workers: ``expected_s(item)`` is a story's expected wall time
    (s), None for a test that is not one. Stories go to the heads of the shares, longest first to the least
    loaded share with room; the other tests follow in their order, filling each share to its size."""
    if workers < 2:
        return list(items)
    times = {id(item): expected_s(item) for item in items}
    stories = sorted((item for item in items if times[id(item)] is not None), key=lambda i: -(times[id(i)] or 0.0))
    rest = iter([item for item in items if times[id(item)] is None])
    sizes = share_sizes(len(items), workers)
    heads: list[list[T]] = [[] for _ in range(workers)]
    load = [0.0] * workers
    for item in stories:
        k = min((k for k in range(workers) if len(heads[k]) < sizes[k]), key=lambda k: load[k])
        heads[k].append(item)
        load[k] += times[id(item)] or 0.0
    ordered: list[T] = []
    for k in range(workers):
        ordered += heads[k]
        ordered += [next(rest) for _ in range(sizes[k] - len(heads[k]))]
    return ordered
