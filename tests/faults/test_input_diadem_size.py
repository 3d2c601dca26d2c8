"""Finding 3 of #12: a data file's size is checked against its header before it is read, and reading is bounded.

A 2 GB sparse ``.r64`` (``truncate``: no disk space, reads as zeros) behind a 40-sample header used to be read
whole (8.3 s, 2.2 GB) before the count mismatch was found. The proof that it is no longer read is the kernel's own
count of bytes this process read (``rchar`` in ``/proc/self/io``), not a clock.
"""

from __future__ import annotations

import os
import shutil
import tracemalloc
from pathlib import Path

import pytest

from rgse_daemon.cli import main
from rgse_daemon.errors import DataError
from rgse_daemon.trace.diadem import MAX_DATA_BYTES, read_trace_file, read_trace_set
from tests.support.campaign import write_campaign, write_measurement
from tests.support.tracehelpers import edit_channel, write_small_set

TWO_GB = 2 * 1024**3
WIDTH = 7  # channels of a drive module in write_small_set


def bytes_read() -> int:
    """Bytes this process has read through read(2) and friends so far (Linux ``/proc/self/io``)."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("rchar:"):
            return int(line.split()[1])
    raise AssertionError("/proc/self/io has no rchar")


def sparse(path: Path, size: int) -> None:
    with open(path, "r+b" if path.exists() else "wb") as f:
        f.truncate(size)


def refused_without_reading(fn, match: str) -> None:
    tracemalloc.start()
    try:
        before = bytes_read()
        with pytest.raises(DataError, match=match):
            fn()
        read = bytes_read() - before
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert read < 1024**2, f"{read} bytes read"
    assert peak < 64 * 1024**2, f"peak {peak} bytes allocated"


def test_sparse_2gb_data_file_behind_a_small_header_is_not_read(tmp_path):
    write_small_set(tmp_path)
    r64 = tmp_path / "run1_NextGenDrive#3.r64"
    sparse(r64, TWO_GB)
    refused_without_reading(lambda: read_trace_file(tmp_path / "run1_NextGenDrive#3.dat"),
                            r"run1_NextGenDrive#3\.r64: data file of 2147483648 bytes exceeds")


def test_header_that_announces_2gb_is_refused_before_reading(tmp_path):
    """Header and file agree on 2 GB: still refused, the count (code 220) is beyond any controller's buffer."""
    write_small_set(tmp_path)
    dat, r64 = tmp_path / "run1_NextGenDrive#3.dat", tmp_path / "run1_NextGenDrive#3.r64"
    rows = TWO_GB // (8 * WIDTH)
    text = dat.read_bytes().decode("iso-8859-1").replace("220,40\r\n", f"220,{rows}\r\n")
    dat.write_bytes(text.encode("iso-8859-1"))
    sparse(r64, rows * WIDTH * 8)
    refused_without_reading(lambda: read_trace_set(tmp_path, "run1"), r"NextGenDrive#3\.r64: .*exceeds")


def test_size_mismatch_below_the_cap_is_found_before_reading(tmp_path):
    """A file that fits the cap but not its header: refused naming the count, nothing read."""
    write_small_set(tmp_path)
    r64 = tmp_path / "run1_NextGenDrive#3.r64"
    sparse(r64, (MAX_DATA_BYTES // (8 * WIDTH)) * 8 * WIDTH)
    refused_without_reading(lambda: read_trace_file(tmp_path / "run1_NextGenDrive#3.dat"),
                            r"header count \(code 220\) 40 disagrees with the data")


def test_channel_storage_size_mismatch_is_found_before_reading(tmp_path):
    write_small_set(tmp_path, storage="CHANNEL")
    edit_channel(tmp_path / "run1_NextGenDrive#5.dat", "Istmoment", 220, "40")  # unchanged: a valid header
    r64 = tmp_path / "run1_NextGenDrive#5.r64"
    sparse(r64, 200 * 1024**2)
    refused_without_reading(lambda: read_trace_file(tmp_path / "run1_NextGenDrive#5.dat"),
                            r"header counts \(code 220\) add up to 280 values")


def test_rgse_mass_refuses_a_sparse_2gb_trace_in_one_line(tmp_path, capsys):
    write_campaign(tmp_path / "cal", seed=5, n_samples=300)
    assert main(["calibrate", "--campaign", str(tmp_path / "cal"), "--out", str(tmp_path / "CAL.json"),
                 "--method", "gain-linear"]) == 0
    write_measurement(tmp_path / "dut", 100.0, seed=6, n_samples=300, n_loops=2)
    sparse(tmp_path / "dut" / "dut_l02_NextGenDrive#5.r64", TWO_GB)
    capsys.readouterr()
    before = bytes_read()
    assert main(["mass", "--traces", str(tmp_path / "dut"), "--calibration", str(tmp_path / "CAL.json")]) == 2
    assert bytes_read() - before < 16 * 1024**2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "dut_l02_NextGenDrive#5.r64" in err and "exceeds" in err, err
    assert os.path.getsize(tmp_path / "dut" / "dut_l02_NextGenDrive#5.r64") == TWO_GB  # raw data untouched


def test_a_real_trace_still_reads(tmp_path):
    write_small_set(tmp_path)
    shutil.copy(tmp_path / "run1_NextGenDrive#3.r64", tmp_path / "copy.r64")
    ts = read_trace_set(tmp_path, "run1")
    assert ts.channel("NextGenDrive#3", "Istmoment").values.size == 40
