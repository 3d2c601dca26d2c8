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
    ("RGSE_MEASUREMENT__DRIFT_PRIOR_PER_K", "-0.001", "measurement.drift_prior_per_k (from environment "
     "RGSE_MEASUREMENT__DRIFT_PRIOR_PER_K): Input should be greater than 0"),
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
    ("[measurement]\ndrift_prior_per_k = 0\n", "measurement.drift_prior_per_k: Input should be greater than 0"),
    ("[measurement]\ndrift_prior_per_k = 0.3\n", "measurement.drift_prior_per_k: Input should be less than or equal "
                                                  "to 0.05"),
    ("[measurement]\ndrift_prior_per_k = nan\n", "measurement.drift_prior_per_k: Input should be a finite number"),
    ('[measurement]\ndrift_prior_per_k = "0.003"\n', "measurement.drift_prior_per_k: Input should be a valid number"),
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


def loads(capsys: pytest.CaptureFixture[str], config: Path) -> str:
    """The one-line error of the real loader through a command that exits right after its work (``rgse krl check``
    of an empty program): ``rgse daemon`` would keep running on a config that wrongly loads."""
    program = config.with_name("empty.src")
    program.write_text("DEF empty()\nEND\n")
    return one_line_error(capsys, ["krl", "check", str(program), "--config", str(config)])


WRONG_TYPE_CASES = [
    # (file, what the line must say): a wrong type is refused, never coerced (docs/configuration.md)
    ("[controller]\nport = true\n", "controller.port: Input should be a valid integer, got a boolean"),
    ('[controller]\nport = "7000"\n', "controller.port: Input should be a valid integer, got a string"),
    ('[measurement]\nloops = "10"\n', "measurement.loops: Input should be a valid integer, got a string"),
    ("[measurement]\nloops = 10.0\n", "measurement.loops: Input should be a valid integer, got a float"),
    ('[measurement]\nwarmup_until_steady = "yes"\n',
     "measurement.warmup_until_steady: Input should be a valid boolean, got a string"),
    ("[measurement]\nwarmup_until_steady = 1\n", "measurement.warmup_until_steady: Input should be a valid boolean"),
    ('[limits]\nt1_speed_mm_s = "200"\n', "limits.t1_speed_mm_s: Input should be a valid number, got a string"),
    ("[mqtt]\ntls = 0\n", "mqtt.tls: Input should be a valid boolean, got an integer"),
    ('[scale]\nport = 3\n', "scale.port: Input should be a valid string, got an integer"),
    ('[properties.fixture]\ncog_flange_m = [0, 0, "0.05"]\n', "properties.fixture.cog_flange_m.2: Input should be"),
    ('[paths]\ndata_dir = ""\n', 'paths.data_dir: must not be empty (write "." for the current directory)'),
    ('[paths]\ndata_dir = "  "\n', "paths.data_dir: must not be empty"),
    ('[controller]\nshare_dir = ""\n', "controller.share_dir: must not be empty"),
    ("[paths]\ndata_dir = 5\n", "paths.data_dir: "),
]


@pytest.mark.parametrize(("text", "needle"), WRONG_TYPE_CASES, ids=[c[0] for c in WRONG_TYPE_CASES])
def test_wrong_type_in_the_file_is_refused_not_coerced(capsys, config, text, needle):
    config.write_text(text)
    err = loads(capsys, config)
    assert needle in err and str(config) in err, err


def test_the_file_keeps_its_natural_types(config):
    """Strict, yet an integer is a float, a string a path, an array a tuple, a string the protocol."""
    from rgse_daemon.config import Protocol, load_config

    config.write_text('[controller]\nprotocol = "kvp"\nshare_dir = "/mnt/krc4"\nport = 7001\n'
                      '[paths]\ndata_dir = "."\n[measurement]\nsettle_s = 1\nloops = 3\nwarmup_until_steady = false\n'
                      '[mqtt]\ncommand_tokens = ["s3cret-token"]\n[properties.fixture]\ncog_flange_m = [0, 0, 0.05]\n')
    cfg = load_config(config)
    assert cfg.controller.protocol is Protocol.KVP and cfg.controller.share_dir == Path("/mnt/krc4")
    assert cfg.controller.port == 7001 and cfg.paths.data_dir == Path(".")
    assert cfg.measurement.settle_s == 1.0 and isinstance(cfg.measurement.settle_s, float)
    assert cfg.measurement.loops == 3 and cfg.measurement.warmup_until_steady is False
    assert cfg.mqtt.command_tokens == ("s3cret-token",) and cfg.properties.fixture.cog_flange_m == (0.0, 0.0, 0.05)


def test_environment_overrides_are_still_text(monkeypatch, config):
    """An environment value is text: it is converted as before (docs: booleans ``true``/``false`` or ``1``/``0``)."""
    from rgse_daemon.config import Protocol, load_config

    for var, value in [("RGSE_CONTROLLER__PORT", "7001"), ("RGSE_MEASUREMENT__LOOPS", "4"),
                       ("RGSE_MEASUREMENT__WARMUP_UNTIL_STEADY", "0"), ("RGSE_MQTT__TLS", "true"),
                       ("RGSE_CONTROLLER__PROTOCOL", "kvp"), ("RGSE_PATHS__DATA_DIR", "/var/lib/rgse"),
                       ("RGSE_MODBUS__INPUTS__ESTOP_OK", "7"), ("RGSE_LIMITS__T1_SPEED_MM_S", "150")]:
        monkeypatch.setenv(var, value)
    cfg = load_config(config)
    assert cfg.controller.port == 7001 and cfg.measurement.loops == 4 and cfg.measurement.warmup_until_steady is False
    assert cfg.mqtt.tls is True and cfg.controller.protocol is Protocol.KVP
    assert cfg.paths.data_dir == Path("/var/lib/rgse")
    assert cfg.modbus is not None and cfg.modbus.inputs.estop_ok == 7 and cfg.limits.t1_speed_mm_s == 150.0


LIMIT_CASES = [
    # measurement settings outside the configured limits: refused at load, naming both keys
    ("[measurement]\nbrake_release_deg = 90\n",
     "measurement.brake_release_deg = 90 exceeds limits.brake_release_max_deg = 45"),
    ("[measurement]\nbrake_release_deg = 40\n[limits]\nbrake_release_max_deg = 30\n",
     "measurement.brake_release_deg = 40 exceeds limits.brake_release_max_deg = 30"),
    ("[measurement]\nbrake_release_deg = 20\nwarmup_amplitude_deg = 30\n[limits]\nbrake_release_max_deg = 25\n",
     "measurement.warmup_amplitude_deg = 30 exceeds limits.brake_release_max_deg = 25"),
    ("[measurement]\nfixture_mass_kg = 600\n[limits]\nmax_payload_kg = 500\n",
     "measurement.fixture_mass_kg = 600 exceeds limits.max_payload_kg = 500"),
    ("[measurement]\npayload_lever_max_m = 0.5\n[properties.fixture]\ncog_flange_m = [0, 0.4, 0.4]\n",
     "properties.fixture.cog_flange_m is 0.565685 m from the flange, beyond measurement.payload_lever_max_m = 0.5"),
]


@pytest.mark.parametrize(("text", "needle"), LIMIT_CASES, ids=[c[1].split(" =")[0] for c in LIMIT_CASES])
def test_measurement_outside_the_limits_is_refused_at_load(capsys, config, text, needle):
    config.write_text(text)
    err = loads(capsys, config)
    assert needle in err and str(config) in err, err


def test_measurement_limit_from_the_environment(capsys, monkeypatch, config):
    config.write_text("[measurement]\nbrake_release_deg = 40\n")
    monkeypatch.setenv("RGSE_LIMITS__BRAKE_RELEASE_MAX_DEG", "30")
    err = loads(capsys, config)
    assert "measurement.brake_release_deg = 40 exceeds limits.brake_release_max_deg = 30" in err, err


def test_krl_render_names_the_key(capsys, config, tmp_path):
    """Within the limits but beyond the axis range: `rgse krl render` says so in one line naming the key (it dumped
    pydantic's multi-line error naming only the template parameter)."""
    config.write_text("[measurement]\nbrake_release_deg = 60\n[limits]\nbrake_release_max_deg = 90\n")
    err = one_line_error(capsys, ["krl", "render", "--out", str(tmp_path / "out"), "--config", str(config)])
    assert "rgse_brake_release" in err and "outside the axis range" in err, err
    assert f"measurement.brake_release_deg = 60 in {config}" in err and "validation error" not in err, err


EMPTY_PATH_OVERRIDES = [
    # (variable, value, the key it sets): an EnvironmentFile line `RGSE_PATHS__DATA_DIR=` is an easy mistake
    ("RGSE_PATHS__DATA_DIR", "", "paths.data_dir"),
    ("RGSE_PATHS__DATA_DIR", "   ", "paths.data_dir"),
    ("rgse_paths__data_dir", "", "paths.data_dir"),
    ("RGSE_PATHS", '{"data_dir": ""}', "paths.data_dir"),
    ("RGSE_CONTROLLER__SHARE_DIR", "", "controller.share_dir"),
    ("RGSE_MQTT__TLS_CA_FILE", "", "mqtt.tls_ca_file"),
]


@pytest.mark.parametrize(("var", "value", "key"), EMPTY_PATH_OVERRIDES,
                         ids=[f"{c[0]}={c[1]!r}" for c in EMPTY_PATH_OVERRIDES])
def test_an_empty_path_override_is_an_error_naming_the_variable(capsys, monkeypatch, config, var, value, key):
    """An empty path from the environment is refused as one from the file is: it does not silently become the
    current directory (``Path("")`` is ``.``) nor leave the file's value in place."""
    config.write_text(f'[robot]\nname = "KR500R2830"\n[paths]\ndata_dir = "{config.parent / "data"}"\n')
    monkeypatch.setenv(var, value)
    monkeypatch.chdir(config.parent)
    err = one_line_error(capsys, ["safety", "status", "--config", str(config)])  # loads the config, reads data_dir
    assert f"{key} (from environment {var}): must not be empty" in err and str(config) in err, err


def test_a_path_override_that_is_not_empty_still_applies(monkeypatch, config, tmp_path):
    from rgse_daemon.config import load_config

    config.write_text(f'[robot]\nname = "KR500R2830"\n[paths]\ndata_dir = "{tmp_path / "file"}"\n')
    monkeypatch.setenv("RGSE_PATHS__DATA_DIR", str(tmp_path / "env"))
    assert load_config(config).paths.data_dir == tmp_path / "env"
    monkeypatch.setenv("RGSE_PATHS__DATA_DIR", ".")  # the current directory, said explicitly
    assert load_config(config).paths.data_dir == Path(".")


def test_an_empty_data_dir_line_of_an_environment_file_stops_the_daemon(tmp_path):
    """As systemd's ``EnvironmentFile=`` passes ``RGSE_PATHS__DATA_DIR=``: the daemon, a process of its own, ends at
    once with one line naming the variable (exit 2), before it opens a store in whatever its working directory is."""
    config = tmp_path / "rgse.toml"
    config.write_text(f'[robot]\nname = "KR500R2830"\n[paths]\ndata_dir = "{tmp_path / "data"}"\n')
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    clean = {k: v for k, v in os.environ.items() if not k.upper().startswith("RGSE_")}
    daemon = subprocess.Popen([sys.executable, "-m", "rgse_daemon", "daemon", "--config", str(config)], cwd=cwd,
                              env={**clean, "PYTHONPATH": str(ROOT), "RGSE_PATHS__DATA_DIR": ""},
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, stderr = daemon.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        daemon.kill()
        _, stderr = daemon.communicate()
        pytest.fail(f"the daemon started (data_dir: {sorted(p.name for p in cwd.iterdir())} in its working "
                    f"directory): {stderr}")
    assert daemon.returncode == 2, stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr, stderr
    assert "paths.data_dir (from environment RGSE_PATHS__DATA_DIR): must not be empty" in stderr, stderr
    assert list(cwd.iterdir()) == [] and not (tmp_path / "data").exists()
