"""The ``rgse`` parser: each sub-command's arguments are its module's (``add_arguments``), ``cli.py`` only wires them
(issue #32, "Tidy the rest"). ``main`` builds the arguments of the one sub-command it runs, so the parser it uses
must say what the whole parser says, and no other command module is imported for it."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from rgse_daemon.cli import COMMANDS, build_parser, command_module

#: Every (nested) sub-command's options and positionals, as they were when they moved out of ``cli.build_parser``
#: (``--help`` left out). A change to a command's options changes this list on purpose.
OPTIONS = {
    "rgse": "--debug --log-format --verbose --version -v",
    "rgse abort": "--config --reason --run --timeout",
    "rgse activate": "--config --json --note calibration",
    "rgse calibrate": "--campaign --drift-prior --json --method --out --points --preprocessing",
    "rgse certificate": "--config --out run_id",
    "rgse cog": "--calibration --json --traces",
    "rgse confirm": "--config --message --point --run --timeout",
    "rgse daemon": "--config",
    "rgse demo": "--console --inertia --json --mqtt --report --robot --seed",
    "rgse doctor": "--config --json --no-record",
    "rgse inertia": "--calibration --json --traces",
    "rgse krl": "",
    "rgse krl check": "--cog --config --payload file",
    "rgse krl render": "--config --out",
    "rgse mass": "--calibration --drift-prior --envelope-limit --fixture-mass --json --traces",
    "rgse plan": "--config --dut --json --lever-a5 --loops-per-point --mass --max-distance --points-out",
    "rgse reference": "--config --json --operation-min --operators --run --timeout --weighed",
    "rgse report": "--calibration --config --out run_id",
    "rgse run": "",
    "rgse run calibrate": "--config --json --method --on-prompt --points --report --timeout",
    "rgse run measure": "--config --dry-run --dut-name --fixture-mass --json --loops --note --on-prompt --operator "
                        "--part-number --project --report --serial-number --timeout",
    "rgse run properties": "--config --dry-run --dut-abc --dut-name --dut-origin --fixture-cog --fixture-mass "
                           "--inertia --json --loops --loops-per-pose --mass-method --no-inertia --note --on-prompt "
                           "--operator "
                           "--part-number --project --report --scheme --serial-number --timeout",
    "rgse runs": "--config --csv --dut --json --kind --out --robot --since --state --status --until",
    "rgse safety": "",
    "rgse safety clear": "--config --message",
    "rgse safety status": "--config",
    "rgse sim": "--commission --config --control-port --globals --host --port --scenario --share --time-scale",
    "rgse sim-op": "--control --json --timeout",
    "rgse sim-op acknowledge": "",
    "rgse sim-op enabling-switch": "state",
    "rgse sim-op mode": "mode",
    "rgse sim-op mount": "--bodies --cog --dut --fixture-mass --inertia --lever-a5 --mpa --nothing --torque",
    "rgse sim-op status": "",
    "rgse status": "--config --json --timeout",
    "rgse study": "--campaign --json --points",
}


def _parsers(parser: argparse.ArgumentParser, path: str = "rgse") -> dict[str, argparse.ArgumentParser]:
    """Every parser under ``parser`` by its command line (``rgse sim-op mount``)."""
    out = {path: parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.update(_parsers(sub, f"{path} {name}"))
    return out


def _options(parser: argparse.ArgumentParser) -> str:
    skip = argparse._SubParsersAction | argparse._HelpAction
    names = (o for a in parser._actions if not isinstance(a, skip) for o in (a.option_strings or [a.dest]))
    return " ".join(sorted(names))


def test_every_command_is_a_module_with_its_arguments_and_its_run() -> None:
    for name in COMMANDS:
        module = command_module(name)
        assert callable(module.add_arguments) and callable(module.run), name


def test_every_command_has_the_options_it_had_in_cli_py() -> None:
    assert {path: _options(p) for path, p in _parsers(build_parser()).items()} == OPTIONS


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_command_built_alone_says_what_the_whole_parser_says(command: str) -> None:
    """``main`` builds only the command it runs: each of its parsers' ``--help`` is the whole parser's."""
    whole = {path: p.format_help() for path, p in _parsers(build_parser()).items()}
    alone = {path: p.format_help() for path, p in _parsers(build_parser([command])).items()
             if path == f"rgse {command}" or path.startswith(f"rgse {command} ")}
    assert alone and alone == {path: whole[path] for path in alone}


def test_rgse_help_imports_no_command_module_and_a_command_only_its_own() -> None:
    probe = ("import sys\nfrom rgse_daemon.cli import main\n"
             "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
             "print(' '.join(sorted(m for m in sys.modules if m.startswith('rgse_daemon.commands.'))))")
    for argv, loaded in ((["--help"], ""), (["mass", "--help"], "rgse_daemon.commands.mass"),
                         (["--debug", "sim-op", "mode", "--help"], "rgse_daemon.commands.sim_op")):
        out = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=60,
                             check=True).stdout
        assert out.splitlines()[-1].strip() == loaded, (argv, out)
