"""The one polling helper of the tests: wait for a condition of the code under test, with a deadline."""

from __future__ import annotations

import asyncio
from collections.abc import Callable


async def wait_until(predicate: Callable[[], bool], what: str = "condition", timeout_s: float = 15.0,
                     period_s: float = 0.02) -> None:
    """Poll ``predicate`` until true; fail naming ``what`` at the deadline (a hang guard, not a timing check)."""
    try:
        async with asyncio.timeout(timeout_s):
            while not predicate():  # noqa: ASYNC110 - counters and flags of the code under test have no event to await
                await asyncio.sleep(period_s)
    except TimeoutError:
        raise AssertionError(f"not within {timeout_s:g} s: {what}") from None
