"""The manifest lines of a run directory (contract §2): the ``[setup]`` table and the trace lists."""

from __future__ import annotations

from collections.abc import Sequence

from rgse_daemon.procedures.settings import RunSettings


def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def setup_toml(s: RunSettings) -> list[str]:
    return ["[setup]", f"robot = {_toml_str(s.robot)}", f"g = {s.g_m_s2!r}",
            f"lever_difference_m = {s.lever_difference_m!r}", ""]


def traces_toml(traces: Sequence[str]) -> str:
    return "traces = [" + ", ".join(_toml_str(t) for t in traces) + "]"
