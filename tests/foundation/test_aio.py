"""``rgse_daemon.aio.within``: a deadline that never swallows a cancellation (what Python 3.11's ``wait_for`` does
when the awaited operation completes in the same loop iteration as the cancel — a rare hang of the interlock
monitor at the end of a plan, reproduced 2 in 15 runs of ``test_finaliser_runs_on_error`` before the fix)."""

from __future__ import annotations

import asyncio

import pytest

from rgse_daemon.aio import within


async def test_cancel_in_the_same_iteration_as_the_result_propagates() -> None:
    fut: asyncio.Future[int] = asyncio.get_running_loop().create_future()
    task = asyncio.create_task(within(fut, 10.0))
    await asyncio.sleep(0)  # the task now waits on fut
    fut.set_result(1)
    task.cancel()  # before the task saw the result
    with pytest.raises(asyncio.CancelledError):
        await task
    assert task.cancelled()


async def test_a_polling_loop_ends_when_cancelled_even_if_each_poll_just_completed() -> None:
    """The monitor's shape: poll with a deadline in a loop; a cancel must end the loop."""
    polls = 0

    async def poll() -> int:
        nonlocal polls
        polls += 1
        return polls

    async def loop() -> None:
        while True:
            await within(poll(), 1.0)
            await asyncio.sleep(0)

    task = asyncio.create_task(loop())
    for _ in range(20):
        await asyncio.sleep(0)
        if not task.done():
            task.cancel()
            break
    done, _ = await asyncio.wait({task}, timeout=5.0)
    assert task in done and task.cancelled()


async def test_deadline_raises_timeout_error() -> None:
    with pytest.raises(TimeoutError):
        await within(asyncio.sleep(10.0), 0.01)
    assert await within(asyncio.sleep(0, result="ok"), 1.0) == "ok"
