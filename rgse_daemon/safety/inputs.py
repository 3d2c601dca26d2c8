"""The safety inputs as the interlock sees them: one immutable view of area cleared, AUT permitted and E-stop.

The Modbus safety I/O module (:mod:`rgse_daemon.io.modbus`) produces these views; the interlock (static check
context, runtime monitor, run admission) consumes them without knowing where they came from.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime


@dataclass(frozen=True)
class SafetyInputs:
    """One view of the safety inputs. ``valid`` is False on link loss, a refused or stale read: then all three
    inputs read False (not cleared, not permitted, E-stop not OK) and ``reason`` says why."""

    area_cleared: bool
    aut_permitted: bool
    estop_ok: bool
    valid: bool
    time_utc: datetime
    """When the values were read (for an invalid view: when the doubt arose)."""
    reason: str = ""

    @property
    def safe(self) -> bool:
        """All three inputs good, from a fresh reading."""
        return self.valid and self.area_cleared and self.aut_permitted and self.estop_ok

    def key(self) -> tuple[bool, bool, bool, bool]:
        """The safety-relevant part: a change in it is reported by ``SafetyIo.changes()``."""
        return (self.area_cleared, self.aut_permitted, self.estop_ok, self.valid)

    @classmethod
    def unsafe(cls, reason: str, time_utc: datetime | None = None) -> SafetyInputs:
        return cls(False, False, False, False, time_utc or datetime.now(UTC), reason)
