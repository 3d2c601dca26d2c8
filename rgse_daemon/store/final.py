"""Recording how a run ended, through a store that may be failing (disk full, database restarting).

A run whose end cannot be recorded would stay ``running`` in the store until the next daemon start marks it
``interrupted`` — the wrong word for a run that failed. :func:`retry_final` repeats the recording with backoff (while
the run's task stays alive, so no new run starts on a store that cannot record) until it is done or
:data:`FINAL_STATE_RETRY_S` passed; then it logs a critical error and the next start marks the run interrupted.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable

from rgse_daemon.errors import RgseError
from rgse_daemon.store.errors import StoreConflict

_log = logging.getLogger(__name__)

#: How long the final state is retried (s).
FINAL_STATE_RETRY_S = 120.0
BACKOFF_MIN_S = 0.25
BACKOFF_MAX_S = 5.0


async def retry_final(attempt: Callable[[], Awaitable[object]], what: str, *,
                      retry_s: float = FINAL_STATE_RETRY_S) -> bool:
    """Await ``attempt()`` until it succeeds or ``retry_s`` passed; returns whether it succeeded. A
    :class:`StoreConflict` is not retried (retrying cannot help); cancellation propagates."""
    deadline = time.monotonic() + retry_s
    pause_s = BACKOFF_MIN_S
    n = 0
    while True:
        n += 1
        try:
            await attempt()
            if n > 1:
                _log.warning("%s: recorded at attempt %d", what, n)
            return True
        except StoreConflict as err:
            _log.error("%s: not recorded: %r", what, err)
            return False
        except (TimeoutError, RgseError) as err:
            _log.error("%s: not recorded (attempt %d): %r", what, n, err)
        if time.monotonic() + pause_s > deadline:
            _log.critical("%s: not recorded within %.0f s; the store shows the run running until the next daemon "
                          "start marks it interrupted", what, retry_s)
            return False
        await asyncio.sleep(pause_s)
        pause_s = min(BACKOFF_MAX_S, pause_s * 2.0)
