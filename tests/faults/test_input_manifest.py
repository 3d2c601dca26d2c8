"""Bad ``manifest.toml`` and points CSV files get a one-line DataError naming the file, the key or trace and the
problem (exit 2, no traceback), through the real CLI on real directories."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from rgse_daemon.cli import main
from tests.support.campaign import write_campaign, write_measurement


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("manifest")
    write_campaign(root / "cal", seed=5, n_samples=300)
    write_measurement(root / "dut", 100.0, seed=6, n_samples=300, n_loops=3)
    assert main(["calibrate", "--campaign", str(root / "cal"), "--out", str(root / "CAL.json"),
                 "--method", "gain-linear"]) == 0
    return root


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


def mass_error(capsys: pytest.CaptureFixture[str], traces: Path, cal: Path) -> str:
    return one_line_error(capsys, ["mass", "--traces", str(traces), "--calibration", str(cal)])


def copy(dirs: Path, tmp_path: Path, name: str) -> tuple[Path, Path]:
    d = tmp_path / name
    shutil.copytree(dirs / name, d)
    return d, d / "manifest.toml"


# --- the file itself ---------------------------------------------------------------------------------------------
def test_manifest_that_is_a_directory_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.unlink()
    m.mkdir()
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "is a directory" in err, err
    assert m.is_dir()


def test_manifest_that_cannot_be_read_is_refused(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    m.unlink()
    m.symlink_to(m.name)  # a loop: an OSError (ELOOP) other than not found, also for root
    err = mass_error(capsys, d, dirs / "CAL.json")
    assert str(m) in err and "cannot read" in err, err


@pytest.mark.parametrize("prefix", ["point = 5\n", "point = [1, 2]\n", 'point = "x"\n'])
def test_point_that_is_not_an_array_of_tables_is_refused(tmp_path, capsys, dirs, prefix):
    d, m = copy(dirs, tmp_path, "cal")
    text = m.read_text()
    m.write_text(prefix + text[text.index("[setup]"):text.index("[[point]]")])
    err = one_line_error(capsys, ["calibrate", "--campaign", str(d), "--out", str(tmp_path / "o.json")])
    assert str(m) in err and "'point' must be [[point]] tables" in err, err
    assert not (tmp_path / "o.json").exists()


def test_manifest_with_a_utf8_bom_is_read(tmp_path, capsys, dirs):
    d, m = copy(dirs, tmp_path, "dut")
    capsys.readouterr()
    assert main(["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json"), "--json"]) == 0
    plain = capsys.readouterr().out
    m.write_bytes(b"\xef\xbb\xbf" + m.read_bytes())
    assert main(["mass", "--traces", str(d), "--calibration", str(dirs / "CAL.json"), "--json"]) == 0
    assert capsys.readouterr().out == plain
