"""One module per ``rgse`` sub-command, each with ``add_arguments(parser)`` and ``run(args: argparse.Namespace) ->
int``; and what several share."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rgse_daemon.config import Config
    from rgse_daemon.errors import DataError


def config_hint(config_path: Path | None) -> str:
    """What to add to "not found in the store" when no ``--config`` was given: the store searched is the default
    configuration's."""
    return "" if config_path is not None else (
        " (no --config given, so this is the default configuration's store; name the daemon's configuration "
        "with --config FILE)")


def absent_store(cfg: Config, what: str, config_path: Path | None) -> DataError | None:
    """The error to raise for ``what`` (``run 'X'``) when ``cfg`` names a SQLite store that does not exist, else None.

    A command that looks something up checks this first: opening the store would create an empty database (and its
    data directory) just to say that it holds nothing — on a wrong ``--config`` or in the wrong directory."""
    from rgse_daemon.errors import DataError
    from rgse_daemon.store import describe_store, sqlite_path

    db_file = sqlite_path(cfg.store.url, cfg.paths.data_dir)
    if db_file is None or db_file.exists():
        return None
    return DataError(f"{what}: not found: the {describe_store(cfg.store.url, cfg.paths.data_dir)} does not exist"
                     f"{config_hint(config_path)}")


def finite(text: str) -> float:
    """An argparse type: a finite number (``nan``/``inf`` are refused as such)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive(text: str) -> float:
    """An argparse type: a finite number > 0 (a timeout, a time scale)."""
    value = finite(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def add_json(p: argparse.ArgumentParser | argparse._MutuallyExclusiveGroup) -> None:
    """``--json``: the one JSON object a command prints instead of its text."""
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
