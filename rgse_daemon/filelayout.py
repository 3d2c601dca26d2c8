"""Which path form and listing form the controller's file interface accepts, recorded by ``rgse doctor``.

The public C3 Bridge source passes names unchanged to KUKA's Cross3 layer, so which forms a real KR C4 accepts
for its TRACE folder (``C:\\KRC\\ROBOTER\\TRACE\\…`` or ``KRC:\\TRACE\\…``), and whether a folder to list is named with
or without a trailing ``\\``, is not known before commissioning (docs/protocol.md §3). ``rgse doctor`` tries
them with a real file round trip and records the one that worked in ``<data_dir>/controller_layout.json``; the
daemon then uses it (:class:`~rgse_daemon.controller.Controller` rewrites every TRACE name into that form). Without
a record the controller probes the candidates once, in :data:`TRACE_DIR_CANDIDATES` order.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path

from rgse_daemon.errors import ConfigError

LAYOUT_FILENAME = "controller_layout.json"
#: Forms of the controller's TRACE folder, most likely first (docs/controller.md §5.2 names the disk path).
TRACE_DIR_CANDIDATES: tuple[str, ...] = ("C:\\KRC\\ROBOTER\\TRACE\\", "KRC:\\TRACE\\")
#: A name in the TRACE folder, in any candidate form or as a KRC name ``/TRACE/…``: group 1 is the rest below it.
_TRACE_NAME = re.compile(r"^(?:C:[\\/]+KRC[\\/]+ROBOTER[\\/]+TRACE|KRC:[\\/]*TRACE|/TRACE)(?:[\\/]+(.*))?$",
                         re.IGNORECASE)


@dataclass(frozen=True)
class FileLayout:
    """The forms that work: ``trace_dir`` (ends with ``\\``) for file names, and whether a folder is listed with
    its trailing ``\\`` (``list_trailing``). ``listing`` describes the info text seen (``fields``, ``bare``,
    ``text``: for the commissioning record), ``file_rate_bytes_s`` the file rate measured then (0 = unknown)."""

    trace_dir: str = TRACE_DIR_CANDIDATES[0]
    list_trailing: bool = True
    listing: str = "unknown"
    file_rate_bytes_s: float = 0.0

    def trace_name(self, name: str) -> str:
        """``name`` in this layout's form if it lies in the TRACE folder (any candidate form), else unchanged."""
        m = _TRACE_NAME.match(name)
        if m is None:
            return name
        rest = (m.group(1) or "").replace("/", "\\")
        return self.trace_dir + rest

    def folder(self, path: str) -> str:
        """A folder name as this controller wants it listed (with or without the trailing ``\\``)."""
        bare = path.rstrip("\\/")
        return bare + "\\" if self.list_trailing else bare


def is_trace_name(name: str) -> bool:
    return _TRACE_NAME.match(name) is not None


def layout_path(data_dir: Path) -> Path:
    return Path(data_dir) / LAYOUT_FILENAME


def load_layout(data_dir: Path) -> FileLayout | None:
    """The recorded layout, or ``None`` if doctor has not recorded one; a damaged record is a ConfigError."""
    path = layout_path(data_dir)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the controller layout: {exc.strerror}") from exc
    try:
        data = json.loads(text)
        layout = FileLayout(
            trace_dir=str(data["trace_dir"]),
            list_trailing=bool(data["list_trailing"]),
            listing=str(data.get("listing", "unknown")),
            file_rate_bytes_s=float(data.get("file_rate_bytes_s", 0.0)),
        )
    except (ValueError, KeyError, TypeError, RecursionError) as exc:  # RecursionError: JSON nested too deeply
        raise ConfigError(f"{path}: not a controller layout record ({exc}); rerun `rgse doctor`") from exc
    if layout.trace_dir not in TRACE_DIR_CANDIDATES:
        raise ConfigError(f"{path}: trace_dir {layout.trace_dir!r} is not one of {', '.join(TRACE_DIR_CANDIDATES)}")
    return layout


def save_layout(data_dir: Path, layout: FileLayout) -> Path:
    """Write the record atomically (temp file + rename); returns its path."""
    path = layout_path(data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(asdict(layout), indent=2) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path
