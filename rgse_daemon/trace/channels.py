"""Names of the KUKA Trace modules and drive channels (docs/controller.md §5.6).

Channels are identified by module and name (DIAdem code 200), never by position: the mapping of the numeric
channel IDs in the trace configuration XML to names is not public.
"""

from __future__ import annotations

#: The interpolator module (Cartesian and axis set-points).
KRC_IPO = "KRCIpo"

#: Implicit time channel that KUKA writes first in every ``.dat`` header (seconds).
ZEIT = "Zeit"

SOLLPOSITION = "Sollposition"  # commanded position, deg (rotary axis) or mm (linear axis)
ISTPOSITION = "Istposition"  # actual position, deg or mm
POSITIONSSCHLEPPFEHLER = "Positionsschleppfehler"  # following error, deg or mm
GESCHWINDIGKEITSDIFFERENZ = "Geschwindigkeitsdifferenz"  # velocity error, deg/s or mm/s
MOTORTEMPERATUR = "Motortemperatur"  # motor temperature, K
ISTMOMENT = "Istmoment"  # actual torque at the gear output, Nm
ISTSTROM = "Iststrom"  # actual motor current, A

#: Drive channel name -> unit as written for a rotary axis.
DRIVE_CHANNEL_UNITS: dict[str, str] = {
    SOLLPOSITION: "deg",
    ISTPOSITION: "deg",
    POSITIONSSCHLEPPFEHLER: "deg",
    GESCHWINDIGKEITSDIFFERENZ: "deg/s",
    MOTORTEMPERATUR: "K",
    ISTMOMENT: "Nm",
    ISTSTROM: "A",
}


def drive_module(axis: int) -> str:
    """The trace module of axis ``A<axis>``'s drive: ``NextGenDrive#<axis>`` (axis 1..6)."""
    if not 1 <= axis <= 6:
        raise ValueError(f"axis must be 1..6, got {axis}")
    return f"NextGenDrive#{axis}"
