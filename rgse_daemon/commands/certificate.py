"""``rgse certificate RUN_ID [--out FILE.pdf] [--config FILE]``: the one-page PDF measurement certificate of a run's
result (:mod:`rgse_daemon.report.certificate`), from the configured store. Prints the path written."""

from __future__ import annotations

import argparse
from pathlib import Path

from rgse_daemon.commands import absent_store
from rgse_daemon.config import load_config
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import EXIT_OK, DataError
from rgse_daemon.report.certificate import certificate_pdf, load
from rgse_daemon.store import Repository


def write(config_path: Path | None, run_id: str, out: Path | None) -> Path:
    cfg = load_config(config_path)
    absent = absent_store(cfg, f"run {run_id!r}", config_path)
    if absent is not None:
        raise absent
    with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
        pdf = certificate_pdf(load(repo, run_id))
    path = out if out is not None else cfg.paths.data_dir / "reports" / f"certificate-{run_id}.pdf"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, pdf)
    except OSError as exc:
        raise DataError(f"{path}: cannot write the certificate: {exc.strerror or exc}") from exc
    return path


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse certificate``."""
    p.add_argument("run_id", metavar="RUN_ID")
    p.add_argument("--out", type=Path, metavar="FILE.pdf",
                   help="where to write it (default <data_dir>/reports/certificate-RUN_ID.pdf)")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its store)")


def run(args: argparse.Namespace) -> int:
    print(write(getattr(args, "config", None), args.run_id, args.out))
    return EXIT_OK
