"""The calibration file ``CAL.json`` (interfaces §3): read, validate, seal and write it, check its robot.

The file's shape lives in one place, :mod:`rgse_daemon.calfile.model` (:class:`CalFile` and its sections): reading
validates into it, writing serialises from it."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rgse_daemon.calfile.model import (
    AXES,
    G_RANGE_M_S2,
    LEVER_DIFFERENCE_RANGE_M,
    SCHEMA,
    Alternative,
    Bias,
    CalFile,
    Fit,
    Provenance,
    SetAsideLoop,
    Torsional,
    TorsionalPose,
    Validation,
    parse,
    parse_torsional,
    plausible_g,
    torsional_dict,
)
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import DataError

__all__ = [
    "AXES", "G_RANGE_M_S2", "LEVER_DIFFERENCE_RANGE_M", "SCHEMA", "Alternative", "Bias", "CalFile", "Fit",
    "Provenance", "SetAsideLoop", "Torsional", "TorsionalPose", "Validation", "check_robot", "content_id", "load",
    "parse", "parse_torsional", "plausible_g", "read", "read_document", "seal", "sealed", "torsional_dict", "write",
]


def content_id(doc: dict[str, Any]) -> str:
    """A hash of the document's content: everything but the id and the creation time."""
    body = json.dumps({k: v for k, v in doc.items() if k not in ("calibration_id", "created_utc")}, sort_keys=True)
    return hashlib.sha256(body.encode()).hexdigest()[:16]


def seal(doc: dict[str, Any]) -> dict[str, Any]:
    """Set a document's ``calibration_id`` to :func:`content_id` (tests and tools that edit a document)."""
    doc["calibration_id"] = content_id(doc)
    return doc


def sealed(cal: CalFile) -> CalFile:
    """``cal`` with its ``calibration_id`` (:func:`content_id`) and, if it has none, its creation time (now)."""
    created = cal.created_utc or datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    cal = dataclasses.replace(cal, created_utc=created)
    return dataclasses.replace(cal, calibration_id=content_id(cal.to_dict()))


def write(path: Path | str, cal: CalFile) -> None:
    """Write ``cal`` atomically (:func:`rgse_daemon.durable.write_atomic`) as indented JSON."""
    path = Path(path)
    try:
        write_atomic(path, json.dumps(cal.to_dict(), indent=2) + "\n")
    except OSError as exc:
        raise DataError(f"{path}: cannot write calibration: {exc}") from exc


def load(doc: Any, where: Path | str = "CAL.json") -> CalFile:
    """A CAL.json document (as stored, e.g. in the store) checked against its ``calibration_id`` and validated."""
    if isinstance(doc, dict) and doc.get("schema") == SCHEMA and doc.get("calibration_id") != content_id(doc):
        raise DataError(f"{where}: the content does not match its calibration_id {doc.get('calibration_id')!r} "
                        f"(edited after it was fitted, or damaged): refit it with rgse calibrate")
    return parse(doc, str(where))


def read(path: Path | str) -> CalFile:
    """Read and validate CAL.json (:func:`load`)."""
    return read_document(path)[1]


def read_document(path: Path | str) -> tuple[dict[str, Any], CalFile]:
    """Read and validate CAL.json: the document exactly as written (what the store keeps: a file is never
    rewritten) and its :class:`CalFile`."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: calibration file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable JSON calibration file: {exc}") from exc
    except RecursionError:  # the json module's answer to arrays nested thousands deep
        raise DataError(f"{path}: not a readable JSON calibration file: nested too deeply") from None
    return doc, load(doc, path)


def check_robot(path: Path | str, cal: CalFile, robot: str) -> None:
    """A calibration is only ever used for the robot it names (interfaces §3)."""
    if cal.robot != robot:
        raise DataError(f"{path}: calibration belongs to robot {cal.robot!r}, the measurement to {robot!r}")
