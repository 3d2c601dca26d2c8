"""The ``rgse`` command (interfaces §1): parses arguments, then hands over to one module per sub-command.

Each sub-command lives in ``rgse_daemon/commands/<name>.py`` and exposes ``run(args) -> int``. Errors that
come from outside input (config, data files, KRL syntax) end in a one-line message and exit status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
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

__all__ = ["EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_OK", "EXIT_REFUSED", "EXIT_WARNINGS", "build_parser", "main"]

#: Offline computations whose ``--json`` prints a refusal as one JSON object on stdout (interfaces §1.3), so that a
#: script reading stdout always gets an object with a ``status``, a refusal's ``reason`` among it.
JSON_REFUSALS = frozenset({"mass", "cog", "inertia"})


class _Parser(argparse.ArgumentParser):
    """Bad arguments end in one line (``rgse mass: error: ...``) and exit 2, like every other bad input."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def finite(text: str) -> float:
    """An argparse type: a finite number (``nan``/``inf`` are refused as such)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive(text: str) -> float:
    """An argparse type: a finite number > 0 (a timeout, a time scale)."""
    value = finite(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")


def build_parser() -> argparse.ArgumentParser:
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

    p = sub.add_parser("demo", help="calibration campaign + in-line measurement on the built-in simulator")
    _add_json(p)
    p.add_argument("--report", type=Path, metavar="DIR", help="also write the HTML report into DIR")
    p.add_argument("--mqtt", metavar="URL", help="also publish on this broker, e.g. mqtt://127.0.0.1:1883")
    p.add_argument("--console", type=int, metavar="PORT", help="also serve the web console on 127.0.0.1:PORT")
    p.add_argument("--inertia", action="store_true",
                   help="the properties run also measures the inertia tensor (DuT and tare excitation)")
    p.add_argument("--seed", type=int, default=2024, metavar="N",
                   help="the simulated robot's seed (gains, offsets, noise; default 2024)")
    p.add_argument("--robot", default="kr500r2830", metavar="MODEL",
                   help="the simulated arm: kr500r2830 (default, the paper's) or kr10r1440 (its subscale bench)")

    p = sub.add_parser("sim", help="run the simulated KR C4 as a server until SIGINT/SIGTERM")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=7000)
    p.add_argument("--share", type=Path, metavar="DIR", help="the controller's 'roboter' share directory")
    p.add_argument("--scenario", type=Path, metavar="FILE", help="scenario TOML (physics, errors, faults)")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X", help="simulated s per wall s")
    p.add_argument("--globals", type=Path, metavar="FILE",
                   help="install this rgse_globals.dat (from rgse krl render) at start, as done once on a real "
                        "controller: without it the programs stop at their first handshake variable")
    p.add_argument("--control-port", type=int, default=None, metavar="PORT",
                   help="what a person at the robot does, for rgse sim-op (default --port + 1 on --host, any free "
                        "port with --port 0; -1: none)")
    p.add_argument("--commission", action="store_true",
                   help="commission as a real KR C4 is once: handshake globals, RGSE_GLOBALS.DAT and the resident "
                        "program (rendered with --config) installed, so rgse doctor passes")
    p.add_argument("--config", type=Path, metavar="FILE", help="with --commission: the daemon's configuration")

    p = sub.add_parser("sim-op", help="act on a running rgse sim as a person at the robot: mount a load, mode, "
                                      "enabling switch")
    p.add_argument("--control", default="127.0.0.1:7001", metavar="HOST:PORT", help="rgse sim's control port")
    p.add_argument("--timeout", type=positive, default=5.0, metavar="S")
    _add_json(p)
    ops = p.add_subparsers(dest="op", required=True, metavar="ACTION")
    o = ops.add_parser("mount", help="mount a load (replaces what was mounted)")
    what = o.add_mutually_exclusive_group(required=True)
    what.add_argument("--nothing", action="store_true", help="the bare flange")
    what.add_argument("--mpa", action="store_true", help="the mounting plate (MPA) alone: a campaign's zero point")
    what.add_argument("--bodies", type=int, metavar="N", help="the MPA with N calibration bodies (a mass point)")
    what.add_argument("--torque", type=int, metavar="N",
                      help="the test adapter with N bodies (a torque point; with --lever-a5)")
    what.add_argument("--dut", type=finite, metavar="KG", help="a device under test of KG on its fixture (with --cog)")
    o.add_argument("--lever-a5", type=finite, metavar="M", help="--torque: the bodies' lever from A5 (m)")
    o.add_argument("--cog", type=finite, nargs=3, metavar=("X", "Y", "Z"), help="--dut: CoG in the flange frame (m)")
    o.add_argument("--inertia", type=finite, nargs=3, metavar=("JX", "JY", "JZ"),
                   help="--dut: principal moments about the CoG along the flange axes (kg m^2)")
    o.add_argument("--fixture-mass", type=finite, metavar="KG", help="--dut: the fixture's mass (default 10.288)")
    o = ops.add_parser("mode", help="turn the mode selector")
    o.add_argument("mode", choices=("T1", "T2", "AUT", "EX"))
    o = ops.add_parser("enabling-switch", help="hold or release the smartPAD's enabling switch")
    o.add_argument("state", choices=("hold", "release"))
    ops.add_parser("acknowledge", help="acknowledge the stop message on the smartPAD")
    ops.add_parser("status", help="what is mounted, the mode and the program state")

    p = sub.add_parser("daemon", help="run the service (systemd entry point)")
    p.add_argument("--config", type=Path, required=True, metavar="FILE")

    p = sub.add_parser("calibrate", help="fit a calibration from Table-1 style points or a campaign")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--points", type=Path, metavar="CSV")
    src.add_argument("--campaign", type=Path, metavar="DIR")
    p.add_argument("--out", type=Path, required=True, metavar="CAL.json")
    p.add_argument("--method", default="paper", metavar="paper|auto|NAME")
    p.add_argument("--preprocessing", metavar="paper|KEY=VALUE,...",
                   help="campaign pre-processing: paper (method F, default) or e.g. a row of rgse study "
                        "(crop_sigma=2,filter=gaussian,window=100,order=forward,location=huber)")
    _add_json(p)

    p = sub.add_parser("activate", help="make a CAL.json the active calibration of the configured robot")
    p.add_argument("calibration", type=Path, metavar="CAL.json")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its robot and store)")
    p.add_argument("--note", metavar="TEXT", help="why, recorded with the activation")
    _add_json(p)

    p = sub.add_parser("certificate", help="the one-page PDF measurement certificate of a run's result")
    p.add_argument("run_id", metavar="RUN_ID")
    p.add_argument("--out", type=Path, metavar="FILE.pdf",
                   help="where to write it (default <data_dir>/reports/certificate-RUN_ID.pdf)")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its store)")

    p = sub.add_parser("runs", help="the history of runs and results from the store: filter, table, CSV, JSON")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (its store)")
    p.add_argument("--robot", metavar="NAME", help="only this robot's runs (default: every robot in the store)")
    p.add_argument("--kind", choices=("measurement", "calibration"))
    p.add_argument("--state", choices=("queued", "running", "completed", "failed", "interrupted", "aborted"))
    p.add_argument("--status", choices=("ok", "warning", "refused"), help="only results of this status")
    p.add_argument("--dut", metavar="TEXT", help="DuT name, serial or part number or project contains TEXT")
    p.add_argument("--since", metavar="DATE", help="created on or after (2026-11-28 or an ISO 8601 time, UTC)")
    p.add_argument("--until", metavar="DATE", help="created on or before")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--csv", action="store_true", help="CSV with the fields of docs/interfaces.md §1.4")
    _add_json(fmt)
    p.add_argument("--out", type=Path, metavar="FILE", help="write to FILE instead of stdout")

    p = sub.add_parser("mass", help="offline in-line mass from a measurement directory")
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, required=True, metavar="CAL.json")
    p.add_argument("--fixture-mass", type=finite, metavar="KG")
    p.add_argument("--envelope-limit", type=finite, default=0.5, metavar="FRACTION",
                   help="refuse a DuT further outside the calibrated loads than this fraction of their span "
                        "(default 0.5)")
    p.add_argument("--drift-prior", type=finite, default=0.003, metavar="PER_K",
                   help="bound on the thermal drift coefficient |β| (1/K) that U carries where the campaign does not "
                        "resolve β (default 0.003, i.e. 0.3 %%/K)")
    _add_json(p)

    p = sub.add_parser("cog", help="offline centre of gravity from a properties run directory")
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, required=True, metavar="CAL.json")
    _add_json(p)

    p = sub.add_parser("inertia", help="offline inertia tensor from a run directory with DuT and tare motion traces")
    p.add_argument("--traces", type=Path, required=True, metavar="DIR")
    p.add_argument("--calibration", type=Path, metavar="CAL.json",
                   help="take the readings through its torsional gain curves of A4..A6 (default: 1:1)")
    _add_json(p)

    p = sub.add_parser("study", help="the pre-processing parameter study (paper Table A2), ranked")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--campaign", type=Path, metavar="DIR")
    src.add_argument("--points", type=Path, metavar="CSV")
    _add_json(p)

    p = sub.add_parser("plan", help="plan a calibration campaign for a DuT range: points, robot time, predicted U")
    p.add_argument("--mass", type=finite, nargs=2, metavar=("KG", "KG"),
                   help="the DuTs' mass range (what is mounted on the MPA), kg")
    p.add_argument("--lever-a5", type=finite, nargs=2, metavar=("M", "M"),
                   help="the DuTs' CoG lever range along the flange axis from A5, m")
    p.add_argument("--dut", type=finite, nargs=2, action="append", metavar=("KG", "M"),
                   help="one DuT (mass, lever from A5), instead of a range; repeat for a list")
    p.add_argument("--loops-per-point", type=int, default=3, metavar="N", help="loops per point (default 3)")
    p.add_argument("--max-distance", type=finite, default=0.15, metavar="D",
                   help="a DuT is covered within D of a calibrated point (torque over the range's largest, per axis)")
    p.add_argument("--config", type=Path, metavar="FILE", help="the daemon's configuration (settling, warm-up)")
    p.add_argument("--points-out", type=Path, metavar="FILE.toml", help="write the points for rgse run calibrate")
    _add_json(p)

    p = sub.add_parser("report", help="self-contained HTML report of a measurement run or a calibration")
    p.add_argument("run_id", nargs="?", metavar="RUN_ID", help="a measurement run")
    p.add_argument("--calibration", metavar="ID", help="report a calibration instead of a run")
    p.add_argument("--out", type=Path, metavar="DIR", help="directory for the HTML file (default <data_dir>/reports)")
    p.add_argument("--config", type=Path, metavar="FILE")

    p = sub.add_parser("reference", help="crane-scale reference weighing of a run, compared as in paper Table 2")
    p.add_argument("--run", required=True, metavar="RUN_ID")
    p.add_argument("--config", type=Path, metavar="FILE")
    p.add_argument("--weighed", choices=("gross", "net"), default="gross",
                   help="gross: DuT and fixture hang on the scale together (the paper's 117.6 kg)")
    p.add_argument("--timeout", type=positive, metavar="S", help="wait at most S s for a stable weighing")
    p.add_argument("--operators", type=int, metavar="N", help="operators of the crane-scale procedure (Table 2)")
    p.add_argument("--operation-min", type=positive, metavar="MIN", help="its total time of operation (Table 2)")
    _add_json(p)

    p = sub.add_parser("krl", help="KRL programs: static check, rendering")
    krl_sub = p.add_subparsers(dest="krl_command", required=True, metavar="ACTION")
    c = krl_sub.add_parser("check", help="the interlock's static check (exit 3 if refused)")
    c.add_argument("file", type=Path, metavar="FILE.src")
    c.add_argument("--config", type=Path, metavar="FILE")
    c.add_argument("--payload", type=float, metavar="KG",
                   help="the DuT's mass mounted (kg; default: cell.dut_mass_kg, else the worst credible)")
    c.add_argument("--cog", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="the DuT's CoG in the flange frame (m; default: cell.dut_cog_flange_m, else worst credible)")
    r = krl_sub.add_parser("render", help="render every template in krl/ with the configured defaults")
    r.add_argument("--out", type=Path, required=True, metavar="DIR")
    r.add_argument("--config", type=Path, metavar="FILE")

    # Operator commands: talk to a running daemon over its MQTT broker (configured in FILE).
    p = sub.add_parser("confirm", help="tell the running daemon that the step its run waits for is done")
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--run", metavar="RUN_ID", help="the run waiting (default: the run of the daemon's state)")
    p.add_argument("--point", type=int, metavar="N", help="index of the campaign point whose load is mounted")
    p.add_argument("--message", metavar="TEXT", help="the operator's note, recorded with the confirmation")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the reply (default 10)")

    p = sub.add_parser("abort", help="stop the running daemon's run now")
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--reason", metavar="TEXT", help="why (recorded with the run)")
    p.add_argument("--run", metavar="RUN_ID", help="abort only this run (default: the run in progress)")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the reply (default 10)")

    p = sub.add_parser("doctor", help="commissioning checklist of the controller, I/O, scale, broker and store")
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--no-record", action="store_true", help="do not record the controller's file layout")
    _add_json(p)

    p = sub.add_parser("safety", help="the safety latch: set when a stop could not be confirmed; no run until cleared")
    safety_sub = p.add_subparsers(dest="safety_command", required=True, metavar="ACTION")
    c = safety_sub.add_parser("status", help="show the latch (exit 0 clear, 1 set)")
    c.add_argument("--config", type=Path, required=True, metavar="FILE")
    c = safety_sub.add_parser("clear", help="clear the latch after checking the robot is stopped")
    c.add_argument("--config", type=Path, required=True, metavar="FILE")
    c.add_argument("--message", required=True, metavar="TEXT", help="what the operator checked (logged)")

    p = sub.add_parser("status", help="the running daemon's retained status, state and results")
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the broker (default 10)")
    _add_json(p)


    # rgse run: start a run on the daemon and follow it (on the Python client)
    p = sub.add_parser("run", help="start a measurement, a properties run or a campaign on the running daemon and "
                                        "follow it")
    kinds = p.add_subparsers(dest="run_kind", required=True, metavar="KIND")
    m = kinds.add_parser("measure", help="an in-line measurement of the mounted DuT")
    m.add_argument("--loops", type=int, metavar="N")
    m.add_argument("--fixture-mass", type=float, metavar="KG")
    m.add_argument("--dry-run", action="store_true", help="check and render, move nothing")
    c = kinds.add_parser("calibrate", help="a calibration campaign (confirming each load)")
    c.add_argument("--points", type=Path, metavar="FILE.toml", help="[[point]] tables (default: paper Table 1)")
    c.add_argument("--method", metavar="paper|auto|NAME")
    r = kinds.add_parser("properties", help="a mass-properties run of the mounted DuT: mass, then CoG")
    r.add_argument("--loops", type=int, metavar="N", help="mass loops (default: measurement.loops)")
    r.add_argument("--loops-per-pose", type=int, metavar="N", help="loops in each CoG pose")
    r.add_argument("--scheme", choices=("paper", "full", "lever"), help="the CoG poses (default: properties.scheme)")
    r.add_argument("--mass-method", choices=("single", "multipose", "auto"),
                   help="where the mass comes from (default: properties.mass_method)")
    r.add_argument("--fixture-mass", type=float, metavar="KG")
    r.add_argument("--fixture-cog", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="the fixture's CoG in the flange frame (m); with it the command's fixture frame replaces "
                        "properties.fixture")
    r.add_argument("--dut-origin", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="the DuT frame's origin in the flange frame (m; needs --fixture-cog)")
    r.add_argument("--dut-abc", type=float, nargs=3, metavar=("A", "B", "C"),
                   help="the DuT frame's KUKA A, B, C in the flange frame (deg; needs --fixture-cog)")
    r.add_argument("--inertia", action=argparse.BooleanOptionalAction, default=None,
                   help="also the inertia tensor: DuT and tare excitation, a prompt to take the DuT off "
                        "(default: properties.inertia)")
    r.add_argument("--dry-run", action="store_true", help="check and render, move nothing")
    for q in (m, r):  # the DuT's identity: stored with the run, shown in its report, published with its result
        q.add_argument("--dut-name", metavar="NAME", help="the DuT's name (e.g. the spacecraft's)")
        q.add_argument("--serial-number", metavar="SN", help="the DuT's serial number")
        q.add_argument("--part-number", metavar="PN", help="the DuT's part number")
        q.add_argument("--project", metavar="NAME", help="the project the measurement is for")
        q.add_argument("--operator", metavar="NAME", help="who runs the measurement")
        q.add_argument("--note", metavar="TEXT", help="a free note, kept with the run")
    for q in (m, c, r):
        q.add_argument("--config", type=Path, required=True, metavar="FILE")
        q.add_argument("--on-prompt", choices=("stdin", "wait"), default="stdin",
                       help="stdin: a line on stdin confirms each prompt (default); wait: answered elsewhere")
        q.add_argument("--timeout", type=float, metavar="S",
                       help="the whole run, then it is aborted (default 3600)")
        q.add_argument("--report", type=Path, metavar="DIR", help="also write the HTML report into DIR")
        q.add_argument("--json", action="store_true", help="print the result as one JSON object")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        log_format = choose_format(args.log_format)
    except ValueError as exc:
        print(f"rgse: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    setup_logging(logging.DEBUG if args.debug else logging.INFO if args.verbose else logging.WARNING, log_format)
    module = importlib.import_module(f"rgse_daemon.commands.{args.command.replace('-', '_')}")
    try:
        return int(module.run(args))
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
