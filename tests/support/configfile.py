"""A configuration as the TOML file the daemon and the operator commands read (for tests that run ``rgse`` as a
subprocess against an in-process daemon)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rgse_daemon.config import Config


def _value(v: Any) -> str:
    return json.dumps(v)  # strings, numbers, booleans and lists of them are the same in JSON and TOML


def write_config(cfg: Config, path: Path) -> Path:
    """``cfg`` as TOML: one table per section, unset (``None``) keys and sections left out."""
    lines: list[str] = []
    for section, body in cfg.model_dump(mode="json").items():
        if not isinstance(body, dict):
            continue
        lines.append(f"[{section}]")
        lines += [f"{k} = {_value(v)}" for k, v in body.items() if v is not None and not isinstance(v, dict)]
        lines.append("")
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
