"""Trace names are plain names: one file-name component, never a path.

A trace name (``dut_l01``) comes from outside — a manifest, a CAL.json, an MQTT command, the controller's
directory listing — and is joined to a directory to find ``<name>_<module>.dat``. A separator, ``..``, an
absolute or drive path, or a control character would let it read (or write) beside the directory instead of in
it, so :func:`plain_name` refuses them, naming the field and the problem. :func:`inside` refuses a file that is
a symbolic link leading out of its directory (a ``.r64`` linked to ``/etc/passwd``).
"""

from __future__ import annotations

import os
from pathlib import Path

from rgse_daemon.errors import DataError

#: Longest accepted name; the store's identifiers hold 128 characters.
MAX_NAME_CHARS = 128


def name_problem(value: object) -> str | None:
    """Why ``value`` is not a plain name, or None if it is one."""
    if not isinstance(value, str):
        return f"must be a string, got {type(value).__name__}"
    if not value:
        return "is empty"
    if len(value) > MAX_NAME_CHARS:
        return f"is longer than {MAX_NAME_CHARS} characters"
    if any(ord(c) < 0x20 or ord(c) == 0x7F for c in value):
        return "contains a control character"
    if value.startswith(("/", "\\")) or (len(value) >= 2 and value[1] == ":"):
        return "is an absolute path, expected a plain name"
    if "/" in value or "\\" in value:
        return "contains a path separator, expected a plain name"
    if value in (".", ".."):
        return "is a directory reference, expected a plain name"
    if ":" in value:
        return "contains ':', expected a plain name"
    return None


def plain_name(value: object, field: str) -> str:
    """``value`` if it is a plain name; DataError naming ``field`` and the problem otherwise."""
    problem = name_problem(value)
    if problem is not None:
        raise DataError(f"{field}: {value!r} {problem}")
    assert isinstance(value, str)
    return value


def inside(directory: Path, path: Path) -> Path:
    """``path`` if it resolves (following symbolic links) to a place inside ``directory``; DataError naming the
    file otherwise (a link that leaves the directory is refused, one that stays inside is followed)."""
    real_dir = Path(os.path.realpath(directory))
    real = Path(os.path.realpath(path))
    if real != real_dir and real_dir not in real.parents:
        raise DataError(f"{path}: symbolic link leads out of {directory} (to {real}); refused")
    return path
