"""``rgse report RUN_ID | --calibration ID [--out DIR] [--config FILE]``: the HTML report of a measurement run or
of a calibration, from the configured store (see :mod:`rgse_daemon.report`). Prints the path written.

Also runnable as ``python -m rgse_daemon.commands.report`` with the same arguments.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rgse_daemon.commands import absent_store, config_hint
from rgse_daemon.config import Config, load_config
from rgse_daemon.errors import ConfigError, DataError, RgseError
from rgse_daemon.report import build_report
from rgse_daemon.store import NotFound, Repository


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse report`` (also used by ``python -m``)."""
    p.add_argument("run_id", nargs="?", metavar="RUN_ID", help="a measurement run")
    p.add_argument("--calibration", metavar="ID", help="report a calibration instead of a run")
    p.add_argument("--out", type=Path, metavar="DIR", help="directory for the HTML file (default <data_dir>/reports)")
    p.add_argument("--config", type=Path, metavar="FILE")


def write(cfg: Config, *, run_id: str | None = None, calibration_id: str | None = None,
          out_dir: Path | None = None, config_path: Path | None = None) -> Path:
    """Write the report of ``run_id`` or ``calibration_id`` from ``cfg``'s store; returns the HTML file's path.

    A run or calibration not in the store is a :class:`DataError` naming the store searched (and, without
    ``config_path``, suggesting ``--config``); a SQLite store that does not exist is not created for that.
    """
    if (run_id is None) == (calibration_id is None):
        raise DataError("give either RUN_ID or --calibration ID")
    data_dir = cfg.paths.data_dir
    absent = absent_store(cfg, f"run {run_id!r}" if run_id is not None else f"calibration {calibration_id!r}",
                          config_path)
    if absent is not None:
        raise absent
    hint = config_hint(config_path)
    with Repository.open(cfg.store.url, data_dir) as repo:
        try:
            if run_id is not None:
                repo.get_run(run_id)
            else:
                repo.get_calibration(calibration_id or "")
        except NotFound as exc:
            raise DataError(f"{exc} in the {repo.description}{hint}") from exc
        return build_report(repo, data_dir, out_dir if out_dir is not None else data_dir / "reports",
                            run_id=run_id, calibration_id=calibration_id)


def run(args: argparse.Namespace) -> int:
    print(write(load_config(args.config), run_id=args.run_id, calibration_id=args.calibration, out_dir=args.out,
                config_path=args.config))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rgse_daemon.commands.report", description=__doc__)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except (ConfigError, DataError) as exc:
        print(f"rgse report: error: {exc}", file=sys.stderr)
        return 2
    except RgseError as exc:
        print(f"rgse report: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
