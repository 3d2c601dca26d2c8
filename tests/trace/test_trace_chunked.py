"""The chunked read (issue 35, item 5): digests taken chunk by chunk equal those of the whole file, and the values,
missing-sample counts and refusals equal a sample-by-sample reading, wherever the chunk boundaries fall.

``diadem.CHUNK_BYTES`` is made small so that a 200-sample file spans many chunks, with boundaries in the middle of
a row (BLOCK) or of a channel (CHANNEL) and, for sizes that are not a multiple of 8, in the middle of a value.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import blake3
import numpy as np
import pytest

import rgse_daemon.trace.diadem as diadem
from rgse_daemon.errors import DataError
from rgse_daemon.trace import read_trace_file
from tests.support.tracehelpers import edit_channel, write_small_set

DAT = "run1_NextGenDrive#3.dat"
R64 = "run1_NextGenDrive#3.r64"
N = 200  # samples per channel
NOVALUE = 9.9e34  # what write_small_set declares in code 111
#: One value, a value and a half, 2 rows and 2 values of a 7-channel BLOCK row, 1000 bytes (mid-value), the default.
CHUNKS = [8, 12, 8 * (2 * 7 + 2), 1000, diadem.CHUNK_BYTES]


@pytest.fixture(params=CHUNKS, ids=lambda c: f"chunk{c}")
def chunk(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    monkeypatch.setattr(diadem, "CHUNK_BYTES", request.param)
    return int(request.param)


def _explicit_blocks(dat: Path) -> tuple[dict[int, str], list[dict[int, str]]]:
    global_header, blocks = diadem.parse_header(dat.read_bytes().decode("iso-8859-1"))
    return global_header, [b for b in blocks if b[210].upper() == "EXPLIZIT"]


def _value_index(dat: Path, channel: str, sample: int) -> int:
    """Where sample ``sample`` of ``channel`` lies in the data file (in values)."""
    _, blocks = _explicit_blocks(dat)
    block = next(b for b in blocks if b[200] == channel)
    pointer = int(block[221])
    return sample * len(blocks) + pointer - 1 if block[213] == "BLOCK" else pointer - 1 + sample


def _poke(dat: Path, channel: str, samples: range | list[int], value: float) -> None:
    r64 = dat.with_name(R64)
    raw = np.fromfile(r64, dtype="<f8")
    for i in samples:
        raw[_value_index(dat, channel, i)] = value
    raw.tofile(r64)


def sample_by_sample(dat: Path) -> dict[str, tuple[np.ndarray, int]]:
    """Each explicit channel's values and missing count computed the plain way: the whole file by np.fromfile, the
    declared marker (within 1e-9 relative), NaN and inf as missing (NaN), ``raw * factor + offset`` elsewhere."""
    global_header, blocks = _explicit_blocks(dat)
    novalue = float(global_header[111]) if 111 in global_header else None
    raw = np.fromfile(dat.with_name(R64), dtype="<f8")
    out = {}
    for block in blocks:
        first, count = int(block[221]) - 1, int(block[220])
        column = raw[first :: len(blocks)] if block[213] == "BLOCK" else raw[first : first + count]
        with np.errstate(all="ignore"):
            missing = ~np.isfinite(column)
            if novalue is not None:
                missing |= np.abs(column - novalue) <= 1e-9 * abs(novalue)
            values = np.where(missing, np.nan, column * float(block.get(241, "1")) + float(block.get(240, "0")))
        out[block[200]] = (values, int(missing.sum()))
    return out


def _drop_novalue(dat: Path) -> None:
    text = dat.read_bytes().decode("iso-8859-1")
    assert "111,9.900000e+034\r\n" in text
    dat.write_bytes(text.replace("111,9.900000e+034\r\n", "").encode("iso-8859-1"))


DAMAGE: dict[str, Callable[[Path], None]] = {
    "clean": lambda dat: None,
    "no-value run in one channel": lambda dat: _poke(dat, "Istmoment", range(37, 121), NOVALUE),
    "no-value in the last sample": lambda dat: _poke(dat, "Iststrom", [N - 1], NOVALUE),
    "NaN": lambda dat: _poke(dat, "Istmoment", [3], float("nan")),
    "inf and -inf": lambda dat: (_poke(dat, "Sollposition", [0], float("inf")),
                                 _poke(dat, "Motortemperatur", [150], float("-inf"))),
    "values near the marker": lambda dat: (
        _poke(dat, "Istposition", [10], NOVALUE * (1 - 2e-9)),  # outside the marker's band: a value
        _poke(dat, "Istposition", [11], NOVALUE * (1 + 5e-10)),  # inside: missing
        _poke(dat, "Iststrom", [12], -NOVALUE),  # a value
    ),
    "no marker declared, 9.9e34 is a value": lambda dat: (_drop_novalue(dat),
                                                          _poke(dat, "Istmoment", [5], NOVALUE),
                                                          _poke(dat, "Istmoment", [6], float("nan"))),
}


#: Missing samples each damage leaves (what it wrote, not what the reader says).
MISSING = {"clean": 0, "no-value run in one channel": 121 - 37, "no-value in the last sample": 1, "NaN": 1,
           "inf and -inf": 2, "values near the marker": 1, "no marker declared, 9.9e34 is a value": 1}


@pytest.mark.parametrize("storage", ["BLOCK", "CHANNEL"])
@pytest.mark.parametrize("scaled", [False, True], ids=["identity", "scaled"])
@pytest.mark.parametrize("case", list(DAMAGE))
def test_chunked_read_equals_a_sample_by_sample_read(tmp_path: Path, chunk: int, storage: str, scaled: bool,
                                                     case: str) -> None:
    write_small_set(tmp_path, n=N, storage=storage, **({"factor": 0.001, "offset": 1.5} if scaled else {}))
    dat = tmp_path / DAT
    DAMAGE[case](dat)
    expected = sample_by_sample(dat)
    tf = read_trace_file(dat, with_blake3=True)
    for name, (values, n_missing) in expected.items():
        ch = tf.channel(name)
        assert ch.n_missing == n_missing, (name, ch.n_missing, n_missing)
        np.testing.assert_array_equal(ch.values, values, err_msg=name)  # NaN where NaN, bit-equal elsewhere
        assert not ch.values.flags.writeable
        if not scaled and n_missing == 0:  # identity and nothing missing: a view into the file's block, no copy
            assert not ch.values.flags.owndata, name
    data = (tmp_path / R64).read_bytes()
    assert tf.sha256[R64] == hashlib.sha256(data).hexdigest()
    assert tf.blake3[R64] == blake3.blake3(data).hexdigest()
    assert sum(n for _, n in expected.values()) == MISSING[case]  # the damage reached the file as meant


def test_a_missing_sample_copies_only_its_own_channel(tmp_path: Path, chunk: int) -> None:
    """Chunks that hold the marker send only the channel that has it down the sample-by-sample path."""
    write_small_set(tmp_path, n=N)
    _poke(tmp_path / DAT, "Istmoment", [90], NOVALUE)
    tf = read_trace_file(tmp_path / DAT)
    assert tf.channel("Istmoment").n_missing == 1 and tf.channel("Istmoment").values.flags.owndata
    others = [c for n, c in tf.channels.items() if n not in ("Istmoment", tf.time_channel)]
    assert len(others) == 6 and not any(c.values.flags.owndata for c in others)


@pytest.mark.parametrize("with_missing", [False, True], ids=["alone", "beside-a-missing-sample"])
def test_a_value_that_scaling_overflows_is_refused_at_its_sample(tmp_path: Path, chunk: int,
                                                                 with_missing: bool) -> None:
    write_small_set(tmp_path, n=N)
    dat = tmp_path / DAT
    edit_channel(dat, "Istmoment", 241, "1e300")
    _poke(dat, "Istmoment", [77], 1e10)
    if with_missing:
        _poke(dat, "Istmoment", [4], NOVALUE)
    suffix = " after scaling (codes 240/241)" if with_missing else ""
    with pytest.raises(DataError) as info:
        read_trace_file(dat)
    assert str(info.value) == (f"{tmp_path / R64}: channel 'Istmoment' has a non-finite value (NaN or inf) at "
                               f"sample 77{suffix}")


@pytest.mark.parametrize("storage", ["BLOCK", "CHANNEL"])
def test_size_not_a_multiple_of_8_and_more_data_than_announced_are_refused(tmp_path: Path, chunk: int,
                                                                           storage: str) -> None:
    write_small_set(tmp_path, n=N, storage=storage)
    r64 = tmp_path / R64
    with open(r64, "ab") as f:
        f.write(b"\x00" * 3)
    size = r64.stat().st_size
    with pytest.raises(DataError) as info:
        read_trace_file(tmp_path / DAT)
    assert str(info.value) == f"{r64}: data size {size} bytes is not a multiple of 8 (REAL64)"
    with open(r64, "ab") as f:
        f.write(b"\x00" * (7 * 8 - 3))  # now one row (7 values) too many
    expected = (f"header count (code 220) {N} disagrees with the data ({N + 1} rows)" if storage == "BLOCK" else
                f"header counts (code 220) add up to {7 * N} values, data has {7 * N + 7}")
    with pytest.raises(DataError) as info:
        read_trace_file(tmp_path / DAT)
    assert str(info.value) == f"{r64}: {expected}"


def test_a_file_that_shrinks_while_read_is_refused(tmp_path: Path, chunk: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The size is taken before reading; a file that then ends early (fstat said one row more) is refused."""
    write_small_set(tmp_path, n=N)
    dat, r64 = tmp_path / DAT, tmp_path / R64
    text = dat.read_bytes().decode("iso-8859-1")
    dat.write_bytes(text.replace(f"220,{N}\r\n", f"220,{N + 1}\r\n").encode("iso-8859-1"))
    real = r64.stat().st_size
    claimed = real + 7 * 8

    def fstat(fd: int) -> SimpleNamespace:
        return SimpleNamespace(st_size=claimed)

    monkeypatch.setattr(diadem, "os", SimpleNamespace(fstat=fstat))  # diadem uses os for fstat only
    with pytest.raises(DataError) as info:
        read_trace_file(dat)
    assert str(info.value) == f"{r64}: data file changed while reading ({real} of {claimed} bytes)"


@pytest.mark.parametrize("novalue", [9.9e34, -1e30, 1.0, 5e-324])
def test_below_the_clear_bound_no_value_is_the_marker(novalue: float) -> None:
    """A magnitude below :func:`diadem._clear_below` is never within the marker's band, even just below it."""
    bound = diadem._clear_below(novalue)
    assert 0.0 < bound <= abs(novalue) * (1 - 1e-9)  # the band starts at or beyond the bound
    below = np.nextafter(bound, 0.0)
    assert diadem._missing(np.array([below, -below, 0.0]), novalue) is None


def test_clear_bound_without_a_marker_and_for_a_marker_of_zero() -> None:
    assert diadem._clear_below(None) == np.inf  # only NaN/inf are missing: every finite value is clear
    assert diadem._clear_below(0.0) == 0.0  # nothing is clear: every chunk goes sample by sample
