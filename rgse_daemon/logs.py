"""Log output on stderr in one of three formats, chosen by ``--log-format`` or ``$RGSE_LOG_FORMAT``.

* ``text``: ``2024-05-01 12:00:00,123 WARNING rgse_daemon.app: message`` — for terminals.
* ``journal``: ``<4>WARNING rgse_daemon.app: message`` — for systemd's journal, which adds the timestamp itself and
  reads the sd-daemon(3) priority prefix ``<N>`` (DEBUG 7, INFO 6, WARNING 4, ERROR 3, CRITICAL 2) of every line.
  journald stores each line of a stream as its own entry, so a multi-line message or a traceback gets the prefix on
  *every* line: each continuation line keeps the record's priority (``journalctl -p err`` shows whole tracebacks).
  Trailing empty lines are dropped.
* ``json``: one object per line: ``time`` (ISO-8601, UTC), ``level``, ``logger``, ``message``, ``exception`` (the
  traceback text, only when there is one), ``stack`` (only with ``stack_info``), plus every field passed with
  ``extra={...}`` (such as ``run_id``, ``robot``, ``watcher``). An extra value that JSON cannot carry (an object,
  NaN, a dict with non-string keys) is written as its ``str()``; an extra named like a fixed field is written as
  ``extra_<name>`` so it never replaces one.
* ``auto`` (the default): ``journal`` when stderr is the journal's stream — ``$JOURNAL_STREAM`` holds the
  ``device:inode`` of that stream, compared with ``fstat`` of stderr — otherwise ``text``.

Hygiene, in every format (filters on the handler, so third-party loggers such as the MQTT client's are covered):

* control characters in a message (a NUL in an abort reason, an escape sequence in a file name) are written
  escaped (``\\x00``); newlines and tabs stay (tracebacks);
* a warning (or worse) repeated with the same text is written once; further copies within
  :data:`REPEAT_WINDOW_S` are counted, and the count is written with the next copy after the window (``... [and
  5523 more times in the last 60 s]``) or when logging shuts down.
"""

from __future__ import annotations

import json
import logging
import os
import re
import sys
import time
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import IO, Any

FORMATS = ("auto", "text", "journal", "json")
ENV_VAR = "RGSE_LOG_FORMAT"
TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
JOURNAL_FORMAT = "%(levelname)s %(name)s: %(message)s"

#: Attributes every LogRecord has; anything else on a record came from ``extra=``.
_RECORD_ATTRS = frozenset(logging.LogRecord("", 0, "", 0, "", (), None).__dict__) | {"message", "asctime"}
_JSON_FIXED = ("time", "level", "logger", "message", "exception", "stack")


#: Repeats of one warning within this many seconds are counted instead of written.
REPEAT_WINDOW_S = 60.0
#: Distinct warnings remembered for throttling (the oldest is forgotten first).
REPEAT_KEYS_MAX = 1024

_CONTROL_RE = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")
_CONTROL_ALL_RE = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def escape_controls(text: str, *, keep_newlines: bool = False) -> str:
    """``text`` with control characters written as ``\\xNN`` (NUL, ESC, DEL, C1, and newline/tab unless
    ``keep_newlines``): text from outside cannot forge log lines, drive a terminal, or put NUL into a store."""
    pattern = _CONTROL_RE if keep_newlines else _CONTROL_ALL_RE
    return pattern.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


class EscapeControls(logging.Filter):
    """Escape control characters of each record's message (newlines and tabs kept)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        escaped = escape_controls(message, keep_newlines=True)
        if escaped != message:
            record.msg, record.args = escaped, None
        return True


class RepeatThrottle(logging.Filter):
    """Write a repeated warning once per ``window_s`` and count the copies in between (see the module docstring)."""

    def __init__(self, window_s: float = REPEAT_WINDOW_S, level: int = logging.WARNING,
                 clock: Any = time.monotonic) -> None:
        super().__init__()
        self.window_s = window_s
        self.level = level
        self._clock = clock
        self._seen: dict[tuple[str, int, str], list[float | int]] = {}  # key -> [window start, suppressed]
        self.suppressed_total = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < self.level:
            return True
        key = (record.name, record.levelno, record.getMessage())
        now = self._clock()
        entry = self._seen.get(key)
        if entry is not None and now - entry[0] < self.window_s:
            entry[1] += 1
            self.suppressed_total += 1
            return False
        if entry is not None and entry[1]:
            record.msg, record.args = f"{key[2]} [and {entry[1]} more times in the last {now - entry[0]:.0f} s]", None
        self._seen.pop(key, None)
        self._seen[key] = [now, 0]
        if len(self._seen) > REPEAT_KEYS_MAX:
            self._seen.pop(next(iter(self._seen)))
        return True

    def pending(self) -> list[logging.LogRecord]:
        """Records that report the copies counted but not yet written (then forgotten)."""
        out = []
        now = self._clock()
        for (name, levelno, message), (start, count) in self._seen.items():
            if count:
                out.append(logging.LogRecord(name, levelno, "", 0, "%s [and %d more times in the last %.0f s]",
                                             (message, count, now - start), None))
        self._seen.clear()
        return out


def syslog_priority(levelno: int) -> int:
    """The syslog priority of a logging level (sd-daemon(3)); a level between two standard ones maps down."""
    if levelno >= logging.CRITICAL:
        return 2
    if levelno >= logging.ERROR:
        return 3
    if levelno >= logging.WARNING:
        return 4
    if levelno >= logging.INFO:
        return 6
    return 7


class JournalFormatter(logging.Formatter):
    """No timestamp; every line prefixed with ``<N>``, the record's syslog priority."""

    def __init__(self) -> None:
        super().__init__(JOURNAL_FORMAT)

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{syslog_priority(record.levelno)}>"
        text = super().format(record).rstrip("\n")
        return "\n".join(prefix + line for line in text.split("\n"))


def _jsonable(value: Any) -> Any:
    """``value`` if ``json.dumps`` writes it as valid JSON, else ``str(value)``."""
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError, RecursionError):
        return str(value)
    return value


class JsonFormatter(logging.Formatter):
    """One JSON object per record, on one line (see the module docstring for the fields)."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds").replace(
                "+00:00", "Z"
            ),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info and not record.exc_text:
            record.exc_text = self.formatException(record.exc_info)
        if record.exc_text:
            doc["exception"] = record.exc_text
        if record.stack_info:
            doc["stack"] = self.formatStack(record.stack_info)
        for key, value in record.__dict__.items():
            if key in _RECORD_ATTRS:
                continue
            doc[f"extra_{key}" if key in _JSON_FIXED else key] = _jsonable(value)
        return json.dumps(doc, allow_nan=False, ensure_ascii=False)


def journal_connected(stream: IO[Any] | None = None, environ: Mapping[str, str] | None = None) -> bool:
    """Whether ``stream`` (default stderr) is the journal's stream: ``$JOURNAL_STREAM`` is its ``device:inode``."""
    env = os.environ if environ is None else environ
    value = env.get("JOURNAL_STREAM", "")
    dev, sep, ino = value.partition(":")
    if not sep or not dev.isdigit() or not ino.isdigit():
        return False
    stream = sys.stderr if stream is None else stream
    try:
        st = os.fstat(stream.fileno())
    except (AttributeError, OSError, ValueError):  # no stream, no file descriptor, or closed
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


def choose_format(option: str | None, environ: Mapping[str, str] | None = None) -> str:
    """The format asked for: the command-line option, else ``$RGSE_LOG_FORMAT``, else ``auto``.

    Raises ``ValueError`` naming the variable when ``$RGSE_LOG_FORMAT`` is set to something else than a format
    (also when the option is given: a bad setting should not go unnoticed).
    """
    env = os.environ if environ is None else environ
    from_env = env.get(ENV_VAR)
    if from_env is not None and from_env not in FORMATS:
        raise ValueError(f"{ENV_VAR}={from_env!r} is not one of {', '.join(FORMATS)}")
    if option is not None:
        if option not in FORMATS:
            raise ValueError(f"log format {option!r} is not one of {', '.join(FORMATS)}")
        return option
    return from_env or "auto"


def make_formatter(fmt: str, stream: IO[Any] | None = None) -> logging.Formatter:
    """The formatter of a format; ``auto`` is decided with :func:`journal_connected` on ``stream``."""
    if fmt == "auto":
        fmt = "journal" if journal_connected(stream) else "text"
    if fmt == "text":
        return logging.Formatter(TEXT_FORMAT)
    if fmt == "journal":
        return JournalFormatter()
    if fmt == "json":
        return JsonFormatter()
    raise ValueError(f"log format {fmt!r} is not one of {', '.join(FORMATS)}")


class _RgseHandler(logging.StreamHandler):
    """The handler :func:`setup_logging` installs; told apart from handlers others installed. Escapes control
    characters and throttles repeats; on close it writes the counts of repeats not yet reported."""

    def __init__(self, stream: IO[Any]) -> None:
        super().__init__(stream)
        self.addFilter(EscapeControls())
        self.throttle = RepeatThrottle()
        self.addFilter(self.throttle)

    def close(self) -> None:
        for record in self.throttle.pending():
            super().emit(record)
        super().close()


def setup_logging(level: int, fmt: str = "auto", stream: IO[Any] | None = None) -> logging.Handler | None:
    """Send the root logger's records at ``level`` and above to ``stream`` (default stderr) in format ``fmt``.

    A second call replaces the handler of the first. Like ``logging.basicConfig``, it leaves a logging setup
    made by someone else alone (root already has other handlers: an embedding program, pytest's capture) and
    returns ``None`` then; otherwise the installed handler.
    """
    root = logging.getLogger()
    ours = [h for h in root.handlers if isinstance(h, _RgseHandler)]
    if len(ours) != len(root.handlers):
        return None
    stream = sys.stderr if stream is None else stream
    handler = _RgseHandler(stream)
    handler.setFormatter(make_formatter(fmt, stream))
    for old in ours:
        root.removeHandler(old)
        old.close()
    root.addHandler(handler)
    root.setLevel(level)
    return handler
