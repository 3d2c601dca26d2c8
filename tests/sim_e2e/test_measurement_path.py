"""Acceptance: one in-line mass measurement loop on the simulated KR C4, driven over the link exactly as the daemon.

Put a KRL program (measurement pose, brake-release move, settling wait) and a trace configuration onto the
controller, run the program, record a trace, pull the files, read them, and find A3's and A5's ``Istmoment`` where
the physics puts them, within the error terms the scenario configures.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rgse_daemon.controller import Controller
from rgse_daemon.kinematics import measurement_pose
from rgse_daemon.link.krlvalue import KrlStruct
from rgse_daemon.trace.diadem import read_trace_set
from simulators.krc4.physics import RobotModel, dut_payload
from simulators.krc4.scenario import default_scenario
from simulators.krc4.sim import SimulatedKrc4

from .conftest import (
    pull_trace,
    put_config,
    put_program,
    run_to_end,
    save,
    start_trace,
    states_until_end,
    trace_config_xml,
)

SETTLE_S = 5.0  # the program's wait after the brake-release move (simulated s)
TRACE_TIME_S = 12.0
RATE_US = 12000

MEAS_SRC = """&ACCESS RVP
DEF rgse_meas( )
  DECL INT i
  BAS(#INITMOV, 0)
  FOR i = 1 TO 6
    $VEL_AXIS[i] = 20
    $ACC_AXIS[i] = 20
  ENDFOR
  ; the measurement pose: forearm horizontal, A4 = 0, flange horizontal (paper Fig. 19)
  PTP {E6AXIS: A1 0.0, A2 -90.0, A3 90.0, A4 0.0, A5 0.0, A6 0.0, E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}
  ; brake-release move (paper 2.4.4): A3 and A5 the same angle away and back
  PTP_REL {A3 35.0, A5 35.0}
  PTP_REL {A3 -35.0, A5 -35.0}
  WAIT SEC rgse_settle_s
  rgse_at_pose = TRUE
END
"""
MEAS_DAT = f"""&ACCESS RVP
DEFDAT rgse_meas PUBLIC
  DECL GLOBAL REAL rgse_settle_s = {SETTLE_S}
  DECL GLOBAL BOOL rgse_at_pose = FALSE
ENDDAT
"""


def tolerance_nm(axis: int, static_nm: float, temps_k: np.ndarray, n_samples: int) -> float:
    """Largest deviation of a trace's mean Istmoment from the noise-free, cold, settled reading that the
    scenario's error terms allow (Nm): thermal drift at the hottest recorded temperature, release transient and
    settling after at least ``SETTLE_S``, hysteresis, and 5 σ of the mean of noise and spikes."""
    sc = default_scenario()
    ax = sc.axis(axis)
    thermal = abs(static_nm) * abs(ax.thermal_coeff_per_k) * max(0.0, float(temps_k.max()) - sc.thermal.ambient_k)
    release = abs(static_nm) * abs(ax.release_transient_frac) * math.exp(-SETTLE_S / sc.release.time_constant_s)
    settle = ax.settle_amplitude_nm * math.exp(-SETTLE_S / sc.settle.time_constant_s)
    noise = 5.0 * ax.noise_nm / math.sqrt(n_samples)
    spikes = 5.0 * sc.spikes.amplitude_nm * math.sqrt(max(sc.spikes.rate_per_sample * n_samples, 1.0)) / n_samples
    return thermal + release + settle + ax.hysteresis_nm + noise + spikes


async def test_measurement_loop_over_the_link(sim: SimulatedKrc4, krc: Controller, tmp_path: Path) -> None:
    payload = dut_payload(107.65, (0.0, 0.0, 0.30))
    sim.mount(payload)

    program = await put_program(krc, "RGSE_MEAS", MEAS_SRC, MEAS_DAT)
    await put_config(krc, "meas_12ms.xml", trace_config_xml(TRACE_TIME_S, rate_us=RATE_US))
    await run_to_end(krc, program)
    assert await krc.read("RGSE_AT_POSE") is True
    axes = await krc.read("$AXIS_ACT")
    assert isinstance(axes, KrlStruct)
    q_deg = np.array([float(axes[f"A{i}"]) for i in range(1, 7)])  # type: ignore[arg-type]
    np.testing.assert_allclose(q_deg, measurement_pose(), atol=1e-6)

    await start_trace(krc, "meas_12ms.xml", "dut_l01")
    seen = await states_until_end(krc)
    assert seen[-1] == "#T_END" and "#TRIGGERED" in seen

    files = await pull_trace(krc, "dut_l01")
    modules = ["KRCIpo", *(f"NextGenDrive#{i}" for i in range(1, 7))]
    assert set(files) == {f"dut_l01_{m}.{ext}" for m in modules for ext in ("dat", "r64", "trc")} | {"dut_l01_PROG.TXT"}
    assert files["dut_l01_PROG.TXT"].decode("latin-1").replace("\r\n", "\n") == MEAS_SRC
    ts = read_trace_set(save(files, tmp_path / "archive"), "dut_l01", modules=modules)

    truth = sim.truths["dut_l01"]
    np.testing.assert_allclose(truth.q_deg, q_deg)
    assert truth.payload_mass_kg == payload.mass_kg
    reference = RobotModel(default_scenario())  # an independent model of the same scenario: no shared state
    expected = reference.static_reading_nm(q_deg, payload)
    sc = default_scenario()
    for axis in (3, 5):
        module = f"NextGenDrive#{axis}"
        torque = ts.channel(module, "Istmoment").values
        temps = ts.channel(module, "Motortemperatur").values
        assert ts.files[module].period_s == RATE_US * 1e-6
        assert torque.size == round(TRACE_TIME_S / (RATE_US * 1e-6))
        # the files carry exactly the physics' samples ...
        np.testing.assert_allclose(torque, sum(truth.terms.values())[axis - 1], rtol=1e-12, atol=1e-9)
        ax = sc.axis(axis)
        np.testing.assert_allclose(
            ts.channel(module, "Iststrom").values, torque / (ax.torque_constant_nm_a * ax.gear_ratio), rtol=1e-12
        )
        # ... and their mean lies where the physics puts the reading, within the configured error terms
        tol = tolerance_nm(axis, expected[axis - 1], temps, torque.size)
        assert abs(torque.mean() - expected[axis - 1]) <= tol, (axis, torque.mean(), expected[axis - 1], tol)
        # the gain error is real and larger than that tolerance: the reading is not the true torque
        true_nm = truth.true_torque_nm[axis - 1] + truth.residual_nm[axis - 1]
        assert abs(torque.mean() - true_nm) > tol
