"""Log formats on stderr (rgse_daemon/logs.py): the real ``rgse`` in subprocesses, plus the formatters on records.

No command logs a warning quickly and deterministically, so the subprocess tests use two real paths:

* ``rgse --debug sim --port 0``, stopped with SIGTERM once it listens: DEBUG (asyncio's selector) and INFO lines
  (``simulators.krc4.server``, ``rgse_daemon.commands.sim``) from the unmodified command;
* ``rgse_daemon.cli.main`` in a child whose ``krl`` command is replaced by one that logs every level, ``extra=``
  fields and a traceback — the option parsing, the environment and the handler on the child's stderr are real.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import signal
import subprocess
import sys
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from rgse_daemon.logs import (
    JournalFormatter,
    JsonFormatter,
    choose_format,
    journal_connected,
    make_formatter,
    syslog_priority,
)

REPO = Path(__file__).resolve().parents[2]
TIMEOUT_S = 60.0
PRIORITY = {"DEBUG": 7, "INFO": 6, "WARNING": 4, "ERROR": 3, "CRITICAL": 2}
TIMESTAMP = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} ")
JOURNAL_LINE = re.compile(r"<([0-7])>(.*)\Z")

#: A child that runs the real ``main`` with ``rgse krl check``'s ``run`` replaced by one that logs.
CHILD = """
import logging, sys
import rgse_daemon.commands.krl as krl
from rgse_daemon.cli import main

class Watcher:
    def __str__(self):
        return "watcher<speed>"

def run(args):
    log = logging.getLogger("rgse_daemon.procedures.engine")
    log.debug("debug line")
    log.info("info line", extra={"run_id": "R-0001", "robot": "KR500R2830"})
    log.warning("run %s: speed limit near", "R-0001",
                extra={"run_id": "R-0001", "watcher": Watcher(), "point": [1, 2.5], "bad": float("nan")})
    log.error("two lines\\nsecond line")
    log.critical("critical line")
    try:
        raise ValueError("boom")
    except ValueError:
        log.exception("step failed", extra={"run_id": "R-0001"})
    return 0

krl.run = run
sys.exit(main(sys.argv[1:]))
"""


def _env(**values: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("JOURNAL_STREAM", "RGSE_LOG_FORMAT")}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    env.update(values)
    return env


def _dev_ino(path: Path) -> str:
    st = os.stat(path)
    return f"{st.st_dev}:{st.st_ino}"


def run_child(tmp_path: Path, *args: str, journal: str | None = None, **env: str) -> tuple[int, str, str]:
    """Run :data:`CHILD` with ``args``; stderr goes to a file. ``journal``: "match" (JOURNAL_STREAM is that file's
    device:inode), "other" (another file's) or None (unset). Returns (exit status, stdout, stderr)."""
    err_path = tmp_path / "stderr.txt"
    with err_path.open("wb") as err:
        if journal == "match":
            env["JOURNAL_STREAM"] = _dev_ino(err_path)
        elif journal == "other":
            other = tmp_path / "other.txt"
            other.touch()
            env["JOURNAL_STREAM"] = _dev_ino(other)
        proc = subprocess.run(
            [sys.executable, "-c", CHILD, *args, "krl", "check", str(tmp_path / "x.src")],
            stdout=subprocess.PIPE, stderr=err, env=_env(**env), text=True, timeout=TIMEOUT_S, cwd=tmp_path,
        )  # fmt: skip
    return proc.returncode, proc.stdout, err_path.read_text()


def run_sim(tmp_path: Path, *args: str, journal: bool = False) -> str:
    """``rgse <args> sim --port 0`` until it listens, then SIGTERM; returns its stderr (written to a file)."""
    err_path = tmp_path / "sim-stderr.txt"
    env: dict[str, str] = {}
    with err_path.open("wb") as err:
        if journal:
            env["JOURNAL_STREAM"] = _dev_ino(err_path)
        proc = subprocess.Popen(
            [sys.executable, "-m", "rgse_daemon.cli", *args, "sim", "--host", "127.0.0.1", "--port", "0",
             "--share", str(tmp_path / "share")],
            stdout=subprocess.PIPE, stderr=err, env=_env(**env), text=True, cwd=tmp_path,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            assert line.startswith("rgse sim: listening on"), (line, err_path.read_text())
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=TIMEOUT_S)
        finally:
            if proc.returncode is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0, err_path.read_text()
    return err_path.read_text()


def journal_lines(text: str) -> list[tuple[int, str]]:
    """(priority, rest) of every line; fails on a line without the ``<N>`` prefix."""
    out = []
    for line in text.splitlines():
        m = JOURNAL_LINE.match(line)
        assert m, f"line without a priority prefix: {line!r}"
        out.append((int(m.group(1)), m.group(2)))
    return out


# --- the real command in a subprocess ---------------------------------------------------------------------------


def test_sim_auto_on_the_journal_prefixes_every_line(tmp_path: Path) -> None:
    lines = journal_lines(run_sim(tmp_path, "--debug", journal=True))
    assert {p for p, _ in lines} >= {6, 7}
    for prio, rest in lines:
        assert not TIMESTAMP.match(rest), rest
        level = rest.split(" ", 1)[0]
        assert PRIORITY[level] == prio, (prio, rest)
    assert any(rest.startswith("INFO rgse_daemon.commands.sim: simulated KR C4 stopped") for _, rest in lines)


def test_sim_auto_off_the_journal_is_text(tmp_path: Path) -> None:
    lines = run_sim(tmp_path, "-v").splitlines()
    assert lines and all(TIMESTAMP.match(line) for line in lines), lines
    assert not any(line.startswith("<") for line in lines)
    assert any(" INFO rgse_daemon.commands.sim: simulated KR C4 stopped" in line for line in lines)


def test_sim_json(tmp_path: Path) -> None:
    lines = run_sim(tmp_path, "-v", "--log-format", "json").splitlines()
    assert lines
    docs = [json.loads(line) for line in lines]
    for doc in docs:
        assert {"time", "level", "logger", "message"} <= set(doc)
        assert datetime.fromisoformat(doc["time"]).utcoffset().total_seconds() == 0
    assert {"level": "INFO", "logger": "rgse_daemon.commands.sim"}.items() <= docs[-1].items()
    assert docs[-1]["message"] == "simulated KR C4 stopped after 0 requests"


@pytest.mark.parametrize("journal", ["match", "other", None])
def test_journal_stream_decides_auto(tmp_path: Path, journal: str | None) -> None:
    rc, _, err = run_child(tmp_path, journal=journal)
    assert rc == 0, err
    if journal == "match":
        lines = journal_lines(err)
        assert {p for p, _ in lines} == {2, 3, 4}  # WARNING and above without -v
    else:
        assert TIMESTAMP.match(err), err
        assert "<4>" not in err


def test_journal_every_level_and_traceback_keep_the_priority(tmp_path: Path) -> None:
    rc, _, err = run_child(tmp_path, "--debug", journal="match")
    assert rc == 0, err
    lines = journal_lines(err)
    firsts = [(p, rest) for p, rest in lines if rest.split(" ", 1)[0] in PRIORITY]
    assert [p for p, _ in firsts] == [7, 6, 4, 3, 2, 3]
    assert all(not TIMESTAMP.match(rest) for _, rest in lines)
    assert (3, "second line") in lines  # a multi-line message: the continuation keeps <3>
    start = lines.index((3, "ERROR rgse_daemon.procedures.engine: step failed"))
    tb = lines[start + 1:]
    assert tb[0] == (3, "Traceback (most recent call last):")
    assert tb[-1] == (3, "ValueError: boom")
    assert len(tb) >= 3 and all(p == 3 for p, _ in tb)


def test_json_lines_carry_extra_fields(tmp_path: Path) -> None:
    rc, _, err = run_child(tmp_path, "--debug", "--log-format", "json", journal="match")  # the option beats auto
    assert rc == 0, err
    docs = [json.loads(line) for line in err.splitlines()]
    assert [d["level"] for d in docs] == ["DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL", "ERROR"]
    assert all(d["logger"] == "rgse_daemon.procedures.engine" for d in docs)
    info, warning, error, _, exc = docs[1:]
    assert info["run_id"] == "R-0001" and info["robot"] == "KR500R2830"
    assert warning["message"] == "run R-0001: speed limit near"
    assert warning["watcher"] == "watcher<speed>" and warning["point"] == [1, 2.5] and warning["bad"] == "nan"
    assert error["message"] == "two lines\nsecond line" and "exception" not in error
    assert exc["run_id"] == "R-0001"
    assert exc["exception"].startswith("Traceback (most recent call last):")
    assert exc["exception"].endswith("ValueError: boom")


@pytest.mark.parametrize(
    ("args", "env", "expect"),
    [
        ((), {"RGSE_LOG_FORMAT": "json"}, "json"),
        ((), {"RGSE_LOG_FORMAT": "text"}, "text"),
        (("--log-format", "text"), {"RGSE_LOG_FORMAT": "json"}, "text"),
        (("--log-format", "journal"), {}, "journal"),
    ],
)
def test_environment_and_option(tmp_path: Path, args: tuple[str, ...], env: dict[str, str], expect: str) -> None:
    rc, _, err = run_child(tmp_path, *args, **env)
    assert rc == 0, err
    first = err.splitlines()[0]
    if expect == "json":
        assert json.loads(first)["level"] == "WARNING"
    elif expect == "text":
        assert TIMESTAMP.match(first), first
    else:
        assert first.startswith("<4>WARNING "), first


@pytest.mark.parametrize("args", [(), ("--log-format", "text")])
def test_bad_environment_value_exits_2(tmp_path: Path, args: tuple[str, ...]) -> None:
    rc, out, err = run_child(tmp_path, *args, RGSE_LOG_FORMAT="bogus")
    assert rc == 2
    assert out == ""
    assert err.count("\n") == 1 and "RGSE_LOG_FORMAT" in err and "bogus" in err and "Traceback" not in err, err


def test_bad_option_value_exits_2(tmp_path: Path) -> None:
    rc, _, err = run_child(tmp_path, "--log-format", "xml")
    assert rc == 2 and "--log-format" in err


# --- the pieces, in process -------------------------------------------------------------------------------------


def _record(level: int, msg: str, *args: Any, exc: bool = False, **extra: Any) -> logging.LogRecord:
    exc_info = None
    if exc:
        try:
            raise RuntimeError("inner")
        except RuntimeError:
            exc_info = sys.exc_info()
    record = logging.LogRecord("rgse_daemon.app", level, __file__, 1, msg, args, exc_info)
    record.__dict__.update(extra)
    return record


@pytest.mark.parametrize(
    ("level", "prio"),
    [(logging.DEBUG, 7), (5, 7), (logging.INFO, 6), (25, 6), (logging.WARNING, 4), (logging.ERROR, 3),
     (logging.CRITICAL, 2), (60, 2)],
)  # fmt: skip
def test_syslog_priority(level: int, prio: int) -> None:
    assert syslog_priority(level) == prio


def test_journal_formatter_lines() -> None:
    fmt = JournalFormatter()
    assert fmt.format(_record(logging.WARNING, "a %s", "b")) == "<4>WARNING rgse_daemon.app: a b"
    assert fmt.format(_record(logging.INFO, "x\n\ny\n")) == "<6>INFO rgse_daemon.app: x\n<6>\n<6>y"
    lines = fmt.format(_record(logging.CRITICAL, "down", exc=True)).split("\n")
    assert lines[1] == "<2>Traceback (most recent call last):" and lines[-1] == "<2>RuntimeError: inner"
    assert all(line.startswith("<2>") for line in lines)


def test_json_formatter_fields_and_unserialisable_extras() -> None:
    loop: list[Any] = []
    loop.append(loop)
    record = _record(
        logging.ERROR, "m %d", 3, exc=True,
        run_id="R1", n=None, inf=math.inf, keys={(1, 2): "tuple key"}, loop=loop, logger="clash", path=Path("/x"),
    )  # fmt: skip
    doc = json.loads(JsonFormatter().format(record))
    assert doc["level"] == "ERROR" and doc["logger"] == "rgse_daemon.app" and doc["message"] == "m 3"
    assert doc["time"].endswith("Z")
    assert datetime.fromisoformat(doc["time"]).timestamp() == pytest.approx(record.created, abs=1e-3)
    assert doc["exception"].endswith("RuntimeError: inner")
    assert doc["run_id"] == "R1" and doc["n"] is None and doc["inf"] == "inf"
    assert doc["keys"] == "{(1, 2): 'tuple key'}" and doc["loop"] == "[[...]]" and doc["path"] == "/x"
    assert doc["extra_logger"] == "clash"
    assert "stack" not in doc and "args" not in doc and "msg" not in doc
    plain = json.loads(JsonFormatter().format(_record(logging.INFO, "no exception")))
    assert set(plain) == {"time", "level", "logger", "message"}


def test_journal_connected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "s"
    with path.open("w") as stream:
        st = os.fstat(stream.fileno())
        assert journal_connected(stream, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})
        assert not journal_connected(stream, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino + 1}"})
        assert not journal_connected(stream, {})
        for bad in ("", "garbage", f"{st.st_dev}", f"{st.st_dev}:", f"x:{st.st_ino}"):
            assert not journal_connected(stream, {"JOURNAL_STREAM": bad})
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        assert isinstance(make_formatter("auto", stream), JournalFormatter)
        monkeypatch.delenv("JOURNAL_STREAM")
        auto = make_formatter("auto", stream)
        assert type(auto) is logging.Formatter and auto._fmt == "%(asctime)s %(levelname)s %(name)s: %(message)s"
    assert not journal_connected(stream, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})  # closed


def test_choose_format() -> None:
    assert choose_format(None, {}) == "auto"
    assert choose_format(None, {"RGSE_LOG_FORMAT": "json"}) == "json"
    assert choose_format("text", {"RGSE_LOG_FORMAT": "json"}) == "text"
    with pytest.raises(ValueError, match="RGSE_LOG_FORMAT='JSON'"):
        choose_format(None, {"RGSE_LOG_FORMAT": "JSON"})
    with pytest.raises(ValueError, match="RGSE_LOG_FORMAT"):
        choose_format("json", {"RGSE_LOG_FORMAT": ""})
    with pytest.raises(ValueError, match="xml"):
        choose_format("xml", {})
