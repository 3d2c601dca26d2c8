"""The daemon's I/O beside the controller link: the field devices at the robot and MQTT.

Modules
-------
``rgse_daemon.io.modbus``       ``SafetyIo`` / ``ModbusConfig``: polls "hazard area cleared", "key switch AUT
                                permitted" and "E-stop OK"; drives the stack light and "measurement running".
``rgse_daemon.io.scale``        ``CraneScale`` / ``ScaleConfig``: stable weighings from the Kern HFB crane scale over
                                RS-232 (or a ``socket://`` serial server).
``rgse_daemon.io.mqtt``         the daemon's MQTT face (interfaces §4): status, state, progress, results and alarms
                                out, commands in.
``rgse_daemon.io.commands``     the schemas of the commands that arrive on ``<prefix>/cmd/<verb>``.
``rgse_daemon.io.topics``       the topics under one prefix: the one place a topic name is built.
``rgse_daemon.io.operator``     the operator's MQTT client (``rgse status``, ``confirm``, ``abort``; the Python client).
``rgse_daemon.io.mqtt_client``  aiomqtt's client, made to leave nothing behind (the daemon's and the operator's).

This package module holds only the error tree shared by the two field devices, so that importing one device never
imports the other (or MQTT). Every error names the device (``device``) it came from, e.g. ``modbus 10.0.0.7:502 unit 1``
or ``scale /dev/ttyUSB0``.
"""

from __future__ import annotations

from rgse_daemon.errors import RgseError


class IoDeviceError(RgseError):
    """A field device (safety I/O module, scale) failed; the message starts with the device's name."""

    def __init__(self, device: str, message: str) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.problem = message


class IoTimeout(IoDeviceError):
    """A connect, request or read got no complete answer within its deadline."""


class IoLinkError(IoDeviceError):
    """The connection is down, was dropped by the peer, or could not be opened."""


class IoDeviceRefused(IoDeviceError):
    """The device answered with an error (e.g. a Modbus exception response): it is there but said no."""

    def __init__(self, device: str, message: str, code: int | None = None) -> None:
        super().__init__(device, message)
        self.code = code


class IoFrameError(IoDeviceError):
    """Bytes from the device that do not follow its protocol; carries the raw line or frame."""

    def __init__(self, device: str, message: str, raw: str) -> None:
        super().__init__(device, f"{message} in {raw!r}")
        self.problem = message
        self.raw = raw
