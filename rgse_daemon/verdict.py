"""A result's status (interfaces §1.3, §4.2): ``ok``, ``warning`` or ``refused``, derived from what the result says.

One rule everywhere (the JSON of ``rgse mass``/``cog``/``run``, the MQTT result, the store, the client, the console,
the report), so the operator reads the same word wherever he looks:

* ``refused``: there is no figure to file; ``reason`` says why (an operating point far outside the calibration,
  too few usable loops, bad input, a refused command or a run that did not finish);
* ``warning``: a figure with at least one warning, to be read together with them;
* ``ok``: a figure without warnings.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

Status = Literal["ok", "warning", "refused"]
OK: Status = "ok"
WARNING: Status = "warning"
REFUSED: Status = "refused"
STATUSES: tuple[Status, ...] = (OK, WARNING, REFUSED)


def status_of(result: Mapping[str, Any]) -> Status:
    """The status of a result object: ``refused`` if it says so (or carries a refusal ``reason`` and no figure),
    ``warning`` if its ``warnings`` list is not empty, else ``ok``."""
    if result.get("status") == REFUSED:
        return REFUSED
    warnings = result.get("warnings")
    if isinstance(warnings, list | tuple) and len(warnings) > 0:
        return WARNING
    return OK


def with_status(result: Mapping[str, Any]) -> dict[str, Any]:
    """``result`` with its ``status`` field set by :func:`status_of` (a copy)."""
    return {**result, "status": status_of(result)}


def refusal(reason: str, **context: Any) -> dict[str, Any]:
    """The JSON object of a refused result: ``status`` ``refused``, its ``reason``, no warnings, and ``context``
    (e.g. ``error`` the kind of error, ``run_id``, ``state``)."""
    return {"status": REFUSED, "reason": reason, "warnings": [], **context}
