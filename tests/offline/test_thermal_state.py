"""The thermal state of a measurement: the drives' ``Motortemperatur`` channel read from real trace files, and the
warning when a measurement was taken at other motor temperatures than its calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rgse_daemon.analysis.mass import THERMAL_MISMATCH_K, thermal_mismatch
from rgse_daemon.errors import DataError
from rgse_daemon.manifest import read_loop, thermal_state_k
from simulators.krc4.tracefiles import write_trace_set

N = 200


def _write(directory: Path, name: str, temp_a3_k: np.ndarray | None, temp_a5_k: np.ndarray | None) -> None:
    modules: dict[str, dict[str, tuple[np.ndarray, str]]] = {}
    for module, temp, torque in (("NextGenDrive#3", temp_a3_k, 1400.0), ("NextGenDrive#5", temp_a5_k, 330.0)):
        channels = {"Istmoment": (np.full(N, torque) + np.sin(np.arange(N)), "Nm")}
        if temp is not None:
            channels["Motortemperatur"] = (temp, "K")
        modules[module] = channels
    write_trace_set(directory, name, 0.012, modules)


def test_mean_motor_temperatures_are_read_from_the_traces(tmp_path: Path) -> None:
    _write(tmp_path, "l01", np.linspace(330.0, 331.0, N), np.full(N, 329.5))
    _write(tmp_path, "l02", np.full(N, 332.0), np.full(N, 330.5))
    loops = [read_loop(tmp_path, "l01"), read_loop(tmp_path, "l02")]
    assert loops[0].motor_temp_a3_k == pytest.approx(330.5) and loops[0].motor_temp_a5_k == pytest.approx(329.5)
    state = thermal_state_k(loops)
    assert state == pytest.approx({"A3": 331.25, "A5": 330.0})


def test_traces_without_the_channel_have_no_thermal_state(tmp_path: Path) -> None:
    _write(tmp_path, "l01", None, None)
    _write(tmp_path, "l02", np.full(N, 332.0), np.full(N, 330.5))
    loops = [read_loop(tmp_path, "l01"), read_loop(tmp_path, "l02")]
    assert loops[0].motor_temp_a3_k is None
    assert thermal_state_k(loops) is None and thermal_state_k([]) is None


@pytest.mark.parametrize("bad", [np.full(N, -5.0), np.full(N, 20.0), np.full(N, 900.0)])
def test_implausible_temperatures_name_the_file(tmp_path: Path, bad: np.ndarray) -> None:
    _write(tmp_path, "l01", np.full(N, 330.0), bad)
    with pytest.raises(DataError, match=r"l01_NextGenDrive#5\.dat.*Motortemperatur"):
        read_loop(tmp_path, "l01")


def test_mismatch_warning_names_the_axes_beyond_the_limit() -> None:
    cal = {"A3": 333.0, "A5": 333.0}
    assert thermal_mismatch({"A3": 333.0 + THERMAL_MISMATCH_K, "A5": 333.0 - THERMAL_MISMATCH_K}, cal) is None
    w = thermal_mismatch({"A3": 333.0 - 12.5, "A5": 334.0}, cal)
    assert w is not None and "A3 -12.5 K" in w and "A5" not in w and "warm up" in w
    # a calibration or a measurement without a thermal record: nothing to compare
    assert thermal_mismatch(None, cal) is None
    assert thermal_mismatch({"A3": 300.0, "A5": 300.0}, None) is None
