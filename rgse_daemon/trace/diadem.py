"""Reader of KUKA Trace output: DIAdem ``.dat`` headers with their ``.r64`` data files (docs/controller.md §5.5).

A KR C4 trace named ``N`` leaves one file pair per module, ``N_<module>.dat`` (text header) and
``N_<module>.r64`` (little-endian float64 values), e.g. ``N_NextGenDrive#3.dat``. The header is a global block
and one block per channel of ``code,value`` lines; the codes this reader interprets:

====  ==========================================================================================
200   channel name                      210  IMPLIZIT/EXPLIZIT (or IMPLICIT/EXPLICIT)
201   comment                           211  data file name (resolved beside the ``.dat``)
202   unit                              213  storage: BLOCK (rows = samples) or CHANNEL (one after another)
214   data type (only REAL64)           220  number of values
221   pointer: 1-based column (BLOCK) or 1-based first value index (CHANNEL)
240   offset (implicit: start value)    241  factor (implicit: step, i.e. the sample period in s)
====  ==========================================================================================

Every other code is kept, as text, in ``Channel.header`` / ``TraceFile.global_header``. Physical values are
``raw * factor + offset``. Channels are found by module and name, never by position.

Missing samples: the global header's code 111 declares DIAdem's "no value" marker (KUKA writes ``9.9e34``). A raw
value equal to it, and a raw NaN or infinity, is a missing sample and reads as NaN, in every channel alike
(``Channel.n_missing`` counts them); what to do with a loop that has a gap is the pipeline's decision. A finite raw
value that the channel's factor/offset carry out of the float range is a corrupt header and refused.

Public API::

    tf = read_trace_file(Path("run1_NextGenDrive#3.dat"))      # -> TraceFile
    torque_nm = tf.channel("Istmoment").values                  # float64, read-only, physical units
    t_s = tf.time_s(); tf.period_s; tf.sha256["run1_NextGenDrive#3.r64"]
    ts = read_trace_set(directory, "run1", modules=["NextGenDrive#3", "NextGenDrive#5"])   # -> TraceSet
    ts.channel("NextGenDrive#5", "Istmoment")

Every problem with the input raises :class:`~rgse_daemon.errors.DataError` naming the file and the problem.
The raw files are only read. ``Channel.values`` may be a read-only strided view into the file's data block
(no copy when factor is 1 and offset 0); call ``np.array(values)`` for a private, writable copy.
"""

from __future__ import annotations

import functools
import hashlib
import io
import math
import os
import re
from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path, PureWindowsPath
from typing import Protocol

import blake3
import numpy as np

from rgse_daemon.errors import DataError
from rgse_daemon.trace.channels import ZEIT
from rgse_daemon.trace.names import inside, plain_name

__all__ = ["Channel", "TraceFile", "TraceSet", "parse_header", "read_trace_file", "read_trace_set"]

#: DIAdem data types this reader understands, with their numpy dtype. KUKA writes only REAL64.
_DTYPES: dict[str, np.dtype] = {"REAL64": np.dtype("<f8")}
_IMPLICIT = {"IMPLIZIT", "IMPLICIT"}
_EXPLICIT = {"EXPLIZIT", "EXPLICIT"}
_STORAGES = {"BLOCK", "CHANNEL"}
#: A header is a few kB; anything much larger is not a DIAdem header.
_MAX_HEADER_BYTES = 16 * 1024 * 1024
#: The largest data file read: the controller's buffer holds 50 000 samples per channel (trace/config.py), a drive
#: module's file of ~20 channels is ~8 MB, so 256 MiB is far beyond any real trace and still fits in memory.
MAX_DATA_BYTES = 256 * 1024 * 1024
#: Relative tolerance on the step of an explicit time channel.
_TIME_STEP_RTOL = 1e-6
_INT_RE = re.compile(r"[+-]?[0-9]+")
#: Counts (220) and pointers (221) are far below 10**18: more digits than that is a corrupt header.
_MAX_INT_DIGITS = 18
_CODE_RE = re.compile(r"[0-9]{1,6}")
#: A decimal number as DIAdem writes one (no digit separators, no hex, no nan/inf words).
_FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_LINE_END_RE = re.compile(r"\r\n|\r|\n")
_BLANKS = " \t"


@dataclass(frozen=True)
class Channel:
    """One channel of a trace file: values in physical units (``raw * factor + offset``), float64, read-only."""

    name: str
    unit: str
    values: np.ndarray
    comment: str = ""
    module: str = ""
    header: Mapping[int, str] = field(default_factory=dict)
    """Every ``code -> value`` line of this channel's header block, as text (unknown codes included)."""
    n_missing: int = 0
    """Samples missing in the file (the global header's no-value marker, code 111, or a raw NaN/inf): NaN here."""


@dataclass(frozen=True)
class TraceFile:
    """One module's ``.dat``/``.r64`` pair. ``period_s`` comes from the header (implicit time step)."""

    module: str
    period_s: float
    n_samples: int
    channels: dict[str, Channel]
    dat_path: Path
    data_path: Path
    sha256: dict[str, str]
    """Hex SHA-256 of each raw file read (the ``.dat`` and its data file), by file name."""
    global_header: dict[int, str]
    time_channel: str = ZEIT
    blake3: dict[str, str] = field(default_factory=dict)
    """Hex BLAKE3 of each raw file read, by file name (``with_blake3=True``; else empty)."""

    def channel(self, name: str) -> Channel:
        """The channel called ``name`` (code 200); DataError naming the file if it has none."""
        try:
            return self.channels[name]
        except KeyError:
            raise DataError(f"{self.dat_path}: no channel {name!r} (channels: {', '.join(self.channels)})") from None

    def time_s(self) -> np.ndarray:
        """Sample times in s: the implicit ``Zeit`` channel (offset + i * period_s)."""
        return self.channels[self.time_channel].values


@dataclass(frozen=True)
class TraceSet:
    """All module files of one trace name, by module (e.g. ``"NextGenDrive#3"``)."""

    name: str
    directory: Path
    files: dict[str, TraceFile]

    def channel(self, module: str, name: str) -> Channel:
        """Channel ``name`` of ``module``; DataError if the module or the channel is absent."""
        try:
            tf = self.files[module]
        except KeyError:
            raise DataError(
                f"{self.directory / f'{self.name}_{module}.dat'}: trace {self.name!r} has no module {module!r} "
                f"(modules read: {', '.join(self.files) or 'none'})"
            ) from None
        return tf.channel(name)

    @property
    def sha256(self) -> dict[str, str]:
        """SHA-256 of every raw file of the set, by file name."""
        out: dict[str, str] = {}
        for tf in self.files.values():
            out.update(tf.sha256)
        return out

    @property
    def blake3(self) -> dict[str, str]:
        """BLAKE3 of every raw file of the set, by file name (read with ``with_blake3=True``)."""
        out: dict[str, str] = {}
        for tf in self.files.values():
            out.update(tf.blake3)
        return out


# --- header ------------------------------------------------------------------------------------------------------
def parse_header(text: str, source: str = "<string>") -> tuple[dict[int, str], list[dict[int, str]]]:
    """Split a DIAdem header into the global block and the channel blocks (``code -> value`` text).

    Accepts CRLF, LF (or CR) line ends and the optional ``DIAEXTENDED`` first line; only these end a line, and only
    blanks and tabs around a line or value are dropped: the header is Latin-1/Windows-1252 text, whose bytes 0x85
    (NEL, Windows-1252 "…"), 0x0B, 0x0C and 0x1C-0x1E ``str.splitlines`` would take for line ends. ``source`` names
    the file in errors.
    """
    global_header: dict[int, str] = {}
    channels: list[dict[int, str]] = []
    state = "start"
    current: dict[int, str] = global_header
    for lineno, raw_line in enumerate(_LINE_END_RE.split(text), start=1):
        line = raw_line.strip(_BLANKS)
        if not line:
            continue
        where = f"{source}:{lineno}"
        if state == "start":
            if line.startswith("DIAEXTENDED") and not global_header:
                continue
            if line != "#BEGINGLOBALHEADER":
                raise DataError(f"{where}: expected #BEGINGLOBALHEADER, found {line[:40]!r}")
            state = "global"
        elif state == "between":
            if line != "#BEGINCHANNELHEADER":
                raise DataError(f"{where}: expected #BEGINCHANNELHEADER, found {line[:40]!r}")
            current = {}
            state = "channel"
        elif (state, line) in (("global", "#ENDGLOBALHEADER"), ("channel", "#ENDCHANNELHEADER")):
            if state == "channel":
                channels.append(current)
            state = "between"
        else:
            code_text, sep, value = line.partition(",")
            code_text = code_text.strip()
            if not sep or not _CODE_RE.fullmatch(code_text):
                raise DataError(f"{where}: expected a 'code,value' line, found {line[:40]!r}")
            code = int(code_text)
            if code in current:
                raise DataError(f"{where}: code {code} given twice in one header block")
            current[code] = value.strip(_BLANKS)
    if state != "between":
        raise DataError(f"{source}: truncated header (ends inside or before the {state} block)")
    if not channels:
        raise DataError(f"{source}: header has no channel blocks")
    return global_header, channels


@dataclass(frozen=True)
class _Spec:
    """One channel block, interpreted."""

    index: int
    name: str
    implicit: bool
    count: int
    offset: float
    factor: float
    data_file: str = ""
    storage: str = ""
    pointer: int = 0
    header: Mapping[int, str] = field(default_factory=dict)


def _get(block: Mapping[int, str], code: int, source: str, what: str) -> str:
    try:
        return block[code]
    except KeyError:
        raise DataError(f"{source}: {what} has no code {code}") from None


def _int(block: Mapping[int, str], code: int, source: str, what: str, minimum: int) -> int:
    text = _get(block, code, source, what)
    if not _INT_RE.fullmatch(text):
        raise DataError(f"{source}: {what}: code {code} is not an integer: {text[:40]!r}")
    if len(text.lstrip("+-").lstrip("0")) > _MAX_INT_DIGITS:  # int() itself refuses > 4300 digits with a ValueError
        raise DataError(f"{source}: {what}: code {code} is out of range ({len(text)} characters): {text[:40]!r}")
    value = int(text)
    if value < minimum:
        raise DataError(f"{source}: {what}: code {code} = {value} is below {minimum}")
    return value


def _float(block: Mapping[int, str], code: int, source: str, what: str, default: float | None = None) -> float:
    if default is not None and code not in block:
        return default
    text = _get(block, code, source, what)
    if not _FLOAT_RE.fullmatch(text):  # float() alone would also take "1_000" (1000.0) and "nan"
        if text.strip(_BLANKS).lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise DataError(f"{source}: {what}: code {code} is not finite: {text[:40]!r}")
        raise DataError(f"{source}: {what}: code {code} is not a number: {text[:40]!r}")
    value = float(text)
    if not math.isfinite(value):
        raise DataError(f"{source}: {what}: code {code} is not finite: {text[:40]!r}")
    return value


def _spec(index: int, block: dict[int, str], source: str) -> _Spec:
    what = f"channel block {index + 1}"
    name = _get(block, 200, source, what)
    if not name:
        raise DataError(f"{source}: {what} has an empty name (code 200)")
    what = f"channel {name!r}"
    kind = _get(block, 210, source, what).upper()
    count = _int(block, 220, source, what, minimum=0)
    if kind in _IMPLICIT:
        offset = _float(block, 240, source, what)
        factor = _float(block, 241, source, what)
        return _Spec(index, name, True, count, offset, factor, header=block)
    if kind not in _EXPLICIT:
        raise DataError(f"{source}: {what}: code 210 must be IMPLIZIT or EXPLIZIT, found {kind[:40]!r}")
    dtype = _get(block, 214, source, what).upper()
    if dtype not in _DTYPES:
        raise DataError(f"{source}: {what}: unsupported data type (code 214) {dtype[:40]!r}; expected REAL64")
    storage = _get(block, 213, source, what).upper()
    if storage not in _STORAGES:
        raise DataError(f"{source}: {what}: storage (code 213) must be BLOCK or CHANNEL, found {storage[:40]!r}")
    # Only the base name: the header was written on the controller (Windows paths) and must not point elsewhere.
    data_file = PureWindowsPath(_get(block, 211, source, what)).name
    if not data_file or data_file in (".", ".."):
        raise DataError(f"{source}: {what}: empty data file name (code 211)")
    return _Spec(
        index,
        name,
        False,
        count,
        offset=_float(block, 240, source, what, default=0.0),
        factor=_float(block, 241, source, what, default=1.0),
        data_file=data_file,
        storage=storage,
        pointer=_int(block, 221, source, what, minimum=1),
        header=block,
    )


# --- data --------------------------------------------------------------------------------------------------------
#: Bytes read per step. Each step's digests and min/max run while its bytes are in the core's cache (L2: 1 MiB
#: per core on the bench machine), so the file's bytes come from memory once, not once per pass. 256 kB to 4 MB
#: read + hash a 100 MB set alike within the noise of the shared 2-core bench machine (docs/accuracy.md, issue 35).
CHUNK_BYTES = 1024 * 1024


@dataclass(frozen=True)
class _Raw:
    """One data file as read: each channel's raw values (read-only views into one block) and, per chunk read, the
    range of value indices ``[starts[i], starts[i + 1])`` with its min and max (NaN if any value is NaN)."""

    columns: dict[str, np.ndarray]
    placement: dict[str, tuple[int, int]]
    """Channel -> (value index of its first sample, values between two samples): sample ``i`` is value
    ``first + i * stride`` of the file."""
    starts: np.ndarray
    lows: np.ndarray
    highs: np.ndarray
    digest: dict[str, str]


def _read_raw(path: Path, specs: list[_Spec], source: str, with_sha256: bool, with_blake3: bool = False) -> _Raw:
    """The raw values of each channel of one data file (read-only), the min/max of every chunk read and, if asked,
    the SHA-256 and/or BLAKE3 of the file's bytes.

    The file's size is checked against the header (codes 220/221, :func:`_layout`) and :data:`MAX_DATA_BYTES`
    *before* a byte of it is read, and no more than that is ever read: a 2 GB file behind a 40-sample header is
    refused at once instead of filling the memory. The file is read in chunks of :data:`CHUNK_BYTES` into one
    block of the size the header announces; the digests hash that block's bytes, chunk by chunk as they arrive."""
    dtype = _DTYPES["REAL64"]
    try:
        with open(path, "rb", buffering=0) as f:
            size = os.fstat(f.fileno()).st_size
            if size % dtype.itemsize:
                raise DataError(f"{path}: data size {size} bytes is not a multiple of {dtype.itemsize} (REAL64)")
            if size > MAX_DATA_BYTES:
                raise DataError(f"{path}: data file of {size} bytes exceeds {MAX_DATA_BYTES} bytes, far more than "
                                "the controller's trace buffer writes; not read")
            n_values = size // dtype.itemsize
            layout = _layout(specs, n_values, path)
            raw = np.empty(n_values, dtype=dtype)
            got, starts, lows, highs, digest = _read_chunks(f, raw, with_sha256, with_blake3)
    except FileNotFoundError:
        raise DataError(f"{source}: data file {path.name!r} (code 211) not found beside the header") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read data file: {exc}") from exc
    if got != size:
        raise DataError(f"{path}: data file changed while reading ({got - got % dtype.itemsize} of {size} bytes)")
    raw.flags.writeable = False
    if isinstance(layout, int):  # BLOCK: a table of ``layout`` columns, one row per sample
        table = raw.reshape(-1, layout)
        columns = {s.name: table[:, s.pointer - 1] for s in specs}
        placement = {s.name: (s.pointer - 1, layout) for s in specs}
    else:
        columns = {s.name: raw[sl] for s, sl in zip(specs, layout, strict=True)}
        placement = {s.name: (s.pointer - 1, 1) for s in specs}
    return _Raw(columns, placement, starts, lows, highs, digest)


def _read_chunks(
    f: io.RawIOBase, raw: np.ndarray, with_sha256: bool, with_blake3: bool
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, dict[str, str]]:
    """Fill ``raw`` from ``f`` chunk by chunk, hashing each chunk and taking its min/max while it is cache-hot.

    Returns the bytes read (fewer than ``raw`` holds if the file shrank), the value index where each chunk starts
    (and, last, where the values read end), each chunk's min and max, and the digests of the bytes read."""
    hashers: dict[str, _Hasher] = {}
    if with_sha256:
        hashers["sha256"] = hashlib.sha256()
    if with_blake3:  # one thread per file: read_trace_set reads the files on threads of its own
        hashers["blake3"] = blake3.blake3(max_threads=1)
    buffer = memoryview(raw).cast("B")
    starts: list[int] = []
    lows: list[float] = []
    highs: list[float] = []
    got = done = 0  # bytes read, values whose min/max is taken
    while got < len(buffer):
        n = f.readinto(buffer[got : got + CHUNK_BYTES])
        if not n:  # the file is shorter than it was a moment ago
            break
        for h in hashers.values():  # SHA-256 and BLAKE3 release the GIL on chunks this large
            h.update(buffer[got : got + n])
        got += n
        end = got // raw.itemsize  # a value cut by the chunk's end is taken with the next chunk
        if end > done:
            chunk = raw[done:end]
            starts.append(done)
            lows.append(chunk.min())
            highs.append(chunk.max())
            done = end
    starts.append(done)
    return (got, np.array(starts, dtype=np.int64), np.array(lows, dtype=raw.dtype), np.array(highs, dtype=raw.dtype),
            {name: h.hexdigest() for name, h in hashers.items()})


class _Hasher(Protocol):
    def update(self, data: memoryview, /) -> object: ...
    def hexdigest(self) -> str: ...


def _digests(data: bytes | np.ndarray, with_sha256: bool, with_blake3: bool) -> dict[str, str]:
    """SHA-256 (what the archive records) and/or BLAKE3 (several times faster, on every core) of ``data``."""
    out = {}
    if with_sha256:
        out["sha256"] = hashlib.sha256(data).hexdigest()
    if with_blake3:
        out["blake3"] = blake3.blake3(data, max_threads=blake3.blake3.AUTO).hexdigest()
    return out


def _layout(specs: list[_Spec], n_values: int, path: Path) -> int | list[slice]:
    """Check that a data file of ``n_values`` values holds exactly what ``specs`` announce (pointers 221, counts
    220), before it is read; the row width for BLOCK storage, else each channel's slice (CHANNEL, ``specs`` order)."""
    storage = specs[0].storage
    if any(s.storage != storage for s in specs):
        raise DataError(f"{path}: channels mix BLOCK and CHANNEL storage in one data file")
    if storage == "BLOCK":
        width = len(specs)
        pointers = sorted(s.pointer for s in specs)
        if pointers != list(range(1, width + 1)):
            raise DataError(f"{path}: BLOCK column pointers (code 221) {pointers} are not 1..{width}")
        counts = {s.count for s in specs}
        if len(counts) != 1:
            raise DataError(f"{path}: channels of one BLOCK file have different counts (code 220): {sorted(counts)}")
        if n_values % width:
            raise DataError(f"{path}: {n_values} values are not a multiple of the row width ({width} channels)")
        rows = n_values // width
        if rows != specs[0].count:
            raise DataError(f"{path}: header count (code 220) {specs[0].count} disagrees with the data ({rows} rows)")
        return width
    expected = 1
    for s in sorted(specs, key=lambda s: s.pointer):
        if s.pointer != expected:
            raise DataError(
                f"{path}: CHANNEL storage: channel {s.name!r} starts at value {s.pointer}, expected {expected} "
                "(channels must follow one another)"
            )
        expected += s.count
    if expected - 1 != n_values:
        raise DataError(f"{path}: header counts (code 220) add up to {expected - 1} values, data has {n_values}")
    return [slice(s.pointer - 1, s.pointer - 1 + s.count) for s in specs]


def _all_finite(values: np.ndarray) -> bool:
    """True if no value is NaN or inf. A sum is finite only if every term is (NaN and inf propagate), and a
    contiguous sum runs at memory speed; the element-wise test runs only when the sum overflowed or is NaN."""
    with np.errstate(over="ignore", invalid="ignore"):
        total = values.sum()
    return bool(np.isfinite(total)) or bool(np.isfinite(values).all())


#: Relative tolerance of a raw value against the declared no-value marker (code 111 is written as decimal text).
_NOVALUE_RTOL = 1e-9


def no_value(global_header: Mapping[int, str], source: str) -> float | None:
    """DIAdem's "no value" marker declared by the global header's code 111 (e.g. ``9.9e34``); None if absent."""
    if 111 not in global_header:
        return None
    return _float(global_header, 111, source, "global header (no-value marker)")


def _clear_below(novalue: float | None) -> float:
    """A magnitude below which a raw value is certainly a sample: finite and not the no-value marker.

    :func:`_missing` takes ``|raw - novalue| <= _NOVALUE_RTOL * |novalue|`` for the marker; this bound keeps
    ``3 * _NOVALUE_RTOL * |novalue|`` clear of that band, far more than the rounding of ``raw - novalue`` (1e-16
    relative). No marker: every finite value is a sample (inf). A marker of 0: nothing is certain (0)."""
    if novalue is None:
        return math.inf
    return abs(novalue) * (1.0 - 4.0 * _NOVALUE_RTOL)


def _doubtful_channels(raw: _Raw, novalue: float | None) -> set[str]:
    """The channels of one data file that may hold a missing sample or a non-finite value; only they need the
    sample-by-sample test of :func:`_physical`.

    A chunk whose min and max lie strictly inside ``±_clear_below(novalue)`` clears every sample in it (NaN makes
    min and max NaN, inf shows in them). In a chunk that is not cleared, each channel's own samples are compared
    with the same bound; a channel none of whose samples fail is clear."""
    bound = _clear_below(novalue)
    doubtful_chunks = np.flatnonzero(~((raw.lows > -bound) & (raw.highs < bound)))
    out: set[str] = set()
    for name, column in raw.columns.items():
        first, stride = raw.placement[name]
        for k in doubtful_chunks:
            v0, v1 = int(raw.starts[k]), int(raw.starts[k + 1])
            i0 = max(0, -((first - v0) // stride))  # the first sample at value index >= v0: ceil((v0-first)/stride)
            i1 = min(column.size, -((first - v1) // stride))
            if i1 > i0 and not bool((np.abs(column[i0:i1]) < bound).all()):  # NaN < bound is False
                out.add(name)
                break
    return out


def _missing(raw: np.ndarray, novalue: float | None) -> np.ndarray | None:
    """Mask of the missing raw samples (the no-value marker, NaN, inf); None when there is none."""
    with np.errstate(over="ignore", invalid="ignore"):
        mask = ~np.isfinite(raw)
        if novalue is not None:
            mask |= np.abs(raw - novalue) <= _NOVALUE_RTOL * abs(novalue)
    return mask if mask.any() else None


def _physical(raw: np.ndarray, spec: _Spec, path: Path, novalue: float | None = None) -> tuple[np.ndarray, int]:
    """``raw * factor + offset``, read-only, with missing samples (:func:`_missing`) as NaN, and their count; a value
    that scaling carries out of the float range is refused (no copy for the identity calibration).

    Sample by sample, for a channel the chunks' min/max did not clear (:func:`_doubtful_channels`); a cleared
    channel goes straight to :func:`_scaled`, with the same result."""
    mask = _missing(raw, novalue)
    if mask is not None:
        with np.errstate(over="ignore", invalid="ignore"):
            values = np.where(mask, np.nan, raw * spec.factor + spec.offset)
        if not np.isfinite(values[~mask]).all():
            bad = int(np.flatnonzero(~mask & ~np.isfinite(values))[0])
            raise DataError(f"{path}: channel {spec.name!r} has a non-finite value (NaN or inf) at sample {bad} "
                            f"after scaling (codes 240/241)")
        values.flags.writeable = False
        return values, int(mask.sum())
    return _scaled(raw, spec, path), 0


def _scaled(raw: np.ndarray, spec: _Spec, path: Path) -> np.ndarray:
    """``raw * factor + offset`` of a channel whose raw values are all finite samples, read-only, checked finite
    (the raw view itself for the identity calibration)."""
    if spec.factor == 1.0 and spec.offset == 0.0:
        return raw
    with np.errstate(over="ignore", invalid="ignore"):  # overflow shows up as inf and is refused below
        values = raw * spec.factor
        if spec.offset != 0.0:
            values += spec.offset
    values.flags.writeable = False
    if not _all_finite(values):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise DataError(f"{path}: channel {spec.name!r} has a non-finite value (NaN or inf) at sample {bad}")
    return values


@functools.lru_cache(maxsize=8)
def _ramp(count: int, offset: float, step: float) -> np.ndarray:
    """``offset + i * step`` for i in 0..count-1, read-only. Cached: every module of a trace shares one time axis
    (the controller's buffer keeps it at <= 50 000 samples, 400 kB)."""
    values = np.arange(count, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        values *= step
        values += offset
    values.flags.writeable = False
    return values


def _implicit_values(spec: _Spec, source: str) -> np.ndarray:
    """The values of an implicit channel; DataError if they leave the float range."""
    values = _ramp(spec.count, spec.offset, spec.factor)
    if values.size and not (np.isfinite(values[0]) and np.isfinite(values[-1])):
        raise DataError(f"{source}: implicit channel {spec.name!r}: offset/step (240/241) overflow the float range")
    return values


def _time_period_s(spec: _Spec, values: np.ndarray, source: str) -> float:
    """The sample period in s of the time channel; DataError unless it increases strictly and uniformly."""
    if spec.implicit:
        if spec.factor <= 0.0:
            raise DataError(f"{source}: time channel {spec.name!r} has a non-positive step (code 241) {spec.factor}")
        return spec.factor
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.diff(values)
        if values.size < 2 or not (steps > 0.0).all():
            raise DataError(f"{source}: explicit time channel {spec.name!r} is not strictly increasing")
        period_s = float((values[-1] - values[0]) / (values.size - 1))
        if not math.isfinite(period_s) or not np.allclose(steps, period_s, rtol=_TIME_STEP_RTOL, atol=0.0):
            raise DataError(f"{source}: explicit time channel {spec.name!r} has a non-uniform step")
    return period_s


def read_trace_file(dat_path: Path | str, module: str | None = None, *, with_sha256: bool = True,
                    with_blake3: bool = False) -> TraceFile:
    """Read one ``.dat`` header and its data file(s).

    ``with_sha256=False`` skips hashing (``TraceFile.sha256`` is then empty): SHA-256 runs at ~2.2 GB/s a core,
    less than half the speed of the rest of the reader, and only the archive and the results need it (their records
    are SHA-256). ``with_blake3=True`` fills ``TraceFile.blake3``: BLAKE3 on every core, for integrity checks of a
    whole archive's re-analysis where no SHA-256 record is compared (``bench/robot_time.py``: read + BLAKE3 vs
    ``numpy.fromfile``).

    ``module`` defaults to the part of the file stem after its last ``_`` (``run1_NextGenDrive#3`` ->
    ``NextGenDrive#3``): KUKA module names contain no underscore, trace names may.
    """
    dat_path = Path(dat_path)
    source = str(dat_path)
    try:
        with open(dat_path, "rb") as f:
            header_bytes = f.read(_MAX_HEADER_BYTES + 1)
    except FileNotFoundError:
        raise DataError(f"{dat_path}: trace header not found") from None
    except OSError as exc:
        raise DataError(f"{dat_path}: cannot read trace header: {exc}") from exc
    if len(header_bytes) > _MAX_HEADER_BYTES:
        raise DataError(f"{dat_path}: larger than {_MAX_HEADER_BYTES} bytes, not a DIAdem header")
    if b"\x00" in header_bytes:
        raise DataError(f"{dat_path}: contains NUL bytes, not a text DIAdem header")
    if module is None:
        module = dat_path.stem.rpartition("_")[2]
    global_header, blocks = parse_header(header_bytes.decode("iso-8859-1"), source)
    specs = [_spec(i, block, source) for i, block in enumerate(blocks)]

    names = [s.name for s in specs]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise DataError(f"{source}: channel name(s) given twice: {', '.join(duplicates)}")
    explicit = [s for s in specs if not s.implicit]
    if not explicit:
        raise DataError(f"{source}: no explicit channel, the header describes no data")
    time_spec = next((s for s in specs if s.name == ZEIT), None) or next((s for s in specs if s.implicit), None)
    if time_spec is None:
        raise DataError(f"{source}: no time channel ({ZEIT!r} or any implicit channel)")

    by_file: dict[str, list[_Spec]] = {}
    for s in explicit:
        by_file.setdefault(s.data_file, []).append(s)
    header_digest = _digests(header_bytes, with_sha256, with_blake3)
    sha256 = {dat_path.name: header_digest["sha256"]} if with_sha256 else {}
    b3 = {dat_path.name: header_digest["blake3"]} if with_blake3 else {}
    raws: list[_Raw] = []
    data_paths: list[Path] = []
    for file_name in by_file:
        if file_name == dat_path.name:
            raise DataError(f"{source}: data file (code 211) names the header itself")
        try:  # is_file() answers False for a missing file but raises on a name too long for the file system
            found = dat_path.with_name(file_name).is_file()
        except OSError as exc:
            raise DataError(f"{source}: data file {file_name[:60]!r} (code 211) cannot be looked up: "
                            f"{exc.strerror or exc}") from None
        if not found:
            raise DataError(f"{source}: data file {file_name!r} (code 211) not found beside the header")
        inside(dat_path.parent, dat_path.with_name(file_name))
    for file_name, group in by_file.items():
        data_path = dat_path.with_name(file_name)
        raw = _read_raw(data_path, group, source, with_sha256, with_blake3)
        if "sha256" in raw.digest:
            sha256[file_name] = raw.digest["sha256"]
        if "blake3" in raw.digest:
            b3[file_name] = raw.digest["blake3"]
        raws.append(raw)
        data_paths.append(data_path)

    n_samples = time_spec.count
    for s in specs:
        if s.count != n_samples:
            raise DataError(
                f"{source}: channel {s.name!r} has {s.count} values (code 220), time channel "
                f"{time_spec.name!r} has {n_samples}"
            )
    channels: dict[str, Channel] = {}
    period_s = 0.0
    novalue = no_value(global_header, source)
    raw_by_name = {name: column for raw in raws for name, column in raw.columns.items()}
    doubtful = set().union(*(_doubtful_channels(raw, novalue) for raw in raws))
    for s in specs:
        missing = 0
        if s.implicit:
            values = _implicit_values(s, source)
        else:
            column, data_path = raw_by_name[s.name], dat_path.with_name(s.data_file)
            if s.name in doubtful:
                values, missing = _physical(column, s, data_path, novalue)
            else:
                values = _scaled(column, s, data_path)
        if s is time_spec and missing:
            raise DataError(f"{source}: time channel {s.name!r} has {missing} missing samples (no value, NaN or inf)")
        if s is time_spec:
            period_s = _time_period_s(s, values, source)
        channels[s.name] = Channel(
            name=s.name,
            unit=s.header.get(202, ""),
            values=values,
            comment=s.header.get(201, ""),
            module=module,
            header=dict(s.header),
            n_missing=missing,
        )
    return TraceFile(
        module=module,
        period_s=period_s,
        n_samples=n_samples,
        channels=channels,
        dat_path=dat_path,
        data_path=data_paths[0],
        sha256=sha256,
        global_header=global_header,
        time_channel=time_spec.name,
        blake3=b3,
    )


def _modules_present(directory: Path, name: str) -> list[str]:
    prefix = f"{name}_"
    found = []
    for path in directory.glob(f"{glob_escape(prefix)}*.dat"):
        module = path.stem[len(prefix) :]
        if module and "_" not in module:
            found.append(module)
    return sorted(found)


def glob_escape(text: str) -> str:
    """``text`` with glob metacharacters escaped, for Path.glob (trace names are plain, but be exact)."""
    return re.sub(r"([*?\[])", r"[\1]", text)


def read_trace_set(
    directory: Path | str,
    name: str,
    modules: Iterable[str] | None = None,
    *,
    max_workers: int = 2,
    with_sha256: bool = True,
    with_blake3: bool = False,
) -> TraceSet:
    """Read the files ``<name>_<module>.dat`` of one trace.

    ``modules=None`` reads every module present (file stems ``<name>_<module>`` whose module part has no
    underscore, so trace ``run`` does not swallow trace ``run_2``); a requested module that is absent is a
    DataError, as is a trace with no files at all. Files are read on up to ``max_workers`` threads: reading and
    hashing release the GIL, so the two cores overlap. ``with_sha256``, ``with_blake3`` as for
    :func:`read_trace_file`.
    """
    directory = Path(directory)
    plain_name(name, f"{directory}: trace name")
    if not directory.is_dir():
        raise DataError(f"{directory}: trace directory not found")
    wanted = _modules_present(directory, name) if modules is None else list(modules)
    if not wanted:
        raise DataError(f"{directory / (name + '_*.dat')}: no trace files for trace {name!r}")
    paths = [directory / f"{name}_{m}.dat" for m in wanted]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise DataError(f"{', '.join(missing)}: trace file(s) of requested module(s) not found")
    for p in paths:
        inside(directory, p)

    def read_one(path: Path, module: str) -> TraceFile:
        return read_trace_file(path, module, with_sha256=with_sha256, with_blake3=with_blake3)

    if max_workers <= 1 or len(paths) == 1:
        read = [read_one(p, m) for p, m in zip(paths, wanted, strict=True)]
    else:
        with ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="trace-read") as pool:
            read = list(pool.map(read_one, paths, wanted))
    return TraceSet(name=name, directory=directory, files=dict(zip(wanted, read, strict=True)))
