"""``rgse calibrate``: fit a calibration from Table-1 style points or from a campaign directory, write CAL.json."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rgse_daemon import calfile, robots
from rgse_daemon.analysis.calibration import POINTS_ROBOT, calibrate, fit_campaign, parse_preprocessing
from rgse_daemon.commands import add_drift_prior, add_json
from rgse_daemon.errors import DataError
from rgse_daemon.kinematics import G_PAPER_M_S2
from rgse_daemon.manifest import Setup, load_points_csv, source_sha256
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K


def make_room(out: Path) -> str | None:
    """Refuse an ``--out`` that would overwrite anything but a calibration file (a campaign's manifest or trace
    file, the points CSV, a device): raw data is never overwritten. An existing calibration file is kept beside
    it as ``<stem>.<its id><suffix>``; returns a note saying so (None if there was nothing at ``out``)."""
    if not (out.exists() or out.is_symlink()):
        return None
    if not out.is_file() or out.is_symlink():
        raise DataError(f"--out {out}: exists and is not a regular file; choose another path")
    try:
        old = calfile.read(out)
    except DataError:
        raise DataError(f"--out {out}: exists and is not a calibration file (an input of the fit?); it is not "
                        f"overwritten, choose another path") from None
    kept = out.with_name(f"{out.stem}.{old.calibration_id}{out.suffix}")
    if kept.exists():
        raise DataError(f"--out {out}: the calibration it holds is to be kept as {kept}, which exists; "
                        f"choose another path")
    out.rename(kept)
    return f"the calibration that was at {out} ({old.calibration_id}) is kept as {kept}"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse calibrate``."""
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--points", type=Path, metavar="CSV")
    src.add_argument("--campaign", type=Path, metavar="DIR")
    p.add_argument("--out", type=Path, required=True, metavar="CAL.json")
    p.add_argument("--method", default="paper", metavar="paper|auto|NAME")
    p.add_argument("--preprocessing", metavar="paper|KEY=VALUE,...",
                   help="campaign pre-processing: paper (method F, default) or e.g. a row of rgse study "
                        "(crop_sigma=2,filter=gaussian,window=100,order=forward,location=huber)")
    add_drift_prior(p, "the drift a campaign point's loops may show between them before the loop-to-loop "
                       "check sets one aside (--campaign)")
    add_json(p)


def run(args: argparse.Namespace) -> int:
    if args.points is not None:
        if getattr(args, "preprocessing", None) is not None:
            raise DataError("--preprocessing applies to --campaign (the points of a CSV are already averaged)")
        setup = Setup(POINTS_ROBOT, G_PAPER_M_S2, robots.active().lever_difference_m)
        doc, summary = calibrate(load_points_csv(args.points), args.method, setup, pre=None,
                                 bias=calfile.Bias(0.0, 0.0),
                                 provenance=calfile.Provenance(source_sha256([args.points])), where=args.points)
    else:
        pre = parse_preprocessing(getattr(args, "preprocessing", None))
        doc, summary = fit_campaign(args.campaign, args.method, pre,
                                    getattr(args, "drift_prior", DRIFT_PRIOR_PER_K))
    note = make_room(Path(args.out))
    calfile.write(args.out, doc)
    if note:
        print(note, file=sys.stderr)
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"calibration {doc.calibration_id} ({summary['method']}) written to {args.out}")
        print(f"{'method':18s} {'params':>6s} {'in-sample %':>12s} {'held-out %':>10s} {'max kg':>8s} "
              f"{'lever %':>8s}  admissible")
        for e in summary["models"]:
            mark = " *" if e["method"] == summary["method"] else ""
            lever = e["lever_group_mean_abs_err_pct"]
            adm = "yes" if e["admissible"] else f"no: {e['note']}"
            print(f"{e['method']:18s} {e['n_params']:6d} {e['in_sample_mean_abs_err_pct']:12.4f} "
                  f"{e['loo_mean_abs_err_pct']:10.4f} {e['loo_max_abs_err_kg']:8.3f} "
                  f"{'-' if lever is None else f'{lever:.3f}':>8s}  {adm}{mark}")
        rms = summary["heldout_axis_rms_nm"]
        if summary["nested_mean_abs_err_pct"] is not None:
            # always auto's figure (its whole choice repeated without each configuration), whatever was fitted here
            of = "" if args.method == "auto" else f", not of the {summary['method']} calibration written"
            print(f"out of sample of --method auto (nested: its selection repeated without each configuration"
                  f"{of}): mean |error| {summary['nested_mean_abs_err_pct']:.3f} %")
        if summary.get("r2"):
            r2 = ", ".join(f"{axis} {value:.4f}" for axis, value in sorted(summary["r2"].items()))
            print(f"R² of the K fits: {r2} (CAL.json fit.r2)")
        print(f"held-out per-axis scatter A3 {rms['A3']:.1f} Nm, A5 {rms['A5']:.1f} Nm: reproducibility "
              f"u = {summary['u_reproducibility_kg']:.3f} kg")
        for ax in (summary.get("thermal") or {}).values():  # β, its span and whether it will be applied
            print(f"thermal drift {ax['description']}")
        prior = summary.get("screening_drift_prior_per_k")
        if prior is not None:  # what the loop-to-loop check allowed (CAL.json fit.screening_drift_prior_per_k)
            print(f"loop screening allowed a point's loops a thermal drift of up to {100 * prior:.3g} %/K "
                  f"(--drift-prior {prior:g}; CAL.json fit.screening_drift_prior_per_k)")
        for a in summary.get("set_aside", []):  # loops left out of the points (their files stay as they are)
            print(f"set aside: point {a['point']} loop {a['loop']}: {a['reason']}")
        period_s = doc.fit.sample_period_s
        if period_s is not None:  # a measurement at another period gets a warning (CAL.json fit.sample_period_s)
            print(f"trace sample period {period_s * 1e3:g} ms: measure the DuT at the same period")
        sys.stdout.flush()
    return 0
