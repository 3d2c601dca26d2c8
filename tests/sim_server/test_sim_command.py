"""``rgse sim`` as a real process: listens, serves, stops cleanly on SIGTERM/SIGINT; bad input exits 2."""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from pathlib import Path

import pytest

from rgse_daemon.krl.render import globals_dat_text
from rgse_daemon.link import frames as fr

from .conftest import RawClient

DEADLINE_S = 30.0


DEFAULT_SCENARIO = Path(__file__).resolve().parents[2] / "simulators/krc4/scenarios/default.toml"


async def _start(*args: str) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, "-m", "rgse_daemon", "sim", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
async def test_sim_serves_until_signalled_and_exits_0(tmp_path: Path, sig: signal.Signals) -> None:
    scenario = tmp_path / "scenario.toml"
    # a real scenario: the default one with a different gravity (it is validated by simulators/krc4/scenario.py)
    scenario.write_text(DEFAULT_SCENARIO.read_text().replace("g_m_s2 = 9.81", "g_m_s2 = 9.8134"))
    share = tmp_path / "share"
    proc = await _start("--host", "127.0.0.1", "--port", "0", "--share", str(share), "--scenario", str(scenario),
                        "--time-scale", "10")  # fmt: skip
    try:
        async with asyncio.timeout(DEADLINE_S):
            line = (await proc.stdout.readline()).decode()
        m = re.match(r"rgse sim: listening on 127\.0\.0\.1:(\d+) \(share (.+)\); control on 127\.0\.0\.1:\d+$",
                     line.strip())
        assert m, line
        assert Path(m.group(2)) == share.resolve() and share.is_dir()
        client = await RawClient.open(int(m.group(1)))
        assert await client.call(fr.ReadVarAscii("PING")) == fr.ReadVarAsciiReply("PONG")
        assert await client.call(fr.ReadVarAscii("$MODE_OP")) == fr.ReadVarAsciiReply("#T1")
        proc.send_signal(sig)
        assert await client.at_eof()
        await client.close()
        async with asyncio.timeout(DEADLINE_S):
            _, err = await proc.communicate()
        assert proc.returncode == 0, err.decode()
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def test_sim_installs_the_handshake_globals_it_is_given(tmp_path: Path) -> None:
    """``rgse sim --globals FILE`` does what installing rgse_globals.dat once on a real controller does: the programs'
    handshake variables exist (without it every program stops at its first one)."""
    dat = tmp_path / "rgse_globals.dat"
    dat.write_bytes(globals_dat_text().encode("iso-8859-1"))
    for args, exists in ((["--globals", str(dat)], True), ([], False)):
        proc = await _start("--port", "0", "--share", str(tmp_path / "share"), *args)
        try:
            async with asyncio.timeout(DEADLINE_S):
                line = (await proc.stdout.readline()).decode()
            client = await RawClient.open(int(re.search(r":(\d+) \(share", line).group(1)))
            reply = await client.call(fr.ReadVarAscii("RGSE_DONE"))
            assert (reply == fr.ReadVarAsciiReply("FALSE")) is exists, reply
            await client.close()
            proc.send_signal(signal.SIGTERM)
            async with asyncio.timeout(DEADLINE_S):
                await proc.communicate()
            assert proc.returncode == 0
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()


@pytest.mark.parametrize(
    ("make_args", "message"),
    [
        (lambda d: ["--scenario", str(d / "missing.toml")], "missing.toml: cannot read scenario"),
        (lambda d: ["--scenario", str(d / "bad.toml")], "bad.toml: scenario is not valid TOML"),
        (lambda d: ["--scenario", str(d / "unknown.toml")], "unknown.toml: payload: unknown key"),
        (lambda d: ["--time-scale", "0"], "--time-scale 0"),
        (lambda d: ["--time-scale", "nan"], "--time-scale nan"),
        (lambda d: ["--port", "70000"], "--port 70000"),
        (lambda d: ["--share", str(d / "bad.toml")], "not a directory"),
        (lambda d: ["--globals", str(d / "missing.dat")], "--globals"),
    ],
)
async def test_bad_input_exits_2_naming_the_problem(tmp_path: Path, make_args, message: str) -> None:
    (tmp_path / "bad.toml").write_text("this is = = not toml\n")
    (tmp_path / "unknown.toml").write_text("[payload]\nmass_kg = 107.65\n")  # valid TOML, not a scenario
    proc = await _start("--port", "0", *make_args(tmp_path))
    async with asyncio.timeout(DEADLINE_S):
        out, err = await proc.communicate()
    assert proc.returncode == 2
    assert message in err.decode() and b"Traceback" not in err and out == b""


async def test_port_in_use_fails_with_exit_1(tmp_path: Path) -> None:
    blocker = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
    port = blocker.sockets[0].getsockname()[1]
    try:
        proc = await _start("--port", str(port), "--share", str(tmp_path))
        async with asyncio.timeout(DEADLINE_S):
            _, err = await proc.communicate()
    finally:
        blocker.close()
        await blocker.wait_closed()
    assert proc.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in err.decode()


def test_the_file_work_runs_in_the_time_scale(tmp_path: Path) -> None:
    """``rgse sim --time-scale X``: the controller's file work X times faster, as its motions: the scenario's rate
    (a real C3 Bridge's) times X, the server's default where the scenario sets none."""
    from rgse_daemon.commands.sim import scenario_in_time_scale
    from simulators.krc4.server import DEFAULT_FILE_RATE_BYTES_S

    scaled = scenario_in_time_scale(None, 100.0).server.file_rate_bytes_s
    assert scaled == pytest.approx(100 * DEFAULT_FILE_RATE_BYTES_S)
    assert scenario_in_time_scale(DEFAULT_SCENARIO, 1.0).server.file_rate_bytes_s == DEFAULT_FILE_RATE_BYTES_S
    own = tmp_path / "own.toml"
    text = DEFAULT_SCENARIO.read_text()
    own.write_text(text.replace("file_rate_bytes_s = 100000.0", "file_rate_bytes_s = 40000.0"))
    assert scenario_in_time_scale(own, 10.0).server.file_rate_bytes_s == pytest.approx(400000.0)
    unset = tmp_path / "unset.toml"
    unset.write_text(text.replace("file_rate_bytes_s = 100000.0", ""))
    assert scenario_in_time_scale(unset, 2.0).server.file_rate_bytes_s == pytest.approx(2 * DEFAULT_FILE_RATE_BYTES_S)
