"""Synthetic campaign and measurement directories with known truth (manifest.toml + KUKA trace file sets).

The simulated drive reports ``M_meas = sign · G⁻¹(g·m·lever) + M_0`` per axis with a constant gain per axis,
plus white noise, a decaying settling transient and sparse spikes: what pre-processing and calibration must undo.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgse_daemon import robots
from simulators.krc4.tracefiles import write_trace_set

G = 9.81
_KR500 = robots.get(robots.DEFAULT_KEY)  # the paper's robot and load set
DR = _KR500.lever_difference_m
ROBOT = "KR500R2830-TEST"


@dataclass(frozen=True)
class Drive:
    gain_a3: float = 1.095
    gain_a5: float = 0.87
    bias_a3_nm: float = 1320.46
    bias_a5_nm: float = 315.96
    sign_a3: float = 1.0
    sign_a5: float = 1.0
    noise_nm: float = 8.0
    transient_nm: float = 15.0
    spike_fraction: float = 0.01


def _loop(true_nm: float, gain: float, bias: float, sign: float, n: int, period_s: float, drive: Drive,
          rng: np.random.Generator) -> np.ndarray:
    t = np.arange(n) * period_s
    x = sign * true_nm / gain + bias
    x = x + drive.transient_nm * np.exp(-t / 0.3) + rng.normal(0.0, drive.noise_nm, n)
    spikes = rng.random(n) < drive.spike_fraction
    x[spikes] += rng.choice([-1.0, 1.0], spikes.sum()) * 25 * drive.noise_nm
    return x


def _write(directory: Path, name: str, a3: np.ndarray, a5: np.ndarray, period_s: float, storage: str,
           factor: float) -> None:
    write_trace_set(directory, name, period_s,
                    {"NextGenDrive#3": {"Istmoment": (a3, "Nm")}, "NextGenDrive#5": {"Istmoment": (a5, "Nm")}},
                    storage=storage, factor=factor)


def write_campaign(directory: Path, seed: int = 0, drive: Drive = Drive(), n_samples: int = 1500,
                   period_s: float = 0.004, n_loops: int = 2, storage: str = "BLOCK", factor: float = 1.0,
                   robot: str = ROBOT) -> None:
    """A Table-1-like campaign: zero point, 10 stacked CB points, 3 torque points on a longer lever."""
    rng = np.random.default_rng(seed)
    directory.mkdir(parents=True, exist_ok=True)
    c = _KR500.calibration
    l5_zero = c.zero_lever_a5_m
    specs = [("zero", 0.0, l5_zero + DR, l5_zero)]
    specs += [("mass", c.body_mass_kg * k, l5_zero + DR + c.stack_step_m * k, l5_zero + c.stack_step_m * k)
              for k in range(1, 11)]
    specs += [("torque", 228.51, 1.80 + 0.25 * j, 0.775 + 0.25 * j) for j in range(3)]
    lines = ["[setup]", f'robot = "{robot}"', f"g = {G}", f"lever_difference_m = {DR}", ""]
    for i, (kind, m, l3, l5) in enumerate(specs):
        names = []
        for j in range(n_loops):
            name = f"cal{i:02d}_l{j + 1:02d}"
            a3 = _loop(G * m * l3, drive.gain_a3, drive.bias_a3_nm, drive.sign_a3, n_samples, period_s, drive, rng)
            a5 = _loop(G * m * l5, drive.gain_a5, drive.bias_a5_nm, drive.sign_a5, n_samples, period_s, drive, rng)
            _write(directory, name, a3, a5, period_s, storage, factor)
            names.append(name)
        lines += ["[[point]]", f'kind = "{kind}"', f"mass_kg = {m!r}", f"lever_a3_m = {l3!r}",
                  f"lever_a5_m = {l5!r}", "traces = [" + ", ".join(f'"{n}"' for n in names) + "]", ""]
    (directory / "manifest.toml").write_text("\n".join(lines), encoding="utf-8")


FIXTURE_MASS_KG = _KR500.calibration.fixture_mass_kg


def write_measurement(directory: Path, dut_mass_kg: float, fixture_mass_kg: float = FIXTURE_MASS_KG, seed: int = 1,
                      drive: Drive = Drive(), n_samples: int = 1500, period_s: float = 0.004, n_loops: int = 5,
                      storage: str = "BLOCK", factor: float = 1.0, robot: str = ROBOT,
                      lever_a3_m: float = 1.40) -> None:
    """A measurement directory of a DuT (plus fixture) whose CoG sits at ``lever_a3_m`` from A3."""
    rng = np.random.default_rng(seed)
    directory.mkdir(parents=True, exist_ok=True)
    m = dut_mass_kg + fixture_mass_kg
    names = []
    for j in range(n_loops):
        name = f"dut_l{j + 1:02d}"
        a3 = _loop(G * m * lever_a3_m, drive.gain_a3, drive.bias_a3_nm, drive.sign_a3, n_samples, period_s, drive,
                   rng)
        a5 = _loop(G * m * (lever_a3_m - DR), drive.gain_a5, drive.bias_a5_nm, drive.sign_a5, n_samples, period_s,
                   drive, rng)
        _write(directory, name, a3, a5, period_s, storage, factor)
        names.append(name)
    text = "\n".join(["[setup]", f'robot = "{robot}"', f"g = {G}", f"lever_difference_m = {DR}", "",
                      "[measurement]", f"fixture_mass_kg = {fixture_mass_kg!r}",
                      "traces = [" + ", ".join(f'"{n}"' for n in names) + "]", ""])
    (directory / "manifest.toml").write_text(text, encoding="utf-8")
