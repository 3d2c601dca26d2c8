"""Identification on the simulator's traces (simulators.krc4.dynamics: rigid body, friction, the drive's error
model), written as KUKA Trace files and read back by ``rgse inertia``."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bench import inertia as bench
from rgse_daemon.analysis.inertia import MANIFEST, InertiaManifest
from rgse_daemon.cli import main
from rgse_daemon.pipeline import excitation as ex
from rgse_daemon.pipeline import inertia as inr
from rgse_daemon.trace.channels import drive_module
from simulators.krc4 import physics as ph
from simulators.krc4.dynamics import RobotDynamics
from simulators.krc4.tracefiles import write_trace_set


def _write(directory: Path, name: str, strokes: list, period_s: float) -> None:
    t = np.concatenate([s.t_s for s in strokes])
    order = np.argsort(t)
    soll = np.vstack([s.q_cmd_deg for s in strokes])[order]
    ist = np.vstack([s.q_deg for s in strokes])[order]
    tau = np.vstack([s.torque_nm for s in strokes])[order]
    temp = np.vstack([s.temp_k for s in strokes])[order]
    modules = {drive_module(ax): {"Sollposition": (soll[:, ax - 1], "deg"), "Istposition": (ist[:, ax - 1], "deg"),
                                  "Istmoment": (tau[:, ax - 1], "Nm"), "Motortemperatur": (temp[:, ax - 1], "K")}
               for ax in (4, 5, 6)}
    write_trace_set(directory, name, period_s, modules)


@pytest.fixture(scope="module")
def sim_runs() -> tuple[ph.AsymmetricDut, ph.RobotModel, list, list, tuple[float, float, float]]:
    dut = ph.refex_wing_box()
    design = ex.design(bench.payload_of(dut), limit_mm_s=bench.LIMIT_MM_S, optimise=False)
    model = ph.RobotModel(seed=5)
    dyn = RobotDynamics(model.scenario, robot=model.robot)
    tare = bench.simulate(design, ph.dut_payload(0.0, (0.0, 0.0, 0.0)), model, dyn, 250.0)
    loaded = bench.simulate(design, dut.payload(), model, dyn, 250.0)
    cog = tuple(float(c) for c in np.asarray(dut.cog_flange_m) + np.array([0.0, 0.0, model.mount_cog_shift_m]))
    return dut, model, tare, loaded, cog  # type: ignore[return-value]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory, sim_runs) -> Path:
    directory = tmp_path_factory.mktemp("inertia_run")
    dut, _, tare, loaded, cog = sim_runs
    _write(directory, "inertia_tare", tare, bench.PERIOD_S)
    _write(directory, "inertia_dut", loaded, bench.PERIOD_S)
    fix = ph.dut_payload(0.0, (0.0, 0.0, 0.0))
    man = InertiaManifest("inertia_dut", "inertia_tare", tuple(float(v) for v in tare[0].q_cmd_deg[0]), dut.mass_kg,
                          cog, (0.002, 0.002, 0.002), dut.dut_abc_deg, fix.mass_kg,  # type: ignore[arg-type]
                          tuple(float(c) for c in fix.cog_flange_m))  # type: ignore[arg-type]
    (directory / MANIFEST).write_text(man.to_toml(), encoding="utf-8")
    return directory


def test_rgse_inertia_gives_what_the_identification_gives_in_memory(run_dir, sim_runs, capsys) -> None:
    dut, _, tare, loaded, cog = sim_runs
    assert main(["inertia", "--traces", str(run_dir), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    moments = np.array(out["principal_moments_kgm2"])
    assert moments.shape == (3,) and np.all(np.diff(moments) >= 0)
    assert len(out["U_principal_moments_kgm2"]) == 3 and all(u > 0 for u in out["U_principal_moments_kgm2"])
    strokes = [inr.difference(d, t) for d, t in zip(loaded, tare, strict=True)]
    mem = inr.identify(strokes, bench.PERIOD_S, dut.mass_kg, cog, dut_abc_deg=dut.dut_abc_deg,
                       u_cog_flange_m=(0.001, 0.001, 0.001))
    assert out["n_strokes"] == mem.n_strokes
    # the files hold what the simulator traced (the strokes' edges may differ by a sample: a small part of U)
    assert np.all(np.abs(moments - mem.principal_moments_kgm2) <= 0.25 * mem.U_principal_moments_kgm2)


def test_rgse_inertia_prints_the_moments_with_U_and_the_ecss_comparison(run_dir, capsys) -> None:
    assert main(["inertia", "--traces", str(run_dir)]) == 0
    out = capsys.readouterr().out
    assert "inertia tensor about the CoG, DuT frame" in out
    for k in (1, 2, 3):
        assert f"I{k} = " in out
    assert "ECSS ±3 %" in out


def test_with_the_drive_gain_known_the_large_moments_are_close(sim_runs) -> None:
    # an *ideal* torque calibration (the simulator's own gain curve): what is left is friction, noise, drift; one
    # seed, so a regression check, not a coverage claim (bench/inertia.py has that)
    dut, model, tare, loaded, cog = sim_runs
    strokes = [inr.difference(d, t) for d, t in zip(loaded, tare, strict=True)]
    cal = inr.TorqueCalibration({a: bench.SimulatorGain(model, a) for a in inr.WRIST_AXES}, bench.fixture_pi())
    r = inr.identify(strokes, bench.PERIOD_S, dut.mass_kg, cog, dut_abc_deg=dut.dut_abc_deg, calibration=cal,
                     u_cog_flange_m=(0.001, 0.001, 0.001))
    truth = dut.principal_moments_kgm2
    assert np.all(np.abs(r.principal_moments_kgm2[1:] - truth[1:]) / truth[1:] < 0.06), r.principal_moments_kgm2


def test_a_tare_of_another_program_is_refused(run_dir, tmp_path: Path, capsys) -> None:
    directory = run_dir
    for f in directory.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    text = (tmp_path / MANIFEST).read_text().replace('tare_trace = "inertia_tare"', 'tare_trace = "inertia_dut_x"')
    (tmp_path / MANIFEST).write_text(text)
    assert main(["inertia", "--traces", str(tmp_path)]) != 0
    assert "inertia_dut_x" in capsys.readouterr().err


def _copy_with(run_dir: Path, target: Path, **replace: str) -> Path:
    """The run directory copied to ``target`` with manifest lines ``key = ...`` replaced by ``key = <value>``."""
    for f in run_dir.iterdir():
        (target / f.name).write_bytes(f.read_bytes())
    lines = (target / MANIFEST).read_text().splitlines()
    lines = [f"{k} = {replace[k]}" if (k := line.split(" =")[0]) in replace else line for line in lines]
    (target / MANIFEST).write_text("\n".join(lines) + "\n")
    return target


def _one_line_error(capsys: pytest.CaptureFixture[str], directory: Path) -> str:
    capsys.readouterr()
    rc = main(["inertia", "--traces", str(directory)])
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert rc == 2 and "I1 = " not in captured.out, (rc, captured.out, err)
    assert err.count("\n") == 0 and "Traceback" not in err and "error:" in err, err
    return err


def test_swapped_dut_and_tare_traces_are_refused(run_dir, tmp_path: Path, capsys) -> None:
    """As found: exit 0 with "I1 = -52.157 ± 3.436 kg·m²" (the difference changes sign: a negative moment)."""
    directory = _copy_with(run_dir, tmp_path, dut_trace='"inertia_tare"', tare_trace='"inertia_dut"')
    err = _one_line_error(capsys, directory)
    assert "not a rigid body's" in err and "is negative" in err and "swapped" in err, err
    assert "dut_trace / tare_trace" in err and "cog_flange_m" in err, err


@pytest.mark.parametrize(("key", "value", "needle"), [
    ("cog_flange_m", "[-40.1, -0.028, 0.345]", "cog_flange_m = [-40.1, -0.028, 0.345] is 40.1 m from the flange"),
    ("cog_flange_m", "[0.0, 0.0, nan]", "cog_flange_m must be 3 finite numbers"),
    ("fixture_cog_flange_m", "[0.0, 0.0, 40.0]", "fixture_cog_flange_m = [0.0, 0.0, 40.0] is 40 m from the flange"),
    ("U_cog_flange_m", "[0.002, -0.002, 0.002]", "U_cog_flange_m must be >= 0"),
])
def test_an_implausible_cog_is_refused_naming_the_key(run_dir, tmp_path: Path, capsys, key, value, needle) -> None:
    """As found: a CoG x of -40.1 m gave exit 0 with "I1 = -172535 kg·m²"."""
    directory = _copy_with(run_dir, tmp_path, **{key: value})
    err = _one_line_error(capsys, directory)
    assert needle in err and MANIFEST in err, err


@pytest.mark.parametrize(("dut", "tare"), [('"inertia_dut"', '"inertia_dut"'),
                                           ('["inertia_dut", "x"]', '["inertia_dut", "x"]')])
def test_the_same_trace_as_dut_and_tare_is_refused(run_dir, tmp_path: Path, capsys, dut, tare) -> None:
    """As found: "400 of 400 resamples … too few strokes" instead of the real problem."""
    directory = _copy_with(run_dir, tmp_path, dut_trace=dut, tare_trace=tare)
    err = _one_line_error(capsys, directory)
    assert "dut_trace and tare_trace both name 'inertia_dut'" in err and MANIFEST in err, err
    assert "resamples" not in err, err


def test_a_misspelt_key_is_refused_not_taken_as_its_default(run_dir, tmp_path: Path, capsys) -> None:
    """As found: `fixture_mas_kg` was ignored, so the fixture's mass silently became 0."""
    directory = _copy_with(run_dir, tmp_path)
    text = (directory / MANIFEST).read_text()
    (directory / MANIFEST).write_text(text.replace("[inertia]", "[inertia]\nfixture_mas_kg = 3.0", 1))
    err = _one_line_error(capsys, directory)
    assert "unknown key 'fixture_mas_kg' (did you mean 'fixture_mass_kg'?)" in err and MANIFEST in err, err


def test_a_moment_below_zero_within_U_is_left_to_U() -> None:
    inr.check_physical(np.array([-0.01, 1.0, 1.0]), np.array([0.02, 0.05, 0.05]))
    inr.check_physical(np.array([0.5, 0.5, 1.05]), np.array([0.02, 0.02, 0.02]))
    with pytest.raises(inr.NotPhysical, match=re.escape("I1 + I2 = 1.000 kg·m² < I3 = 1.500")):
        inr.check_physical(np.array([0.5, 0.5, 1.5]), np.array([0.02, 0.02, 0.02]))
    # without a calibration (the axes' scales not in U) the triangle is the caller's warning
    assert "I1 + I2 = 1.000" in str(inr.check_physical(np.array([0.5, 0.5, 1.5]), np.full(3, 0.02), triangle=False))
    with pytest.raises(inr.NotPhysical, match=re.escape("I1 = -0.100 ± 0.020 kg·m² is negative")):
        inr.check_physical(np.array([-0.1, 1.0, 1.0]), np.array([0.02, 0.05, 0.05]))
