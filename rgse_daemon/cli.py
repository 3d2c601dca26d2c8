"""The ``rgse`` command (interfaces §1): parses arguments, then hands over to one module per sub-command.

Each sub-command lives in ``rgse_daemon/commands/<name>.py`` and exposes ``add_arguments(parser)`` and
``run(args) -> int``; this module holds the list of them and the wiring. Errors that come from outside input
(config, data files, KRL syntax) end in a one-line message and exit status 2; ``--debug`` shows the traceback
instead.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import sys
from collections.abc import Collection, Sequence
from types import ModuleType
from typing import NoReturn

from rgse_daemon import __version__
from rgse_daemon.errors import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_OK,
    EXIT_REFUSED,
    EXIT_WARNINGS,
    ConfigError,
    DataError,
    KrlSyntaxError,
    RgseError,
)
from rgse_daemon.logs import ENV_VAR as LOG_FORMAT_ENV
from rgse_daemon.logs import FORMATS as LOG_FORMATS
from rgse_daemon.logs import choose_format, setup_logging
from rgse_daemon.verdict import refusal

__all__ = ["COMMANDS", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_OK", "EXIT_REFUSED", "EXIT_WARNINGS", "build_parser",
           "main"]

#: Offline computations whose ``--json`` prints a refusal as one JSON object on stdout (interfaces §1.3), so that a
#: script reading stdout always gets an object with a ``status``, a refusal's ``reason`` among it.
JSON_REFUSALS = frozenset({"mass", "cog", "inertia"})


class _Parser(argparse.ArgumentParser):
    """Bad arguments end in one line (``rgse mass: error: ...``) and exit 2, like every other bad input."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


#: The sub-commands, in the order ``rgse --help`` lists them, with their line there. Each is the module
#: ``rgse_daemon/commands/<name>.py`` (``-`` as ``_``): ``add_arguments(parser)`` adds its arguments, ``run(args)``
#: runs it.
COMMANDS: dict[str, str] = {
    "demo": "calibration campaign + in-line measurement on the built-in simulator",
    "sim": "run the simulated KR C4 as a server until SIGINT/SIGTERM",
    "sim-op": "act on a running rgse sim as a person at the robot: mount a load, mode, enabling switch",
    "daemon": "run the service (systemd entry point)",
    "calibrate": "fit a calibration from Table-1 style points or a campaign",
    "activate": "make a CAL.json the active calibration of the configured robot",
    "certificate": "the one-page PDF measurement certificate of a run's result",
    "runs": "the history of runs and results from the store: filter, table, CSV, JSON",
    "mass": "offline in-line mass from a measurement directory",
    "cog": "offline centre of gravity from a properties run directory",
    "inertia": "offline inertia tensor from a run directory with DuT and tare motion traces",
    "study": "the pre-processing parameter study (paper Table A2), ranked",
    "plan": "plan a calibration campaign for a DuT range: points, robot time, predicted U",
    "report": "self-contained HTML report of a measurement run or a calibration",
    "reference": "crane-scale reference weighing of a run, compared as in paper Table 2",
    "krl": "KRL programs: static check, rendering",
    # Operator commands: talk to a running daemon over its MQTT broker (configured in FILE).
    "confirm": "tell the running daemon that the step its run waits for is done",
    "abort": "stop the running daemon's run now",
    "doctor": "commissioning checklist of the controller, I/O, scale, broker and store",
    "safety": "the safety latch: set when a stop could not be confirmed; no run until cleared",
    "status": "the running daemon's retained status, state and results",
    "run": "start a measurement, a properties run or a campaign on the running daemon and follow it",
}


def command_module(name: str) -> ModuleType:
    """The module of sub-command ``name``."""
    return importlib.import_module(f"rgse_daemon.commands.{name.replace('-', '_')}")


def build_parser(only: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``rgse`` parser. ``only``: the sub-commands that get their arguments (the others are listed, no more), so
    that only their modules are imported (all of them take seconds: numpy, the simulator, the report); ``None``:
    every sub-command."""
    parser = _Parser(
        prog="rgse", description="Robotic GSE in-line mass determination on a KUKA KR C4, automated."
    )
    parser.add_argument("--version", action="version", version=f"rgse {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    parser.add_argument("-v", "--verbose", action="store_true", help="info logs on stderr")
    parser.add_argument(
        "--log-format", choices=LOG_FORMATS, default=None,
        help=f"log lines on stderr: text, journal (systemd priority prefixes), json (one object a line); auto "
        f"(default) is journal when stderr is the journal, else text; overrides ${LOG_FORMAT_ENV}",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, line in COMMANDS.items():
        p = sub.add_parser(name, help=line)
        if only is None or name in only:
            command_module(name).add_arguments(p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # The sub-command is the first word that names one (no value of rgse's own options does).
    args = build_parser([word for word in argv if word in COMMANDS][:1]).parse_args(argv)
    try:
        log_format = choose_format(args.log_format)
    except ValueError as exc:
        print(f"rgse: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    setup_logging(logging.DEBUG if args.debug else logging.INFO if args.verbose else logging.WARNING, log_format)
    try:
        return int(command_module(args.command).run(args))
    except (ConfigError, DataError, KrlSyntaxError) as exc:
        _json_refusal(args, exc)
        if args.debug:
            raise
        print(f"rgse {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RgseError as exc:
        _json_refusal(args, exc)
        if args.debug:
            raise
        print(f"rgse {args.command}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (`rgse study | head`): not an error of ours. Point stdout at devnull so the
        # interpreter's final flush does not raise again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK


def _json_refusal(args: argparse.Namespace, exc: RgseError) -> None:
    """With ``--json``, an offline computation's refusal is its one JSON object on stdout (the line on stderr stays)."""
    if getattr(args, "json", False) and args.command in JSON_REFUSALS:
        print(json.dumps(refusal(str(exc), error=type(exc).__name__)), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
