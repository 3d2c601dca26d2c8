"""The report's figures as PNG bytes (matplotlib, Agg canvas; pyplot and its global state are never touched).

Each function takes the checked views of :mod:`rgse_daemon.report.data` and draws only what they hold.
Figure numbers refer to Kottmeier et al. 2024.
"""

from __future__ import annotations

import io
import textwrap

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from rgse_daemon.report.data import (
    BAND_K,
    ECSS_COG_LIMITS_M,
    ECSS_MASS_REL,
    AxisProcessing,
    CalibrationView,
    LoopView,
    MeasurementView,
    band_of_k,
)

DPI = 100
_RAW, _KEPT, _FILT, _MEAN = "#b0b0b0", "#1f77b4", "#ff7f0e", "#d62728"
_KIND_STYLE = {"zero": ("#7f7f7f", "s"), "mass": ("#1f77b4", "o"), "torque": ("#2ca02c", "^")}


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _new(width: float, height: float, rows: int = 1, cols: int = 1):
    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


# ------------------------------------------------------------------------------------------------------------
# Fig. 22: one loop
# ------------------------------------------------------------------------------------------------------------
def _axis_trace(ax, a: AxisProcessing, name: str) -> None:
    ax.plot(a.time_s, a.raw_nm, color=_RAW, lw=0.6, label="raw samples")
    ax.plot(a.kept_time_s, a.kept_nm, ".", color=_KEPT, ms=1.5, label=f"kept after crop ({a.n_used}/{a.n_total})")
    ax.plot(a.filtered_time_s, a.filtered_nm, color=_FILT, lw=1.4, label="filtered")
    ax.axhline(a.loop_mean_nm, color=_MEAN, ls="--", lw=1.2, label=f"loop mean {a.loop_mean_nm:.2f} Nm")
    lo, hi = float(np.min(a.kept_nm)), float(np.max(a.kept_nm))
    pad = 0.6 * (hi - lo) + 1e-9
    ax.set_ylim(lo - pad, hi + pad)  # cropped spikes run off the view: the raw line still shows where they are
    ax.set_ylabel(f"{name} torque (Nm)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=7, ncol=2)


def loop_traces(loop: LoopView) -> bytes:
    fig, axes = _new(10, 5.2, 2, 1)
    _axis_trace(axes[0, 0], loop.a3, "A3")
    _axis_trace(axes[1, 0], loop.a5, "A5")
    axes[1, 0].set_xlabel("time in trace (s)")
    fig.suptitle(f"Loop {loop.index + 1}: {loop.record.trace_name} (sample period {loop.period_s * 1e3:g} ms)",
                 fontsize=10)
    return _png(fig)


# ------------------------------------------------------------------------------------------------------------
# measurement: loop masses, mass against ECSS-E-10-03C
# ------------------------------------------------------------------------------------------------------------
def loop_masses(view: MeasurementView) -> bytes:
    res = view.result.result
    fixture = float(res.get("fixture_mass_kg", 0.0))
    net = np.array([lp.gross_mass_kg - fixture for lp in view.loops])
    x = np.arange(1, net.size + 1)
    m, big_u = float(res["mass_kg"]), float(res["U_kg"])
    fig, axes = _new(10, 3.4)
    ax = axes[0, 0]
    ax.axhspan(m - big_u, m + big_u, color="#1f77b4", alpha=0.12, label=f"result ± U (k = 2): {m:.3f} ± {big_u:.3f} kg")
    e = ECSS_MASS_REL * abs(m)
    ax.axhspan(m - e, m + e, color="#2ca02c", alpha=0.35, label=f"ECSS-E-10-03C ± 0.05 % (± {e:.3f} kg)")
    ax.axhline(m, color="#1f77b4", lw=1.0)
    ax.plot(x, net, "o-", color="#d62728", ms=5, lw=0.8, label="net mass of each loop alone")
    lo = min(float(net.min()), m - e)
    hi = max(float(net.max()), m + e)
    pad = max(0.4 * (hi - lo), e)
    ax.set_ylim(lo - pad, hi + pad)  # zoomed on the loops: a U band wider than the view fills it
    ax.set_xticks(x)
    ax.set_xlabel("loop")
    ax.set_ylabel("net mass (kg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return _png(fig)


def mass_vs_ecss(view: MeasurementView) -> bytes:
    res = view.result.result
    m, big_u = float(res["mass_kg"]), float(res["U_kg"])
    ref = view.references[-1] if view.references else None
    centre = ref.net_mass_kg if ref is not None else m
    e = ECSS_MASS_REL * abs(centre)
    fig, axes = _new(10, 1.9 if ref is None else 2.8)
    ax = axes[0, 0]
    ax.axvspan(centre - e, centre + e, color="#2ca02c", alpha=0.35,
               label=f"ECSS-E-10-03C ± 0.05 % of {'the scale' if ref else 'the in-line'} mass (± {e:.3f} kg)")
    y_inline = 1 if ref is not None else 0
    ax.errorbar([m], [y_inline], xerr=[[big_u], [big_u]], fmt="o", color="#1f77b4", capsize=6,
                label=f"in-line net mass ± U (k = 2): {m:.3f} ± {big_u:.3f} kg")
    labels = ["in-line (robot)"]
    if ref is not None:
        d = ref.resolution_kg
        ax.axvspan(ref.net_mass_kg - d, ref.net_mass_kg + d, ymin=0.0, ymax=0.5, color="#ff7f0e", alpha=0.25,
                   label=f"crane scale ± d ({d:g} kg)")
        ax.errorbar([ref.net_mass_kg], [0], xerr=[[2 * ref.u_kg], [2 * ref.u_kg]], fmt="s", color="#ff7f0e",
                    capsize=6, label=f"crane scale net mass ± 2u: {ref.net_mass_kg:.3f} ± {2 * ref.u_kg:.3f} kg")
        labels = ["crane scale", "in-line (robot)"]
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels)
    ax.set_ylim(-0.7, len(labels) - 0.3)
    ax.set_xlabel("net mass (kg)")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _png(fig)


def cog_in_dut_frame(cog: dict) -> bytes:
    """The CoG in the DuT's frame (mm): across the launch axis (x-y, with U as a rectangle) and along it (z), each
    with the ECSS-E-10-03C accuracy (±1 mm across, ±2.5 mm along) drawn about the measured point for comparison."""
    c = 1000.0 * np.asarray(cog["cog_dut_m"], dtype=float)
    u = 1000.0 * np.asarray(cog["U_cog_dut_m"], dtype=float)
    lim = 1000.0 * np.asarray(ECSS_COG_LIMITS_M)
    fig, axes = _new(10, 5.0, 1, 2)
    ax = axes[0, 0]
    ax.add_patch(_rect(c[0] - lim[0], c[1] - lim[1], 2 * lim[0], 2 * lim[1], "#2ca02c", 0.25,
                       f"ECSS ± {lim[0]:g} mm across"))
    ax.add_patch(_rect(c[0] - u[0], c[1] - u[1], 2 * u[0], 2 * u[1], "#1f77b4", 0.35, "± U (k = 2)"))
    ax.plot([c[0]], [c[1]], "o", color="#d62728", label=f"CoG x {c[0]:.2f}, y {c[1]:.2f} mm")
    half = 1.6 * max(lim[0], u[0], u[1])  # zoomed to the CoG: U and the ECSS box must be readable
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm, DuT frame)")
    ax.set_ylabel("y (mm, DuT frame)")
    ax.set_title("across the launch axis", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3)
    ax = axes[0, 1]
    ax.axhspan(c[2] - lim[2], c[2] + lim[2], color="#2ca02c", alpha=0.25, label=f"ECSS ± {lim[2]:g} mm along")
    ax.errorbar([0], [c[2]], yerr=[[u[2]], [u[2]]], fmt="o", color="#d62728", capsize=8,
                label=f"CoG z {c[2]:.2f} ± {u[2]:.2f} mm (k = 2)")
    ax.set_xticks([])
    ax.set_xlim(-1, 1)
    ax.set_ylabel("z (mm, DuT frame: the launch axis)")
    ax.set_title("along the launch axis", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.04), ncol=1)
    return _png(fig)


def _rect(x: float, y: float, w: float, h: float, color: str, alpha: float, label: str):
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, color=color, alpha=alpha, label=label)


# ------------------------------------------------------------------------------------------------------------
# calibration: Fig. 25 (curves), Fig. 27 (K fits with corridor), Fig. 28 (results and error corridor)
# ------------------------------------------------------------------------------------------------------------
def calibration_curves(calv: CalibrationView) -> bytes:
    cal = calv.calibration
    fig, axes = _new(10, 5.0, 1, 2)
    for ax, name, k_axis in ((axes[0, 0], "A3", cal.k_a3), (axes[0, 1], "A5", cal.k_a5)):
        meas = np.array([getattr(p, f"measured_{name.lower()}_nm") for p in calv.points])
        exp = np.array([getattr(p, f"expected_{name.lower()}_nm") for p in calv.points])
        kinds = [str(p.spec.get("kind")) for p in calv.points]
        span = max(float(np.max(np.abs(exp))), float(np.max(np.abs(meas))), 1.0)
        ax.plot([0, span], [0, span], color="#7f7f7f", lw=0.8, ls=":", label="ideal: measured = expected")
        sign = 1.0 if float(np.sum(meas)) >= 0 else -1.0
        grid = sign * np.linspace(0, float(np.max(np.abs(meas))) * 1.05, 200)
        ax.plot(np.abs(k_axis.corrected_torque_nm(grid)), np.abs(grid), color="#d62728", lw=1.2,
                label="calibration K(M)·M")
        for kind in sorted(set(kinds)):
            sel = np.array([k == kind for k in kinds])
            color, marker = _KIND_STYLE.get(kind, ("#000000", "x"))
            ax.plot(np.abs(exp[sel]), np.abs(meas[sel]), marker, color=color, ms=6, ls="", label=f"{kind} points")
        ax.set_xlabel(f"expected torque |g·m·lever| {name} (Nm)")
        ax.set_ylabel(f"measured torque |M − M₀| {name} (Nm)")
        ax.set_title(f"{name}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    # an averaged method names every member model; wrapped above the axes so that it never squeezes them
    fig.suptitle("\n".join(textwrap.wrap(f"method: {cal.method}", 110)), fontsize=8)
    return _png(fig)


def k_fits(calv: CalibrationView, working: tuple[float, float] | None = None) -> bytes:
    cal = calv.calibration
    cov = np.asarray(cal.covariance, float)
    n3 = len(cal.k_a3.params)
    fig, axes = _new(10, 5.0, 1, 2)
    for ax, name, k_axis, block, rng, w in (
        (axes[0, 0], "A3", cal.k_a3, cov[:n3, :n3], cal.torque_range_a3_nm, None if working is None else working[0]),
        (axes[0, 1], "A5", cal.k_a5, cov[n3:, n3:], cal.torque_range_a5_nm, None if working is None else working[1]),
    ):
        lo, hi = rng
        top = max(hi, abs(w) if w is not None else 0.0) * 1.05
        grid = np.linspace(max(lo * 0.5, 1e-3), top, 300)
        k = k_axis.k(grid)
        sd = band_of_k(k_axis, block, grid)
        ax.fill_between(grid, k - BAND_K * sd, k + BAND_K * sd, color="#1f77b4", alpha=0.2,
                        label=f"± {BAND_K:g}σ from the parameter covariance")
        ax.plot(grid, k, color="#1f77b4", lw=1.4, label=f"K({name}) fitted ({k_axis.kind})")
        ax.axvspan(lo, hi, color="#7f7f7f", alpha=0.08, label="calibrated torque range")
        inside = (grid >= lo) & (grid <= hi)
        shown = [k[inside]] if inside.any() else [k]
        if calv.points:
            meas = np.array([getattr(p, f"measured_{name.lower()}_nm") for p in calv.points])
            exp = np.array([getattr(p, f"expected_{name.lower()}_nm") for p in calv.points])
            loaded = np.array([float(p.spec["mass_kg"]) > 0 for p in calv.points]) & (meas != 0)
            ratio = exp[loaded] / meas[loaded]
            shown.append(ratio)
            ax.plot(np.abs(meas[loaded]), ratio, "o", color="#d62728", ms=5,
                    label="ratio samples K = expected / measured")
        if w is not None:
            kw = float(k_axis.k(np.array([w]))[0])
            ax.plot([abs(w)], [kw], "*", color="#2ca02c", ms=14, label=f"this measurement |M| = {abs(w):.1f} Nm")
            shown.append(np.array([kw]))
        vals = np.concatenate(shown)
        span = float(vals.max() - vals.min()) or 1e-3 * abs(float(vals.mean()))
        ax.set_ylim(float(vals.min()) - 0.5 * span, float(vals.max()) + 0.5 * span)
        ax.set_xlabel(f"measured torque |M − M₀| {name} (Nm)")
        ax.set_ylabel(f"calibration factor K {name}")
        ax.set_title(name, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    return _png(fig)


def calibration_results(calv: CalibrationView) -> bytes:
    true = np.array([float(p.spec["mass_kg"]) for p in calv.points])
    calc = np.array([p.mass_calc_kg for p in calv.points])
    band = BAND_K * np.array([p.u_mass_cal_kg for p in calv.points])
    x = np.arange(1, true.size + 1)
    fig, axes = _new(10, 3.6)
    ax = axes[0, 0]
    ax.axhline(0.0, color="#7f7f7f", lw=0.8)
    ax.errorbar(x, calc - true, yerr=band, fmt="o", color="#1f77b4", capsize=4,
                label=f"calculated − true mass, ± {BAND_K:g}σ from the parameter covariance")
    loo = calv.cal_file.fit.loo_max_abs_err_kg  # finite: validated on reading
    ax.axhspan(-loo, loo, color="#ff7f0e", alpha=0.12, label=f"leave-one-out max error ± {loo:.3f} kg")
    ax.set_xticks(x)
    ax.set_xticklabels([f"{i}\n{m:g} kg" for i, m in zip(x, true, strict=True)], fontsize=7)
    ax.set_xlabel("calibration point")
    ax.set_ylabel("mass error (kg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return _png(fig)
