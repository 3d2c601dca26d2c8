"""The one durable-write helper: whole file or nothing, the permissions of a plain open, no temporary left over."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon.durable import write_atomic


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
    calfile.write(target, {"a": 1})
    inode = target.stat().st_ino
    calfile.write(target, {"a": 2})
    assert target.read_text() == '{\n  "a": 2\n}\n'
    assert target.stat().st_ino != inode  # a new file renamed over the old one, never rewritten in place
