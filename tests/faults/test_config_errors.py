"""Finding 6 of #12: every bad configuration value, whatever its source (file, environment, command line), ends in
one clear line naming the source and the problem, exit 2, before any I/O; empty tokens and NaN/inf are refused
with the right reason."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from rgse_daemon.cli import main

ROOT = Path(__file__).resolve().parents[2]


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    capsys.readouterr()
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse
        rc = exc.code
    err = capsys.readouterr().err.strip()
    assert rc == 2, (rc, err)
    assert err.count("\n") == 0 and "Traceback" not in err and "error:" in err, err
    return err


@pytest.fixture
def config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for k in list(os.environ):
        if k.upper().startswith("RGSE_"):
            monkeypatch.delenv(k)
    f = tmp_path / "rgse.toml"
    f.write_text('[robot]\nname = "KR500R2830"\n')
    return f


ENV_CASES = [
    # (variable, value, what the line must say)
    ("RGSE_MQTT__COMMAND_TOKENS", "notjson", "RGSE_MQTT__COMMAND_TOKENS: not a valid value for 'mqtt'"),
    ("RGSE_CONTROLLER", "junk", "RGSE_CONTROLLER: not a valid value for 'controller'"),
    ("RGSE_CONTROLLER", '{"port": 0}', "controller.port (from environment RGSE_CONTROLLER)"),
    ("RGSE_MQTT__COMMAND_TOKENS", '[""]', "token 0 is empty"),
    ("RGSE_MQTT__COMMAND_TOKENS", '["ok-token", "   "]', "token 1 is empty"),
    ("RGSE_MQTT__COMMAND_TOKENS", '["with space"]', "without spaces"),
    ("RGSE_MEASUREMENT__SETTLE_S", "nan", "settle_s (from environment RGSE_MEASUREMENT__SETTLE_S): Input should be a\
 finite number"),
    ("RGSE_MEASUREMENT__SETTLE_S", "inf", "Input should be a finite number"),
    ("RGSE_LIMITS__T1_SPEED_MM_S", "-inf", "(from environment RGSE_LIMITS__T1_SPEED_MM_S): Input should be a finite"),
    ("RGSE_MODBUS", '{"host": "127.0.0.1", "poll_period_s": NaN}', "Input should be a finite number"),
    ("RGSE_CONTROLLER__PORT", "abc", "controller.port (from environment RGSE_CONTROLLER__PORT)"),
    ("RGSE_MQTT__COMMAND_TOKEN", '["x"]', "command_token (from environment RGSE_MQTT__COMMAND_TOKEN): unknown key"),
    ("rgse_mqtt__tls", "maybe", "mqtt.tls (from environment rgse_mqtt__tls)"),
    ("RGSE_MQQT__HOST", "broker", "RGSE_MQQT__HOST: no config section 'mqqt'"),
]


@pytest.mark.parametrize(("var", "value", "needle"), ENV_CASES, ids=[f"{c[0]}={c[1]}" for c in ENV_CASES])
def test_bad_environment_value_is_one_line_exit_2(capsys, monkeypatch, config, var, value, needle):
    monkeypatch.setenv(var, value)
    err = one_line_error(capsys, ["daemon", "--config", str(config)])
    assert needle in err and str(config) in err, err


FILE_CASES = [
    ('[mqtt]\ncommand_tokens = [""]\n', "mqtt.command_tokens: token 0 is empty"),
    ("[measurement]\nsettle_s = nan\n", "measurement.settle_s: Input should be a finite number"),
    ("[measurement]\nsettle_s = inf\n", "measurement.settle_s: Input should be a finite number"),
    ("[controller]\nkeepalive_s = -nan\n", "controller.keepalive_s: Input should be a finite number"),
    ('[scale]\nport = "/dev/ttyUSB0"\ndefault_timeout_s = inf\n', "Input should be a finite number"),
    ("[measurement]\nsettle_s = 1e999\n", "Input should be a finite number"),
    ("[measurement\n", "not valid TOML"),
]


@pytest.mark.parametrize(("text", "needle"), FILE_CASES)
def test_bad_file_value_is_one_line_exit_2(capsys, config, text, needle):
    config.write_text(text)
    err = one_line_error(capsys, ["daemon", "--config", str(config)])
    assert needle in err and str(config) in err, err


CLI_CASES = [
    (["mass", "--traces", "d", "--calibration", "c", "--fixture-mass", "nan"], "--fixture-mass: must be a finite"),
    (["mass", "--traces", "d", "--calibration", "c", "--fixture-mass", "ten"], "--fixture-mass: not a number"),
    (["status", "--config", "x.toml", "--timeout", "inf"], "must be a finite number"),
    (["abort", "--config", "x.toml", "--timeout", "0"], "> 0"),
    (["confirm", "--config", "x.toml", "--timeout=-nan"], "must be a finite number"),
    (["reference", "--run", "r", "--operation-min", "inf"], "--operation-min: must be a finite number"),
    (["sim", "--time-scale", "nan"], "--time-scale nan"),  # rgse sim checks it itself
    (["sim", "--port", "x"], "--port: invalid int value"),
    (["mass", "--traces"], "--traces: expected one argument"),
]


@pytest.mark.parametrize(("argv", "needle"), CLI_CASES, ids=[" ".join(c[0]) for c in CLI_CASES])
def test_bad_command_line_value_is_one_line_exit_2(capsys, config, argv, needle):
    config.write_text('[mqtt]\nenabled = true\ncommand_tokens = ["s3cret-token"]\n')
    err = one_line_error(capsys, [str(config) if a == "x.toml" else a for a in argv])
    assert needle in err and f"rgse {argv[0]}" in err, err


@pytest.mark.parametrize("env", [{"RGSE_MQTT__COMMAND_TOKENS": "notjson"}, {"RGSE_CONTROLLER": "junk"}])
def test_the_reported_overrides_as_a_process(tmp_path, env):
    """As found: ``rgse daemon`` started with the override, a separate process (50-line traceback, exit 1 before)."""
    config = tmp_path / "rgse.toml"
    config.write_text('[robot]\nname = "KR500R2830"\n')
    clean = {k: v for k, v in os.environ.items() if not k.upper().startswith("RGSE_")}
    done = subprocess.run([sys.executable, "-m", "rgse_daemon", "daemon", "--config", str(config)], cwd=ROOT,
                          env={**clean, **env}, capture_output=True, text=True, timeout=60)
    (var,) = env
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and var in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_valid_overrides_still_apply(monkeypatch, config):
    from rgse_daemon.config import load_config

    monkeypatch.setenv("RGSE_MQTT__COMMAND_TOKENS", '["s3cret-token"]')
    monkeypatch.setenv("RGSE_LOG_FORMAT", "text")  # not a config section: left to the logger
    monkeypatch.setenv("RGSE_MEASUREMENT__SETTLE_S", "2.5")
    cfg = load_config(config)
    assert cfg.mqtt.command_tokens == ("s3cret-token",) and cfg.measurement.settle_s == 2.5
