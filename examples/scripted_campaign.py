"""A scripted calibration campaign: a custom load sequence, each load confirmed once it is mounted, with retries.

    python examples/scripted_campaign.py --config /etc/rgse/rgse.toml [--bodies 0,2,4,6,8,10] \\
        [--torque-levers 0.761,1.261] [--attempts 3] [--method auto]

The lab's own sequence of loads (here: calibration bodies stacked in the order given, then torque points at the
given levers) replaces paper Table 1. The operator is asked on the terminal to mount each load; the script confirms
it to the daemon with the operator's note. When a run fails (an interlock trip, a lost controller link, a refused
start because the daemon was busy), the script says why, waits until the daemon is ready again and starts the
campaign anew, up to ``--attempts`` times; an abort by the operator (Ctrl-C here, ``rgse abort``, the console) is
not retried. Everything goes through :mod:`rgse_daemon.client`; the tests run this file against the simulator.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path

from rgse_daemon.client import (
    CalibrationResult,
    CampaignPoint,
    Prompt,
    Refused,
    RgseClient,
    Run,
    RunFailed,
    WaitTimeout,
)

#: One calibration body (paper §2.4.2) and the test adapter of the torque points, kg.
BODY_KG = 20.93
ADAPTER_KG = 19.20
#: The levers of the mass points in the measurement pose (as paper Table 1), m.
LEVER_A3_M = 1.3
LEVER_A5_M = 0.3
#: Bodies on the test adapter at a torque point.
TORQUE_BODIES = 10
#: Bound of the abort sent when the script gives up on a run (s).
ABORT_S = 10.0

Mount = Callable[[Prompt], Awaitable[str | None]]
OnRetry = Callable[[int, Exception], Awaitable[None]]


def load_sequence(bodies: Sequence[int], torque_levers_a5_m: Sequence[float]) -> list[CampaignPoint]:
    """The zero point first, then the stacks of ``bodies`` in order, then the torque points."""
    points = [CampaignPoint("zero", 0.0, LEVER_A3_M, LEVER_A5_M)]
    points += [CampaignPoint("mass", round(n * BODY_KG, 3), LEVER_A3_M, LEVER_A5_M) for n in bodies if n > 0]
    points += [CampaignPoint("torque", round(TORQUE_BODIES * BODY_KG + ADAPTER_KG, 3), LEVER_A3_M, lever)
               for lever in torque_levers_a5_m]
    return points


async def campaign(rgse: RgseClient, points: Sequence[CampaignPoint], mount: Mount, *, attempts: int = 3,
                   method: str | None = "auto", run_timeout_s: float = 3600.0, ready_timeout_s: float = 120.0,
                   on_retry: OnRetry | None = None) -> CalibrationResult:
    """Run the campaign until one attempt succeeds; each failure is told to ``on_retry`` before the next."""
    last: Exception | None = None
    for attempt in range(1, attempts + 1):
        if last is not None:
            print(f"attempt {attempt - 1} failed: {last}; trying again", file=sys.stderr)
            if on_retry is not None:
                await on_retry(attempt, last)
        try:
            await rgse.ready(ready_timeout_s)
            run = await rgse.calibrate(points, method=method)
            print(f"attempt {attempt}: run {run.run_id}", file=sys.stderr)
            try:
                result = await run.wait(run_timeout_s, on_prompt=mount)
            except BaseException as exc:  # given up here (end of input, Ctrl-C, a deadline): not left waiting there
                if run.end_state() is None:
                    await abort_quietly(run, f"scripted campaign gave up: {exc or type(exc).__name__}")
                raise
        except RunFailed as exc:
            if exc.state == "aborted":
                raise  # somebody meant it: not retried
            last = exc
        except Refused as exc:  # e.g. busy, not connected: wait for ready and try again
            last = exc
        else:
            assert isinstance(result, CalibrationResult)
            return result
    assert last is not None
    raise last


async def abort_quietly(run: Run, reason: str) -> None:
    """Abort ``run`` within :data:`ABORT_S`; a failure to abort is said, since the run may then still wait."""
    try:
        async with asyncio.timeout(ABORT_S):
            await run.abort(reason[:500])
        print(f"run {run.run_id} aborted", file=sys.stderr)
    except Exception as exc:
        print(f"could not abort run {run.run_id}: {exc}; abort it with rgse abort", file=sys.stderr)


async def ask_on_terminal(prompt: Prompt) -> str | None:
    """The person at the robot: mount the load, press Enter (a typed line becomes the recorded note). End of input
    means nobody is there to confirm: the run is aborted, not left waiting."""
    try:
        line = await asyncio.to_thread(input, f"{prompt.message}\n"
                                              "mounted? note (Enter): ")
    except EOFError:
        raise RunFailed(prompt.run_id, "aborted", "end of input on stdin: nobody to confirm the prompt") from None
    return line.strip() or None


async def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--bodies", default="0,2,4,6,8,10", help="stacks in the order to mount (number of bodies)")
    p.add_argument("--torque-levers", default="0.761,1.261", help="torque points: lever of the bodies from A5, m")
    p.add_argument("--attempts", type=int, default=3)
    p.add_argument("--method", default="auto")
    args = p.parse_args(argv)
    points = load_sequence([int(n) for n in args.bodies.split(",") if n],
                           [float(x) for x in args.torque_levers.split(",") if x])
    async with RgseClient.from_config(args.config) as rgse:
        try:
            result = await campaign(rgse, points, ask_on_terminal, attempts=args.attempts, method=args.method)
        except (RunFailed, Refused, WaitTimeout) as exc:
            print(f"campaign failed: {exc}", file=sys.stderr)
            return 1
    print(f"calibration {result.calibration_id} ({result.method}): LOO mean |error| "
          f"{result.loo_mean_abs_err_pct:.2f} %, {result.points} points, run {result.run_id}")
    return 0


if __name__ == "__main__":
    raise SystemExit(asyncio.run(main()))
