"""The one time format of every MQTT payload and JSON log line: ISO 8601, UTC, milliseconds, ``Z``.

``2026-11-24T06:53:50.123Z``. Epoch seconds (``time.time()``) and aware datetimes are both written this way, so a
client never has to guess whether ``time`` is a number or a string.
"""

from __future__ import annotations

from datetime import UTC, datetime


def iso_utc(ts: datetime | float) -> str:
    """``ts`` (an aware datetime, or seconds since the epoch) as ``YYYY-MM-DDTHH:MM:SS.mmmZ``."""
    if not isinstance(ts, datetime):
        ts = datetime.fromtimestamp(float(ts), UTC)
    elif ts.tzinfo is None:
        raise ValueError(f"{ts!r}: a naive datetime has no time zone; give an aware (UTC) one")
    return ts.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def now_utc() -> str:
    """The current time as :func:`iso_utc`."""
    return iso_utc(datetime.now(UTC))
