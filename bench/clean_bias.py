"""Where the ``clean`` row's bias comes from (issue 33: −0.63 ± 0.13 kg over 60 seeds in ``bench/accuracy.py
--issue33 clean``).

Two experiments on the simulated KR 500 (``simulators.krc4``), the code path of ``bench/accuracy.py``:

* ``sources``: the ``clean`` story with the simulator's error sources switched off one at a time (``--variants``),
  mean error ± s.e. over ``--seeds`` seeds and the error's regression on the DuT's mass; ``flip`` draws every
  mounting's reading offsets with the opposite sign, and the pair (default + flip)/2 is the part of the error that is
  even in the offsets; ``<variant>_paper`` uses the paper's method instead of ``auto``.
* ``offsets``: an ideal campaign (every error source off), then per-point reading offsets of Table 1's size
  (σ 7 Nm A3, 14 Nm A5) added to each point's loops with + and − signs; the mean of the two DuT errors less the
  error without offsets is the pipeline's even response to zero-mean offsets: on all points, on the zero point (the
  bias M_0) only, on the loaded points only.
* ``models``: each single model's DuT error beside auto's on the same stories (``--variants``, ``--seeds``; DuTs of
  50–200 kg with their CoG 0.25 m out, 3 loops), and which models auto's average held.

Run: ``.venv/bin/python bench/clean_bias.py sources --seeds 30 --variants default flip no_mount``
     ``.venv/bin/python bench/clean_bias.py offsets --seed 0 --method paper --draws 10``
     ``.venv/bin/python bench/clean_bias.py models --seeds 16 --variants default no_offset no_cogshift``
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy as acc

from rgse_daemon.analysis.calibration import CampaignData, campaign_points
from rgse_daemon.pipeline import calibration as cal_mod
from rgse_daemon.pipeline import inline, selection
from rgse_daemon.pipeline import preprocess as pp
from simulators.krc4 import physics as ph
from simulators.krc4.scenario import Scenario, default_scenario
from tests.support.simcampaign import G, simulate_campaign, simulate_measurement

VARIANTS = ("default", "no_thermal", "no_offset", "no_cogshift", "no_mount", "ideal", "flip")


def _axes(sc: Scenario, **kw: float) -> Scenario:
    return sc.model_copy(update={"axes": {k: a.model_copy(update=kw) for k, a in sc.axes.items()}})


def variant(name: str) -> Scenario:
    """The default scenario with the named error sources off (``ideal``: all of them)."""
    sc = default_scenario()
    off = {name} if name != "ideal" else {"no_thermal", "no_mount", "no_hyst", "no_release", "no_settle", "no_spikes",
                                          "exact_kin", "no_noise"}
    if "no_thermal" in off:
        sc = _axes(sc, thermal_coeff_per_k=0.0)
    if off & {"no_offset", "no_mount"}:
        sc = _axes(sc, mount_offset_nm=0.0)
    if off & {"no_cogshift", "no_mount"}:
        sc = sc.model_copy(update={"mounting": sc.mounting.model_copy(update={"cog_shift_m": 0.0})})
    if "no_hyst" in off:
        sc = _axes(sc, hysteresis_nm=0.0)
    if "no_release" in off:
        sc = _axes(sc, release_transient_frac=0.0)
    if "no_settle" in off:
        sc = _axes(sc, settle_amplitude_nm=0.0)
    if "no_noise" in off:
        sc = _axes(sc, noise_nm=0.0)
    if "no_spikes" in off:
        sc = sc.model_copy(update={"spikes": sc.spikes.model_copy(update={"rate_per_sample": 0.0})})
    if "exact_kin" in off:
        sc = sc.model_copy(update={"kinematics": sc.kinematics.model_copy(
            update={"length_sigma_m": 0.0, "twist_sigma_deg": 0.0, "zero_offset_sigma_deg": 0.0})})
    return sc


def _story(job: tuple[str, int]) -> tuple[str, int, float, float, float, str]:
    """One ``clean`` story of ``bench/accuracy.py`` in variant ``name``: (name, seed, DuT kg, error kg, U kg,
    method)."""
    name, seed = job
    base = name.removesuffix("_paper")
    if base == "flip":
        original = ph.RobotModel.new_mounting

        def flipped(self: ph.RobotModel) -> None:
            original(self)
            self.mount_offset_nm = -self.mount_offset_nm

        ph.RobotModel.new_mounting = flipped  # type: ignore[method-assign]  # this worker process only
    acc.default_scenario = lambda: variant("default" if base == "flip" else base)
    if name.endswith("_paper"):
        acc.selection.choose_auto = lambda points, evs: next(e for e in evs if e.method == "paper")
    acc._FITS.clear()
    r = acc.repetition33("clean", seed)
    a = r.get("auto")
    method = next(iter(acc._FITS.values()))[1][1] if acc._FITS else "?"
    return (name, seed, r["dut_kg"], a["err_kg"] if a else np.nan, a["U_kg"] if a else np.nan, method)


def sources(seeds: int, variants: list[str]) -> None:
    with ProcessPoolExecutor(2, max_tasks_per_child=1) as ex:  # a fresh process each story: the patches above
        res = list(ex.map(_story, [(v, s) for v in variants for s in range(seeds)]))
    err = {(n, s): e for n, s, _, e, _, _ in res}
    if "default" in variants and "flip" in variants:
        even = np.array([(err[("default", s)] + err[("flip", s)]) / 2 for s in range(seeds)])
        odd = np.array([(err[("default", s)] - err[("flip", s)]) / 2 for s in range(seeds)])
        print(f"even in the offsets {even.mean():+.3f} ± {even.std(ddof=1) / np.sqrt(seeds):.3f} kg, "
              f"odd {odd.mean():+.3f} ± {odd.std(ddof=1) / np.sqrt(seeds):.3f} kg")
    for v in variants:
        rows = [(m, e, u) for n, _, m, e, u, _ in res if n == v and np.isfinite(e)]
        m, e, u = (np.array(x) for x in zip(*rows, strict=True))
        coef, *_ = np.linalg.lstsq(np.vstack([np.ones_like(m), m / 100.0]).T, e, rcond=None)
        methods = Counter(c.split(":")[0] for n, *_, c in res if n == v)
        print(f"{v:16s} n={e.size} mean err {e.mean():+.3f} ± {e.std(ddof=1) / np.sqrt(e.size):.3f} kg; "
              f"err ≈ {coef[0]:+.3f} {coef[1]:+.3f}·m/100 kg; within ±U {np.mean(np.abs(e) <= u):.0%}, "
              f"mean U {u.mean():.2f} kg; methods {dict(methods)}")


def offsets(seed: int, method: str, draws: int) -> None:
    camp, model = simulate_campaign(seed, scenario=variant("ideal"))
    meas = simulate_measurement(model, 120.0, 0.2, n_loops=3)
    dr = camp.manifest.setup.lever_difference_m
    rng = np.random.default_rng(1)

    def error(off3: np.ndarray, off5: np.ndarray) -> float:
        loops = [[(lp.torque_a3_nm + off3[i], lp.torque_a5_nm + off5[i], lp.period_s) for lp in point]
                 for i, point in enumerate(camp.loops)]
        points, b3, b5 = campaign_points(CampaignData(camp.manifest, loops, []), pp.PAPER)
        m = selection.choose_auto(points, selection.evaluate_all(points, G, dr)).method if method == "auto" \
            else method
        r = inline.in_line_mass([(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in meas.loops],
                                inline.MassCalibration(cal_mod.fit(points, m, G, dr), b3, b5), pp.PAPER,
                                fixture_mass_kg=meas.fixture_mass_kg)
        return r.mass_kg - 120.0

    n = len(camp.loops)
    e0 = error(np.zeros(n), np.zeros(n))
    parts: dict[str, list[float]] = {"all points": [], "zero point only": [], "loaded points only": []}
    for _ in range(draws):
        d3, d5 = rng.normal(0.0, 7.0, n), rng.normal(0.0, 14.0, n)
        only0 = np.zeros(n), np.zeros(n)
        only0[0][0], only0[1][0] = d3[0], d5[0]
        loaded = d3.copy(), d5.copy()
        loaded[0][0] = loaded[1][0] = 0.0
        for part, (o3, o5) in (("all points", (d3, d5)), ("zero point only", only0), ("loaded points only", loaded)):
            parts[part].append((error(o3, o5) + error(-o3, -o5)) / 2.0 - e0)
    text = "; ".join(f"{k} {np.mean(v):+.3f} ± {np.std(v, ddof=1) / np.sqrt(len(v)):.3f}" for k, v in parts.items())
    print(f"seed {seed}, {method}, 120 kg DuT: error without offsets {e0:+.3f} kg; even part: {text} kg")


SINGLE_MODELS = ("axis-linear", "axis-quad", "axis-log", "axis-sat", "axis-sat-sat", "paper")


def models(seeds: int, variants: list[str]) -> None:
    for name in variants:
        errs: dict[str, list[float]] = {m: [] for m in (*SINGLE_MODELS, "auto")}
        members: Counter[str] = Counter()
        rng = np.random.default_rng(5)
        for seed in range(seeds):
            camp, model = simulate_campaign(seed, scenario=variant(name))
            m_true = float(rng.uniform(50.0, 200.0))
            meas = simulate_measurement(model, m_true, 0.25, n_loops=3)
            dr = camp.manifest.setup.lever_difference_m
            points, b3, b5 = campaign_points(CampaignData(camp.manifest, [
                [(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s) for lp in point] for point in camp.loops], []),
                pp.PAPER)
            chosen = selection.choose_auto(points, selection.evaluate_all(points, G, dr)).method
            members.update(chosen.split(":")[-1].split("+"))
            loops = [(lp.torque_a3_nm, lp.torque_a5_nm, lp.period_s, lp.trace) for lp in meas.loops]
            for m in errs:
                cal = inline.MassCalibration(cal_mod.fit(points, chosen if m == "auto" else m, G, dr), b3, b5)
                errs[m].append(inline.in_line_mass(loops, cal, pp.PAPER,
                                                   fixture_mass_kg=meas.fixture_mass_kg).mass_kg - m_true)
        print(f"== {name}: {seeds} seeds; auto's members {dict(members.most_common())}")
        for m, e in errs.items():
            a = np.array(e)
            print(f"  {m:14s} mean err {a.mean():+.3f} ± {a.std(ddof=1) / np.sqrt(a.size):.3f} kg, "
                  f"mean |err| {np.abs(a).mean():.3f} kg")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("experiment", choices=("sources", "offsets", "models"))
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--variants", nargs="+", default=["default", "flip", "no_mount", "ideal"],
                    help=f"of {', '.join(VARIANTS)}, each optionally with _paper")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--method", default="paper")
    ap.add_argument("--draws", type=int, default=10)
    args = ap.parse_args()
    if args.experiment == "sources":
        sources(args.seeds, args.variants)
    elif args.experiment == "models":
        models(args.seeds, args.variants)
    else:
        offsets(args.seed, args.method, args.draws)


if __name__ == "__main__":
    main()
