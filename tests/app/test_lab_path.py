"""The README's lab path (issue #34), walked on the simulator exactly as documented, as separate processes: the
simulated robot commissioned (``rgse sim --commission``), ``rgse doctor`` passing, ``rgse daemon``, a campaign with
each load mounted on the simulator (``rgse sim-op``) when ``rgse run calibrate`` asks for it, a named DuT measured
(``rgse run measure --dut-name ...``), its certificate (``rgse certificate``) and the history (``rgse runs --csv``);
then a second DuT through the Python client. The configuration is ``deploy/rgse.sim.toml`` as shipped, with only
its ports (free ones, a private broker) and its data directory changed."""

from __future__ import annotations

import asyncio
import csv
import io
import re
import signal
import sys
from pathlib import Path

import pytest
from pypdf import PdfReader

from rgse_daemon.client import Identity, RgseClient
from tests.support.mqtt import MosquittoProcess, free_port

ROOT = Path(__file__).resolve().parents[2]
RGSE = (sys.executable, "-m", "rgse_daemon")
STEP_S = 120.0
#: A calibration of 8 points x 3 loops at 100x and a 3-loop measurement; generous for a loaded 2-core machine.
CAMPAIGN_S = 900.0


def sim_config(tmp_path: Path, port: int, broker: int) -> Path:
    text = (ROOT / "deploy" / "rgse.sim.toml").read_text()
    for old, new in ((r"^port = 7000 ", f"port = {port} "), (r'^data_dir = "\./rgse-sim-data"',
                                                            f'data_dir = "{tmp_path / "data"}"'),
                     (r"^port = 1883", f"port = {broker}"), (r"^port = 8080", f"port = {free_port()}")):
        text, n = re.subn(old, new, text, flags=re.MULTILINE)
        assert n == 1, old  # the shipped file still has the line the README's path relies on
    path = tmp_path / "rgse.sim.toml"
    path.write_text(text)
    return path


async def rgse(*args: str, stdin: bytes | None = None, timeout_s: float = STEP_S) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(*RGSE, *args, cwd=ROOT, stdin=asyncio.subprocess.PIPE,
                                                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    async with asyncio.timeout(timeout_s):
        out, err = await proc.communicate(stdin)
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode()


def mount_args(prompt: str) -> list[str]:
    """What the person at the simulator types for a prompt (examples/rehearsal-points.toml lists the same)."""
    if "empty MPA" in prompt:
        return ["--mpa"]
    if m := re.search(r"test adapter with (\d+) calibration bodies at ([\d.]+) m from A5", prompt):
        return ["--torque", m.group(1), "--lever-a5", m.group(2)]
    if m := re.search(r"mount (\d+) calibration bod(?:y|ies) on the MPA", prompt):
        return ["--bodies", m.group(1)]
    raise AssertionError(f"a prompt the README does not cover: {prompt}")


async def stop(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        proc.send_signal(signal.SIGTERM)
        try:
            async with asyncio.timeout(30):
                await proc.wait()
        except TimeoutError:
            proc.kill()
            await proc.wait()


@pytest.mark.slow(expected_s=77)
@pytest.mark.timeout(STEP_S * 4 + CAMPAIGN_S * 3)  # the sum of its steps' deadlines
async def test_the_readme_lab_path_on_the_simulator(tmp_path: Path, private_broker: MosquittoProcess) -> None:
    port, control_port = free_port(), free_port()
    config = sim_config(tmp_path, port, private_broker.port)
    control = f"127.0.0.1:{control_port}"
    # 1. the robot, commissioned once
    sim = await asyncio.create_subprocess_exec(
        *RGSE, "sim", "--commission", "--config", str(config), "--time-scale", "100", "--share",
        str(tmp_path / "sim-share"), "--port", str(port), "--control-port", str(control_port), cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL)
    daemon = None
    try:
        async with asyncio.timeout(STEP_S):
            assert "rgse sim: listening on" in (await sim.stdout.readline()).decode()
        # 2. every doctor check passes
        rc, out, err = await rgse("doctor", "--config", str(config))
        assert rc == 0 and "all checks passed" in out, out + err
        # 3. the service
        daemon = await asyncio.create_subprocess_exec(*RGSE, "daemon", "--config", str(config), cwd=ROOT,
                                                      stdout=asyncio.subprocess.DEVNULL,
                                                      stderr=asyncio.subprocess.DEVNULL)
        async with RgseClient.from_config(config) as client:  # a person waits until the console says it is up
            await client.ready(STEP_S)
        # 4. the campaign: each load mounted on the simulator when asked, then Enter
        run = await asyncio.create_subprocess_exec(
            *RGSE, "run", "calibrate", "--config", str(config), "--points", "examples/rehearsal-points.toml",
            "--method", "auto", cwd=ROOT, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE)
        prompts, said = [], []
        async with asyncio.timeout(CAMPAIGN_S):
            while line := (await run.stderr.readline()).decode():
                said.append(line)
                if "press Enter when done" in line:
                    prompts.append(line)
                    rc, out, err = await rgse("sim-op", "--control", control, "mount", *mount_args(line))
                    assert rc == 0, err
                    run.stdin.write(b"\n")
                    await run.stdin.drain()
            out = (await run.stdout.read()).decode()
            await run.wait()
        assert run.returncode == 0 and len(prompts) == 8, (out, "".join(said))
        calibration_id = re.search(r"calibration (\w+)", out).group(1)

        # 5. a named DuT
        rc, _, err = await rgse("sim-op", "--control", control, "mount", "--dut", "61.7", "--cog", "0.02", "-0.01",
                                "0.30")
        assert rc == 0, err
        rc, out, err = await rgse("run", "measure", "--config", str(config), "--dut-name", "ReFEx wing box",
                                  "--serial-number", "SN-0042", "--project", "ReFEx", "--operator", "A. Operator",
                                  timeout_s=CAMPAIGN_S)
        assert rc in (0, 4), out + err  # 4: a result with warnings, each printed
        run_id = re.search(r"^run (\S+) \(ReFEx wing box\): status (ok|warning)", out, re.MULTILINE).group(1)
        mass, u = (float(v) for v in re.search(r"mass ([\d.]+) kg, U ([\d.]+) kg", out).groups())
        assert 0 < u < 0.1 * mass and abs(mass - 61.7) < 3 * u, out  # 3U: a broken method, not bad luck

        # 6. the certificate and the history
        rc, out, err = await rgse("certificate", run_id, "--config", str(config))
        assert rc == 0, err
        reader = PdfReader(out.strip())
        text = " ".join(reader.pages[0].extract_text().split())
        assert len(reader.pages) == 1
        for needed in ("ReFEx wing box", "SN-0042", f"{mass:.3f} kg", f"{u:.3f} kg", calibration_id):
            assert needed in text, (needed, text)
        rc, out, err = await rgse("runs", "--config", str(config), "--csv")
        assert rc == 0, err
        rows = {r["run_id"]: r for r in csv.DictReader(io.StringIO(out))}
        assert rows[run_id]["dut_name"] == "ReFEx wing box" and rows[run_id]["serial_number"] == "SN-0042"
        assert float(rows[run_id]["mass_kg"]) == pytest.approx(mass, abs=5e-4)

        # the same measurement through the Python client
        rc, _, err = await rgse("sim-op", "--control", control, "mount", "--dut", "48.2", "--cog", "0", "0.03", "0.25")
        assert rc == 0, err
        async with RgseClient.from_config(config) as client:
            m = await (await client.measure(identity=Identity(dut_name="ReFEx wing box", serial_number="SN-0043"))
                       ).wait(CAMPAIGN_S)
        assert m.status in ("ok", "warning") and abs(m.mass_kg - 48.2) < 3 * m.U_kg
        assert m.identity is not None and m.identity.serial_number == "SN-0043"
        rc, out, err = await rgse("runs", "--config", str(config), "--csv", "--dut", "SN-0043")
        assert rc == 0 and [r["run_id"] for r in csv.DictReader(io.StringIO(out))] == [m.run_id], out + err
    finally:
        if daemon is not None:
            await stop(daemon)
        await stop(sim)
