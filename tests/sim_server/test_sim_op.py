"""``rgse sim --commission`` and ``rgse sim-op`` as real processes: the simulator commissioned as a real KR C4 is once,
and a person's actions at the robot (mounting loads and a DuT, the mode selector) sent to its control port; bad
requests are refused naming the field (issue #34: the lab's path rehearsed on the simulator)."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import sys
from pathlib import Path

import pytest

from rgse_daemon.commands.krl import template_defaults
from rgse_daemon.config import Config
from rgse_daemon.doctor import krl_bytes
from rgse_daemon.krl.render import default_params, globals_dat_text, render
from rgse_daemon.link import frames as fr
from simulators.krc4.control import ControlServer, payload_of
from simulators.krc4.physics import CB_MASS_KG, MPA_MASS_KG
from simulators.krc4.sim import SimulatedKrc4

from .conftest import RawClient

DEADLINE_S = 30.0


async def _rgse(*args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(sys.executable, "-m", "rgse_daemon", *args,
                                                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    async with asyncio.timeout(DEADLINE_S):
        out, err = await proc.communicate()
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


async def test_commissioned_sim_takes_a_persons_actions_on_its_control_port(tmp_path: Path) -> None:
    share = tmp_path / "share"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "rgse_daemon", "sim", "--port", "0", "--share", str(share), "--commission",
        "--time-scale", "10", stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    try:
        async with asyncio.timeout(DEADLINE_S):
            line = (await proc.stdout.readline()).decode().strip()
        m = re.match(r"rgse sim: listening on 127\.0\.0\.1:(\d+) \(share .+\); control on 127\.0\.0\.1:(\d+)$", line)
        assert m, line
        port, control = int(m.group(1)), f"127.0.0.1:{m.group(2)}"
        # commissioned: the handshake globals exist, and the files rgse doctor compares lie where it looks
        client = await RawClient.open(port)
        assert await client.call(fr.ReadVarAscii("RGSE_DONE")) == fr.ReadVarAsciiReply("FALSE")
        await client.close()
        program = share / "R1" / "PROGRAM"
        resident = render("rgse_resident", default_params("rgse_resident", template_defaults(Config()))).src_text
        assert (program / "RGSE_RESIDENT.SRC").read_bytes() == krl_bytes(resident)
        assert (program / "RGSE_GLOBALS.DAT").read_bytes() == krl_bytes(globals_dat_text())

        rc, out, err = await _rgse("sim-op", "--control", control, "--json", "status")
        assert rc == 0 and json.loads(out)["mounted"] == "nothing (bare flange)", (out, err)
        rc, out, err = await _rgse("sim-op", "--control", control, "mount", "--bodies", "3")
        assert rc == 0, err
        assert "the MPA with 3 calibration bodies" in out
        rc, out, _ = await _rgse("sim-op", "--control", control, "--json", "status")
        assert json.loads(out)["mass_kg"] == pytest.approx(MPA_MASS_KG + 3 * CB_MASS_KG)
        rc, out, err = await _rgse("sim-op", "--control", control, "mount", "--dut", "61.7", "--cog", "0", "0.05",
                                   "0.3")
        assert rc == 0 and "a DuT of 61.7 kg" in out, err
        rc, out, _ = await _rgse("sim-op", "--control", control, "mode", "AUT")
        assert rc == 0
        client = await RawClient.open(port)
        assert await client.call(fr.ReadVarAscii("$MODE_OP")) == fr.ReadVarAsciiReply("#AUT")
        await client.close()
        # refused in the simulator, naming the field; nothing changes
        rc, out, err = await _rgse("sim-op", "--control", control, "mount", "--bodies", "99")
        assert rc == 1 and "n_cb" in err and "0..10" in err, err
        rc, out, _ = await _rgse("sim-op", "--control", control, "--json", "status")
        assert json.loads(out)["mounted"].startswith("a DuT of 61.7 kg")
        # refused on the command line: bad arguments exit 2
        rc, _, err = await _rgse("sim-op", "--control", control, "mount", "--dut", "50")
        assert rc == 2 and "--cog" in err
    finally:
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(DEADLINE_S):
            await proc.communicate()
    assert proc.returncode == 0
    rc, _, err = await _rgse("sim-op", "--control", control, "status")
    assert rc == 2 and "is rgse sim running" in err, err


@pytest.mark.parametrize(("request_line", "error"), [
    (b"not json", "not a JSON object"),
    (b"[1, 2]", "not a JSON object"),
    (b'{"op": "fly"}', "op: 'fly'"),
    (b'{"op": "mount", "op": "status"}', "duplicate key 'op'"),
    (b'{"op": "mount", "load": {"kind": "dut", "mass_kg": -3, "cog_m": [0, 0, 0.2]}}', "mass_kg: -3"),
    (b'{"op": "mount", "load": {"kind": "dut", "mass_kg": 50, "cog_m": [0, 0, NaN]}}', "cog_m[2]"),
    (b'{"op": "mount", "load": {"kind": "torque", "n_cb": 2, "cb_lever_a5_m": 3.0}}', "outside the guide rail"),
    (b'{"op": "mount", "load": {"kind": "bodies", "n_cb": true}}', "n_cb"),
    (b'{"op": "mode", "mode": "X9"}', "mode"),
    (b'{"op": "enabling_switch", "held": "yes"}', "held"),
])
def test_control_requests_are_validated_and_refusals_change_nothing(request_line: bytes, error: str,
                                                                   tmp_path: Path) -> None:
    sim = SimulatedKrc4(tmp_path, time_scale=10.0)
    control = ControlServer(sim)
    before = sim.payload
    reply = control.handle(request_line)
    assert reply["ok"] is False and error in reply["error"], reply
    assert sim.payload is before and sim.store.read("$MODE_OP") == "#T1"


def test_a_prompts_point_mounts_what_the_campaign_asks_for() -> None:
    payload, what = payload_of({"kind": "point", "point": {"kind": "torque", "n_cb": 10, "cb_lever_a5_m": 1.011}})
    assert "torque point" in what and payload.mass_kg > 10 * CB_MASS_KG
