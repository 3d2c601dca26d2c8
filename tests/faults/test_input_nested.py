"""Files nested thousands deep: the json and tomllib modules answer with ``RecursionError`` (a ``RuntimeError``, not
their decode errors), which every reader of an outside file must turn into its own clear error like any other
malformed file, and the safety latch into a latch that holds."""

from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon.client.types import load_points
from rgse_daemon.commands.sim import load_scenario
from rgse_daemon.errors import ConfigError, DataError
from rgse_daemon.filelayout import layout_path, load_layout
from rgse_daemon.safety.latch import latch_path, read_latch
from tests.support.cli import fitted_dirs, one_line_error

DEPTH = 100_000
DEEP_JSON = "[" * DEPTH + "]" * DEPTH
DEEP_TOML = "a = " + DEEP_JSON + "\n"


@pytest.fixture(scope="module")
def dirs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fitted_dirs(tmp_path_factory.mktemp("nested"), "axis-quad")


def test_a_nested_calibration_or_manifest_is_a_one_line_error(capsys, tmp_path: Path, dirs: Path) -> None:
    cal = tmp_path / "CAL.json"
    cal.write_text(DEEP_JSON)
    err = one_line_error(capsys, ["mass", "--traces", str(dirs / "dut"), "--calibration", str(cal)])
    assert err.endswith(f"{cal}: not a readable JSON calibration file: nested too deeply"), err
    campaign = tmp_path / "campaign"
    campaign.mkdir()
    (campaign / "manifest.toml").write_text(DEEP_TOML)
    err = one_line_error(capsys, ["calibrate", "--campaign", str(campaign), "--out", str(tmp_path / "X.json")])
    assert err.endswith(f"{campaign / 'manifest.toml'}: not valid TOML: nested too deeply"), err
    assert not (tmp_path / "X.json").exists()


def test_a_nested_config_scenario_or_points_file_is_refused_naming_it(capsys, tmp_path: Path) -> None:
    path = tmp_path / "deep.toml"
    path.write_text(DEEP_TOML)
    err = one_line_error(capsys, ["daemon", "--config", str(path)])
    assert err.endswith(f"{path}: not valid TOML: nested too deeply"), err
    with pytest.raises(ConfigError, match=r"deep\.toml: scenario is not valid TOML: nested too deeply$"):
        load_scenario(path)
    with pytest.raises(DataError, match=r"deep\.toml: cannot read the points file: nested too deeply$"):
        load_points(path)


def test_a_nested_latch_file_still_latches_and_a_nested_layout_is_refused(tmp_path: Path) -> None:
    latch_path(tmp_path).write_text(DEEP_JSON)
    latch = read_latch(tmp_path)
    assert latch is not None and latch.reason.endswith("it is still a latch"), latch
    layout_path(tmp_path).write_text(DEEP_JSON)
    with pytest.raises(ConfigError, match="not a controller layout record"):
        load_layout(tmp_path)
