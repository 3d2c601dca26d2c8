from __future__ import annotations

from pathlib import Path

import pytest

from rgse_daemon.cli import main
from rgse_daemon.config import Protocol, load_config
from rgse_daemon.errors import ConfigError


def test_defaults_are_the_papers_setup() -> None:
    cfg = load_config(None)
    assert cfg.limits.t1_speed_mm_s == 200.0
    assert cfg.limits.a1_range_deg == 45.0
    assert cfg.controller.port == 7000
    assert cfg.controller.protocol is Protocol.AUTO


def test_file_values_and_nested_sections(tmp_path: Path) -> None:
    f = tmp_path / "rgse.toml"
    f.write_text('[robot]\nname = "KR500-7"\n[controller]\nhost = "10.1.2.3"\npool_size = 10\n')
    cfg = load_config(f)
    assert cfg.robot.name == "KR500-7"
    assert cfg.controller.host == "10.1.2.3"
    assert cfg.controller.pool_size == 10


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ("[controller]\nbogus = 1\n", "controller.bogus: unknown key"),
        ("[nonsense]\nx = 1\n", "nonsense: unknown key"),
        ("[controller]\npool_size = 11\n", "controller.pool_size"),
        ("[controller]\nport = 0\n", "controller.port"),
        ("[controller]\nkeepalive_s = 30\n", "controller.keepalive_s"),
        ("[controller]\nreconnect_min_s = 5\nreconnect_max_s = 1\n", "reconnect_min_s"),
        ("[limits]\nt1_speed_mm_s = 251\n", "limits.t1_speed_mm_s"),
        ("[robot]\nname = 'a b'\n", "robot.name"),
        ("[controller\n", "not valid TOML"),
    ],
)
def test_bad_config_names_the_field(tmp_path: Path, toml: str, expected: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(toml)
    with pytest.raises(ConfigError) as err:
        load_config(f)
    assert str(f) in str(err.value)
    assert expected in str(err.value)


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(tmp_path / "absent.toml")


def test_environment_overrides_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    f = tmp_path / "rgse.toml"
    f.write_text('[controller]\nhost = "10.1.2.3"\nport = 7001\n')
    monkeypatch.setenv("RGSE_CONTROLLER__PORT", "7002")
    cfg = load_config(f)
    assert (cfg.controller.host, cfg.controller.port) == ("10.1.2.3", 7002)


def test_cli_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ex:
        main(["--version"])
    assert ex.value.code == 0
    assert "rgse 0." in capsys.readouterr().out


def test_leak_guard_fails_a_leaking_test(pytester: pytest.Pytester) -> None:
    pytester.makeconftest((Path(__file__).parent.parent / "conftest.py").read_text())
    pytester.makeini("[pytest]\nasyncio_mode = auto\nasyncio_default_fixture_loop_scope = function\n")
    pytester.makepyfile(
        """
        import asyncio

        async def test_leaks():
            asyncio.create_task(asyncio.sleep(30), name="forgotten")

        async def test_clean():
            await asyncio.create_task(asyncio.sleep(0))
        """
    )
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=2, errors=1)  # the leaking test errors in teardown
    result.stdout.fnmatch_lines(["*leaked 1 asyncio task*forgotten*"])


def test_cli_survives_a_closed_pipe(paper_dir: Path) -> None:
    """`rgse ... | head`: the reader is gone before we write; no traceback, no failure status."""
    import subprocess
    import sys

    rgse = Path(sys.executable).with_name("rgse")
    proc = subprocess.Popen(
        [str(rgse), "study", "--points", str(paper_dir / "table1_calibration.csv")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stdout is not None
    proc.stdout.close()  # the reader goes away while the child is still starting
    _, err = proc.communicate(timeout=120)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert proc.returncode == 0
