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


def drift_prior(text: str) -> float:
    """An argparse type: a bound on the thermal drift coefficient |β| (1/K), as ``measurement.drift_prior_per_k``
    takes it: > 0 and at most :data:`rgse_daemon.config.MAX_DRIFT_PRIOR_PER_K`."""
    from rgse_daemon.config import MAX_DRIFT_PRIOR_PER_K

    value = finite(text)
    if not 0.0 < value <= MAX_DRIFT_PRIOR_PER_K:
        raise argparse.ArgumentTypeError(f"a bound on |β| must lie in (0, {MAX_DRIFT_PRIOR_PER_K:g}] per K, "
                                         f"got {text!r}")
    return value


def add_drift_prior(p: argparse.ArgumentParser, what: str) -> None:
    """``--drift-prior PER_K`` (the daemon's ``measurement.drift_prior_per_k``, default 0.3 %/K): ``what`` says what
    it bounds in this command."""
    from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K

    p.add_argument("--drift-prior", type=drift_prior, default=DRIFT_PRIOR_PER_K, metavar="PER_K",
                   help=f"outer bound on the thermal drift coefficient |β| (1/K): {what} (default "
                        f"{DRIFT_PRIOR_PER_K:g}, i.e. {100 * DRIFT_PRIOR_PER_K:g} %%/K; the daemon's "
                        f"measurement.drift_prior_per_k)")


def add_json(p: argparse.ArgumentParser | argparse._MutuallyExclusiveGroup) -> None:
    """``--json``: the one JSON object a command prints instead of its text."""
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
