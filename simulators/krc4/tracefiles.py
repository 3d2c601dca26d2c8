"""Writes a KUKA Trace file set the way a KR C4 leaves it in ``C:\\KRC\\ROBOTER\\TRACE`` (docs/controller.md §5.4).

For trace name ``N`` and each module ``M``: ``N_M.r64`` (little-endian float64), ``N_M.dat`` (DIAdem header:
text, ISO-8859-1, CRLF), ``N_M.trc`` and, if program text is given, ``N_PROG.TXT``.

The real ``.trc`` is KUKA's own (undocumented) copy of the trace configuration; the simulator writes a small
plain-text stand-in naming the trace, the module, the sample period and the channels. Nothing reads it.

Every file appears atomically: written under a temporary name in the same directory, fsynced, then renamed;
the data file before the header, so a reader that sees ``N_M.dat`` also finds complete data.

Public API::

    paths = write_trace_set(directory, "run1", 0.012,
                            {"NextGenDrive#3": {"Istmoment": (torque_nm, "Nm"), "Iststrom": (current_a, "A")}})

Raises ValueError for unusable arguments (mismatched lengths, non-finite values or period, bad names).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path

import numpy as np

from rgse_daemon.durable import fsync_dir, write_atomic

__all__ = ["write_trace_set"]

#: DIAdem's "no value" marker as KUKA Trace declares it in the global header (code 111): a sample not delivered.
NO_VALUE = 9.9e34
_ZEIT = "Zeit"  # kept literal: the simulator must not borrow names from the reader it is testing
_FORBIDDEN_IN_NAMES = set(',\r\n\\/:*?"<>|')


def _check_text(kind: str, text: str, *, file_name: bool = False, allow_empty: bool = False) -> None:
    """Header values are one line of ISO-8859-1; trace and module names also become file names."""
    forbidden = _FORBIDDEN_IN_NAMES if file_name else {"\r", "\n"}
    if (not text and not allow_empty) or forbidden & set(text) or text.strip() != text:
        raise ValueError(f"{kind} {text!r} is empty, padded or contains a character it may not contain")
    try:
        text.encode("iso-8859-1")
    except UnicodeEncodeError:
        raise ValueError(f"{kind} {text!r} is not ISO-8859-1") from None


def _fmt(value: float) -> str:
    """Shortest text that reads back as exactly the same float."""
    return repr(float(value))


def _header(
    trace: str,
    module: str,
    data_file: str,
    period_s: float,
    n_samples: int,
    channels: list[tuple[str, str, np.ndarray]],
    storage: str,
    factor: float,
    offset: float,
    now: datetime,
) -> bytes:
    """The DIAdem ``.dat`` header text for one module, encoded ISO-8859-1 with CRLF line ends."""
    lines = [
        "DIAEXTENDED  {@:ENGLISH",
        "",
        "#BEGINGLOBALHEADER",
        "1,WINDOWS 32Bit",  # origin
        "2,KUKA Trace (rgse simulator)",  # revision / writer
        f"101,{trace} {module}",  # description
        "103,KR C4",  # author
        f"104,{now:%m-%d-%Y}",
        f"105,{now:%H:%M:%S}",
        "111,9.900000e+034",  # the DIAdem "no value" marker (NO_VALUE)
        "112,High -> Low",
        "#ENDGLOBALHEADER",
        "",
        "#BEGINCHANNELHEADER",
        f"200,{_ZEIT}",
        "201,Zeit",
        "202,s",
        "210,IMPLIZIT",
        "213,BLOCK",
        "214,REAL64",
        f"220,{n_samples}",
        "240,0.0",
        f"241,{_fmt(period_s)}",
        "250,0.0",
        f"251,{_fmt(period_s * max(n_samples - 1, 0))}",
        "253,increasing",
        "260,Time",
        "#ENDCHANNELHEADER",
    ]
    pointer = 1
    for column, (name, unit, values) in enumerate(channels, start=1):
        lines += [
            "",
            "#BEGINCHANNELHEADER",
            f"200,{name}",
            f"201,{module} {name}",
            f"202,{unit}",
            "210,EXPLIZIT",
            f"211,{data_file}",
            f"213,{storage}",
            "214,REAL64",
            f"220,{n_samples}",
            f"221,{column if storage == 'BLOCK' else pointer}",
            f"240,{_fmt(offset)}",
            f"241,{_fmt(factor)}",
            f"250,{_fmt(np.nanmin(values)) if np.isfinite(values).any() else '0.0'}",
            f"251,{_fmt(np.nanmax(values)) if np.isfinite(values).any() else '0.0'}",
            "253,not monotone",
            "260,Numeric",
            "#ENDCHANNELHEADER",
        ]
        pointer += n_samples
    return ("\r\n".join(lines) + "\r\n").encode("iso-8859-1")


def _trc_text(trace: str, module: str, period_s: float, names: list[str]) -> bytes:
    lines = [
        "; KUKA Trace configuration copy (rgse simulator stand-in for the controller's binary .trc)",
        f"Trace={trace}",
        f"Module={module}",
        f"Rate_us={round(period_s * 1e6)}",
        *(f"Channel{i}={n}" for i, n in enumerate(names, start=1)),
    ]
    return ("\r\n".join(lines) + "\r\n").encode("iso-8859-1")


def write_trace_set(
    directory: Path | str,
    name: str,
    period_s: float,
    modules: Mapping[str, Mapping[str, tuple[np.ndarray, str]]],
    *,
    storage: str = "BLOCK",
    factor: float = 1.0,
    offset: float = 0.0,
    prog_text: str | None = None,
    now: datetime | None = None,
) -> list[Path]:
    """Write trace ``name`` into ``directory``: per module a ``.r64``, ``.trc`` and ``.dat``; returns the paths.

    ``modules`` maps module -> channel name -> (physical values, unit); all channels of a module must have the
    same length. ``period_s`` is the sample period in s (the implicit ``Zeit`` step). The ``.r64`` stores
    ``(physical - offset) / factor`` in ``storage`` layout ``"BLOCK"`` (one row per sample, as KUKA writes)
    or ``"CHANNEL"`` (one channel after another). ``prog_text`` becomes ``<name>_PROG.TXT``.
    """
    directory = Path(directory)
    _check_text("trace name", name, file_name=True)
    if storage not in ("BLOCK", "CHANNEL"):
        raise ValueError(f"storage must be 'BLOCK' or 'CHANNEL', got {storage!r}")
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"period_s must be finite and positive, got {period_s}")
    if not (math.isfinite(factor) and factor != 0.0 and math.isfinite(offset)):
        raise ValueError(f"factor must be finite and non-zero and offset finite, got {factor}, {offset}")
    if not modules:
        raise ValueError("no modules to write")
    now = now or datetime.now()

    prepared: dict[str, list[tuple[str, str, np.ndarray]]] = {}
    for module, channels in modules.items():
        _check_text("module name", module, file_name=True)
        if "_" in module:
            raise ValueError(f"module name {module!r} contains '_': KUKA module names have none (N_M.dat naming)")
        if not channels:
            raise ValueError(f"module {module!r} has no channels")
        columns = []
        for channel, (values, unit) in channels.items():
            _check_text("channel name", channel)
            if channel == _ZEIT:
                raise ValueError(f"module {module!r}: {_ZEIT!r} is the implicit time channel, do not pass it")
            _check_text("unit", unit, allow_empty=True)
            array = np.asarray(values, dtype=np.float64)
            if array.ndim != 1:
                raise ValueError(f"module {module!r} channel {channel!r}: values must be one-dimensional")
            if np.isinf(array).any():
                raise ValueError(f"module {module!r} channel {channel!r}: values must be finite or NaN (a sample "
                                 f"the drive did not deliver, written as DIAdem's no-value marker)")
            columns.append((channel, unit, array))
        lengths = {c[2].size for c in columns}
        if len(lengths) != 1:
            raise ValueError(f"module {module!r}: channels have different lengths {sorted(lengths)}")
        prepared[module] = columns

    directory.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if prog_text is not None:
        prog = directory / f"{name}_PROG.TXT"
        write_atomic(prog, prog_text.replace("\r\n", "\n").replace("\n", "\r\n").encode("iso-8859-1", "replace"))
        written.append(prog)
    for module, columns in prepared.items():
        stem = f"{name}_{module}"
        data_file = f"{stem}.r64"
        n_samples = columns[0][2].size
        # a missing sample (NaN) is written as the no-value marker the global header declares (code 111)
        raws = [np.where(np.isfinite(c[2]), (c[2] - offset) / factor, NO_VALUE) for c in columns]
        if storage == "BLOCK":
            table = np.column_stack(raws) if n_samples else np.empty((0, len(raws)))
        else:
            table = np.concatenate(raws)
        r64, trc, dat = directory / data_file, directory / f"{stem}.trc", directory / f"{stem}.dat"
        write_atomic(r64, np.ascontiguousarray(table, dtype="<f8").tobytes())
        write_atomic(trc, _trc_text(name, module, period_s, [c[0] for c in columns]))
        write_atomic(dat, _header(name, module, data_file, period_s, n_samples, columns, storage, factor, offset, now))
        written += [r64, trc, dat]
    fsync_dir(directory)
    return written
