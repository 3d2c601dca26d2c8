"""Recording how a run ended, through a store that may be failing (disk full, database restarting).

A run whose end cannot be recorded would stay ``running`` in the store until the next daemon start marks it
``interrupted`` — the wrong word for a run that failed. :func:`record_final_state` retries with backoff (while the
run's task stays alive, so no new run starts on a store that cannot record) until the state is recorded or
:data:`FINAL_STATE_RETRY_S` passed; then it logs a critical error and the next start marks the run interrupted.
"""

from __future__ import annotations

import asyncio
import logging
import time

from rgse_daemon.aio import within
from rgse_daemon.errors import RgseError
from rgse_daemon.store.errors import StoreConflict
from rgse_daemon.store.records import RunState
from rgse_daemon.store.store import Store

_log = logging.getLogger(__name__)

#: How long the final state is retried (s).
FINAL_STATE_RETRY_S = 120.0
#: Deadline of one attempt (s).
ATTEMPT_TIMEOUT_S = 10.0
BACKOFF_MIN_S = 0.25
BACKOFF_MAX_S = 5.0


async def record_final_state(store: Store, run_id: str, state: RunState, detail: str | None, *,
                             retry_s: float = FINAL_STATE_RETRY_S) -> bool:
    """Record ``state`` of run ``run_id``; retried until done or ``retry_s`` passed. Returns whether it was recorded.
    Each attempt is shielded: a cancellation (shutdown) does not interrupt a write under way, and still propagates."""
    deadline = time.monotonic() + retry_s
    pause_s = BACKOFF_MIN_S
    attempt = 0
    while True:
        attempt += 1
        try:
            await asyncio.shield(within(store.set_run_state(run_id, state, detail), ATTEMPT_TIMEOUT_S))
            if attempt > 1:
                _log.warning("run %s: state %s recorded at attempt %d", run_id, state, attempt)
            return True
        except StoreConflict as err:  # retrying cannot help
            _log.error("run %s: could not record state %s: %r", run_id, state, err)
            return False
        except (TimeoutError, RgseError) as err:
            _log.error("run %s: could not record state %s (attempt %d): %r", run_id, state, attempt, err)
        if time.monotonic() + pause_s > deadline:
            _log.critical("run %s: state %s not recorded within %.0f s; the store shows it running until the next "
                          "daemon start marks it interrupted", run_id, state, retry_s)
            return False
        await asyncio.sleep(pause_s)
        pause_s = min(BACKOFF_MAX_S, pause_s * 2.0)
