"""The kinds of run (interfaces §4.2, §6): one enumeration for the store, MQTT, the console and the client.

A value is the word on the wire and in the store's ``runs.kind`` column; a member compares equal to its word.
"""

from __future__ import annotations

from enum import StrEnum


class RunKind(StrEnum):
    MEASUREMENT = "measurement"
    """The mass of the mounted DuT from the measurement loops (``rgse_daemon.procedures.measurement``)."""
    PROPERTIES = "properties"
    """A mass-properties run: the mass loops, then the CoG poses, optionally the inertia
    (``rgse_daemon.procedures.properties``). Stored as ``measurement`` before schema migration 3."""
    CALIBRATION = "calibration"
    """A calibration campaign over load points (``rgse_daemon.procedures.calibration``)."""
