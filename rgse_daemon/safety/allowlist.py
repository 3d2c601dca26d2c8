"""The write allow-list: the only controller variables the daemon may write, a safety policy.

The controller facade (:mod:`rgse_daemon.controller`) refuses any other write before a byte is sent, and the
interlock's static check (:mod:`rgse_daemon.safety.static`) refuses KRL that writes outside it. This module imports
nothing of the project, so both can use it without the facade depending on the interlock.
"""

from __future__ import annotations

import re

#: Variables the daemon may write (trace control and program override); anything else is refused locally.
WRITABLE_VARIABLES: frozenset[str] = frozenset({"$OV_PRO", "$TRACE.CONFIG[]", "$TRACE.NAME[]", "$TRACE.MODE"})
#: The controller-side watchdog (docs/security.md): the system timer the daemon's heartbeat keeps below 0, the
#: interrupt every daemon program arms on it, and its condition (the timer ran out, or someone stopped it).
WATCHDOG_TIMER = 16
WATCHDOG_INTERRUPT = 1
WATCHDOG_CONDITION = f"$TIMER_FLAG[{WATCHDOG_TIMER}] OR $TIMER_STOP[{WATCHDOG_TIMER}]"
#: What the heartbeat writes: only the daemon over its link, never a program (the static check refuses it there).
WATCHDOG_VARIABLES: frozenset[str] = frozenset({f"$TIMER[{WATCHDOG_TIMER}]", f"$TIMER_STOP[{WATCHDOG_TIMER}]"})
#: User globals of the daemon's own KRL programs (declared in its $CONFIG.DAT part) are writable too.
WRITABLE_PREFIX = "RGSE_"
_USER_GLOBAL = re.compile(r"RGSE_[A-Z0-9_]+(\[[0-9]*(,[0-9]+)*\])?(\.[A-Z0-9_]+)*")


def writable(name: str) -> bool:
    """Whether the allow-list lets the daemon write ``name`` (case-insensitive, as KRL names are)."""
    n = name.strip().upper()
    return n in WRITABLE_VARIABLES or n in WATCHDOG_VARIABLES or _USER_GLOBAL.fullmatch(n) is not None
