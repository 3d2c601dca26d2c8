"""``rgse status --config FILE [--json] [--timeout S]``: what a running daemon last said on its broker.

Reads the retained ``<prefix>/status``, ``<prefix>/state`` and ``<prefix>/run/<run_id>/result`` topics (contracts
§4) and prints them; ``--json`` prints one object ``{broker, prefix, status, state, results: {run_id: result}}``
(``null`` / ``{}`` for what nothing is retained on). Exit 0 once the broker was read, 2 when the configuration is
bad or the broker cannot be read within ``--timeout`` (default 10 s). The client is :mod:`rgse_daemon.io.operator`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from rgse_daemon.commands import add_json
from rgse_daemon.commands.operator_cli import run_operator
from rgse_daemon.errors import EXIT_OK
from rgse_daemon.io.operator import check_timeout, describe_status, endpoint, read_status

#: Longest line of a nested value in the human output (``--json`` has everything).
WIDTH = 160


def _short(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))
    return text if len(text) <= WIDTH else text[: WIDTH - 1] + "…"


def _xyz(value: Any) -> bool:
    return isinstance(value, list) and len(value) == 3 and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value)


def _result_line(result: Any) -> str:
    if isinstance(result, dict) and isinstance(result.get("mass_kg"), int | float):
        line = f"mass {result['mass_kg']:.3f} kg"
        if isinstance(result.get("U_kg"), int | float):
            line += f", U {result['U_kg']:.3f} kg (k = {result.get('k', '?')})"
        cog, u_cog = result.get("cog_m"), result.get("U_cog_m")
        if _xyz(cog) and _xyz(u_cog):  # a properties run: the CoG in the flange frame with its U
            line += "; CoG (flange) " + ", ".join(f"{a} {1000 * c:.2f} ± {1000 * u:.2f}"
                                                  for a, c, u in zip("xyz", cog, u_cog, strict=True)) + " mm"
        return line
    if isinstance(result, dict) and result.get("calibration_id"):
        line = f"calibration {result['calibration_id']}"
        if isinstance(result.get("loo_mean_abs_err_pct"), int | float):
            line += f", LOO mean |error| {result['loo_mean_abs_err_pct']:.2f} %"
        return line
    return _short(result)


def print_status(out: dict[str, Any]) -> None:
    print(f"daemon   {out['prefix']} on mqtt broker {out['broker']}")
    print(f"status   {describe_status(out['status'])}")
    state = out["state"]
    if isinstance(state, dict):
        head = f"engine {state.get('engine', '?')}"
        if state.get("run_id"):
            head += f", run {state['run_id']} ({state.get('run_kind') or '?'})"
        print(f"state    {head}, at {state.get('time', '?')}")
        for key, value in state.items():
            if key not in ("engine", "run_id", "run_kind", "time"):
                print(f"         {key}: {_short(value)}")
    else:
        print(f"state    {'(nothing retained)' if state is None else _short(state)}")
    results = out["results"]
    print(f"results  {len(results)} retained")
    for run_id, result in results.items():
        print(f"         {run_id}  {_result_line(result)}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse status``."""
    p.add_argument("--config", type=Path, required=True, metavar="FILE")
    p.add_argument("--timeout", type=float, metavar="S", help="wait at most S s for the broker (default 10)")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    ep = endpoint(args.config)
    timeout_s = check_timeout(getattr(args, "timeout", None))

    async def main() -> int:
        out = await read_status(ep, timeout_s)
        if getattr(args, "json", False):
            print(json.dumps(out))
        else:
            print_status(out)
        return EXIT_OK

    return run_operator("status", args, main)
