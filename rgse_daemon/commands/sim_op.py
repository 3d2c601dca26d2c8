"""``rgse sim-op``: act on a running ``rgse sim`` as a person at the robot does — mount a campaign's load or a DuT,
turn the mode selector, hold or release the enabling switch, acknowledge a stop message (the control port of
:mod:`simulators.krc4.control`; one JSON line out, one back).

Exit 0 when the simulator did it; 1 when it refused (the reason on stderr, or in the JSON); 2 on bad arguments or
when the control port cannot be reached.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from typing import Any

from rgse_daemon.commands import add_json, finite, positive
from rgse_daemon.errors import EXIT_FAILED, EXIT_OK, ConfigError, LinkError

#: Longest reply read (bytes).
MAX_REPLY_BYTES = 65536


def request_of(args: argparse.Namespace) -> dict[str, Any]:
    """The control request the command line asks for (checked here as far as the command line goes; the simulator
    checks every field again)."""
    if args.op == "mount":
        if args.nothing:
            load: dict[str, Any] = {"kind": "nothing"}
        elif args.mpa:
            load = {"kind": "mpa"}
        elif args.bodies is not None:
            load = {"kind": "bodies", "n_cb": args.bodies}
        elif args.torque is not None:
            if args.lever_a5 is None:
                raise ConfigError("mount --torque N needs --lever-a5 M (the bodies' lever from A5)")
            load = {"kind": "torque", "n_cb": args.torque, "cb_lever_a5_m": args.lever_a5}
        else:
            if args.cog is None:
                raise ConfigError("mount --dut KG needs --cog X Y Z (its CoG in the flange frame, m)")
            load = {"kind": "dut", "mass_kg": args.dut, "cog_m": list(args.cog)}
            if args.inertia is not None:
                load["inertia_kgm2"] = list(args.inertia)
            if args.fixture_mass is not None:
                load["fixture_mass_kg"] = args.fixture_mass
        if args.lever_a5 is not None and args.torque is None:
            raise ConfigError("--lever-a5 goes with mount --torque")
        if args.dut is None and (args.cog, args.inertia, args.fixture_mass) != (None, None, None):
            raise ConfigError("--cog, --inertia and --fixture-mass go with mount --dut")
        return {"op": "mount", "load": load}
    if args.op == "mode":
        return {"op": "mode", "mode": args.mode}
    if args.op == "enabling-switch":
        return {"op": "enabling_switch", "held": args.state == "hold"}
    return {"op": args.op}


def _address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) <= 65535:
        raise ConfigError(f"--control {text!r}: expected HOST:PORT")
    return host, int(port)


async def send(host: str, port: int, request: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """One request to the control port and its reply, under one deadline."""
    try:
        async with asyncio.timeout(timeout_s):
            reader, writer = await asyncio.open_connection(host, port, limit=MAX_REPLY_BYTES)
            try:
                writer.write(json.dumps(request).encode() + b"\n")
                await writer.drain()
                line = await reader.readline()
            finally:
                writer.close()
    except TimeoutError as exc:
        raise LinkError(f"rgse sim's control port {host}:{port} did not answer within {timeout_s:g} s") from exc
    except (OSError, ValueError) as exc:
        raise LinkError(f"rgse sim's control port {host}:{port}: {exc}") from exc
    try:
        reply = json.loads(line)
    except json.JSONDecodeError as exc:
        raise LinkError(f"rgse sim's control port {host}:{port} answered no JSON: {line[:80]!r}") from exc
    if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
        raise LinkError(f"rgse sim's control port {host}:{port} answered {reply!r}")
    return reply


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse sim-op``."""
    p.add_argument("--control", default="127.0.0.1:7001", metavar="HOST:PORT", help="rgse sim's control port")
    p.add_argument("--timeout", type=positive, default=5.0, metavar="S")
    add_json(p)
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


def run(args: argparse.Namespace) -> int:
    host, port = _address(args.control)
    request = request_of(args)
    try:
        reply = asyncio.run(send(host, port, request, args.timeout))
    except LinkError as exc:
        raise ConfigError(f"{exc} (is rgse sim running with its control port?)") from exc
    if args.json:
        print(json.dumps(reply))
    elif reply["ok"]:
        print(", ".join(f"{k}: {v}" for k, v in reply.items() if k != "ok"))
    else:
        print(f"rgse sim-op: refused: {reply.get('error')}", file=sys.stderr)
    return EXIT_OK if reply["ok"] else EXIT_FAILED
