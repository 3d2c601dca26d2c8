"""Issue 33: the thermal drift prior is configurable (``measurement.drift_prior_per_k``) and travels with the run:
the daemon writes it into the measurement directory's manifest, where ``rgse mass`` reads it back, so a stored
result is recomputed with the bound it was computed with."""

from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon.config import load_config
from rgse_daemon.errors import ConfigError
from rgse_daemon.manifest import load_manifest
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K
from rgse_daemon.procedures.measurement import write_measurement_dir
from rgse_daemon.procedures.settings import RunSettings

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_the_configured_prior_reaches_the_runs_manifest(tmp_path: Path) -> None:
    example = (DEPLOY / "rgse.example.toml").read_text()
    assert load_config(DEPLOY / "rgse.example.toml").measurement.drift_prior_per_k == DRIFT_PRIOR_PER_K
    cfg_file = tmp_path / "rgse.toml"
    cfg_file.write_text(example.replace("drift_prior_per_k = 0.003", "drift_prior_per_k = 0.0015"))
    s = RunSettings.from_config(load_config(cfg_file))
    assert s.drift_prior_per_k == 0.0015
    write_measurement_dir(tmp_path / "run", s, ["dut_l01", "dut_l02"], {"calibration_id": "x"})
    man = load_manifest(tmp_path / "run")
    assert man.drift_prior_per_k == 0.0015 and man.measurement_traces == ("dut_l01", "dut_l02")
    cfg_file.write_text(example.replace("drift_prior_per_k = 0.003", "drift_prior_per_k = 0.3"))
    with pytest.raises(ConfigError, match="drift_prior_per_k"):
        load_config(cfg_file)
