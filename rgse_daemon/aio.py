"""Small asyncio helpers the whole daemon shares."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


async def within(aw: Awaitable[T], timeout_s: float) -> T:
    """``await aw`` with a deadline (``TimeoutError`` after ``timeout_s``), never swallowing a cancellation.

    Use instead of ``asyncio.wait_for``: on Python 3.11, when the awaited operation completes in the same loop
    iteration in which the caller is cancelled, ``wait_for`` returns the result and the cancellation is lost (fixed
    in 3.12, whose ``wait_for`` is built on ``asyncio.timeout``, as this is). A polling loop cancelled that way runs
    on, and whoever waits for it to end waits forever — seen as a rare hang of the interlock monitor at the end of a
    plan.
    """
    async with asyncio.timeout(timeout_s):
        return await aw
