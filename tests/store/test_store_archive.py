"""The raw-file archive: durable copy, verification, never overwriting."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rgse_daemon.store import (
    ArchiveConflict,
    ArchiveError,
    archive_file,
    archive_file_async,
    archive_root,
    discard_partial_copies,
    file_digest,
    relative_path,
    verify_file,
)


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def _leftovers(run_dir: Path) -> list[str]:
    return sorted(p.name for p in run_dir.iterdir() if p.name.startswith("."))


def test_archive_copies_and_reports_hash_and_size(tmp_path: Path) -> None:
    data = os.urandom(300_000)
    src = _write(tmp_path / "share" / "dut_l01_NextGenDrive#3.r64", data)
    run_dir = archive_root(tmp_path / "data") / "runs" / "r1"  # created, with its parents

    digest = hashlib.sha256(data).hexdigest()
    path, sha, size = archive_file(src, run_dir, expected_size=len(data), expected_sha256=digest)

    assert path == run_dir / src.name
    assert path.read_bytes() == data
    assert (sha, size) == (hashlib.sha256(data).hexdigest(), len(data))
    assert src.read_bytes() == data  # the source is untouched: the daemon deletes it only after this returned
    assert _leftovers(run_dir) == []
    assert relative_path(path, archive_root(tmp_path / "data")) == f"runs/r1/{src.name}"


def test_archiving_the_identical_file_again_is_idempotent(tmp_path: Path) -> None:
    src = _write(tmp_path / "share" / "t.dat", b"header\n")
    first = archive_file(src, tmp_path / "run")
    again = archive_file(src, tmp_path / "run", expected_size=7)
    assert again == first
    assert _leftovers(tmp_path / "run") == []


def test_a_different_file_with_the_same_name_is_refused_and_nothing_is_overwritten(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    archive_file(_write(tmp_path / "a" / "t.r64", b"\x01" * 64), run_dir)
    other = _write(tmp_path / "b" / "t.r64", b"\x02" * 64)

    with pytest.raises(ArchiveConflict, match=r"t\.r64: already archived with different content"):
        archive_file(other, run_dir)

    assert (run_dir / "t.r64").read_bytes() == b"\x01" * 64
    assert _leftovers(run_dir) == []


def test_a_short_copy_is_detected_and_not_archived(tmp_path: Path) -> None:
    # The controller said 4096 bytes; the file on the share is truncated (still being written, or a lost write).
    src = _write(tmp_path / "share" / "t.r64", b"\x00" * 4000)
    with pytest.raises(ArchiveError, match=r"t\.r64: 4000 bytes, expected 4096 \(short or truncated copy\)"):
        archive_file(src, tmp_path / "run", expected_size=4096)
    assert not (tmp_path / "run" / "t.r64").exists()
    assert _leftovers(tmp_path / "run") == []
    assert src.stat().st_size == 4000  # the source is kept for a retry


def test_a_corrupted_copy_is_detected_by_its_hash(tmp_path: Path) -> None:
    good = b"0123456789" * 100
    corrupted = bytearray(good)
    corrupted[500] ^= 0x40
    src = _write(tmp_path / "share" / "t.r64", bytes(corrupted))
    with pytest.raises(ArchiveError, match=r"corrupted copy"):
        archive_file(src, tmp_path / "run", expected_size=len(good), expected_sha256=hashlib.sha256(good).hexdigest())
    assert not (tmp_path / "run" / "t.r64").exists()
    assert _leftovers(tmp_path / "run") == []


def test_bad_sources_and_arguments_are_typed_errors_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(ArchiveError, match=r"missing\.r64: cannot read"):
        archive_file(tmp_path / "missing.r64", tmp_path / "run")
    (tmp_path / "adir").mkdir()
    with pytest.raises(ArchiveError, match=r"adir: not a regular file"):
        archive_file(tmp_path / "adir", tmp_path / "run")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(ArchiveError, match=r"pipe: not a regular file"):
        archive_file(fifo, tmp_path / "run")
    src = _write(tmp_path / "t.dat", b"x")
    with pytest.raises(ArchiveError, match=r"expected_sha256 'abc'"):
        archive_file(src, tmp_path / "run", expected_sha256="abc")
    with pytest.raises(ArchiveError, match=r"expected_size -1"):
        archive_file(src, tmp_path / "run", expected_size=-1)
    _write(tmp_path / "notadir", b"")
    with pytest.raises(ArchiveError, match=r"notadir"):
        archive_file(src, tmp_path / "notadir" / "run")


def test_verify_file_detects_later_corruption_and_truncation(tmp_path: Path) -> None:
    src = _write(tmp_path / "share" / "t.r64", os.urandom(2048))
    path, sha, size = archive_file(src, tmp_path / "run")
    verify_file(path, sha, size)

    data = bytearray(path.read_bytes())
    data[100] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(ArchiveError, match=r"file corrupted"):
        verify_file(path, sha, size)
    # Re-archiving the good original does not "repair" by overwriting: a conflict, for a human to look at.
    with pytest.raises(ArchiveConflict):
        archive_file(src, tmp_path / "run")

    path.write_bytes(bytes(data[:1000]))
    with pytest.raises(ArchiveError, match=r"1000 bytes on disk, 2048 recorded"):
        verify_file(path, sha, size)


def test_partial_copies_left_by_a_crash_are_discarded_but_archived_files_kept(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    path, _, _ = archive_file(_write(tmp_path / "t.dat", b"keep"), run_dir)
    stale = _write(run_dir / ".rgse-part-abc123", b"half a cop")
    assert discard_partial_copies(run_dir) == [stale]
    assert not stale.exists()
    assert path.read_bytes() == b"keep"


def test_relative_path_refuses_files_outside_the_archive(tmp_path: Path) -> None:
    with pytest.raises(ArchiveError, match="not inside the archive"):
        relative_path(tmp_path / "elsewhere" / "x", tmp_path / "archive")


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=5000), name=st.from_regex(r"[A-Za-z0-9_#]{1,20}\.(dat|r64)", fullmatch=True))
def test_archive_round_trip_property(tmp_path: Path, data: bytes, name: str) -> None:
    src = _write(tmp_path / "src" / name, data)
    run_dir = tmp_path / "runs" / hashlib.sha256(data + name.encode()).hexdigest()[:16]
    path, sha, size = archive_file(src, run_dir, expected_size=len(data))
    assert path.read_bytes() == data
    assert file_digest(path) == (sha, size) == (hashlib.sha256(data).hexdigest(), len(data))
    assert archive_file(src, run_dir) == (path, sha, size)


async def test_async_archive_runs_off_the_loop_with_the_same_checks(tmp_path: Path) -> None:
    src = _write(tmp_path / "share" / "t.r64", b"abc" * 1000)
    path, sha, size = await archive_file_async(src, tmp_path / "run", expected_size=3000, timeout_s=30)
    assert path.read_bytes() == src.read_bytes() and size == 3000 and sha == hashlib.sha256(b"abc" * 1000).hexdigest()
    with pytest.raises(ArchiveError, match="short or truncated"):
        await archive_file_async(src, tmp_path / "run2", expected_size=3001, timeout_s=30)
