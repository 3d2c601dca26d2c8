"""Helpers of the CLI-level input tests: a fitted campaign with a DuT, and the one-line error of a refused command."""

from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon.cli import main
from tests.support.campaign import write_campaign, write_measurement


def fitted_dirs(root: Path, method: str, n_samples: int = 300) -> Path:
    """``root/cal`` (a Table-1-like campaign), ``root/dut`` (a 100 kg DuT, 3 loops) and ``root/CAL.json`` fitted
    by ``rgse calibrate --method method``."""
    write_campaign(root / "cal", seed=5, n_samples=n_samples)
    write_measurement(root / "dut", 100.0, seed=6, n_samples=n_samples, n_loops=3)
    assert main(["calibrate", "--campaign", str(root / "cal"), "--out", str(root / "CAL.json"),
                 "--method", method]) == 0
    return root


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """``rgse argv`` exits 2 with one line on stderr and no traceback; returns that line."""
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err
