"""The warm-up (paper §2.4.4 A) and the preparation of a run: verify, trace configuration, warm-up, pose."""

from __future__ import annotations

import logging
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

from rgse_daemon.krc import Snapshot
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.events import Event
from rgse_daemon.procedures.preconditions import verify_start
from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, render_program, run_checked, trace_config_xml
from rgse_daemon.procedures.retrieval import TRACE_DIR
from rgse_daemon.procedures.settings import RunSettings
from rgse_daemon.safety.inputs import SafetyInputs

_log = logging.getLogger(__name__)

#: The axes whose motor temperature sets the thermal state of the measurement (the measurement axes).
THERMAL_AXES = (3, 5)


def motor_temps_k(snap: Snapshot | None) -> tuple[float, ...] | None:
    """$MOT_TEMP of A3 and A5 (K), or None when the snapshot lacks one of them."""
    if snap is None:
        return None
    temps = tuple(snap.motor_temps_k[a - 1] for a in THERMAL_AXES)
    return None if any(t is None for t in temps) else tuple(float(t) for t in temps)  # type: ignore[arg-type]


@dataclass
class ThermalHistory:
    """Motor temperatures of the measurement axes against accumulated warm-up motion time."""

    samples: list[tuple[float, tuple[float, ...]]] = field(default_factory=list)

    def add(self, motion_s: float, temps_k: tuple[float, ...]) -> None:
        self.samples.append((motion_s, temps_k))

    def steady(self, window_s: float, band_k: float) -> bool:
        """True when the temperatures stayed within ``band_k`` of the latest ones over the last ``window_s`` of
        motion (and at least that much motion has been observed)."""
        if not self.samples:
            return False
        t_now, now = self.samples[-1]
        if t_now - self.samples[0][0] < window_s:
            return False
        recent = [temps for t, temps in self.samples if t_now - t <= window_s]
        recent.append(next(temps for t, temps in reversed(self.samples) if t_now - t >= window_s))
        return all(abs(a - b) <= band_k for temps in recent for a, b in zip(temps, now, strict=True))

    def describe(self) -> str:
        (_, first), (t_last, last) = self.samples[0], self.samples[-1]
        axes = ", ".join(f"A{a} {t0:.0f} -> {t1:.0f} K" for a, t0, t1 in zip(THERMAL_AXES, first, last, strict=True))
        return f"{axes} in {t_last:.0f} s of warm-up motion"


def warm_up(s: RunSettings, snap: Snapshot | None) -> Generator[m.Msg, Any, tuple[Snapshot | None, list[str]]]:
    """The warm-up (paper §2.4.4 A): one run of ``warmup_cycles`` cycles, repeated while ``warmup_until_steady``
    and the A3/A5 motor temperatures still move by more than ``warmup_steady_k`` over ``warmup_steady_window_s``
    of warm-up motion, at most ``warmup_max_s``. Returns the last snapshot and warnings for the result."""
    history = ThermalHistory()
    motion_s = 0.0
    temps = motor_temps_k(snap)
    if temps is not None:
        history.add(motion_s, temps)
    runs = 0
    while True:
        runs += 1
        yield m.Emit(Event("step", f"warm-up move, run {runs} ({s.warmup_cycles} cycles)", step="warm-up",
                           data={"run": runs, "motor_temps_k": temps}))
        ran_s = (yield from run_checked((yield from render_program("rgse_warmup", s, snap)), s)) or 0.0
        motion_s += ran_s
        snap = yield m.ReadState()
        if not s.warmup_until_steady or ran_s <= 0.0:  # one run asked for, or nothing moved (dry run)
            return snap, []
        temps = motor_temps_k(snap)
        if temps is None:
            return snap, ["warm-up: the controller does not report $MOT_TEMP of A3/A5; thermal state not verified"]
        history.add(motion_s, temps)
        if history.steady(s.warmup_steady_window_s, s.warmup_steady_k):
            _log.info("warm-up: thermal state steady after %d runs: %s", runs, history.describe())
            return snap, []
        if motion_s >= s.warmup_max_s:
            return snap, [f"warm-up: motor temperatures not steady within {s.warmup_steady_k:g} K over "
                          f"{s.warmup_steady_window_s:g} s after {s.warmup_max_s:g} s ({history.describe()}); the "
                          f"calibration's thermal state may differ"]


def prepare(s: RunSettings, inputs: Callable[[], SafetyInputs] | None) -> Generator[m.Msg, Any, list[str]]:
    """Verify, push the trace configuration, warm up (if cycles > 0) and move to the measurement pose; returns the
    warm-up's warnings."""
    snap = yield from verify_start(inputs)
    yield m.PutFile(TRACE_DIR + TRACE_CONFIG_NAME, trace_config_xml(s).encode("utf-8"))
    warnings: list[str] = []
    if s.warmup_cycles > 0:
        snap, warnings = yield from warm_up(s, snap)
    yield m.Emit(Event("step", "moving to the measurement pose", step="measurement-pose"))
    yield from run_checked((yield from render_program("rgse_meas_pose", s, snap)), s)
    return warnings
