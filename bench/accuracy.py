"""Accuracy of the in-line mass over seeds and scenarios: one table (issue #18).

Each repetition is a whole story on the simulated KR 500 (``simulators.krc4.physics``, default scenario: Table 1's
gains, thermal drift, settling, noise, spikes, per-mounting offsets): a Table-1-like campaign (every point a new
mounting), the calibration, one DuT of random mass (20-230 kg) on the fixture, a new mounting, its loops. The same
code path as ``rgse calibrate --campaign`` / ``rgse mass`` after reading the trace files (offline, no socket).

Scenarios: ``12ms`` (the paper's trace rate, DuT near the mass-stack pose), ``4ms`` (the same at 4 ms), ``lever``
(DuT CoG out to the torque points' levers), ``lever-6tp`` (the same DuTs after a campaign with six torque rows,
:data:`TORQUE_ROWS_6`, instead of three), ``no-mount`` and ``lever-no-mount`` (no per-mounting scatter: what
is left is each model's form error at the DuT, and the loops), ``warm`` (DuT measured after
15 min of holding: a thermal mismatch with the campaign, corrected with the campaign's drift), ``robots`` (a
new robot per repetition: A3's and A5's drive gain curves drawn from :data:`ROBOT_FAMILY`, DuT anywhere from the
mass-stack pose out to the torque points' levers: what carries over to robots Table 1 never saw). Rows: ``paper``
(eq. 19/20), ``auto`` (what ``--method auto`` chooses: the average of the best per-axis gain models) and the best
single catalogue model of the scenario. Columns: mean |err| %, the signed mean error (kg) with its standard error
over the seeds (a bias shows here; with per-mounting scatter each seed's DuT carries its own mounting's offset, one
draw that no loop averages, so the mean wanders by about ±0.1-0.2 kg at 120 seeds), max |err| kg, coverage of ±U
(k = 2) with its Clopper-Pearson 95 % interval, mean U kg, refused (far outside the envelope), and the loop-and-mount
noise floor. A last row per scenario, ``true form`` (simulation only), fits each axis by least squares in a basis that
holds the simulated robot's own reading curve exactly (:func:`true_form_mass_kg`): no form error, only the campaign's
scatter. It is what these campaigns allow a method that knew the drive's shape; it has no U, and its ``refused``
counts the DuTs `auto` refused plus those whose reading its fitted curve never reaches.

Goals: mean |err| ≤ 0.3 % without per-mount scatter; ≤ 1.2 × the noise floor with it; coverage 90-99 %.

Issue 33's rows (``--issue33 [NAME]``, :data:`ISSUE33`; docs/accuracy.md): a knock during the DuT's loops,
missing samples (DIAdem's no value) in each channel of the campaign and of the DuT through real trace files,
thermal drift (β = 0 and the simulator's) on campaigns spanning 0.2-4.6 K with and without the correction, and DuTs
in the gap between the mass stack and the torque rows; each row counts the refusals and the loops set aside by
reason. The rows on one in-memory campaign share its fit per seed (``_FITS``); ``--runs-out FILE`` keeps every story,
so that chunks of seeds (``--first-seed``) can be summarised together.

Run: ``.venv/bin/python bench/accuracy.py [--seeds N] [--first-seed S] [--workers 1|2] [--json]`` (120 seeds from
0 by default, 11 min on 2 cores: at 40 the |err|/floor ratio wanders by about ±0.1; coverage with its Clopper-Pearson
95 % interval; ``--first-seed`` checks a figure on seeds the table did not use).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import optimize, stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' simulated campaigns

from rgse_daemon.analysis.calibration import CampaignData, campaign_points, campaign_thermal
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import inline, selection
from rgse_daemon.pipeline import preprocess as pp
from rgse_daemon.pipeline import uncertainty as unc
from rgse_daemon.pipeline.envelope import Envelope, OperatingPointError
from simulators.krc4.scenario import default_scenario
from tests.support.simcampaign import G, simulate_campaign, simulate_measurement

#: The ``lever-6tp`` campaign's torque rows (n_cb, CB lever to A5 in m): Table 1's three with ten bodies, one more
#: further out, and two with five bodies that fill the A5 torques between the mass stack (840 Nm) and them (1.8 kNm).
TORQUE_ROWS_6 = ((5, 0.761), (5, 1.261), (10, 0.761), (10, 1.011), (10, 1.261), (10, 1.45))
SINGLE = ("axis-linear", "axis-quad", "axis-log", "ratio-linear")
SCENARIOS = {
    "12ms": {"period_s": 0.012, "n_samples": 250, "cog": (0.05, 0.35)},
    "4ms": {"period_s": 0.004, "n_samples": 750, "cog": (0.05, 0.35)},
    "lever": {"period_s": 0.012, "n_samples": 250, "cog": (0.35, 0.95)},
    "no-mount": {"period_s": 0.012, "n_samples": 250, "cog": (0.05, 0.35), "no_mount": True},
    "lever-no-mount": {"period_s": 0.012, "n_samples": 250, "cog": (0.35, 0.95), "no_mount": True},
    "lever-6tp": {"period_s": 0.012, "n_samples": 250, "cog": (0.35, 0.95), "torque_rows": TORQUE_ROWS_6},
    "robots": {"period_s": 0.012, "n_samples": 250, "cog": (0.05, 0.95), "robots": True},
    "warm": {"period_s": 0.012, "n_samples": 250, "cog": (0.05, 0.35), "warm_s": 900.0},
}


#: The ``robots`` scenario's family of drive gain curves (measured/true torque, ``AxisErrors``): each repetition draws
#: A3's and A5's G(x) = gain0 + gain_sat·(1 − exp(−x/tau_sat_nm)) + slope·x/1000 + quad·(x/1000)² uniformly from
#: these ranges (log-uniform tau): robots that Table 1 never saw, with gains from 15 % low to 15 % high, a saturating
#: term of either sign at any torque scale from 100 Nm to 3 kNm, and a tilt and a bend over the 5 kNm range.
ROBOT_FAMILY = {"gain0": (0.85, 1.15), "gain_sat": (-0.25, 0.25), "tau_sat_nm": (100.0, 3000.0),
                "gain_slope_per_knm": (-0.03, 0.03), "gain_quad_per_knm2": (-0.005, 0.005)}


def robot_axis(axis, rng: np.random.Generator):
    """``axis`` with its drive gain curve drawn from :data:`ROBOT_FAMILY` (tau log-uniform, the rest uniform)."""
    return axis.model_copy(update={k: float(np.exp(rng.uniform(*np.log(r))) if k == "tau_sat_nm" else rng.uniform(*r))
                                   for k, r in ROBOT_FAMILY.items()})


def _scenario(spec: dict, seed: int = 0):
    sc = default_scenario()
    if spec.get("robots"):
        rng = np.random.default_rng(70_000 + seed)
        sc = sc.model_copy(update={"axes": {**sc.axes, **{k: robot_axis(sc.axis(int(k[1])), rng)
                                                           for k in ("A3", "A5")}}})
    if not spec.get("no_mount", False):
        return sc
    axes = {k: a.model_copy(update={"mount_offset_nm": 0.0}) for k, a in sc.axes.items()}
    return sc.model_copy(update={"axes": axes, "mounting": sc.mounting.model_copy(update={"cog_shift_m": 0.0})})


def _true_basis(torque_nm: np.ndarray, axis) -> np.ndarray:
    """The fewest columns that span the simulated axis' bias-normalised reading f(x) = F(x + x0) − F(x0) exactly,
    for F(x) = x·G(x), G = gain0 + gain_sat·(1 − e^(−x/τ)) + slope·x + quad·x² (``AxisErrors``) and any MPA torque
    x0: x; x² with a slope or bend; x³ with a bend; 1 − e^(−x/τ) and x·e^(−x/τ) with a saturating term (f(0) = 0
    leaves out the constant)."""
    x = np.abs(np.asarray(torque_nm, float)) / 1000.0
    cols = [x]
    if axis.gain_slope_per_knm != 0.0 or axis.gain_quad_per_knm2 != 0.0:
        cols.append(x**2)
    if axis.gain_quad_per_knm2 != 0.0:
        cols.append(x**3)
    if axis.gain_sat != 0.0:
        tau = axis.tau_sat_nm / 1000.0
        cols += [-np.expm1(-x / tau), x * np.exp(-x / tau)]
    return np.stack(cols, axis=-1)


def _invert(axis, coef: np.ndarray, reading_nm: float, top_nm: float) -> float:
    """The smallest torque (0 to ``top_nm``) whose fitted reading is ``reading_nm``; NaN if the curve never gets
    there (a fit that bends over below the DuT's torque)."""

    def miss(torque_nm: float) -> float:
        return float(_true_basis(np.array([torque_nm]), axis)[0] @ coef) - reading_nm

    grid = np.linspace(0.0, top_nm, 2001)
    above = np.flatnonzero(_true_basis(grid, axis) @ coef >= reading_nm)
    if above.size == 0 or above[0] == 0:
        return float("nan")
    return float(optimize.brentq(miss, grid[above[0] - 1], grid[above[0]]))


def true_form_mass_kg(points, sc, torque_a3_nm: float, torque_a5_nm: float, lever_difference_m: float,
                      fixture_mass_kg: float) -> float:
    """Simulation only: the DuT mass a calibration without form error would give on these points (eq. 21). Per axis
    the reading is least-squares fitted as a function of the expected torque in :func:`_true_basis` (the classical
    calibration curve: the reference is exact, the reading carries the noise), then inverted at the DuT's reading."""
    corrected = []
    for axis, torque, expected, dut in ((sc.axis(3), points.torque_a3_nm, points.expected_a3_nm, torque_a3_nm),
                                        (sc.axis(5), points.torque_a5_nm, points.expected_a5_nm, torque_a5_nm)):
        coef, *_ = np.linalg.lstsq(_true_basis(expected, axis), np.abs(torque), rcond=None)
        corrected.append(_invert(axis, coef, abs(dut), 3.0 * float(np.max(np.abs(expected)))))
    return (corrected[0] - corrected[1]) / (G * lever_difference_m) - fixture_mass_kg


def repetition(name: str, seed: int) -> dict:
    spec = SCENARIOS[name]
    sc = _scenario(spec, seed)
    camp, model = simulate_campaign(seed, period_s=spec["period_s"], n_samples=spec["n_samples"], scenario=sc,
                                    torque_rows=spec.get("torque_rows"))
    dr = camp.manifest.setup.lever_difference_m
    data = CampaignData(camp.manifest, [[(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point]
                                        for point in camp.loops], [],
                        loop_temps_k=[[(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in point]
                                      for point in camp.loops])
    points, bias3, bias5 = campaign_points(data, pp.PAPER)
    evaluations = selection.evaluate_all(points, G, dr)
    chosen = selection.choose_auto(points, evaluations)
    by = {e.method: e for e in [*evaluations, chosen]}
    rng = np.random.default_rng(900 + seed)
    dut_kg, cog = float(rng.uniform(20.0, 230.0)), float(rng.uniform(*spec["cog"]))
    meas = simulate_measurement(model, dut_kg, cog, period_s=spec["period_s"], n_samples=spec["n_samples"],
                                warm_s=spec.get("warm_s", 0.0))
    loops = [(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in meas.loops]
    temps = [(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in meas.loops]
    drift = campaign_thermal(data, pp.PAPER)
    env = Envelope.from_torques(points.torque_a3_nm, points.torque_a5_nm)
    cache: dict[str, tuple] = {}

    def model_of(method: str):
        if method not in cache:
            cache[method] = (cal_mod.fit(points, method, G, dr),
                             unc.calibration_uncertainty(points, method, G, dr, by[method].heldout_residual_nm))
        return cache[method]

    limit = unc.PLAUSIBLE_LOO_FACTOR * chosen.loo_mean_abs_err_pct
    alts = [e.method for e in evaluations if e.method != chosen.method and e.admissible
            and e.loo_mean_abs_err_pct <= limit]
    out = {"dut_kg": dut_kg}
    for row, method, alternatives in (("paper", "paper", []), ("auto", chosen.method, alts),
                                      *((m, m, []) for m in SINGLE)):
        cal, cu = model_of(method)
        try:
            r = inline.in_line_mass(loops, inline.MassCalibration(
                cal, bias3, bias5, alternatives=[model_of(a)[0] for a in alternatives], uncertainty=cu,
                alternative_uncertainty=[model_of(a)[1] for a in alternatives], envelope=env, thermal=drift),
                pp.PAPER, fixture_mass_kg=meas.fixture_mass_kg, loop_temps_k=temps)
        except OperatingPointError:
            out[row] = None
            continue
        out[row] = {"err_kg": r.mass_kg - dut_kg, "U_kg": r.uncertainty.expanded_kg,
                    "u_loops_kg": r.uncertainty.u_loops_kg, "u_components_kg": r.uncertainty.components(),
                    "method": r.method}
        if row == "auto":  # the DuT's corrected operating point, where the true form is read too
            out["true form"] = {"err_kg": true_form_mass_kg(points, sc, r.torque_a3_nm, r.torque_a5_nm, dr,
                                                            meas.fixture_mass_kg) - dut_kg}
    return out


# ------------------------------------------------------------------------------------------------------------
# issue 33: every result right within its U, or flagged, set aside or refused
# ------------------------------------------------------------------------------------------------------------
#: The thermal rows' campaigns (simulate_campaign keywords) by the temperature span β rests on: a warmed-up campaign
#: with quick body changes (0.2 K, 0.7 K within a point), the default (3 K), long body changes and loops (4.6 K).
SPANS = {"0.2K": {"warm_s": 3600.0, "change_s": 5.0, "loop_s": 40.0},
         "0.7K": {"warm_s": 3600.0, "change_s": 20.0, "loop_s": 40.0},
         "3K": {}, "4.6K": {"change_s": 900.0, "loop_s": 60.0}}
ISSUE33 = {
    "clean": {"n_loops": 5},
    "bump": {"knock": True, "n_loops": 5},
    **{f"novalue-dut-{ch}": {"gap": ("dut", ch)} for ch in ("A3", "A5", "T")},
    **{f"novalue-cal-{ch}": {"gap": ("cal", ch)} for ch in ("A3", "A5", "T")},
    **{f"thermal-{span}{tag}": {"campaign": kw, "beta0": beta0, "dut_warm_s": 300.0}
       for span, kw in SPANS.items() for tag, beta0 in (("", False), ("-beta0", True))},
    **{f"thermal-{span}-near{tag}": {"campaign": SPANS[span], "beta0": beta0, "dut_warm_s": 45.0}
       for span in ("3K", "4.6K") for tag, beta0 in (("", False), ("-beta0", True))},
    "stack-row-gap": {"dut_kg": (150.0, 200.0), "cog": (0.6, 0.8)},
}


def _beta0(sc):
    """The scenario with torques that do not depend on motor temperature at all (β = 0 on every axis)."""
    return sc.model_copy(update={"axes": {k: a.model_copy(update={"thermal_coeff_per_k": 0.0})
                                          for k, a in sc.axes.items()}})


def _through_files(camp, meas, gap, rng, root: Path):
    """Write the campaign and the DuT as KUKA trace files with a gap of missing samples (DIAdem's no value) in one
    loop's channel ``gap = (where, channel)`` (A3/A5 torque or both motor temperatures), read them back."""
    from rgse_daemon.analysis.calibration import load_campaign
    from rgse_daemon.manifest import load_manifest, read_loops
    from tests.support.simcampaign import with_gap, write_dirs

    where, channel = gap
    pool = [lp for point in camp.loops for lp in point] if where == "cal" else meas.loops
    victim = pool[int(rng.integers(len(pool)))]
    start, length = float(rng.uniform(0.0, 0.4)), float(rng.uniform(0.05, 0.6))
    n = victim.torque_a3_nm.size
    tgaps = {}
    if channel == "T":
        tgaps[victim.trace] = slice(int(start * n), int(start * n) + max(int(length * n), 1))
    else:
        gapped = with_gap(victim, channel, start, length)
        loops = [[gapped if lp is victim else lp for lp in point] for point in camp.loops]
        camp = type(camp)(camp.manifest, loops, camp.body_masses_kg)
        meas = type(meas)([gapped if lp is victim else lp for lp in meas.loops], meas.true_dut_mass_kg,
                          meas.fixture_mass_kg)
    write_dirs(camp, meas, root / "cal", root / "dut", tgaps)
    data = load_campaign(root / "cal")
    man = load_manifest(root / "dut")
    return data, read_loops(root / "dut", man.measurement_traces), f"{victim.trace} {channel} {length:.0%}"


#: The in-memory campaigns' fits of this process, by (scenario, seed): the rows that share a campaign (``clean``,
#: ``bump``, ``stack-row-gap``, ``thermal-3K`` and ``-near`` on the default one; the other spans with their ``-near``)
#: fit it once per seed. Each use gets its own copy of the robot model after the campaign (its state and noise).
_FITS: dict[tuple, tuple] = {}


def _campaign_fit(seed: int, beta0: bool, campaign: dict, data=None, camp=None, model=None) -> tuple:
    """The campaign of ``seed`` (screened like ``rgse calibrate``), ``auto`` and everything the DuT's mass needs; from
    ``data`` (read back from trace files) if given, else simulated in memory and cached. Raises DataError if the
    campaign is refused."""
    import copy
    import pickle

    from rgse_daemon.analysis.calibration import screen_campaign

    key = (seed, beta0, tuple(sorted(campaign.items())))
    if data is None and key in _FITS:
        blob, fitted = _FITS[key]
        camp, model = pickle.loads(blob)
        return (camp, model, *fitted)
    if camp is None:
        sc = _beta0(default_scenario()) if beta0 else default_scenario()
        camp, model = simulate_campaign(seed, scenario=sc, **campaign)
    blob = pickle.dumps((camp, model)) if data is None else None
    if data is None:
        data = CampaignData(camp.manifest, [[(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point]
                                            for point in camp.loops], [],
                            loop_temps_k=[[(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in point]
                                          for point in camp.loops])
    data = screen_campaign(data, pp.PAPER)
    dr = camp.manifest.setup.lever_difference_m
    points, bias3, bias5 = campaign_points(data, pp.PAPER)
    evaluations = selection.evaluate_all(points, G, dr)
    chosen = selection.choose_auto(points, evaluations)
    by = {e.method: e for e in [*evaluations, chosen]}
    limit = unc.PLAUSIBLE_LOO_FACTOR * chosen.loo_mean_abs_err_pct
    alts = [e.method for e in evaluations if e.method != chosen.method and e.admissible
            and e.loo_mean_abs_err_pct <= limit]
    fits = {m: (cal_mod.fit(points, m, G, dr), unc.calibration_uncertainty(points, m, G, dr,
                                                                           by[m].heldout_residual_nm))
            for m in [chosen.method, *alts]}
    drift = campaign_thermal(data, pp.PAPER)
    env = Envelope.from_torques(points.torque_a3_nm, points.torque_a5_nm)
    extrapolation = inline.extrapolation_slope_kg(env, by[chosen.method].heldout_residual_nm, G, dr)
    set_aside = [f"point {p} loop {a.loop}: {a.reason}" for p, a in data.set_aside]
    fitted = (set_aside, chosen.method, alts, fits, bias3, bias5, drift, env, extrapolation)
    if blob is not None:
        _FITS[key] = (blob, fitted)
        camp, model = pickle.loads(blob)
    return (camp, copy.deepcopy(model) if blob is None else model, *fitted)


def repetition33(name: str, seed: int) -> dict:
    """One story of an issue-33 row: the campaign (screened like ``rgse calibrate``), ``auto``, one DuT; the result,
    or the refusal's reason, and the loops set aside."""
    import tempfile

    from rgse_daemon.errors import DataError
    from tests.support.simcampaign import Knock

    spec = ISSUE33[name]
    beta0, campaign = bool(spec.get("beta0")), spec.get("campaign", {})
    try:
        camp, model, *fitted = _campaign_fit(seed, beta0, campaign) if "gap" not in spec else (None, None)
    except DataError as exc:
        return {"dut_kg": float("nan"), "auto": None, "auto refused": f"campaign: {exc}"}
    if camp is None:  # through trace files: simulated here, fitted from what is read back
        sc = _beta0(default_scenario()) if beta0 else default_scenario()
        camp, model = simulate_campaign(seed, scenario=sc, **campaign)
    rng = np.random.default_rng(3300 + seed)
    dut_kg, cog = float(rng.uniform(*spec.get("dut_kg", (20.0, 230.0)))), float(rng.uniform(*spec.get("cog",
                                                                                                       (0.05, 0.35))))
    knock = None
    if spec.get("knock"):
        knock = Knock(int(rng.integers(spec["n_loops"])), float(rng.uniform(0.2, 0.8)),
                      float(rng.choice([-1, 1]) * rng.uniform(10.0, 40.0)),
                      float(rng.choice([-1, 1]) * rng.uniform(10.0, 40.0)))
    meas = simulate_measurement(model, dut_kg, cog, n_loops=spec.get("n_loops", 3), knock=knock,
                                warm_s=spec.get("dut_warm_s", 0.0))
    out: dict = {"dut_kg": dut_kg}
    if "gap" in spec:
        with tempfile.TemporaryDirectory() as tmp:
            data, dut_loops, out["gap"] = _through_files(camp, meas, spec["gap"], rng, Path(tmp))
        try:
            _, _, *fitted = _campaign_fit(seed, beta0, campaign, data=data, camp=camp, model=model)
        except DataError as exc:
            return {**out, "auto": None, "auto refused": f"campaign: {exc}"}
    else:
        dut_loops = meas.loops
    set_aside, chosen, alts, fits, bias3, bias5, drift, env, extrapolation = fitted
    out["cal set aside"] = set_aside
    loops = [(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in dut_loops]
    temps = [(lp.motor_temp_a3_k, lp.motor_temp_a5_k) for lp in dut_loops]
    if drift is not None and temps[0][0] is not None:
        out["dut_offset_k"] = float(np.mean([t[1] for t in temps]) - drift.reference_k["A5"])
        out["beta_a5"] = (drift.coeff_per_k["A5"], drift.u_coeff_per_k["A5"], drift.span_k["A5"])
    rows = [("auto", drift)] + ([("auto, no β", None)] if name.startswith("thermal") else [])
    for row, thermal in rows:
        try:
            r = inline.in_line_mass(loops, inline.MassCalibration(
                fits[chosen][0], bias3, bias5, alternatives=[fits[a][0] for a in alts],
                uncertainty=fits[chosen][1], alternative_uncertainty=[fits[a][1] for a in alts], envelope=env,
                thermal=thermal, extrapolation_kg=extrapolation), pp.PAPER, fixture_mass_kg=meas.fixture_mass_kg,
                loop_temps_k=temps)
        except DataError as exc:
            out[row], out[f"{row} refused"] = None, str(exc)
            continue
        out[row] = {"err_kg": r.mass_kg - dut_kg, "U_kg": r.uncertainty.expanded_kg,
                    "u_loops_kg": r.uncertainty.u_loops_kg, "set_aside": [f"{a.loop}: {a.reason}"
                                                                          for a in r.loops_set_aside],
                    "outside": r.operating_point == "outside", "thermal_applied": r.thermal_applied}
    return out


def _run33(job: tuple[str, int]) -> dict:
    return repetition33(*job)


def _reason(text: str) -> str:
    """The kind of a refusal or set-aside, for the table."""
    for key in ("samples missing", "a step of", "after the step", "disagrees", "far outside", "below zero"):
        if key in text:
            return key
    return text[:40]


def summarise33(runs: list[dict], row: str) -> dict:
    s = summarise(runs, row, 0.0)
    refusals = [_reason(r[f"{row} refused"]) for r in runs if r.get(row) is None and f"{row} refused" in r]
    aside = [_reason(a) for r in runs if r.get(row) is not None for a in r[row]["set_aside"]]
    aside += [_reason(a) for r in runs for a in r.get("cal set aside", [])]
    ok = [r[row] for r in runs if r.get(row) is not None]
    s.update({"refusals": {k: refusals.count(k) for k in sorted(set(refusals))},
              "set_aside": {k: aside.count(k) for k in sorted(set(aside))},
              "outside": int(sum(o["outside"] for o in ok)),
              "thermal_applied": int(sum(any(o["thermal_applied"].values()) for o in ok)),
              "dut_offset_k": float(np.mean([r["dut_offset_k"] for r in runs if "dut_offset_k" in r] or [np.nan])),
              "beta_a5_z": float(np.median([abs(r["beta_a5"][0]) / r["beta_a5"][1] for r in runs if "beta_a5" in r]
                                           or [np.nan]))})
    return s


def main33(seeds: int, first: int, workers: int, names: list[str], as_json: bool, runs_out: Path | None = None
           ) -> int:
    t0 = time.monotonic()
    jobs = [(name, seed) for seed in range(first, first + seeds) for name in names]  # a seed's rows together
    with ProcessPoolExecutor(workers) as pool:
        done = list(pool.map(_run33, jobs, chunksize=len(names)))
    table = {}
    for name in names:
        runs = [r for (n, _), r in zip(jobs, done, strict=True) if n == name]
        table[name] = {row: summarise33(runs, row) for row in ("auto", "auto, no β") if row in runs[0]}
    if runs_out is not None:  # every story, so that chunks of seeds can be summarised together (merge33)
        runs_out.write_text(json.dumps({"first_seed": first, "seeds": seeds, "seconds": time.monotonic() - t0,
                                        "runs": {n: [r for (m, _), r in zip(jobs, done, strict=True) if m == n]
                                                 for n in names}}))
    if as_json:
        print(json.dumps({"bench": "accuracy-issue33", "seeds": seeds, "first_seed": first, "table": table,
                          "seconds": round(time.monotonic() - t0, 1)}))
        return 0
    print("| scenario | row | n | mean \\|err\\| % | mean err ± s.e. kg | max \\|err\\| kg | coverage ±U (95 % CI) "
          "| mean U kg | refused (why) | loops set aside (why) | outside | β applied | DuT ΔT K | \\|β_A5\\|/u |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- | ---: | ---: | ---: | ---: |")
    for name, rows in table.items():
        for row, s in rows.items():
            lo, hi = s["coverage_ci95"]
            why = ", ".join(f"{k} {v}" for k, v in s["refusals"].items())
            aside = ", ".join(f"{k} {v}" for k, v in s["set_aside"].items())
            print(f"| {name} | {row} | {s['n']} | {s['mean_abs_err_pct']:.2f} | {s['mean_err_kg']:+.2f} ± "
                  f"{s['sem_err_kg']:.2f} | {s['max_abs_err_kg']:.2f} | {100 * s['coverage']:.0f} % "
                  f"({100 * lo:.0f}–{100 * hi:.0f}) | {s['mean_U_kg']:.2f} | {s['refused']}{f' ({why})' if why else ''}"
                  f" | {aside or '0'} | {s['outside']} | {s['thermal_applied']} | {s['dut_offset_k']:+.1f} | "
                  f"{s['beta_a5_z']:.1f} |")
    print(f"{seeds} seeds per scenario (from {first}), {time.monotonic() - t0:.0f} s")
    return 0


def coverage_interval(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a coverage of k in n (``scipy.stats.binomtest``)."""
    if n == 0:
        return (float("nan"), float("nan"))
    ci = stats.binomtest(k, n).proportion_ci(0.95, method="exact")
    return (float(ci.low), float(ci.high))


def _run(job: tuple[str, int]) -> dict:
    return repetition(*job)


def summarise(runs: list[dict], row: str, mount_sigma_kg: float) -> dict:
    ok = [(r[row], r["dut_kg"]) for r in runs if r.get(row) is not None and np.isfinite(r[row]["err_kg"])]
    err = np.array([o["err_kg"] for o, _ in ok])
    pct = np.array([abs(o["err_kg"]) / m * 100 for o, m in ok])
    big_u = np.array([o.get("U_kg", np.nan) for o, _ in ok])  # the true-form row has no U
    loops = np.array([o["u_loops_kg"] for o, _ in ok if "u_loops_kg" in o]
                     or [r["auto"]["u_loops_kg"] for r in runs if r.get("auto") is not None])  # true form: auto's
    floor = float(np.sqrt(2 / np.pi) * np.sqrt(mount_sigma_kg**2 + np.mean(loops**2))) if len(loops) else float("nan")
    return {"n": len(ok), "refused": len(runs) - len(ok),
            "mean_abs_err_pct": float(pct.mean()) if ok else float("nan"),
            "mean_abs_err_kg": float(np.abs(err).mean()) if ok else float("nan"),
            "mean_err_kg": float(err.mean()) if ok else float("nan"),
            "sem_err_kg": float(err.std(ddof=1) / np.sqrt(len(err))) if len(ok) > 1 else float("nan"),
            "max_abs_err_kg": float(np.abs(err).max()) if ok else float("nan"),
            "coverage": float(np.mean(np.abs(err) <= big_u)) if ok else float("nan"),
            "coverage_ci95": coverage_interval(int(np.sum(np.abs(err) <= big_u)), len(ok)),
            "mean_U_kg": float(big_u.mean()) if ok else float("nan"), "noise_floor_kg": floor}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=120, help="repetitions per scenario")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="seed of the first repetition (fresh seeds check a figure without re-using the table's)")
    ap.add_argument("--workers", type=int, default=2, choices=(1, 2), help="processes (at most 2 on this machine)")
    ap.add_argument("--scenario", action="append", choices=sorted(SCENARIOS))
    ap.add_argument("--issue33", action="append", nargs="?", const="all", choices=["all", *ISSUE33],
                    help="the rows of issue 33 (bump, missing samples, thermal spans, the stack/row gap) instead")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--runs-out", type=Path, help="with --issue33: also write every story to this JSON file")
    args = ap.parse_args(argv)
    if args.issue33:
        names = list(ISSUE33) if "all" in args.issue33 else args.issue33
        return main33(args.seeds, args.first_seed, args.workers, names, args.json, args.runs_out)
    t0 = time.monotonic()
    table = {}
    names = args.scenario or list(SCENARIOS)
    jobs = [(name, seed) for name in names for seed in range(args.first_seed, args.first_seed + args.seeds)]
    with ProcessPoolExecutor(args.workers) as pool:
        done = list(pool.map(_run, jobs, chunksize=4))
    for name in names:
        runs = [r for (n, _), r in zip(jobs, done, strict=True) if n == name]
        sc = _scenario(SCENARIOS[name])
        mount_sigma_kg = float(np.hypot(sc.axis(3).mount_offset_nm, sc.axis(5).mount_offset_nm) / (G * 1.025))
        rows = {row: summarise(runs, row, mount_sigma_kg) for row in ("paper", "auto", *SINGLE, "true form")}
        best = min(SINGLE, key=lambda m: rows[m]["mean_abs_err_pct"])
        table[name] = {"paper": rows["paper"], "auto": rows["auto"], f"best single ({best})": rows[best],
                       "true form": rows["true form"]}
    if args.json:
        print(json.dumps({"bench": "accuracy", "seeds": args.seeds, "first_seed": args.first_seed, "table": table,
                          "seconds": round(time.monotonic() - t0, 1)}))
        return 0
    print("| scenario | row | n | mean \\|err\\| % | mean err ± s.e. kg | max \\|err\\| kg | coverage ±U (95 % CI) "
          "| mean U kg | refused | floor kg | \\|err\\|/floor |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, rows in table.items():
        for row, s in rows.items():
            lo, hi = s["coverage_ci95"]
            has_u = np.isfinite(s["mean_U_kg"])
            cover = f"{100 * s['coverage']:.0f} % ({100 * lo:.0f}–{100 * hi:.0f})" if has_u else "—"
            mean_u = f"{s['mean_U_kg']:.2f}" if has_u else "—"
            print(f"| {name} | {row} | {s['n']} | {s['mean_abs_err_pct']:.2f} | "
                  f"{s['mean_err_kg']:+.2f} ± {s['sem_err_kg']:.2f} | {s['max_abs_err_kg']:.2f} | "
                  f"{cover} | {mean_u} | "
                  f"{s['refused']} | {s['noise_floor_kg']:.2f} | {s['mean_abs_err_kg'] / s['noise_floor_kg']:.2f} |")
    print(f"{args.seeds} seeds per scenario (from {args.first_seed}), {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
