"""The reader's digests: BLAKE3 beside SHA-256, each equal to the digest of the file's bytes as they lie on disk."""

from __future__ import annotations

import hashlib
from pathlib import Path

import blake3
import numpy as np
import pytest

from rgse_daemon.trace import read_trace_set
from simulators.krc4.tracefiles import write_trace_set


def _trace(tmp_path: Path, storage: str = "BLOCK") -> Path:
    rng = np.random.default_rng(3)
    modules = {f"NextGenDrive#{k}": {"Istmoment": (rng.standard_normal(5000), "Nm"),
                                     "Motortemperatur": (300.0 + rng.standard_normal(5000), "K")} for k in (3, 5)}
    write_trace_set(tmp_path, "dig", 0.012, modules, storage=storage)
    return tmp_path


@pytest.mark.parametrize("storage", ["BLOCK", "CHANNEL"])
def test_blake3_and_sha256_are_the_files_own(tmp_path: Path, storage: str):
    d = _trace(tmp_path, storage)
    both = read_trace_set(d, "dig", with_blake3=True)
    files = sorted(set(both.sha256))
    assert files == sorted(set(both.blake3)) and len(files) == 4  # two modules, .dat and .r64 each
    for name in files:
        data = (d / name).read_bytes()
        assert both.sha256[name] == hashlib.sha256(data).hexdigest()
        assert both.blake3[name] == blake3.blake3(data).hexdigest()
    # the default stays SHA-256 only (what the archive records); BLAKE3 alone leaves SHA-256 empty
    default = read_trace_set(d, "dig")
    assert default.sha256 == both.sha256 and default.blake3 == {}
    fast = read_trace_set(d, "dig", with_sha256=False, with_blake3=True)
    assert fast.sha256 == {} and fast.blake3 == both.blake3
    # and the values read are the same whichever digests were taken
    for module in both.files:
        assert np.array_equal(fast.channel(module, "Istmoment").values, default.channel(module, "Istmoment").values)


def test_a_changed_byte_changes_the_blake3(tmp_path: Path):
    d = _trace(tmp_path)
    before = read_trace_set(d, "dig", with_blake3=True).blake3
    r64 = next(p for p in d.iterdir() if p.name.endswith("#3.r64"))
    raw = bytearray(r64.read_bytes())
    raw[100] ^= 0x01
    r64.write_bytes(bytes(raw))
    after = read_trace_set(d, "dig", with_blake3=True).blake3
    assert after[r64.name] != before[r64.name]
    assert {k: v for k, v in after.items() if k != r64.name} == {k: v for k, v in before.items() if k != r64.name}
