"""The run directory as a contract-§2 measurement or campaign directory: manifest lines, durable text writes."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from rgse_daemon.procedures.settings import RunSettings


def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def setup_toml(s: RunSettings) -> list[str]:
    return ["[setup]", f"robot = {_toml_str(s.robot)}", f"g = {s.g_m_s2!r}",
            f"lever_difference_m = {s.lever_difference_m!r}", ""]


def traces_toml(traces: Sequence[str]) -> str:
    return "traces = [" + ", ".join(_toml_str(t) for t in traces) + "]"


def write_text_durably(path: Path, text: str) -> None:
    """Write ``path`` via a temporary file, fsync and rename (a manifest is never half written)."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


