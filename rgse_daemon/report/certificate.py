"""The one-page measurement certificate of a run's result, as a PDF to file in a test report or a PDM system.

It holds what the person who files it needs and nothing else (the full HTML report has the rest): the DuT's
identity; the status and the warnings first; mass (and CoG and inertia where measured) with U (k = 2) beside the
ECSS-E-10-03C bands; the method and the calibration's id and date; the operator and the date; and one reference to
the raw data, the SHA-256 of the run's archived ``manifest.toml`` (which names every trace of the run).

Drawn with fpdf2 (a maintained, pure-Python PDF writer) in its core Helvetica font: text is Latin-1, so symbols
outside it are spelled out (:func:`latin1`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from fpdf import FPDF

from rgse_daemon import __version__
from rgse_daemon.errors import DataError
from rgse_daemon.massmethod import mass_method_text, thermal_text
from rgse_daemon.store import NotFound, Repository
from rgse_daemon.store.records import CalibrationRecord, ResultRecord, RunRecord

#: ECSS-E-10-03C's accuracy requirements for mass properties (kuka-facts §7; docs/controller.md).
ECSS_MASS_REL = 0.0005
ECSS_COG_ALONG_M = 0.0025
ECSS_COG_PERPENDICULAR_M = 0.001
ECSS_INERTIA_REL = 0.03
#: At most this many warnings are printed; the rest are counted (the HTML report lists them all).
MAX_WARNINGS = 8
#: Longest printed warning (characters).
MAX_WARNING_CHARS = 220
IDENTITY_LABELS = (("dut_name", "Device under test"), ("serial_number", "Serial number"),
                   ("part_number", "Part number"), ("project", "Project"), ("operator", "Operator"),
                   ("note", "Note"))
_SPELLED = {"≤": "<=", "≥": ">=", "±": "+/-", "·": "*", "²": "^2", "…": "...", "–": "-", "—": "-", "σ": "sigma",
            "Δ": "delta", "β": "beta", "°": " deg", "’": "'", "“": '"', "”": '"', "→": "->"}


def latin1(text: Any) -> str:
    """``text`` in the core font's Latin-1 (± ² ° stay; others spelled out or replaced by ``?``)."""
    s = str(text)
    for a, b in _SPELLED.items():
        if a not in "±²°":
            s = s.replace(a, b)
    return s.encode("latin-1", "replace").decode("latin-1")


@dataclass(frozen=True)
class CertificateData:
    run: RunRecord
    result: ResultRecord
    calibration: CalibrationRecord | None
    manifest_sha256: str | None
    n_files: int


def load(repo: Repository, run_id: str) -> CertificateData:
    """What the certificate of ``run_id`` shows; a :class:`DataError` if the run has no result to certify."""
    try:
        run = repo.get_run(run_id)
    except NotFound as exc:
        raise DataError(f"{exc} in the {repo.description}") from exc
    results = repo.results(run_id)
    if not results:
        raise DataError(f"run {run_id} ({run.state.value}{': ' + run.detail if run.detail else ''}) has no result: "
                        f"there is nothing to certify (rgse report {run_id} shows what was recorded)")
    result = results[-1]
    cal_id = result.calibration_id or result.result.get("calibration_id")
    calibration = None
    if isinstance(cal_id, str):
        try:
            calibration = repo.get_calibration(cal_id)
        except NotFound:
            calibration = None
    files = repo.trace_files(run_id)
    manifest = [f for f in files if f.loop_index is None and f.path.rsplit("/", 1)[-1] == "manifest.toml"]
    return CertificateData(run, result, calibration, manifest[-1].sha256 if manifest else None, len(files))


def _fmt(value: float, u: float | None, unit: str, scale: float = 1.0, digits: int = 3) -> tuple[str, str]:
    v = f"{value * scale:.{digits}f} {unit}"
    return v, (f"{u * scale:.{digits}f} {unit}" if u is not None and math.isfinite(u) else "-")


def quantity_rows(doc: dict[str, Any]) -> list[tuple[str, str, str, str, str]]:
    """(quantity, value, U (k = 2), ECSS-E-10-03C band, met?) for every figure the result holds."""
    rows: list[tuple[str, str, str, str, str]] = []
    mass, u_mass = doc.get("mass_kg"), doc.get("U_kg")
    if isinstance(mass, int | float):
        value, u = _fmt(float(mass), u_mass if isinstance(u_mass, int | float) else None, "kg")
        band = ECSS_MASS_REL * abs(float(mass))
        met = "yes" if isinstance(u_mass, int | float) and u_mass <= band else "no"
        rows.append(("Mass", value, u, f"+/- {band:.3f} kg (0.05 %)", met))
    cog = doc.get("cog_dut_m") or doc.get("cog_m")
    u_cog = doc.get("U_cog_dut_m") or doc.get("U_cog_m")
    if isinstance(cog, list) and len(cog) == 3:
        frame = "DuT frame" if doc.get("cog_dut_m") else "flange frame"
        for i, axis in enumerate("xyz"):
            u = u_cog[i] if isinstance(u_cog, list) and len(u_cog) == 3 else None
            value, us = _fmt(float(cog[i]), u, "mm", 1000.0, 1)
            if u is None:
                met = "-"
            elif u <= ECSS_COG_PERPENDICULAR_M:
                met = "yes"
            elif u <= ECSS_COG_ALONG_M:
                met = "along only"
            else:
                met = "no"
            rows.append((f"CoG {axis} ({frame})", value, us, "1 mm perp. / 2.5 mm along launch axis", met))
    moments, u_moments = doc.get("principal_moments_kgm2"), doc.get("U_principal_moments_kgm2")
    if isinstance(moments, list) and moments:
        for i, j in enumerate(moments):
            u = u_moments[i] if isinstance(u_moments, list) and i < len(u_moments) else None
            value, us = _fmt(float(j), u, "kg m²")
            met = "-" if u is None else "yes" if u <= ECSS_INERTIA_REL * abs(float(j)) else "no"
            rows.append((f"Principal moment I{i + 1}", value, us, "+/- 3 %", met))
    return rows


def _time(t: datetime | None) -> str:
    return t.astimezone(UTC).strftime("%Y-%m-%d %H:%M UTC") if t is not None else "-"


class _Page(FPDF):
    run_id = ""

    def footer(self) -> None:
        self.set_y(-12)
        self.set_font("Helvetica", "", 7)
        self.set_text_color(110)
        self.cell(0, 5, latin1(f"RGSE daemon {__version__} - generated {_time(datetime.now(UTC))} - one page; the "
                               f"full report with every loop, file and check: rgse report {self.run_id}"),
                  align="C")


def certificate_pdf(data: CertificateData) -> bytes:
    """The certificate as PDF bytes (A4, one page)."""
    doc = data.result.result
    status = data.result.status
    pdf = _Page(format="A4")
    pdf.run_id = data.run.id
    pdf.set_auto_page_break(False)
    pdf.set_margins(18, 16, 18)
    pdf.add_page()
    width = pdf.w - pdf.l_margin - pdf.r_margin

    pdf.set_font("Helvetica", "B", 16)
    pdf.cell(width, 9, "Mass properties measurement certificate", new_x="LMARGIN", new_y="NEXT")
    pdf.set_font("Helvetica", "", 9)
    pdf.cell(width, 5, latin1(f"In-line measurement with the robot {data.run.robot} (RGSE, Smart GSE method) - "
                              f"run {data.run.id}"), new_x="LMARGIN", new_y="NEXT")
    pdf.ln(3)

    colour = {"ok": (30, 120, 50), "warning": (190, 120, 0), "refused": (170, 30, 30)}[status]
    pdf.set_fill_color(*colour)
    pdf.set_text_color(255)
    pdf.set_font("Helvetica", "B", 12)
    banner = {"ok": "STATUS: OK - no warnings",
              "warning": f"STATUS: WARNING - {len(doc.get('warnings') or [])} warning(s), read them with the result",
              "refused": f"STATUS: REFUSED - {doc.get('reason') or 'no figure to file'}"}[status]
    pdf.multi_cell(width, 8, latin1(banner), fill=True, new_x="LMARGIN", new_y="NEXT")
    pdf.set_text_color(0)
    warnings = [str(w) for w in doc.get("warnings") or []]
    if warnings:
        pdf.set_font("Helvetica", "", 8)
        for w in warnings[:MAX_WARNINGS]:
            text = w if len(w) <= MAX_WARNING_CHARS else w[:MAX_WARNING_CHARS - 3] + "..."
            pdf.multi_cell(width, 4, latin1(f"- {text}"), align="L", new_x="LMARGIN", new_y="NEXT")
        if len(warnings) > MAX_WARNINGS:
            pdf.multi_cell(width, 4, f"... and {len(warnings) - MAX_WARNINGS} more (see the full report)",
                           new_x="LMARGIN", new_y="NEXT")
    pdf.ln(3)

    def section(title: str) -> None:
        pdf.set_font("Helvetica", "B", 11)
        pdf.cell(width, 7, title, new_x="LMARGIN", new_y="NEXT")
        pdf.set_draw_color(160)
        pdf.line(pdf.l_margin, pdf.get_y(), pdf.l_margin + width, pdf.get_y())
        pdf.ln(1)

    def pair(label: str, value: str) -> None:
        pdf.set_font("Helvetica", "B", 9)
        pdf.cell(45, 5, latin1(label))
        pdf.set_font("Helvetica", "", 9)
        pdf.multi_cell(width - 45, 5, latin1(value), align="L", new_x="LMARGIN", new_y="NEXT")

    section("Device under test")
    identity = doc.get("identity") if isinstance(doc.get("identity"), dict) else {}
    for key, label in IDENTITY_LABELS:
        pair(label, str(identity.get(key) or "-"))
    pair("Measured", _time(data.result.created_utc))
    pdf.ln(2)

    section("Result (U: expanded uncertainty, k = 2, about 95 % coverage)")
    rows = quantity_rows(doc)
    widths = (42, 30, 27, 56, width - 155)
    pdf.set_font("Helvetica", "B", 8.5)
    for w, h in zip(widths, ("Quantity", "Value", "U (k = 2)", "ECSS-E-10-03C band", "U within?"), strict=True):
        pdf.cell(w, 6, h, border="B")
    pdf.ln()
    pdf.set_font("Helvetica", "", 8.5)
    for r in rows or [("-", "no figure", "-", "-", "-")]:
        for w, text in zip(widths, r, strict=True):
            pdf.cell(w, 5.5, latin1(text))
        pdf.ln()
    fixture = doc.get("fixture_mass_kg")
    if isinstance(fixture, int | float):
        pdf.set_font("Helvetica", "", 8)
        gross = doc.get("gross_mass_kg")
        gross_text = f"{gross:.3f} kg" if isinstance(gross, int | float) else "-"
        pdf.multi_cell(width, 4.5, latin1(f"Mass of the DuT alone: the fixture's {fixture:.3f} kg subtracted from "
                                          f"the gross {gross_text}."), new_x="LMARGIN", new_y="NEXT")
    pdf.ln(2)

    section("Method and calibration")
    cal = data.calibration
    pair("Method", "in-line mass from the drive torques of A3 and A5 (Kottmeier et al., Aerospace 11, 279, 2024)")
    method = mass_method_text(doc)
    if method is not None:  # a properties run: which mass it gives, whether auto chose it, both estimates
        pair("Mass method", method)
    pair("Calibration model", str(doc.get("method") or (cal.method if cal else "-")))
    pair("Calibration", f"{cal.id} of {_time(cal.created_utc)}" if cal is not None else
         str(doc.get("calibration_id") or "-"))
    thermal = thermal_text(doc)
    if thermal is not None:  # how the drift of the mass given was treated: β applied, or why not and U's bound
        pair("Thermal correction", thermal)
    if doc.get("operating_point") == "outside":
        pair("Operating point", "outside the calibrated envelope: U widened (see the warnings)")
    loops = doc.get("loops")
    pair("Loops", f"{loops}" + (f" ({doc.get('stop_reason')})" if doc.get("stop_reason") else "")
         if loops is not None else "-")
    pair("Robot time", f"{doc['robot_time_s'] / 60:.1f} min" if isinstance(doc.get("robot_time_s"), int | float)
         else "-")
    pdf.ln(2)

    section("Raw data")
    pair("Run manifest", f"SHA-256 {data.manifest_sha256}" if data.manifest_sha256 else "not archived")
    pair("Archive", f"{data.n_files} files of run {data.run.id}, unchanged since recording (each indexed by its "
                    f"SHA-256 in the store)")
    pdf.ln(6)
    pdf.set_font("Helvetica", "", 9)
    pdf.cell(width / 2, 5, "Operator: ____________________________")
    pdf.cell(width / 2, 5, "Reviewed: ____________________________", new_x="LMARGIN", new_y="NEXT")
    if pdf.page_no() != 1:  # the layout is bounded above; a second page would be a bug
        raise RuntimeError("the certificate ran over one page")
    return bytes(pdf.output())
