"""A configuration as the TOML file the daemon and the operator commands read (for tests that run ``rgse`` as a
subprocess against an in-process daemon)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rgse_daemon.config import Config


def _value(v: Any) -> str:
    return json.dumps(v)  # strings, numbers, booleans and lists of them are the same in JSON and TOML


def _table(name: str, body: dict[str, Any], lines: list[str], array: bool = False) -> None:
    """``body`` as the TOML table ``name`` (``[[name]]`` for an element of an array of tables): its plain keys first,
    then its sub-tables and arrays of tables; unset (``None``) keys left out."""
    lines.append(f"[[{name}]]" if array else f"[{name}]")
    nested: list[tuple[str, Any]] = []
    for k, v in body.items():
        if v is None:
            continue
        if isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(x, dict) for x in v)):
            nested.append((k, v))
        else:
            lines.append(f"{k} = {_value(v)}")
    lines.append("")
    for k, v in nested:
        if isinstance(v, dict):
            _table(f"{name}.{k}", v, lines)
        else:
            for element in v:
                _table(f"{name}.{k}", element, lines, array=True)


def write_config(cfg: Config, path: Path) -> Path:
    """``cfg`` as TOML: one table per section (sub-tables and arrays of tables as TOML writes them), unset (``None``)
    keys and sections left out."""
    lines: list[str] = []
    for section, body in cfg.model_dump(mode="json").items():
        if isinstance(body, dict):
            _table(section, body, lines)
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
