"""One small tree of typed errors.

Every error that crosses a layer boundary is one of these, raised ``from`` its cause, so that callers can
react by kind (retry a link timeout, stop on an interlock trip, exit 2 on bad input) without parsing messages.
"""

from __future__ import annotations

#: Exit statuses of the ``rgse`` command (interfaces §1), shared by every sub-command.
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_REFUSED = 3
#: A result was computed and carries warnings (status ``warning``, rgse_daemon.verdict): ``rgse mass``, ``rgse cog``,
#: ``rgse run``. Its figure is printed; a script that files it must read the warnings.
EXIT_WARNINGS = 4


class RgseError(Exception):
    """Base of every error the project raises on purpose."""


# --- configuration -------------------------------------------------------------------------------------------
class ConfigError(RgseError):
    """A configuration file or field is missing, malformed or out of bounds."""


# --- the controller link ---------------------------------------------------------------------------------------
class LinkError(RgseError):
    """Anything that went wrong talking to the controller."""


class LinkTimeout(LinkError):
    """A request (or connect) got no complete answer within its deadline."""


class LinkClosed(LinkError):
    """The connection is closed, was dropped by the peer, or could not be opened."""


class ProtocolError(LinkError):
    """Bytes or values that do not follow the C3 Bridge / KVP protocol or the KRL value syntax."""


class VariableError(LinkError):
    """The controller refused to read or write a variable."""

    def __init__(self, name: str, message: str, code: int | None = None) -> None:
        super().__init__(f"{name}: {message}")
        self.name = name
        self.code = code


class NotAllowedError(RgseError):
    """A write or command that the allow-list refuses; it never reached the wire."""


# --- data ------------------------------------------------------------------------------------------------------
class DataError(RgseError):
    """Input data (trace file, manifest, calibration file, CSV) is missing, malformed or inconsistent.

    The message names the file and the problem.
    """


# --- KRL and safety ----------------------------------------------------------------------------------------------
class KrlSyntaxError(RgseError):
    """A KRL program does not parse. Carries file, line and column."""

    def __init__(self, message: str, file: str = "<string>", line: int = 0, column: int = 0) -> None:
        super().__init__(f"{file}:{line}:{column}: {message}")
        self.file = file
        self.line = line
        self.column = column


class InterlockError(RgseError):
    """The interlock refused a program or tripped during a plan."""
