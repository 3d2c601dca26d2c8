"""``rgse run measure|calibrate`` as a shell script runs it: a subprocess against the daemon (in-process, on the
simulated KR C4 and a private Mosquitto), prompts answered on stdin by the test acting as the operator."""

from __future__ import annotations

import asyncio
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rgse_daemon import calfile
from simulators.krc4.physics import campaign_point_payload, dut_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.client import SHORT_CAMPAIGN, write_points
from tests.support.configfile import write_config
from tests.support.daemon import WAIT_S, daemon_config, running_daemon, seed_calibration
from tests.support.mqtt import MosquittoProcess
from tests.support.polling import wait_until

DUT = dut_payload(95.0, (0.0, 0.05, 0.25), fixture_mass_kg=10.288)


@dataclass(frozen=True)
class Ran:
    rc: int
    out: str
    err: str


def loads_of() -> list[dict[str, Any]]:
    """What the operator mounts for each point of the short campaign, by point index."""
    return [{"kind": p.kind, "n_cb": p.n_cb, "cb_lever_a5_m": p.cb_lever_a5_m} for p in SHORT_CAMPAIGN]


async def rgse_run(*args: str | Path, sim: SimulatedKrc4 | None = None, loads: list[dict[str, Any]] | None = None,
                   close_stdin: bool = False) -> Ran:
    """``rgse run ARGS`` in a subprocess; each prompt it prints is answered on its stdin after the test (the
    operator) mounted that point's load (``loads``) on the simulated flange, or stdin is closed (``close_stdin``)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RGSE_")}
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "rgse_daemon.cli", "run", *map(str, args), stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env)
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    err: list[str] = []
    if close_stdin:
        proc.stdin.close()
    try:
        async with asyncio.timeout(2 * WAIT_S):
            out_task = asyncio.create_task(proc.stdout.read())
            while line := (await proc.stderr.readline()).decode():
                err.append(line)
                if "press Enter when done" in line and not close_stdin:
                    assert sim is not None and loads is not None
                    # "mount <label> (point i/n) and confirm": i counts from 1
                    index = int(line.split("(point ", 1)[1].split("/", 1)[0]) - 1
                    sim.mount(campaign_point_payload(loads[index]))
                    proc.stdin.write(f"mounted point {index}\n".encode())
                    await proc.stdin.drain()
            out = (await out_task).decode()
            rc = await proc.wait()
    except BaseException:
        proc.kill()
        await proc.wait()
        raise
    return Ran(rc, out, "".join(err))


def setup(tmp_path: Path, sim: SimulatedKrc4, broker: MosquittoProcess, **measurement: Any) -> tuple[Any, Path]:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=broker.port, **measurement)
    return cfg, write_config(cfg, tmp_path / "rgse.toml")


async def test_run_calibrate_answers_prompts_on_stdin_and_prints_the_result(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg, config = setup(tmp_path, sim, private_broker, loops=1)
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        ran = await rgse_run("calibrate", "--config", config, "--points", write_points(tmp_path / "pts.toml"),
                             "--method", "auto", "--json", "--report", tmp_path / "reports", sim=sim,
                             loads=loads_of())
    assert ran.rc == 0, ran.err
    result = json.loads(ran.out)
    assert result["points"] == 5 and result["calibration_id"]
    assert ran.err.count("press Enter when done") == 5 and "rgse run: loop: " in ran.err
    (report,) = (tmp_path / "reports").glob("*.html")
    assert result["calibration_id"] in report.read_text()


async def test_run_measure_prints_the_mass(sim: SimulatedKrc4, private_broker: MosquittoProcess,
                                           calibration_doc: dict[str, Any], tmp_path: Path) -> None:
    cfg, config = setup(tmp_path, sim, private_broker)
    await seed_calibration(cfg, calibration_doc)
    sim.mount(DUT)
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        ran = await rgse_run("measure", "--config", config, "--loops", "2")
    assert ran.out, ran.err  # a failed command prints nothing on stdout: show why
    warned = "status warning" in ran.out.splitlines()[0]
    assert ran.rc == (4 if warned else 0), ran.err  # interfaces §1.1: 4 for a result with warnings
    assert ran.out.startswith("run ") and " kg, U " in ran.out and "(k = 2" in ran.out, ran.out
    assert "rgse run: loop: 2/2" in ran.err, ran.err


async def test_run_measure_of_a_named_dut_with_warnings_exits_4_and_publishes_status_and_identity(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    """A calibration campaign that ran 15 K cooler than this robot now: the result warns (motor temperatures); the
    command says ``status warning`` first, prints the warnings, exits 4; --json has status and identity."""
    cfg, config = setup(tmp_path, sim, private_broker)
    cool = {ax: t - 15.0 for ax, t in calibration_doc["thermal_state_k"].items()}
    await seed_calibration(cfg, calfile.seal({**calibration_doc, "thermal_state_k": cool}))
    sim.mount(DUT)
    who = ["--dut-name", "Refex wing box", "--serial-number", "SN-0042", "--part-number", "PN-7-100",
           "--project", "GSE-7", "--operator", "A. Tester", "--note", "first fit check"]
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        text = await rgse_run("measure", "--config", config, "--loops", "1", *who[:2])
        ran = await rgse_run("measure", "--config", config, "--loops", "1", "--json", *who)
    assert text.rc == 4, text.err
    first, *rest = text.out.splitlines()
    assert first.startswith("run ") and "(Refex wing box): status warning, " in first, text.out
    assert any(line.startswith("warning: motor temperatures differ") for line in rest), text.out
    assert ran.rc == 4, ran.err
    assert ran.out.count("\n") == 1
    result = json.loads(ran.out)
    assert result["status"] == "warning" and any("motor temperatures differ" in w for w in result["warnings"])
    assert result["identity"] == {"dut_name": "Refex wing box", "serial_number": "SN-0042",
                                  "part_number": "PN-7-100", "project": "GSE-7", "operator": "A. Tester",
                                  "note": "first fit check"}


async def test_end_of_input_aborts_the_campaign_and_exits_1(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg, config = setup(tmp_path, sim, private_broker, loops=1)
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        ran = await rgse_run("calibrate", "--config", config, "--points", write_points(tmp_path / "pts.toml"),
                             close_stdin=True)
        await wait_until(lambda: str(rd.daemon.engine.state) == "aborted", "the run aborted")
    assert ran.rc == 1, ran.err
    assert "end of input on stdin" in ran.err and "aborted" in ran.err, ran.err


async def test_refusals_exit_1_bad_input_exits_2(sim: SimulatedKrc4, private_broker: MosquittoProcess,
                                                 tmp_path: Path) -> None:
    cfg, config = setup(tmp_path, sim, private_broker)
    bad = tmp_path / "bad.toml"
    bad.write_text('[[point]]\nkind = "zero"\nmass_kg = 1.0\n')
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        no_cal = await rgse_run("measure", "--config", config)
        bad_points = await rgse_run("calibrate", "--config", config, "--points", bad)
        bad_timeout = await rgse_run("measure", "--config", config, "--timeout", "-1")
    assert no_cal.rc == 1, no_cal.err
    assert bad_points.rc == 2 and "bad.toml [[point]] #1: lever_a3_m" in bad_points.err, bad_points.err
    assert bad_timeout.rc == 2 and "--timeout" in bad_timeout.err, bad_timeout.err


async def test_run_calibrate_follows_prompts_answered_elsewhere(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    """``--on-prompt wait``: the command only follows; the operator confirms with another tool (here the client)."""
    from rgse_daemon.client import RgseClient

    cfg, config = setup(tmp_path, sim, private_broker, loops=1)
    loads = loads_of()
    async with running_daemon(cfg) as rd, RgseClient.of(cfg) as op:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        follower = asyncio.create_task(rgse_run("calibrate", "--config", config, "--points",
                                                write_points(tmp_path / "pts.toml"), "--on-prompt", "wait"))
        for index in range(len(loads)):
            state = await op.until(lambda: s if (s := op.latest_state) and s.engine == "confirm" else None,
                                   "a prompt", 60)
            sim.mount(campaign_point_payload(loads[index]))
            await op.confirm(state.run_id or "", point=index, message="from the other tool")
            await op.until(lambda: (s := op.latest_state) is not None and s.engine != "confirm", "answered", 60)
        ran = await follower
    assert ran.rc == 0, ran.err
    assert ran.out.startswith("run ") and "calibration" in ran.out, ran.out
    assert ran.err.count("waiting for the operator's confirmation") == len(loads), ran.err


async def test_run_properties_refused_without_a_cog_calibration_and_on_a_half_fixture_frame(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, calibration_doc: dict[str, Any],
        tmp_path: Path) -> None:
    cfg, config = setup(tmp_path, sim, private_broker, loops=1)
    await seed_calibration(cfg, calibration_doc)  # mass only: no torsional section
    async with running_daemon(cfg) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        half = await rgse_run("properties", "--config", config, "--dut-origin", "0", "0", "0.04", close_stdin=True)
        assert half.rc == 2 and "--fixture-cog" in half.err
        ran = await rgse_run("properties", "--config", config, "--scheme", "paper", "--fixture-cog", "0", "0", "0.05",
                             close_stdin=True)
        assert ran.rc == 1 and ran.out == ""
        assert "refused by the daemon" in ran.err and "no torsional section" in ran.err
        # with --json the refusal is one object on stdout, with its reason
        ran = await rgse_run("properties", "--config", config, "--scheme", "paper", "--fixture-cog", "0", "0", "0.05",
                             "--json", close_stdin=True)
        assert ran.rc == 1 and ran.out.count("\n") == 1, ran.out
        refused = json.loads(ran.out)
        assert refused["status"] == "refused" and refused["state"] == "refused"
        assert "no torsional section" in refused["reason"]
        assert not rd.daemon.run_active
