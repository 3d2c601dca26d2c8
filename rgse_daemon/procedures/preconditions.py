"""The state a run may start from (paper Fig. 24 'verify')."""

from __future__ import annotations

from collections.abc import Callable, Generator
from typing import Any

from rgse_daemon.errors import InterlockError
from rgse_daemon.krc import Snapshot
from rgse_daemon.procedures import messages as m
from rgse_daemon.procedures.events import Event
from rgse_daemon.safety.inputs import SafetyInputs

#: $LOAD.M of KUKA's "unknown payload" mode, which the paper's method requires (the controller then does not
#: compensate the payload, so the torques carry it).
UNKNOWN_PAYLOAD_KG = -1.0


class PreconditionError(InterlockError):
    """The controller is not in a state in which a plan may start (mode, $LOAD, stop message, program running)."""


def check_preconditions(snap: Snapshot, inputs: SafetyInputs | None) -> str:
    """The state a run may start from (paper Fig. 24 'verify'); returns the operating mode, else
    :class:`PreconditionError` naming every problem. Unreadable means refused."""
    problems: list[str] = []
    mode = snap.mode_op
    if mode == "AUT":
        if inputs is None or not inputs.safe:
            why = "no safety inputs" if inputs is None else (inputs.reason or "area not cleared / key / E-stop")
            problems.append(f"AUT needs the area cleared, the AUT key and E-stop OK ({why})")
    elif mode != "T1":
        problems.append(f"$MODE_OP is #{mode}: the RGSE runs in T1 (or AUT with the area cleared)")
    elif inputs is not None and not (inputs.valid and inputs.estop_ok):
        problems.append("E-stop chain not OK on the safety I/O module" if inputs.valid else
                        f"E-stop state unknown: safety inputs invalid ({inputs.reason})")
    if snap.load is None:
        problems.append("$LOAD unreadable")
    elif snap.load.mass_kg != UNKNOWN_PAYLOAD_KG:
        problems.append(f"$LOAD.M is {snap.load.mass_kg:g} kg: the method needs the unknown-payload mode (-1)")
    if snap.stopmess is not False:
        problems.append("a stop message is active ($STOPMESS): acknowledge it on the smartPAD" if snap.stopmess
                        else "$STOPMESS unreadable")
    if snap.user_saf is not True:
        problems.append("operator safety ($USER_SAF) not closed or unreadable")
    if snap.pro_state1 in (None, "P_ACTIVE"):
        problems.append(f"robot interpreter is #{snap.pro_state1}: a program is running or the state is unreadable")
    if snap.trace_state != "T_END":
        problems.append(f"$TRACE.STATE is #{snap.trace_state}: a trace is active or the state is unreadable")
    if snap.axes_deg is None:
        problems.append("$AXIS_ACT unreadable")
    if problems:
        raise PreconditionError("refused to start: " + "; ".join(problems))
    assert mode is not None
    return mode


def verify_start(inputs: Callable[[], SafetyInputs] | None) -> Generator[m.Msg, Any, Snapshot | None]:
    """Read the controller and check :func:`check_preconditions`; returns the snapshot."""
    yield m.Emit(Event("step", "verifying the controller state", step="verify"))
    snap = yield m.ReadState()
    if snap is not None:
        check_preconditions(snap, inputs() if inputs is not None else None)
    return snap
