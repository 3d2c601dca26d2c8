"""Link-specific refinements of :class:`~rgse_daemon.errors.LinkError`."""

from __future__ import annotations

from rgse_daemon.errors import LinkError


class CommandError(LinkError):
    """The controller refused a command (program control, file operation, confirm) with a C3 Bridge error code."""

    def __init__(self, what: str, message: str, code: int | None = None) -> None:
        super().__init__(f"{what}: {message}" + ("" if code is None else f" (code {code})"))
        self.what = what
        self.code = code


class NotSupportedError(LinkError):
    """The connected server cannot do this (e.g. program control over plain KUKAVARPROXY)."""
