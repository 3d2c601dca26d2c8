"""The report as one self-contained HTML page: inline CSS, figures as ``data:image/png`` URIs, no external fetch.

All text goes through :func:`html.escape`. Every number is rendered by :func:`num`, which also writes the exact
value into ``data-field``/``data-value`` attributes, so a test (or a person with the inspector) can compare the
page with the store without parsing formatted text. A few lines of script mark each ``<img>`` with
``data-loaded`` once the page has loaded (used by the browser test; harmless otherwise).
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Iterable, Sequence
from datetime import datetime
from html import escape
from typing import Any

from rgse_daemon.analysis import reference as ref
from rgse_daemon.analysis.inertia import ECSS_REL
from rgse_daemon.massmethod import mass_method_text, thermal_text
from rgse_daemon.report import plots
from rgse_daemon.report.data import (
    BAND_K,
    ECSS_COG_LIMITS_M,
    ECSS_MASS_REL,
    CalibrationView,
    MeasurementView,
    ReportMeta,
)
from rgse_daemon.store import LoopRecord, RunRecord, TraceFileRecord
from rgse_daemon.verdict import status_of

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1b1b1b;background:#f4f5f7}
main{max-width:1080px;margin:0 auto;padding:18px 28px 60px;background:#fff;box-shadow:0 0 6px rgba(0,0,0,.08)}
h1{font-size:1.45em;margin:.3em 0 .1em}h2{font-size:1.15em;margin:1.6em 0 .5em;border-bottom:2px solid #dde;
padding-bottom:.2em}h3{font-size:1em;margin:1.1em 0 .3em}
.sub{color:#555;margin:0 0 .8em}
table{border-collapse:collapse;margin:.4em 0 .8em;font-size:.88em}
th,td{border:1px solid #d6d8dc;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#eef0f4;font-weight:600}td.r,th.r{text-align:right}
.num{font-variant-numeric:tabular-nums;white-space:nowrap}
code{font-family:ui-monospace,"SFMono-Regular",Menlo,Consolas,monospace;font-size:.86em;white-space:nowrap}
code.hash{white-space:normal;word-break:break-all}td.t{white-space:nowrap}
pre{background:#f6f7f9;border:1px solid #e1e3e6;padding:8px;overflow-x:auto;font-size:.8em}
img{display:block;max-width:100%;height:auto;margin:.4em 0 1em}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-size:.8em;font-weight:600}
.ok{background:#dff3e3;color:#185c27}.bad{background:#fbe0e0;color:#8a1a1a}.info{background:#e3ecf9;color:#1d3f73}
span.t{white-space:nowrap}.key td:first-child{width:280px;color:#444}
.warn{background:#fff6dd;border-left:4px solid #e0a800;padding:6px 10px;margin:.5em 0}
.status{display:inline-block;padding:2px 12px;border-radius:6px;font-weight:700;font-size:1.1em}
.status.ok{background:#dff3e3;color:#185c27}.status.warning{background:#fff6dd;color:#7a5600}
.status.refused{background:#fbe0e0;color:#8a1a1a}
footer{margin-top:2em;color:#666;font-size:.8em}
"""

_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    var good = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute('data-loaded', good ? 'yes' : 'no');
    imgs[i].setAttribute('data-natural-width', String(imgs[i].naturalWidth));
    if (good) { ok++; }
  }
  document.body.setAttribute('data-images-total', String(imgs.length));
  document.body.setAttribute('data-images-loaded', String(ok));
});
"""


# ------------------------------------------------------------------------------------------------------------
# small builders
# ------------------------------------------------------------------------------------------------------------
def t(text: object) -> str:
    """Escaped text."""
    return escape(str(text), quote=True)


def num(value: float | int | None, fmt: str, field: str, unit: str = "") -> str:
    """A number as text plus its exact value in ``data-value`` (``repr`` of the float: round-trips exactly)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return f'<span class="num" data-field="{t(field)}" data-value="">–</span>'
    shown = format(value, fmt) + (f" {unit}" if unit else "")
    return f'<span class="num" data-field="{t(field)}" data-value="{t(repr(value))}">{t(shown)}</span>'


def code(text: object, field: str | None = None, wrap: bool = False) -> str:
    """Monospaced text; ``wrap`` lets long tokens (hashes, JSON) break anywhere."""
    attr = f' data-field="{t(field)}" data-value="{t(text)}"' if field else ""
    cls = ' class="hash"' if wrap else ""
    return f"<code{cls}{attr}>{t(text)}</code>"


def when(ts: datetime | None) -> str:
    return "–" if ts is None else f'<span class="t">{t(ts.strftime("%Y-%m-%d %H:%M:%S"))} UTC</span>'


def table(header: Sequence[str], rows: Iterable[Sequence[str]], right: Sequence[int] = (), cls: str = "") -> str:
    """Cells are already HTML (built with :func:`t`, :func:`num`, :func:`code`); headers are escaped here."""
    head = "".join(f'<th class="{"r" if i in right else ""}">{t(h)}</th>' for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f'<td class="{"r" if i in right else ""}">{c}</td>' for i, c in enumerate(r))
                   + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def kv(rows: Iterable[tuple[str, str]]) -> str:
    return '<table class="key"><tbody>' + "".join(f"<tr><td>{t(k)}</td><td>{v}</td></tr>" for k, v in rows) \
        + "</tbody></table>"


def figure(png: bytes, alt: str, name: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{t(alt)}" data-figure="{t(name)}">'


def badge(ok: bool, yes: str, no: str) -> str:
    return f'<span class="badge {"ok" if ok else "bad"}">{t(yes if ok else no)}</span>'


def page(title: str, subtitle: str, body: str, meta: ReportMeta) -> str:
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<meta name=\"generator\" content=\"rgse {t(meta.software_version)}\">"
        f"<title>{t(title)}</title><style>{_CSS}</style></head><body><main>"
        f"<h1>{t(title)}</h1><p class=\"sub\">{subtitle}</p>{body}"
        f"<footer>Generated {when(meta.generated_utc)} by rgse {t(meta.software_version)} from store "
        f"{code(meta.store)}. Figures after Kottmeier et al. 2024 (Fig. 22, 25, 27, 28; Table 2).</footer>"
        f"</main><script>{_SCRIPT}</script></body></html>\n"
    )


def _files_table(files: Sequence[TraceFileRecord], prefix: str) -> str:
    rows = [(code(f.path), "–" if f.loop_index is None else num(f.loop_index + 1, "d", f"{prefix}.loop"),
             num(f.size_bytes, ",d", f"{prefix}.size_bytes", "B"), code(f.sha256, f"{prefix}.sha256", wrap=True),
             when(f.archived_utc)) for f in files]
    return table(("path (relative to the archive)", "loop", "size", "SHA-256", "archived"), rows, right=(1, 2))


def _checks(checks: Sequence[str]) -> str:
    return "<ul>" + "".join(f"<li>{badge(True, 'equal', '')} {t(c)}</li>" for c in checks) + "</ul>"


# ------------------------------------------------------------------------------------------------------------
# calibration section (shared by both pages)
# ------------------------------------------------------------------------------------------------------------
def _calibration_summary(calv: CalibrationView) -> str:
    rec, calf, cal = calv.record, calv.cal_file, calv.calibration
    fit = calf.fit
    pre = None if calf.preprocessing is None else calf.preprocessing.to_dict()
    rows = [
        ("calibration id", code(rec.id, "calibration_id")),
        ("method", code(cal.method, "calibration_method")),
        ("robot", code(rec.robot)),
        ("created (document)", t(calf.created_utc or "–")),
        ("added to the store", when(rec.added_utc)),
        ("active", (badge(True, "active", "") + f" since {when(rec.activated_utc)}") if rec.active
         else '<span class="badge info">not active</span>'),
        ("campaign run", code(rec.run_id) if rec.run_id else "– (fitted from pre-averaged points)"),
        ("g", num(cal.g_m_s2, "g", "g_m_s2", "m/s²")),
        ("lever difference r_A3 − r_A5", num(cal.lever_difference_m, "g", "lever_difference_m", "m")),
        ("bias M₀ A3 / A5", num(calf.bias.a3_nm, ".3f", "bias_a3_nm", "Nm") + " / "
         + num(calf.bias.a5_nm, ".3f", "bias_a5_nm", "Nm")),
        ("calibrated torque range A3", num(cal.torque_range_a3_nm[0], ".1f", "range_a3_lo") + " … "
         + num(cal.torque_range_a3_nm[1], ".1f", "range_a3_hi", "Nm")),
        ("calibrated torque range A5", num(cal.torque_range_a5_nm[0], ".1f", "range_a5_lo") + " … "
         + num(cal.torque_range_a5_nm[1], ".1f", "range_a5_hi", "Nm")),
        ("mean abs. mass error in sample / LOO", num(fit.in_sample_mean_abs_err_pct, ".4f", "in_sample_pct", "%")
         + " / " + num(fit.loo_mean_abs_err_pct, ".4f", "loo_pct", "%")),
        ("LOO max abs. mass error", num(fit.loo_max_abs_err_kg, ".3f", "loo_max_kg", "kg")),
        ("pre-processing",
         code(json.dumps(pre, sort_keys=True), wrap=True) if pre else "– (not recorded; paper method F)"),
    ]
    return kv(rows)


def _model_table(calv: CalibrationView) -> str:
    cal = calv.calibration
    cov = cal.covariance
    rows, j = [], 0
    for name, k_axis in (("A3", cal.k_a3), ("A5", cal.k_a5)):
        for i, p in enumerate(k_axis.params):
            sd = math.sqrt(max(float(cov[j, j]), 0.0))
            rows.append((t(name), t(k_axis.kind), t(f"p{i + 1}"), num(float(p), ".6g", f"param_{name}_{i}"),
                         num(sd, ".3g", f"param_sd_{name}_{i}")))
            j += 1
    return table(("axis", "model", "parameter", "value", "σ (covariance)"), rows, right=(3, 4))


def _calibration_points_table(calv: CalibrationView) -> str:
    rows = []
    for p in calv.points:
        m = float(p.spec["mass_kg"])
        err = p.mass_calc_kg - m
        k3 = p.expected_a3_nm / p.measured_a3_nm if m > 0 and p.measured_a3_nm else None
        k5 = p.expected_a5_nm / p.measured_a5_nm if m > 0 and p.measured_a5_nm else None
        rows.append((num(p.index + 1, "d", "point"), t(p.spec.get("kind")), num(m, ".3f", "point.mass_kg"),
                     num(p.expected_a3_nm, ".2f", "point.expected_a3"),
                     num(p.measured_a3_nm, ".2f", "point.measured_a3"),
                     num(k3, ".4f", "point.k_a3"), num(p.expected_a5_nm, ".2f", "point.expected_a5"),
                     num(p.measured_a5_nm, ".2f", "point.measured_a5"), num(k5, ".4f", "point.k_a5"),
                     num(p.mass_calc_kg, ".3f", "point.mass_calc_kg"), num(err, "+.3f", "point.err_kg"),
                     num(100 * err / m if m > 0 else None, "+.3f", "point.err_pct"),
                     num(BAND_K * p.u_mass_cal_kg, ".3f", "point.band_kg"), t(len(p.loop_indices))))
    return table(("#", "kind", "mass kg", "exp. A3 Nm", "meas. A3 Nm", "K A3", "exp. A5 Nm", "meas. A5 Nm", "K A5",
                  "calc. kg", "error kg", "error %", f"±{BAND_K:g}σ kg", "loops"), rows,
                 right=tuple(range(0, 14)))


def _campaign_screen(calv: CalibrationView) -> str:
    """What the campaign's data resolve and what it left out: β per axis with its uncertainty and span and whether
    a measurement applies it (CAL.json ``fit.thermal``), and the loops set aside with their reasons
    (``fit.set_aside``) under the drift prior the screen allowed (``fit.screening_drift_prior_per_k``)."""
    fit = calv.cal_file.fit
    out = "<h3>Thermal drift β</h3>"
    if fit.thermal is None:
        out += "<p>none fitted (the campaign's traces had no motor temperatures): no thermal correction</p>"
    else:
        out += kv([(f"{ax}", f'<span data-field="thermal.{ax}" data-value="{t(fit.thermal.describe(ax))}">'
                    f"{t(fit.thermal.describe(ax))}</span>") for ax in ("A3", "A5")])
    out += "<h3>Campaign loops set aside</h3>"
    prior = fit.screening_drift_prior_per_k
    out += ("<p>The loop-to-loop check allowed a point's loops a thermal drift of up to "
            + (f'<span data-field="screening_drift_prior_per_k" data-value="{t(repr(prior))}">{100 * prior:.3g} %/K'
               "</span> (<code>--drift-prior</code>, CAL.json "
               "<code>fit.screening_drift_prior_per_k</code>).</p>" if prior is not None else
               "a drift prior this file does not record (written before it was recorded; a calibration from "
               "pre-averaged points screens no loops).</p>"))
    if not fit.set_aside:
        out += "<p>none: every loop is in its point</p>"
    else:
        out += ('<p class="warn">' + f"{len(fit.set_aside)} loop(s) left out of their points (files archived as "
                "recorded):</p>" + table(("point", "loop", "reason"), [
                    (num(a.point, "d", "set_aside.point"), code(a.loop, "set_aside.loop"),
                     f'<span data-field="set_aside.reason" data-value="{t(a.reason)}">{t(a.reason)}</span>')
                    for a in fit.set_aside], right=(0,)))
    return out


def calibration_section(calv: CalibrationView, working: tuple[float, float] | None) -> str:
    parts = [_calibration_summary(calv), _campaign_screen(calv), "<h3>Calibration functions K</h3>",
             _model_table(calv)]
    if calv.points:
        parts += ["<h3>Calibration curves (Fig. 25)</h3>",
                  figure(plots.calibration_curves(calv), "measured against expected torque, A3 and A5",
                         "calibration_curves")]
    parts += ["<h3>K fits and error corridor (Fig. 27)</h3>",
              figure(plots.k_fits(calv, working), "calibration factor K of A3 and A5 with error corridor", "k_fits")]
    if calv.points:
        parts += ["<h3>Calibration results and error corridor (Fig. 28)</h3>",
                  figure(plots.calibration_results(calv), "mass error per calibration point", "calibration_results"),
                  "<h3>Calibration points</h3>", _calibration_points_table(calv)]
    elif calv.run is None:
        parts.append('<p class="warn">The calibration points are not in the store (the calibration was fitted from '
                     "pre-averaged points, not from an archived campaign): only the K functions are shown.</p>")
    return "".join(parts)


def _calibration_provenance(calv: CalibrationView) -> str:
    src = calv.cal_file.provenance.source_sha256
    rows = [(code(name), code(sha, "source_sha256", wrap=True)) for name, sha in sorted(src.items())]
    out = "<h3>Calibration inputs (CAL.json <code>source_sha256</code>)</h3>"
    out += table(("file", "SHA-256"), rows) if rows else "<p>none recorded</p>"
    if calv.files:
        out += f"<h3>Archived files of campaign run {code(calv.run.id if calv.run else '')}</h3>"
        out += _files_table(calv.files, "cal_file")
    return out


# ------------------------------------------------------------------------------------------------------------
# the two pages
# ------------------------------------------------------------------------------------------------------------
def render_calibration(calv: CalibrationView, meta: ReportMeta) -> str:
    rec = calv.record
    body = [
        status_lines(calv.result.result) if calv.result is not None else
        "<p>No campaign result is stored for this calibration (fitted offline): its status is not recorded.</p>",
        f"<p>{badge(True, f'{len(calv.checks)} consistency checks passed', '')}</p>",
        "<h2>Calibration</h2>", calibration_section(calv, None),
        "<h2>Provenance</h2>", _calibration_provenance(calv),
        kv([("software (this report)", code(meta.software_version, "software_version")),
            ("robot", code(rec.robot, "robot"))]),
        "<h3>Consistency checks</h3>", _checks(calv.checks),
    ]
    subtitle = f"robot {code(rec.robot)} · method {code(calv.calibration.method)} · added {when(rec.added_utc)}"
    return page(f"Calibration {rec.id}", subtitle, "".join(body), meta)


def _thermal_rows(measured: object, calibration: object) -> list[tuple[str, str]]:
    """Mean A3/A5 motor temperature of the run's traces against the calibration campaign's (the torque estimate
    drifts with it; a difference beyond 3 K is also a warning of the result)."""
    if not isinstance(measured, dict):
        return []
    cal = calibration if isinstance(calibration, dict) else {}
    rows = []
    for ax in ("A3", "A5"):
        text = num(measured.get(ax), ".1f", f"motor_temp_k.{ax}", "K")
        if ax in cal:
            text += " (calibration " + num(cal[ax], ".1f", f"cal_thermal_state_k.{ax}", "K") + ")"
        rows.append((f"{ax} motor temperature, mean", text))
    return rows


def _thermal_correction_rows(res: dict) -> list[tuple[str, str]]:
    """How the thermal drift of the mass the result gives was treated (:func:`~rgse_daemon.massmethod.thermal_text`:
    the multi-pose mass's note, or the single pose's β per axis applied or why not and the bound U carries), with
    U's thermal term; the warnings say how to avoid an uncorrected drift when it matters."""
    text = thermal_text(res)
    if text is None:
        return []
    return [("thermal correction", f'<span data-field="thermal_correction" data-value="{t(text)}">{t(text)}</span>')]


def _result_summary(view: MeasurementView) -> str:
    res = view.result.result
    m, big_u = float(res["mass_kg"]), float(res["U_kg"])
    rel = big_u / abs(m) if m else math.nan
    ecss_ok = rel <= ECSS_MASS_REL
    rows = [
        ("net mass of the DuT ± U (k = " + t(res.get("k", 2)) + ")",
         f"<strong>{num(m, '.3f', 'mass_kg')} ± {num(big_u, '.3f', 'U_kg', 'kg')}</strong>"),
        *([("mass method", t(mass_method_text(res)))] if mass_method_text(res) is not None else []),
        ("standard uncertainty u", num(res.get("u_kg"), ".4f", "u_kg", "kg")),
        *[(f"  u component: {name}", num(v if isinstance(v, int | float) else None, ".4f", f"u_component.{name}", "kg"))
          for name, v in sorted((res.get("u_components_kg") or {}).items())],
        ("gross mass (DuT and fixture)", num(res.get("gross_mass_kg"), ".3f", "gross_mass_kg", "kg")),
        ("fixture mass", num(res.get("fixture_mass_kg"), ".3f", "fixture_mass_kg", "kg")),
        ("loops", num(res.get("loops"), "d", "loops")),
        ("valid samples used / total", num(res.get("samples_used"), "d", "samples_used") + " / "
         + num(res.get("samples_total"), "d", "samples_total")),
        ("calibration", code(res.get("calibration_id"), "result_calibration_id") + " "
         + code(res.get("method"), "result_method")),
        *_thermal_rows(res.get("motor_temp_k"), view.calibration.cal_file.provenance.thermal_state_k),
        *_thermal_correction_rows(res),
        *([("operating point", f'<span data-field="operating_point" data-value="{t(res["operating_point"])}">'
            f'{t(res["operating_point"])} the calibrated envelope</span>'
            + (" (U widened; see the warnings)" if res["operating_point"] == "outside" else ""))]
          if res.get("operating_point") in ("inside", "outside") else []),
        ("ECSS-E-10-03C mass accuracy ± 0.05 %",
         f"{badge(ecss_ok, 'met', 'not met')} U / m = {num(100 * rel, '.3f', 'U_rel_pct', '%')} "
         f"(requirement {num(100 * ECSS_MASS_REL, '.2f', 'ecss_pct', '%')} = "
         f"{num(ECSS_MASS_REL * abs(m), '.3f', 'ecss_kg', 'kg')})"),
        ("result id", code(view.result.id, "result_id")),
        ("result stored", when(view.result.created_utc)),
    ]
    out = kv(rows)  # (the warnings are at the top of the report, with the status)
    if len(view.all_results) > 1:
        out += (f'<p class="warn">{len(view.all_results)} results are stored for this run; the newest is shown. '
                "Others: " + ", ".join(code(r.id) for r in view.all_results[:-1]) + "</p>")
    return out


def _reference_section(view: MeasurementView) -> str:
    if not view.references:
        return ("<p>No crane-scale reference weighing is recorded for this run "
                "(<code>rgse reference --run RUN_ID</code>).</p>")
    latest = view.references[-1]
    cmp = ref.compare(view.result.result, latest)
    rows = ref.table2_rows(view.run, cmp, latest)
    out = table(("parameter (Table 2)", "reference crane scale", "in-line robot"),
                [(t(p), t(a), t(b)) for p, a, b in rows if not p.startswith(("difference", "agreement"))],
                right=(1, 2))  # difference and agreement follow below with their exact values
    out += kv([
        ("difference in-line − scale", num(cmp.difference_kg, "+.3f", "ref.difference_kg", "kg") + " ("
         + num(cmp.difference_pct, "+.3f", "ref.difference_pct", "%") + ")"),
        ("agreement |Δ| ≤ √(U² + (2u)²)", badge(cmp.agree, "agree", "disagree") + " limit "
         + num(cmp.limit_kg, ".3f", "ref.limit_kg", "kg")),
    ])
    wrows = [(num(r.mass_kg, ".3f", "ref.mass_kg", "kg"), t(r.weighed), num(r.net_mass_kg, ".3f", "ref.net_mass_kg"),
              num(r.u_kg, ".4f", "ref.u_kg"), num(r.resolution_kg, "g", "ref.resolution_kg"),
              code(r.raw_line, "ref.raw"),
              code(r.device), t(r.weighed_utc), num(r.bad_frames, "d", "ref.bad_frames"), code(r.result_id))
             for r in view.references]
    out += "<h3>Recorded weighings</h3>" + table(
        ("reading kg", "weighed", "net kg", "u kg", "d kg", "raw line", "device", "time", "bad frames", "for result"),
        wrows, right=(0, 2, 3, 4, 8))
    return out


def _loops_table(view: MeasurementView) -> str:
    res = view.result.result
    fixture = float(res.get("fixture_mass_kg", 0.0))
    aside = {str(a.get("loop")): str(a.get("reason")) for a in res.get("loops_set_aside") or ()
             if isinstance(a, dict)}
    rows = []
    for number, lp in enumerate(view.loops, 1):  # numbered 1..n as in the loop plot, whatever the stored index
        r = lp.record
        used = ("yes" if r.trace_name not in aside else
                f'<span class="warn" data-field="loop.set_aside" data-value="{t(aside[r.trace_name])}">set aside: '
                f"{t(aside[r.trace_name])}</span>")
        rows.append((num(number, "d", "loop.number"), code(r.trace_name, "loop.trace"), t(r.state.value), used,
                     num(lp.a3.loop_mean_nm, ".3f", "loop.a3_mean_nm"),
                     num(lp.a5.loop_mean_nm, ".3f", "loop.a5_mean_nm"),
                     '<span class="t">' + num(lp.a3.n_used, "d", "loop.a3_used") + " / "
                     + num(lp.a3.n_total, "d", "loop.a3_total") + "</span>",
                     '<span class="t">' + num(lp.a5.n_used, "d", "loop.a5_used") + " / "
                     + num(lp.a5.n_total, "d", "loop.a5_total") + "</span>",
                     num(lp.gross_mass_kg - fixture if lp.gross_mass_kg is not None else None, ".3f",
                         "loop.net_mass_kg"),
                     when(r.robot_start_utc), when(r.record_end_utc)))
    return table(("loop", "trace", "state", "in the result", "A3 mean Nm", "A5 mean Nm", "A3 used", "A5 used",
                  "net mass kg", "robot start", "recording end"), rows, right=(0, 4, 5, 6, 7, 8))


def _cog_section(cog: dict[str, Any]) -> str:
    """The CoG table (flange and DuT frame, U with k = 2) beside the ECSS-E-10-03C accuracy, and its picture."""
    rows = []
    for i, axis in enumerate("xyz"):
        lim = ECSS_COG_LIMITS_M[i]
        u_dut = float(cog["U_cog_dut_m"][i])
        rows.append((t(axis), num(1000 * float(cog["cog_flange_m"][i]), ".2f", f"cog_flange_mm.{axis}"),
                     num(1000 * float(cog["U_cog_flange_m"][i]), ".2f", f"U_cog_flange_mm.{axis}"),
                     num(1000 * float(cog["cog_dut_m"][i]), ".2f", f"cog_dut_mm.{axis}"),
                     num(1000 * u_dut, ".2f", f"U_cog_dut_mm.{axis}"),
                     t(f"±{1000 * lim:g} mm " + ("along" if axis == "z" else "across")),
                     badge(u_dut <= lim, "met", "not met")))
    out = table(("coordinate", "flange frame mm", "U mm (k = 2)", "DuT frame mm", "U mm (k = 2)",
                 "ECSS-E-10-03C", "U within it"), rows, right=(1, 2, 3, 4), cls="cog")
    out += kv([("scheme / poses", t(f"{cog.get('scheme')} / {cog.get('n_poses')}")),
               ("DuT mass used", num(cog.get("mass_kg"), ".3f", "cog_mass_kg", "kg") + " ± "
                + num(cog.get("U_mass_kg"), ".3f", "cog_U_mass_kg", "kg")),
               ("reduced χ² of the fit", num((cog.get("budget") or {}).get("chi2_red"), ".2f", "cog_chi2_red"))])
    out += ("<p>The launch axis is the DuT frame's z. The CoG is recomputed from the archived pose loops with the "
            "stored calibration and found equal to the stored one.</p>")
    for w in cog.get("warnings") or []:
        out += f'<p class="warn">warning: {t(w)}</p>'
    return '<div class="cog-figure">' + out + figure(plots.cog_in_dut_frame(cog), "the CoG in the DuT frame with U "
                                                     "and the ECSS accuracy", "cog_in_dut_frame") + "</div>"


def _inertia_section(inertia: dict[str, Any]) -> str:
    """The inertia tensor about the CoG in the DuT frame, the principal moments (ascending) with U (k = 2) beside
    ECSS-E-10-03C's ±3 %, said plainly where U exceeds it, and the principal axes."""
    tensor, u_tensor = inertia["inertia_cog_dut_kgm2"], inertia["U_inertia_cog_dut_kgm2"]
    rows = [(t(axis), *(num(float(tensor[i][j]), ".3f", f"inertia_cog_dut_kgm2.{axis}{b}") + " ± "
                        + num(float(u_tensor[i][j]), ".3f", f"U_inertia_cog_dut_kgm2.{axis}{b}")
                        for j, b in enumerate("xyz")))
            for i, axis in enumerate("xyz")]
    out = "<p>Inertia tensor about the CoG, DuT frame (kg·m², U with k = 2):</p>"
    out += table(("", "x", "y", "z"), rows, right=(1, 2, 3), cls="inertia")
    prows = []
    met_all = True
    for k, (m, u, axis, ua) in enumerate(zip(inertia["principal_moments_kgm2"], inertia["U_principal_moments_kgm2"],
                                             inertia["principal_axes_dut"], inertia["U_principal_axes_deg"],
                                             strict=True), 1):
        met = float(u) <= ECSS_REL * abs(float(m))
        met_all &= met
        prows.append((t(f"I{k}"), num(float(m), ".3f", f"principal_moments_kgm2.{k}"),
                      num(float(u), ".3f", f"U_principal_moments_kgm2.{k}"),
                      num(100.0 * float(u) / abs(float(m)) if m else None, ".1f", f"U_principal_pct.{k}", "%"),
                      t("(" + ", ".join(f"{float(v):+.3f}" for v in axis) + ")"),
                      num(float(ua), ".1f", f"U_principal_axes_deg.{k}", "°"),
                      t("±3 %"), badge(met, "met", "not met")))
    out += table(("moment", "kg·m²", "U kg·m² (k = 2)", "U / moment", "axis (DuT frame)", "U axis",
                  "ECSS-E-10-03C", "U within it"), prows, right=(1, 2, 3, 5), cls="inertia")
    if not met_all:
        out += ('<p class="warn">Where U exceeds ±3 % the measurement does not show the ECSS accuracy: at T1 speeds '
                "the inertial torques are small against the drive's noise, and the parallel-axis shift to the CoG "
                "carries the CoG's own U (README, Moments of inertia).</p>")
    exc = inertia.get("excitation") or {}
    out += kv([("strokes / samples", t(f"{inertia.get('n_strokes')} / {inertia.get('n_samples')}")),
               ("excitation", t(f"{exc.get('moves')} moves in {exc.get('parts')} parts, "
                                f"{exc.get('planned_robot_time_s', float('nan')):.0f} s planned per run, tare and "
                                "DuT")),
               ("condition number", num(inertia.get("condition_number"), ".1f", "inertia_condition_number"))])
    out += ("<p>Identified from the DuT's and the tare's excitation (the same programs, the DuT taken off for the "
            "tare) with the mass and CoG of this run; recomputed from the archived traces with the stored "
            "calibration and found equal to the stored result.</p>")
    for w in inertia.get("warnings") or []:
        out += f'<p class="warn">warning: {t(w)}</p>'
    return out


#: The identity fields of a run (interfaces §4.3 ``identity``), in the order the report shows them.
IDENTITY_FIELDS = (("dut_name", "DuT"), ("serial_number", "serial number"), ("part_number", "part number"),
                   ("project", "project"), ("operator", "operator"), ("note", "note"))


def status_lines(result: dict[str, Any]) -> str:
    """A result's status (``ok``, ``warning``, ``refused``), every warning, a refusal's reason and, for a properties
    run, where its mass came from."""
    status = status_of(result)
    warnings = result.get("warnings") or []
    out = (f'<p>status <span class="status {status}" data-field="status" data-value="{t(status)}">{t(status)}</span> '
           + (f"{len(warnings)} warning(s): read them before filing the result" if warnings else "no warnings")
           + "</p>")
    for w in warnings:
        out += f'<p class="warn">warning: <span data-field="warning" data-value="{t(w)}">{t(w)}</span></p>'
    if result.get("reason"):
        out += f'<p class="warn">refused: {t(result["reason"])}</p>'
    method = mass_method_text(result)
    if method is not None:
        out += f'<p>mass: <span data-field="mass_method" data-value="{t(method)}">{t(method)}</span></p>'
    return out


def status_head(result: dict[str, Any], identity: dict[str, Any] | None) -> str:
    """The top of a run's report: the result's status (``ok``, ``warning``, ``refused``), every warning, and who
    and what was measured (the run's identity)."""
    out = status_lines(result)
    who = identity or {}
    rows = [(label, f'<span data-field="identity.{key}" data-value="{t(who[key])}">{t(who[key])}</span>')
            for key, label in IDENTITY_FIELDS if who.get(key)]
    out += kv(rows) if rows else "<p>No identity was given for this run (DuT name, serial number, project, " \
                                 "operator: <code>rgse run measure --dut-name ...</code>).</p>"
    return out


def render_measurement(view: MeasurementView, meta: ReportMeta) -> str:
    run = view.run
    n_checks = len(view.checks) + len(view.calibration.checks)
    identity = view.result.result.get("identity") or (run.config.get("settings") or {}).get("identity")
    body = [
        status_head(view.result.result, identity),
        f"<p>{badge(True, f'{n_checks} consistency checks passed', '')} "
        "(raw files verified, result recomputed from them and found equal)</p>",
        "<h2>Result</h2>", _result_summary(view),
        "<h2>Mass against ECSS-E-10-03C and the crane scale</h2>",
        figure(plots.mass_vs_ecss(view), "net mass with U against the ECSS band and the crane scale", "mass_vs_ecss"),
        *(["<h2>Centre of gravity</h2>", _cog_section(view.cog)] if view.cog is not None else []),
        *(["<h2>Moments of inertia</h2>", _inertia_section(view.inertia)] if view.inertia is not None else []),
        "<h2>Reference measurement (Table 2)</h2>", _reference_section(view),
        "<h2>Loop by loop</h2>", _loops_table(view),
        figure(plots.loop_masses(view), "net mass of each loop", "loop_masses"),
        "<p>A loop's mass is eq. 21 on that loop's pre-processed means alone; the result uses the double average of "
        "eq. 16 over all loops"
        + (" for its single-pose estimate; the mass it gives is the multi-pose one (above)"
           if view.result.result.get("mass_method") == "multipose" else "") + ".</p>",
        "<h2>Torque traces per loop (Fig. 22)</h2>",
        f"<p>Pre-processing {code(json.dumps(view.calibration.preprocessing.to_dict(), sort_keys=True), wrap=True)}"
        ": raw samples, "
        "the samples kept after the settle cut and the σ crop, the filtered series and the loop mean.</p>",
    ]
    for number, lp in enumerate(view.loops, 1):
        body.append(figure(plots.loop_traces(lp), f"torque traces of loop {number} ({lp.record.trace_name}), A3 and A5",
                           f"loop_{number}"))
    body += ["<h2>Calibration used</h2>",
             calibration_section(view.calibration, (view.working_a3_nm, view.working_a5_nm))]
    prov = [
        ("run id", code(run.id, "run_id")), ("kind / state", t(f"{run.kind.value} / {run.state.value}")),
        ("robot", code(run.robot, "robot")), ("created", when(run.created_utc)), ("started", when(run.started_utc)),
        ("ended", when(run.ended_utc)), ("archive directory", code(run.directory)),
        ("software (this report)", code(meta.software_version, "software_version")),
        ("software (recorded with the run)", code(run.config.get("software_version", "–"))),
        ("calibration", code(view.calibration.record.id) + " " + code(view.calibration.calibration.method)),
        ("result inputs (SHA-256)", num(len(view.result.trace_sha256), "d", "result_inputs") + " archived files"),
    ]
    if run.detail:
        prov.append(("detail", t(run.detail)))
    body += ["<h2>Provenance</h2>", kv(prov),
             "<h3>Run configuration</h3>", f"<pre>{t(json.dumps(run.config, indent=2, sort_keys=True))}</pre>",
             _calibration_provenance(view.calibration)]
    if view.events:
        body += ["<h3>Events</h3>", table(("time", "level", "kind", "message"),
                                          [(when(e.time_utc), t(e.level.value), code(e.kind), t(e.message))
                                           for e in view.events])]
    body += ["<h3>Consistency checks</h3>", _checks([*view.calibration.checks, *view.checks]),
             "<h2>Appendix: archived raw files</h2>",
             "<p>Every file the result rests on, as archived (never rewritten), with its SHA-256.</p>",
             _files_table(view.files, "file")]
    subtitle = (f"robot {code(run.robot)} · run {code(run.id)} · {t(run.state.value)} · "
                f"{num(float(view.result.result['mass_kg']), '.3f', 'headline_mass_kg', 'kg')} ± "
                f"{num(float(view.result.result['U_kg']), '.3f', 'headline_U_kg', 'kg')} (k = 2)")
    return page(f"In-line mass determination, run {run.id}", subtitle, "".join(body), meta)


def render_run_record(run: RunRecord, loops: Sequence[LoopRecord], files: Sequence[TraceFileRecord],
                      events: Sequence[Any], meta: ReportMeta, refused: dict[str, Any] | None = None) -> str:
    """The report of a run that has no figure (failed, aborted, interrupted, or completed with a ``refused`` result):
    why it ended or was refused, what it recorded (the loops set aside with their reasons), and its archived raw
    files; nothing is computed."""
    reason = run.detail or "no reason recorded"
    head = refused if refused is not None else {"status": "refused", "reason": f"run {run.state.value}: {reason}",
                                                "warnings": []}
    if refused is not None:
        reason = str(refused.get("reason") or "no reason given")
    aside = (refused or {}).get("loops_set_aside") or []
    body = [status_head(head, (run.config.get("settings") or {}).get("identity")),
            "<h2>Run</h2>",
            kv([("run id", code(run.id, "run_id")), ("kind / state", t(f"{run.kind.value} / {run.state.value}")),
                ("why it ended", t(reason)), ("robot", code(run.robot, "robot")), ("created", when(run.created_utc)),
                ("started", when(run.started_utc)), ("ended", when(run.ended_utc)),
                ("archive directory", code(run.directory))]),
            "<h2>Loops recorded</h2>",
            table(("loop", "trace", "state", "robot start", "recording end"),
                  [(num(i, "d", "loop.number"), code(lp.trace_name, "loop.trace"), t(lp.state.value),
                    when(lp.robot_start_utc), when(lp.record_end_utc)) for i, lp in enumerate(loops, 1)],
                  right=(0,)) if loops else "<p>No loop was recorded.</p>"]
    if aside:
        body += ["<h2>Loops set aside</h2>", table(("loop", "reason"), [(code(str(a.get("loop")), "loop.trace"),
                                                                          t(str(a.get("reason")))) for a in aside])]
    if events:
        body += ["<h2>Events</h2>", table(("time", "level", "kind", "message"),
                                          [(when(e.time_utc), t(e.level.value), code(e.kind), t(e.message))
                                           for e in events])]
    body += ["<h2>Run configuration</h2>", f"<pre>{t(json.dumps(run.config, indent=2, sort_keys=True))}</pre>",
             "<h2>Appendix: archived raw files</h2>",
             _files_table(files, "file") if files else "<p>No file was archived.</p>"]
    subtitle = (f"robot {code(run.robot)} · run {code(run.id)} · {t(run.state.value)} · "
                + ("result refused" if refused is not None else "no result"))
    return page(f"Run record, {run.kind.value} run {run.id}", subtitle, "".join(body), meta)
