"""Finding 2 of #12: trace names are plain names, and symbolic links do not lead out of the trace directory.

Every source of a trace name is attacked: the manifest (``rgse mass``/``rgse calibrate``), CAL.json's
``source_sha256``, MQTT command fields and the controller's TRACE listing (over the link to the simulator).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from rgse_daemon import calfile
from rgse_daemon.cli import main
from rgse_daemon.config import ControllerConfig
from rgse_daemon.controller import Controller
from rgse_daemon.errors import DataError
from rgse_daemon.io.commands import CommandRefused, parse_command
from rgse_daemon.procedures.retrieval import TRACE_DIR, pull_trace
from rgse_daemon.trace.diadem import read_trace_set
from rgse_daemon.trace.names import plain_name
from simulators.krc4.sim import SimulatedKrc4
from tests.support.campaign import write_measurement
from tests.support.cli import fitted_dirs


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = fitted_dirs(tmp_path_factory.mktemp("names"), "gain-linear")
    write_measurement(root / "other", 250.0, seed=7, n_samples=300, n_loops=3)  # where the symlink attacks point
    return root


def mass_error(capsys: pytest.CaptureFixture[str], traces: Path, cal: Path) -> str:
    capsys.readouterr()
    assert main(["mass", "--traces", str(traces), "--calibration", str(cal)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize(("name", "problem"), [
    ("../other/dut_l01", "path separator"),
    ("..\\other\\dut_l01", "path separator"),
    ("/abs/path/dut_l02", "absolute path"),
    ("C:\\KRC\\ROBOTER\\TRACE\\dut_l02", "absolute path"),
    ("..", "directory reference"),
    ("dut\x00l01", "control character"),
])
def test_manifest_trace_name_that_is_a_path_is_refused(tmp_path, capsys, dirs, name, problem):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    m = d / "manifest.toml"
    m.write_text(m.read_text().replace('"dut_l01"', json.dumps(name)))
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert "traces[0]" in err and problem in err and str(m) in err, err


def test_campaign_manifest_trace_name_outside_is_refused(tmp_path, capsys, dirs):
    d = tmp_path / "cal"
    shutil.copytree(dirs / "cal", d)
    m = d / "manifest.toml"
    m.write_text(m.read_text().replace('"cal03_l01"', json.dumps(str(dirs / "cal" / "cal03_l01"))))
    capsys.readouterr()
    assert main(["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err
    assert "absolute path" in err and "traces[0]" in err and not (tmp_path / "o.json").exists()


def test_symlinked_data_file_leaving_the_directory_is_not_read(tmp_path, capsys, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    r64 = d / "dut_l02_NextGenDrive#3.r64"
    r64.unlink()
    r64.symlink_to("/etc/passwd")
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert "dut_l02_NextGenDrive#3.r64" in err and "symbolic link leads out" in err, err


def test_symlinked_header_to_another_directory_is_refused(tmp_path, capsys, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    for ext in ("dat", "r64"):  # a consistent pair in another measurement: the mass would be plausible, and wrong
        f = d / f"dut_l01_NextGenDrive#5.{ext}"
        f.unlink()
        f.symlink_to(dirs / "other" / f"dut_l01_NextGenDrive#5.{ext}")
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert "dut_l01_NextGenDrive#5.dat" in err and "symbolic link leads out" in err, err


def test_symlink_that_stays_inside_is_followed(tmp_path, dirs):
    d = tmp_path / "dut"
    shutil.copytree(dirs / "dut", d)
    (d / "keep").mkdir()
    r64 = d / "dut_l01_NextGenDrive#3.r64"
    os.replace(r64, d / "keep" / r64.name)
    r64.symlink_to(Path("keep") / r64.name)
    ts = read_trace_set(d, "dut_l01")
    assert ts.channel("NextGenDrive#3", "Istmoment").values.size == 300


def test_read_trace_set_refuses_a_path_as_trace_name(dirs):
    with pytest.raises(DataError, match=r"trace name.*path separator"):
        read_trace_set(dirs / "dut", "../other/dut_l01")


@pytest.mark.parametrize("name", ["dut_l01", "cal00_l01", "a..b", "Trace-1.v2", "x" * 128])
def test_plain_names_pass(name):
    assert plain_name(name, "f") == name


@pytest.mark.parametrize("name", ["", "x" * 129, "a/b", "a\\b", "/", ".", "..", "C:x", "a:b", "tab\there", "\x7f"])
def test_non_plain_names_fail_naming_the_field(name):
    with pytest.raises(DataError, match=r"^the field: "):
        plain_name(name, "the field")


def test_cal_json_source_reference_with_a_path_is_refused(tmp_path, capsys, dirs):
    doc = json.loads((dirs / "CAL.json").read_text())
    doc["source_sha256"]["../../etc/passwd"] = "0" * 64
    bad = tmp_path / "CAL.json"
    bad.write_text(json.dumps(calfile.seal(doc)))  # sealed: the reference itself is what must be refused
    err = mass_error(capsys, dirs / "dut", bad)
    assert "source_sha256" in err and "path separator" in err and str(bad) in err, err


@pytest.mark.parametrize("run_id", ["..", "."])
def test_mqtt_run_id_directory_reference_is_refused(run_id):
    with pytest.raises(CommandRefused, match=r"run_id.*directory reference"):
        parse_command("confirm", json.dumps({"request_id": "r1", "run_id": run_id}).encode())
    with pytest.raises(CommandRefused, match=r"run_id.*directory reference"):
        parse_command("abort", json.dumps({"request_id": "r1", "run_id": run_id, "reason": "x"}).encode())


async def test_controller_listing_with_a_hostile_file_name_is_refused(tmp_path):
    """A controller (or whoever answers on its port) lists a file whose name carries a terminal escape: the pull is
    refused naming the listing, nothing is archived."""
    async with SimulatedKrc4(tmp_path / "roboter", seed=7, time_scale=100.0, latency_s=0.0) as sim:
        trace = sim.share_dir / "TRACE"
        trace.mkdir(parents=True, exist_ok=True)
        for suffix in ("NextGenDrive#3.dat", "NextGenDrive#3.r64", "NextGenDrive#5.dat", "NextGenDrive#5.r64"):
            (trace / f"t1_{suffix}").write_bytes(b"x")
        (trace / "t1_NextGenDrive#3.trc\x1b[2J").write_bytes(b"x")
        cfg = ControllerConfig(host="127.0.0.1", port=sim.port, request_timeout_s=2.0, pool_size=1)
        async with Controller.connect(cfg) as krc:
            with pytest.raises(DataError, match=r"listed file.*control character"):
                await pull_trace(krc, "t1", tmp_path / "run")
            with pytest.raises(DataError, match=r"trace name.*path separator"):
                await pull_trace(krc, "../t1", tmp_path / "run")
    assert not any((tmp_path / "run").glob("t1_*"))
    assert TRACE_DIR.endswith("\\")
