"""Progress events: what the engine tells its subscribers (MQTT ``progress``/``alarm``/``result``, CLI, logs).

A subscriber is a plain callable ``(Event) -> None`` registered with :meth:`RunEngine.subscribe`. It is called on
the event loop and must not block (put the event on a queue); an exception in a subscriber is logged and never
reaches the plan. Kinds:

* ``state``   — engine state changed: ``data["state"]`` is an
  :class:`~rgse_daemon.procedures.engine.EngineState` value: ``running``/``paused``/``confirm`` (waiting for the
  operator)/``done``/``failed``/``aborted`` (``idle`` before the first plan). There is no ``finalizing``: the
  finaliser runs while the state is still ``running``/``paused``/``confirm``.
* ``step``    — a plan step began (``step``: e.g. ``"warm-up"``, ``"loop"``, ``"pull"``, ``"compute"``).
* ``loop``    — loop ``loop_index`` of ``loop_count`` finished; ``eta_s`` estimates the rest, ``data`` holds the
  loop's timing (``robot_s``, ``overhead_s``).
* ``confirm`` — the plan waits for the operator: ``message`` is the prompt; answer with :meth:`RunEngine.confirm`.
* ``alarm``   — an interlock trip, a refused program, link loss: ``data["watcher"]`` names the watcher.
* ``result``  — the measurement or calibration result (``data``: as ``rgse mass --json`` / ``rgse calibrate``); the
  :class:`~rgse_daemon.procedures.documents.Result` document is what records and publishes it.
* ``log``     — anything else worth showing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from rgse_daemon.utc import iso_utc

EventKind = Literal["state", "step", "loop", "confirm", "alarm", "result", "log"]


@dataclass(frozen=True)
class Event:
    kind: EventKind
    message: str = ""
    run_id: str | None = None
    step: str | None = None
    loop_index: int | None = None  # 1-based
    loop_count: int | None = None
    eta_s: float | None = None
    data: dict[str, Any] = field(default_factory=dict)
    time_s: float = field(default_factory=time.time)  # wall clock

    def to_json(self) -> dict[str, Any]:
        """The event as the MQTT payload (interfaces §4: step, loop i/n, eta)."""
        out: dict[str, Any] = {"kind": self.kind, "time": iso_utc(self.time_s)}
        for key in ("message", "run_id", "step", "loop_index", "loop_count", "eta_s"):
            value = getattr(self, key)
            if value not in (None, ""):
                out[key] = value
        if self.data:
            out["data"] = self.data
        return out


Subscriber = Callable[[Event], None]
