"""``rgse run measure|properties|calibrate --config FILE [...]``: start a run on the running daemon and follow it to
its result, for shell scripts (on :mod:`rgse_daemon.client`).

``rgse run measure --config FILE [--loops N] [--fixture-mass KG] [--dry-run]``
``rgse run properties --config FILE [--loops N] [--loops-per-pose N] [--scheme paper|full|lever] [--fixture-mass KG]
[--fixture-cog X Y Z [--dut-origin X Y Z] [--dut-abc A B C]] [--dry-run]``
``rgse run calibrate --config FILE [--points FILE.toml] [--method M]``
common: ``[--on-prompt stdin|wait] [--timeout S] [--report DIR] [--json]``

Progress goes to stderr, one line per event; the result to stdout (``--json``: the daemon's result object, one
line). A prompt ("mount 5 calibration bodies") is printed on stderr; with ``--on-prompt stdin`` (the default) one
line read from stdin confirms it (a non-empty line is the note recorded with the confirmation, end of input aborts
the run); with ``wait`` the prompt is answered elsewhere (``rgse confirm``, the console). The run is aborted when
``--timeout`` (default 3600 s, the whole run) passes or the command is interrupted: a script that stops following
does not leave the robot running unwatched.

Exit 0 when the run is done and its result has no warnings; 4 when it is done and its result has warnings (status
``warning``: the warnings are printed under the figure); 1 when the daemon refused it, it failed, was aborted or
interrupted (its daemon died during it: the restarted daemon's final result says so, and nothing is left to abort),
or the deadline passed (with ``--json`` then one object with ``status`` ``refused``, ``state`` and the ``reason``); 2 on
a bad configuration, points file or option, or when the broker is unreachable.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path

from rgse_daemon.client import (
    FixtureFrame,
    Identity,
    Prompt,
    Refused,
    ResultRefused,
    RgseClient,
    Run,
    RunFailed,
    WaitTimeout,
    load_points,
)
from rgse_daemon.commands.operator_cli import run_operator
from rgse_daemon.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, EXIT_WARNINGS, ConfigError
from rgse_daemon.verdict import OK, REFUSED, refusal

DEFAULT_RUN_TIMEOUT_S = 3600.0
#: Bound of the abort sent when the command gives up on a run.
ABORT_S = 5.0


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class StdinLines:
    """Lines of stdin, read without blocking the loop (one reader for the whole command: none is lost between
    prompts); ``None`` at the end of input."""

    def __init__(self) -> None:
        self._reader: asyncio.StreamReader | None = None
        self._transport: asyncio.BaseTransport | None = None

    async def line(self) -> str | None:
        if self._reader is None:
            reader = asyncio.StreamReader()
            pipe = os.fdopen(os.dup(sys.stdin.fileno()), "rb", buffering=0)  # closing it leaves fd 0 open
            try:
                self._transport, _ = await asyncio.get_running_loop().connect_read_pipe(
                    lambda: asyncio.StreamReaderProtocol(reader), pipe)
            except ValueError:  # a regular file (or /dev/null): reading it never blocks
                pipe.close()
                text = sys.stdin.readline()
                return text or None
            self._reader = reader
        raw = await self._reader.readline()
        return raw.decode(errors="replace") if raw else None

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()


def answer_on(stdin: StdinLines) -> Callable[[Prompt], Awaitable[str | None]]:
    async def answer(prompt: Prompt) -> str | None:
        _say(f"rgse run: {prompt.message} (press Enter when done; a note may be typed)")
        line = await stdin.line()
        if line is None:
            raise RunFailed(prompt.run_id, "aborted", "end of input on stdin: nobody to confirm the prompt")
        return line.strip() or None

    return answer


def tell(prompt: Prompt) -> None:
    _say(f"rgse run: {prompt.message} (waiting for the operator's confirmation)")


async def follow(rgse: RgseClient, run: Run, args: argparse.Namespace, timeout_s: float) -> int:
    """Follow ``run`` to its end (printing progress), answer its prompts, print the result."""
    assert run.run_id is not None
    _say(f"rgse run: {run.kind} run {run.run_id} started")

    async def printer() -> None:
        async for ev in run.events(timeout_s):
            detail = ev.message or ev.step or ev.state or ""
            if ev.kind == "loop" and ev.loop_index is not None:
                detail = f"{ev.loop_index}/{ev.loop_count}" + (f", eta {ev.eta_s:.0f} s" if ev.eta_s else "")
            _say(f"rgse run: {ev.kind}: {detail}")

    stdin = StdinLines()
    printing = asyncio.create_task(printer(), name="rgse-run-progress")
    try:
        if args.on_prompt == "stdin":
            result = await run.wait(timeout_s, answer_on(stdin))
        else:
            result = await run.wait(timeout_s, tell, confirm=False)
    finally:
        stdin.close()
        printing.cancel()
        await asyncio.gather(printing, return_exceptions=True)
    assert result is not None
    if not args.json:
        identity = getattr(result, "identity", None)
        name = f" ({identity.dut_name})" if identity is not None and identity.dut_name else ""
        n = len(result.warnings)
        print(f"run {run.run_id}{name}: status {result.status}" + (f", {n} warning(s) below" if n else ""))
    if args.json:
        print(json.dumps({**result.raw, "status": result.status}))
    elif run.kind == "properties":
        r = result.raw
        mm = [1000.0 * v for v in r["cog_m"]]
        umm = [1000.0 * v for v in r["U_cog_m"]]
        print(f"run {run.run_id}: mass {r.get('mass_kg', float('nan')):.3f} kg, U {r.get('U_kg', float('nan')):.3f} kg;"
              f" CoG (flange) x {mm[0]:.2f} ± {umm[0]:.2f}, y {mm[1]:.2f} ± {umm[1]:.2f}, z {mm[2]:.2f} ± "
              f"{umm[2]:.2f} mm (k = {r.get('k', 2)})")
        if r.get("principal_moments_kgm2") is not None:
            print(f"run {run.run_id}: principal moments " + ", ".join(
                f"{v:.3f} ± {u:.3f}" for v, u in zip(r["principal_moments_kgm2"], r["U_principal_moments_kgm2"],
                                                     strict=True)) + " kg·m² (about the CoG, k = 2)")
    elif run.kind == "measurement":
        r = result.raw
        print(f"run {run.run_id}: mass {r.get('mass_kg', float('nan')):.3f} kg, U {r.get('U_kg', float('nan')):.3f}"
              f" kg (k = {r.get('k', 2)})")
    else:
        print(f"run {run.run_id}: calibration {result.raw.get('calibration_id')}, LOO mean |error| "
              f"{result.raw.get('loo_mean_abs_err_pct', float('nan')):.2f} %")
    if not args.json:
        for w in result.warnings:
            print(f"warning: {w}")
    if args.report is not None:
        calibration_id = result.raw.get("calibration_id") if run.kind == "calibration" else None
        path = await rgse.report(None if calibration_id else run.run_id, calibration_id=calibration_id,
                                 out_dir=args.report)
        _say(f"rgse run: report {path}")
    return EXIT_OK if result.status == OK else EXIT_WARNINGS


def _refused(args: argparse.Namespace, exc: ResultRefused) -> None:
    """A run that completed with a refused result: its reason and the loops set aside on stderr (stdout: one line,
    ``--json`` the result object)."""
    r = exc.result
    _say(f"rgse run: run {exc.run_id}: result refused: {exc.reason}")
    for a in r.get("loops_set_aside") or ():
        _say(f"rgse run: loop {a.get('loop')} set aside: {a.get('reason')}")
    if args.json:
        print(json.dumps({**r, "status": REFUSED, "state": "completed", "run_id": exc.run_id}), flush=True)
    else:
        print(f"run {exc.run_id}: status refused: {exc.reason}")


def _no_result(args: argparse.Namespace, reason: str, state: str, run_id: str | None = None) -> None:
    """With ``--json``: the one JSON object of a run without a result (refused, failed, aborted, given up)."""
    if args.json:
        print(json.dumps(refusal(reason, state=state, run_id=run_id)), flush=True)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse run``."""
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


def run(args: argparse.Namespace) -> int:
    timeout_s = DEFAULT_RUN_TIMEOUT_S if args.timeout is None else float(args.timeout)
    if not (math.isfinite(timeout_s) and timeout_s > 0):
        raise ConfigError(f"--timeout {args.timeout!r}: must be a finite number of seconds > 0")
    points = load_points(args.points) if getattr(args, "points", None) is not None else None
    fixture = _fixture(args)
    identity = Identity(*(getattr(args, k, None) for k in ("dut_name", "serial_number", "part_number", "project",
                                                           "operator", "note")))
    rgse = RgseClient.from_config(args.config)

    async def main() -> int:
        async with rgse:
            try:
                if args.run_kind == "measure":
                    run_ = await rgse.measure(loops=args.loops, fixture_mass_kg=args.fixture_mass,
                                              dry_run=args.dry_run, identity=identity)
                elif args.run_kind == "properties":
                    run_ = await rgse.properties(loops=args.loops, loops_per_pose=args.loops_per_pose,
                                                 scheme=args.scheme, fixture_mass_kg=args.fixture_mass,
                                                 fixture=fixture, inertia=args.inertia, dry_run=args.dry_run,
                                                 identity=identity, mass_method=args.mass_method)
                else:
                    run_ = await rgse.calibrate(points, method=args.method)
            except Refused as exc:
                _say(f"rgse run: refused by the daemon: {exc.reason}")
                _no_result(args, exc.reason, REFUSED)
                return EXIT_FAILED
            if run_.run_id is None:
                _say("rgse run: accepted without a run id (a dry run moves nothing and stores nothing)")
                return EXIT_OK
            try:
                return await follow(rgse, run_, args, timeout_s)
            except ResultRefused as exc:  # a result, not a failed run: as rgse mass refuses (exit 2, one object)
                _refused(args, exc)
                return EXIT_BAD_INPUT
            except (RunFailed, WaitTimeout, Refused) as exc:
                _say(f"rgse run: failed: {exc}")
                if run_.end_state() is None:
                    await _abort(run_, f"rgse run gave up: {exc}")
                _no_result(args, getattr(exc, "reason", str(exc)), getattr(exc, "state", "timeout")
                           if not isinstance(exc, Refused) else REFUSED, run_.run_id)
                return EXIT_FAILED
            except asyncio.CancelledError:
                await _abort(run_, "rgse run interrupted")
                raise

    return run_operator("run", args, main)


def _fixture(args: argparse.Namespace) -> FixtureFrame | None:
    """The command line's fixture frame (``--fixture-cog``, ``--dut-origin``, ``--dut-abc``), None without it."""
    cog = getattr(args, "fixture_cog", None)
    origin, abc = getattr(args, "dut_origin", None), getattr(args, "dut_abc", None)
    if cog is None:
        if origin is not None or abc is not None:
            raise ConfigError("--dut-origin/--dut-abc need --fixture-cog: the command's fixture frame replaces the "
                              "configured one as a whole")
        return None
    for name, values in (("--fixture-cog", cog), ("--dut-origin", origin), ("--dut-abc", abc)):
        if values is not None and not all(math.isfinite(v) for v in values):
            raise ConfigError(f"{name} {values}: three finite numbers")
    return FixtureFrame(tuple(cog), tuple(origin or (0.0, 0.0, 0.0)), tuple(abc or (0.0, 0.0, 0.0)))


async def _abort(run_: Run, reason: str) -> None:
    """Abort the run this command gave up on (bounded; a failure to abort is said, not hidden)."""
    try:
        async with asyncio.timeout(ABORT_S):
            await run_.abort(reason[:500])
        _say(f"rgse run: run {run_.run_id} aborted")
    except Exception as exc:  # reported: the operator must know the run may still go on
        _say(f"rgse run: could not abort run {run_.run_id}: {exc}; abort it with rgse abort")
