"""Every kind of bad trace input gives a DataError that names the file and the problem; nothing is modified."""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.errors import DataError
from rgse_daemon.trace import read_trace_file, read_trace_set
from tests.support.tracehelpers import edit_channel, write_small_set

DAT = "run1_NextGenDrive#3.dat"
R64 = "run1_NextGenDrive#3.r64"
N = 40  # samples written by write_small_set
WIDTH = 7  # drive channels per row


def _append_values(path: Path, values: list[float]) -> None:
    with open(path, "ab") as f:
        np.asarray(values, dtype="<f8").tofile(f)


def _append_bytes(path: Path, data: bytes) -> None:
    with open(path, "ab") as f:
        f.write(data)


def _drop_zeit_block(directory: Path) -> None:
    path = directory / DAT
    text = path.read_bytes().decode("iso-8859-1")
    start = text.index("#BEGINCHANNELHEADER\r\n200,Zeit")
    end = text.index("#ENDCHANNELHEADER", start) + len("#ENDCHANNELHEADER")
    path.write_bytes((text[:start] + text[end:]).encode("iso-8859-1"))


def _poke(path: Path, index: int, value: float) -> None:
    raw = np.fromfile(path, dtype="<f8")
    raw[index] = value
    raw.tofile(path)


def _replace_header_text(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_bytes().decode("iso-8859-1")
    assert old in text
    path.write_bytes(text.replace(old, new, count).encode("iso-8859-1"))


CASES: dict[str, tuple[Callable[[Path], None], str, str]] = {
    # name: (damage, file the message must name, problem in the message)
    "missing r64": (lambda d: (d / R64).unlink(), DAT, "not found"),
    "211 names a missing file": (lambda d: edit_channel(d / DAT, "Istmoment", 211, "other.r64"), DAT, "'other.r64'"),
    "211 names the header": (lambda d: edit_channel(d / DAT, "Istmoment", 211, DAT), DAT, "names the header itself"),
    "211 too long for the file system": (
        lambda d: edit_channel(d / DAT, "Istmoment", 211, "x" * 300 + ".r64"), DAT, "File name too long",
    ),
    "211 missing": (lambda d: edit_channel(d / DAT, "Istmoment", 211, None), DAT, "no code 211"),
    "size not multiple of 8": (lambda d: _append_bytes(d / R64, b"abc"), R64, "not a multiple of 8"),
    "size not multiple of row": (lambda d: _append_values(d / R64, [1.0, 2.0]), R64, "multiple of the row width"),
    "extra whole row": (lambda d: _append_values(d / R64, [1.0] * WIDTH), R64, "disagrees with the data"),
    "count too small everywhere": (
        lambda d: _replace_header_text(d / DAT, f"220,{N}", f"220,{N - 1}", count=-1),
        R64,
        "disagrees with the data",
    ),
    "counts differ in block": (lambda d: edit_channel(d / DAT, "Iststrom", 220, "39"), R64, "different counts"),
    "time count differs": (lambda d: edit_channel(d / DAT, "Zeit", 220, "41"), DAT, "time channel 'Zeit' has 41"),
    "overflow by factor": (
        lambda d: (_poke(d / R64, 0, 1e308), edit_channel(d / DAT, "Sollposition", 241, "10.0")),
        R64,
        "non-finite",
    ),
    "REAL32": (lambda d: edit_channel(d / DAT, "Istmoment", 214, "REAL32"), DAT, "unsupported data type"),
    "INT16": (lambda d: edit_channel(d / DAT, "Istmoment", 214, "INT16"), DAT, "unsupported data type"),
    "zero time step": (lambda d: edit_channel(d / DAT, "Zeit", 241, "0"), DAT, "non-positive step"),
    "negative time step": (lambda d: edit_channel(d / DAT, "Zeit", 241, "-0.012"), DAT, "non-positive step"),
    "time step not a number": (lambda d: edit_channel(d / DAT, "Zeit", 241, "0,012"), DAT, "not a number"),
    "time step with a digit separator": (lambda d: edit_channel(d / DAT, "Zeit", 241, "0_012"), DAT, "not a number"),
    "factor with a digit separator": (lambda d: edit_channel(d / DAT, "Istmoment", 241, "1_000"), DAT, "not a number"),
    "time step nan": (lambda d: edit_channel(d / DAT, "Zeit", 241, "nan"), DAT, "not finite"),
    "time overflows": (lambda d: edit_channel(d / DAT, "Zeit", 241, "1e307"), DAT, "overflow"),
    "time channel explicit without data file": (
        lambda d: edit_channel(d / DAT, "Zeit", 210, "EXPLIZIT"),
        DAT,
        "'Zeit' has no code 211",
    ),
    "no time channel": (_drop_zeit_block, DAT, "no time channel"),
    "bad 210": (lambda d: edit_channel(d / DAT, "Istmoment", 210, "MAYBE"), DAT, "IMPLIZIT or EXPLIZIT"),
    "bad storage": (lambda d: edit_channel(d / DAT, "Istmoment", 213, "ROWS"), DAT, "BLOCK or CHANNEL"),
    "mixed storage": (lambda d: edit_channel(d / DAT, "Istmoment", 213, "CHANNEL"), R64, "mix BLOCK and CHANNEL"),
    "pointer out of range": (lambda d: edit_channel(d / DAT, "Istmoment", 221, "9"), R64, "not 1..7"),
    "pointer twice": (lambda d: edit_channel(d / DAT, "Istmoment", 221, "1"), R64, "not 1..7"),
    "pointer zero": (lambda d: edit_channel(d / DAT, "Istmoment", 221, "0"), DAT, "below 1"),
    "count not integer": (lambda d: edit_channel(d / DAT, "Istmoment", 220, "40.0"), DAT, "not an integer"),
    # more than the 4300 digits int() converts (it raises a plain ValueError)
    "count of 5000 digits": (lambda d: edit_channel(d / DAT, "Istmoment", 220, "9" * 5000), DAT, "out of range"),
    "pointer of 5000 digits": (lambda d: edit_channel(d / DAT, "Istmoment", 221, "1" * 5000), DAT, "out of range"),
    "no name": (lambda d: edit_channel(d / DAT, "Istmoment", 200, None), DAT, "no code 200"),
    "duplicate name": (lambda d: edit_channel(d / DAT, "Iststrom", 200, "Istmoment"), DAT, "given twice"),
    "duplicate code": (
        lambda d: _replace_header_text(d / DAT, "202,Nm\r\n", "202,Nm\r\n202,Nm\r\n"),
        DAT,
        "code 202 given twice",
    ),
    "truncated header": (
        lambda d: (d / DAT).write_bytes((d / DAT).read_bytes()[: len((d / DAT).read_bytes()) // 2]),
        DAT,
        "truncated header",
    ),
    "garbled line": (lambda d: _replace_header_text(d / DAT, "202,Nm", "202 Nm"), DAT, "'code,value'"),
    "garbled block marker": (
        lambda d: _replace_header_text(d / DAT, "#ENDCHANNELHEADER\r\n\r\n#BEGIN", "#ENDCHANNELHEADER\r\n\r\nBEGIN"),
        DAT,
        "expected #BEGINCHANNELHEADER",
    ),
    "no global header": (
        lambda d: _replace_header_text(d / DAT, "#BEGINGLOBALHEADER", "#GLOBALHEADER"),
        DAT,
        "expected #BEGINGLOBALHEADER",
    ),
    "binary garbage": (lambda d: (d / DAT).write_bytes(b"\x00\x01\x02" * 100), DAT, "NUL bytes"),
    "empty header": (lambda d: (d / DAT).write_bytes(b""), DAT, "truncated header"),
    "header without channels": (
        lambda d: (d / DAT).write_bytes(b"#BEGINGLOBALHEADER\r\n1,x\r\n#ENDGLOBALHEADER\r\n"),
        DAT,
        "no channel blocks",
    ),
    "missing dat": (lambda d: (d / DAT).unlink(), DAT, "not found"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_gives_data_error_naming_file(tmp_path: Path, case: str) -> None:
    damage, file_name, problem = CASES[case]
    write_small_set(tmp_path)
    damage(tmp_path)
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in tmp_path.iterdir()}
    with pytest.raises(DataError) as info:
        read_trace_file(tmp_path / DAT)
    message = str(info.value)
    assert str(tmp_path / file_name) in message or (file_name == R64 and f"{tmp_path / DAT}" in message), message
    assert re.search(problem, message), message
    with pytest.raises(DataError):
        read_trace_set(tmp_path, "run1", modules=["NextGenDrive#3"])
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("marker", [9.9e34, float("nan"), float("-inf")], ids=["novalue", "nan", "inf"])
def test_missing_samples_read_as_nan_in_every_channel_alike(tmp_path: Path, marker: float) -> None:
    """DIAdem's no-value marker (global header code 111, 9.9e34 as KUKA writes it) and a raw NaN/inf are missing
    samples: NaN in whichever channel they sit, counted, never a refusal of the file (issue 33)."""
    write_small_set(tmp_path)
    clean = read_trace_file(tmp_path / DAT)
    names = [n for n in clean.channels if n != clean.time_channel]
    assert len(names) == WIDTH and "111" not in "".join(names)
    for column, name in enumerate(names):
        d = tmp_path / name
        write_small_set(d)
        pointer = int(clean.channels[name].header[221])
        _poke(d / R64, 5 * WIDTH + pointer - 1, marker)
        tf = read_trace_file(d / DAT)
        values = tf.channel(name).values
        assert np.isnan(values[5]) and tf.channel(name).n_missing == 1, (column, name)
        np.testing.assert_array_equal(np.delete(values, 5), np.delete(clean.channel(name).values, 5))
        assert all(tf.channel(other).n_missing == 0 for other in names if other != name)


def test_a_marker_other_than_the_declared_one_is_a_value(tmp_path: Path) -> None:
    write_small_set(tmp_path)
    _replace_header_text(tmp_path / DAT, "111,9.900000e+034", "111,-1.0e+30")
    _poke(tmp_path / R64, 3, 9.9e34)
    assert read_trace_file(tmp_path / DAT).channel("Istmoment").n_missing + sum(
        c.n_missing for c in read_trace_file(tmp_path / DAT).channels.values()) == 0


def test_channel_storage_counts_must_tile_the_file(tmp_path: Path) -> None:
    write_small_set(tmp_path, storage="CHANNEL")
    dat = tmp_path / DAT
    edit_channel(dat, "Istmoment", 221, str(5 * N + 2))
    with pytest.raises(DataError, match=r"NextGenDrive#3\.r64.*'Istmoment' starts at value 202, expected 201"):
        read_trace_file(dat)
    edit_channel(dat, "Istmoment", 221, str(5 * N + 1))
    read_trace_file(dat)
    _append_values(tmp_path / R64, [0.0] * 3)
    with pytest.raises(DataError, match=r"NextGenDrive#3\.r64.*add up to 280 values, data has 283"):
        read_trace_file(dat)


def test_block_with_pointer_permutation_is_fine(tmp_path: Path) -> None:
    """Swapping two pointers swaps the channels' data; a valid permutation is read, not refused."""
    modules = write_small_set(tmp_path)
    edit_channel(tmp_path / DAT, "Istmoment", 221, "7")
    edit_channel(tmp_path / DAT, "Iststrom", 221, "6")
    tf = read_trace_file(tmp_path / DAT)
    np.testing.assert_allclose(tf.channel("Istmoment").values, modules["NextGenDrive#3"]["Iststrom"][0], rtol=1e-12)
