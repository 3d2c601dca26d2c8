"""The one durable-write helper: whole file or nothing, the permissions of a plain open, no temporary left over."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon import calfile
from rgse_daemon.durable import write_atomic
from rgse_daemon.pipeline.calibration import Calibration, PolyK


def linear_calibration() -> Calibration:
    return Calibration("axis-linear", PolyK(np.array([1.0])), PolyK(np.array([1.0])), np.eye(2), (0.0, 1.0),
                       (0.0, 1.0), 9.81, 1.0)


def test_writes_text_and_bytes_with_the_mode_of_a_plain_open(tmp_path: Path) -> None:
    umask = os.umask(0o022)
    try:
        write_atomic(tmp_path / "sub" / "a.txt", "zwölf\n")
        write_atomic(tmp_path / "b.bin", b"\x00\x01")
    finally:
        os.umask(umask)
    assert (tmp_path / "sub" / "a.txt").read_text(encoding="utf-8") == "zwölf\n"
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert (tmp_path / "b.bin").stat().st_mode & 0o777 == 0o644
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "b.bin", "sub"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "CAL.json"
    write_atomic(target, "old")
    with pytest.raises(TypeError):
        write_atomic(target, 12345)  # type: ignore[arg-type]  # fails inside the write, after the temp file exists
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["CAL.json"]


def test_calfile_write_replaces_atomically(tmp_path: Path) -> None:
    target = tmp_path / "CAL.json"
    first = calfile.sealed(calfile.CalFile("R", linear_calibration(), calfile.Bias(0.0, 0.0),
                                           calfile.Fit(1.0, 1.0, 1.0)))
    calfile.write(target, first)
    inode = target.stat().st_ino
    second = calfile.sealed(dataclasses.replace(first, bias=calfile.Bias(1.0, 2.0)))
    calfile.write(target, second)
    assert target.read_text() == json.dumps(second.to_dict(), indent=2) + "\n"
    assert target.stat().st_ino != inode  # a new file renamed over the old one, never rewritten in place
