"""``rgse demo --robot kr10r1440`` (issue 32): the whole story on the paper's subscale bench, a simulated KR 10
R1440-2 with its own scenario (gain curves, roughness), its 10 kg-class calibration set and a 4.6 kg DuT: the
installed CLI, the simulator in its own process, the whole daemon. Mass and CoG must agree with the simulator's truth
within U."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: About a minute on a 2-core machine (the campaign's 16 points with the torsional ones), 11.4 min measured while
#: seven other test runs shared it; a hang guard, not a timing check.
DEMO_TIMEOUT_S = 900


@pytest.mark.slow(expected_s=66)
@pytest.mark.timeout(DEMO_TIMEOUT_S + 20)
def test_kr10_demo_agrees_with_truth_within_u() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "rgse_daemon.cli", "demo", "--robot", "kr10r1440", "--json"],
        capture_output=True, text=True, timeout=DEMO_TIMEOUT_S, check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout
    out = json.loads(lines[0])
    assert out["robot"] == "kr10r1440" and out["true_mass_kg"] == 4.6
    assert 3 <= out["loops"] <= 10 and out["stop_reason"] in ("loop term below share", "target U met", "max loops")
    err = out["mass_kg"] - out["true_mass_kg"]
    assert abs(err) <= out["U_kg"], f"measured {out['mass_kg']:.4f} ± {out['U_kg']:.4f} kg, true 4.6 kg"
    assert out["within_U"] is True
    # a real uncertainty of this arm's class: the KR 500 demo's bound, 5 % of the mass
    assert 0.0 < out["U_kg"] < 0.05 * out["true_mass_kg"]
    assert out["warnings"] == []
    # the CoG: the subscale box's, about 0.1 m in front of the flange (not the KR 500 wing box's 0.335 m)
    assert abs(out["true_cog_m"][2] - 0.097) < 0.01, out["true_cog_m"]
    assert all(u > 0 for u in out["U_cog_m"])
    assert out["cog_within_U"] is True, (out["cog_error_mm"], out["U_cog_m"])
    # the calibration fitted this robot's campaign (11 Table 1 points of 0.77 kg bodies)
    assert out["calibration"]["points"] == 11
