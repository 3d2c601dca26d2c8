"""Helpers shared by the trace tests: a small drive trace and in-place edits of a header's channel blocks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgse_daemon.trace.channels import DRIVE_CHANNEL_UNITS
from simulators.krc4.tracefiles import write_trace_set


def drive_channels(n: int, seed: int) -> dict[str, tuple[np.ndarray, str]]:
    """Seven drive channels of ``n`` samples with both signs and different magnitudes."""
    rng = np.random.default_rng(seed)
    scale = {"Motortemperatur": 300.0, "Istmoment": 2500.0, "Iststrom": 12.0}
    return {
        name: (rng.standard_normal(n) * scale.get(name, 1.0) + (300.0 if unit == "K" else 0.0), unit)
        for name, unit in DRIVE_CHANNEL_UNITS.items()
    }


def write_small_set(directory: Path, name: str = "run1", n: int = 40, storage: str = "BLOCK", **kw) -> dict:
    """A set with two drive modules and KRCIpo; returns the physical input by module."""
    modules = {
        "NextGenDrive#3": drive_channels(n, 3),
        "NextGenDrive#5": drive_channels(n, 5),
        "KRCIpo": {"Override": (np.full(n, 10.0), "%")},
    }
    write_trace_set(directory, name, kw.pop("period_s", 0.012), modules, storage=storage, **kw)
    return modules


def edit_channel(dat: Path, channel: str, code: int, value: str | None) -> None:
    """Set (or with ``None`` delete) ``code`` in the header block of ``channel``; keeps CRLF line ends."""
    text = dat.read_bytes().decode("iso-8859-1")
    blocks = text.split("#BEGINCHANNELHEADER")
    for i, block in enumerate(blocks):
        lines = block.split("\r\n")
        if f"200,{channel}" not in lines:
            continue
        kept = [ln for ln in lines if not ln.startswith(f"{code},")]
        if value is not None:
            kept.insert(1, f"{code},{value}")
        blocks[i] = "\r\n".join(kept)
        dat.write_bytes("#BEGINCHANNELHEADER".join(blocks).encode("iso-8859-1"))
        return
    raise AssertionError(f"{dat} has no channel {channel}")
